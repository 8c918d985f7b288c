"""`stella run`, `inspect` and `diff`: one concrete scenario flown (alone, repeated, or against a
reference SUT), and the logs flights leave read back."""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from harness.errors import InputError, Problem
from harness.tools.commands.common import command, emit, non_negative_float, non_negative_int, positive_float, positive_int, seed_int
from harness.tools.commands.sut_options import (add_reference_options, add_sut_options, check_rig, check_transport, mission_plan, reference_spec,
                                                rigged, space_of, sut_spec)
from sim_bridge.sut_link import TRANSPORTS

if TYPE_CHECKING:
    from harness.flight.results import EvaluationResult
    from sut_adapter import SutConfig


def _run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", nargs="?", help="logical scenario JSON (a concrete one is sampled with --seed)")
    p.add_argument("--concrete", help="concrete scenario JSON (from `stella sample --out`) instead of sampling")
    p.add_argument("--seed", type=seed_int, default=0, help="sampling and sensor-noise seed")
    p.add_argument("--profile", default="default")
    add_sut_options(p)
    p.add_argument("--out", default="runs", help="folder for the MCAP log (default: runs/)")
    p.add_argument("--rate-hz", type=positive_float, help="lockstep rate (default: the SUT's own, 250 Hz; ArduPilot 800 Hz)")
    p.add_argument("--cores", type=int, choices=(1, 2), default=2,
                   help="2: the simulator and the SUT get a core each and poll for each other (faster; the default); 1: they share one core")
    p.add_argument("--transport", choices=TRANSPORTS, default="auto",
                   help="memory: the bundled autopilot steps inside the simulator's process, on one core (the same flight, bit for bit); "
                        "unix: in its own process over a Unix-domain socket; shm: the same socket, the bytes through shared memory (Linux on x86-64); "
                        "tcp: in its own process over TCP (any SUT); "
                        "auto (default): memory with --cores 1, shm with --cores 2 for the bundled autopilot, tcp for other SUTs")
    p.add_argument("--fail-on-violation", action="store_true", help="exit 1 when the run (with --repeat: any repeat) violates the safety distance")
    p.add_argument("--repeat", type=positive_int, default=1,
                   help="fly the same concrete scenario N times with the same seed and report the spread of fitness and clearance and how many "
                        "repeats violated (a real SUT's timing differs run to run)")
    p.add_argument("--confirm", type=non_negative_int, default=0, help="with a reference: fly a revealing pair N more times on both sides and judge all flights")
    p.add_argument("--property", action="append", metavar="NAME|FILE",
                   help="also score this safety property (`stella properties` names them; or a JSON property file); repeatable")
    add_reference_options(p)


@command("run", "fly one concrete scenario against the SUT and score it", _run_options)
def cmd_run(args: argparse.Namespace) -> int:
    from harness.flight.evaluation import evaluate
    from harness.flight.results import RunOptions
    from harness.flight.fitness import COULD_NOT_FINISH, Status
    from harness.properties.spec import load_property
    from harness.scenario.world import load_concrete

    sut = sut_spec(args)
    if args.concrete:
        space, x = load_concrete(Path(args.concrete), args.drive, mission_plan(args))
        space = rigged(space, args)
    elif args.scenario:
        space = space_of(args)
        x = space.sample_feasible(np.random.default_rng(args.seed), 1)[0]
    else:
        raise InputError([Problem("stella run", "", "give a logical scenario to sample from, or --concrete FILE")])
    check_transport(args.transport, sut)
    reference = reference_spec(args, sut)
    check_rig(space.profile.rig, sut, reference)
    options = RunOptions(sut=sut, rate_hz=args.rate_hz, cores=args.cores, transport=args.transport,
                         properties=tuple(load_property(given) for given in args.property or []))
    if reference is not None:
        if args.repeat != 1:
            raise InputError([Problem("--repeat", "", "a differential run confirms with --confirm N (both sides), not --repeat")])
        results = [_run_pair(args, space, x, options, reference)]
    elif args.repeat == 1:
        result = evaluate(space, x, seed=args.seed, out_dir=Path(args.out), options=options)
        emit(args, result.as_dict(), _result_text(result))
        results = [result]
    else:
        results = _repeat(args, space, x, options)
    if any(r.status in COULD_NOT_FINISH for r in results):
        return 3
    return 1 if args.fail_on_violation and any(r.status == Status.VIOLATION for r in results) else 0


