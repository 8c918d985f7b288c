"""The simulator link's bytes through shared memory, between two processes on one machine.

A Unix-domain socket's round trip costs each lockstep step a few microseconds of system calls on
both sides (send, wake-up, receive), more than the bridge's answer-critical work on two cores. Here the
same byte stream goes through two single-writer, single-reader rings in one shared mapping, and
a reader with a core of its own finds the peer's bytes by polling a counter, without a system
call. The Unix-domain socket stays: the simulator hands the mapping over on it (SCM_RIGHTS) when
the SUT connects, a reader about to sleep is woken through it, and its end of file is how either
side learns that the other has gone.

A ring is a byte array of CAPACITY with two counters of all bytes ever written (head, the
writer's) and read (tail, the reader's). The writer copies its bytes in, then moves head; the
reader copies them out, then moves tail. That order alone keeps it consistent where stores
become visible to other cores in program order (x86-64's total store order), with each counter
an aligned 8-byte word that one instruction stores and loads. Elsewhere it would need memory
barriers, which Python cannot issue: AVAILABLE says where it runs.

A reader that finds nothing and must sleep announces it in its ring's sleep word (odd: asleep,
counted up on every sleep), checks the ring once more and waits on the socket; a writer that
finds the sleep word odd sends one wake byte for that sleep. The check and the announcement can
cross (each side's store may still be in its core's buffer when it reads the other's word), so
a sleeper also looks at the ring every RECHECK_S: a lost wake-up costs at most that, never a hang.
"""

from __future__ import annotations

import mmap
import os
import platform
import select
import socket
import time

AVAILABLE = hasattr(os, "memfd_create") and hasattr(socket, "send_fds") and platform.machine().lower() in ("x86_64", "amd64")

CAPACITY = 1 << 16
# Each counter on a cache line pair of its own, so that the writer's and the reader's stores do
# not contend for one line (adjacent lines are prefetched together).
_WORD_SPACING = 128
_HEAD, _TAIL, _SLEEP = 0, _WORD_SPACING // 8, 2 * _WORD_SPACING // 8
_HEADER = 3 * _WORD_SPACING
_RING_BYTES = _HEADER + CAPACITY
SIZE = 2 * _RING_BYTES
# What the simulator sends with the mapping's file descriptor, so that a SUT told to use shared
# memory finds out when the simulator offers none.
OFFER = b"stella-shm-1"
RECHECK_S = 0.002
_FULL_WAIT_S = 50e-6


class _Ring:
    """One direction of the link, seen from one side (the writer's or the reader's)."""

    def __init__(self, memory: memoryview, offset: int):
        self.words = memory[offset:offset + _HEADER].cast("Q")
        self.data = memory[offset + _HEADER:offset + _RING_BYTES]
        self.woken_sleep = 0  # the writer's: the last sleep it sent a wake byte for

    def write(self, data: memoryview) -> int:
        """As much of data as fits; how much that was."""
        words = self.words
        head = words[_HEAD]
        count = min(len(data), CAPACITY - (head - words[_TAIL]))
        start = head % CAPACITY
        first = min(count, CAPACITY - start)
        self.data[start:start + first] = data[:first]
        if count > first:
            self.data[:count - first] = data[first:count]
        words[_HEAD] = head + count  # only now may the reader see the bytes
        return count

    def take(self) -> bytes:
        words = self.words
        tail = words[_TAIL]
        count = words[_HEAD] - tail
        if not count:
            return b""
        start = tail % CAPACITY
        end = start + count
        if end <= CAPACITY:
            data = bytes(self.data[start:end])
        else:
            data = bytes(self.data[start:]) + bytes(self.data[:end - CAPACITY])
        words[_TAIL] = tail + count  # only now may the writer reuse the space
        return data

    def has_data(self) -> bool:
        return self.words[_HEAD] != self.words[_TAIL]

    def release(self) -> None:
        self.words.release()
        self.data.release()


