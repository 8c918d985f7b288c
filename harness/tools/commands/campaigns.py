"""`stella campaign`, `compare`, `report`, `triage` and `export-regressions`: a search campaign,
and what is read from its store afterwards."""

from __future__ import annotations

import argparse
import json
import logging
import subprocess
import sys
from collections import Counter
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

from harness.errors import InfrastructureError, InputError, Problem
from harness.execution import registry as executors
from harness.campaigns.screen import CORRECTIONS, SCREENS
from harness.flight.fitness import COULD_NOT_FINISH, Status
from harness.scenario.logical import load_logical
from harness.scenario.profile import load_profile
from harness.search import DEFAULT_BATCH
from harness.tools.commands.common import RefusingParser, add_options, command, emit, non_negative_int, positive_float, positive_int, seed_int, share
from harness.tools.commands.sut_options import (add_reference_options, add_sut_logs_option, add_sut_options, check_coverage_build, check_rig,
                                                check_transport, mission_plan, reference_spec, sut_spec)
from sim_bridge.sut_link import TRANSPORTS

if TYPE_CHECKING:
    from harness.campaigns.campaign import CampaignConfig, RunSummary
    from harness.campaigns.screen import ScreenSettings
    from harness.flight.results import EvaluationResult
    from sut_adapter import SutConfig

log = logging.getLogger(__name__)


def _campaign_options(p: argparse.ArgumentParser) -> None:
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
    add_sut_options(p)
    p.add_argument("--executor", choices=executors.names(), default="local",
                   help="local: worker processes here (default); dask: a Dask cluster; docker: one container per evaluation")
    p.add_argument("--workers", type=positive_int, help="parallel evaluations (default: cores; with --dask-scheduler the cluster's threads)")
    p.add_argument("--transport", choices=TRANSPORTS, default="auto",
                   help="memory: the bundled autopilot steps inside the simulator's process (the same flights); unix: in its own process over a "
                        "Unix-domain socket; shm: the same socket, the bytes through shared memory (Linux on x86-64); tcp: in its own process over TCP; "
                        "auto (default): memory where an evaluation gets one core (as many workers as cores), shm where it gets two, for the bundled "
                        "autopilot; tcp for other SUTs")
    p.add_argument("--cold-start", action="store_true",
                   help="start the simulator afresh for every evaluation; by default a worker keeps it for its next evaluation, which it "
                        "flies with a fresh world and a fresh SUT (the same flights, without the simulator's start: 0.3-0.4 s of CPU less each)")
    add_sut_logs_option(p)
    p.add_argument("--attempts", type=positive_int, default=2, help="tries per evaluation that ends sut_crashed, sim_crashed or timeout, or loses its worker (default 2)")
    p.add_argument("--eval-timeout-s", type=positive_float, default=600.0, help="hard wall-clock limit of one try (default 600)")
    p.add_argument("--dask-scheduler", help="with --executor dask: a scheduler address such as tcp://10.0.0.5:8786 (default: start a local cluster)")
    p.add_argument("--docker-image", help="with --executor docker: the worker image (default: stella-worker:latest)")
    p.add_argument("--store", required=True, help="SQLite campaign store; re-run the same command to resume")
    p.add_argument("--stop-at-violation", action="store_true", help="end each run at its first violation")
    p.add_argument("--stop-at-reveal", action="store_true", help="with a reference: end each run at its first (confirmed) revealing candidate")
    p.add_argument("--property", action="append", metavar="NAME|FILE",
                   help="score this safety property on every flight and search for the least robustness among those given instead of f "
                        "(`stella properties` names them; or a JSON property file); repeatable")
    add_reference_options(p, campaign=True)
    add_screen_options(p)
    p.add_argument("--screen-learn-from", action="append", metavar="STORE",
                   help="with --screen and its correction: learn also from the candidates flown both ways in this earlier screened campaign's store "
                        "(the same SUT build, parameters, drive and profile; pairs of the same scenarios), copied into --store when the campaign "
                        "begins; repeatable")
    p.add_argument("--wall-time-s", type=positive_float, help="end each run after this much wall time")



