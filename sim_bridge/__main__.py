"""`python -m sim_bridge --world WORLD.json --sim-port 4560 --control-port P --mcap OUT.mcap`

Listens for the SUT on the simulator port, runs the lockstep simulation, records to MCAP and
prints the run's summary as one JSON line on stdout. Exit code 0 when the run ended normally
(landed, time limit, stopped), 3 when the SUT never connected, stalled or disconnected, or when
SIGTERM came as the recording was being finished (held until the file was complete).
`--serve` instead flies world after world, each named on the control channel
(sim_bridge/control.py has the protocol): with a SUT inside the process (`python -m
sut_adapter.inline`) a fresh one for each, else whichever SUT connects next to the simulator
port (the harness starts one for each flight), so that a campaign pays this process's start
and imports once per worker rather than once per evaluation.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import signal
import socket
import sys
import time
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Callable, Iterator

from sim_bridge import ardupilot_link
from sim_bridge.bridge import Bridge
from sim_bridge.bridge_io import BridgeConfig
from sim_bridge.channel import ControlChannel
from sim_bridge.recording import COMPANION_TOPIC, COMPRESSIONS, RIG_TOPIC, Recorder
from sim_bridge.rig import DISTANCE_SENSOR_CONVENTIONS
from sim_bridge.control import EXIT_CUT_SHORT, EndReason, Finished, Load, Loaded, LoadRefused, Quit, Rejected
from sim_bridge.frames import RANGE_MESSAGES
from sim_bridge.spec import WorldSpec
from sim_bridge.sut_link import SocketLink, SutLink
from simlink import codec, shared_memory


def listen(port: int, host: str = "127.0.0.1") -> socket.socket:
    listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    listener.bind((host, port))
    listener.listen(1)
    return listener


def listen_unix(name: str) -> socket.socket:
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        listener.bind(codec.unix_socket_address(name))
        listener.listen(1)
    except OSError:
        listener.close()
        raise
    return listener


def _connect_sut(listener: socket.socket | None, args, inline_sut: Callable[[], SutLink] | None, control: ControlChannel) -> SutLink:
    """The SUT's link once it connected; socket.timeout when it did not within the connect
    timeout or the harness stopped the wait."""
    if inline_sut is not None:
        return inline_sut()
    if args.sim_protocol == "ardupilot-json":
        return ardupilot_link.accept(listener, args.connect_timeout_s, args.stall_timeout_s, control.wait_readable)
    if not control.wait_readable(listener, args.connect_timeout_s):
        raise socket.timeout(f"no SUT connected within {args.connect_timeout_s:.0f} s, or the harness stopped waiting for it")
    sock, _ = listener.accept()
    if args.sim_shared_memory:
        try:
            return shared_memory.offer(sock, args.stall_timeout_s)
        except OSError:
            sock.close()
            raise
    return SocketLink(sock, args.stall_timeout_s)


class _Stop:
    """The harness's SIGTERM: raised as KeyboardInterrupt where it lands, except while a flight's
    recording is being finished, when it waits until the file is complete. Landing inside the
    MCAP writer's finish cut the file's end off: the harness closing a warm stack after a failed
    set-up, as the simulator was ending the flight by itself, lost that flight's log."""

    held = False
    pending = False


def _interrupt(signum, frame) -> None:
    if _Stop.held:
        _Stop.pending = True
        return
    raise KeyboardInterrupt


@contextmanager
def _stop_held() -> Iterator[None]:
    """SIGTERM held for the block, then raised at its end if one came."""
    _Stop.held = True
    try:
        yield
    finally:
        _Stop.held = False
        if _Stop.pending:
            _Stop.pending = False
            raise KeyboardInterrupt


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text} is not a finite number")
    return value


def _positive(text: str) -> float:
    value = _number(text)
    if value <= 0.0:
        raise argparse.ArgumentTypeError(f"{text} is not a positive number")
    return value


def _non_negative(text: str) -> float:
    value = _number(text)
    if value < 0.0:
        raise argparse.ArgumentTypeError(f"{text} is negative")
    return value


