"""The harness's end of the bridge's control channel (see sim_bridge/bridge.py for the protocol)."""

from __future__ import annotations

import json
import select
import socket
import time
from typing import Any, Mapping

from harness.errors import InfrastructureError


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
        self.events: list[dict[str, Any]] = []

    def send(self, op: Mapping[str, Any]) -> None:
        self._sock.setblocking(True)
        self._sock.sendall(json.dumps(op).encode() + b"\n")
        self._sock.setblocking(False)

    def poll(self, timeout_s: float = 0.0) -> list[dict[str, Any]]:
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
            new = [json.loads(line) for line in lines if line.strip()]
            self.events.extend(new)
        return new

    closed = False

    def wait_for(self, event: str, timeout_s: float, alive=lambda: True) -> dict[str, Any] | None:
        """The first event of a kind, waiting up to timeout_s while alive() holds."""
        deadline = time.monotonic() + timeout_s
        for seen in self.events:
            if seen.get("event") == event:
                return seen
        while time.monotonic() < deadline and not self.closed and alive():
            for seen in self.poll(0.05):
                if seen.get("event") == event:
                    return seen
        return None

    def close(self) -> None:
        self._sock.close()
