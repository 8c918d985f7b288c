"""`python -m sut_adapter.inline BRIDGE-ARGUMENTS -- AUTOPILOT-ARGUMENTS`: the bundled autopilot
inside the bridge's process, its simulator link through memory (autopilot/inline.py) rather
than TCP. The harness starts it for `--transport memory`; the bridge's arguments are
`python -m sim_bridge`'s, the autopilot's `python -m autopilot`'s (--api, --params, --fault).
With the bridge's `--serve` (warm workers) every flight gets a fresh autopilot.
"""

from __future__ import annotations

import copy
import sys
from typing import Callable

import sim_bridge.__main__ as bridge
from autopilot.__main__ import address, arguments, load_params
from autopilot.app import Autopilot
from autopilot.inline import InProcessLink
from autopilot.params import ParamError, Params


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if "--" not in argv:
        print(f"usage: python -m sut_adapter.inline BRIDGE-ARGUMENTS -- AUTOPILOT-ARGUMENTS; got {' '.join(argv)!r}", file=sys.stderr)
        return 2
    split = argv.index("--")
    autopilot_args = arguments(argv[split + 1:])
    try:
        params = load_params(autopilot_args)
    except (ParamError, OSError, ValueError) as error:
        print(f"{autopilot_args.params or '--fault'}: {error}", file=sys.stderr)
        return 2
    return bridge.main(argv[:split], inline_sut=fresh_autopilots(params, address(autopilot_args.api, "udp")))


def fresh_autopilots(params: Params, api_address: tuple[str, int]) -> Callable[[], InProcessLink]:
    """A new autopilot for each flight, with its own copy of the start-up parameters: one flown
    before it in this process (the bridge's --serve) may have changed its own over MAVLink (the
    pilot drive's RC mapping and takeoff altitude, SYS_FAILURE_EN)."""
    return lambda: InProcessLink(Autopilot(copy.deepcopy(params)), api_address)


if __name__ == "__main__":
    sys.exit(main())
