"""Systems under test: start, configure, health-check and stop one, behind one small protocol.

Nothing outside this package knows which SUT runs; the harness asks `system_for(SutConfig(...))`
(or `get(name, options)`) for one.
"""

from __future__ import annotations

from sut_adapter.base import Capabilities, SutConfig, SutError, SutHandle, SystemUnderTest
from sut_adapter.registry import get, names, register, system_for

__all__ = ["Capabilities", "SutConfig", "SutError", "SutHandle", "SystemUnderTest", "get", "names", "register", "system_for"]
