"""Executors by name, for the command line, the campaign page and the benchmarks: the built-in
ones, and any other a user registers (as SUTs are, sut_adapter/registry.py).

Light to import, so that the command line can offer the names: an executor's module (and the
flight machinery behind it) is imported when one is made.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Mapping, Protocol

if TYPE_CHECKING:
    from harness.execution.executor import Executor


class ExecutorFactory(Protocol):
    def __call__(self, workers: int | None, attempts: int, timeout_s: float, settings: Mapping[str, str]) -> Executor: ...


_REGISTRY: dict[str, ExecutorFactory] = {}


def register(name: str, factory: ExecutorFactory) -> None:
    _REGISTRY[name] = factory


def names() -> list[str]:
    return list(_REGISTRY)


def make_executor(name: str, workers: int | None, *, attempts: int | None = None, timeout_s: float | None = None,
                  settings: Mapping[str, str] | None = None) -> Executor:
    """attempts and timeout_s: per evaluation (None: executor.py's defaults); settings:
    `scheduler` for dask (an address; none starts a LocalCluster), `image` for docker."""
    from harness.execution.executor import DEFAULT_ATTEMPTS, DEFAULT_TIMEOUT_S

    if name not in _REGISTRY:
        raise ValueError(f"unknown executor {name!r}; available: {', '.join(names())}")
    return _REGISTRY[name](workers, DEFAULT_ATTEMPTS if attempts is None else attempts, DEFAULT_TIMEOUT_S if timeout_s is None else timeout_s,
                           settings or {})


def _sequential(workers: int | None, attempts: int, timeout_s: float, settings: Mapping[str, str]) -> Executor:
    from harness.execution.local import SequentialExecutor

    return SequentialExecutor(attempts, timeout_s)


def _local(workers: int | None, attempts: int, timeout_s: float, settings: Mapping[str, str]) -> Executor:
    from harness.execution.local import LocalExecutor

    return LocalExecutor(workers, attempts, timeout_s)


def _dask(workers: int | None, attempts: int, timeout_s: float, settings: Mapping[str, str]) -> Executor:
    # Imported when asked for: dask's import alone takes about a second, and most campaigns run locally.
    from harness.execution.dask_executor import DaskExecutor

    return DaskExecutor(workers, attempts, timeout_s, scheduler=settings.get("scheduler"))


def _docker(workers: int | None, attempts: int, timeout_s: float, settings: Mapping[str, str]) -> Executor:
    from harness.execution.docker_executor import DockerExecutor

    return DockerExecutor(workers, attempts, timeout_s, image=settings.get("image"))


register("sequential", _sequential)
register("local", _local)
register("dask", _dask)
register("docker", _docker)
