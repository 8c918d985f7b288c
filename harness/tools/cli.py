"""The `stella` command line. Results go to stdout (one JSON object with --json); logs to stderr.

Exit codes: 0 success, 1 a violation where the user asked to fail on one, 2 bad input or
usage, 3 infrastructure failure.
"""

from __future__ import annotations

import argparse
import errno
import json
import logging
import math
import os
import signal
import sqlite3
import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

from harness.errors import InputError, Problem, StellaError
from harness.paths import scenarios_dir
from harness.scenario.documents import load_json
from harness.scenario.logical import DRIVES, load_logical, logical_problems, with_plan_embedded
from harness.scenario.plan import plan_problems
from harness.scenario.profile import is_profile_document, load_profile, profile_problems
from harness.scenario.space import CONCRETE_FORMAT

if TYPE_CHECKING:
    from harness.campaigns.campaign import CampaignConfig
    from sut_adapter import SutConfig
from harness.scenario.world import space_from_concrete
from sim_bridge.sut_link import TRANSPORTS
from harness.search import DEFAULT_BATCH

log = logging.getLogger("stella")

Command = Callable[[argparse.Namespace], int]
COMMANDS: dict[str, Command] = {}


def command(name: str) -> Callable[[Command], Command]:
    def register(function: Command) -> Command:
        COMMANDS[name] = function
        return function

    return register


def emit(args: argparse.Namespace, result: Any, text: str) -> None:
    if getattr(args, "json", False):
        print(json.dumps(result, indent=2))
    else:
        print(text)


def _expand(paths: Sequence[str]) -> list[Path]:
    files: list[Path] = []
    for raw in paths:
        path = Path(raw)
        found = sorted([*path.glob("*.json"), *path.glob("*.plan")]) if path.is_dir() else [path]
        if not found:
            raise InputError([Problem(str(path), "", "a folder without *.json or *.plan files: give scenario, profile or plan files, or a folder of them")])
        files.extend(found)
    return files


@command("validate")
def cmd_validate(args: argparse.Namespace) -> int:
    profile = load_profile(args.profile)
    problems: list[Problem] = []
    report = []
    for path in _expand(args.paths):
        try:
            document = load_json(path)
        except InputError as error:
            problems.extend(error.problems)
            report.append({"file": str(path), "ok": False})
            continue
        if path.suffix == ".plan":
            found, kind, notes = plan_problems(document, str(path)), "QGroundControl plan", []
        elif is_profile_document(document):
            found = profile_problems(document, str(path))
            kind = "profile"
            notes: list[str] = []
            if not found:
                notes = [f"{name} not simulated" for name, p in document["parameters"].items() if not p["simulated"]]
        elif isinstance(document, dict) and document.get("format") == CONCRETE_FORMAT:
            kind, notes = "concrete scenario", []
            try:
                space = space_from_concrete(document, str(path))
                space.from_concrete(document, str(path))
                found = []
            except InputError as error:
                found = list(error.problems)
        else:
            try:
                found = logical_problems(with_plan_embedded(document, path.parent), profile, str(path))
            except InputError as error:  # its plan file
                found = list(error.problems)
            kind = "logical scenario"
            notes = []
            if not found:
                logical = load_logical(path, profile)
                notes = [f"{w.parameter} = {w.category} ({w.source}) is not simulated" for w in logical.not_simulated]
        problems.extend(found)
        report.append({"file": str(path), "kind": kind, "ok": not found, "notes": notes})
    if args.json:
        print(json.dumps({"files": report, "problems": [p.__dict__ for p in problems]}, indent=2))
    else:
        for problem in problems:
            print(problem)
        for entry in report:
            if entry["ok"]:
                notes = "; ".join(entry["notes"])
                print(f"ok: {entry['file']} ({entry['kind']})" + (f"; note: {notes}" if notes else ""))
    return 2 if problems else 0


def _space(args: argparse.Namespace):
    from harness.scenario.space import SearchSpace

    profile = load_profile(args.profile)
    return SearchSpace(load_logical(Path(args.scenario), profile, getattr(args, "drive", None), _mission_plan(args)), profile)


def _mission_plan(args: argparse.Namespace) -> Path | None:
    plan = getattr(args, "mission_plan", None)
    return Path(plan) if plan else None


@command("space")
def cmd_space(args: argparse.Namespace) -> int:
    space = _space(args)
    description = space.describe()
    lines = [f"{space.logical.name} ({space.n_dimensions} dimensions, profile {space.profile.name})"]
    lines += [f"  {d['name']:<28} {d['lower']:>10.3f} {d['upper']:>10.3f}  {d['unit']}" for d in description["dimensions"]]
    lines += [f"  fixed: {f['name']} = {f['value']} {f['unit']}" for f in description["fixed"]]
    lines += [
        f"  not simulated: {n['parameter']} = {n['category']} ({n['min']}-{n['max']} {n['unit']})"
        for n in description["not_simulated"]
    ]
    lines += [f"  constraint: {c}" for c in description["constraints"]]
    emit(args, description, "\n".join(lines))
    return 0


@command("sample")
def cmd_sample(args: argparse.Namespace) -> int:
    from harness.scenario.world import world_spec

    space = _space(args)
    x = space.sample_feasible(np.random.default_rng(args.seed), 1)[0]
    result = {"vector": x.tolist(), "concrete": space.to_concrete(x), "world": world_spec(space, x, args.seed).as_dict()}
    if args.out:
        Path(args.out).write_text(json.dumps(result["concrete"], indent=2) + "\n")
    text = json.dumps({k: v for k, v in result["concrete"].items() if k not in ("logical_scenario", "profile_document")}, indent=2)
    emit(args, result, text)
    return 0


