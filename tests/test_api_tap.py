"""The API tap's stamps: the SUT's clock read from its frames' bytes is the clock pymavlink's
parser reads, frame for frame, for every kind of datagram a SUT may send."""

from __future__ import annotations

import random

from pymavlink.dialects.v20 import common as mavlink

from harness.flight.api_tap import SutClock


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
