"""The harness's end of the simulator's control channel (sim_bridge/control.py has its messages)."""

from __future__ import annotations

import select
import socket
import time
from typing import Callable, TypeVar

from harness.errors import InfrastructureError
from sim_bridge.control import ControlError, Event, Op, decode_event

E = TypeVar("E", bound=Event)


class BridgeControl:
    def __init__(self, port: int, connect_timeout_s: float = 20.0):
        deadline = time.monotonic() + connect_timeout_s
        while True:
            try:
                self._sock = socket.create_connection(("127.0.0.1", port), timeout=1.0)
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise InfrastructureError(f"the simulator's control port {port} did not open within {connect_timeout_s:.0f} s") from None
                time.sleep(0.02)
        self._sock.setblocking(False)
        self._buffer = b""
        self.events: list[Event] = []
        self.closed = False

    def send(self, op: Op) -> None:
        self._sock.setblocking(True)
        self._sock.sendall(op.encode())
        self._sock.setblocking(False)

    def poll(self, timeout_s: float = 0.0) -> list[Event]:
        readable, _, _ = select.select([self._sock], [], [], timeout_s)
        new = []
        if readable:
            try:
                data = self._sock.recv(65536)
            except OSError:
                data = b""
            if not data:
                self.closed = True
            self._buffer += data
            *lines, self._buffer = self._buffer.split(b"\n")
            try:
                new = [decode_event(line) for line in lines if line.strip()]
            except ControlError as error:
                raise InfrastructureError(f"the simulator's control channel: {error}") from None
            self.events.extend(new)
        return new

    def seen(self, kind: type[E] | tuple[type[E], ...]) -> E | None:
        """The first event of a kind (of any of several) heard so far."""
        return next((event for event in self.events if isinstance(event, kind)), None)

    def heard(self, kind: type[E] | tuple[type[E], ...]) -> E | None:
        """The first event of a kind (of any of several), once all the simulator sent is read: a
        simulator that exited may have said why just before."""
        while not self.closed and select.select([self._sock], [], [], 0.0)[0]:
            self.poll(0.0)
        return self.seen(kind)

    def wait_for(self, kind: type[E] | tuple[type[E], ...], timeout_s: float, alive: Callable[[], bool] = lambda: True) -> E | None:
        """The first event of a kind (of any of several), waiting up to timeout_s while alive() holds."""
        deadline = time.monotonic() + timeout_s
        seen = self.seen(kind)
        if seen is not None:
            return seen
        while time.monotonic() < deadline and not self.closed and alive():
            for event in self.poll(0.05):
                if isinstance(event, kind):
                    return event
        return None

    def close(self) -> None:
        self._sock.close()
