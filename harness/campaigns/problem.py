"""The campaign's evaluation of an optimizer's candidates: a function from batches of vectors to
fitness values, which the campaign's search loop (campaign.run_sequence) calls between ask and tell.

It owns the loop's side effects: the store (replay of finished evaluations on resume), the
executor, the budgets. Within a run each distinct vector is flown at most once; asking again
(for instance a sequence step re-evaluating the best solutions it was seeded with) is answered
from memory and costs no budget.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Mapping

import numpy as np

from harness.campaigns.coverage import CodeNovelty, code_reached
from harness.campaigns.store import Store, evaluation_name, vector_key
from harness.execution.executor import Executor, Job
from harness.flight.differential import Reveal
from harness.flight.evaluation import infeasible
from harness.flight.results import EvaluationResult, RunOptions
from harness.flight.fitness import COULD_NOT_FINISH, Status, unpenalized
from harness.scenario.space import SearchSpace
from harness.search.termination import Progress, Termination

if TYPE_CHECKING:
    from harness.campaigns.diversity import FailureModes
    from harness.campaigns.pairs import PairedFlights
    from harness.campaigns.screen import CheapOutcome, Screen


log = logging.getLogger(__name__)

# A screened run ends when its optimizer asks this many infeasible candidates in a row: they cost
# no budget there, so nothing else would end a search stuck outside the realism constraints.
REFUSED_STREAK_LIMIT = 1000


class StopSearch(Exception):
    """Raised by CampaignProblem.evaluate once the step's budget or the run's termination is reached
    (what it could evaluate of the batch is stored); ends the step's search loop."""

    def __init__(self, campaign_done: bool):
        self.campaign_done = campaign_done
        super().__init__("campaign termination reached" if campaign_done else "step budget reached")


def least_robustness(properties: Mapping[str, Mapping[str, Any]]) -> float | None:
    """The least robustness among a flight's scored properties (None: none was scored)."""
    scored = [p["robustness"] for p in properties.values() if p.get("robustness") is not None]
    return min(scored) if scored else None


@dataclass(frozen=True)
class Trial:
    """One distinct candidate of a run once it has an outcome (flown, refused as infeasible, or
    replayed from the store): its place in the run, its vector and identity, and its outcome."""

    ordinal: int
    vector: np.ndarray = field(compare=False)
    key: str
    fitness: float
    status: Status
    reveals: Reveal | None = None
    log_path: str | None = field(default=None, compare=False)
    robustness: float | None = None  # the least of the safety properties' asked (None: none scored)
    robustness_each: tuple[float | None, ...] = ()  # each property's asked, in the order asked (None: not scored)
    reached: frozenset[str] = field(default=frozenset(), compare=False)  # a coverage build's: the lines and branches it ran


@dataclass(frozen=True)
class _Candidate:
    """A vector an optimizer asked for, clipped into the space, with its identity in the run."""

    index: int  # its place in the batch
    vector: np.ndarray = field(compare=False)
    key: str


@dataclass(frozen=True)
class _Step:
    """Which step of a sequence is asking, for the store, and where its budget ends."""

    index: int = 0
    optimizer: str = ""
    limit: int | None = None


