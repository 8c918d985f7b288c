"""Systems under test: start, configure, health-check and stop one, behind one small protocol.

Nothing outside this package knows which SUT runs; the harness asks `system_for(SutConfig(...))`
(or `get(name, options)`) for one.
"""

from __future__ import annotations

from sut_adapter.base import (SutConfig, SutError, SutHandle, SystemUnderTest, connects_to_shared_memory, connects_to_unix_socket, failure_params,
                               hold_pace, injects_failures, instance_count, mission_home_item, needs_world, physics_rate, pilot_setup, rc_port, runs_inline,
                               sim_protocol, with_failure_deliveries)
from sut_adapter.registry import get, names, register, system_for

__all__ = ["SutConfig", "SutError", "SutHandle", "SystemUnderTest", "connects_to_shared_memory", "connects_to_unix_socket", "failure_params", "get", "hold_pace", "injects_failures", "instance_count", "mission_home_item", "names", "needs_world", "physics_rate", "pilot_setup", "rc_port", "register", "runs_inline",
           "sim_protocol", "system_for", "with_failure_deliveries"]
