"""`stella mutants ACTION`: mutation analysis of one source file (harness/firmware/): mutants
generated as patches, built, attacked by differential flights, and scored. Each action declares
its own options."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any

from harness.errors import InputError, Problem
from harness.tools.commands.campaigns import add_screen_options, screen_settings
from harness.tools.commands.common import command, command_with_actions, emit, non_negative_int, positive_float, positive_int
from harness.tools.commands.sut import coverage_options, coverage_paths, worktree_option
from harness.tools.commands.sut_options import add_sut_logs_option, sut_param_values
from sut_adapter import SutConfig

command_with_actions("mutants", "mutation analysis of one source file: generate, build, run, rejudge, recheck, report",
                     description="Mutants of one C/C++ or Python file, built as cached variants, each attacked by differential "
                                 "flights against the unmutated build (docs/real_faults.md).")


def _generate_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--source", required=True, help="the source tree: PX4-Autopilot, or a checkout of this project")
    p.add_argument("--file", required=True, help="the file to mutate, relative to --source (e.g. src/lib/collision_prevention/CollisionPrevention.cpp)")
    p.add_argument("--function", help="only lines of this function's definition")
    p.add_argument("--limit", type=positive_int, help="a seeded random sample of this many of the mutants (default: all)")
    p.add_argument("--seed", type=non_negative_int, default=0, help="the sample's seed (default 0)")
    p.add_argument("--out", required=True, help="the mutation run's folder")


@command("mutants generate", "write the mutants of one file as patches", _generate_options)
def mutants_generate(args: argparse.Namespace) -> int:
    from harness.firmware import mutants

    index = mutants.generate(Path(args.source), args.file, Path(args.out), function=args.function, limit=args.limit, seed=args.seed)
    emit(args, index, f"{len(index['mutants'])} of {index['generated']} mutants of {index['file']} written to {Path(args.out) / 'mutants'}")
    return 0


def _build_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("folder", help="the folder `stella mutants generate --out` wrote")
    p.add_argument("--cache", help="the build cache (default: FOLDER/builds)")
    p.add_argument("--jobs", type=positive_int, help="parallel compile jobs (default: cores)")
    p.add_argument("--only", action="append", default=[], metavar="ID", help="only this mutant (repeatable)")
    coverage_options(p)
    worktree_option(p)


@command("mutants build", "build the original and every mutant; sort out stillborn, equivalent and duplicate ones", _build_options)
def mutants_build(args: argparse.Namespace) -> int:
    from harness.firmware import mutants

    record = mutants.build_all(Path(args.folder), cache=Path(args.cache) if args.cache else None, jobs=args.jobs, only=args.only,
                               worktree_command=args.worktree_command, progress=lambda line: print(line, file=sys.stderr),
                               coverage_paths=coverage_paths(args))
    counts = mutants.counts(record)
    emit(args, {**record, "counts": counts}, ", ".join(f"{n} {state}" for state, n in counts.items()))
    return 0


def _run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("folder", help="the folder of generated and built mutants")
    p.add_argument("--suite", action="append", required=True, metavar="CASE",
                   help="a regression case or concrete scenario every mutant is flown in (repeatable; a folder adds its *.regression.json and *.json)")
    p.add_argument("--scenario", action="append", default=[], help="a logical scenario the suite's survivors are searched in (repeatable; none: suite only)")
    p.add_argument("--algorithm", action="append", help="search algorithms (default NSGAII and RANDOM)")
    p.add_argument("--evaluations", type=positive_int, default=40, help="candidates per search (scenario x algorithm; default 40)")
    p.add_argument("--population", type=positive_int, default=10, help="population of NSGA-II and SMPSO, BO's initial set (default 10)")
    p.add_argument("--confirm", type=non_negative_int, default=0, help="fly a revealing pair N more times on both sides before it kills (PX4: 2 or more)")
    p.add_argument("--seed", type=non_negative_int, default=0)
    p.add_argument("--drive", choices=["mission", "pilot"], help="fly every case and scenario with this drive (PX4's CP acts in pilot only)")
    p.add_argument("--objective", choices=["subject", "difference", "coverage"], default="difference",
                   help="what the searches minimise (default difference; coverage: the difference less a reward for code no earlier flight reached, "
                        "with mutants built with --coverage)")
    p.add_argument("--rig", metavar="NAME|FILE", help="fly every case and search with this sensor rig (`stella rigs`, or a rig file) instead of the profile's sensor")
    add_screen_options(p)
    p.add_argument("--workers", type=positive_int, help="flights at once (default: cores)")
    p.add_argument("--only", action="append", default=[], metavar="ID", help="only this mutant (repeatable)")
    add_sut_logs_option(p)
    p.add_argument("--sut-param", action="append", metavar="NAME=VALUE", help="a SUT parameter for both sides, e.g. CP_DIST=2.0; repeatable")
    p.add_argument("--sut-params-file", metavar="FILE", help="SUT parameters from a QGroundControl .params export or a NAME,VALUE CSV")


@command("mutants run", "screen each mutant with a suite, then search the survivors; resumable", _run_options)
def mutants_run(args: argparse.Namespace) -> int:
    from harness.execution.local import LocalExecutor
    from harness.firmware import mutation

    params: dict[str, Any] = {}
    if args.sut_params_file:
        from harness.interop.param_files import load_params_file

        params.update(load_params_file(Path(args.sut_params_file)))
    params.update(sut_param_values(args.sut_param))
    plan = mutation.MutationPlan(_suite(args.suite), tuple(args.scenario), tuple(a.upper() for a in (args.algorithm or ["NSGAII", "RANDOM"])),
                                 args.evaluations, args.population, args.confirm, args.seed, args.drive, args.objective, params,
                                 sut_logs=args.sut_logs,
                                 # the cheap model: the bundled autopilot unmutated, with the parameters of both sides
                                 screen=screen_settings(args, SutConfig("bundled", params), {args.drive or "mission"},
                                                        "difference" if args.objective == "coverage" else args.objective), rig=args.rig)
    executor = LocalExecutor(args.workers or len(os.sched_getaffinity(0)))
    try:
        document = mutation.run(Path(args.folder), plan, executor, only=args.only, progress=lambda line: print(line, file=sys.stderr))
    finally:
        executor.close()
    states = [o["state"] for o in document["mutants"].values()]
    emit(args, document, f"{len(states)} mutants analysed: " + ", ".join(f"{states.count(s)} {s}" for s in sorted(set(states)))
         + f"\n`stella mutants report {args.folder}` for the scores")
    return 0


def _suite(items: list[str]) -> tuple[str, ...]:
    files: list[str] = []
    for item in items:
        path = Path(item)
        if path.is_dir():
            files += sorted(str(p) for p in path.glob("*.json"))
        elif path.is_file():
            files.append(str(path))
        else:
            raise InputError([Problem(item, "", "no such suite case: give regression cases, concrete scenarios or folders of them")])
    return tuple(files)


def _test_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("folder", help="the folder of generated and built mutants")
    p.add_argument("--tree", required=True, help="a source tree with the unmutated file, configured and built once (e.g. a PX4 worktree with "
                                                 "build/px4_sitl_test), where each mutant's patch is applied in turn and put back")
    p.add_argument("--command", required=True, help="a shell command run in the tree for each mutant: exit 0 passes (the mutant survives), "
                                                    "anything else kills it; e.g. 'make tests TESTFILTER=CollisionPrevention'")
    p.add_argument("--timeout-s", type=positive_float, default=600.0,
                   help="seconds before a hanging command counts as a kill, once and for good: well above the unmutated run's time (default 600)")
    p.add_argument("--only", action="append", default=[], metavar="ID", help="only this mutant (repeatable)")
    p.add_argument("--out", help="the results file (default FOLDER/other_tests.json); resumable")


@command("mutants test", "run another test method (e.g. PX4's unit tests) against each mutant, for the report's comparison", _test_options)
def mutants_test(args: argparse.Namespace) -> int:
    from harness.firmware import mutant_tests

    document = mutant_tests.run(Path(args.folder), tree=Path(args.tree), command=args.command, timeout_s=args.timeout_s, only=args.only,
                                out=Path(args.out) if args.out else None, progress=lambda line: print(line, file=sys.stderr))
    killed = sum(v["killed"] for v in document["mutants"].values())
    emit(args, document, f"the command killed {killed} of {len(document['mutants'])} mutants; results in {document['out']}, "
                         f"each run's output in {document['logs']}\n"
                         f"`stella mutants report {args.folder} --other-tests {document['out']}` for the table beside the flights' kills")
    return 0


def _rejudge_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("folder", help="the folder of a mutation run")


@command("mutants rejudge", "judge the searches' stored flights again with this version's rule, without flying", _rejudge_options)
def mutants_rejudge(args: argparse.Namespace) -> int:
    from harness.firmware import mutation

    result = mutation.rejudge(Path(args.folder))
    emit(args, result.as_dict(), result.text() + f"\n`stella mutants report {args.folder}` for the scores")
    return 0


def _recheck_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("folder", help="the folder of a mutation run")
    p.add_argument("--flights", type=positive_int, default=8,
                   help="fly each search's first revealing candidate until it has this many flights a side, then judge it again (default 8)")
    p.add_argument("--only", action="append", default=[], metavar="ID", help="only this mutant (repeatable)")
    p.add_argument("--workers", type=positive_int, help="flights at once (default: cores)")
    add_sut_logs_option(p)


@command("mutants recheck", "fly each search's kill again, more often, and withdraw those that were the SUT's own spread", _recheck_options)
def mutants_recheck(args: argparse.Namespace) -> int:
    from harness.execution.local import LocalExecutor
    from harness.firmware import recheck

    executor = LocalExecutor(args.workers or len(os.sched_getaffinity(0)))
    try:
        rechecked = recheck.recheck(Path(args.folder), args.flights, executor, only=args.only, sut_logs=args.sut_logs,
                                    progress=lambda line: print(line, file=sys.stderr))
    finally:
        executor.close()
    unfinished = sum(not change.finished for change in rechecked)
    withdrawn = sum(change.finished and change.after is None for change in rechecked)
    emit(args, {"rechecked": [vars(change) for change in rechecked]},
         f"{len(rechecked)} revealing candidates flown again: {withdrawn} withdrawn, {len(rechecked) - withdrawn - unfinished} stand"
         + (f", {unfinished} could not be flown (left as they were: ask again)" if unfinished else "")
         + f"\n`stella mutants report {args.folder}` for the scores")
    return 3 if unfinished else 0


def _report_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("folder")
    p.add_argument("--baseline", default="RANDOM", help="the algorithm the others are tested against (default RANDOM)")
    p.add_argument("--other-tests", metavar="FILE", help="another test method's kills, {\"mutants\": {ID: {\"killed\": true|false}}} (e.g. PX4's "
                                                         "unit tests run against each mutant): the harness-only / other-only / both / neither table")
    p.add_argument("--other-name", default="unit tests", help="what to call them in the table (default: unit tests)")


@command("mutants report", "mutation score per algorithm, kills by level, survivors with their diff", _report_options)
def mutants_report(args: argparse.Namespace) -> int:
    from harness.firmware import mutation

    report = mutation.report(Path(args.folder), args.baseline, Path(args.other_tests) if args.other_tests else None, args.other_name)
    emit(args, report, mutation.report_text(report))
    return 0
