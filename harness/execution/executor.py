"""Executors fly batches of concrete scenarios and hand back results as they finish.

The contract, the same for every executor:

* `run(jobs)` yields `(job, result)` as evaluations finish, in any order.
* A try that ends `sut_crashed`, `sim_crashed` or `timeout`, or whose worker died on the way
  (a killed worker process, a killed container, a lost Dask worker), is tried again, up to
  `attempts` tries in all; every try's status and cause are in the result's `attempts` and the
  last try's result stands. A SUT that crashes in every try is then a finding, not bad luck.
* Each try has a hard wall-clock limit, `timeout_s`: past it the try is ended and is a
  `timeout`.
* `cancel()` drops what has not started (what runs finishes and is reported; on Dask it is
  abandoned); `close()` ends the workers.

`sequential` and `local` (local.py) fly in this process or in a pool of worker processes on
this machine, each evaluation with its own port block, temp dir and core (see
harness/flight/stack.py); `dask` (dask_executor.py) and `docker` (docker_executor.py)
elsewhere; registry.py makes one by name. Jobs carry the world spec the simulator
loads and the concrete scenario it came from, so a worker needs nothing but the job and
derives nothing again.
"""

from __future__ import annotations

import concurrent.futures
import logging
import os
import signal
import threading
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping

import numpy as np

from harness.flight import stack
from harness.flight.evaluation import fly
from harness.flight.results import EvaluationResult, RunOptions
from harness.flight.fitness import COULD_NOT_FINISH, PENALTY, Status
from harness.scenario.space import SearchSpace
from harness.scenario.world import world_spec
from sim_bridge.spec import WorldSpec
from sut_adapter import SutConfig

log = logging.getLogger(__name__)

DEFAULT_ATTEMPTS = 2
DEFAULT_TIMEOUT_S = 600.0


@dataclass(frozen=True)
class Job:
    """One flight to make: the world spec the simulator loads and the concrete scenario it came
    from, both made where the search space is, so that a worker derives nothing again."""

    key: int
    world: WorldSpec
    concrete: Mapping[str, Any]
    seed: int
    out_dir: str
    name: str
    options: RunOptions

    def to_json(self) -> dict[str, Any]:
        return {**asdict(self), "world": self.world.as_dict(), "options": asdict(self.options)}

    @classmethod
    def from_json(cls, document: Mapping[str, Any]) -> "Job":
        options = document["options"]
        return cls(**{**document, "world": WorldSpec.from_dict(document["world"]), "options": RunOptions(**{**options, "sut": SutConfig(**options["sut"])})})

    @classmethod
    def of(cls, key: int, space: SearchSpace, x: np.ndarray, *, seed: int, out_dir: Path | str, name: str, options: RunOptions) -> "Job":
        """The job for point x of space, which must be feasible (evaluation.infeasible says)."""
        # Absolute: the log paths a store keeps are read later from anywhere (triage, report,
        # export-findings), and a Dask worker's working directory is not the campaign's.
        return cls(key, world_spec(space, x, seed), space.to_concrete(x), seed, str(Path(out_dir).absolute()), name, options)


def run_job(job: Job) -> EvaluationResult:
    """One try of one evaluation, in this process."""
    return fly(job.world, job.concrete, seed=job.seed, out_dir=Path(job.out_dir), options=job.options, name=job.name)


def failed_try(job: Job, status: Status, why: str) -> EvaluationResult:
    """The result of a try that produced none of its own (its worker died or ran out of time)."""
    return EvaluationResult(status=status, fitness=PENALTY, why=why, min_clearance_m=None, min_clearance_at_s=None, min_clearance_obstacle=None,
                            sim_time_s=0.0, wall_time_s=0.0, real_time_factor=None, seed=job.seed, log_path=None, scenario=job.world.scenario,
                            sut=job.options.sut.name)


class _TryTimedOut(BaseException):
    """Raised into the evaluation by the watchdog; a BaseException so nothing swallows it."""


