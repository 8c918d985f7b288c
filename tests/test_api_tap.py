"""The API tap's stamps: the SUT's clock read from its frames' bytes is the clock pymavlink's
parser reads, frame for frame, for every kind of datagram a SUT may send. And the ground
station's heartbeat it sends on the SUT's clock, which a data-link failure silences."""

from __future__ import annotations

import random
import socket
import time

from pymavlink.dialects.v20 import common as mavlink

from harness.flight.api_tap import ApiTap, SutClock
from harness.flight.ports import PortLease
from harness.flight.stack import CLIENT_PORT_OFFSET


def pymavlink_clock(datagrams: list[bytes], parser_per_datagram: bool = False) -> list[int]:
    """What the tap stamped before: the latest time_boot_ms among pymavlink's parsed messages
    (one parser for the stream, as before, or one per datagram)."""
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    stamps, time_ns = [], 0
    for datagram in datagrams:
        if parser_per_datagram:
            parser = mavlink.MAVLink(None)
            parser.robust_parsing = True
        for message in parser.parse_buffer(datagram) or []:
            if getattr(message, "time_boot_ms", None) is not None:
                time_ns = max(time_ns, int(message.time_boot_ms) * 1_000_000)
        stamps.append(time_ns)
    return stamps


def frames(rng: random.Random, time_boot_ms: int, version: int = 2) -> bytes:
    link = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    messages = [
        mavlink.MAVLink_attitude_message(time_boot_ms, *(rng.uniform(-1, 1) for _ in range(6))),
        # time_boot_ms after a uint64: at offset 8
        mavlink.MAVLink_system_time_message(rng.randrange(2**40), time_boot_ms),
        # all zeros after time_boot_ms: MAVLink 2 truncates the payload to it
        mavlink.MAVLink_local_position_ned_message(time_boot_ms, 0, 0, 0, 0, 0, 0),
        mavlink.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3),  # no time_boot_ms
    ]
    return b"".join(m.pack(link, force_mavlink1=version == 1) for m in rng.sample(messages, rng.randint(1, len(messages))))


def stream(rng: random.Random, broken_share: float) -> list[bytes]:
    datagrams = []
    for step in range(400):
        time_boot_ms = step * 4 + rng.randrange(3)
        kind = rng.random()
        if kind < broken_share:
            datagram = bytearray(frames(rng, time_boot_ms))
            datagram[rng.randrange(len(datagram))] ^= 0xFF  # a bad checksum, a broken header or length
            datagrams.append(b"\x55" + bytes(datagram) if rng.random() < 0.5 else bytes(datagram))
        else:
            datagrams.append(frames(rng, time_boot_ms, version=1 if kind < broken_share + 0.1 else 2))
    return datagrams


def clock_of(datagrams: list[bytes]) -> list[int]:
    clock, stamps = SutClock(), []
    for datagram in datagrams:
        clock.feed(datagram)
        stamps.append(clock.time_ns)
    return stamps


def test_the_clock_read_from_frame_bytes_is_pymavlinks_for_mavlink_2_and_1_datagrams():
    datagrams = stream(random.Random(7), broken_share=0.0)
    stamps = clock_of(datagrams)
    assert stamps == pymavlink_clock(datagrams)
    assert stamps[-1] > 1_000_000_000  # the stream's clock did advance


def test_a_broken_datagram_costs_only_its_own_frames():
    datagrams = stream(random.Random(11), broken_share=0.15)
    assert clock_of(datagrams) == pymavlink_clock(datagrams, parser_per_datagram=True)


def heartbeats_heard(sut: socket.socket) -> list[tuple[int, int]]:
    """The system and component of each ground-station heartbeat waiting at the SUT's socket."""
    parser = mavlink.MAVLink(None)
    heard = []
    sut.setblocking(False)
    while True:
        try:
            datagram = sut.recv(65536)
        except BlockingIOError:
            return heard
        heard += [(m.get_srcSystem(), m.get_srcComponent()) for m in parser.parse_buffer(datagram) or []
                  if m.get_type() == "HEARTBEAT" and m.type == mavlink.MAV_TYPE_GCS]


def test_the_ground_station_heartbeat_follows_the_sut_clock_in_the_clients_name_and_stops_in_a_blackout():
    with PortLease() as ports:
        tap_heartbeats(ports.api, ports.api + CLIENT_PORT_OFFSET)


def tap_heartbeats(api_port: int, client_port: int) -> None:
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    client.bind(("127.0.0.1", client_port))
    sut = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sut.bind(("127.0.0.1", 0))
    sut_link = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    client_link = mavlink.MAVLink(None, srcSystem=245, srcComponent=190)

    def sut_says(seconds: range) -> None:
        """Ten simulated seconds per wall second and more: far faster than MAVSDK's 1 Hz of wall time."""
        for second in seconds:
            for tenth in range(10):
                sut.sendto(mavlink.MAVLink_attitude_message(second * 1000 + tenth * 100, 0, 0, 0, 0, 0, 0).pack(sut_link), ("127.0.0.1", api_port))
                time.sleep(0.002)
        deadline = time.monotonic() + 30.0
        while tap.sut_time_ns < (seconds[-1] * 1000 + 900) * 1_000_000 and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.05)  # the tap sends a heartbeat just after reading the clock it is due on

    with ApiTap(api_port, client_port) as tap:
        sut_says(range(0, 1))
        heard_port = client.recvfrom(65536)[1][1]
        # a command, not a heartbeat: a fast flight may be over before MAVSDK's first, 1 s of wall time in
        client.sendto(mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0).pack(client_link),
                      ("127.0.0.1", heard_port))
        sut.settimeout(30.0)
        assert mavlink.MAVLink(None).parse_buffer(sut.recv(65536))[0].get_type() == "COMMAND_LONG"  # relayed, and its sender learnt
        sut_says(range(1, 21))
        # one per simulated second, in MAVSDK's name: 20 simulated seconds in well under 2 wall seconds
        assert heartbeats_heard(sut) == [(245, 190)] * 20
        tap.blackout = True
        sut_says(range(21, 31))
        assert heartbeats_heard(sut) == []
        tap.blackout = False
        sut_says(range(31, 36))
        assert heartbeats_heard(sut) == [(245, 190)] * 5
    client.close()
    sut.close()