@command("generate")
def cmd_generate(args: argparse.Namespace) -> int:
    from harness.scenario.generate import fewest_rows, generate, paper_factors

    factors = len(paper_factors())
    if not 1 <= args.strength <= factors:
        raise InputError([Problem("--strength", "", f"{args.strength} is not a strength for {factors} value sets: choose 1 to {factors} (2, pairwise, is usual)")])
    bound = fewest_rows(args.strength)
    if bound > args.max_scenarios:
        raise InputError([Problem("--strength", "", f"strength {args.strength} gives at least {bound:,} logical scenarios, more than --max-scenarios "
                                                    f"{args.max_scenarios:,}: choose a lower strength, or raise --max-scenarios")])
    print(f"strength {args.strength}: at least {bound:,} logical scenarios (the product of the {args.strength} largest value sets); "
          f"covering arrays of strength 3 and more take minutes", file=sys.stderr)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for stem, document in generate(args.strength):
        path = out / f"{stem}.json"
        path.write_text(json.dumps(document, indent=2) + "\n")
        written.append(str(path))
    emit(args, {"strength": args.strength, "count": len(written), "files": written}, f"wrote {len(written)} logical scenarios covering every {args.strength}-wise combination to {out}")
    return 0


def _result_text(result: dict[str, Any]) -> str:
    lines = [f"status: {result['status']}" + (f" ({result['why']})" if result.get("why") else "")]
    lines.append(f"fitness: {result['fitness']:.3f}")
    if result.get("min_clearance_at_s") is not None:
        lines.append(f"min clearance: {result['min_clearance_m']:.3f} m at t={result['min_clearance_at_s']:.3f} s to {result['min_clearance_obstacle']}")
    lines.append(f"simulated {result['sim_time_s']:.1f} s in {result['wall_time_s']:.1f} s wall" + (f" (flight at {result['real_time_factor']:.1f}x real time)" if result.get("real_time_factor") else ""))
    if result.get("log_path"):
        lines.append(f"log: {result['log_path']}")
    for refused in result.get("failures_refused") or []:
        lines.append(f"warning: the SUT refused the {refused['unit']} {refused['type']} failure at t={refused['t']:.1f} s ({refused['result']}): "
                     "it flew on without it")
    return "\n".join(lines)


def _sut_param_values(items: list[str] | None) -> dict[str, float]:
    """--sut-param NAME=VALUE items as numbers."""
    params: dict[str, float] = {}
    for item in items or []:
        name, _, value = item.partition("=")
        try:
            params[name] = int(value) if value.lstrip("-").isdigit() else float(value)
        except ValueError:
            raise InputError([Problem("--sut-param", "", f"{item!r} is not NAME=NUMBER (e.g. CP_DIST=2.5)")]) from None
        if not math.isfinite(params[name]):
            raise InputError([Problem("--sut-param", "", f"{item!r}: a parameter's value must be a finite number")])
    return params


def _sut_spec(args: argparse.Namespace) -> SutConfig:
    """The SUT the command line chose, checked by its adapter."""
    import sut_adapter

    if args.sut_fault is not None and args.sut != "bundled":
        raise InputError([Problem("--sut-fault", "", f"seeded faults live in the bundled autopilot, not in --sut {args.sut}")])
    from_file: dict[str, float] = {}
    if args.sut_params_file:
        from harness.interop.param_files import load_params_file

        from_file = load_params_file(Path(args.sut_params_file))
    params = {**from_file, **_sut_param_values(args.sut_param)}
    config = sut_adapter.SutConfig(args.sut, params, args.sut_fault, args.px4_bin, args.sut_command, args.sut_hold, args.autopilot_dir,
                                   getattr(args, "ardupilot_bin", None))
    return _checked_sut(config, "--sut", "--sut-param", from_file)


def _checked_sut(config: SutConfig, option: str, params_option: str, from_file: dict[str, float] | None = None) -> SutConfig:
    """The configuration, if its SUT takes it; else InputError naming the option at fault (the
    parameter file's where the file's own parameters are refused)."""
    import sut_adapter

    try:
        system = sut_adapter.system_for(config)
    except sut_adapter.SutError as error:
        raise InputError([Problem(option, "", str(error))]) from None
    try:
        system.check_params(config.params)
    except sut_adapter.SutError as error:
        raise InputError([Problem(_refused_params_option(system, params_option, from_file), "", str(error))]) from None
    return config


def _refused_params_option(system, params_option: str, from_file: dict[str, float] | None) -> str:
    """The option refused parameters came from: the parameter file where its own are refused."""
    import sut_adapter

    if not from_file:
        return params_option
    try:
        system.check_params(from_file)
    except sut_adapter.SutError:
        return "--sut-params-file"
    return params_option


def _reference_spec(args: argparse.Namespace, subject: SutConfig) -> SutConfig | None:
    """The reference SUT of a differential run: the subject's configuration with what the
    --reference-* options change (another build, another SUT, other parameters); None without them."""
    import sut_adapter

    given = {name: getattr(args, f"reference_{name}") for name in ("sut", "px4_bin", "autopilot_dir", "sut_param", "sut_fault")}
    if not any(value is not None for value in given.values()):
        if args.objective != "subject":
            raise InputError([Problem("--objective", "", "difference needs a reference SUT: add --reference-px4-bin, --reference-sut or --reference-sut-param")])
        return None
    name = given["sut"] or subject.name
    same = name == subject.name
    reference = sut_adapter.SutConfig(
        name, {**(subject.params if same else {}), **_sut_param_values(given["sut_param"])},
        given["sut_fault"], given["px4_bin"] or (subject.px4_bin if same else None),
        subject.command if same else None, subject.hold if same else None,
        given["autopilot_dir"] or (subject.autopilot_dir if same and given["sut_fault"] is None else None))
    if reference == subject:
        raise InputError([Problem("--reference-sut", "", "the reference is the subject itself: give another build (--reference-px4-bin, "
                                                         "--reference-autopilot-dir), SUT or parameters")])
    return _checked_sut(reference, "--reference-sut", "--reference-sut-param")


def _check_transport(transport: str, sut: SutConfig) -> None:
    import sut_adapter
    from harness.flight.evaluation import transport_problem

    problem = transport_problem(transport, sut_adapter.system_for(sut))
    if problem is not None:
        raise InputError([Problem("--transport", "", problem)])


