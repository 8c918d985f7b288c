"""SUTs by name: the built-in ones, and any other a user registers."""

from __future__ import annotations

from typing import Callable, Mapping

from sut_adapter.ardupilot import ArduPilotSitl
from sut_adapter.base import Capabilities, SutConfig, SutError, SystemUnderTest
from sut_adapter.bundled import BundledAutopilot
from sut_adapter.command import CommandSut
from sut_adapter.px4 import Px4Sitl

_REGISTRY: dict[str, Callable[[Mapping[str, str]], SystemUnderTest]] = {}


def register(name: str, factory: Callable[[Mapping[str, str]], SystemUnderTest]) -> None:
    _REGISTRY[name] = factory


def names() -> list[str]:
    return sorted(_REGISTRY)


def get(name: str, config: Mapping[str, str] | None = None) -> SystemUnderTest:
    """The SUT called name, configured by config (e.g. {"px4_bin": PATH}, {"command": TEMPLATE})."""
    if name not in _REGISTRY:
        raise SutError(name, f"unknown SUT; available: {', '.join(names())}")
    system = _REGISTRY[name](config or {})
    if not isinstance(getattr(system, "capabilities", None), Capabilities):
        raise SutError(name, "its adapter declares no capabilities: give it `capabilities = sut_adapter.Capabilities(hold_mode=..., range_messages=...)`")
    system.capabilities.check(name)
    return system


def system_for(config: SutConfig) -> SystemUnderTest:
    """The SUT a SutConfig names, configured by it."""
    return get(config.name, config.adapter_options())


register("bundled", BundledAutopilot)
register("command", CommandSut)
register("px4", Px4Sitl)
register("ardupilot", ArduPilotSitl)