def _port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port number") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"{text} is not a port: give 0 to 65535")
    return value


def _range_messages(text: str) -> tuple[str, ...]:
    names = tuple(name for name in text.split(",") if name)
    unknown = sorted(set(names) - set(RANGE_MESSAGES))
    if unknown:
        raise argparse.ArgumentTypeError(f"unknown {', '.join(unknown)}; choose from {', '.join(RANGE_MESSAGES)}")
    return names


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m sim_bridge", description=__doc__.splitlines()[0])
    parser.add_argument("--world", help="world spec JSON (stella sample --json prints one)")
    parser.add_argument("--sim-port", type=_port, default=4560)
    parser.add_argument("--sim-socket", help="listen for the SUT on this Unix-domain socket (a path, or @NAME in the abstract namespace) instead of the simulator port")
    parser.add_argument("--sim-shared-memory", action="store_true",
                        help="with --sim-socket: hand the SUT shared memory on it and exchange the link's bytes there (simlink/shared_memory.py; "
                             "the bundled autopilot's --sim shm:PATH)")
    parser.add_argument("--sim-protocol", choices=ardupilot_link.PROTOCOLS, default="mavlink",
                        help="mavlink: PX4's HIL messages, the SUT connects over TCP (default); ardupilot-json: ArduPilot's JSON physics backend, "
                             "its servo frames arrive over UDP on the simulator port (ArduPilot's --sim-port-out)")
    parser.add_argument("--rc-port", type=_port, help="with --sim-protocol ardupilot-json and the pilot drive: send the pilot's sticks to this UDP port "
                                                    "(ArduPilot SITL's --rc-in-port)")
    parser.add_argument("--companion-port", type=_port, help="send the rig's --companion-messages to this UDP port, a companion computer's "
                                                            "MAVLink link to the SUT (PX4's onboard link), instead of the simulator link")
    parser.add_argument("--companion-messages", default="", type=_range_messages, help="comma-separated: which of a rig's messages go to --companion-port")
    parser.add_argument("--companion-connects", action="store_true",
                        help="the SUT sends to --companion-port from a port of its own (ArduPilot SITL's udpclient:): listen there and answer it")
    parser.add_argument("--distance-sensor-convention", choices=sorted(DISTANCE_SENSOR_CONVENTIONS), default="px4",
                        help="how a rig's DISTANCE_SENSOR is written: px4, its direction a custom rotation's quaternion, nothing within reach "
                             "read as the maximum; ardupilot, one of MAV_SENSOR_ROTATION's eight yaws, nothing read beyond the maximum")
    parser.add_argument("--control-port", type=_port, default=0, help="harness control channel; 0 = none")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--mcap", help="where to record the flight")
    parser.add_argument("--mcap-compression", choices=sorted(COMPRESSIONS), default="zstd",
                        help="the recording's chunk compression: none for a log read once and rewritten, as the harness does (default zstd)")
    parser.add_argument("--serve", action="store_true", help="fly world after world, each named on the control channel, each with the SUT that connects next")
    parser.add_argument("--harness-pid", type=int, help="with --serve: quit when this process, the harness that started us, is gone (default: our parent)")
    parser.add_argument("--rate-hz", type=float, default=250.0)
    parser.add_argument("--hold-after-s", type=float, default=3.0, help="pause after this much simulation until the harness sends run; 0 = never")
    parser.add_argument("--hold-mode", choices=["frozen", "paced"], default="frozen",
                        help="frozen: simulated time stops during the hold; paced: it runs on at --hold-pace (for SUTs such as PX4 that follow the lockstep clock)")
    parser.add_argument("--hold-pace", type=_positive, default=1.0,
                        help="a paced hold's speed in simulated seconds per wall-clock second (default 1: real time)")
    parser.add_argument("--range-messages", default=",".join(RANGE_MESSAGES), type=_range_messages,
                        help="comma-separated: OBSTACLE_DISTANCE (72 sectors, read by the bundled autopilot), DISTANCE_SENSOR (six wedges, read by PX4)")
    parser.add_argument("--connect-timeout-s", type=float, default=60.0)
    parser.add_argument("--stall-timeout-s", type=float, default=10.0)
    parser.add_argument("--linger-s", type=_non_negative, default=0.0,
                        help="after the flight, keep the SUT's simulator link open until the SUT hangs up, at most this long "
                             "(the harness stops the SUT first: PX4 spins on a closed simulator link)")
    parser.add_argument("--spin-us", type=float, default=0.0,
                        help="poll this long for the SUT's answer before sleeping; only worth it when the SUT runs on another core")
    parser.add_argument("--lockstep-from-start", action="store_true",
                        help="the SUT answers every HIL_SENSOR from the first: wait for each answer from step 0, not at real-time pace until its first")
    parser.add_argument("--answer-times-echoed", action="store_true",
                        help="the SUT's HIL_ACTUATOR_CONTROLS carry the time_usec of the HIL_SENSOR they answer: a late answer is not taken for a later step's")
    parser.add_argument("-v", "--verbose", action="store_true")
    return parser


