"""Executors evaluate a batch of concrete scenarios and hand back results as they finish.

`sequential` flies them one after another in this process; `local` in a pool of worker
processes, each evaluation with its own port block, temp dir and core (see evaluation.py).
Jobs carry the concrete scenario JSON, which embeds its logical scenario and profile, so a
worker needs nothing but the job.
"""

from __future__ import annotations

import concurrent.futures
import multiprocessing
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping, Protocol

from harness.evaluation import RunOptions, evaluate
from harness.scenario.world import space_from_concrete


@dataclass(frozen=True)
class Job:
    key: int
    concrete: Mapping[str, Any]
    seed: int
    out_dir: str
    name: str
    options: RunOptions


def run_job(job: Job) -> dict[str, Any]:
    space = space_from_concrete(job.concrete, job.name)
    x = space.from_concrete(job.concrete, job.name)
    return evaluate(space, x, seed=job.seed, out_dir=Path(job.out_dir), options=job.options, name=job.name).as_dict()


class Executor(Protocol):
    name: str

    def run(self, jobs: Iterable[Job]) -> Iterator[tuple[Job, dict[str, Any]]]:
        """Results in the order they finish."""

    def close(self) -> None: ...


class SequentialExecutor:
    name = "sequential"

    def run(self, jobs: Iterable[Job]) -> Iterator[tuple[Job, dict[str, Any]]]:
        for job in jobs:
            yield job, run_job(job)

    def close(self) -> None:
        pass


class LocalExecutor:
    name = "local"

    def __init__(self, workers: int | None = None):
        self.workers = workers or len(os.sched_getaffinity(0))
        # spawn, not fork: the parent may hold threads (MAVSDK, progress) that fork would copy half-way.
        self._pool = concurrent.futures.ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"))

    def run(self, jobs: Iterable[Job]) -> Iterator[tuple[Job, dict[str, Any]]]:
        futures = {self._pool.submit(run_job, job): job for job in jobs}
        try:
            for future in concurrent.futures.as_completed(futures):
                yield futures[future], future.result()
        finally:
            for future in futures:
                future.cancel()

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)


EXECUTORS = {"sequential": SequentialExecutor, "local": LocalExecutor}


def make_executor(name: str, workers: int | None) -> Executor:
    if name == "sequential":
        return SequentialExecutor()
    if name == "local":
        return LocalExecutor(workers)
    raise ValueError(f"unknown executor {name!r}; available: {', '.join(EXECUTORS)}")
