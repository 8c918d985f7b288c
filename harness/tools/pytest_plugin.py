"""The pytest plugin (entry point `pytest11`): regression cases as test items, and fixtures for
hand-written scenario tests.

* Every `NAME.regression.json` file is collected as one item, `FILE::NAME`; it flies the case
  through the harness and fails with what happened (`harness.campaigns.regression.verdict`). The MCAP
  log's path goes into the JUnit XML as the property `stella_log`.
* `fly(scenario, seed=0, sut=None, sut_params=None, drive=None, **values)` flies a logical scenario (a
  concrete one sampled with the seed), a concrete scenario or a regression case and returns
  the `EvaluationResult`; `values` set search-space dimensions by name, `__` standing for `.`
  (`obstacle_1__north_m=30.0`).
* `@pytest.mark.scenario(PATH, seed=..., **values)` names what the `flight` fixture flies.
"""

from __future__ import annotations

import threading
from concurrent.futures import Future
from dataclasses import replace
from pathlib import Path
from statistics import fmean
from typing import Any, Callable, Iterator, Mapping

import numpy as np
import pytest

from harness.campaigns.regression import EXPECTATIONS, SUFFIX, Regression, load_regression, verdict
from harness.errors import InputError
from harness.execution.executor import Executor, Job, run_job
from harness.execution.local import LocalExecutor
from harness.flight.evaluation import evaluate, infeasible
from harness.flight.results import EvaluationResult, RunOptions
from harness.flight.logs import slug
from harness.scenario.documents import load_json
from harness.scenario.logical import DRIVES, load_logical
from harness.scenario.profile import load_profile
from harness.scenario.space import CONCRETE_FORMAT, SearchSpace
from harness.scenario.world import load_concrete
from sut_adapter import SutConfig

FLIGHTS = pytest.StashKey["Flights"]()


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("stella", "Stella UAV scenario flights")
    group.addoption("--stella-sut", default=None, help="fly every regression case against this SUT instead of the one its file names")
    group.addoption("--stella-drive", default=None, choices=DRIVES,
                    help="fly every case and `fly` scenario with this drive (mission or pilot) instead of the one its scenario names")
    group.addoption("--stella-px4-bin", default=None, help="the px4 binary or its build folder, for cases flown against PX4 SITL (default: $STELLA_PX4_BIN)")
    group.addoption("--stella-autopilot-dir", default=None, help="fly cases of the bundled autopilot with the `autopilot` package in this folder (a build of "
                                                                 "`stella sut build bundled` or `stella mutants build`)")
    group.addoption("--stella-workers", type=int, default=1, help="fly regression cases in parallel with this many local workers")
    group.addoption("--stella-repeat", type=int, default=1, help="fly each regression case N times and report the spread of its fitness")
    group.addoption("--stella-out", default=None, help="folder for the flights' MCAP logs (default: stella-logs/ in the rootdir)")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "scenario(path, seed=0, sut=None, **values): the scenario the `flight` fixture flies")
    config.stash[FLIGHTS] = Flights(config)


def pytest_collect_file(file_path: Path, parent: pytest.Collector) -> pytest.Collector | None:
    if file_path.name.endswith(SUFFIX):
        return RegressionFile.from_parent(parent, path=file_path)
    return None


@pytest.hookimpl(tryfirst=True)
def pytest_runtestloop(session: pytest.Session) -> None:
    if not session.config.option.collectonly:
        session.config.stash[FLIGHTS].start([item for item in session.items if isinstance(item, RegressionItem)])


def pytest_sessionfinish(session: pytest.Session) -> None:
    session.config.stash[FLIGHTS].close()


def pytest_terminal_summary(terminalreporter: Any, config: pytest.Config) -> None:
    flights = config.stash[FLIGHTS]
    if flights.repeat > 1 and flights.spreads:
        terminalreporter.section("stella: fitness spread over repeats")
        for name, (spread, values) in sorted(flights.spreads.items()):
            terminalreporter.write_line(f"{name}: spread {spread:.6f} over {len(values)} repeats (mean fitness {fmean(values):.6f})")


class RegressionFailure(Exception):
    """A regression case that did not meet its expectation; the message says what happened."""


