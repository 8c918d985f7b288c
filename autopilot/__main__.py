"""`python -m autopilot --sim tcp:127.0.0.1:4560|unix:PATH|shm:PATH --api udp:127.0.0.1:14540 [--params FILE] [--spin-us US]`"""

from __future__ import annotations

import argparse
import logging
import signal
import sys

from autopilot.app import Autopilot
from autopilot.params import ParamError, Params
from simlink import codec, shared_memory


def address(text: str, scheme: str) -> tuple[str, int]:
    prefix = f"{scheme}:"
    if not text.startswith(prefix):
        raise argparse.ArgumentTypeError(f"expected {scheme}:HOST:PORT, got {text!r}")
    host, _, port = text[len(prefix):].rpartition(":")
    return host.lstrip("/") or "127.0.0.1", int(port)


def sim_address(text: str) -> tuple[str, int] | str:
    """tcp:HOST:PORT, or unix:PATH (unix:@NAME: Linux's abstract namespace) for a simulator
    listening on a Unix-domain socket, or shm:PATH (shm:@NAME) for one that hands over shared
    memory on it."""
    scheme = text.partition(":")[0]
    if scheme not in ("unix", "shm"):
        return address(text, "tcp")
    if scheme == "shm" and not shared_memory.AVAILABLE:
        raise argparse.ArgumentTypeError("shm: this machine's link through shared memory needs Linux on x86-64: use unix:PATH")
    try:
        return codec.unix_socket_address(text.removeprefix(f"{scheme}:"))
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _checked_sim(text: str) -> str:
    sim_address(text)
    return text


def arguments(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m autopilot", description="The bundled PX4-like autopilot.")
    parser.add_argument("--sim", default="tcp:127.0.0.1:4560", type=_checked_sim, help="simulator to connect to (PX4's simulator protocol): tcp:HOST:PORT, or unix:PATH or unix:@NAME (a Unix-domain socket), "
                             "or shm:PATH or shm:@NAME (the same socket, the bytes through the shared memory the simulator hands over on it)")
    parser.add_argument("--api", default="udp:127.0.0.1:14540", help="where the API client (MAVSDK) listens")
    parser.add_argument("--params", help="JSON file of PX4-named parameter overrides")
    parser.add_argument("--fault", help="switch on one seeded fault (autopilot/faults.py) to test a test")
    parser.add_argument("--connect-timeout-s", type=float, default=60.0)
    parser.add_argument("--spin-us", type=float, default=0.0,
                        help="poll this long for the simulator's next message before sleeping; only worth it when the simulator runs on another core")
    parser.add_argument("-v", "--verbose", action="store_true")
    return parser.parse_args(argv)


def load_params(args: argparse.Namespace) -> Params:
    return Params.from_file(args.params, args.fault) if args.params else Params(fault=args.fault)


def main(argv: list[str] | None = None) -> int:
    args = arguments(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, stream=sys.stderr, format="autopilot %(levelname)s: %(message)s")
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    try:
        params = load_params(args)
    except (ParamError, OSError, ValueError) as error:
        print(f"{args.params or '--fault'}: {error}", file=sys.stderr)
        return 2
    try:
        return Autopilot(params).serve(sim_address(args.sim), address(args.api, "udp"), args.connect_timeout_s, args.spin_us * 1e-6,
                                        over_shared_memory=args.sim.startswith("shm:"))
    except OSError as error:
        print(f"autopilot: simulator at {args.sim} unreachable: {error}", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        return 0


if __name__ == "__main__":
    sys.exit(main())
