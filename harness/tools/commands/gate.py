"""`stella gate`: is a firmware branch less safe than its base? Both built (or given), the team's
suite and bounded differential searches flown, the verdict written for a CI job and a pull
request (harness/campaigns/gate.py, gate_report.py), exit 0 (no regression), 1 (a confirmed
regression), 2 (bad input), 3 (infrastructure)."""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from harness.errors import InputError, Problem
from harness.tools.commands.common import command, emit, non_negative_float, non_negative_int, positive_float, positive_int, seed_int
from harness.tools.commands.sut_options import checked_sut, sut_param_values
from harness.tools.commands.sut import worktree_option

DEFAULT_BUDGET_FLIGHTS = 30  # per scenario, where neither the command line nor the file gives a budget
# The bundled stack repeats itself bit for bit; a firmware's flights spread (PX4's pilot flights
# by up to 0.4 m on one wall), so a pair that differs is flown again, and a regression must hold
# over 7 flights a side (harness/campaigns/gate.py: verify).
DEFAULT_CONFIRM = {"bundled": 0, "px4": 2, "ardupilot": 2}
DEFAULT_VERIFY_FLIGHTS = {"bundled": 1, "px4": 7, "ardupilot": 7}


def _gate_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sut", choices=["px4", "ardupilot", "bundled"], help="what the firmware is (or the configuration file's `sut`)")
    builds = p.add_argument_group("the two sides", "two builds, or a source tree and two commits (PX4 and the bundled autopilot)")
    builds.add_argument("--base-build", metavar="DIR", help="the base's build: PX4's build folder or px4, ArduPilot's build/sitl or arducopter, "
                                                            "the bundled autopilot's folder")
    builds.add_argument("--head-build", metavar="DIR", help="the head's build, of the same kind")
    builds.add_argument("--source", metavar="TREE", help="the firmware tree (a git clone) to build both commits from")
    builds.add_argument("--base", metavar="COMMIT", help="the base commit (a pull request's target)")
    builds.add_argument("--head", metavar="COMMIT", help="the head commit (default: the tree's HEAD)")
    builds.add_argument("--patch", action="append", default=[], metavar="FILE", help="apply this diff to the head; repeatable")
    builds.add_argument("--jobs", type=positive_int, help="parallel compile jobs (default: cores)")
    worktree_option(builds)
    p.add_argument("--config", metavar="FILE", help="the gate's settings (default: TREE/stella.toml where it exists); the options here win")
    p.add_argument("--suite", nargs="+", metavar="CASE", help="regression cases, concrete scenarios or folders of them, flown on both sides")
    p.add_argument("--scenario", nargs="+", metavar="S", help="logical scenarios to search for where the head is worse")
    p.add_argument("--budget-flights", type=positive_int, help=f"search candidates in all, split across the scenarios (default {DEFAULT_BUDGET_FLIGHTS} each)")
    p.add_argument("--budget-minutes", type=positive_float, help="the whole gate's wall time, builds included: the searches stop at it")
    p.add_argument("--drive", choices=["mission", "pilot"], help="how every scenario is flown (default: each scenario's own)")
    p.add_argument("--sut-param", action="append", metavar="NAME=VALUE", help="a parameter of both sides (over the file's); repeatable")
    p.add_argument("--algorithm", help="the search algorithm (default NSGAII)")
    p.add_argument("--population", type=positive_int, help="its population (default 10, at most the scenario's budget)")
    p.add_argument("--confirm", type=non_negative_int, help="flights more of each side for a pair that differs (default: 2 for firmware, 0 bundled)")
    p.add_argument("--verify-flights", type=positive_int, help="flights a side a regression must hold over before it fails the gate (default: 7 for firmware, 1 bundled)")
    p.add_argument("--closer-m", type=non_negative_float, help="a head closer than the base by less than this, beyond the base's spread, passes (default 0)")
    p.add_argument("--seed", type=seed_int, help="the searches' seed (default 0)")
    p.add_argument("--max-findings", type=positive_int, help="bundles written for the worst regressions (default 5)")
    p.add_argument("--shrink-candidates", type=non_negative_int, help="candidates (pairs) the worst regression's shrink may fly (default 30; 0: no shrink)")
    p.add_argument("--fly-identical", action="store_true", default=None,
                   help="fly a head that builds to the same program as its base too (by default it passes unflown: no flight can tell them apart)")
    p.add_argument("--workers", type=positive_int, help="flights at once (default: cores)")
    p.add_argument("--cache", metavar="DIR", help="builds and the base's flights, kept between gates (default: $XDG_CACHE_HOME/stella or ~/.cache/stella)")
    p.add_argument("--out", required=True, metavar="DIR", help="summary.md, junit.xml, gate.json, findings/, and the flights")


def _cache_dir(given: str | None) -> Path:
    if given:
        return Path(given).expanduser().resolve()
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache").expanduser().resolve() / "stella"


def _settings(args: argparse.Namespace) -> dict:
    """The configuration file's settings under the command line's."""
    from harness.campaigns.gate_config import FILE_NAME, load_config, merged

    config_path = Path(args.config) if args.config else (Path(args.source) / FILE_NAME if args.source else None)
    config = load_config(config_path) if config_path is not None and (args.config or config_path.is_file()) else {}
    given = {"sut": args.sut, "suite": [str(Path(s).resolve()) for s in args.suite] if args.suite else None,
             "scenarios": [str(Path(s).resolve()) for s in args.scenario] if args.scenario else None, "drive": args.drive,
             "budget_flights": args.budget_flights, "budget_minutes": args.budget_minutes, "algorithm": args.algorithm, "population": args.population,
             "confirm": args.confirm, "verify_flights": args.verify_flights, "seed": args.seed, "closer_m": args.closer_m, "max_findings": args.max_findings, "shrink_candidates": args.shrink_candidates, "workers": args.workers,
             "fly_identical": args.fly_identical,
             "worktree_command": args.worktree_command, "cache": args.cache}
    settings = merged(config, given)
    settings["sut_params"] = {**config.get("sut_params", {}), **sut_param_values(args.sut_param)}
    if "sut" not in settings:
        raise InputError([Problem("--sut", "", "say what the firmware is: --sut px4, ardupilot or bundled (or `sut` in stella.toml)")])
    return settings


def _sides(args: argparse.Namespace, settings: dict):
    """The base and the head: built from the tree, or the builds given."""
    from harness.campaigns.gate import Side
    from harness.firmware import builds
    from sut_adapter import SutConfig

    kind = settings["sut"]
    params = dict(settings["sut_params"])
    if settings.get("sut_params_file"):
        from harness.interop.param_files import load_params_file

        params = {**load_params_file(Path(settings["sut_params_file"])), **params}
    option = builds.SUT_OPTION[kind]
    given_builds = args.base_build or args.head_build
    if given_builds and args.source:
        raise InputError([Problem("--source", "", "give either two builds (--base-build, --head-build) or a tree to build them from, not both")])
    if given_builds:
        if not (args.base_build and args.head_build):
            raise InputError([Problem("--base-build" if not args.base_build else "--head-build", "", "give both sides' builds")])
        if args.patch:
            raise InputError([Problem("--patch", "", "patches are applied when the gate builds the head from --source; apply them to --head-build yourself")])
        sides = [Side(SutConfig(kind, params, **{option: str(Path(folder).resolve())}), f"the build {Path(folder).resolve()}", str(Path(folder).resolve()))
                 for folder in (args.base_build, args.head_build)]
    else:
        if not args.source or not args.base:
            raise InputError([Problem("--source", "", "give the tree and the base commit (--source TREE --base COMMIT [--head COMMIT]), "
                                                      "or both builds (--base-build DIR --head-build DIR)")])
        found = builds.tree_kind(Path(args.source).expanduser().resolve())
        if found != kind:
            raise InputError([Problem("--source", "", f"{args.source} is a {found} tree, not {kind}: give the tree of the firmware --sut names")])
        cache = _cache_dir(settings.get("cache")) / "builds"
        sides = []
        for commit, patches in ((args.base, []), (args.head or "HEAD", [Path(p) for p in args.patch])):
            variant = builds.build(Path(args.source), out=cache, commit=commit, patches=patches, jobs=args.jobs,
                                   worktree_command=settings.get("worktree_command"))
            described = f"commit {variant.commit[:10] if variant.commit else commit}" + (f" with {len(patches)} patch{'es' * (len(patches) > 1)}" if patches else "")
            described += ", from the cache" if variant.cached else f", built in {variant.build_s:.0f} s"
            built_by = " ".join(["stella sut build", kind, "--source TREE", f"--commit {variant.commit or commit}", *(f"--patch {p}" for p in patches),
                                 "--out BUILDS"])
            sides.append(Side(SutConfig(kind, params, **{option: variant.folder}), described, variant.folder,
                              None if variant.cached else variant.build_s, variant.cached, built_by))
    base, head = sides
    for side, name in ((base, "--base-build"), (head, "--head-build")):
        checked_sut(side.sut, name, "--sut-param")
    return base, head


@command("gate", "is a firmware branch less safe than its base? Both built, the suite and bounded differential searches flown, "
                 "the verdict for CI (exit 1 on a confirmed regression)", _gate_options,
         description="Build the base and the head of a change (or take two builds), fly the team's suite on both, search the scenarios "
                     "named for where the head is worse than the base beyond the base's spread, and write summary.md, junit.xml, gate.json "
                     "and a bundle for each regression into --out. Exit 0: no regression; 1: a confirmed regression; 2: bad input; "
                     "3: infrastructure. See docs/ci.md.")
def cmd_gate(args: argparse.Namespace) -> int:
    from harness.campaigns import gate, gate_report
    from harness.execution.registry import make_executor
    from harness.firmware.programs import fingerprint

    started = time.monotonic()
    settings = _settings(args)
    kind = settings["sut"]
    scenarios = tuple(settings.get("scenarios", ()))
    budget_flights = settings.get("budget_flights")
    if budget_flights is None and settings.get("budget_minutes") is None:
        budget_flights = DEFAULT_BUDGET_FLIGHTS * len(scenarios)
    plan = gate.GatePlan(tuple(settings.get("suite", ())), scenarios, budget_flights, settings.get("budget_minutes"), settings.get("drive"),
                         settings.get("algorithm", "NSGAII").upper(), settings.get("population", 10), settings.get("confirm", DEFAULT_CONFIRM[kind]),
                         settings.get("seed", 0), settings.get("closer_m", 0.0), settings.get("max_findings", 5), settings.get("profile", "default"),
                         settings.get("shrink_candidates", 30), settings.get("verify_flights", DEFAULT_VERIFY_FLIGHTS[kind]),
                         settings.get("fly_identical", False))
    gate.check(plan)
    base, head = _sides(args, settings)
    progress = (lambda line: None) if args.json else (lambda line: print(line, file=sys.stderr))
    progress(f"base: {base.described}\nhead: {head.described}")
    executor = make_executor("local", settings.get("workers"))
    try:
        result = gate.run_gate(plan, base, head, executor, out_dir=Path(args.out), cache_dir=_cache_dir(settings.get("cache")), started=started,
                               progress=progress, one_program=not plan.fly_identical and fingerprint(base.sut) == fingerprint(head.sut))
    finally:
        executor.close()
    written = gate_report.write(result, Path(args.out))
    regressions = result.regressions
    if result.identical:
        lines = ["passed: the head builds to the same program as the base; nothing flown (--fly-identical flies it)"]
    else:
        lines = [f"{'FAILED' if regressions else 'passed'}: {len(regressions)} regression{'s' * (len(regressions) != 1)} "
                 f"({len(result.suite)} suite case{'s' * (len(result.suite) != 1)}, {len(result.searched)} search pairs, {result.wall_s / 60:.1f} min)"]
    lines += [f"  {pair.name}: {pair.judgement.kind}: {pair.judgement.why}" for pair in regressions]
    lines.append(f"wrote {written['summary']}, {written['junit']}, {written['result']}")
    emit(args, {"passed": result.passed, "regressions": len(regressions), **written}, "\n".join(lines))
    return 0 if result.passed else 1