class RegressionFile(pytest.File):
    def collect(self) -> Iterator[pytest.Item]:
        try:
            regression = load_regression(self.path, self.config.getoption("stella_drive"))
        except InputError as error:
            raise self.CollectError(str(error)) from None
        yield RegressionItem.from_parent(self, name=regression.name, regression=regression)


class RegressionItem(pytest.Item):
    def __init__(self, *, regression: Regression, **kwargs: Any):
        super().__init__(**kwargs)
        self.regression = regression

    def runtest(self) -> None:
        flights = self.config.stash[FLIGHTS]
        results = flights.results(self)
        self.user_properties.append(("stella_expect", self.regression.expect))
        for index, result in enumerate(results):
            suffix = "" if len(results) == 1 else f"_{index + 1}"
            self.user_properties.append((f"stella_log{suffix}", result.log_path or ""))
            self.user_properties.append((f"stella_fitness{suffix}", repr(result.fitness)))
        fitnesses = [result.fitness for result in results]
        if len(results) > 1:
            spread = max(fitnesses) - min(fitnesses)
            flights.spreads[self.nodeid] = (spread, fitnesses)
            self.user_properties.append(("stella_fitness_spread", repr(spread)))
        failures = [(i, message) for i, result in enumerate(results)
                    if (message := verdict(self.regression.expect, result, self.regression.safety_distance_m, self.regression.reference))]
        if not failures:
            return
        expectation = f"{self.regression.name}: {EXPECTATIONS[self.regression.expect]}"
        if len(results) == 1:
            raise RegressionFailure(f"{expectation}\n{failures[0][1]}")
        lines = [f"repeat {i + 1}/{len(results)}: {message}" for i, message in failures]
        flaky = " (flaky: the other repeats met it)" if len(failures) < len(results) else ""
        raise RegressionFailure("\n".join([f"{expectation}{flaky}", *lines]))

    def repr_failure(self, excinfo: pytest.ExceptionInfo[BaseException], style: Any = None) -> str:
        if isinstance(excinfo.value, RegressionFailure):
            return str(excinfo.value)
        return str(super().repr_failure(excinfo, style=style))

    def reportinfo(self) -> tuple[Path, int | None, str]:
        return self.path, None, f"{self.regression.name} (expect {self.regression.expect})"


class Flights:
    """Flies regression cases: one after another in this process, or all at once through the
    local executor when --stella-workers > 1 (each item then waits for its own results)."""

    def __init__(self, config: pytest.Config):
        self.workers: int = config.getoption("stella_workers")
        self.repeat: int = config.getoption("stella_repeat")
        if self.workers < 1 or self.repeat < 1:
            raise pytest.UsageError("--stella-workers and --stella-repeat must be at least 1")
        self.sut_override: str | None = config.getoption("stella_sut")
        self.drive: str | None = config.getoption("stella_drive")
        self.px4_bin: str | None = config.getoption("stella_px4_bin")
        self.autopilot_dir: str | None = config.getoption("stella_autopilot_dir")
        out = config.getoption("stella_out")
        self.out_dir = Path(out) if out else config.rootpath / "stella-logs"
        self.spreads: dict[str, tuple[float, list[float]]] = {}
        self._futures: dict[str, list[Future]] = {}
        self._executor: Executor | None = None
        self._thread: threading.Thread | None = None

    def options(self, regression: Regression) -> RunOptions:
        sut = self.sut_override or regression.sut.name
        return replace(self.run_options(sut, regression.sut.params, regression.sut.fault if sut == "bundled" else None), properties=regression.properties)

    def run_options(self, sut: str, params: Mapping[str, float], fault: str | None = None) -> RunOptions:
        return RunOptions(sut=SutConfig(sut, dict(params), fault, self.px4_bin if sut == "px4" else None,
                                        autopilot_dir=self.autopilot_dir if sut == "bundled" else None))

    def names(self, regression: Regression) -> list[str]:
        return [regression.name] if self.repeat == 1 else [f"{regression.name}-repeat{i + 1}" for i in range(self.repeat)]

    def refusal(self, regression: Regression) -> EvaluationResult | None:
        """The infeasible result of a case that breaks a realism constraint: it is not flown."""
        return infeasible(regression.space, regression.x, seed=regression.seed, sut=self.options(regression).sut.name)

    def jobs(self, item: RegressionItem, first_key: int = 0) -> list[Job]:
        regression = item.regression
        return [Job.of(first_key + i, regression.space, regression.x, seed=regression.seed, out_dir=self.out_dir, name=name, options=self.options(regression))
                for i, name in enumerate(self.names(regression))]

    def start(self, items: list[RegressionItem]) -> None:
        if self.workers == 1 or not items:
            return
        jobs: list[Job] = []
        futures: dict[int, Future] = {}
        for item in items:
            if self.refusal(item.regression) is not None:
                continue
            item_jobs = self.jobs(item, len(jobs))
            jobs.extend(item_jobs)
            self._futures[item.nodeid] = [futures.setdefault(job.key, Future()) for job in item_jobs]
        self._executor = LocalExecutor(self.workers)

        def fly_all() -> None:
            try:
                for job, result in self._executor.run(jobs):
                    futures[job.key].set_result(result)
            except BaseException as error:  # every waiting item must hear of it, not hang
                for future in futures.values():
                    if not future.done():
                        future.set_exception(error)

        self._thread = threading.Thread(target=fly_all, name="stella-flights", daemon=True)
        self._thread.start()

    def results(self, item: RegressionItem) -> list[EvaluationResult]:
        refused = self.refusal(item.regression)
        if refused is not None:
            return [refused] * len(self.names(item.regression))
        if item.nodeid in self._futures:
            return [future.result() for future in self._futures[item.nodeid]]
        return [run_job(job) for job in self.jobs(item)]

    def close(self) -> None:
        if self._executor is not None:
            self._executor.close()
        if self._thread is not None:
            self._thread.join()