class SharedMemoryLink:
    """One side of the link. Its receive() keeps codec.receive's contract and sendall() a
    socket's (send() is sendall(), as the bridge's SutLink protocol has it), so that the bridge
    (as a SutLink) and the autopilot (as its simulator socket) use it as they use a socket."""

    def __init__(self, sock: socket.socket, mapping: mmap.mmap, simulator_side: bool, timeout_s: float):
        self.sock = sock
        self.timeout_s = timeout_s  # receive()'s wait without `also`, as a socket's receive timeout
        self._mapping = mapping
        self._memory = memoryview(mapping)
        simulator_to_sut, sut_to_simulator = _Ring(self._memory, 0), _Ring(self._memory, _RING_BYTES)
        self._out, self._in = (simulator_to_sut, sut_to_simulator) if simulator_side else (sut_to_simulator, simulator_to_sut)
        self._peer_gone = False
        self._closed = False
        self._ready: tuple[socket.socket, socket.socket] | None = None
        sock.setblocking(True)
        sock.settimeout(None)

    # -- writing -----------------------------------------------------------------------------

    def sendall(self, data: bytes) -> None:
        """All of data into the ring, waiting for room while the peer reads; OSError when the
        peer has gone."""
        ring = self._out
        view = memoryview(data)
        while True:
            written = ring.write(view)
            self._wake_peer()
            view = view[written:]
            if not view:
                return
            self._wait_for_room()

    send = sendall

    def _wake_peer(self) -> None:
        ring = self._out
        sleep = ring.words[_SLEEP]
        if sleep & 1 and sleep != ring.woken_sleep:
            ring.woken_sleep = sleep
            try:
                self.sock.send(b"\x01", socket.MSG_DONTWAIT)
            except BlockingIOError:  # its buffer is full of wake bytes: it is being woken anyway
                pass

    def _wait_for_room(self) -> None:
        if self._peer_gone or (select.select([self.sock], [], [], 0.0)[0] and not self._drain_wake_bytes()):
            raise BrokenPipeError("the peer closed the simulator link")
        time.sleep(_FULL_WAIT_S)

    # -- reading -----------------------------------------------------------------------------

    def receive(self, spin_s: float = 0.0, *, also: socket.socket | None = None, wait_s: float = 0.0) -> bytes:
        """What the peer has written since, polling for up to spin_s first, then sleeping until
        it writes, or for timeout_s (BlockingIOError then); b"" once it has gone and everything
        it wrote was read. With `also`, input there or wait_s passing ends the sleep too (then
        BlockingIOError), as in codec.receive."""
        ring = self._in
        data = ring.take()
        if data:
            return data
        if spin_s > 0.0:
            words = ring.words
            tail = words[_TAIL]
            perf = time.perf_counter
            deadline = perf() + spin_s
            while words[_HEAD] == tail:
                if perf() > deadline:
                    break
            else:
                return ring.take()
        if self._sleep(wait_s if also is not None else self.timeout_s, also) == "data":
            return ring.take()
        if self._peer_gone:
            return b""
        raise BlockingIOError("nothing from the peer yet")

    def readable(self, timeout_s: float) -> bool:
        """Whether receive() has something now (bytes, or the peer's end), waiting up to timeout_s."""
        return self._sleep(timeout_s, None) != "timeout"

    def idle(self) -> bytes:
        """What the peer wrote meanwhile, without waiting (b"": nothing); OSError when it has gone."""
        self._sleep_ends()
        if select.select([self.sock], [], [], 0.0)[0]:
            self._drain_wake_bytes()
        data = self._in.take()
        if not data and self._peer_gone:
            raise ConnectionResetError("the peer closed the simulator link")
        return data

    def waitable(self) -> socket.socket:
        """The socket to wait on while simulated time stands still: from now until the next
        idle() or receive() the peer wakes it when it writes; one already readable when the
        peer wrote (or went) since the last look."""
        self._sleep_begins()
        if self._in.has_data() or self._peer_gone:
            self._sleep_ends()
            return self._readable_now()
        return self.sock

    def _readable_now(self) -> socket.socket:
        """A socket that stays readable (one of a private pair, with a byte nobody reads)."""
        if self._ready is None:
            self._ready = socket.socketpair()
            self._ready[1].send(b"\x01")
        return self._ready[0]

    def _sleep(self, timeout_s: float, also: socket.socket | None) -> str:
        """Sleep until the ring has data ("data"), the peer has gone ("gone"), `also` has input
        ("also") or timeout_s passed ("timeout")."""
        ring = self._in
        sockets = [self.sock] if also is None else [self.sock, also]
        deadline = time.monotonic() + timeout_s
        while True:
            self._sleep_begins()
            if ring.has_data():
                self._sleep_ends()
                return "data"
            if self._peer_gone:
                self._sleep_ends()
                return "gone"
            remaining = deadline - time.monotonic()
            # At least one look at the sockets, so that even a zero timeout sees the peer's end.
            readable = select.select(sockets, [], [], min(max(remaining, 0.0), RECHECK_S))[0]
            self._sleep_ends()
            if self.sock in readable:
                self._drain_wake_bytes()
            if ring.has_data():
                return "data"
            if self._peer_gone:
                return "gone"
            if also is not None and also in readable:
                return "also"
            if remaining <= 0.0:
                return "timeout"

    def _sleep_begins(self) -> None:
        words = self._in.words
        if not words[_SLEEP] & 1:
            words[_SLEEP] += 1

    def _sleep_ends(self) -> None:
        words = self._in.words
        if words[_SLEEP] & 1:
            words[_SLEEP] += 1

    def _drain_wake_bytes(self) -> bool:
        """Read the wake bytes waiting on the socket; False (and the peer gone) at its end."""
        try:
            if self.sock.recv(4096, socket.MSG_DONTWAIT):
                return True
        except BlockingIOError:
            return True
        except OSError:
            pass
        self._peer_gone = True
        return False

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        # The socket first: the peer learns at once that we have gone, whatever happens below.
        self.sock.close()
        if self._ready is not None:
            for end in self._ready:
                end.close()
        self._out.release()
        self._in.release()
        self._memory.release()
        self._mapping.close()