@command("run")
def cmd_run(args: argparse.Namespace) -> int:
    from harness.flight.evaluation import RunOptions, evaluate
    from harness.flight.fitness import COULD_NOT_FINISH, Status
    from harness.scenario.world import load_concrete

    sut = _sut_spec(args)
    if args.concrete:
        space, x = load_concrete(Path(args.concrete), args.drive, _mission_plan(args))
    elif args.scenario:
        space = _space(args)
        x = space.sample_feasible(np.random.default_rng(args.seed), 1)[0]
    else:
        raise InputError([Problem("stella run", "", "give a logical scenario to sample from, or --concrete FILE")])
    _check_transport(args.transport, sut)
    options = RunOptions(sut=sut, rate_hz=args.rate_hz, cores=args.cores, transport=args.transport)
    reference = _reference_spec(args, sut)
    if reference is not None:
        if args.repeat != 1:
            raise InputError([Problem("--repeat", "", "a differential run confirms with --confirm N (both sides), not --repeat")])
        results = [_run_pair(args, space, x, options, reference)]
    elif args.repeat == 1:
        result = evaluate(space, x, seed=args.seed, out_dir=Path(args.out), options=options).as_dict()
        emit(args, result, _result_text(result))
        results = [result]
    else:
        results = _repeat(args, space, x, options)
    if any(r["status"] in COULD_NOT_FINISH for r in results):
        return 3
    return 1 if args.fail_on_violation and any(r["status"] == Status.VIOLATION for r in results) else 0


def _run_pair(args: argparse.Namespace, space, x, options, reference: SutConfig) -> dict[str, Any]:
    """One concrete scenario against the subject and the reference, side by side on two workers."""
    from harness.campaigns.pairs import PairedFlights, outcome_lines
    from harness.execution.executor import Job
    from harness.execution.local import LocalExecutor
    from harness.flight.evaluation import infeasible
    from harness.flight.logs import slug

    refused = infeasible(space, x, seed=args.seed, sut=options.sut.name)
    if refused is not None:
        result = refused.as_dict()
        emit(args, result, _result_text(result))
        return result
    job = Job.of(0, space, x, seed=args.seed, out_dir=Path(args.out), name=slug(f"{space.logical.name}-seed{args.seed}"), options=options)
    executor = LocalExecutor(min(2, len(os.sched_getaffinity(0))))
    try:
        [(_job, result)] = list(PairedFlights(executor, reference, objective=args.objective, confirm=args.confirm).run([job]))
    finally:
        executor.close()
    document = result.as_dict()
    emit(args, document, "\n".join([*outcome_lines(document["differential"]), f"objective ({args.objective}): {document['fitness']:.3f}"]))
    return document


def _repeat(args: argparse.Namespace, space, x, options) -> list[dict[str, Any]]:
    """The same concrete scenario flown --repeat times with the same seed: what differs is the SUT's."""
    from harness.flight import warm
    from harness.flight.evaluation import evaluate
    from harness.flight.logs import slug
    from harness.campaigns.statistics import spread

    stem = slug(f"{space.logical.name}-seed{args.seed}")
    results = []
    try:
        for index in range(args.repeat):
            results.append(evaluate(space, x, seed=args.seed, out_dir=Path(args.out), options=replace(options, warm=True),
                                    name=f"{stem}-repeat{index + 1}").as_dict())
            if not args.json:
                r = results[-1]
                print(f"repeat {index + 1}/{args.repeat}: {r['status']}, fitness {r['fitness']:.6f}", file=sys.stderr)
    finally:
        warm.close_all()
    report = {**spread(results), "runs": results}
    lines = [f"{report['repeats']} repeats: " + ", ".join(f"{n} {status}" for status, n in report["statuses"].items())]
    for name in ("fitness", "min_clearance_m"):
        if report[name]:
            lines.append(f"{name}: min {report[name]['min']:.6f}, median {report[name]['median']:.6f}, max {report[name]['max']:.6f}")
    lines.append(f"violations: {report['violations']} of {report['repeats']}" + (" (flaky: not every repeat violated)" if report["flaky"] else ""))
    emit(args, report, "\n".join(lines))
    return results


@command("inspect")
def cmd_inspect(args: argparse.Namespace) -> int:
    from harness.flight.inspect_log import export_csv, plot, summarize, topics

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
    summary = summarize(path)
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


def _seconds(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


@command("diff")
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


@command("bench")
def cmd_bench(args: argparse.Namespace) -> int:
    from harness.tools.bench import PLACEMENTS, bench_text, run_bench
    from harness.flight.evaluation import RunOptions

    for given, option in ((args.drive, "--drive"), (args.mission_plan, "--mission-plan")):
        if given and (args.executor or args.campaign):
            raise InputError([Problem(option, "", f"the executor and campaign benchmarks fly the standard scenario's own mission; leave {option} out")])
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
                                    transport=args.transport or "auto", warm=not args.cold_start)
        emit(args, report, campaign_bench_text(report))
        return 0
    sut = _sut_spec(args)
    if args.transport:
        _check_transport(args.transport, sut)
    placements = tuple(p for p in PLACEMENTS if args.cores in (None, p[0]) and args.transport in (None, p[1]))
    if not placements:
        measured = sorted({cores for cores, transport, _warm in PLACEMENTS if transport == args.transport})
        raise InputError([Problem("--transport", "", f"no placement has --cores {args.cores} with --transport {args.transport} "
                                                     f"(it is measured with --cores {' or '.join(map(str, measured))}): leave one of them out")])
    report = run_bench(args.runs, Path(args.scenario) if args.scenario else None, args.seed, args.rate_hz, pin_cpu=not args.no_pin,
                       sut=RunOptions(sut=sut), placements=placements,
                       drive=args.drive, mission_plan=_mission_plan(args))
    emit(args, report, bench_text(report))
    return 0


def campaign_config(args: argparse.Namespace) -> CampaignConfig:
    """The campaign a `stella campaign` command line asks for, every option checked before anything
    starts: what the command runs, and how the campaign page checks a campaign set up on it."""
    from harness.campaigns.campaign import CampaignConfig
    from harness.search.optimizers import parse_algorithm

    for algorithm in args.algorithm:
        try:
            parse_algorithm(algorithm)
        except ValueError as error:
            raise InputError([Problem("--algorithm", "", str(error))]) from None
    for scenario in args.scenarios:
        load_logical(Path(scenario), load_profile(args.profile), args.drive, _mission_plan(args))
    sut = _sut_spec(args)
    _check_transport(args.transport, sut)
    config = CampaignConfig(tuple(args.scenarios), tuple(a.upper() for a in args.algorithm), args.evaluations, args.runs, args.seed,
                            args.population, args.profile, args.stop_at_violation, args.wall_time_s, sut, args.drive, args.batch, args.confirm,
                            args.mission_plan, _reference_spec(args, sut), args.objective, args.stop_at_reveal)
    if args.stop_at_reveal and config.reference is None:
        raise InputError([Problem("--stop-at-reveal", "", "needs a reference SUT (--reference-px4-bin, --reference-sut or --reference-sut-param)")])
    return config


