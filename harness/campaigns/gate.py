"""The pull-request gate (`stella gate`): is the head of a change (a branch, a commit, patches)
less safe than its base?

Both sides are built from the firmware tree (harness/firmware/builds.py, cached) or given as
builds. Then, the head the subject and the base the reference of differential flights
(harness/campaigns/pairs.py):

1. **suite**: the team's cases (regression cases, concrete scenarios) flown as pairs, each pair
   that differs flown again on both sides (`confirm`) and judged on all its flights;
2. **search**: a bounded differential search (objective difference: where the head comes closer
   than the base) on each scenario named, the budget (candidates, minutes) split across them,
   each a stored campaign that a second gate on the same builds resumes;
3. every pair **judged** (`judge`): a *regression* where the head is worse than the base beyond
   the base's own spread: it violates the safety distance where the base keeps it, comes closer
   by more than the spread (and the team's `closer_m`), ends worse (blocked where the base flies
   its mission to the end), or cannot finish its flight where the base can; a *change* where it
   differs otherwise (farther away, sooner, later), which passes; *unjudged* where the base
   itself could not finish;
4. each regression, worst first, **verified**: both sides flown until each has `verify_flights`
   flights, and judged again on all of them. Where two builds are one program, the chance that
   all k head flights land worse than all k base flights is 1 / C(2k, k) for a clearance (1/20
   at k = 3, 1/3432 at k = 7), and at most 4^-k for an end such as a violation, so a gate that
   judges tens of pairs still raises no false alarm on a firmware whose flights spread. Only
   a regression that holds counts; the worst one is shrunk and every one written as a finding
   bundle (harness/campaigns/gate_report.py).

Before any of that, a head that builds to the same program as its base (the same machine code and
data, start-up scripts and modules: harness/firmware/programs.py, which the command asks), as a
refactoring, a comment or a change of code the build leaves out does, passes at once: no flight
could tell them apart. `fly_identical` flies them all the same, to see the gate's own false
alarms.

Base flights are cached by (concrete scenario, seed, base build) in the cache folder beside the
builds, so a gate on the same base again flies the head only.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from harness.campaigns.campaign import CampaignConfig, content_key, run_campaign
from harness.campaigns.pairs import PairedFlights, ReferenceCache
from harness.campaigns.regression import suite_cases
from harness.campaigns.shrink_steps import space_of
from harness.campaigns.store import Store, StoredEvaluation
from harness.errors import InfrastructureError, InputError, Problem
from harness.execution.executor import Executor, Job
from harness.flight.differential import CLEARANCE_RESOLUTION_M, Difference, Outcome, Reveal, compare
from harness.flight.fitness import COULD_NOT_FINISH, Status
from harness.flight.logs import slug
from harness.flight.results import RunOptions
from harness.scenario.logical import load_logical
from harness.scenario.profile import load_profile
from sut_adapter import SutConfig

REGRESSION, CHANGE, SAME, UNJUDGED = "regression", "change", "same", "unjudged"
BASE_FLIGHTS = "base_flights.db"
# How far an end is from the mission flown to its end: a head ending further down than every base
# flight did ends worse.
STATUS_RANK = {Status.OK: 0, Status.MISSION_FAILED: 1, Status.VIOLATION: 2}
# A regression's kind, most severe first: the order findings are written and listed in.
SEVERITY = ("unsafe", "crash", "status", "closer")
UNBOUNDED_CANDIDATES = 1_000_000
# Of the time left when a search starts, the share kept for verifying and shrinking the regressions.
FINISH_SHARE = 0.25
SIDES = ("head", "base")  # the subject and the reference of the pairs, in the gate's words


@dataclass(frozen=True)
class Side:
    """One side of the gate: the SUT that flies it and how it came to be."""

    sut: SutConfig
    described: str  # for people: "commit 1a2b3c4d with 1 patch, built in 27 s" or "the build in DIR"
    folder: str  # the build's folder (or binary) as given to the SUT options
    build_s: float | None = None  # None: given as a build, or found in the cache
    cached: bool = False
    built_by: str | None = None  # the command that builds it anywhere (`stella sut build ...`); None: given as a build


@dataclass(frozen=True)
class GatePlan:
    suite: tuple[str, ...] = ()  # regression cases and concrete scenarios
    scenarios: tuple[str, ...] = ()  # logical scenarios searched
    budget_flights: int | None = None  # search candidates in all
    budget_minutes: float | None = None  # the whole gate's wall time; searches get what the suite leaves
    drive: str | None = None
    algorithm: str = "NSGAII"
    population: int = 10
    confirm: int = 0  # flights more of each side for a pair that differs
    seed: int = 0
    closer_m: float = 0.0  # a head closer than the base by less than this (beyond the base's spread) passes
    max_findings: int = 5
    profile: str = "default"
    shrink_candidates: int = 30  # candidates the worst regression's shrink may fly (each a pair); 0: not shrunk
    verify_flights: int = 1  # flights a side a regression must hold over (1: the first flights, for a SUT that repeats bit for bit)
    fly_identical: bool = False  # fly a head that builds to the base's very program too (else it passes unflown)


@dataclass(frozen=True)
class Judgement:
    verdict: str  # REGRESSION, CHANGE, SAME or UNJUDGED
    why: str
    kind: str | None = None  # a regression's (SEVERITY) or a change's (farther, shorter, longer, status)


@dataclass(frozen=True)
class JudgedPair:
    """A concrete scenario flown on both sides, and what that says."""

    name: str
    origin: str  # "suite", or the logical scenario searched
    judgement: Judgement
    concrete: Mapping[str, Any]
    seed: int
    differential: Mapping[str, Any]  # pairs.record: the head's flights as "subject", the base's as "reference"
    evaluation: StoredEvaluation | None = None  # a search's, as stored
    store: str | None = None

    @property
    def head_log(self) -> str | None:
        return self.differential["subject"][0].get("log_path")

    @property
    def base_log(self) -> str | None:
        return self.differential["reference"][0].get("log_path")

    @property
    def gap_m(self) -> float:
        """How much closer the head came than the base (larger is worse; unknown counts worst)."""
        head = [o["min_clearance_m"] for o in self.differential["subject"] if o["min_clearance_m"] is not None]
        base = [o["min_clearance_m"] for o in self.differential["reference"] if o["min_clearance_m"] is not None]
        return min(base) - max(head) if head and base else float("inf")


@dataclass(frozen=True)
class SearchCoverage:
    """What one scenario's search covered."""

    scenario: str
    budget: int | None  # candidates it was given (None: as many as its time allowed)
    evaluated: int  # candidates it asked (infeasible ones included)
    flown: int  # of which flown (the rest infeasible or from its store)
    wall_s: float
    stopped: str | None  # why it ended before its budget, or why it never began
    store: str | None


