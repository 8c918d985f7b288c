"""How the bridge's bytes reach the SUT and its answers come back.

Over TCP as PX4's simulator_mavlink connects, or over a Unix-domain socket for a SUT that can
connect to one (`SocketLink` either way; the kernel's round trip takes half TCP's), or through
shared memory handed over on that socket (`simlink.shared_memory.SharedMemoryLink`: no system
call per step while both sides poll on cores of their own), or, for a SUT
that runs inside the bridge's process (the bundled autopilot, `python -m sut_adapter.inline`),
through memory: the same MAVLink bytes, handed over by a call instead of a socket. Either way the bridge sees the
protocol below; what it sends and what it reads back are the same bytes.
"""

from __future__ import annotations

import select
import socket
from typing import Protocol

from simlink import codec

# "tcp": the SUT in a process of its own (any SUT); "unix": the same over a Unix-domain socket
# (a SUT that can connect to one: the bundled autopilot); "shm": its bytes through shared memory
# handed over on that socket (the same SUTs; Linux on x86-64); "memory": inside the bridge's
# process (a SUT that can run there); "auto": memory where an evaluation has one core, shm (else
# unix) where it has two, whichever the SUT can, else tcp.
TRANSPORTS = ("auto", "tcp", "memory", "unix", "shm")


class SutLink(Protocol):
    def send(self, data: bytes) -> None:
        """The simulator's frames of one step; OSError when the SUT has gone."""

    def receive(self, spin_s: float) -> bytes:
        """What the SUT has sent since, waiting up to the stall timeout: b"" when it has gone,
        BlockingIOError when it stayed silent that long, OSError when the link broke."""

    def readable(self, timeout_s: float) -> bool:
        """Whether receive() has something now, waiting up to timeout_s."""

    def idle(self) -> bytes:
        """While simulated time stands still: what the SUT sent meanwhile, without waiting (b"":
        nothing yet); OSError when it has gone."""

    def waitable(self) -> socket.socket:
        """A socket that turns readable when idle() has something to do, so that a bridge holding
        simulated time wakes for it at once rather than at its next poll."""

    def close(self) -> None: ...


class SocketLink:
    """A SUT connected over TCP or a Unix-domain socket."""

    def __init__(self, sock: socket.socket, stall_timeout_s: float):
        self.sock = sock
        codec.send_at_once(sock)
        codec.set_receive_timeout(sock, stall_timeout_s)

    def send(self, data: bytes) -> None:
        self.sock.sendall(data)

    def receive(self, spin_s: float) -> bytes:
        return codec.receive(self.sock, spin_s)

    def readable(self, timeout_s: float) -> bool:
        return bool(select.select([self.sock], [], [], timeout_s)[0])

    def idle(self) -> bytes:
        if not self.readable(0.0):
            return b""
        data = self.sock.recv(65536)
        if not data:
            raise ConnectionResetError("the SUT closed its simulator link")
        return data

    def waitable(self) -> socket.socket:
        return self.sock

    def close(self) -> None:
        self.sock.close()
