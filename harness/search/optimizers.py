"""Optimizer adapters, one per library, each an ask/tell search over a search space: the
campaign owns the loop (asks, evaluates through its store and executor, tells), and an
optimizer knows nothing of stores, executors or budgets.

jMetalPy's NSGA-II and SMPSO are driven by their own methods, their run loop taken apart at the
evaluation; bayesian-optimization is ask/tell already (`suggest` / `register`); random search is
the baseline. Each is registered by the letter the paper uses in its sequential combinations.
"""

from __future__ import annotations

import copy
import logging
import random
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from jmetal.algorithm.multiobjective.nsgaii import NSGAII
from jmetal.algorithm.multiobjective.smpso import SMPSO
from jmetal.core.problem import FloatProblem
from jmetal.operator.crossover import SBXCrossover
from jmetal.operator.mutation import PolynomialMutation
from jmetal.operator.selection import BinaryTournamentSelection
from jmetal.util.archive import CrowdingDistanceArchive
from jmetal.util.generator import InjectorGenerator
from jmetal.util.termination_criterion import StoppingByEvaluations

from harness.scenario.space import SearchSpace

# jMetalPy logs every generation at DEBUG through its own handler; keep campaigns' stderr readable.
logging.getLogger("jmetal").setLevel(logging.WARNING)

BO_TARGET_CAP = 100.0  # BO's Gaussian process sees min(fitness, cap): penalties rank last without wrecking its scale


class Search(Protocol):
    """One optimizer's search, driven by the campaign: ask for candidates, tell their fitness."""

    def ask(self) -> list[np.ndarray]: ...

    def tell(self, vectors: list[np.ndarray], fitness: list[float] | list[list[float]]) -> None:
        """fitness: a number per vector, or with several objectives a list of them, all minimised."""


class Optimizer(Protocol):
    letter: str
    name: str

    def start(self, space: SearchSpace, *, seed: int, population: int, batch: int, initial: list[np.ndarray], objectives: int = 1) -> Search:
        """A search over space, beginning with the initial candidates (fewer than population: the
        rest is the optimizer's own). With several objectives NSGA-II and SMPSO rank by Pareto
        dominance; BO, a single-objective method, minimises the least of them."""


class _JMetalProblem(FloatProblem):
    def __init__(self, lower: np.ndarray, upper: np.ndarray, objectives: int = 1):
        super().__init__()
        self.lower_bound = [float(v) for v in lower]
        self.upper_bound = [float(v) for v in upper]
        self._objectives = objectives

    def number_of_objectives(self) -> int:
        return self._objectives

    def number_of_constraints(self) -> int:
        return 0

    def evaluate(self, solution):
        raise RuntimeError("solutions are evaluated in batches by the harness's evaluator")

    def name(self) -> str:
        return "stella-uav"


class _OwnStreams:
    """jMetalPy's operators draw from the global `random` stream (SMPSO from numpy's as well), and so
    may whatever runs between two generations: a Dask client, a process pool, a library. So a
    search keeps its own seeded copy of both streams, installed only while jMetalPy's code runs
    (in ask and tell); one seed then gives the same candidates on every executor, and the rest of
    the program's streams are left as they were."""

    def __init__(self, seed: int):
        self._random = random.Random(seed).getstate()
        self._numpy = np.random.RandomState(seed % 2**32).get_state()

    def _swap(self, state: tuple) -> tuple:
        mine = (random.getstate(), np.random.get_state())
        random.setstate(state[0])
        np.random.set_state(state[1])
        return mine

    @contextmanager
    def installed(self):
        outside = self._swap((self._random, self._numpy))
        try:
            yield
        finally:
            self._random, self._numpy = self._swap(outside)


def _injected(jproblem: _JMetalProblem, initial: list[np.ndarray]):
    solutions = []
    for x in initial:
        solution = jproblem.create_solution()
        solution.variables = [float(v) for v in x]
        solutions.append(solution)
    # InjectorGenerator pops from the end: reverse so the first seed goes in first.
    return InjectorGenerator(list(reversed(solutions)))


def _mutation(n: int) -> PolynomialMutation:
    return PolynomialMutation(probability=1.0 / n, distribution_index=20.0)