@dataclass(frozen=True)
class Shrunk:
    """The worst regression made as small and simple as it goes while it still regresses."""

    of: str  # the regression's name
    pair: JudgedPair | None  # the smallest pair that still regresses; None: the regression did not come back when flown as given
    kept: tuple[str, ...]  # the steps kept, in words
    tried: int
    flown: int
    stopped: str | None  # why it ended before it was done


@dataclass
class GateResult:
    base: Side
    head: Side
    plan: GatePlan
    suite: list[JudgedPair] = field(default_factory=list)
    searches: list[SearchCoverage] = field(default_factory=list)
    searched: list[JudgedPair] = field(default_factory=list)  # every pair the searches flew
    regressions: list[JudgedPair] = field(default_factory=list)  # verified, worst first
    not_held: list[JudgedPair] = field(default_factory=list)  # judged regressions that did not hold when verified
    unverified: list[JudgedPair] = field(default_factory=list)  # judged regressions the verification's budget left
    shrunk: Shrunk | None = None  # the worst regression, shrunk
    identical: bool = False  # the head builds to the base's program: nothing flown
    wall_s: float = 0.0

    @property
    def candidates(self) -> list[JudgedPair]:
        """Every pair judged a regression, the most severe and then the largest gap first; a
        concrete scenario found twice (the suite and a search) counted once."""
        found, seen = [], set()
        for pair in sorted(self.suite + self.searched, key=_severity):
            key = content_key(pair.concrete)
            if pair.judgement.verdict == REGRESSION and key not in seen:
                seen.add(key)
                found.append(pair)
        return found

    @property
    def passed(self) -> bool:
        return not self.regressions