def add_screen_options(p: argparse.ArgumentParser) -> None:
    """Screening (harness/campaigns/screen.py), for campaigns and mutants' searches alike."""
    p.add_argument("--screen", choices=SCREENS, default="none",
                   help="fly each batch on the bundled autopilot configured like the SUT first, and the SUT only where those flights rank it worth it "
                        "(--evaluations then counts the SUT's flights); default none")
    p.add_argument("--screen-share", type=share, default=0.3, help="with --screen: the share of each batch flown for real as the most promising (default 0.3)")
    p.add_argument("--screen-explore", type=share, default=0.1,
                   help="with --screen: the chance that each of the others is flown for real all the same, so the screen's blind spots are sampled (default 0.1)")
    p.add_argument("--screen-correction", choices=CORRECTIONS, default="gp",
                   help="with --screen: gp trains a Gaussian process on the candidates flown both ways (this run's and the store's earlier runs' "
                        "of the scenario) to correct the cheap model; none ranks by the cheap flights alone (default gp)")


def screen_settings(args: argparse.Namespace, sut: SutConfig, drives: set[str], objective: str) -> ScreenSettings | None:
    """What --screen and its options ask for, checked; None without a screen."""
    from harness.campaigns.screen import ScreenSettings, screen_sut

    if args.screen == "none":
        return None
    if objective == "difference" and args.screen_correction == "none":
        raise InputError([Problem("--screen-correction", "", "none ranks by the cheap flights' clearance, which is not the difference of two SUTs "
                                                              "that --objective difference searches: use the correction (gp)")])
    if sut.name in ("px4", "ardupilot") and len(drives) > 1:
        raise InputError([Problem("--screen", "", f"configures the cheap model by drive, as {sut.name}'s collision avoidance acts on the pilot's sticks "
                                                  "and not in missions: give --drive, or screen the scenarios of each drive in a campaign of their own")])
    if sut.params and sut.name not in ("px4", "bundled", "ardupilot"):
        log.warning("--screen: the cheap model flies with the bundled autopilot's defaults; %s's parameters are not mapped onto it", sut.name)
    return ScreenSettings(screen_sut(sut, next(iter(drives), "mission")), args.screen_share, args.screen_explore, correction=args.screen_correction)


def campaign_config(args: argparse.Namespace) -> CampaignConfig:
    """The campaign a `stella campaign` command line asks for, every option checked before anything
    starts: what the command runs, and how the campaign page checks a campaign set up on it."""
    from harness.campaigns.campaign import CampaignConfig
    from harness.properties.spec import load_property
    from harness.search.optimizers import parse_algorithm

    for algorithm in args.algorithm:
        try:
            parse_algorithm(algorithm)
        except ValueError as error:
            raise InputError([Problem("--algorithm", "", str(error))]) from None
    drives = {load_logical(Path(scenario), load_profile(args.profile), args.drive, mission_plan(args)).drive for scenario in args.scenarios}
    sut = sut_spec(args)
    check_transport(args.transport, sut)
    config = CampaignConfig(tuple(args.scenarios), tuple(a.upper() for a in args.algorithm), args.evaluations, args.runs, args.seed,
                            args.population, args.profile, args.stop_at_violation, args.wall_time_s, sut, args.drive, args.batch, args.confirm,
                            args.mission_plan, reference_spec(args, sut), args.objective, args.stop_at_reveal,
                            tuple(load_property(given) for given in args.property or []))
    if config.properties and config.objective not in ("subject", "properties"):
        raise InputError([Problem("--property", "", "searches the properties' robustness: leave out --objective, or use --objective properties "
                                                    "(a differential campaign then compares the properties of both sides too)")])
    if config.objective == "properties" and len(config.properties) < 2:
        raise InputError([Problem("--objective", "", "properties makes each --property an objective of its own: name two or more properties")])
    if config.objective == "coverage":
        check_coverage_build(sut)
    config = replace(config, screen=screen_settings(args, sut, drives, config.objective), rig=args.rig, learn_from=tuple(args.screen_learn_from or ()))
    if config.learn_from and (config.screen is None or config.screen.correction == "none"):
        raise InputError([Problem("--screen-learn-from", "", "teaches the screen's learned correction: give --screen bundled (with --screen-correction gp)")])
    documents = config.read()
    for logical in documents.scenarios:
        check_rig(logical.rig or documents.profile.rig, sut, config.reference)
    if args.stop_at_reveal and config.reference is None:
        raise InputError([Problem("--stop-at-reveal", "", "needs a reference SUT (--reference-px4-bin, --reference-sut or --reference-sut-param)")])
    return config