def nsgaii(space: SearchSpace, population: int, initial: list[np.ndarray], objectives: int = 1) -> NSGAII:
    """jMetalPy's NSGA-II with the paper's settings, its population starting with initial."""
    jproblem = _JMetalProblem(space.lower, space.upper, objectives)
    return NSGAII(
        problem=jproblem,
        population_size=population,
        # SBX makes two children of two parents: an odd population's last child would lack a partner.
        offspring_population_size=population + population % 2,
        mutation=_mutation(space.n_dimensions),
        crossover=SBXCrossover(probability=0.9, distribution_index=20.0),
        selection=BinaryTournamentSelection(),
        termination_criterion=StoppingByEvaluations(max_evaluations=10**9),
        population_generator=_injected(jproblem, initial),
    )


def smpso(space: SearchSpace, population: int, initial: list[np.ndarray], objectives: int = 1) -> SMPSO:
    """jMetalPy's SMPSO with the paper's settings, its swarm starting with initial."""
    jproblem = _JMetalProblem(space.lower, space.upper, objectives)
    return SMPSO(
        problem=jproblem,
        swarm_size=population,
        mutation=_mutation(space.n_dimensions),
        leaders=CrowdingDistanceArchive(100),
        termination_criterion=StoppingByEvaluations(max_evaluations=10**9),
        swarm_generator=_injected(jproblem, initial),
    )


def _vectors(solutions) -> list[np.ndarray]:
    return [np.array(solution.variables, dtype=float) for solution in solutions]


def _told(solutions, fitness: list[float] | list[list[float]]) -> None:
    for solution, value in zip(solutions, fitness):
        solution.objectives[:] = value if isinstance(value, list) else [value]


class _NSGAIISearch:
    """jMetalPy's NSGA-II generation loop (EvolutionaryAlgorithm.run and step) taken apart at its
    evaluation: ask makes a generation's offspring (the initial population first), tell ranks them in."""

    def __init__(self, algorithm: NSGAII, streams: _OwnStreams):
        self._algorithm, self._streams = algorithm, streams
        self._started = False
        self._offspring: list = []
        with streams.installed():
            algorithm.start_computing_time = time.time()
            algorithm.solutions = algorithm.create_initial_solutions()

    def ask(self) -> list[np.ndarray]:
        if not self._started:
            return _vectors(self._algorithm.solutions)
        with self._streams.installed():
            self._offspring = self._algorithm.reproduction(self._algorithm.selection(self._algorithm.solutions))
        return _vectors(self._offspring)

    def tell(self, vectors: list[np.ndarray], fitness: list[float]) -> None:
        algorithm = self._algorithm
        with self._streams.installed():
            if not self._started:
                _told(algorithm.solutions, fitness)
                algorithm.init_progress()
                self._started = True
            else:
                _told(self._offspring, fitness)
                algorithm.solutions = algorithm.replacement(algorithm.solutions, self._offspring)
                algorithm.update_progress()


class _SMPSOSearch:
    """jMetalPy's SMPSO loop (ParticleSwarmOptimization.run and step) taken apart at its
    evaluation: ask moves the swarm (the initial swarm first), tell updates the bests."""

    def __init__(self, algorithm: SMPSO, streams: _OwnStreams):
        self._algorithm, self._streams = algorithm, streams
        self._started = False
        with streams.installed():
            algorithm.start_computing_time = time.time()
            algorithm.solutions = algorithm.create_initial_solutions()

    def ask(self) -> list[np.ndarray]:
        if self._started:
            algorithm = self._algorithm
            with self._streams.installed():
                algorithm.update_velocity(algorithm.solutions)
                algorithm.update_position(algorithm.solutions)
                algorithm.perturbation(algorithm.solutions)
        return _vectors(self._algorithm.solutions)

    def tell(self, vectors: list[np.ndarray], fitness: list[float]) -> None:
        algorithm = self._algorithm
        _told(algorithm.solutions, fitness)
        with self._streams.installed():
            if not self._started:
                algorithm.init_progress()
                self._started = True
            else:
                algorithm.update_global_best(algorithm.solutions)
                algorithm.update_particle_best(algorithm.solutions)
                algorithm.update_progress()


@dataclass(frozen=True)
class NSGAIIOptimizer:
    letter: str = "N"
    name: str = "NSGAII"

    def start(self, space: SearchSpace, *, seed: int, population: int, batch: int, initial: list[np.ndarray], objectives: int = 1) -> Search:
        return _NSGAIISearch(nsgaii(space, population, initial, objectives), _OwnStreams(seed))