def checked_campaign(argv: Sequence[str]) -> CampaignConfig:
    """`stella campaign ARGV`'s campaign, checked as the command checks it, with InputError naming
    the option for whatever argparse refuses too (it would print usage and exit)."""
    return campaign_config(parser(RefusingParser).parse_args(["campaign", *argv]))


@command("campaign")
def cmd_campaign(args: argparse.Namespace) -> int:
    from harness.campaigns.campaign import run_campaign
    from harness.flight.evaluation import EvaluationResult, RunOptions
    from harness.execution.registry import make_executor
    from harness.campaigns.store import Store
    from tqdm import tqdm

    config = campaign_config(args)
    settings = {key: value for key, value in (("scheduler", args.dask_scheduler), ("image", args.docker_image)) if value}
    try:
        executor = make_executor(args.executor, args.workers, attempts=args.attempts, timeout_s=args.eval_timeout_s, settings=settings)
    except ValueError as error:
        raise InputError([Problem("--executor", "", str(error))]) from None
    store_path = Path(args.store)
    try:
        store = Store.for_campaign(store_path)
    except InputError:
        executor.close()
        raise
    total = len(config.scenarios) * len(config.algorithms) * config.runs * config.evaluations
    # A bar on stderr for people; nothing with --json, where a script reads stdout.
    bar = tqdm(total=total, unit="eval", file=sys.stderr, disable=args.json, dynamic_ncols=True)

    def progress(result: EvaluationResult) -> None:
        bar.update(1)
        bar.set_postfix_str(f"last {result.status} f={result.fitness:.2f}", refresh=False)

    try:
        with store:
            summary = run_campaign(config, store, executor, store_path.parent / f"{store_path.stem}-logs", on_result=progress,
                                   options=RunOptions(transport=args.transport, warm=not args.cold_start))
    finally:
        bar.close()
        executor.close()
    text = "\n".join(f"{r['scenario']} {r['algorithm']} run {r['run']}: best {r['best_fitness']:.3f}, {r['violations']} violations, "
                     + (f"{r['revealing']} revealing, " if "revealing" in r else "")
                     + f"{r['flown']} flown, {r['replayed']} from the store"
                     + (f"; warning: the SUT refused a failure injection in {r['failures_refused']} flights, which flew without it"
                        if r["failures_refused"] else "") for r in summary.runs) or "every run was already finished"
    emit(args, {"store": str(store_path), "runs": summary.runs}, text)
    return 0


@command("compare")
def cmd_compare(args: argparse.Namespace) -> int:
    from harness.campaigns.statistics import compare, table
    from harness.campaigns.store import Store

    with Store.existing(Path(args.store)) as store:
        report = compare(store, args.baseline)
    emit(args, report, table(report))
    return 0


@command("report")
def cmd_report(args: argparse.Namespace) -> int:
    from harness.campaigns.report import write_report
    from harness.campaigns.store import Store

    with Store.existing(Path(args.store)) as store:
        write_report(store, Path(args.out), args.worst, args.baseline)
    emit(args, {"report": args.out}, f"wrote {args.out}")
    return 0


@command("sut")
def cmd_sut(args: argparse.Namespace) -> int:
    from harness.flight.evaluation import RunOptions
    from harness.tools.sut_check import as_dicts, check, report_text

    if args.action == "build":
        from harness.tools.cli_firmware import sut_build

        return sut_build(args)
    sut = _sut_spec(args)
    space = _space(args)
    x = space.sample_feasible(np.random.default_rng(0), 1)[0]
    stages = check(space, x, RunOptions(sut=sut), args.timeout_s)
    emit(args, {"sut": sut.name, "stages": as_dicts(stages), "ok": all(s.ok for s in stages)}, report_text(sut.name, stages))
    return 0 if all(s.ok for s in stages) else 3


@command("faults")
def cmd_faults(args: argparse.Namespace) -> int:
    from harness.faults import checks as faults

    if args.action == "list":
        listed = faults.fault_list()
        lines = []
        for fault in listed:
            lines += [f"{fault['name']} ({fault['area']}): {fault['breaks']}",
                      f"    like: {fault['kin']}; revealed by: {fault['revealed_by']}; witness: {fault['witness'] or 'none'}"]
        emit(args, {"faults": listed}, "\n".join(lines))
        return 0
    if args.action == "bench":
        return _faults_bench(args)
    if args.action == "report":
        from harness.faults.bench import report, report_text

        if not args.store:
            raise InputError([Problem("stella faults report", "", "give --store FOLDER (the one `stella faults bench` wrote)")])
        result = report(Path(args.store), args.baseline)
        emit(args, result, report_text(result))
        return 0
    out = Path(args.out)
    if args.action == "check":
        report = faults.check(args.fault, out, args.workers, progress=lambda line: None if args.json else print(line, file=sys.stderr))
        emit(args, {"witnesses": report, "all_revealed": all(e["revealed"] for e in report)}, faults.check_text(report).splitlines()[-1])
        return 0 if all(e["revealed"] for e in report) else 1
    if not args.fault or len(args.fault) != 1 or not args.scenario or len(args.scenario) != 1:
        raise InputError([Problem("stella faults witness", "", "give one --fault NAME and one --scenario to sample witnesses from")])
    [fault] = args.fault
    concrete, tried = faults.find_witness(fault, Path(args.scenario[0]), args.tries, args.seed, out)
    if concrete is None:
        emit(args, {"fault": fault, "witness": None, "tried": tried}, f"none of {tried} samples of {args.scenario} reveals {fault}")
        return 1
    path = faults.write_witness(fault, concrete)
    emit(args, {"fault": fault, "witness": str(path), "tried": tried}, f"sample {tried} reveals {fault}: written to {path}")
    return 0


