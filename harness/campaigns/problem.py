"""The campaign's evaluation of an optimizer's candidates: a function from batches of vectors to
fitness values, which the campaign's search loop (campaign.run_sequence) calls between ask and tell.

It owns the loop's side effects: the store (replay of finished evaluations on resume), the
executor, the budgets. Within a run each distinct vector is flown at most once; asking again
(for instance a sequence step re-evaluating the best solutions it was seeded with) is answered
from memory and costs no budget.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from harness.campaigns.store import Store, vector_key
from harness.execution.executor import Executor, Job
from harness.flight.evaluation import EvaluationResult, RunOptions, infeasible
from harness.flight.fitness import Status
from harness.scenario.space import SearchSpace
from harness.search.termination import Progress, Termination

if TYPE_CHECKING:
    from harness.campaigns.pairs import PairedFlights


class StopSearch(Exception):
    """Raised by CampaignProblem.evaluate once the step's budget or the run's termination is reached
    (what it could evaluate of the batch is stored); ends the step's search loop."""

    def __init__(self, campaign_done: bool):
        self.campaign_done = campaign_done
        super().__init__("campaign termination reached" if campaign_done else "step budget reached")


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
    step: int = 0
    optimizer: str = ""
    step_limit: int | None = None
    confirm: int = 0  # re-flights of each violation, to tell a steady one from a flaky one
    pairs: PairedFlights | None = None  # each candidate flown against a reference SUT too, confirmed there

    def __post_init__(self) -> None:
        self._stored = self.store.evaluations(self.run_id)
        self._memory: dict[str, float] = {}
        self._history: dict[int, tuple[np.ndarray, float]] = {}
        self.spent = 0
        self.violations = 0
        self.flown = 0
        self.replayed = 0
        self.revealing = 0
        self._started = time.monotonic()

    @property
    def progress(self) -> Progress:
        return Progress(self.spent, time.monotonic() - self._started, self.violations, self.revealing)

    @property
    def history(self) -> list[tuple[np.ndarray, float]]:
        """Distinct vectors and their fitness in request order, however the executor finished them."""
        return [self._history[ordinal] for ordinal in sorted(self._history)]

    @property
    def best(self) -> tuple[np.ndarray, float] | None:
        return min(self.history, key=lambda entry: entry[1]) if self.history else None

    def _check_budgets(self) -> None:
        if self.termination.done(self.progress):
            raise StopSearch(campaign_done=True)
        if self.step_limit is not None and self.spent >= self.step_limit:
            raise StopSearch(campaign_done=False)

    def _record(self, ordinal: int, key: str, x: np.ndarray, fitness: float, status: Status, reveals: str | None) -> None:
        self._memory[key] = fitness
        self._history[ordinal] = (x, fitness)
        if status == Status.VIOLATION:
            self.violations += 1
        if reveals:
            self.revealing += 1

    def evaluate(self, vectors: list[np.ndarray]) -> list[float]:
        """Fitness for each vector, in order; raises StopSearch once a budget is used up."""
        results: list[float | None] = [None] * len(vectors)
        jobs: list[tuple[int, Job, np.ndarray, str, int]] = []
        stop: StopSearch | None = None
        for index, raw in enumerate(vectors):
            x = np.clip(np.asarray(raw, dtype=float), self.space.lower, self.space.upper)
            key = vector_key(x)
            if key in self._memory:
                results[index] = self._memory[key]
                continue
            if any(key == pending[3] for pending in jobs):
                continue
            try:
                self._check_budgets()
            except StopSearch as reached:
                stop = reached
                break
            ordinal = self.spent
            self.spent += 1
            stored = self._stored.get(key)
            if stored is not None:
                self.replayed += 1
                self._record(ordinal, key, x, stored.fitness, stored.status, stored.reveals)
                results[index] = stored.fitness
                continue
            refused = infeasible(self.space, x, seed=self.seed, sut=self.options.sut.name)
            if refused is not None:
                self._finish(ordinal, x, key, refused, None)
                results[index] = refused.fitness
                continue
            name = f"run{self.run_id}-eval{ordinal:05d}"
            jobs.append((index, Job.of(ordinal, self.space, x, seed=self.seed, out_dir=self.out_dir, name=name, options=self.options), x, key, ordinal))
        by_ordinal = {job.key: (index, x, key) for index, job, x, key, _ in jobs}
        to_confirm: list[tuple[Job, EvaluationResult]] = []
        # A pair is confirmed on both sides where it reveals a difference (PairedFlights), not here.
        flights = self.pairs or self.executor
        for job, result in flights.run([job for _, job, _, _, _ in jobs]):
            index, x, key = by_ordinal[job.key]
            results[index] = result.fitness
            if result.status == Status.VIOLATION and self.confirm and self.pairs is None:
                to_confirm.append((job, result))
            else:
                self._finish(job.key, x, key, result, job.concrete)
        for job, result in self._confirmed(to_confirm):
            index, x, key = by_ordinal[job.key]
            self._finish(job.key, x, key, result, job.concrete)
        # Duplicates inside one batch share the first one's result.
        for index, raw in enumerate(vectors):
            if results[index] is None:
                key = vector_key(np.clip(np.asarray(raw, dtype=float), self.space.lower, self.space.upper))
                if key in self._memory:
                    results[index] = self._memory[key]
        if stop is not None or any(r is None for r in results):
            raise stop or StopSearch(campaign_done=True)
        return results  # type: ignore[return-value]

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

    def _finish(self, ordinal: int, x: np.ndarray, key: str, result: EvaluationResult, concrete) -> None:
        self.store.add_evaluation(self.run_id, ordinal=ordinal, step=self.step, optimizer=self.optimizer, vector=x, result=result, concrete=concrete)
        self.flown += 1 if result.status != Status.INFEASIBLE else 0
        self._record(ordinal, key, x, result.fitness, result.status, result.differential["reveals"] if result.differential else None)
        self.on_result(result)