def _check(parser: argparse.ArgumentParser, args: argparse.Namespace, inline_sut: Callable[[], SutLink] | None) -> None:
    """Refuse, through the parser (exit 2), options that cannot go together."""
    if args.serve and not args.control_port:
        parser.error("--serve needs a --control-port: the worlds to fly are named on it")
    if args.serve and args.sim_protocol != "mavlink":
        # A datagram of the last flight's SUT still queued on the port would be taken for the next one's.
        parser.error("--serve takes its SUTs over a connection: ArduPilot's JSON link (UDP) is served one flight per process")
    if not args.serve and (args.world is None or args.mcap is None):
        parser.error("--world and --mcap are required (unless --serve)")
    if args.sim_socket is not None:
        try:
            codec.unix_socket_address(args.sim_socket)
        except ValueError as error:
            parser.error(f"--sim-socket: {error}")
    if args.sim_shared_memory and (args.sim_socket is None or inline_sut is not None):
        parser.error("--sim-shared-memory needs a --sim-socket to hand the shared memory over on (and a SUT in a process of its own)")
    if args.sim_protocol != "mavlink" and (args.lockstep_from_start or args.answer_times_echoed):
        parser.error("--lockstep-from-start and --answer-times-echoed are about HIL_ACTUATOR_CONTROLS: ArduPilot's JSON link is in lockstep from its first frame")
    if args.sim_protocol != "mavlink" and (args.sim_socket is not None or inline_sut is not None):
        parser.error("--sim-protocol ardupilot-json takes its SUT over UDP on --sim-port: no --sim-socket, no SUT inside this process")
    if args.sim_shared_memory and not shared_memory.AVAILABLE:
        parser.error("--sim-shared-memory: the link through shared memory needs Linux on x86-64; leave it out to use the Unix-domain socket alone")


def _listen_for_sut(args: argparse.Namespace) -> socket.socket:
    """Where the SUT reaches the simulator: a Unix-domain socket, ArduPilot's UDP port, or TCP."""
    if args.sim_socket is not None:
        return listen_unix(args.sim_socket)
    if args.sim_protocol == "ardupilot-json":
        return ardupilot_link.listen_udp(args.sim_port, args.host)
    return listen(args.sim_port, args.host)