def _severity(pair: JudgedPair) -> tuple[int, bool, float]:
    """Most severe first; of one kind, the team's own suite cases before what a search found."""
    kind = pair.judgement.kind
    return (SEVERITY.index(kind) if kind in SEVERITY else len(SEVERITY), pair.origin != "suite", -pair.gap_m)


def judge(head: Sequence[Outcome], base: Sequence[Outcome], closer_m: float = 0.0) -> Judgement:
    """The gate's verdict on one pair's flights (each side at least one)."""
    unfinished_base = [o for o in base if o.status in COULD_NOT_FINISH or o.min_clearance_m is None]
    if unfinished_base:
        return Judgement(UNJUDGED, f"the base could not finish its flight ({unfinished_base[0].status}: {unfinished_base[0].why})")
    finished_head = [o for o in head if o.status not in COULD_NOT_FINISH and o.min_clearance_m is not None]
    if not finished_head:
        return Judgement(REGRESSION, f"the head could not finish its flight ({head[0].status}: {head[0].why}) where the base flew to its end "
                                     f"({base[0].status})", "crash")
    verdict = compare(finished_head, base, SIDES)
    if verdict.reveals is None:
        return Judgement(SAME, verdict.why)
    if verdict.reveals == Reveal.UNSAFE:
        return Judgement(REGRESSION, verdict.why, "unsafe")
    if verdict.difference == Difference.CLOSER:
        base_clearances = [o.min_clearance_m for o in base]
        gap = min(base_clearances) - max(o.min_clearance_m for o in finished_head)
        margin = max(CLEARANCE_RESOLUTION_M, max(base_clearances) - min(base_clearances))
        if gap > margin + closer_m:
            return Judgement(REGRESSION, verdict.why, "closer")
        return Judgement(CHANGE, f"{verdict.why}, within the {closer_m:.2f} m the gate allows", "closer")
    if verdict.difference == Difference.STATUS:
        worse = min(STATUS_RANK.get(o.status, 3) for o in finished_head) > max(STATUS_RANK.get(o.status, 3) for o in base)
        return Judgement(REGRESSION if worse else CHANGE, verdict.why, "status")
    return Judgement(CHANGE, verdict.why, str(verdict.difference))


def judged(differential: Mapping[str, Any], closer_m: float) -> Judgement:
    """`judge` on a stored pair (pairs.record)."""
    return judge([Outcome.from_dict(o) for o in differential["subject"]], [Outcome.from_dict(o) for o in differential["reference"]], closer_m)


# -- flying ------------------------------------------------------------------------------------


def fly_suite(plan: GatePlan, base: Side, head: Side, executor: Executor, cache: ReferenceCache, out_dir: Path,
              progress: Callable[[str], None]) -> list[JudgedPair]:
    cases = suite_cases(plan.suite, plan.drive)
    pairs = PairedFlights(executor, base.sut, objective="difference", confirm=plan.confirm, cache=cache)
    options = RunOptions(sut=head.sut, warm=executor.keeps_stacks)
    jobs = [Job.of(number, space, x, seed=seed, out_dir=out_dir, name=name, options=options) for number, (name, space, x, seed) in enumerate(cases)]
    flown = []
    for job, result in sorted(pairs.run(jobs), key=lambda pair: pair[0].key):
        judgement = judged(result.differential, plan.closer_m)
        flown.append(JudgedPair(job.name, "suite", judgement, job.concrete, job.seed, result.differential))
        progress(f"suite {job.name}: {judgement.verdict}: {judgement.why}")
    return flown


