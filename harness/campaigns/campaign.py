"""Campaigns: logical scenarios x algorithms x runs, each run a sequence of optimizer steps.

A run's budget (`evaluations`) is split evenly over the steps of its algorithm string (NSGAII
alone is one step; NPB is three). Each step after the first starts from the best solutions so
far (`SEEDS_FROM_BEST` of them: jMetalPy's injector, BO's probes) plus candidates from the least
explored regions: of `EXPLORE_POOL` uniform points, greedily those farthest (in the space
scaled to the unit cube) from every evaluated point and from each other (maximin distance).
The run's result is the lowest fitness of all its steps.
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from harness.campaigns.coverage import CodeNovelty
from harness.campaigns.diversity import FailureModes
from harness.campaigns.problem import CampaignProblem, StopSearch
from harness.campaigns.screen import Screen, ScreenSettings
from harness.campaigns.screen_sources import pairs_to_learn
from harness.campaigns.store import Store
from harness.execution.executor import Executor
from harness.flight.results import EvaluationResult, RunOptions
from harness.properties.spec import Property
from harness.scenario.logical import LogicalScenario, load_logical
from harness.scenario.profile import Profile, load_profile
from harness.scenario.rig import with_rig
from harness.scenario.space import SearchSpace
from harness.search import DEFAULT_BATCH
from harness.search.optimizers import OPTIMIZERS, parse_algorithm
from harness.search.termination import AnyOf, EvaluationBudget, FirstReveal, FirstViolation, Termination, WallTimeBudget
from sut_adapter import SutConfig

log = logging.getLogger(__name__)

SEEDS_FROM_BEST = 5
# What a differential pair's fitness is, by the campaign's objective: with safety properties the
# subject's (each property compares the two); a coverage-guided search looks for differences.
PAIR_OBJECTIVES = {"properties": "subject", "coverage": "difference"}
EXPLORE_POOL = 2000


@dataclass(frozen=True)
class CampaignDocuments:
    """A campaign's documents, read once: the profile and its logical scenarios as flown."""

    profile: Profile
    scenarios: tuple[LogicalScenario, ...]


