"""Port blocks for evaluations: a SUT whose instances are numbered within a range waits for a
slot in it instead of taking one it cannot use."""

from __future__ import annotations

import threading
import time

import pytest

from harness.errors import InfrastructureError
from harness.flight import ports
from harness.flight.ports import PortLease


def test_a_lease_limited_to_a_range_waits_for_a_slot_in_it_and_says_why_when_none_frees(tmp_path, monkeypatch):
    monkeypatch.setattr(ports, "LOCK_DIR", tmp_path)
    held = [PortLease(first_slot=150, slots=3) for _ in range(3)]
    assert sorted(lease.block.slot for lease in held) == [150, 151, 152]
    with pytest.raises(InfrastructureError, match="no free port block among the 3 slots from 150 within 1 s"):
        PortLease(first_slot=150, slots=3, wait_s=1.0)
    threading.Timer(0.5, held[1].close).start()
    started = time.monotonic()
    with PortLease(first_slot=150, slots=3, wait_s=10.0) as block:
        assert block.slot == 151 and time.monotonic() - started >= 0.4
    for lease in held:
        lease.close()
