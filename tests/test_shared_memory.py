"""The simulator link through shared memory (simlink/shared_memory.py): a byte stream in order
both ways, through the rings' wrap-around and past their capacity, a sleeping reader woken, and
the peer's end and silence reported as a socket reports them. The flights over it are
tests/test_transport.py's."""

from __future__ import annotations

import hashlib
import json
import os
import select
import socket
import subprocess
import sys
import threading
import time

import pytest

from conftest import ROOT
from simlink import shared_memory
from test_bridge_lockstep import world

pytestmark = pytest.mark.skipif(not shared_memory.AVAILABLE, reason="shared memory links need Linux on x86-64")


@pytest.fixture
def pair():
    """(simulator side, SUT side), handed over as the bridge and the autopilot do."""
    simulator_sock, sut_sock = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    simulator = shared_memory.offer(simulator_sock, timeout_s=0.2)
    sut = shared_memory.accept(sut_sock, timeout_s=0.2, offer_timeout_s=1.0)
    yield simulator, sut
    for link in (simulator, sut):
        if link.sock.fileno() != -1:
            link.close()


def test_bytes_arrive_in_order_both_ways_across_the_wrap_around(pair):
    simulator, sut = pair
    sent, received = bytearray(), bytearray()
    for index in range(3 * shared_memory.CAPACITY // 997 + 5):  # past the end of the ring several times
        chunk = bytes((index + k) % 251 for k in range(997))
        simulator.sendall(chunk)
        sent += chunk
        received += sut.receive()
        sut.sendall(chunk[:7])
        assert simulator.receive() == chunk[:7]
    assert received == sent


def test_a_write_larger_than_the_ring_waits_for_the_reader(pair):
    simulator, sut = pair
    message = os.urandom(3 * shared_memory.CAPACITY + 123)
    received = bytearray()

    def read():
        while len(received) < len(message):
            received.extend(sut.receive(spin_s=0.001))

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    simulator.sendall(message)
    reader.join(10.0)
    assert not reader.is_alive() and bytes(received) == message


def test_a_silent_peer_is_a_blocking_error_after_the_timeout_and_other_input_ends_the_wait_at_once(pair):
    simulator, sut = pair
    started = time.monotonic()
    with pytest.raises(BlockingIOError):
        simulator.receive(spin_s=0.001)
    assert 0.2 <= time.monotonic() - started < 1.0
    other_a, other_b = socket.socketpair()
    with other_a, other_b:
        other_b.send(b"x")
        started = time.monotonic()
        with pytest.raises(BlockingIOError):
            sut.receive(also=other_a, wait_s=5.0)
        assert time.monotonic() - started < 1.0
    assert not simulator.readable(0.01) and simulator.idle() == b""


def test_a_sleeping_reader_is_woken_through_the_socket_and_an_awake_one_is_not(pair):
    simulator, sut = pair
    sut.sendall(b"while awake")
    assert not select.select([simulator.sock], [], [], 0.05)[0]
    assert simulator.idle() == b"while awake"
    waitable = simulator.waitable()  # the bridge is about to wait on its socket
    sut.sendall(b"while asleep")
    assert select.select([waitable], [], [], 1.0)[0]
    assert simulator.idle() == b"while asleep"
    sut.sendall(b"awake again")
    assert not select.select([simulator.sock], [], [], 0.05)[0]


def test_a_reader_in_another_process_sleeping_past_its_spin_gets_every_byte(pair):
    simulator, sut = pair
    chunks = [os.urandom(97) for _ in range(50)]
    expected = b"".join(chunks)
    child = os.fork()
    if child == 0:
        try:
            sut.timeout_s = 5.0
            total = bytearray()
            while len(total) < len(expected):
                total += sut.receive()
            sut.sendall(hashlib.sha256(total).digest() + len(total).to_bytes(8, "little"))
        finally:
            os._exit(0)
    for chunk in chunks:
        simulator.sendall(chunk)
        time.sleep(0.003)  # longer than the reader's recheck: it sleeps between chunks
    simulator.timeout_s = 5.0
    answer = bytearray()
    while len(answer) < 40:
        answer += simulator.receive()
    assert bytes(answer) == hashlib.sha256(expected).digest() + len(expected).to_bytes(8, "little")
    os.waitpid(child, 0)


def test_the_peer_going_away_is_reported_after_what_it_wrote(pair):
    simulator, sut = pair
    sut.sendall(b"last words")
    sut.close()
    sut.close()  # twice is harmless
    assert simulator.readable(1.0)
    assert simulator.receive() == b"last words"
    assert simulator.receive() == b""
    with pytest.raises(ConnectionResetError):
        simulator.idle()


def test_a_look_without_waiting_sees_the_peer_gone(pair):
    simulator, sut = pair
    sut.close()
    time.sleep(0.05)
    assert simulator.readable(0.0)


def test_what_arrived_before_the_wait_makes_the_waitable_socket_readable_at_once(pair):
    simulator, sut = pair
    assert simulator.idle() == b""
    sut.sendall(b"between the look and the wait")
    assert select.select([simulator.waitable()], [], [], 0.0)[0]
    assert simulator.idle() == b"between the look and the wait"
    assert not select.select([simulator.waitable()], [], [], 0.05)[0]
    simulator.idle()


def test_writing_into_a_full_ring_whose_reader_has_gone_fails():
    simulator_sock, sut_sock = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    simulator = shared_memory.offer(simulator_sock, timeout_s=0.2)
    sut_sock.close()  # the SUT died before taking the mapping
    try:
        with pytest.raises(BrokenPipeError):
            simulator.sendall(bytes(2 * shared_memory.CAPACITY))
    finally:
        simulator.close()


def test_a_simulator_that_offers_no_shared_memory_is_named():
    plain, sut_sock = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    with plain:
        with pytest.raises(ConnectionError, match="offered no shared memory within 0.2 s: is it running with --sim-shared-memory"):
            shared_memory.accept(sut_sock, timeout_s=1.0, offer_timeout_s=0.2)
        plain.send(b"\xfd" * 20)  # a plain simulator's first MAVLink bytes
        with pytest.raises(ConnectionError, match="did not offer this link's shared memory"):
            shared_memory.accept(sut_sock, timeout_s=1.0, offer_timeout_s=0.2)
    sut_sock.close()


@pytest.mark.slow
def test_a_sut_gone_before_the_hand_over_ends_the_flight_as_disconnected(tmp_path):
    """The simulator hands the mapping over once it has built its world; a SUT that connected
    and went meanwhile ends the flight with a summary, as over a plain socket."""
    world_path = tmp_path / "world.json"
    world_path.write_text(json.dumps(world(time_limit_s=2.0)))
    name = f"@stella-test-{os.getpid()}"
    bridge = subprocess.Popen([sys.executable, "-m", "sim_bridge", "--world", str(world_path), "--mcap", str(tmp_path / "flight.mcap"),
                               "--sim-socket", name, "--sim-shared-memory", "--hold-after-s", "0", "--connect-timeout-s", "20"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        deadline = time.monotonic() + 20.0
        while True:
            sut = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                sut.connect("\0" + name[1:])
                break
            except OSError:
                sut.close()
                assert time.monotonic() < deadline, "the simulator never listened"
                time.sleep(0.05)
        sut.close()
        out, err = bridge.communicate(timeout=30)
    finally:
        bridge.kill()
    assert bridge.returncode == 3, err
    assert json.loads(out.strip().splitlines()[-1])["end_reason"] == "sut_disconnected"
    assert "Traceback" not in err