def print_run_line(run: RunSummary) -> None:
    """Each finished run on stderr, as a campaign goes (the campaign page shows them in its console)."""
    from harness.campaigns.campaign import run_line

    print(run_line(run), file=sys.stderr)


def checked_campaign(argv: Sequence[str]) -> CampaignConfig:
    """`stella campaign ARGV`'s campaign, checked as the command checks it, with InputError naming
    the option for whatever argparse refuses too (it would print usage and exit)."""
    parser = RefusingParser(prog="stella campaign")
    add_options(parser, _campaign_options)
    return campaign_config(parser.parse_args(argv))


class UnflownFlights:
    """Counts the flights that failed before anything was recorded (a SUT that would not start, a
    worker without the build): a campaign in which every flight did has tested nothing, and
    ends with exit 3 saying why rather than with a best fitness."""

    def __init__(self) -> None:
        self.tries = 0
        self.causes: Counter[str] = Counter()

    def hear(self, result: EvaluationResult) -> None:
        if result.status == Status.INFEASIBLE:
            return
        self.tries += 1
        if result.log_path is None and result.status in COULD_NOT_FINISH:
            self.causes[result.why or str(result.status)] += 1

    def check(self) -> None:
        if self.tries and sum(self.causes.values()) == self.tries:
            cause, count = self.causes.most_common(1)[0]
            raise InfrastructureError(f"none of the {self.tries} flights this campaign made now flew, they tested nothing; "
                                      + (f"each failed so: {cause}" if count == self.tries else f"{count} failed so: {cause}"))


@command("campaign", "search logical scenarios for worst cases; resumable from its store", _campaign_options)
def cmd_campaign(args: argparse.Namespace) -> int:
    from harness.campaigns.campaign import run_campaign, screen_line
    from harness.flight.results import EvaluationResult, RunOptions
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

    unflown = UnflownFlights()

    def progress(result: EvaluationResult) -> None:
        bar.update(1)
        bar.set_postfix_str(f"last {result.status} f={result.fitness:.2f}", refresh=False)
        unflown.hear(result)

    try:
        with store:
            summary = run_campaign(config, store, executor, store_path.parent / f"{store_path.stem}-logs", on_result=progress,
                                   on_run=print_run_line, options=RunOptions(transport=args.transport, warm=not args.cold_start,
                                                                                         sut_logs=args.sut_logs))
    finally:
        bar.close()
        executor.close()
    unflown.check()
    text = "\n".join(f"{r.scenario} {r.algorithm} run {r.run}: "
                     + (f"least robustness {r.best_fitness:.3f}, {r.property_violations} violating a property, "
                        if r.property_violations is not None else f"best {r.best_fitness:.3f}, ")
                     + f"{r.violations} violations, "
                     + (f"{r.revealing} revealing, " if r.revealing is not None else "")
                     + f"{r.flown} flown, {r.replayed} from the store"
                     + (f"; {screen_line(r.screen)}" if r.screen else "")
                     + (f"; warning: the SUT refused a failure injection in {r.failures_refused} flights, which flew without it"
                        if r.failures_refused else "") for r in summary.runs) or "every run was already finished"
    emit(args, {"store": str(store_path), "runs": [r.as_dict() for r in summary.runs]}, text)
    return 0