@dataclass(frozen=True)
class SMPSOOptimizer:
    letter: str = "P"
    name: str = "SMPSO"

    def start(self, space: SearchSpace, *, seed: int, population: int, batch: int, initial: list[np.ndarray], objectives: int = 1) -> Search:
        return _SMPSOSearch(smpso(space, population, initial, objectives), _OwnStreams(seed))


class _BOSearch:
    """Bayesian optimization; maximizes -fitness. The initial set (the seeds, then random points,
    `population` in all) goes first, `batch` at a time; then batches for parallel workers by the
    constant liar: suggestions are drawn from a copy that is told the best value so far at each one."""

    def __init__(self, space: SearchSpace, seed: int, population: int, batch: int, initial: list[np.ndarray]):
        from bayes_opt import BayesianOptimization

        self._names = [f"x{i:03d}" for i in range(space.n_dimensions)]
        self._optimizer = BayesianOptimization(
            f=None, pbounds={n: (float(lo), float(hi)) for n, lo, hi in zip(self._names, space.lower, space.upper)},
            random_state=seed % 2**32, verbose=0, allow_duplicate_points=True,
        )
        self._batch = batch
        self._queue = list(initial) + [self._vector(p) for p in self._optimizer.random_sample(max(0, population - len(initial)))]

    def _vector(self, params) -> np.ndarray:
        return np.array([params[n] for n in self._names], dtype=float)

    def ask(self) -> list[np.ndarray]:
        if self._queue:
            asked, self._queue = self._queue[: self._batch], self._queue[self._batch :]
            return asked
        liar = copy.deepcopy(self._optimizer)
        lie = self._optimizer.max["target"] if self._optimizer.max else 0.0
        suggestions = []
        for _ in range(self._batch):
            params = liar.suggest()
            suggestions.append(self._vector(params))
            liar.register(params=params, target=lie)
        return suggestions

    def tell(self, vectors: list[np.ndarray], fitness: list[float] | list[list[float]]) -> None:
        for x, value in zip(vectors, fitness):
            least = min(value) if isinstance(value, list) else value
            self._optimizer.register(params=dict(zip(self._names, x.tolist())), target=-min(least, BO_TARGET_CAP))


@dataclass(frozen=True)
class BOOptimizer:
    letter: str = "B"
    name: str = "BO"

    def start(self, space: SearchSpace, *, seed: int, population: int, batch: int, initial: list[np.ndarray], objectives: int = 1) -> Search:
        return _BOSearch(space, seed, population, batch, initial)


class _RandomSearch:
    def __init__(self, space: SearchSpace, seed: int, batch: int, initial: list[np.ndarray]):
        self._space, self._rng, self._batch = space, np.random.default_rng(seed), batch
        self._initial = list(initial)

    def ask(self) -> list[np.ndarray]:
        if self._initial:
            asked, self._initial = self._initial, []
            return asked
        return list(self._space.sample(self._rng, self._batch))

    def tell(self, vectors: list[np.ndarray], fitness: list[float] | list[list[float]]) -> None:
        pass


@dataclass(frozen=True)
class RandomSearch:
    letter: str = "R"
    name: str = "RANDOM"

    def start(self, space: SearchSpace, *, seed: int, population: int, batch: int, initial: list[np.ndarray], objectives: int = 1) -> Search:
        return _RandomSearch(space, seed, batch, initial)


OPTIMIZERS: dict[str, Optimizer] = {o.letter: o for o in (NSGAIIOptimizer(), SMPSOOptimizer(), BOOptimizer(), RandomSearch())}
NAMES = {o.name: o.letter for o in OPTIMIZERS.values()}


def parse_algorithm(text: str) -> str:
    """'NSGAII', 'SMPSO', 'BO', 'RANDOM', or a combination string of N, P, B, R such as 'NPB'."""
    upper = text.upper()
    if upper in NAMES:
        return NAMES[upper]
    if upper and all(letter in OPTIMIZERS for letter in upper):
        return upper
    raise ValueError(f"unknown algorithm {text!r}: use {', '.join(NAMES)} or a string of {''.join(OPTIMIZERS)} such as NPB")