def _faults_bench(args: argparse.Namespace) -> int:
    from harness.execution.registry import make_executor
    from harness.faults.bench import report, report_text, run_bench
    from harness.search.optimizers import parse_algorithm
    import sut_adapter

    missing = [flag for flag, value in (("--fault", args.fault), ("--algorithm", args.algorithm), ("--scenario", args.scenario),
                                        ("--evaluations", args.evaluations), ("--store", args.store)) if not value]
    if missing:
        raise InputError([Problem("stella faults bench", "", f"give {', '.join(missing)}")])
    for algorithm in args.algorithm:
        try:
            parse_algorithm(algorithm)
        except ValueError as error:
            raise InputError([Problem("--algorithm", "", str(error))]) from None
    profile = load_profile("default")
    for scenario in args.scenario:
        load_logical(Path(scenario), profile)
    sut_params = _sut_param_values(args.sut_param)
    try:
        sut_adapter.system_for(sut_adapter.SutConfig(params=sut_params)).check_params(sut_params)
    except sut_adapter.SutError as error:
        raise InputError([Problem("--sut-param", "", str(error))]) from None
    try:
        executor = make_executor(args.executor, args.workers)
    except ValueError as error:
        raise InputError([Problem("--executor", "", str(error))]) from None
    try:
        run_bench(args.fault, tuple(a.upper() for a in args.algorithm), tuple(args.scenario), args.runs, args.evaluations, Path(args.store), executor,
                  seed=args.seed, population=args.population, sut_params=sut_params)
    finally:
        executor.close()
    result = report(Path(args.store), args.baseline)
    emit(args, result, report_text(result))
    return 0


@command("docker")
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


@command("ui")
def cmd_ui(args: argparse.Namespace) -> int:
    from harness.tools.ui.server import serve

    serve(Path(args.store_dir), args.host, args.port, args.token)
    return 0


@command("export-regressions")
def cmd_export_regressions(args: argparse.Namespace) -> int:
    from harness.campaigns.regression import export_regressions

    if args.format == "aerialist":
        return _export_aerialist(args)
    written = export_regressions(Path(args.store), Path(args.out), threshold=args.threshold, worst=args.worst, expect=args.expect, per_mode=args.per_mode,
                                 revealing=args.revealing)
    text = "\n".join(str(p) for p in written) + f"\nwrote {len(written)} regression case(s) to {args.out}; run them with: pytest {args.out}"
    emit(args, {"out": args.out, "files": [str(p) for p in written]}, text)
    return 0


def _export_aerialist(args: argparse.Namespace) -> int:
    from harness.interop.aerialist import export_aerialist
    from harness.campaigns.regression import chosen_cases

    sut, chosen = chosen_cases(Path(args.store), args.threshold, args.worst, args.per_mode)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    written, skipped = [], []
    for name, case in chosen:
        path, reasons = export_aerialist(name, json.loads(case["concrete"]), sut["params"], out)
        if path:
            written.append(str(path))
        else:
            skipped.append({"name": name, "reasons": reasons})
    lines = written + [f"not expressible in the competition's format: {s['name']}: {'; '.join(s['reasons'])}" for s in skipped]
    lines.append(f"wrote {len(written)} competition test(s) (YAML and .plan) to {out}; {len(skipped)} not expressible")
    emit(args, {"out": str(out), "files": written, "not_expressible": skipped}, "\n".join(lines))
    return 0


@command("triage")
def cmd_triage(args: argparse.Namespace) -> int:
    from harness.campaigns.triage import triage, triage_text

    report = triage(Path(args.store))
    emit(args, report, triage_text(report))
    return 0


@command("import")
def cmd_import(args: argparse.Namespace) -> int:
    from harness.interop.aerialist import import_aerialist

    concrete, params = import_aerialist(Path(args.test), args.safety_distance)
    out = Path(args.out)
    out.write_text(json.dumps(concrete, indent=2) + "\n")
    files = [str(out)]
    command = f"stella run --concrete {out}"
    if params:
        params_path = out.with_name(out.stem + ".params.csv")
        params_path.write_text("".join(f"{name},{value}\n" for name, value in params.items()))
        files.append(str(params_path))
        command += f" --sut-params-file {params_path}"
    boxes = len(concrete["obstacles"])
    emit(args, {"files": files, "obstacles": boxes, "sut_params": params, "fly": command},
         "\n".join(files) + f"\nimported {boxes} box(es) and the plan; fly it with: {command}  (add --sut px4 for PX4 SITL)")
    return 0


def _bounded(name: str, convert: Callable[[str], Any], accepts: Callable[[Any], bool], is_not: str) -> Callable[[str], Any]:
    """An argparse type: convert, then refuse values outside the range with `TEXT is not ...`."""
    def parse(text: str):
        value = convert(text)
        if not accepts(value):
            raise argparse.ArgumentTypeError(f"{text} is not {is_not}")
        return value
    parse.__name__ = name  # argparse names the type in "invalid NAME value"
    return parse


positive_int = _bounded("positive_int", int, lambda v: v >= 1, "a positive whole number")
non_negative_int = _bounded("non_negative_int", int, lambda v: v >= 0, "a whole number of zero or more")
seed_int = _bounded("seed_int", int, lambda v: 0 <= v < 2**32, "a seed: give a whole number from 0 to 4294967295")
port_int = _bounded("port_int", int, lambda v: 1 <= v <= 65535, "a TCP port: give 1 to 65535")
positive_float = _bounded("positive_float", float, lambda v: 0 < v < math.inf, "a positive number")
non_negative_float = _bounded("non_negative_float", float, lambda v: 0 <= v < math.inf, "a number of zero or more")


class RefusingParser(argparse.ArgumentParser):
    """An argument parser that raises InputError where argparse would print usage and exit."""

    def error(self, message: str):
        option, separator, text = message.partition(": ")
        if separator and option.startswith("argument "):
            raise InputError([Problem(option.removeprefix("argument "), "", text)])
        raise InputError([Problem(self.prog, "", message)])


