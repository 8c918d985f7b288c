"""A SUT that refuses failure injection: the bundled autopilot answering every
MAV_CMD_INJECT_FAILURE with MAV_RESULT_UNSUPPORTED, as a PX4 build does for a unit or type its
simulator interface cannot fail, so the flight goes on unfailed.

python tests/refusing_sut.py SIM_PORT API_PORT
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

import autopilot.app  # noqa: E402
from autopilot.__main__ import main  # noqa: E402
from autopilot.api import ApiLink  # noqa: E402


class RefusingApiLink(ApiLink):
    def _inject_failure(self, msg) -> None:
        self._ack(msg, mavlink.MAV_RESULT_UNSUPPORTED)


if __name__ == "__main__":
    autopilot.app.ApiLink = RefusingApiLink  # the autopilot makes its API link when it connects
    sys.exit(main(["--sim", f"tcp:127.0.0.1:{sys.argv[1]}", "--api", f"udp:127.0.0.1:{sys.argv[2]}"]))