@dataclass(frozen=True)
class CampaignConfig:
    scenarios: tuple[str, ...]
    algorithms: tuple[str, ...]
    evaluations: int
    runs: int = 1
    seed: int = 0
    population: int = 50
    profile: str = "default"
    stop_at_violation: bool = False
    wall_time_s: float | None = None
    sut: SutConfig = field(default_factory=SutConfig)  # its identity part is the campaign's
    drive: str | None = None  # None: each scenario's own mission.drive
    batch: int = DEFAULT_BATCH
    confirm: int = 0
    mission_plan: str | None = None  # a .plan flown instead of each scenario's route
    # Differential: every candidate flown against this SUT too (harness/campaigns/pairs.py), and
    # the search minimising the subject's f ("subject") or f_subject - f_reference ("difference").
    # Without a reference, "diverse": f shared over failure modes (harness/campaigns/diversity.py).
    reference: SutConfig | None = None
    objective: str = "subject"
    stop_at_reveal: bool = False  # end each run at its first confirmed revealing candidate
    # Safety properties scored on every flight (harness/properties); the search then minimises the
    # least of their robustness instead of f.
    properties: tuple[Property, ...] = ()
    # Each batch flown on a cheap model first, the real SUT only where it pays (harness/campaigns/screen.py).
    screen: ScreenSettings | None = None
    rig: str | None = None  # a sensor rig (preset name or file) instead of the profile's range sensors
    # --objective coverage: code (coverage.line_name) every flight that runs it is rewarded for first.
    coverage_target: tuple[str, ...] = ()
    # Differential: where the subject's program differs from the reference's (a mutant's line); a
    # coverage build's flight that ran none of them reveals nothing (harness/campaigns/pairs.py).
    # Not part of the identity: it judges the pairs, and `stella rejudge` judges stored ones again.
    changed_lines: tuple[str, ...] = ()
    # Screened: other stores whose candidates flown both ways the correction learns from too
    # (harness/campaigns/screen_sources.py). Not part of the identity: they are copied into the
    # store when the campaign begins, and a resumed campaign learns from that copy.
    learn_from: tuple[str, ...] = ()

    def read(self) -> CampaignDocuments:
        """The profile and the logical scenarios as this campaign flies them (drive and plan applied)."""
        profile = load_profile(self.profile)
        plan = Path(self.mission_plan) if self.mission_plan else None
        return CampaignDocuments(profile, tuple(load_logical(Path(s), profile, self.drive, plan, self.rig) for s in self.scenarios))

    def identity(self, documents: CampaignDocuments | None = None) -> dict[str, Any]:
        """What makes two invocations the same campaign (and so resumable from one store): the
        scenario documents and the profile as read (documents, else read now), by content, not
        where they lie, so a store copied to another checkout or machine resumes there."""
        documents = documents or self.read()
        return self._identity(scenarios=[content_key(s.document) for s in documents.scenarios], profile=content_key(documents.profile.document))

    def legacy_identities(self, documents: CampaignDocuments | None = None) -> list[dict[str, Any]]:
        """The identities stores were made with before: by the scenario files' (and the mission
        plan's) absolute paths and the profile's name, before they were known by content; and
        without the firmware's digest where the environment named the build (STELLA_PX4_BIN),
        before such builds counted; and with --rig's sensors in the profile rather than in each
        scenario, before scenarios had rigs of their own. Such a store is that campaign, and is
        re-keyed by today's."""
        documents = documents or self.read()
        if self.rig is not None:
            rig = documents.scenarios[0].rig
            return [self._identity(scenarios=[content_key({k: v for k, v in s.document.items() if k != "rig"}) for s in documents.scenarios],
                                   profile=content_key(with_rig(documents.profile.document, rig)))]
        by_path = self._identity(scenarios=[str(Path(s).resolve()) for s in self.scenarios], profile=self.profile, from_environment=False)
        if self.mission_plan:
            by_path["mission_plan"] = str(Path(self.mission_plan).resolve())
        by_content = self._identity(scenarios=[content_key(s.document) for s in documents.scenarios], profile=content_key(documents.profile.document),
                                    from_environment=False)
        return [by_path, by_content]

    def sources(self) -> dict[str, Any]:
        """Where the campaign's documents were read from: information, not identity."""
        from harness.campaigns.pairs import build_record

        return {"scenario_files": [str(Path(s).resolve()) for s in self.scenarios], "profile": self.profile,
                **({"mission_plan": str(Path(self.mission_plan).resolve())} if self.mission_plan else {}),
                **({"rig": self.rig} if self.rig else {}),
                "sut_build": build_record(self.sut), **({"reference_build": build_record(self.reference)} if self.reference else {})}

    def _identity(self, *, scenarios: list[str], profile: str, from_environment: bool = True) -> dict[str, Any]:
        from harness.campaigns.pairs import build_identity, firmware_digest

        overrides: dict[str, Any] = {"drive": self.drive} if self.drive else {}
        if self.batch != DEFAULT_BATCH:  # stores made before the batch was a setting resume as they were
            overrides["batch"] = self.batch
        if self.confirm:
            overrides["confirm"] = self.confirm
        if self.sut.fault:
            overrides["sut_fault"] = self.sut.fault
        if self.reference is not None:
            overrides.update(reference=build_identity(self.reference, from_environment=from_environment), objective=self.objective,
                             subject=build_identity(self.sut, from_environment=from_environment))
        else:
            # Another build is another campaign: a store does not replay the last build's flights
            # as this one's (a firmware rebuilt with a fix, flown again with the same command).
            build = firmware_digest(self.sut, from_environment=from_environment)
            if build:
                overrides["sut_build"] = build
            if self.objective != "subject":  # the optimizer hears other values, so it asks other candidates
                overrides["objective"] = self.objective
        if self.stop_at_reveal:
            overrides["stop_at_reveal"] = True
        if self.properties:  # another objective: the optimizer hears other values
            overrides["properties"] = [prop.as_dict() for prop in self.properties]
        if self.screen is not None:  # other candidates flown for real
            overrides["screen"] = self.screen.identity()
        if self.coverage_target:  # the optimizer hears other values
            overrides["coverage_target"] = list(self.coverage_target)
        return {
            "scenarios": scenarios,
            "algorithms": list(self.algorithms),
            "evaluations": self.evaluations,
            "runs": self.runs,
            "seed": self.seed,
            "population": self.population,
            "profile": profile,
            "stop_at_violation": self.stop_at_violation,
            "sut": self.sut.name,
            "sut_params": dict(self.sut.params),
            **overrides,
        }