def search(plan: GatePlan, base: Side, head: Side, executor: Executor, cache: ReferenceCache, out_dir: Path, deadline: float | None,
           progress: Callable[[str], None]) -> tuple[list[SearchCoverage], list[JudgedPair]]:
    """Each scenario searched in turn with its share of what is left of the budget."""
    coverage: list[SearchCoverage] = []
    pairs: list[JudgedPair] = []
    flights_left = plan.budget_flights
    for index, scenario in enumerate(plan.scenarios):
        scenarios_left = len(plan.scenarios) - index
        budget = flights_left // scenarios_left if flights_left is not None else None
        wall_s = (deadline - time.monotonic()) * (1 - FINISH_SHARE) / scenarios_left if deadline is not None else None
        if budget == 0 or (wall_s is not None and wall_s <= 0):
            coverage.append(SearchCoverage(scenario, budget or 0, 0, 0, 0.0, "not searched: the budget was spent", None))
            progress(f"search {Path(scenario).name}: not searched, the budget was spent")
            continue
        # With a budget in minutes only, the time ends the search, long before this many candidates.
        candidates = budget if budget is not None else UNBOUNDED_CANDIDATES
        config = CampaignConfig((scenario,), (plan.algorithm,), candidates, 1, plan.seed, min(plan.population, candidates), plan.profile,
                                wall_time_s=wall_s, sut=head.sut, drive=plan.drive, confirm=plan.confirm, reference=base.sut, objective="difference")
        identity = hashlib.sha256(json.dumps(config.identity(), sort_keys=True).encode()).hexdigest()[:12]
        store_path = out_dir / f"{slug(Path(scenario).stem)}-{plan.algorithm}-{identity}.db"
        started = time.monotonic()
        with Store.for_campaign(store_path) as store:
            summary = run_campaign(config, store, executor, store_path.with_suffix(""), options=RunOptions(warm=True), reference_cache=cache)
            found = [JudgedPair(f"{slug(Path(scenario).stem)}-eval{case.id:05d}", Path(scenario).stem, judged(case.differential, plan.closer_m),
                                case.concrete, case.seed, case.differential, case, str(store_path))
                     for case in store.pairs() if case.concrete is not None]
            evaluated = len(store.all_evaluations())
        wall = time.monotonic() - started
        flown = sum(run.flown for run in summary.runs)
        stopped = None if evaluated >= candidates else f"stopped at the time budget after {evaluated}" + (f" of {budget}" if budget else "") + " candidates"
        coverage.append(SearchCoverage(scenario, budget, evaluated, flown, wall, stopped, str(store_path)))
        pairs += found
        if flights_left is not None:
            flights_left -= budget
        regressions = sum(p.judgement.verdict == REGRESSION for p in found)
        progress(f"search {Path(scenario).name}: {evaluated} candidates ({flown} flown now) in {wall:.0f} s, {regressions} regressions"
                 + (f"; {stopped}" if stopped else ""))
    return coverage, pairs