def run_job_with_watchdog(job: Job, timeout_s: float) -> EvaluationResult:
    """run_job under a wall-clock limit. The limit is a SIGALRM, so it needs the main thread
    (pool workers and the sequential executor run there); the evaluation's context managers
    stop its processes and free its ports on the way out."""
    if threading.current_thread() is not threading.main_thread():
        return run_job(job)

    def expire(_signum, _frame):
        raise _TryTimedOut()

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, timeout_s)
    try:
        return run_job(job)
    except _TryTimedOut:
        return failed_try(job, Status.TIMEOUT, f"no result within {timeout_s:.0f} s wall time (the executor's limit per try)")
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


class WorkerLost(Exception):
    """A try's worker died under it: a killed process or container, a lost Dask worker."""


class Executor:
    """The retrying loop every executor shares; subclasses say how one try is submitted."""

    name = "base"
    # Whether its tries run one after another in processes that live on (RunOptions.warm pays
    # there); an executor that starts a process or container per try says no.
    keeps_stacks = False

    def __init__(self, workers: int, attempts: int = DEFAULT_ATTEMPTS, timeout_s: float = DEFAULT_TIMEOUT_S):
        if attempts < 1:
            raise ValueError("attempts must be at least 1")
        self.workers = workers
        self.attempts = attempts
        self.timeout_s = timeout_s
        self._cancelled = threading.Event()

    def submit(self, job: Job) -> concurrent.futures.Future:
        """Start one try; the future holds its EvaluationResult, or raises what lost_worker() knows."""
        raise NotImplementedError

    def lost_worker(self, error: BaseException) -> bool:
        """Whether a try's exception means its worker died (rather than a bug to raise)."""
        return isinstance(error, WorkerLost)

    def recover(self) -> None:
        """Make the executor usable again after a worker died (a pool rebuilt, say)."""

    def check_sut(self, sut: SutConfig) -> None:
        """Raise InfrastructureError, with one message, where the SUT cannot start where this
        executor flies (its build missing there, a library the build needs): asked once before a
        campaign flies, so that it does not crash every evaluation instead. On this machine the
        SUT's own adapter says so at its start."""

    def cores_per_evaluation(self) -> int:
        """Two when every concurrent evaluation can have two of this machine's cores (see
        RunOptions.cores), else one."""
        return 2 if len(os.sched_getaffinity(0)) >= 2 * self.workers else 1

    def run(self, jobs: Iterable[Job]) -> Iterator[tuple[Job, EvaluationResult]]:
        self._cancelled.clear()
        cores = self.cores_per_evaluation()
        jobs = [replace(job, options=replace(job.options, cores=cores)) for job in jobs]
        pending: dict[concurrent.futures.Future, tuple[Job, list[dict[str, str]]]] = {self.submit(job): (job, []) for job in jobs}
        try:
            while pending:
                if self._cancelled.is_set():
                    # Tries not started are dropped; running ones finish and are reported.
                    for future in [f for f in pending if f.cancel()]:
                        del pending[future]
                    if not pending:
                        break
                done, _ = concurrent.futures.wait(pending, timeout=0.2, return_when=concurrent.futures.FIRST_COMPLETED)
                for future in done:
                    job, tries = pending.pop(future)
                    if future.cancelled():
                        continue
                    try:
                        result = future.result()
                    except Exception as error:
                        if not self.lost_worker(error):
                            raise
                        if self._cancelled.is_set():  # ended by the cancellation itself: there is no result
                            continue
                        log.warning("%s: its worker died: %s", job.name, error)
                        self.recover()
                        result = failed_try(job, Status.SIM_CRASHED, f"the worker died: {error}")
                    tries.append({"status": result.status, "why": result.why})
                    if result.status in COULD_NOT_FINISH and len(tries) < self.attempts and not self._cancelled.is_set():
                        log.warning("%s: try %d ended %s (%s); trying again", job.name, len(tries), result.status, result.why)
                        pending[self.submit(job)] = (job, tries)
                        continue
                    yield job, replace(result, attempts=tries)
        finally:
            for future in pending:
                future.cancel()

    def cancel(self) -> None:
        self._cancelled.set()

    def close(self) -> None:
        self.cancel()
        stack.close_kept()  # what evaluations in this process kept (RunOptions.warm)