def _compare_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("store")
    p.add_argument("--baseline", default="NSGAII")


@command("compare", "the algorithm comparison table (median best fitness, relative performance, p-value, A12)", _compare_options)
def cmd_compare(args: argparse.Namespace) -> int:
    from harness.campaigns.statistics import compare, table
    from harness.campaigns.store import Store

    with Store.existing(Path(args.store)) as store:
        report = compare(store, args.baseline)
    emit(args, report, table(report))
    return 0


def _report_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("store")
    p.add_argument("--out", required=True)
    p.add_argument("--worst", type=int, default=5)
    p.add_argument("--baseline", default="NSGAII")


@command("report", "a self-contained HTML report: convergence, comparison, violations, worst cases", _report_options)
def cmd_report(args: argparse.Namespace) -> int:
    from harness.campaigns.report import write_report
    from harness.campaigns.store import Store

    with Store.existing(Path(args.store)) as store:
        write_report(store, Path(args.out), args.worst, args.baseline)
    emit(args, {"report": args.out}, f"wrote {args.out}")
    return 0


def _coverage_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("stores", nargs="+", metavar="DB", help="campaign stores (a suite's, a search's, a mutation run's) flown with a coverage build")
    p.add_argument("--source", metavar="FILE", help="only this source file (its path, or the end of it: CollisionPrevention.cpp)")
    p.add_argument("--html", metavar="DIR", help="also write gcovr's HTML report there: each line with how many flights ran it")
    p.add_argument("--sources", metavar="TREE", help="with --html: the source tree to show (default: the one the flights' coverage build kept)")
    p.add_argument("--suite", metavar="DIR", help="write a suite of regression cases there: the fewest flights (greedy set cover) that reach "
                                                   "every branch and line the flights reached")


@command("coverage", "lines and branches of the firmware that a coverage build's flights reached, merged over campaigns", _coverage_options)
def cmd_coverage(args: argparse.Namespace) -> int:
    from harness.campaigns.coverage import merged, stored_flights, table, uncovered_text

    flights = stored_flights([Path(s) for s in args.stores])
    files = merged(flights, args.source)
    if not files:
        raise InputError([Problem(args.stores[0], "", "no flight of these stores recorded coverage" + (f" of {args.source}" if args.source else "")
                                  + ": fly a coverage build (`stella sut build KIND --coverage`)")])
    text = table(files) + "\n" + uncovered_text(files)
    summary: dict = {"files": [f.as_dict() for f in files]}
    if args.html:
        summary["html"] = str(_coverage_html(args, flights, files))
        text += f"\nHTML report: {summary['html']}"
    if args.suite:
        summary["suite"], summary["suite_misses"] = _coverage_suite(flights, files, args.source, Path(args.suite))
        text += "\n" + "\n".join(f"{case['case']}: +{case['branches_added']} branches, +{case['lines_added']} lines" for case in summary["suite"])
        text += (f"\nwrote {len(summary['suite'])} regression case(s) to {args.suite}: pytest {args.suite}, or "
                 f"`stella mutants run --suite {args.suite}`; it reaches all the flights reached but {summary['suite_misses']['branches']} branches "
                 f"and {summary['suite_misses']['lines']} lines, which only flights that could not finish reached")
    emit(args, summary, text)
    return 0