def shrink(pair: JudgedPair, plan: GatePlan, base: Side, head: Side, executor: Executor, cache: ReferenceCache, out_dir: Path,
           deadline: float | None, progress: Callable[[str], None]) -> Shrunk:
    """The regression shrunk (harness/campaigns/shrink.py) while the pair still regresses at least
    as badly: each candidate flown on both sides, confirmed as the suite's pairs are."""
    from harness.campaigns import shrink as shrinking

    pairs = PairedFlights(executor, base.sut, objective="difference", confirm=plan.confirm, cache=cache)
    options = RunOptions(sut=head.sut, warm=executor.keeps_stacks)
    flown: dict[str, JudgedPair] = {}

    def fly(document: Mapping[str, Any], name: str) -> shrinking.Flight:
        space = space_of(document)
        job = Job.of(0, space, space.from_concrete(document), seed=pair.seed, out_dir=out_dir / "flights", name=f"{pair.name}-{name}", options=options)
        [(_job, result)] = list(pairs.run([job]))
        judgement = judged(result.differential, plan.closer_m)
        flown[result.log_path or name] = JudgedPair(f"{pair.name}-shrunk", pair.origin, judgement, job.concrete, pair.seed, result.differential)
        return shrinking.Flight(str(result.status), result.fitness, result.min_clearance_m, result.min_clearance_obstacle, result.log_path,
                                judgement.why, judgement.kind if judgement.verdict == REGRESSION else judgement.verdict)

    start = shrinking.start_document(shrinking.Case(dict(pair.concrete), pair.seed, head.sut.identity(), pair.name, pair.name), plan.drive)
    header = {"format": shrinking.JOURNAL_FORMAT, "start": shrinking.key_of(start), "seed": pair.seed, "head": head.folder, "base": base.folder,
              "confirm": plan.confirm, "closer_m": plan.closer_m}
    # Each gate shrinks afresh: its findings hold the pairs this run flew, not a journal's verdicts.
    (out_dir / f"{pair.name}.journal.jsonl").unlink(missing_ok=True)
    journal = shrinking.Journal(out_dir / f"{pair.name}.journal.jsonl", header)
    wall_s = deadline - time.monotonic() if deadline is not None else None
    # A step is kept while the head is as bad as it was found or worse: an unsafe regression does
    # not shrink into one that only comes closer.
    as_bad = set(SEVERITY[:SEVERITY.index(pair.judgement.kind) + 1])
    shrinker = shrinking.Shrinker(fly, journal, budget=shrinking.Budget(plan.shrink_candidates, wall_s), keeps=lambda f: f.verdict in as_bad,
                                  on_step=lambda step, _s: progress(f"shrink {pair.name}: {shrinking.step_line(step)}"))
    if wall_s is not None and wall_s <= 0:
        return Shrunk(pair.name, None, (), 0, 0, "the time budget was spent before it")
    try:
        report = shrinker.shrink(start, pair.name)
    except InputError:  # flown as given, it did not regress again (a firmware's spread)
        return Shrunk(pair.name, None, (), 0, shrinker.flown, "the regression did not come back when flown again as found")
    except (shrinking.Stopped, InfrastructureError) as stopped:  # the budget, or flights that could not finish, before the case flew as given
        return Shrunk(pair.name, None, (), 0, shrinker.flown, str(stopped))
    final = report.result_flights[0]
    return Shrunk(pair.name, flown.get(final.log or "") if report.kept else None, tuple(step.description for step in report.kept), len(report.steps),
                  report.flown, report.stopped)


