"""A companion computer's MAVLink link to the SUT: where a rig's messages go that the SUT does
not read on its simulator link, as UDP datagrams sent in step with the simulation.

SUTs open such a link one of two ways round. PX4 listens on its onboard link's port and the
companion sends there. ArduPilot SITL's serial port given as `udpclient:HOST:PORT` sends from a
port of its own to the companion's, which answers the address it last heard from, as
mavlink-router on a real companion computer does. Until such a SUT has been heard (its first
heartbeat on that port), nothing reaches it: the readings are lost, as on a link not yet up, and
the recording keeps only what was sent.
"""

from __future__ import annotations

import socket
from typing import Sequence


class CompanionLink:
    def __init__(self, port: int, *, sut_connects: bool, host: str = "127.0.0.1"):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.listening = sut_connects
        self.peer: tuple[str, int] | None = None if sut_connects else (host, port)
        if sut_connects:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.sock.bind((host, port))
            self.sock.setblocking(False)

    def send(self, frames: Sequence[bytes]) -> bytes:
        """The frames to the SUT; the bytes that went out."""
        if self.listening:
            self._hear()
        if self.peer is None:
            return b""
        sent = bytearray()
        for frame in frames:
            try:
                self.sock.sendto(frame, self.peer)
            except OSError:  # the SUT is not listening (yet): a companion's datagram is lost as on a real link
                continue
            sent += frame
        return bytes(sent)

    def _hear(self) -> None:
        """Drain what the SUT sent (its heartbeats and streams, which nothing here reads) and
        answer where the latest came from: a restarted SUT sends from another port."""
        while True:
            try:
                _datagram, address = self.sock.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # an ICMP error for an earlier datagram: the SUT's port closed
                self.peer = None
                return
            self.peer = address

    def close(self) -> None:
        self.sock.close()
