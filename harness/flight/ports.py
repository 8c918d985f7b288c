"""Port blocks: evaluation slot k uses simulator 4560+k, API 14540+k and control 24560+k.

A slot is taken by holding an exclusive lock file, so parallel evaluations (threads, processes
or separate campaigns on one host) never share ports; the lock dies with its holder. A SUT that
numbers its instances within a range (PX4: 0-9) takes a slot in that range, waiting for one to be
free when other evaluations on the host hold them all.
"""

from __future__ import annotations

import fcntl
import os
import socket
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from harness.errors import InfrastructureError

SIM_BASE = 4560
API_BASE = 14540
CONTROL_BASE = 24560
MAX_SLOTS = 200
SLOT_POLL_S = 0.2
LOCK_DIR = Path(os.environ.get("STELLA_LOCK_DIR", Path(tempfile.gettempdir()) / "stella-slots"))


@dataclass(frozen=True)
class PortBlock:
    slot: int
    sim: int
    api: int
    control: int


def _free(port: int, kind: int) -> bool:
    with socket.socket(socket.AF_INET, kind) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


class PortLease:
    """Holds one slot until closed."""

    def __init__(self, first_slot: int = 0, slots: int = MAX_SLOTS, wait_s: float = 0.0):
        """A free slot among `slots` from `first_slot`, waiting up to wait_s for one."""
        LOCK_DIR.mkdir(parents=True, exist_ok=True)
        self._handle = None
        deadline = time.monotonic() + wait_s
        while not self._take(first_slot, slots):
            if time.monotonic() >= deadline:
                raise InfrastructureError(f"no free port block among the {slots} slots from {first_slot}"
                                          + (f" within {wait_s:.0f} s: other evaluations on this host hold them all" if wait_s else ""))
            time.sleep(SLOT_POLL_S)

    def _take(self, first_slot: int, slots: int) -> bool:
        for slot in range(first_slot, first_slot + slots):
            handle = open(LOCK_DIR / f"slot-{slot}.lock", "w")
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                handle.close()
                continue
            block = PortBlock(slot, SIM_BASE + slot, API_BASE + slot, CONTROL_BASE + slot)
            if _free(block.sim, socket.SOCK_STREAM) and _free(block.control, socket.SOCK_STREAM) and _free(block.api, socket.SOCK_DGRAM):
                self._handle = handle
                self.block = block
                return True
            handle.close()
        return False

    def __enter__(self) -> PortBlock:
        return self.block

    def __exit__(self, *exc_info) -> None:
        self.close()

    def close(self) -> None:
        if self._handle is not None:
            self._handle.close()
            self._handle = None