def parser(kind: type[argparse.ArgumentParser] = argparse.ArgumentParser) -> argparse.ArgumentParser:
    root = kind(prog="stella", description="Scenario-based safety testing of UAV autopilots over MAVLink.")
    root.add_argument("-v", "--verbose", action="store_true", help="log progress to stderr")
    sub = root.add_subparsers(dest="command", required=True)

    def add(name: str, help_text: str) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
        return p

    p = add("validate", "check logical scenarios and profiles; each error as `file: /json/pointer: message`")
    p.add_argument("paths", nargs="+", help="JSON files or folders of them")
    p.add_argument("--profile", default="default", help="profile name or path used to check units (default: default)")

    for name, help_text in (("space", "print the derived search space"), ("sample", "sample one feasible concrete scenario and its world spec")):
        p = add(name, help_text)
        p.add_argument("scenario", help="logical scenario JSON")
        p.add_argument("--profile", default="default")
        p.add_argument("--drive", choices=DRIVES, help="override the scenario's mission.drive (pilot adds the pilot's dimensions)")
        p.add_argument("--mission-plan", metavar="PLAN", help="fly this QGroundControl .plan instead of the scenario's route (its home is the origin)")
        if name == "sample":
            p.add_argument("--seed", type=seed_int, default=0)
            p.add_argument("--out", help="also write the concrete scenario to this file")

    def add_sut(p: argparse.ArgumentParser) -> None:
        p.add_argument("--sut", default="bundled", help="bundled (default), px4, ardupilot or command")
        p.add_argument("--px4-bin", help="with --sut px4: the px4 binary or its build folder (default: $STELLA_PX4_BIN)")
        p.add_argument("--ardupilot-bin", help="with --sut ardupilot: the arducopter binary or its build folder, build/sitl (default: $STELLA_ARDUPILOT_BIN)")
        p.add_argument("--sut-command", help="with --sut command: the SUT's command line with {sim_port}, {api_port}, {instance}, {workdir}")
        p.add_argument("--sut-hold", choices=["paced", "frozen"], help="with --sut command: how the SUT waits during setup (default paced; see README)")
        p.add_argument("--sut-param", action="append", metavar="NAME=VALUE", help="a SUT parameter, e.g. CP_DIST=2.0; repeatable; wins over --sut-params-file")
        p.add_argument("--sut-fault", metavar="NAME", help="switch on one of the bundled autopilot's seeded faults (`stella faults list`)")
        p.add_argument("--autopilot-dir", metavar="DIR", help="with --sut bundled: fly the `autopilot` package in DIR instead (a mutant's folder from "
                                                              "`stella mutants build`, or a build of `stella sut build --source .`)")
        p.add_argument("--sut-params-file", metavar="FILE", help="SUT parameters from QGroundControl's .params export or a NAME,VALUE CSV (the UAV Testing Competition's)")
        p.add_argument("--mission-plan", metavar="PLAN", help="fly this QGroundControl .plan instead of the scenario's route (its home becomes the origin; "
                                                          "takeoff, waypoint, land, return, change speed, delay)")
        p.add_argument("--drive", choices=DRIVES, help="how the route is flown, overriding the scenario's mission.drive: mission (an uploaded mission) "
                                                       "or pilot (a simulated pilot in Position mode with stick input, relying on collision prevention)")

    def add_reference(p: argparse.ArgumentParser) -> None:
        group = p.add_argument_group("differential", "fly every scenario against a reference SUT too, and say where the subject (the --sut) differs")
        group.add_argument("--reference-sut", metavar="NAME", help="the reference SUT (default: the subject's, with the changes below)")
        group.add_argument("--reference-px4-bin", metavar="PATH", help="the reference's px4 binary or build folder (e.g. main's, against your branch's --px4-bin)")
        group.add_argument("--reference-autopilot-dir", metavar="DIR", help="the reference's bundled autopilot folder")
        group.add_argument("--reference-sut-param", action="append", metavar="NAME=VALUE", help="a reference parameter (over the subject's); repeatable")
        group.add_argument("--reference-sut-fault", metavar="NAME", help="a seeded fault of the reference's bundled autopilot")
        group.add_argument("--objective", choices=["subject", "difference"], default="subject",
                           help="what a campaign minimises: the subject's fitness (default), or f_subject - f_reference (where the subject is worse)")

    p = add("run", "fly one concrete scenario against the SUT and score it")
    p.add_argument("scenario", nargs="?", help="logical scenario JSON (a concrete one is sampled with --seed)")
    p.add_argument("--concrete", help="concrete scenario JSON (from `stella sample --out`) instead of sampling")
    p.add_argument("--seed", type=seed_int, default=0, help="sampling and sensor-noise seed")
    p.add_argument("--profile", default="default")
    add_sut(p)
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
    add_reference(p)

    p = add("inspect", "summarize an evaluation log and recompute the fitness from it alone")
    p.add_argument("log", help="an evaluation's .mcap file")
    p.add_argument("--plot", help="write a PNG: top view of the trajectory and the clearance over time")
    p.add_argument("--topics", action="store_true", help="list the log's topics with schema, message count and time span instead")
    p.add_argument("--competition", action="store_true",
                   help="also score the flight as the UAV Testing Competition does (2D distance of the path to each box, soft fail < 1.5 m, points)")
    p.add_argument("--export", choices=["csv"], help="also write one CSV per topic (nested fields as dotted columns, /clearance one row per step)")
    p.add_argument("--topic", action="append", help="with --export: only this topic; repeatable (default: every topic)")
    p.add_argument("--out", help="with --export: folder for the CSV files (default: LOG-csv/ beside the log)")

    p = add("diff", "compare two logs of one scenario: inputs, results, first divergence of clearance and trajectory; exit 1 if they differ")
    p.add_argument("a", help="first .mcap")
    p.add_argument("b", help="second .mcap")
    p.add_argument("--tolerance", type=non_negative_float, default=0.0, help="metres of difference still counted as equal (default 0: bit-identical)")

    p = add("bench", "the speed benchmark: real-time factor, evaluations per hour and where a step's time goes")
    p.add_argument("--runs", type=positive_int, default=5)
    p.add_argument("--scenario", help="logical scenario (default: Table III scenario 31)")
    p.add_argument("--seed", type=seed_int, default=4)
    p.add_argument("--rate-hz", type=positive_float, help="lockstep rate (default: the SUT's own, 250 Hz; ArduPilot 800 Hz)")
    p.add_argument("--no-pin", action="store_true", help="let the OS place the simulator and the SUT on any core")
    p.add_argument("--cores", type=int, choices=(1, 2), help="measure only placements with this many cores per evaluation (default: all)")
    p.add_argument("--transport", choices=TRANSPORTS[1:], help="measure only placements with this transport (default: all; memory, unix and shm: the bundled autopilot only)")
    add_sut(p)
    p.add_argument("--campaign", action="store_true", help="instead: an NSGA-II campaign (default Table III scenario 9) with the local executor")
    p.add_argument("--executor", choices=["local", "docker", "dask"], help="instead: fly the standard scenario --evaluations times (default 10) through this executor")
    p.add_argument("--evaluations", type=positive_int, help="with --campaign (default 500) or --executor (default 10)")
    p.add_argument("--workers", type=positive_int, help="with --campaign (default: cores) or --executor (default 1)")
    p.add_argument("--cold-start", action="store_true", help="with --campaign: every evaluation starts its processes afresh (as `stella campaign --cold-start`)")

    p = add("campaign", "search logical scenarios for worst cases; resumable from its store")
    p.add_argument("scenarios", nargs="+", help="logical scenario JSON files")
    p.add_argument("--algorithm", action="append", required=True, help="NSGAII, SMPSO, BO, RANDOM or a combination of N P B R such as NPB; repeatable")
    p.add_argument("--evaluations", type=positive_int, required=True, help="budget per run (split evenly over a combination's steps)")
    p.add_argument("--runs", type=positive_int, default=1)
    p.add_argument("--seed", type=seed_int, default=0, help="run r uses seed + r")
    p.add_argument("--population", type=positive_int, default=50, help="population, swarm size and BO initial set")
    p.add_argument("--confirm", type=non_negative_int, default=0,
                   help="fly each violation N more times with the same seed and store how often it came back; one that did not every "
                        "time is marked flaky in report and export-regressions")
    p.add_argument("--batch", type=positive_int, default=DEFAULT_BATCH,
                   help=f"candidates BO and RANDOM ask for at once (default {DEFAULT_BATCH}); part of the campaign, so a seed flies the same "
                        "candidates on every executor; raise it to the number of workers on a big machine")
    p.add_argument("--profile", default="default")
    add_sut(p)
    p.add_argument("--executor", choices=["sequential", "local", "dask", "docker"], default="local",
                   help="local: worker processes here (default); dask: a Dask cluster; docker: one container per evaluation")
    p.add_argument("--workers", type=positive_int, help="parallel evaluations (default: cores; with --dask-scheduler the cluster's threads)")
    p.add_argument("--transport", choices=TRANSPORTS, default="auto",
                   help="memory: the bundled autopilot steps inside the simulator's process (the same flights); unix: in its own process over a "
                        "Unix-domain socket; shm: the same socket, the bytes through shared memory (Linux on x86-64); tcp: in its own process over TCP; "
                        "auto (default): memory where an evaluation gets one core (as many workers as cores), shm where it gets two, for the bundled "
                        "autopilot; tcp for other SUTs")
    p.add_argument("--cold-start", action="store_true",
                   help="start the simulator and the SUT afresh for every evaluation; by default a worker flying in memory keeps them for its next "
                        "evaluation (a fresh world and autopilot in the same process: the same flights, about a fifth of a second less each)")
    p.add_argument("--attempts", type=positive_int, default=2, help="tries per evaluation that ends sut_crashed, sim_crashed or timeout, or loses its worker (default 2)")
    p.add_argument("--eval-timeout-s", type=positive_float, default=600.0, help="hard wall-clock limit of one try (default 600)")
    p.add_argument("--dask-scheduler", help="with --executor dask: a scheduler address such as tcp://10.0.0.5:8786 (default: start a local cluster)")
    p.add_argument("--docker-image", help="with --executor docker: the worker image (default: stella-worker:latest)")
    p.add_argument("--store", required=True, help="SQLite campaign store; re-run the same command to resume")
    p.add_argument("--stop-at-violation", action="store_true", help="end each run at its first violation")
    p.add_argument("--stop-at-reveal", action="store_true", help="with a reference: end each run at its first (confirmed) revealing candidate")
    add_reference(p)
    p.add_argument("--wall-time-s", type=positive_float, help="end each run after this much wall time")

    p = add("compare", "the algorithm comparison table (median best fitness, relative performance, p-value, A12)")
    p.add_argument("store")
    p.add_argument("--baseline", default="NSGAII")

    p = add("report", "a self-contained HTML report: convergence, comparison, violations, worst cases")
    p.add_argument("store")
    p.add_argument("--out", required=True)
    p.add_argument("--worst", type=int, default=5)
    p.add_argument("--baseline", default="NSGAII")

    from harness.tools import cli_firmware

    def json_flag(p: argparse.ArgumentParser) -> None:
        p.add_argument("--json", action="store_true", help="print one JSON object on stdout")

    def sut_params(p: argparse.ArgumentParser) -> None:
        p.add_argument("--sut-param", action="append", metavar="NAME=VALUE", help="a SUT parameter for both sides, e.g. CP_DIST=2.0; repeatable")
        p.add_argument("--sut-params-file", metavar="FILE", help="SUT parameters from a QGroundControl .params export or a NAME,VALUE CSV")

    help_text = "check that a SUT comes up against the simulator (check), or build one from source (build)"
    actions = sub.add_parser("sut", help=help_text, description=help_text).add_subparsers(dest="action", required=True)
    p = actions.add_parser("check", help="start a SUT with the simulator and report each stage with its time")
    json_flag(p)
    add_sut(p)
    p.add_argument("--scenario", default=str(scenarios_dir() / "examples" / "fig4.json"),
                   help="logical scenario whose world the check starts (default: Fig. 4)")
    p.add_argument("--profile", default="default")
    p.add_argument("--timeout-s", type=positive_float, default=60.0, help="per stage")
    cli_firmware.add_build_parser(actions, json_flag)
    cli_firmware.add_mutants_parser(sub, json_flag, sut_params)

    p = add("faults", "the bundled autopilot's seeded faults: list them, fly each witness with and without its fault, find a witness")
    p.add_argument("action", choices=["list", "check", "witness", "bench", "report"])
    p.add_argument("--fault", action="append", metavar="NAME", help="with check: only these (repeatable; default all); with witness: the fault; "
                                                                    "with bench: the faults to campaign against (none: the fault-free control)")
    p.add_argument("--scenario", action="append", help="with witness: the logical scenario to sample candidates from; with bench: repeatable")
    p.add_argument("--algorithm", action="append", help="with bench: as for campaign; repeatable")
    p.add_argument("--runs", type=positive_int, default=3, help="with bench: runs per fault, algorithm and scenario (default 3)")
    p.add_argument("--evaluations", type=positive_int, help="with bench: budget per run")
    p.add_argument("--population", type=positive_int, default=50, help="with bench: as for campaign")
    p.add_argument("--store", help="with bench and report: the benchmark's folder (one campaign store per fault and the fault-free re-flights)")
    p.add_argument("--executor", choices=["sequential", "local", "dask", "docker"], default="local", help="with bench: as for campaign")
    p.add_argument("--baseline", default="RANDOM", help="with bench and report: the algorithm the others are tested against (default RANDOM)")
    p.add_argument("--tries", type=positive_int, default=20, help="with witness: samples to try (default 20)")
    p.add_argument("--seed", type=seed_int, default=0, help="with witness: the sampling seed; with bench: run r uses seed + r")
    p.add_argument("--out", default="runs/faults", help="folder for the flights' logs (default runs/faults)")
    p.add_argument("--workers", type=positive_int, help="with check and bench: flights at once (default: cores)")
    p.add_argument("--sut-param", action="append", metavar="NAME=VALUE",
                   help="with bench: an autopilot parameter for the faulty and the fault-free flights alike, e.g. CP_DIST=1.5; repeatable")

    p = add("docker", "build the worker image for --executor docker and docker/compose.yaml")
    p.add_argument("action", choices=["build"])
    p.add_argument("--base", help="base image (default: debian:bookworm-slim, or the one --make-base makes)")
    p.add_argument("--make-base", action="store_true", help="build on stella-base:bookworm, made first with debootstrap if missing (for machines that reach no image registry)")
    p.add_argument("--tag", default="stella-worker:latest")

    p = add("ui", "a web page to set up, launch, watch and browse campaigns")
    p.add_argument("--store-dir", default="runs/ui", help="where campaigns' stores, logs and uploads live (default: runs/ui)")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default loopback; any other needs the token)")
    p.add_argument("--port", type=port_int, default=8765)
    p.add_argument("--token", help="the token the page asks for (default: made up and printed when binding beyond loopback)")

    p = add("export-regressions", "write each violation (or chosen worst case) of a campaign as a regression case that pytest flies")
    p.add_argument("store", help="SQLite campaign store")
    p.add_argument("--out", required=True, help="folder for the NAME.regression.json files")
    p.add_argument("--threshold", type=float, default=0.0, help="export evaluations with fitness below this (default 0: the violations)")
    p.add_argument("--worst", type=int, default=0, help="also export the N lowest-fitness evaluations of each run")
    p.add_argument("--expect", choices=["safe", "violation"], default="safe",
                   help="safe: the test fails until the SUT keeps the safety distance (default); violation: it fails once the known violation stops reproducing")

    p.add_argument("--per-mode", action="store_true", help="only the worst violation of each failure mode (`stella triage`) instead of every one")
    p.add_argument("--revealing", action="store_true",
                   help="instead: each revealing scenario of a differential campaign, as a case that fails unless the SUT does as well as the "
                        "reference did (run it with --stella-px4-bin or --stella-autopilot-dir of either build)")
    p.add_argument("--format", choices=["stella", "aerialist"], default="stella",
                   help="stella: regression cases for pytest (default); aerialist: the UAV Testing Competition's YAML and .plan (static boxes only)")

    p = add("triage", "group a campaign's violations into failure modes by what happened (obstacle, phase, approach, speed, environment)")
    p.add_argument("store", help="SQLite campaign store")

    p = add("import", "turn a UAV Testing Competition test (Aerialist YAML) into a concrete scenario")
    p.add_argument("kind", choices=["aerialist"])
    p.add_argument("test", help="the test's YAML (its mission_file and params_file are found beside it or in the working directory)")
    p.add_argument("--out", required=True, help="the concrete scenario JSON to write (its SUT parameters go beside it as NAME.params.csv)")
    p.add_argument("--safety-distance", type=non_negative_float, default=1.5, help="metres (default 1.5: the competition's soft-fail distance)")

    p = add("generate", "write logical scenarios covering every T-wise combination of the paper's value sets")
    p.add_argument("--strength", type=int, default=2)
    p.add_argument("--max-scenarios", type=positive_int, default=10_000, help="refuse a strength that gives more logical scenarios than this (default 10,000)")
    p.add_argument("--out", required=True)
    return root