def _coverage_suite(flights, files, source: str | None, out: Path) -> tuple[list[dict], dict[str, int]]:
    """The fewest flights, among those the SUT flew to an end, that reach what they reached
    (coverage.covering_suite), written as regression cases that expect what each flight did: to
    keep the safety distance and finish (`safe`), to keep it short of the goal (`kept`: blocked
    by collision prevention, say) or to violate again. A flight the SUT or the simulator could
    not finish has no such expectation and is left out; what only such flights reached is
    counted as missed."""
    from harness.campaigns.coverage import covering_suite, merged
    from harness.campaigns.regression import SUFFIX, case_document, case_name
    from harness.campaigns.store import Store
    from harness.flight.fitness import Status

    expectation_of = {Status.OK: "safe", Status.MISSION_FAILED: "kept", Status.VIOLATION: "violation"}
    cases, suts = {}, {}
    for store_path in sorted({flight.store for flight, _record in flights}):
        with Store.existing(Path(store_path)) as store:
            suts[store_path] = store.campaign_sut()
            cases.update({(store_path, e.id): e for e in store.all_evaluations() if e.coverage and e.status in expectation_of})
    expected = [(flight, record) for flight, record in flights if (flight.store, flight.evaluation) in cases]
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for chosen in covering_suite(expected, source):
        case = cases[(chosen.flight.store, chosen.flight.evaluation)]
        name = f"{Path(chosen.flight.store).stem}-{case_name(case)}"  # the stores' cases may share names
        expect = expectation_of[case.status]
        (out / f"{name}{SUFFIX}").write_text(json.dumps(case_document(name, case, suts[chosen.flight.store], Path(chosen.flight.store), expect),
                                                        indent=2) + "\n")
        written.append({"case": name, **chosen.as_dict()})
    reached = merged(expected, source)
    misses = {"branches": sum(len(f.first_branch) for f in files) - sum(len(f.first_branch) for f in reached),
              "lines": sum(len(f.first_line) for f in files) - sum(len(f.first_line) for f in reached)}
    return written, misses


def _coverage_html(args: argparse.Namespace, flights, files) -> Path:
    from harness.campaigns.coverage import sources_of, write_html

    if args.sources:
        sources, where = Path(args.sources), "--sources"
    else:
        trees = sources_of(flights)
        if len(trees) != 1:
            why = (f"the flights' coverage builds kept several source trees ({', '.join(trees)})" if trees
                   else "the flights' records name no source tree (flown before coverage builds kept one)")
            raise InputError([Problem("--sources", "", f"{why}: give the tree to show with --sources")])
        sources, where = Path(trees[0]), args.stores[0]
    missing = [f.path for f in files if not (sources / f.path).is_file()]
    if missing:
        raise InputError([Problem(where, "", f"{sources} has no {missing[0]}: give the source tree the flights' build was made of with --sources")])
    return write_html(files, sources, Path(args.html))


def _rejudge_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("store", nargs="+", help="a differential campaign's store (flown with --reference-...)")


@command("rejudge", "judge a differential campaign's stored pairs again with this version's rule, without flying", _rejudge_options)
def cmd_rejudge(args: argparse.Namespace) -> int:
    from harness.campaigns.rejudge import rejudge_campaigns

    result = rejudge_campaigns([Path(path) for path in args.store])
    emit(args, result.as_dict(), result.text())
    return 0


def _triage_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("store", help="SQLite campaign store")


@command("triage", "group a campaign's violations into failure modes by what happened (obstacle, phase, approach, speed, environment)", _triage_options)
def cmd_triage(args: argparse.Namespace) -> int:
    from harness.campaigns.triage import triage, triage_text

    report = triage(Path(args.store))
    emit(args, report.as_dict(), triage_text(report))
    return 0


def _export_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("store", help="SQLite campaign store")
    p.add_argument("--out", required=True, help="folder for the NAME.regression.json files")
    p.add_argument("--threshold", type=float, default=0.0, help="export evaluations with fitness below this (default 0: the violations)")
    p.add_argument("--worst", type=int, default=0, help="also export the N lowest-fitness evaluations of each run")
    p.add_argument("--expect", choices=["safe", "kept", "violation"], default="safe",
                   help="safe: the test fails until the SUT keeps the safety distance and completes the mission (default); kept: until it keeps "
                        "the safety distance, finished or not; violation: it fails once the known violation stops reproducing")
    p.add_argument("--per-mode", action="store_true", help="only the worst violation of each failure mode (`stella triage`) instead of every one")
    p.add_argument("--revealing", action="store_true",
                   help="instead: each revealing scenario of a differential campaign, as a case that fails unless the SUT does as well as the "
                        "reference did (run it with --stella-px4-bin or --stella-autopilot-dir of either build)")
    p.add_argument("--format", choices=["stella", "aerialist"], default="stella",
                   help="stella: regression cases for pytest (default); aerialist: the UAV Testing Competition's YAML and .plan (static boxes only)")
    p.add_argument("--property", action="append", metavar="NAME|FILE",
                   help="the cases judge this safety property (in place of the campaign's; `stella properties` names them, or a JSON property file); "
                        "repeatable")