def _result_text(result: EvaluationResult) -> str:
    lines = [f"status: {result.status}" + (f" ({result.why})" if result.why else "")]
    lines.append(f"fitness: {result.fitness:.3f}")
    if result.min_clearance_at_s is not None:
        lines.append(f"min clearance: {result.min_clearance_m:.3f} m at t={result.min_clearance_at_s:.3f} s to {result.min_clearance_obstacle}")
    lines.append(f"simulated {result.sim_time_s:.1f} s in {result.wall_time_s:.1f} s wall" + (f" (flight at {result.real_time_factor:.1f}x real time)" if result.real_time_factor else ""))
    lines += property_lines(result.properties)
    if result.log_path:
        lines.append(f"log: {result.log_path}")
    for refused in result.failures_refused or []:
        lines.append(f"warning: the SUT refused the {refused['unit']} {refused['type']} failure at t={refused['t']:.1f} s ({refused['result']}): "
                     "it flew on without it")
    return "\n".join(lines)


def _run_pair(args: argparse.Namespace, space, x, options, reference: SutConfig) -> EvaluationResult:
    """One concrete scenario against the subject and the reference, side by side on two workers."""
    from harness.campaigns.pairs import PairedFlights, outcome_lines
    from harness.execution.executor import Job
    from harness.execution.local import LocalExecutor
    from harness.flight.evaluation import infeasible
    from harness.flight.logs import slug

    refused = infeasible(space, x, seed=args.seed, sut=options.sut.name)
    if refused is not None:
        emit(args, refused.as_dict(), _result_text(refused))
        return refused
    job = Job.of(0, space, x, seed=args.seed, out_dir=Path(args.out), name=slug(f"{space.logical.name}-seed{args.seed}"), options=options)
    executor = LocalExecutor(min(2, len(os.sched_getaffinity(0))))
    try:
        [(_job, result)] = list(PairedFlights(executor, reference, objective=args.objective, confirm=args.confirm).run([job]))
    finally:
        executor.close()
    emit(args, result.as_dict(), "\n".join([*outcome_lines(result.differential), f"objective ({args.objective}): {result.fitness:.3f}"]))
    return result


def _repeat(args: argparse.Namespace, space, x, options) -> list[EvaluationResult]:
    """The same concrete scenario flown --repeat times with the same seed: what differs is the SUT's."""
    from harness.flight import stack
    from harness.flight.evaluation import evaluate
    from harness.flight.logs import slug
    from harness.campaigns.statistics import spread

    stem = slug(f"{space.logical.name}-seed{args.seed}")
    results = []
    options = replace(options, warm=True)
    try:
        stack.start_kept(options)
        for index in range(args.repeat):
            results.append(evaluate(space, x, seed=args.seed, out_dir=Path(args.out), options=options,
                                    name=f"{stem}-repeat{index + 1}"))
            if not args.json:
                print(f"repeat {index + 1}/{args.repeat}: {results[-1].status}, fitness {results[-1].fitness:.6f}", file=sys.stderr)
    finally:
        stack.close_kept()
    report = {**spread(results), "runs": [result.as_dict() for result in results]}
    lines = [f"{report['repeats']} repeats: " + ", ".join(f"{n} {status}" for status, n in report["statuses"].items())]
    for name in ("fitness", "min_clearance_m"):
        if report[name]:
            lines.append(f"{name}: min {report[name]['min']:.6f}, median {report[name]['median']:.6f}, max {report[name]['max']:.6f}")
    lines.append(f"violations: {report['violations']} of {report['repeats']}" + (" (flaky: not every repeat violated)" if report["flaky"] else ""))
    emit(args, report, "\n".join(lines))
    return results


def _inspect_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="an evaluation's .mcap file")
    p.add_argument("--plot", help="write a PNG: top view of the trajectory and the clearance over time")
    p.add_argument("--topics", action="store_true", help="list the log's topics with schema, message count and time span instead")
    p.add_argument("--competition", action="store_true",
                   help="also score the flight as the UAV Testing Competition does (2D distance of the path to each box, soft fail < 1.5 m, points)")
    p.add_argument("--export", choices=["csv"], help="also write one CSV per topic (nested fields as dotted columns, /clearance one row per step)")
    p.add_argument("--topic", action="append", help="with --export: only this topic; repeatable (default: every topic)")
    p.add_argument("--out", help="with --export: folder for the CSV files (default: LOG-csv/ beside the log)")
    p.add_argument("--property", action="append", metavar="NAME|FILE", help="also score this property from the log alone (`stella properties` names them); repeatable")