def main(argv: list[str] | None = None, inline_sut: Callable[[], SutLink] | None = None) -> int:
    """inline_sut: a SUT in this process (sut_adapter/inline.py): its link instead of the simulator port."""
    parser = _parser()
    args = parser.parse_args(argv)
    _check(parser, args, inline_sut)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, stream=sys.stderr, format="bridge %(levelname)s: %(message)s")
    # The harness stops us with SIGTERM; unwinding finishes the MCAP file.
    signal.signal(signal.SIGTERM, _interrupt)
    config = BridgeConfig(rate_hz=args.rate_hz, hold_after_s=args.hold_after_s, hold_mode=args.hold_mode, hold_pace=args.hold_pace,
                          stall_timeout_s=args.stall_timeout_s,
                          range_messages=args.range_messages, spin_s=args.spin_us * 1e-6, protocol=args.sim_protocol,
                          rc_port=args.rc_port, companion_port=args.companion_port, companion_messages=args.companion_messages,
                          companion_connects=args.companion_connects, distance_sensor_convention=args.distance_sensor_convention,
                          lockstep_from_start=args.lockstep_from_start, answer_times_echoed=args.answer_times_echoed)
    control_listener = listen(args.control_port, args.host) if args.control_port else None
    if not args.serve:
        try:
            world = load_world(args.world)
        except (OSError, ValueError) as error:  # SpecError and JSONDecodeError are ValueErrors
            print(f"{args.world}: {error}", file=sys.stderr)
            return 2
        try:
            Path(args.mcap).open("wb").close()  # before any SUT connects: fly() writes it from the start
        except OSError as error:
            print(f"--mcap {args.mcap}: cannot write the recording there: {error}", file=sys.stderr)
            return 2
    try:
        sim_listener = None if inline_sut is not None else _listen_for_sut(args)
    except OSError as error:
        where = f"--sim-socket {args.sim_socket}" if args.sim_socket is not None else f"--sim-port {args.sim_port}"
        print(f"{where}: cannot listen: {error}", file=sys.stderr)
        return 2
    # A SUT inside this process goes when we do: there is no link to keep open for it.
    linger_s = 0.0 if inline_sut is not None else args.linger_s

    def connect_sut(control: ControlChannel) -> Callable[[], SutLink]:
        return lambda: _connect_sut(sim_listener, args, inline_sut, control)

    try:
        if args.serve:
            return _serve(control_listener, config, connect_sut, args.harness_pid or os.getppid(), args.mcap_compression, linger_s)
        control = ControlChannel(control_listener)
        try:
            summary = fly(world, config, Path(args.mcap), control, connect_sut(control), args.mcap_compression, linger_s)
        except KeyboardInterrupt:  # stopped as its recording was being finished: the file is complete, the harness gone
            return EXIT_CUT_SHORT
        finally:
            control.close()
    finally:
        if sim_listener is not None:
            sim_listener.close()
            if args.sim_socket is not None and not args.sim_socket.startswith("@"):
                os.unlink(args.sim_socket)  # a path's socket file outlives its listener
    print(json.dumps(summary), flush=True)
    return 0 if summary["end_reason"].normal else EXIT_CUT_SHORT


def load_world(path: str) -> WorldSpec:
    document = json.loads(Path(path).read_text())
    if "world" in document:  # accept `stella sample --json` output as it is
        document = document["world"]
    return WorldSpec.from_dict(document)


def fly(world: WorldSpec, config: BridgeConfig, mcap_path: Path, control: ControlChannel, connect_sut: Callable[[], SutLink],
        compression: str, linger_s: float = 0.0) -> dict:
    """One flight from start to its finished MCAP file; its summary, which the harness gets as the
    "finished" event once the file is complete."""
    optional_topics = ("/pilot",) if world.drive == "pilot" else ()
    if world.atmosphere.varies:
        optional_topics += ("/wind",)
    optional_topics += tuple(f"{RIG_TOPIC}{sensor.name}" for sensor in world.rig or ())
    if config.companion_port is not None and any(sensor.message in config.companion_messages for sensor in world.rig or ()):
        optional_topics += (COMPANION_TOPIC,)
    sut = None
    try:
        with ExitStack() as finishing, open(mcap_path, "wb") as stream, Recorder(stream, optional_topics, compression) as recorder:
            recorder.metadata("world", {"json": json.dumps(world.as_dict())})
            recorder.metadata("bridge", {"rate_hz": str(config.rate_hz), "pid": str(os.getpid())})
            control.send(Loaded())
            bridge = Bridge(world, config, recorder)
            finishing.callback(bridge.close)
            try:
                sut = connect_sut()
            except socket.timeout:
                bridge.summary.end_reason = EndReason.SUT_NEVER_CONNECTED
            except OSError:  # it connected and went at once (the shared memory's hand-over failed)
                bridge.summary.end_reason = EndReason.SUT_DISCONNECTED
            except KeyboardInterrupt:
                bridge.summary.end_reason = EndReason.INTERRUPTED
            if sut is not None:
                try:
                    bridge.run(sut, control)
                except KeyboardInterrupt:
                    bridge.settle_outcome()
                    bridge.summary.end_reason = EndReason.INTERRUPTED
            finishing.enter_context(_stop_held())
            summary = bridge.summary.as_dict()
            recorder.metadata("bridge_summary", {"json": json.dumps(summary)})
        control.send(Finished(summary))
        if sut is not None and summary["end_reason"] is not EndReason.INTERRUPTED and getattr(sut, "can_hang_up", True):
            _wait_for_hang_up(sut, linger_s)
    finally:
        if sut is not None:
            sut.close()
    return summary