@command("export-regressions", "write each violation (or chosen worst case) of a campaign as a regression case that pytest flies", _export_options)
def cmd_export_regressions(args: argparse.Namespace) -> int:
    from harness.campaigns.regression import export_regressions
    from harness.properties.spec import load_property

    properties = [load_property(given) for given in args.property or []]
    if args.format == "aerialist":
        if properties:
            raise InputError([Problem("--property", "", "the competition's format has no properties: leave --property out with --format aerialist")])
        return _export_aerialist(args)
    written = export_regressions(Path(args.store), Path(args.out), threshold=args.threshold, worst=args.worst, expect=args.expect, per_mode=args.per_mode,
                                 revealing=args.revealing, properties=[prop.as_dict() for prop in properties] or None)
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
        path, reasons = export_aerialist(name, case.concrete, sut["params"], out)
        if path:
            written.append(str(path))
        else:
            skipped.append({"name": name, "reasons": reasons})
    lines = written + [f"not expressible in the competition's format: {s['name']}: {'; '.join(s['reasons'])}" for s in skipped]
    lines.append(f"wrote {len(written)} competition test(s) (YAML and .plan) to {out}; {len(skipped)} not expressible")
    emit(args, {"out": str(out), "files": written, "not_expressible": skipped}, "\n".join(lines))
    return 0


def _findings_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("store", help="SQLite campaign store")
    p.add_argument("--out", required=True, help="folder for one bundle per failure mode and FINDINGS.md")
    p.add_argument("--shrink", action="store_true", help="also shrink each mode's case into its bundle's shrunk/ (flies; `stella shrink` with the campaign's SUT)")
    p.add_argument("--shrink-evaluations", type=positive_int, default=100, help="with --shrink: flights per case (default 100)")


@command("export-findings", "write one bug-report bundle per failure mode of a campaign: case, logs, plot, FINDING.md", _findings_options)
def cmd_export_findings(args: argparse.Namespace) -> int:
    from harness.campaigns.findings import broken_by, export_findings, judged_by
    from harness.campaigns.store import Store
    from harness.properties.spec import LIBRARY

    bundles = export_findings(Path(args.store), Path(args.out))
    with Store.existing(Path(args.store)) as store:
        config = store.campaign_config()
        broken = {evaluation: broken_by(store.evaluation(evaluation), config) for _folder, evaluation in bundles}
    for folder, evaluation in bundles if args.shrink else ():
        # As a user would run it (its progress on stderr), with the SUT the store records, while
        # the properties it broke stay broken.
        shrunk = subprocess.run([sys.executable, "-m", "harness.tools.cli", "shrink", args.store, "--evaluation", str(evaluation), "--out", str(folder / "shrunk"),
                                 "--name", "minimal", "--max-evaluations", str(args.shrink_evaluations),
                                 *(a for given in judged_by(broken[evaluation], folder) for a in ("--property", given if given in LIBRARY else str(folder / given)))],
                                stdout=subprocess.DEVNULL)
        if shrunk.returncode not in (0, 1):
            return shrunk.returncode
    text = "\n".join(str(f) for f, _ in bundles) + f"\nwrote {len(bundles)} finding(s) to {args.out}: start with {Path(args.out) / 'FINDINGS.md'}"
    emit(args, {"out": args.out, "findings": [str(f) for f, _ in bundles]}, text)
    return 0