def _resolve(scenario: str | Path, request: pytest.FixtureRequest) -> Path:
    path = Path(scenario)
    for candidate in (path, request.path.parent / path, request.config.rootpath / path):
        if candidate.exists():
            return candidate
    raise pytest.UsageError(f"scenario {scenario!r} not found (looked relative to {request.path.parent} and {request.config.rootpath})")


def _space_and_vector(path: Path, seed: int, drive: str | None) -> tuple[SearchSpace, np.ndarray, int]:
    """(space, vector, flight seed) for a regression case, a concrete or a logical scenario."""
    if path.name.endswith(SUFFIX):
        regression = load_regression(path, drive)
        return regression.space, regression.x, regression.seed
    document = load_json(path)
    if isinstance(document, dict) and document.get("format") == CONCRETE_FORMAT:
        space, x = load_concrete(path, drive)
        return space, x, seed
    profile = load_profile("default")
    space = SearchSpace(load_logical(path, profile, drive), profile)
    return space, space.sample_feasible(np.random.default_rng(seed), 1)[0], seed


@pytest.fixture
def fly(request: pytest.FixtureRequest) -> Callable[..., EvaluationResult]:
    """Fly a scenario and return its result; see the module docstring for the arguments."""
    flights: Flights = request.config.stash[FLIGHTS]
    count = 0

    def fly(scenario: str | Path, *, seed: int = 0, sut: str | None = None, sut_params: dict[str, float] | None = None, drive: str | None = None,
            **values: float) -> EvaluationResult:
        nonlocal count
        space, x, flight_seed = _space_and_vector(_resolve(scenario, request), seed, drive or flights.drive)
        try:
            x = space.with_values(x, {name.replace("__", "."): value for name, value in values.items()})
        except KeyError as error:
            raise pytest.UsageError(str(error.args[0])) from None
        count += 1
        name = slug(request.node.name) + (f"-{count}" if count > 1 else "")
        options = flights.run_options(sut or flights.sut_override or "bundled", sut_params or {})
        result = evaluate(space, x, seed=flight_seed, out_dir=flights.out_dir, options=options, name=name)
        request.node.user_properties.append(("stella_log" if count == 1 else f"stella_log_{count}", result.log_path or ""))
        return result

    return fly


@pytest.fixture
def flight(request: pytest.FixtureRequest, fly: Callable[..., EvaluationResult]) -> EvaluationResult:
    """The result of flying what the test's `@pytest.mark.scenario(...)` names."""
    marker = request.node.get_closest_marker("scenario")
    if marker is None or not marker.args:
        raise pytest.UsageError(f"{request.node.nodeid}: the `flight` fixture needs @pytest.mark.scenario(PATH, seed=..., **values)")
    return fly(*marker.args, **marker.kwargs)
