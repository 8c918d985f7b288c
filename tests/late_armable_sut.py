"""A SUT that becomes armable late: the bundled autopilot whose pre-arm checks pass only LATE_S
(default 1 s) of simulated time after its position estimate is healthy, denying arming until
then, as PX4 does just after MAVSDK first reports it healthy (its estimate settling). With
"failed" it answers a refusal with MAV_RESULT_FAILED instead of DENIED, as ArduPilot answers an
arming its pre-arm checks fail (its GCS_MAVLINK::handle_command_component_arm_disarm).

python tests/late_armable_sut.py SIM_PORT API_PORT [LATE_S [denied|failed]]
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import autopilot.__main__ as entry  # noqa: E402
from autopilot.app import Autopilot  # noqa: E402

class LateArmable(Autopilot):
    healthy_since_s = None

    def ready_to_arm(self) -> tuple[bool, str]:
        ready, reason = super().ready_to_arm()
        if not ready:
            return ready, reason
        if self.healthy_since_s is None:
            self.healthy_since_s = self.now_s
        if self.now_s - self.healthy_since_s < late_s:
            return False, "pre-arm checks still running"
        return True, ""


if __name__ == "__main__":
    late_s = float(sys.argv[3]) if len(sys.argv) > 3 else 1.0
    if sys.argv[4:] == ["failed"]:
        from pymavlink.dialects.v20 import common as mavlink

        mavlink.MAV_RESULT_DENIED = mavlink.MAV_RESULT_FAILED  # the constant every refusal of this autopilot is answered with
    entry.Autopilot = LateArmable  # the autopilot python -m autopilot makes
    sys.exit(entry.main(["--sim", f"tcp:127.0.0.1:{sys.argv[1]}", "--api", f"udp:127.0.0.1:{sys.argv[2]}"]))
