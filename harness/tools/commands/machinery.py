"""`stella bench`, `docker` and `ui`: what campaigns run on and from: the speed benchmarks, the
Docker worker image, and the campaign page."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from harness.errors import InputError, Problem
from harness.execution import registry as executors
from harness.tools.commands.campaigns import print_run_line
from harness.tools.commands.common import command, emit, port_int, positive_float, positive_int, seed_int
from harness.scenario.rig import load_rig
from harness.tools.commands.sut_options import add_sut_options, check_rig, check_transport, mission_plan, sut_spec
from sim_bridge.sut_link import TRANSPORTS


def _bench_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runs", type=positive_int, default=5)
    p.add_argument("--scenario", help="logical scenario (default: Table III scenario 31)")
    p.add_argument("--seed", type=seed_int, default=4)
    p.add_argument("--rate-hz", type=positive_float, help="lockstep rate (default: the SUT's own, 250 Hz; ArduPilot 800 Hz)")
    p.add_argument("--no-pin", action="store_true", help="let the OS place the simulator and the SUT on any core")
    p.add_argument("--cores", type=int, choices=(1, 2), help="measure only placements with this many cores per evaluation (default: all)")
    p.add_argument("--transport", choices=TRANSPORTS[1:], help="measure only placements with this transport (default: all; memory, unix and shm: the bundled autopilot only)")
    add_sut_options(p)
    p.add_argument("--limit", action="store_true", help="also the SUT alone: the first flight's simulator link replayed to it --runs times per placement's cores, "
                                                        "and each flight's speed as a share of that (the SUT in its own process, over PX4's simulator protocol)")
    p.add_argument("--campaign", action="store_true", help="instead: an NSGA-II campaign (default Table III scenario 9) with the local executor")
    # Sequential flies in this process: it has no overhead of its own to measure.
    p.add_argument("--executor", choices=[name for name in executors.names() if name != "sequential"], help="instead: fly the standard scenario --evaluations times (default 10) through this executor")
    p.add_argument("--evaluations", type=positive_int, help="with --campaign (default 500) or --executor (default 10)")
    p.add_argument("--workers", type=positive_int, help="with --campaign (default: cores) or --executor (default 1)")
    p.add_argument("--cold-start", action="store_true", help="with --campaign: every evaluation starts its processes afresh (as `stella campaign --cold-start`)")


@command("bench", "the speed benchmark: real-time factor, evaluations per hour and where a step's time goes", _bench_options)
def cmd_bench(args: argparse.Namespace) -> int:
    from harness.tools.bench import PLACEMENTS, bench_text, run_bench
    from harness.flight.results import RunOptions

    for given, option in ((args.drive, "--drive"), (args.mission_plan, "--mission-plan"), (args.rig, "--rig")):
        if given and (args.executor or args.campaign):
            raise InputError([Problem(option, "", f"the executor and campaign benchmarks fly the standard scenario's own mission; leave {option} out")])
    if args.limit and (args.executor or args.campaign):
        raise InputError([Problem("--limit", "", "the SUT-alone replay goes with the flight benchmark; leave out --campaign and --executor")])
    if args.cold_start and not args.campaign:
        raise InputError([Problem("--cold-start", "", "only the campaign benchmark takes it (--campaign); the flight benchmark measures cold and warm starts both")])
    if args.executor:
        from harness.tools.bench import executor_bench_text, run_executor_bench

        report = run_executor_bench(args.executor, args.workers or 1, args.evaluations or 10, Path(args.scenario) if args.scenario else None)
        emit(args, report, executor_bench_text(report))
        return 0
    if args.campaign:
        from harness.tools.bench import campaign_bench_text, run_campaign_bench

        report = run_campaign_bench(args.evaluations or 500, args.workers, Path(args.scenario) if args.scenario else None,
                                    transport=args.transport or "auto", warm=not args.cold_start, on_run=print_run_line, sut=sut_spec(args))
        emit(args, report, campaign_bench_text(report))
        return 0
    sut = sut_spec(args)
    if args.transport:
        check_transport(args.transport, sut)
    if args.rig:
        check_rig(load_rig(args.rig), sut)
    placements = tuple(p for p in PLACEMENTS if args.cores in (None, p[0]) and args.transport in (None, p[1]))
    if not placements:
        measured = sorted({cores for cores, transport, _warm in PLACEMENTS if transport == args.transport})
        raise InputError([Problem("--transport", "", f"no placement has --cores {args.cores} with --transport {args.transport} "
                                                     f"(it is measured with --cores {' or '.join(map(str, measured))}): leave one of them out")])
    report = run_bench(args.runs, Path(args.scenario) if args.scenario else None, args.seed, args.rate_hz, pin_cpu=not args.no_pin,
                       sut=RunOptions(sut=sut), placements=placements,
                       drive=args.drive, mission_plan=mission_plan(args), limit=args.limit, rig=args.rig)
    emit(args, report, bench_text(report))
    return 0


def _docker_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("action", choices=["build"])
    p.add_argument("--base", help="base image (default: debian:bookworm-slim, or the one --make-base makes)")
    p.add_argument("--make-base", action="store_true", help="build on stella-base:bookworm, made first with debootstrap if missing (for machines that reach no image registry)")
    p.add_argument("--tag", default="stella-worker:latest")


@command("docker", "build the worker image for --executor docker and docker/compose.yaml", _docker_options)
def cmd_docker(args: argparse.Namespace) -> int:
    from harness.execution.docker_executor import BASE_IMAGE, build_image, image_exists, make_base

    base = args.base
    if args.make_base:
        base = BASE_IMAGE
        if not image_exists(BASE_IMAGE):
            print(f"making {BASE_IMAGE} with debootstrap", file=sys.stderr)
            make_base()
    for line in build_image(base or "debian:bookworm-slim", args.tag):
        if args.verbose:
            print(line, file=sys.stderr)
    emit(args, {"image": args.tag, "base": base}, f"built {args.tag} from {base}")
    return 0


def _ui_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--store-dir", default="runs/ui", help="where campaigns' stores, logs and uploads live (default: runs/ui)")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default loopback; any other needs the token)")
    p.add_argument("--port", type=port_int, default=8765)
    p.add_argument("--token", help="the token the page asks for (default: made up and printed when binding beyond loopback)")


@command("ui", "a web page to set up, launch, watch and browse campaigns", _ui_options)
def cmd_ui(args: argparse.Namespace) -> int:
    from harness.tools.ui.server import serve

    serve(Path(args.store_dir), args.host, args.port, args.token)
    return 0
