"""Executors by name, for the command line, the campaign page and the benchmarks."""

from __future__ import annotations

from typing import Mapping

from harness.execution.executor import DEFAULT_ATTEMPTS, DEFAULT_TIMEOUT_S, Executor
from harness.execution.local import LocalExecutor, SequentialExecutor


EXECUTORS = ("sequential", "local", "dask", "docker")


def make_executor(name: str, workers: int | None, *, attempts: int = DEFAULT_ATTEMPTS, timeout_s: float = DEFAULT_TIMEOUT_S,
                  settings: Mapping[str, str] | None = None) -> Executor:
    """settings: `scheduler` for dask (an address; none starts a LocalCluster), `image` for docker."""
    settings = settings or {}
    if name == "sequential":
        return SequentialExecutor(attempts, timeout_s)
    if name == "local":
        return LocalExecutor(workers, attempts, timeout_s)
    if name == "dask":
        from harness.execution.dask_executor import DaskExecutor

        return DaskExecutor(workers, attempts, timeout_s, scheduler=settings.get("scheduler"))
    if name == "docker":
        from harness.execution.docker_executor import DockerExecutor

        return DockerExecutor(workers, attempts, timeout_s, image=settings.get("image"))
    raise ValueError(f"unknown executor {name!r}; available: {', '.join(EXECUTORS)}")