def verify(candidates: list[JudgedPair], plan: GatePlan, base: Side, head: Side, executor: Executor, out_dir: Path, deadline: float | None,
           progress: Callable[[str], None]) -> tuple[list[JudgedPair], list[JudgedPair], list[JudgedPair]]:
    """(held, not held, not verified): the candidates, worst first, each flown on both sides until
    it has `verify_flights` a side and judged again on all, until `max_findings` held or the time
    budget is spent; one flown so often already holds as it is."""
    held: list[JudgedPair] = []
    not_held: list[JudgedPair] = []
    unverified: list[JudgedPair] = []
    for pair in candidates:
        more = {side: max(0, plan.verify_flights - len(pair.differential[side])) for side in ("subject", "reference")}
        if not any(more.values()):
            held.append(pair)
            continue
        if len(held) >= plan.max_findings or (deadline is not None and time.monotonic() >= deadline):
            unverified.append(pair)
            continue
        space = space_of(pair.concrete)
        x = space.from_concrete(pair.concrete)
        jobs = [Job.of(0, space, x, seed=pair.seed, out_dir=out_dir, name=f"{pair.name}-{SIDES[side == 'reference']}-verify{number}",
                       options=RunOptions(sut=(head if side == "subject" else base).sut, warm=executor.keeps_stacks))
                for side, count in more.items() for number in range(1, count + 1)]
        flown = {job.name: result for job, result in executor.run([replace(job, key=key) for key, job in enumerate(jobs)])}
        differential = dict(pair.differential)
        for side in more:
            differential[side] = [*pair.differential[side], *(Outcome.of(result).as_dict() for name, result in sorted(flown.items())
                                                               if name.startswith(f"{pair.name}-{SIDES[side == 'reference']}-verify"))]
        judgement = judged(differential, plan.closer_m)
        verified = replace(pair, judgement=judgement, differential=differential)
        (held if judgement.verdict == REGRESSION else not_held).append(verified)
        progress(f"verify {pair.name} over {plan.verify_flights} flights a side: {'holds' if judgement.verdict == REGRESSION else 'does not hold'}: "
                 f"{judgement.why}")
    return held, not_held, unverified


def check(plan: GatePlan) -> None:
    """InputError for a plan that cannot fly, before anything is built: nothing to fly, a suite
    case or scenario that does not load or is infeasible."""
    if not plan.suite and not plan.scenarios:
        raise InputError([Problem("--suite", "", "nothing to fly: give the suite's cases (--suite) or scenarios to search (--scenario), "
                                                 "here or in the configuration file")])
    suite_cases(plan.suite, plan.drive)
    profile = load_profile(plan.profile)
    for scenario in plan.scenarios:
        load_logical(Path(scenario), profile, plan.drive)


def run_gate(plan: GatePlan, base: Side, head: Side, executor: Executor, *, out_dir: Path, cache_dir: Path,
             started: float | None = None, progress: Callable[[str], None] = lambda _line: None, one_program: bool = False) -> GateResult:
    """The suite, then the searches, judged. `started` (time.monotonic()) is when the gate began,
    builds included, for the time budget. `one_program`: the two sides build to the same program
    (harness/firmware/programs.py), so unless the plan says to fly them all the same, nothing is
    flown."""
    started = time.monotonic() if started is None else started
    check(plan)
    for side in (base, head):
        executor.check_sut(side.sut)
    deadline = started + plan.budget_minutes * 60 if plan.budget_minutes is not None else None
    result = GateResult(base, head, plan)
    if one_program and not plan.fly_identical:
        progress("the head builds to the same program as the base: nothing to fly")
        result.identical = True
        result.wall_s = time.monotonic() - started
        return result
    cache_dir.mkdir(parents=True, exist_ok=True)
    cache = ReferenceCache(cache_dir / BASE_FLIGHTS)
    try:
        if plan.suite:
            result.suite = fly_suite(plan, base, head, executor, cache, out_dir / "suite", progress)
        if plan.scenarios:
            result.searches, result.searched = search(plan, base, head, executor, cache, out_dir / "search", deadline, progress)
        result.regressions, result.not_held, result.unverified = verify(result.candidates, plan, base, head, executor, out_dir / "verify", deadline,
                                                                         progress)
        shrinkable = [pair for pair in result.regressions if pair.judgement.kind != "crash"]
        if shrinkable and plan.shrink_candidates:
            result.shrunk = shrink(shrinkable[0], plan, base, head, executor, cache, out_dir / "shrink", deadline, progress)
    finally:
        cache.close()
    result.wall_s = time.monotonic() - started
    judged_pairs = result.suite + result.searched
    if judged_pairs and all(p.judgement.verdict == UNJUDGED for p in judged_pairs):
        raise InfrastructureError(f"the base could not finish any of its {len(judged_pairs)} flights, so nothing was judged: "
                                  f"{judged_pairs[0].judgement.why}")
    return result

