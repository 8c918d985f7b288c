"""`stella sut check` and `stella sut build`: a SUT brought up stage by stage against the
simulator, and a firmware variant built from source (harness/firmware/builds.py)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from harness.errors import InputError, Problem
from harness.paths import scenarios_dir
from harness.tools.commands.common import command, command_with_actions, emit, positive_float, positive_int
from harness.tools.commands.sut_options import add_sut_options, check_rig, space_of, sut_spec

command_with_actions("sut", "check that a SUT comes up against the simulator (check), or build one from source (build)")


def _check_options(p: argparse.ArgumentParser) -> None:
    add_sut_options(p)
    p.add_argument("--scenario", default=str(scenarios_dir() / "examples" / "fig4.json"),
                   help="logical scenario whose world the check starts (default: Fig. 4)")
    p.add_argument("--profile", default="default")
    p.add_argument("--timeout-s", type=positive_float, default=60.0, help="per stage")


@command("sut check", "start a SUT with the simulator and report each stage with its time", _check_options)
def sut_check(args: argparse.Namespace) -> int:
    from harness.flight.results import RunOptions
    from harness.tools.sut_check import as_dicts, check, report_text

    sut = sut_spec(args)
    space = space_of(args)
    check_rig(space.profile.rig, sut)
    x = space.sample_feasible(np.random.default_rng(0), 1)[0]
    stages = check(space, x, RunOptions(sut=sut), args.timeout_s)
    emit(args, {"sut": sut.name, "stages": as_dicts(stages), "ok": all(s.ok for s in stages)}, report_text(sut.name, stages))
    return 0 if all(s.ok for s in stages) else 3


def worktree_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--worktree-command", metavar="TEMPLATE",
                   help="PX4, ArduPilot: make a commit's worktree with this shell command ({source}, {commit}, {dir} filled in) instead of `git worktree add` "
                        "and `git submodule update` (for trees whose submodules come from local mirrors, sparse checkouts, board edits)")


def _build_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("kind", choices=["px4", "ardupilot", "bundled"],
                   help="what the tree is: px4 (PX4-Autopilot), ardupilot (ArduPilot: ArduCopter SITL) or bundled (a checkout of this project)")
    p.add_argument("--source", required=True, help="the source tree (a git clone; its submodules initialised)")
    p.add_argument("--commit", help="build this commit (default: the tree's HEAD)")
    p.add_argument("--patch", action="append", default=[], metavar="FILE", help="apply this unified diff first; repeatable, applied in order")
    p.add_argument("--out", required=True, help="the build cache: one folder per variant, worktrees/ for PX4's and ArduPilot's commits")
    p.add_argument("--jobs", type=positive_int, help="parallel compile jobs (default: cores)")
    coverage_options(p)
    worktree_option(p)


def coverage_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--coverage", action="store_true",
                   help="coverage builds: their flights record the lines and branches of --coverage-path that ran (`stella coverage`, --objective coverage)")
    p.add_argument("--coverage-path", action="append", default=[], metavar="PATH",
                   help="a file or folder of the tree to measure; repeatable (default: the collision prevention, "
                        "src/lib/collision_prevention, libraries/AC_Avoidance and libraries/AP_Proximity, or autopilot/collision.py)")


def coverage_paths(args: argparse.Namespace) -> list[str] | None:
    """The paths a coverage build measures ([]: the default ones), None for no coverage build."""
    if args.coverage_path and not args.coverage:
        raise InputError([Problem("--coverage-path", "", "says what a coverage build measures: add --coverage")])
    return args.coverage_path if args.coverage else None


@command("sut build", "build a firmware variant from a source tree (a commit, patches), cached; prints the SUT options that fly it", _build_options,
         description="Build px4_sitl_default of a PX4-Autopilot tree, ArduCopter SITL of an ArduPilot tree (or this project's bundled "
                     "autopilot) at a commit with patches "
                     "applied, in a worktree per commit, incrementally, cached by (commit, patches, build config).")
def sut_build(args: argparse.Namespace) -> int:
    from harness.firmware import builds

    source = Path(args.source).expanduser()
    if source.is_dir() and builds.tree_kind(source.resolve()) != args.kind:
        raise InputError([Problem(str(source), "", f"is a {builds.tree_kind(source.resolve())} tree, not {args.kind}: give the kind it is")])
    variant = builds.build(source, out=Path(args.out), commit=args.commit, patches=[Path(p) for p in args.patch], jobs=args.jobs,
                           worktree_command=args.worktree_command, coverage_paths=coverage_paths(args))
    option = "--" + next(iter(variant.sut_options())).replace("_", "-")
    text = (f"{'cached' if variant.cached else 'built'}: {variant.folder} ({variant.build_s:.1f} s to build)\n"
            f"fly it with: {option} {variant.folder}\nbuild log: {Path(variant.folder) / builds.BUILD_LOG}")
    emit(args, {**variant.__dict__, "fly_with": {option: variant.folder}}, text)
    return 0