def offer(sock: socket.socket, timeout_s: float) -> SharedMemoryLink:
    """The simulator's side, on a SUT's fresh connection: create the mapping and hand it over."""
    fd = os.memfd_create("stella-simulator-link", os.MFD_CLOEXEC)
    try:
        os.ftruncate(fd, SIZE)
        mapping = mmap.mmap(fd, SIZE)
        socket.send_fds(sock, [OFFER], [fd])
    finally:
        os.close(fd)
    return SharedMemoryLink(sock, mapping, simulator_side=True, timeout_s=timeout_s)


def accept(sock: socket.socket, timeout_s: float, offer_timeout_s: float) -> SharedMemoryLink:
    """The SUT's side, just connected: take the simulator's mapping, waiting up to
    offer_timeout_s for it (the simulator builds its world before it accepts); the link's
    receive() waits timeout_s. ConnectionError when the simulator offers none (it was not
    started with --sim-shared-memory)."""
    sock.settimeout(offer_timeout_s)
    try:
        message, fds, _flags, _address = socket.recv_fds(sock, len(OFFER), 1)
    except socket.timeout:
        raise ConnectionError(f"the simulator offered no shared memory within {offer_timeout_s:g} s: is it running with --sim-shared-memory?") from None
    try:
        if message != OFFER or len(fds) != 1 or os.fstat(fds[0]).st_size != SIZE:
            raise ConnectionError(f"the simulator did not offer this link's shared memory (got {message!r}): is it running with --sim-shared-memory?")
        mapping = mmap.mmap(fds[0], SIZE)
    finally:
        for fd in fds:
            os.close(fd)
    return SharedMemoryLink(sock, mapping, simulator_side=False, timeout_s=timeout_s)
