"""Systems under test: start, configure, health-check and stop one, behind one small protocol.

Nothing outside this package knows which SUT runs; the harness asks `get(name)` for one.
"""

from __future__ import annotations

from sut_adapter.base import SutError, SutHandle, SystemUnderTest
from sut_adapter.registry import get, names, register

__all__ = ["SutError", "SutHandle", "SystemUnderTest", "get", "names", "register"]