def content_key(document: Any) -> str:
    """A JSON document's identity by content: the SHA-256 of its canonical text."""
    return "sha256:" + hashlib.sha256(json.dumps(document, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def least_explored(space: SearchSpace, evaluated: Sequence[np.ndarray], count: int, rng: np.random.Generator) -> list[np.ndarray]:
    """count points of a uniform pool, each the farthest from everything evaluated or chosen so far."""
    if count <= 0:
        return []
    span = np.where(space.upper > space.lower, space.upper - space.lower, 1.0)
    pool = space.sample(rng, EXPLORE_POOL)
    scaled_pool = (pool - space.lower) / span
    if len(evaluated):
        known = (np.asarray(evaluated) - space.lower) / span
        nearest = np.min(np.linalg.norm(scaled_pool[:, None, :] - known[None, :, :], axis=2), axis=1)
    else:
        nearest = np.full(len(pool), np.inf)
    chosen = []
    for _ in range(min(count, len(pool))):
        best = int(np.argmax(nearest))
        chosen.append(pool[best])
        nearest = np.minimum(nearest, np.linalg.norm(scaled_pool - scaled_pool[best], axis=1))
    return chosen


def run_sequence(combination: str, problem: CampaignProblem, *, budget: int, seed: int, population: int, batch: int) -> None:
    per_step = [budget // len(combination) + (1 if i < budget % len(combination) else 0) for i in range(len(combination))]
    rng = np.random.default_rng(seed)
    for step, (letter, step_budget) in enumerate(zip(combination, per_step)):
        optimizer = OPTIMIZERS[letter]
        initial: list[np.ndarray] = []
        if problem.history:
            ranked = sorted(problem.history, key=problem.objective_of)
            initial = [trial.vector for trial in ranked[: min(SEEDS_FROM_BEST, population)]]
            initial += least_explored(problem.space, [trial.vector for trial in problem.history], population - len(initial), rng)
        problem.start_step(step, optimizer.name, step_budget)
        search = optimizer.start(problem.space, seed=seed * 1000 + step, population=population, batch=batch, initial=initial, objectives=problem.objectives)
        try:
            while True:
                vectors = search.ask()
                search.tell(vectors, problem.evaluate(vectors))
        except StopSearch as stop:
            if stop.campaign_done and problem.step_cut_short:
                return
        problem.checkpoint()


@dataclass(frozen=True)
class RunSummary:
    """What one run of a campaign gave, as `stella campaign` reports it."""

    run_id: int
    scenario: str
    algorithm: str
    run: int
    seed: int
    evaluations: int
    flown: int
    replayed: int
    violations: int
    failures_refused: int  # flights in which the SUT refused a failure injection
    best_fitness: float | None
    revealing: int | None = None  # a differential campaign's candidates that reveal a difference; None in others
    property_violations: int | None = None  # flights that violated a safety property asked; None where none was
    screen: dict[str, Any] | None = None  # a screened campaign's cheap flights and the screen's error (Screen.summary); None in others

    def as_dict(self) -> dict[str, Any]:
        document = asdict(self)
        for optional in ("revealing", "property_violations", "screen"):
            if document[optional] is None:
                del document[optional]
        return document


def run_line(run: RunSummary) -> str:
    """One line on a finished run, for a console."""
    best = run.best_fitness if run.best_fitness is not None else float("nan")
    if run.property_violations is not None:
        line = (f"{run.scenario} {run.algorithm} run {run.run}: least robustness {best:.3f}, {run.property_violations} flights violating a property, "
                f"{run.violations} violations of the safety distance in {run.evaluations} evaluations")
    else:
        line = f"{run.scenario} {run.algorithm} run {run.run}: best fitness {best:.3f}, {run.violations} violations in {run.evaluations} evaluations"
    return line + (f"; {screen_line(run.screen)}" if run.screen else "")


def screen_line(screen: dict[str, Any]) -> str:
    def known(correlation: float | None) -> str:
        return f"{correlation:.2f}" if correlation is not None else "not yet known"

    corrected = "corrected_rank_correlation" in screen
    return (f"screen: {screen['flights']} cheap flights, {screen['screened_out']} not flown for real, rank correlation "
            + known(screen["rank_correlation"]) + (f" (corrected {known(screen['corrected_rank_correlation'])})" if corrected else "")
            + f" over {screen['pairs']} flown both ways, {screen['false_negatives']} false negatives"
            + (f" (corrected {screen['corrected_false_negatives']}; trained on {screen['training_pairs']}"
               + (f", {screen['learned_pairs']} of them from other stores" if screen.get("learned_pairs") else "") + ")" if corrected else "")
            + (", fell back to flying every candidate" if screen["fell_back"] else ""))


@dataclass
class CampaignSummary:
    runs: list[RunSummary] = field(default_factory=list)


def termination_for(config: CampaignConfig) -> Termination:
    parts: list[Termination] = [EvaluationBudget(config.evaluations)]
    if config.stop_at_violation:
        parts.append(FirstViolation())
    if config.stop_at_reveal:
        parts.append(FirstReveal())
    if config.wall_time_s:
        parts.append(WallTimeBudget(config.wall_time_s))
    return AnyOf(tuple(parts))


def run_campaign(config: CampaignConfig, store: Store, executor: Executor, out_dir: Path, *, options: RunOptions = RunOptions(),
                 on_result: Callable[[EvaluationResult], None] = lambda r: None, on_run: Callable[[RunSummary], None] = lambda r: None,
                 reference_cache=None) -> CampaignSummary:
    """options: how each flight runs; its SUT is always the campaign's (config.sut), and it runs
    warm only where the executor's processes live on. on_result hears of every evaluation, on_run
    of every run as it finishes. A differential campaign keeps its reference flights in its store
    unless given another ReferenceCache (a mutation run's, shared)."""
    options = replace(options, sut=config.sut, warm=options.warm and executor.keeps_stacks, properties=config.properties)
    for sut in filter(None, (config.sut, config.reference, config.screen.sut if config.screen else None)):
        executor.check_sut(sut)
    combinations = [parse_algorithm(a) for a in config.algorithms]
    documents = config.read()
    identity = config.identity(documents)
    learning = pairs_to_learn(store, identity, {content_key(s.document) for s in documents.scenarios}, config.learn_from)
    campaign_id = store.campaign(identity, legacy=config.legacy_identities(documents), sources=config.sources())
    for source, pairs in learning.items():
        store.learn_screen_pairs(source, pairs)
    if config.learn_from:
        log.info("the screen's correction learns from %s", ", ".join(f"{count} candidates flown both ways in {source}"
                                                                    for source, count in store.screen_sources().items()))
    pairs = None
    if config.reference is not None:
        from harness.campaigns.pairs import PairedFlights, ReferenceCache

        # With properties the pair's fitness is the subject's; the problem makes the objectives of its properties.
        pairs = PairedFlights(executor, config.reference, objective=PAIR_OBJECTIVES.get(config.objective, config.objective), confirm=config.confirm,
                              cache=reference_cache or ReferenceCache(store.path), changed_lines=config.changed_lines)
    summary = CampaignSummary()
    for scenario_file, logical in zip(config.scenarios, documents.scenarios):
        space = SearchSpace(logical, documents.profile)
        for algorithm, combination in zip(config.algorithms, combinations):
            for run_index in range(config.runs):
                seed = config.seed + run_index
                run_id, finished = store.run(campaign_id, str(Path(scenario_file).resolve()), space.logical.name, algorithm.upper(), run_index, seed,
                                             scenario_key=content_key(logical.document))
                if finished:
                    continue
                screen = None if config.screen is None else Screen(config.screen, executor, store, run_id, seed, out_dir / f"run{run_id}" / "screen",
                                                                  options, space, config.properties,
                                                                  comparable=config.reference is None or PAIR_OBJECTIVES.get(config.objective, config.objective) != "difference")
                problem = CampaignProblem(space, store, run_id, executor, seed, termination_for(config), out_dir / f"run{run_id}", options, on_result,
                                          confirm=config.confirm, pairs=pairs, diversity=FailureModes() if config.objective == "diverse" else None,
                                          novelty=CodeNovelty(config.coverage_target) if config.objective == "coverage" else None,
                                          each_property=config.objective == "properties", screen=screen)
                run_sequence(combination, problem, budget=config.evaluations, seed=seed, population=config.population, batch=config.batch)
                store.finish_run(run_id)
                best = problem.best
                run = RunSummary(run_id, space.logical.name, algorithm.upper(), run_index, seed, problem.spent, problem.flown, problem.replayed,
                                 problem.violations, store.failures_refused(run_id), problem.objective_of(best) if best else None,
                                 problem.revealing if pairs else None, problem.property_violations if config.properties else None,
                                 screen.summary() if screen else None)
                summary.runs.append(run)
                on_run(run)
    return summary
