"""The simulator's end of the control channel (sim_bridge/control.py has its messages): the
harness's ops as they arrive, and events sent now or, before the harness connects, once it does."""

from __future__ import annotations

import select
import socket
import time

from sim_bridge.control import Event, Op, Stop, decode_op


class ControlChannel:
    """The harness's side channel; absent until the harness connects."""

    def __init__(self, listener: socket.socket | None, own_listener: bool = True):
        """own_listener=False: close() hangs up on the harness but keeps listening for the next."""
        self._listener = listener
        self._own_listener = own_listener
        self._conn: socket.socket | None = None
        self._buffer = b""
        self._backlog: list[Event] = []
        self._held_ops: list[Op] = []
        # The harness keeps its connection for the whole flight: losing it means the harness died.
        self.hung_up = False
        if listener is not None:
            listener.setblocking(False)

    @property
    def connected(self) -> bool:
        return self._conn is not None

    def poll(self, timeout_s: float = 0.0, wake: socket.socket | None = None) -> list[Op]:
        """The harness's ops, waiting up to timeout_s for one, or for `wake` to turn readable."""
        ops, self._held_ops = self._held_ops, []
        sockets = [s for s in (self._listener, self._conn) if s is not None]
        if not sockets and wake is None:
            if timeout_s and not ops:
                time.sleep(timeout_s)
            return ops
        readable, _, _ = select.select(sockets + ([wake] if wake is not None else []), [], [], 0.0 if ops else timeout_s)
        for sock in readable:
            if sock is wake:
                continue
            if sock is self._listener:
                self._conn, _ = self._listener.accept()
                self._conn.setblocking(False)
                backlog, self._backlog = self._backlog, []
                for message in backlog:
                    self.send(message)
                continue
            try:
                data = sock.recv(65536)
            except BlockingIOError:
                continue
            except OSError:  # reset: the harness went as we wrote to it
                data = b""
            if not data:
                self._conn = None
                self.hung_up = True
                continue
            self._buffer += data
            *lines, self._buffer = self._buffer.split(b"\n")
            ops += [decode_op(line) for line in lines if line.strip()]
        return ops

    def wait_readable(self, sock: socket.socket, timeout_s: float) -> bool:
        """Wait up to timeout_s for sock to turn readable (the SUT's connection or first frame);
        False when it did not, or the harness said stop or went meanwhile: a harness that gave up
        on its SUT (dead at once, or never heard of) would otherwise leave us waiting for it, and
        it can only SIGTERM us, before our log is open. Its other ops wait for the next poll."""
        deadline = time.monotonic() + timeout_s
        while not select.select([sock], [], [], 0.0)[0]:
            remaining = deadline - time.monotonic()
            if remaining <= 0 or self.hung_up:
                return False
            ops = self.poll(remaining, wake=sock)
            if any(isinstance(op, Stop) for op in ops):
                return False
            self._held_ops += ops
        return True

    def send(self, message: Event) -> None:
        """Send now, or as soon as the harness connects."""
        if self._conn is None:
            self._backlog.append(message)
            return
        self._conn.setblocking(True)
        try:
            self._conn.sendall(message.encode())
        except OSError:
            self._conn = None
            self.hung_up = True
        else:
            self._conn.setblocking(False)

    def close(self) -> None:
        for sock in (self._conn, self._listener if self._own_listener else None):
            if sock is not None:
                sock.close()
