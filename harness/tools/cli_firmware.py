"""`stella sut build` and `stella mutants ACTION`: firmware variants from source and mutation
analysis (harness/firmware/). Each action declares its options here, beside its handler."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any, Callable

from harness.errors import InputError, Problem
from harness.tools.cli import command, emit, non_negative_int, positive_int


def add_build_parser(actions: argparse._SubParsersAction, json_flag: Callable[[argparse.ArgumentParser], None]) -> None:
    p = actions.add_parser("build", help="build a firmware variant from a source tree (a commit, patches), cached; prints the SUT options that fly it",
                           description="Build px4_sitl_default of a PX4-Autopilot tree (or this project's bundled autopilot) at a commit with patches "
                                       "applied, in a worktree per commit, incrementally, cached by (commit, patches, build config).")
    json_flag(p)
    p.add_argument("kind", choices=["px4", "bundled"], help="what the tree is: px4 (PX4-Autopilot) or bundled (a checkout of this project)")
    p.add_argument("--source", required=True, help="the source tree (a git clone; PX4's submodules initialised)")
    p.add_argument("--commit", help="build this commit (default: the tree's HEAD)")
    p.add_argument("--patch", action="append", default=[], metavar="FILE", help="apply this unified diff first; repeatable, applied in order")
    p.add_argument("--out", required=True, help="the build cache: one folder per variant, worktrees/ for PX4's commits")
    p.add_argument("--jobs", type=positive_int, help="parallel compile jobs (default: cores)")
    worktree_option(p)


def worktree_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--worktree-command", metavar="TEMPLATE",
                   help="PX4: make a commit's worktree with this shell command ({source}, {commit}, {dir} filled in) instead of `git worktree add` "
                        "and `git submodule update` (for trees whose submodules come from local mirrors, sparse checkouts, board edits)")


def sut_build(args: argparse.Namespace) -> int:
    from harness.firmware import builds

    source = Path(args.source).expanduser()
    if source.is_dir() and builds.tree_kind(source.resolve()) != args.kind:
        raise InputError([Problem(str(source), "", f"is a {builds.tree_kind(source.resolve())} tree, not {args.kind}: give the kind it is")])
    variant = builds.build(source, out=Path(args.out), commit=args.commit, patches=[Path(p) for p in args.patch], jobs=args.jobs,
                           worktree_command=args.worktree_command)
    option = "--px4-bin" if variant.kind == "px4" else "--autopilot-dir"
    text = (f"{'cached' if variant.cached else 'built'}: {variant.folder} ({variant.build_s:.1f} s to build)\n"
            f"fly it with: {option} {variant.folder}\nbuild log: {Path(variant.folder) / builds.BUILD_LOG}")
    emit(args, {**variant.__dict__, "fly_with": {option: variant.folder}}, text)
    return 0


def add_mutants_parser(sub: argparse._SubParsersAction, json_flag: Callable[[argparse.ArgumentParser], None],
                       add_sut_params: Callable[[argparse.ArgumentParser], None]) -> None:
    parent = sub.add_parser("mutants", help="mutation analysis of one source file: generate, build, run, report",
                            description="Mutants of one C/C++ or Python file, built as cached variants, each attacked by differential "
                                        "flights against the unmutated build (docs/real_faults.md).")
    actions = parent.add_subparsers(dest="action", required=True)

    p = actions.add_parser("generate", help="write the mutants of one file as patches")
    json_flag(p)
    p.add_argument("--source", required=True, help="the source tree: PX4-Autopilot, or a checkout of this project")
    p.add_argument("--file", required=True, help="the file to mutate, relative to --source (e.g. src/lib/collision_prevention/CollisionPrevention.cpp)")
    p.add_argument("--function", help="only lines of this function's definition")
    p.add_argument("--limit", type=positive_int, help="a seeded random sample of this many of the mutants (default: all)")
    p.add_argument("--seed", type=non_negative_int, default=0, help="the sample's seed (default 0)")
    p.add_argument("--out", required=True, help="the mutation run's folder")

    p = actions.add_parser("build", help="build the original and every mutant; sort out stillborn, equivalent and duplicate ones")
    json_flag(p)
    p.add_argument("folder", help="the folder `stella mutants generate --out` wrote")
    p.add_argument("--cache", help="the build cache (default: FOLDER/builds)")
    p.add_argument("--jobs", type=positive_int, help="parallel compile jobs (default: cores)")
    p.add_argument("--only", action="append", default=[], metavar="ID", help="only this mutant (repeatable)")
    worktree_option(p)

    p = actions.add_parser("run", help="screen each mutant with a suite, then search the survivors; resumable")
    json_flag(p)
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
    p.add_argument("--objective", choices=["subject", "difference"], default="difference", help="what the searches minimise (default difference)")
    p.add_argument("--workers", type=positive_int, help="flights at once (default: cores)")
    p.add_argument("--only", action="append", default=[], metavar="ID", help="only this mutant (repeatable)")
    add_sut_params(p)

    p = actions.add_parser("report", help="mutation score per algorithm, kills by level, survivors with their diff")
    json_flag(p)
    p.add_argument("folder")
    p.add_argument("--baseline", default="RANDOM", help="the algorithm the others are tested against (default RANDOM)")
    p.add_argument("--other-tests", metavar="FILE", help="another test method's kills, {\"mutants\": {ID: {\"killed\": true|false}}} (e.g. PX4's "
                                                         "unit tests run against each mutant): the harness-only / other-only / both / neither table")
    p.add_argument("--other-name", default="unit tests", help="what to call them in the table (default: unit tests)")


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


@command("mutants")
def cmd_mutants(args: argparse.Namespace) -> int:
    from harness.firmware import mutants, mutation

    if args.action == "generate":
        index = mutants.generate(Path(args.source), args.file, Path(args.out), function=args.function, limit=args.limit, seed=args.seed)
        emit(args, index, f"{len(index['mutants'])} of {index['generated']} mutants of {index['file']} written to {Path(args.out) / 'mutants'}")
        return 0
    if args.action == "build":
        record = mutants.build_all(Path(args.folder), cache=Path(args.cache) if args.cache else None, jobs=args.jobs, only=args.only,
                                   worktree_command=args.worktree_command, progress=lambda line: print(line, file=sys.stderr))
        counts = mutants.counts(record)
        emit(args, {**record, "counts": counts}, ", ".join(f"{n} {state}" for state, n in counts.items()))
        return 0
    if args.action == "run":
        return _mutants_run(args)
    report = mutation.report(Path(args.folder), args.baseline, Path(args.other_tests) if args.other_tests else None, args.other_name)
    emit(args, report, mutation.report_text(report))
    return 0


def _mutants_run(args: argparse.Namespace) -> int:
    from harness.execution.local import LocalExecutor
    from harness.firmware import mutation
    from harness.tools.cli import _sut_param_values

    params: dict[str, Any] = {}
    if args.sut_params_file:
        from harness.interop.param_files import load_params_file

        params.update(load_params_file(Path(args.sut_params_file)))
    params.update(_sut_param_values(args.sut_param))
    plan = mutation.MutationPlan(_suite(args.suite), tuple(args.scenario), tuple(a.upper() for a in (args.algorithm or ["NSGAII", "RANDOM"])),
                                 args.evaluations, args.population, args.confirm, args.seed, args.drive, args.objective, params)
    executor = LocalExecutor(args.workers or len(os.sched_getaffinity(0)))
    try:
        document = mutation.run(Path(args.folder), plan, executor, only=args.only, progress=lambda line: print(line, file=sys.stderr))
    finally:
        executor.close()
    states = [o["state"] for o in document["mutants"].values()]
    emit(args, document, f"{len(states)} mutants analysed: " + ", ".join(f"{states.count(s)} {s}" for s in sorted(set(states)))
         + f"\n`stella mutants report {args.folder}` for the scores")
    return 0