@dataclass
class CampaignProblem:
    space: SearchSpace
    store: Store
    run_id: int
    executor: Executor
    seed: int
    termination: Termination
    out_dir: Path
    options: RunOptions = field(default_factory=RunOptions)
    on_result: Callable[[EvaluationResult], None] = lambda result: None
    confirm: int = 0  # re-flights of each violation, to tell a steady one from a flaky one
    pairs: PairedFlights | None = None  # each candidate flown against a reference SUT too, confirmed there
    diversity: FailureModes | None = None  # the optimizer is told fitness shared over failure modes (--objective diverse)
    novelty: CodeNovelty | None = None  # the optimizer is told of code no flight reached before (--objective coverage)
    each_property: bool = False  # the optimizer is told one objective per property (--objective properties)
    screen: Screen | None = None  # each batch flown on a cheap model first, the real SUT only where it pays (--screen)

    def __post_init__(self) -> None:
        self._stored = self.store.evaluations(self.run_id)
        self._trials: dict[str, Trial] = {}
        self._step = _Step()
        self.spent = 0
        self.violations = 0
        self.property_violations = 0
        self.flown = 0
        self.replayed = 0
        self.revealing = 0
        self._started = time.monotonic()
        self._pending = 0
        self._batches_s = 0.0  # wall time spent flying batches
        self._batched = 0  # candidates those batches flew
        self._screened_out: dict[str, CheapOutcome] = {}  # candidates flown on the screen only, by key
        # A screened run's infeasible candidates, by key: never flown, so not of the subject's
        # flights that --evaluations counts, nor stored; told their constraint penalty.
        self._refused: dict[str, float] = {}
        self._refusals: dict[str, EvaluationResult | None] = {}  # this batch's, by key
        self._refused_streak = 0

    @property
    def progress(self) -> Progress:
        return Progress(self.spent, time.monotonic() - self._started, self.violations, self.revealing, self._pending,
                        self._batches_s / self._batched if self._batched else 0.0)

    @property
    def history(self) -> list[Trial]:
        """Distinct candidates with their outcome in request order, however the executor finished them."""
        return sorted(self._trials.values(), key=lambda trial: trial.ordinal)

    @property
    def best(self) -> Trial | None:
        return min(self.history, key=self.objective_of, default=None)

    @property
    def objectives(self) -> int:
        """How many objectives the optimizer is told per candidate."""
        return len(self.options.properties) if self.each_property else 1

    def _robustness_each(self, properties: Mapping[str, Mapping[str, Any]]) -> tuple[float | None, ...]:
        return tuple(properties.get(prop.name, {}).get("robustness") for prop in self.options.properties)

    def objective_of(self, trial: Trial) -> float:
        """What the search minimises: the flight's f, or with safety properties asked, the least
        of their robustness (a flight that could not finish, or was not flown, keeps its penalty)."""
        return trial.robustness if self.options.properties and trial.robustness is not None else trial.fitness

    def start_step(self, index: int, optimizer: str, budget: int) -> None:
        """A sequence's next step asks from now on, with budget evaluations of its own."""
        self._step = _Step(index, optimizer, self.spent + budget)

    @property
    def step_cut_short(self) -> bool:
        """Whether the step ended before its own budget (the run's termination came first)."""
        return self._step.limit is not None and self.spent < self._step.limit

    def checkpoint(self) -> None:
        """The step's end in the store: its optimizer, the evaluations spent and the best so far."""
        best = self.best
        self.store.checkpoint(self.run_id, self._step.index, {"optimizer": self._step.optimizer, "spent": self.spent,
                                                              "best_fitness": best.fitness if best else None,
                                                              "best_vector": best.vector.tolist() if best else None})

    def _check_budgets(self) -> None:
        if self.termination.done(self.progress):
            raise StopSearch(campaign_done=True)
        if self._step.limit is not None and self.spent >= self._step.limit:
            raise StopSearch(campaign_done=False)

    def _record(self, trial: Trial) -> None:
        self._trials[trial.key] = trial
        if trial.status == Status.VIOLATION:
            self.violations += 1
        if trial.robustness is not None and trial.robustness < 0:
            self.property_violations += 1
        if trial.reveals:
            self.revealing += 1

    def _candidate(self, index: int, raw: np.ndarray) -> _Candidate:
        x = np.clip(np.asarray(raw, dtype=float), self.space.lower, self.space.upper)
        return _Candidate(index, x, vector_key(x))

    def evaluate(self, vectors: list[np.ndarray]) -> list[float] | list[list[float]]:
        """Fitness for each vector, in order; raises StopSearch once a budget is used up."""
        candidates = [self._candidate(index, raw) for index, raw in enumerate(vectors)]
        self._refusals = {}
        screened_out = self._screen(candidates) if self.screen is not None else set()
        to_fly: dict[int, tuple[_Candidate, Job]] = {}  # by ordinal, the key of its job
        ids: dict[int, int] = {}  # the store's evaluation id by ordinal
        stop: StopSearch | None = None
        self._pending = 0
        for candidate in candidates:
            # Known already, or a duplicate inside this batch: answered from its first one's outcome.
            if (candidate.key in self._trials or candidate.key in self._screened_out or candidate.key in self._refused
                    or any(candidate.key == flying.key for flying, _job in to_fly.values())):
                continue
            if candidate.key in screened_out:  # no budget: not flown for real
                self._screened_out[candidate.key] = self.screen.cheap(candidate.key)
                continue
            if self.screen is not None:
                refused = self._refusal(candidate)
                if refused is not None:
                    self._refused[candidate.key] = refused.fitness
                    self._refused_streak += 1
                    if self._refused_streak >= REFUSED_STREAK_LIMIT:
                        log.warning("%d candidates in a row broke the scenario's realism constraints: the run ends", self._refused_streak)
                        stop = StopSearch(campaign_done=True)
                        break
                    continue
                self._refused_streak = 0
            try:
                self._check_budgets()
            except StopSearch as reached:
                stop = reached
                break
            ordinal = self.spent
            self.spent += 1
            stored = self._stored.get(candidate.key)
            if stored is not None:
                self.replayed += 1
                self._record(Trial(ordinal, candidate.vector, candidate.key, stored.fitness, stored.status, stored.reveals, stored.log_path,
                                   least_robustness(stored.properties), self._robustness_each(stored.properties), code_reached(stored.coverage)))
                self._learn(candidate.key)
                continue
            # Its id in the store, known now so that its log carries it: one number for an
            # evaluation in its log's name and in every command that shows or takes it.
            ids[ordinal] = self.store.new_evaluation_id()
            refused = self._refusal(candidate)
            if refused is not None:
                self._finish(ordinal, ids[ordinal], candidate, refused, None)
                continue
            to_fly[ordinal] = (candidate, Job.of(ordinal, self.space, candidate.vector, seed=self.seed, out_dir=self.out_dir,
                                                 name=evaluation_name(ids[ordinal]), options=self.options))
            self._pending += 1
        to_confirm: list[tuple[Job, EvaluationResult]] = []
        # A pair is confirmed on both sides where it reveals a difference (PairedFlights), not here.
        flights = self.pairs or self.executor
        flying_since = time.monotonic()
        for job, result in flights.run([job for _candidate, job in to_fly.values()]):
            if result.status == Status.VIOLATION and self.confirm and self.pairs is None:
                to_confirm.append((job, result))
            else:
                self._finish(job.key, ids[job.key], to_fly[job.key][0], result, job.concrete)
        for job, result in self._confirmed(to_confirm):
            self._finish(job.key, ids[job.key], to_fly[job.key][0], result, job.concrete)
        if to_fly:
            self._batches_s += time.monotonic() - flying_since
            self._batched += len(to_fly)
        self._pending = 0
        for candidate, _job in to_fly.values():
            self._learn(candidate.key)
        if stop is not None or any(c.key not in self._trials and c.key not in self._screened_out and c.key not in self._refused for c in candidates):
            raise stop or StopSearch(campaign_done=True)
        return [self._told(self._trials[c.key]) if c.key in self._trials else self._told_cheap(c.key) if c.key in self._screened_out
                else self._told_refused(self._refused[c.key]) for c in candidates]

    def _refusal(self, candidate: _Candidate) -> EvaluationResult | None:
        """The outcome of a candidate that breaks the scenario's realism constraints (None if it
        does not), worked out once a batch: the screen and the batch's loop both ask."""
        if candidate.key not in self._refusals:
            self._refusals[candidate.key] = infeasible(self.space, candidate.vector, seed=self.seed, sut=self.options.sut.name)
        return self._refusals[candidate.key]

    def _told_refused(self, fitness: float) -> float | list[float]:
        """What the optimizer hears of a screened run's infeasible candidate: its penalty."""
        return [fitness] * self.objectives if self.each_property else fitness

    def _learn(self, key: str) -> None:
        """The screen hears the real outcome of a candidate it flew cheaply (a flight that could
        not finish tells nothing of the screen's error)."""
        trial = self._trials.get(key)
        if self.screen is not None and trial is not None and trial.status not in COULD_NOT_FINISH and self.screen.knows(key):
            properties_scored = self.options.properties and trial.robustness is not None
            self.screen.learn(key, trial.vector, trial.robustness if properties_scored else unpenalized(trial.fitness, trial.status))

    def _screen(self, candidates: list[_Candidate]) -> set[str]:
        """The keys of this batch's candidates to screen out: of those that would fly (new to the
        run and the store, feasible), the ones their cheap flights rank not worth a real one."""
        new: dict[str, _Candidate] = {}
        for candidate in candidates:
            if (candidate.key in self._trials or candidate.key in self._screened_out or candidate.key in self._stored or candidate.key in new
                    or self._refusal(candidate) is not None):
                continue
            new[candidate.key] = candidate
        if not new:
            return set()
        flying = [(key, candidate.vector) for key, candidate in new.items()]
        self.screen.fly(flying)
        return set(new) - self.screen.choose(flying)

    def _told_cheap(self, key: str) -> float | list[float]:
        """What the optimizer hears of a candidate flown on the screen only: the real objective the
        screen predicts, or with one objective per property, each one's cheap robustness."""
        cheap = self._screened_out[key]
        if self.each_property:
            return [cheap.fitness if value is None else value for value in self._robustness_each(cheap.properties)]
        return self.screen.told(key)

    def _told(self, trial: Trial) -> float | list[float]:
        """The fitness the optimizer hears of (the stored one is the flight's own): with one
        objective per property, each one's robustness (a property not scored, in a flight that
        could not finish or was not flown, gets the flight's penalty)."""
        if self.each_property:
            return [trial.fitness if value is None else value for value in trial.robustness_each]
        told = self.objective_of(trial) if self.diversity is None else self.diversity.shared(trial, self._trials.values())
        return told if self.novelty is None else self.novelty.told(told, trial, self._trials.values())

    def _confirmed(self, violations: list[tuple[Job, EvaluationResult]]) -> list[tuple[Job, EvaluationResult]]:
        """Each violation with the outcome of flying it `confirm` more times (same scenario and
        seed); stored with it, the evaluation counts as flown once, costing one of the budget."""
        if not violations:
            return []
        again = {f"{job.name}-confirm{i + 1}": job for job, _result in violations for i in range(self.confirm)}
        outcomes: dict[str, list[EvaluationResult]] = {job.name: [] for job, _result in violations}
        jobs = [replace(job, key=number, name=name) for number, (name, job) in enumerate(again.items())]
        for job, result in self.executor.run(jobs):
            outcomes[again[job.name].name].append(result)
        confirmed = []
        for job, result in violations:
            flights = outcomes[job.name]
            confirmations = {"repeats": len(flights), "violations": sum(r.status == Status.VIOLATION for r in flights),
                             "fitness": [r.fitness for r in flights], "statuses": [str(r.status) for r in flights]}
            confirmed.append((job, replace(result, confirmations=confirmations)))
        return confirmed

    def _finish(self, ordinal: int, evaluation_id: int, candidate: _Candidate, result: EvaluationResult, concrete) -> None:
        self.store.add_evaluation(self.run_id, evaluation_id=evaluation_id, ordinal=ordinal, step=self._step.index, optimizer=self._step.optimizer,
                                  vector=candidate.vector, result=result, concrete=concrete)
        self.flown += 1 if result.status != Status.INFEASIBLE else 0
        reveals = result.differential["reveals"] if result.differential else None
        self._record(Trial(ordinal, candidate.vector, candidate.key, result.fitness, result.status, Reveal(reveals) if reveals else None,
                           result.log_path, least_robustness(result.properties), self._robustness_each(result.properties), code_reached(result.coverage)))
        self.on_result(result)
