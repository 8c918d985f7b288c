"""Screening: each batch of candidates flown first on a cheap model (the bundled autopilot,
configured like the subject), and on the real SUT only those the cheap flights rank most
promising, with a random share of the others so that the screen's blind spots are still
sampled. The optimizer hears the real outcome of what was flown for real and the cheap one of
what was screened out; the budget counts real flights only.

The screen's error is measured on the candidates flown both ways: the rank correlation between
the cheap and the real objective (Spearman), and its false negatives, real violations the cheap
flight called safe. Once enough candidates were flown both ways and the correlation is too low,
the screen has stopped predicting: the run says so and flies every candidate for real.
"""

from __future__ import annotations

import hashlib
import logging
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from harness.campaigns.problem import least_robustness
from harness.campaigns.store import Store
from harness.execution.executor import Executor, Job
from harness.flight.results import RunOptions
from harness.scenario.space import SearchSpace
from sut_adapter import SutConfig

log = logging.getLogger(__name__)

SCREENS = ("none", "bundled")


@dataclass(frozen=True)
class ScreenSettings:
    """How a campaign screens: the cheap SUT, the share of each batch flown for real as the most
    promising, the chance that each of the others is flown all the same, and when the screen
    counts as no longer predicting (min_correlation over at least min_pairs candidates)."""

    sut: SutConfig
    share: float = 0.3
    explore: float = 0.1
    min_pairs: int = 10
    min_correlation: float = 0.3

    def identity(self) -> dict[str, Any]:
        return {"sut": self.sut.identity(), "share": self.share, "explore": self.explore,
                "min_pairs": self.min_pairs, "min_correlation": self.min_correlation}


def screen_sut(subject: SutConfig) -> SutConfig:
    """The bundled autopilot configured like the subject: PX4's parameter names as the subject's
    (the bundled autopilot takes PX4's names, and accepts those it does not model without effect);
    none of the subject's seeded fault, which the cheap model is not to know of."""
    params = dict(subject.params) if subject.name in ("px4", "bundled") else {}
    return SutConfig("bundled", params)


@dataclass(frozen=True)
class CheapOutcome:
    """A candidate's cheap flight: what it scored, and the objective the search would hear."""

    fitness: float
    status: str
    properties: Mapping[str, Any]
    objective: float


@dataclass
class Screen:
    settings: ScreenSettings
    executor: Executor
    store: Store
    run_id: int
    seed: int
    out_dir: Path
    options: RunOptions
    properties: Sequence[Any] = ()  # the campaign's safety properties (their least robustness is the objective)
    _cheap: dict[str, CheapOutcome] = field(default_factory=dict)
    _chosen: dict[str, bool] = field(default_factory=dict)  # the screen's decision on each candidate it ranked
    _pairs: list[tuple[float, float]] = field(default_factory=list)  # (cheap, real) objective of candidates flown both ways
    fell_back: bool = False

    def __post_init__(self) -> None:
        for key, row in self.store.screen_flights(self.run_id).items():
            self._cheap[key] = self._outcome(row["fitness"], row["status"], row["properties"])
            if row["chosen"] is not None:
                self._chosen[key] = row["chosen"]

    def _outcome(self, fitness: float, status: str, properties: Mapping[str, Any]) -> CheapOutcome:
        return CheapOutcome(fitness, status, properties, objective(fitness, properties, self.properties))

    @property
    def flights(self) -> int:
        return len(self._cheap)

    def cheap(self, key: str) -> CheapOutcome:
        return self._cheap[key]

    def knows(self, key: str) -> bool:
        return key in self._cheap

    def fly(self, space: SearchSpace, candidates: Sequence[tuple[str, np.ndarray]]) -> None:
        """The cheap flight of each candidate not flown cheaply yet, stored with the run."""
        todo = [(key, x) for key, x in candidates if key not in self._cheap]
        options = replace(self.options, sut=self.settings.sut)
        jobs = [Job.of(index, space, x, seed=self.seed, out_dir=self.out_dir, name=f"screen-{key[:16]}", options=options)
                for index, (key, x) in enumerate(todo)]
        for job, result in self.executor.run(jobs):
            key = todo[job.key][0]
            self._cheap[key] = self._outcome(result.fitness, str(result.status), result.properties or {})
            self.store.add_screen_flight(self.run_id, key, result)

    def choose(self, keys: Sequence[str]) -> set[str]:
        """Of these candidates, all flown cheaply, the ones to fly for real: the most promising
        share by the cheap objective, and each of the others with the explore chance; every one
        once the screen has fallen back. A batch decided before (a resumed run) is decided alike;
        a new one by a generator seeded with the run's seed and the batch's candidates."""
        if all(key in self._chosen for key in keys):
            return {key for key in keys if self._chosen[key]}
        if self.fell_back:
            decided = {key: True for key in keys}
        else:
            batch = hashlib.sha256("".join(sorted(keys)).encode()).digest()
            rng = np.random.default_rng([self.seed, int.from_bytes(batch[:8], "little")])
            ranked = sorted(keys, key=lambda key: (self._cheap[key].objective, key))
            promising = max(1, math.ceil(self.settings.share * len(ranked)))
            decided = {key: index < promising or rng.random() < self.settings.explore for index, key in enumerate(ranked)}
        self._chosen.update(decided)
        self.store.screen_decisions(self.run_id, decided)
        return {key for key, chosen in decided.items() if chosen}

    @property
    def screened_out(self) -> int:
        return sum(not chosen for chosen in self._chosen.values())

    def learn(self, key: str, real_objective: float) -> None:
        """A candidate flown both ways; the screen falls back once it stops predicting."""
        self._pairs.append((self._cheap[key].objective, real_objective))
        correlation = self.rank_correlation
        if not self.fell_back and len(self._pairs) >= self.settings.min_pairs and correlation is not None and correlation < self.settings.min_correlation:
            self.fell_back = True
            log.warning("the screen stopped predicting: rank correlation %.2f with the real SUT over %d candidates flown both ways "
                        "(below %.2f); every candidate is flown for real from now on", correlation, len(self._pairs), self.settings.min_correlation)

    @property
    def rank_correlation(self) -> float | None:
        """Spearman's rank correlation of the cheap and the real objective over the candidates flown
        both ways (None: fewer than three, or one side constant)."""
        if len(self._pairs) < 3:
            return None
        from scipy.stats import spearmanr  # here: the command line need not import scipy to start

        cheap, real = zip(*self._pairs)
        if len(set(cheap)) < 2 or len(set(real)) < 2:
            return None
        return float(spearmanr(cheap, real).statistic)

    @property
    def false_negatives(self) -> int:
        """Real violations among the candidates flown both ways that the cheap flight called safe."""
        return sum(real < 0 <= cheap for cheap, real in self._pairs)

    def summary(self) -> dict[str, Any]:
        return {"flights": self.flights, "screened_out": self.screened_out, "pairs": len(self._pairs), "rank_correlation": self.rank_correlation,
                "false_negatives": self.false_negatives, "fell_back": self.fell_back}


def objective(fitness: float, properties: Mapping[str, Any], asked: Sequence[Any]) -> float:
    """What a flight gives the search to minimise: the least robustness of the safety properties
    asked where any was scored, else the flight's f (as CampaignProblem.objective_of)."""
    least = least_robustness(properties)
    return least if asked and least is not None else fitness