@command("inspect", "summarize an evaluation log and recompute the fitness from it alone", _inspect_options)
def cmd_inspect(args: argparse.Namespace) -> int:
    from harness.flight.evaluation import properties_of_log
    from harness.flight.inspect_log import export_csv, plot, summarize, topics
    from harness.properties.spec import load_property

    path = Path(args.log)
    if not path.is_file():
        raise InputError([Problem(str(path), "", "no such file" if not path.exists() else "not a file: give an evaluation log (*.mcap)")])
    if args.topic and not args.export:
        raise InputError([Problem("--topic", "", "only means something with --export csv")])
    if args.topics:
        rows = topics(path)
        lines = [f"{'topic':<28} {'schema':<26} {'messages':>8} {'first (s)':>10} {'last (s)':>10}"]
        lines += [f"{r['topic']:<28} {r['schema'] or '-':<26} {r['messages']:>8} {_seconds(r['first_s']):>10} {_seconds(r['last_s']):>10}" for r in rows]
        emit(args, {"log": str(path), "topics": rows}, "\n".join(lines))
        return 0
    properties = [load_property(given) for given in args.property or []]
    summary = summarize(path)
    if properties:
        summary["properties"] = properties_of_log(path, properties)
    if args.competition:
        from harness.interop.competition_score import competition_score

        summary["competition"] = competition_score(path)
    if args.plot:
        plot(path, Path(args.plot))
        summary["plot"] = args.plot
    lines = [f"{summary['log']}: {summary['scenario']}"]
    if summary["partial"]:
        lines.append(f"log {summary['truncation_text']}; everything below is of what was recorded before it (partial)")
    else:
        lines.append(f"duration: {summary['duration_s']:.2f} s simulated, ended: {summary['end_reason']}")
    lines.append(f"status: {summary['status']}" + (f" ({summary['why']})" if summary["why"] else ""))
    if summary["min_clearance_at_s"] is not None:
        lines.append(f"min clearance: {summary['min_clearance_m']:.3f} m at t={summary['min_clearance_at_s']:.3f} s to {summary['min_clearance_obstacle']}")
    lines.append(f"fitness (recomputed from the log): {summary['fitness']:.6f}; recorded: {summary['recorded_fitness']}; reproduced: {'not checked (partial log)' if summary['partial'] else summary['fitness_reproduced']}")
    lines += property_lines(summary.get("properties", {}))
    if args.competition:
        score = summary["competition"]
        per_box = ", ".join(f"{name} {d:.3f} m" for name, d in score["distances_m"].items())
        lines.append(f"the UAV Testing Competition's score: {score['verdict']}, {score['points']} point(s); 2D distance {per_box}")
    if args.export:
        out = Path(args.out) if args.out else path.with_name(f"{path.stem}-csv")
        written = export_csv(path, out, args.topic)
        summary["exported"] = [str(p) for p in written]
        lines.append(f"exported {len(written)} CSV file(s) to {out}")
    emit(args, summary, "\n".join(lines))
    return 0


def property_lines(properties: dict) -> list[str]:
    return [f"property {name}: {scored['verdict']}, robustness "
            + ("-" if scored["robustness"] is None else f"{scored['robustness']:.3f} {scored['unit']}") for name, scored in properties.items()]


def _seconds(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


def _diff_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("a", help="first .mcap")
    p.add_argument("b", help="second .mcap")
    p.add_argument("--tolerance", type=non_negative_float, default=0.0, help="metres of difference still counted as equal (default 0: bit-identical)")


@command("diff", "compare two logs of one scenario: inputs, results, first divergence of clearance and trajectory; exit 1 if they differ", _diff_options)
def cmd_diff(args: argparse.Namespace) -> int:
    from harness.flight.inspect_log import diff

    for name in (args.a, args.b):
        if not Path(name).is_file():
            raise InputError([Problem(name, "", "no such file" if not Path(name).exists() else "not a file: give an evaluation log (*.mcap)")])
    report = diff(Path(args.a), Path(args.b), args.tolerance)
    lines = []
    for side in ("a", "b"):
        r = report[side]
        lines.append(f"{side}: {r['log']}: {r['status']}, fitness {r['fitness']:.6f}, {_seconds(r['duration_s'])} s simulated")
    lines += [f"log {side} is {text}; compared up to it" for side, text in report["truncated"].items()]
    different_inputs = [name for name, same in report["same_inputs"].items() if not same]
    lines.append("inputs: " + (f"differ in {', '.join(different_inputs)}" if different_inputs else "same concrete scenario, world and SUT"))
    lines.append(f"clearance: {report['common_steps']} common steps, largest difference {report['max_clearance_difference_m']:.6g} m"
                 + (f", {report['steps_only_in_a']} steps only in a, {report['steps_only_in_b']} only in b" if report["steps_only_in_a"] or report["steps_only_in_b"] else ""))
    if report["clearance_divergence"]:
        d = report["clearance_divergence"]
        lines.append(f"clearance first differs at t={d['t_s']:.3f} s: {d['a_m']} m vs {d['b_m']} m")
    if report["path_divergence"]:
        d = report["path_divergence"]
        lines.append(f"trajectories first differ at t={d['t_s']:.3f} s, {d['distance_m']:.6g} m apart")
    lines.append("identical" if report["identical"] else f"different (tolerance {args.tolerance} m)")
    emit(args, report, "\n".join(lines))
    return 0 if report["identical"] else 1
