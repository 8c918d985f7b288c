"""The SUT protocol and its registry."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping, Protocol


class SutError(Exception):
    """A SUT would not start or answer; carries its name and the tail of its log."""

    def __init__(self, sut: str, message: str, log_tail: str = ""):
        self.sut = sut
        self.log_tail = log_tail
        super().__init__(f"{sut}: {message}" + (f"\n{log_tail}" if log_tail else ""))


@dataclass
class SutHandle:
    """A started SUT. `alive()` says whether it still runs; `artifacts` lists its log files."""

    name: str
    alive: Callable[[], bool]
    stop: Callable[[], int | None]
    artifacts: list[Path] = field(default_factory=list)
    stderr_tail: Callable[[], str] = lambda: ""
    pids: list[int] = field(default_factory=list)


class SystemUnderTest(Protocol):
    name: str

    def start(self, *, sim_port: int, api_port: int, instance: int, workdir: Path, params: Mapping[str, float]) -> SutHandle:
        """Start the SUT so that it connects to the simulator on sim_port and sends its API link to api_port."""


_REGISTRY: dict[str, Callable[[], SystemUnderTest]] = {}


def register(name: str, factory: Callable[[], SystemUnderTest]) -> None:
    _REGISTRY[name] = factory


def names() -> list[str]:
    return sorted(_REGISTRY)


def get(name: str) -> SystemUnderTest:
    if name not in _REGISTRY:
        raise SutError(name, f"unknown SUT; available: {', '.join(names())}")
    return _REGISTRY[name]()


def _register_builtins() -> None:
    from sut_adapter.bundled import BundledAutopilot

    register("bundled", BundledAutopilot)


_register_builtins()
