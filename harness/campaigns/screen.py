"""Screening: each batch of candidates flown first on a cheap model (the bundled autopilot,
configured like the subject), and on the real SUT only those the cheap flights rank most
promising, with a random share of the others so that the screen's blind spots are still
sampled. The optimizer hears the real outcome of what was flown for real and the cheap one of
what was screened out; the budget counts real flights only.

With the learned correction (harness/campaigns/residual.py), the candidates flown both ways so
far, in this run and in the store's earlier runs of the same scenario, train a model of the real
clearance on top of the cheap one; the screen then ranks by the real clearance to be expected
with some luck (two standard deviations below the prediction), and the optimizer hears the
prediction of what was screened out. The correction can also mislead (measured on PX4: a rank
correlation of 0.95 of the cheap flights fell to 0.38 corrected in one Table III scenario, and
rose from 0.44 to 0.78 in another), so it is judged as it goes, prequentially: on this run's
candidates flown both ways that it had predicted before their real flights, once there are
min_pairs of them, the screen ranks by whichever of the two ranked those better, and the
optimizer hears what it ranks by.

The screen ranks by clearance, the objective without the penalty of a mission not performed.
Its error is measured on the candidates flown both ways: the rank correlation between the cheap
(and the corrected) clearance and the real one (Spearman), and the false negatives,
real violations that the cheap flight (and the correction) called safe. Once enough candidates
were flown both ways and the correlation of what the screen ranks by is too low, the screen has
stopped predicting: the run says so and flies every candidate for real.
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
from harness.campaigns.residual import Pair, Prediction, ResidualModel
from harness.campaigns.store import Store
from harness.execution.executor import Executor, Job
from harness.flight.fitness import unpenalized
from harness.flight.results import RunOptions
from harness.scenario.space import SearchSpace
from sut_adapter import SutConfig

log = logging.getLogger(__name__)

SCREENS = ("none", "bundled")
CORRECTIONS = ("gp", "none")


@dataclass(frozen=True)
class ScreenSettings:
    """How a campaign screens: the cheap SUT, the share of each batch flown for real as the most
    promising, the chance that each of the others is flown all the same, when the screen counts
    as no longer predicting (min_correlation over at least min_pairs candidates), and the learned
    correction ("gp", trained once min_train candidates were flown both ways, or "none")."""

    sut: SutConfig
    share: float = 0.3
    explore: float = 0.1
    min_pairs: int = 10
    min_correlation: float = 0.3
    correction: str = "gp"
    min_train: int = 5

    def identity(self) -> dict[str, Any]:
        # Stores screened before the correction existed resume with --screen-correction none.
        corrected = {"correction": self.correction, "min_train": self.min_train} if self.correction != "none" else {}
        return {"sut": self.sut.identity(), "share": self.share, "explore": self.explore,
                "min_pairs": self.min_pairs, "min_correlation": self.min_correlation, **corrected}


def screen_sut(subject: SutConfig, drive: str) -> SutConfig:
    """The bundled autopilot configured like the subject, none of the subject's seeded fault,
    which the cheap model is not to know of:

    * a PX4 subject's parameters as given (the bundled autopilot takes PX4's names, and accepts
      those it does not model without effect), calibrated to PX4's collision prevention: in the
      pilot drive it acts on the sticks' acceleration as PX4's does since v1.15 (CP_STICK_ACCEL),
      and in a mission not at all, as PX4's acts in Position mode only (docs/screening.md);
    * an ArduPilot subject's mapped onto their counterparts, by drive
      (sut_adapter/ardupilot.py: bundled_equivalent);
    * a bundled subject's as given; another SUT's none."""
    if subject.name == "ardupilot":
        from sut_adapter.ardupilot import bundled_equivalent

        return SutConfig("bundled", bundled_equivalent(subject.params, drive))
    if subject.name == "px4":
        return SutConfig("bundled", {**subject.params, **({"CP_STICK_ACCEL": 1} if drive == "pilot" else {"CP_DIST": -1.0})})
    return SutConfig("bundled", dict(subject.params) if subject.name == "bundled" else {})


@dataclass(frozen=True)
class CheapOutcome:
    """A candidate's cheap flight: what it scored, the objective the search would hear of it, and
    its clearance (the objective without a mission's penalty), which the screen ranks by."""

    fitness: float
    status: str
    properties: Mapping[str, Any]
    objective: float
    clearance: float


@dataclass(frozen=True)
class _FlownBothWays:
    """A candidate's cheap clearance, what the screen predicted of its real one when it chose it
    (the cheap one where no correction was trained yet) and its real clearance."""

    cheap: float
    predicted: float
    real: float
    corrected: bool = False  # predicted by a trained correction, not the cheap clearance itself


@dataclass
class Screen:
    settings: ScreenSettings
    executor: Executor
    store: Store
    run_id: int
    seed: int
    out_dir: Path
    options: RunOptions
    space: SearchSpace
    properties: Sequence[Any] = ()  # the campaign's safety properties (their least robustness is the objective)
    # Whether the cheap objective means what the real one does; the clearance of one cheap flight
    # does not mean the difference of a subject's and a reference's (--objective difference).
    comparable: bool = True
    _cheap: dict[str, CheapOutcome] = field(default_factory=dict)
    _chosen: dict[str, bool] = field(default_factory=dict)  # the screen's decision on each candidate it ranked
    _predicted: dict[str, Prediction] = field(default_factory=dict)  # the correction's prediction where one was trained
    _pairs: dict[str, _FlownBothWays] = field(default_factory=dict)  # by key, in the order they were learned
    _ranked_by_cheap: set[str] = field(default_factory=set)  # candidates ranked by the cheap flights though a correction predicted them
    # The pairs learned from other stores, the store's earlier runs' of the scenario, and this run's.
    _training: list[Pair] = field(default_factory=list)
    _learned: int = 0  # of them from other stores (--screen-learn-from)
    fell_back: bool = False

    def __post_init__(self) -> None:
        for key, row in self.store.screen_flights(self.run_id).items():
            self._cheap[key] = self._outcome(row["fitness"], row["status"], row["properties"])
            if row["chosen"] is not None:
                self._chosen[key] = row["chosen"]
            if row["predicted"] is not None:
                self._predicted[key] = Prediction(*row["predicted"])
            if row["ranked_by_cheap"]:
                self._ranked_by_cheap.add(key)
        if self.settings.correction != "none":
            earlier = self.store.earlier_screen_pairs(self.run_id)
            self._training = [Pair(f"{row['origin']}:{row['key']}", np.asarray(row["vector"], dtype=float),
                                   clearance(row["cheap_fitness"], row["cheap_status"], row["cheap_properties"], self.properties),
                                   clearance(row["fitness"], row["status"], row["properties"], self.properties))
                              for row in earlier]
            self._learned = sum(row["learned"] for row in earlier)

    def _outcome(self, fitness: float, status: str, properties: Mapping[str, Any]) -> CheapOutcome:
        return CheapOutcome(fitness, status, properties, objective(fitness, properties, self.properties),
                            clearance(fitness, status, properties, self.properties))

    @property
    def flights(self) -> int:
        return len(self._cheap)

    def cheap(self, key: str) -> CheapOutcome:
        return self._cheap[key]

    def knows(self, key: str) -> bool:
        return key in self._cheap

    def told(self, key: str) -> float:
        """What the optimizer hears of a candidate screened out: the cheap flight's objective, or
        where a correction was trained, the real clearance it predicted, with the penalty of the
        cheap flight's mission not performed unless it predicts a violation."""
        cheap = self._cheap[key]
        if key not in self._predicted or key in self._ranked_by_cheap:
            return cheap.objective
        predicted = self._predicted[key].objective
        return predicted + (cheap.objective - cheap.clearance if predicted >= 0.0 else 0.0)

    def fly(self, candidates: Sequence[tuple[str, np.ndarray]]) -> None:
        """The cheap flight of each candidate not flown cheaply yet, stored with the run."""
        todo = [(key, x) for key, x in candidates if key not in self._cheap]
        options = replace(self.options, sut=self.settings.sut)
        jobs = [Job.of(index, self.space, x, seed=self.seed, out_dir=self.out_dir, name=f"screen-{key[:16]}", options=options)
                for index, (key, x) in enumerate(todo)]
        for job, result in self.executor.run(jobs):
            key = todo[job.key][0]
            self._cheap[key] = self._outcome(result.fitness, str(result.status), result.properties or {})
            self.store.add_screen_flight(self.run_id, key, result)

    def choose(self, candidates: Sequence[tuple[str, np.ndarray]]) -> set[str]:
        """Of these candidates, all flown cheaply, the ones to fly for real: the most promising
        share, and each of the others with the explore chance; every one once the screen has
        fallen back, and, where the cheap objective is not comparable with the real one, until a
        correction is trained to translate it. Promising is the least cheap objective, or with a correction trained, the
        least real objective to be expected with some luck (Prediction.optimistic). A batch decided before (a resumed run) is decided
        alike; a new one by a generator seeded with the run's seed and the batch's candidates."""
        keys = [key for key, _x in candidates]
        if all(key in self._chosen for key in keys):
            return {key for key in keys if self._chosen[key]}
        predicted: dict[str, Prediction] = {}
        model = None if self.fell_back else self._model()
        by_cheap = False
        if self.fell_back or (model is None and not self.comparable):
            decided = {key: True for key in keys}
        else:
            if model is not None:
                predicted = dict(zip(keys, model.predict(np.array([x for _key, x in candidates]), np.array([self._cheap[key].clearance for key in keys]))))
                by_cheap = self.comparable and not self.correction_ranks_better
            batch = hashlib.sha256("".join(sorted(keys)).encode()).digest()
            rng = np.random.default_rng([self.seed, int.from_bytes(batch[:8], "little")])
            ranked = sorted(keys, key=lambda key: (predicted[key].optimistic, key) if predicted and not by_cheap
                            else (self._cheap[key].clearance, key))
            promising = max(1, math.ceil(self.settings.share * len(ranked)))
            decided = {key: index < promising or rng.random() < self.settings.explore for index, key in enumerate(ranked)}
        self._chosen.update(decided)
        self._predicted.update(predicted)
        if by_cheap:
            self._ranked_by_cheap.update(keys)
        self.store.screen_decisions(self.run_id, decided, {key: (p.mean, p.sd) for key, p in predicted.items()}, by_cheap)
        return {key for key, chosen in decided.items() if chosen}

    @property
    def correction_ranks_better(self) -> bool:
        """Whether the correction ranked the candidates it predicted at least as well as their
        cheap flights did (Spearman, against their real flights), or too few were judged yet
        (min_pairs) to say otherwise."""
        judged = [pair for pair in self._pairs.values() if pair.corrected]
        if len(judged) < self.settings.min_pairs:
            return True
        corrected = _spearman([(pair.predicted, pair.real) for pair in judged])
        cheap = _spearman([(pair.cheap, pair.real) for pair in judged])
        return corrected is not None and (cheap is None or corrected >= cheap)

    def _model(self) -> ResidualModel | None:
        if self.settings.correction == "none" or len(self._training) < self.settings.min_train:
            return None
        return ResidualModel(self.space.lower, self.space.upper, self._training, self.seed)

    @property
    def screened_out(self) -> int:
        return sum(not chosen for chosen in self._chosen.values())

    def learn(self, key: str, x: np.ndarray, real_clearance: float) -> None:
        """A candidate flown both ways, with its real clearance: training for the correction; the
        screen falls back once what it ranks by stops predicting."""
        cheap = self._cheap[key].clearance
        self._pairs[key] = (_FlownBothWays(cheap, self._predicted[key].objective, real_clearance, corrected=True) if key in self._predicted
                            else _FlownBothWays(cheap, cheap, real_clearance))
        if self.settings.correction != "none":
            self._training.append(Pair(f"{self.run_id}:{key}", np.asarray(x, dtype=float), cheap, real_clearance))
        # The screen stops predicting once both of what it may rank by rank badly (the cheap
        # clearance alone where it cannot mean the real objective, or there is no correction).
        candidates = ([self.corrected_rank_correlation] if self.settings.correction != "none" else []) + ([self.rank_correlation] if self.comparable else [])
        correlations = [c for c in candidates if c is not None]
        correlation = max(correlations) if correlations else None
        if not self.fell_back and len(self._pairs) >= self.settings.min_pairs and correlation is not None and correlation < self.settings.min_correlation:
            self.fell_back = True
            log.warning("the screen stopped predicting: rank correlation %.2f with the real SUT over %d candidates flown both ways "
                        "(below %.2f); every candidate is flown for real from now on", correlation, len(self._pairs), self.settings.min_correlation)

    @property
    def rank_correlation(self) -> float | None:
        """Spearman's rank correlation of the cheap and the real clearance over the candidates flown
        both ways (None: fewer than three, or one side constant)."""
        return _spearman([(pair.cheap, pair.real) for pair in self._pairs.values()])

    @property
    def corrected_rank_correlation(self) -> float | None:
        """The same of what the screen predicted when it chose each candidate."""
        return _spearman([(pair.predicted, pair.real) for pair in self._pairs.values()])

    @property
    def false_negatives(self) -> int:
        """Real violations among the candidates flown both ways that the cheap flight called safe."""
        return sum(pair.real < 0 <= pair.cheap for pair in self._pairs.values())

    @property
    def corrected_false_negatives(self) -> int:
        """Real violations among them that the screen's prediction called safe."""
        return sum(pair.real < 0 <= pair.predicted for pair in self._pairs.values())

    def summary(self) -> dict[str, Any]:
        corrected = ({"corrected_rank_correlation": self.corrected_rank_correlation, "corrected_false_negatives": self.corrected_false_negatives,
                      "training_pairs": len(self._training), "learned_pairs": self._learned, "ranked_by_cheap": len(self._ranked_by_cheap)}
                     if self.settings.correction != "none" else {})
        return {"flights": self.flights, "screened_out": self.screened_out, "pairs": len(self._pairs), "rank_correlation": self.rank_correlation,
                "false_negatives": self.false_negatives, **corrected, "fell_back": self.fell_back}


def _spearman(pairs: Sequence[tuple[float, float]]) -> float | None:
    if len(pairs) < 3:
        return None
    from scipy.stats import spearmanr  # here: the command line need not import scipy to start

    first, second = zip(*pairs)
    if len(set(first)) < 2 or len(set(second)) < 2:
        return None
    return float(spearmanr(first, second).statistic)


def objective(fitness: float, properties: Mapping[str, Any], asked: Sequence[Any]) -> float:
    """What a flight gives the search to minimise: the least robustness of the safety properties
    asked where any was scored, else the flight's f (as CampaignProblem.objective_of)."""
    least = least_robustness(properties)
    return least if asked and least is not None else fitness


def clearance(fitness: float, status: str, properties: Mapping[str, Any], asked: Sequence[Any]) -> float:
    """What the screen ranks, predicts and measures its error by: the objective without the
    penalty of a mission not performed. A pilot that collision prevention held back 1.6 m from an
    obstacle came close, whatever became of the mission, and the real SUT may come closer still;
    a violation is never behind a penalty (harness/flight/fitness.py), so f < 0 means the same."""
    least = least_robustness(properties)
    return least if asked and least is not None else unpenalized(fitness, status)