def main(argv: Sequence[str] | None = None) -> int:
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        # Started in the background of a script (which ignores SIGINT for its & jobs), or by such a
        # process: Ctrl-C is still how a campaign stops with nothing lost, and how the campaign
        # page's Cancel stops one.
        signal.signal(signal.SIGINT, signal.default_int_handler)
    args = parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, stream=sys.stderr, format="%(levelname)s %(name)s: %(message)s")
    try:
        return COMMANDS[args.command](args)
    except InputError as error:
        print(str(error), file=sys.stderr)
        return error.exit_code
    except StellaError as error:
        print(f"error: {error}", file=sys.stderr)
        return error.exit_code
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away (`stella faults list | head`): stop quietly, as other tools do;
        # stdout is pointed at /dev/null so that closing it at exit raises nothing more.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except sqlite3.OperationalError as error:
        if "full" not in str(error):
            raise
        # SQLite rolled the transaction back: the store holds every evaluation finished before.
        print(f"{getattr(args, 'store', 'the campaign store')}: {error}: make room and run the same command again to resume", file=sys.stderr)
        return 2
    except OSError as error:
        if error.filename is None and error.errno != errno.ENOSPC:
            raise
        # An output that cannot be written (no such folder, no permission, a full disk): the
        # user's to mend, so one line naming the path rather than a traceback.
        resume = "; the store keeps every finished evaluation: run the same command again to resume" if args.command == "campaign" else ""
        print(f"{error.filename or 'writing the campaign store or logs'}: {error.strerror}: give a path in a writable folder with room{resume}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
