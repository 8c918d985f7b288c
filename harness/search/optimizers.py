"""Optimizer adapters, one per library; each sees only Problem.evaluate (vectors -> fitness).

jMetalPy's algorithms own their generation loop, so they are driven through a batch Evaluator
instead of ask/tell; bayesian-optimization is ask/tell (`suggest` / `register`); random search is
the baseline. Each is registered by the letter the paper uses in its sequential combinations.
"""

from __future__ import annotations

import copy
import logging
import random
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np
from jmetal.algorithm.multiobjective.nsgaii import NSGAII
from jmetal.algorithm.multiobjective.smpso import SMPSO
from jmetal.core.problem import FloatProblem
from jmetal.operator.crossover import SBXCrossover
from jmetal.operator.mutation import PolynomialMutation
from jmetal.operator.selection import BinaryTournamentSelection
from jmetal.util.archive import CrowdingDistanceArchive
from jmetal.util.evaluator import Evaluator
from jmetal.util.generator import InjectorGenerator
from jmetal.util.termination_criterion import StoppingByEvaluations

from harness.search.problem import Problem

# jMetalPy logs every generation at DEBUG through its own handler; keep campaigns' stderr readable.
logging.getLogger("jmetal").setLevel(logging.WARNING)

BO_TARGET_CAP = 100.0  # BO's Gaussian process sees min(fitness, cap): penalties rank last without wrecking its scale


class Optimizer(Protocol):
    letter: str
    name: str

    def search(self, problem: Problem, *, seed: int, population: int, batch: int, initial: list[np.ndarray]) -> None:
        """Evaluate candidates through problem.evaluate until it raises StopSearch."""


class _JMetalProblem(FloatProblem):
    def __init__(self, lower: np.ndarray, upper: np.ndarray):
        super().__init__()
        self.lower_bound = [float(v) for v in lower]
        self.upper_bound = [float(v) for v in upper]

    def number_of_objectives(self) -> int:
        return 1

    def number_of_constraints(self) -> int:
        return 0

    def evaluate(self, solution):
        raise RuntimeError("solutions are evaluated in batches by the harness's evaluator")

    def name(self) -> str:
        return "stella-uav"


class _OwnStreams:
    """jMetalPy's operators draw from the global `random` stream (SMPSO from numpy's as well), and so
    may whatever runs between two generations: a Dask client, a process pool, a library. So an
    optimizer keeps its own seeded copy of both streams, installed while jMetalPy runs and put aside
    while the harness evaluates; one seed then gives the same candidates on every executor, and the
    rest of the program's streams are left as they were."""

    def __init__(self, seed: int):
        self._random = random.Random(seed).getstate()
        self._numpy = np.random.RandomState(seed % 2**32).get_state()
        self._outside: tuple | None = None

    def _swap(self, state: tuple) -> tuple:
        mine = (random.getstate(), np.random.get_state())
        random.setstate(state[0])
        np.random.set_state(state[1])
        return mine

    @contextmanager
    def installed(self):
        self._outside = self._swap((self._random, self._numpy))
        try:
            yield
        finally:
            self._random, self._numpy = self._swap(self._outside)

    @contextmanager
    def put_aside(self):
        mine = self._swap(self._outside)
        try:
            yield
        finally:
            self._outside = self._swap(mine)


class _BatchEvaluator(Evaluator):
    def __init__(self, evaluate: Callable[[list[np.ndarray]], list[float]], streams: _OwnStreams):
        self._evaluate = evaluate
        self._streams = streams

    def evaluate(self, solution_list, problem):
        with self._streams.put_aside():
            values = self._evaluate([np.array(s.variables, dtype=float) for s in solution_list])
        for solution, value in zip(solution_list, values):
            solution.objectives[0] = value
        return solution_list


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


@dataclass(frozen=True)
class NSGAIIOptimizer:
    letter: str = "N"
    name: str = "NSGAII"

    def search(self, problem: Problem, *, seed: int, population: int, batch: int, initial: list[np.ndarray]) -> None:
        streams = _OwnStreams(seed)
        jproblem = _JMetalProblem(problem.space.lower, problem.space.upper)
        algorithm = NSGAII(
            problem=jproblem,
            population_size=population,
            # SBX makes two children of two parents: an odd population's last child would lack a partner.
            offspring_population_size=population + population % 2,
            mutation=_mutation(problem.space.n_dimensions),
            crossover=SBXCrossover(probability=0.9, distribution_index=20.0),
            selection=BinaryTournamentSelection(),
            termination_criterion=StoppingByEvaluations(max_evaluations=10**9),
            population_generator=_injected(jproblem, initial),
            population_evaluator=_BatchEvaluator(problem.evaluate, streams),
        )
        with streams.installed():
            algorithm.run()


@dataclass(frozen=True)
class SMPSOOptimizer:
    letter: str = "P"
    name: str = "SMPSO"

    def search(self, problem: Problem, *, seed: int, population: int, batch: int, initial: list[np.ndarray]) -> None:
        streams = _OwnStreams(seed)
        jproblem = _JMetalProblem(problem.space.lower, problem.space.upper)
        algorithm = SMPSO(
            problem=jproblem,
            swarm_size=population,
            mutation=_mutation(problem.space.n_dimensions),
            leaders=CrowdingDistanceArchive(100),
            termination_criterion=StoppingByEvaluations(max_evaluations=10**9),
            swarm_generator=_injected(jproblem, initial),
            swarm_evaluator=_BatchEvaluator(problem.evaluate, streams),
        )
        with streams.installed():
            algorithm.run()


@dataclass(frozen=True)
class BOOptimizer:
    """Bayesian optimization; maximizes -fitness. Batches for parallel workers by the constant
    liar: suggestions are drawn from a copy that is told the best value so far at each one."""

    letter: str = "B"
    name: str = "BO"

    def search(self, problem: Problem, *, seed: int, population: int, batch: int, initial: list[np.ndarray]) -> None:
        from bayes_opt import BayesianOptimization

        space = problem.space
        names = [f"x{i:03d}" for i in range(space.n_dimensions)]
        optimizer = BayesianOptimization(
            f=None, pbounds={n: (float(lo), float(hi)) for n, lo, hi in zip(names, space.lower, space.upper)},
            random_state=seed % 2**32, verbose=0, allow_duplicate_points=True,
        )

        def to_vector(params) -> np.ndarray:
            return np.array([params[n] for n in names], dtype=float)

        def tell(vectors: list[np.ndarray]) -> None:
            for x, fitness in zip(vectors, problem.evaluate(vectors)):
                optimizer.register(params=dict(zip(names, x.tolist())), target=-min(fitness, BO_TARGET_CAP))

        # The initial set: the seeds (BO's probes) and then random points, `population` in all.
        start = list(initial) + [to_vector(p) for p in optimizer.random_sample(max(0, population - len(initial)))]
        for offset in range(0, len(start), batch):
            tell(start[offset : offset + batch])
        while True:
            liar = copy.deepcopy(optimizer)
            lie = optimizer.max["target"] if optimizer.max else 0.0
            suggestions = []
            for _ in range(batch):
                params = liar.suggest()
                suggestions.append(to_vector(params))
                liar.register(params=params, target=lie)
            tell(suggestions)


@dataclass(frozen=True)
class RandomSearch:
    letter: str = "R"
    name: str = "RANDOM"

    def search(self, problem: Problem, *, seed: int, population: int, batch: int, initial: list[np.ndarray]) -> None:
        rng = np.random.default_rng(seed)
        if initial:
            problem.evaluate(list(initial))
        while True:
            problem.evaluate(list(problem.space.sample(rng, batch)))


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