def _wait_for_hang_up(sut: SutLink, linger_s: float) -> None:
    """Keep the simulator link open after the flight until the SUT hangs up, at most linger_s
    (or until we are stopped; not at all when we were). The harness stops the SUT before us, and a SUT should go while
    its simulator is still there: PX4 busy-waits on a closed simulator link, its real-time
    threads starving its own shutdown for most of a second."""
    deadline = time.monotonic() + linger_s
    try:
        while (remaining := deadline - time.monotonic()) > 0:
            if sut.readable(min(remaining, 1.0)):
                sut.idle()  # what the SUT still says goes unread; its hang-up raises
    except (OSError, KeyboardInterrupt):
        pass


def _serve(listener: socket.socket, config: BridgeConfig, connect_sut: Callable[[ControlChannel], Callable[[], SutLink]], harness_pid: int,
           compression: str, linger_s: float) -> int:
    """Flight after flight in this one process (the harness's warm workers): each harness
    connection on the control port names a world and an MCAP file ({"op": "load", "world": PATH,
    "mcap": PATH}) and gets a fresh world for them, flown with a fresh SUT (one inside this
    process, or the next to connect to the simulator port); {"op": "quit"}, the
    harness's SIGTERM or its death ends it. A flight that did not end normally ends it too, with exit code 3,
    so that nothing of it can leak into the next."""
    try:
        while True:
            control = ControlChannel(listener, own_listener=False)
            try:
                request = _next_request(control, harness_pid)
                if request is None:
                    return 0
                if isinstance(request, Rejected) or not isinstance(request.world, str) or not isinstance(request.mcap, str):
                    control.send(LoadRefused(f"a load request names a world and an mcap file: got {request}"))
                    continue
                try:
                    world = load_world(request.world)
                except (OSError, ValueError) as error:
                    control.send(LoadRefused(f"{request.world}: {error}"))
                    continue
                # The harness reports a crash with the end of our stderr: say where each flight's part begins.
                print(f"flying {request.world}", file=sys.stderr, flush=True)
                summary = fly(world, config, Path(request.mcap), control, connect_sut(control), compression, linger_s)
                if not summary["end_reason"].normal:
                    return EXIT_CUT_SHORT
            finally:
                control.close()
    except KeyboardInterrupt:
        return 0
    finally:
        listener.close()


def _next_request(control: ControlChannel, harness_pid: int) -> Load | Rejected | None:
    """The next harness's load request (Rejected: one it could not read); None when it asks us to
    quit or is gone (no longer our parent). Its death normally signals us (die_with_parent), but
    a server left waiting forever would hold its port block, so we look for ourselves too."""
    while os.getppid() == harness_pid:
        for op in control.poll(1.0):
            if isinstance(op, Quit):
                return None
            if isinstance(op, Load) or isinstance(op, Rejected) and op.name == Load.NAME:
                return op
    return None


if __name__ == "__main__":
    sys.exit(main())
