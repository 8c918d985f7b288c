"""A generated fuzzer for both MAVLink links: what a broken, hostile or merely newer peer sends.

Each call of `junk(rng)` gives the bytes of one bad frame of a kind drawn at random: noise,
truncated or bit-flipped frames, lengths that announce more than arrives, signed frames without
their signature, well-formed frames of any message in the dialect with random payloads, frames
longer than their message (a newer dialect's extensions), actuator frames with non-finite or
absurd values, stale (out-of-order) answers and floods of one small frame. Seeded, so a failure
replays.
"""

from __future__ import annotations

import random
import struct

from pymavlink.dialects.v20 import common as mavlink

from simlink import codec

MESSAGES = sorted(mavlink.mavlink_map.items())
KINDS = ("noise", "truncated", "bit_flip", "announces_more", "unsigned_signed", "any_message", "over_long", "odd_actuator", "stale_answer", "flood")


def frame(msgid: int, payload: bytes, seq: int = 0, signed: bool = False) -> bytes:
    """A MAVLink 2 frame with a correct checksum for any payload (of any length up to 255)."""
    crc_extra = mavlink.mavlink_map[msgid].crc_extra
    header = struct.pack("<BBBBBBBHB", codec.STX_V2, len(payload), codec.INCOMPAT_SIGNED if signed else 0, 0, seq & 0xFF, 1, 1, msgid & 0xFFFF, msgid >> 16)
    crc = codec._mcrf4xx(header[1:] + payload + bytes((crc_extra,)), 0xFFFF)
    return header + payload + struct.pack("<H", crc)


def _odd_float(rng: random.Random) -> float:
    return rng.choice([float("nan"), float("inf"), -float("inf"), 1e30, -1e30, rng.uniform(-5.0, 5.0), 0.0])


def actuator_answer(time_usec: int, controls: tuple[float, ...]) -> bytes:
    return codec.encode_hil_actuator_controls(seq=0, sysid=1, compid=1, time_usec=time_usec, controls=controls, mode=0, flags=1)


# Kinds after which the peer's next answer still arrives intact. A frame flagged as signed takes
# the next 13 bytes as its signature, as any MAVLink parser does, so it swallows what follows;
# odd actuator values are answers a vehicle cannot fly on.
SURVIVABLE = tuple(k for k in KINDS if k not in ("unsigned_signed", "odd_actuator"))


# Kinds that never hold a well-formed HIL_ACTUATOR_CONTROLS, i.e. never answer a lockstep step.
NEVER_ANSWERS = ("noise", "truncated", "bit_flip", "announces_more", "unsigned_signed", "any_message", "flood")


def junk(rng: random.Random, kinds: tuple[str, ...] = KINDS, answers: bool = True) -> tuple[str, bytes]:
    """(kind, bytes) of one bad frame of a kind drawn from kinds; without answers, never a
    well-formed HIL_ACTUATOR_CONTROLS (kinds then must be among NEVER_ANSWERS)."""
    kind = rng.choice(kinds)
    msgid, message = rng.choice([m for m in MESSAGES if answers or m[0] != codec.HIL_ACTUATOR_CONTROLS_ID])
    payload = rng.randbytes(min(255, max(1, message.unpacker.size)))
    whole = frame(msgid, payload, seq=rng.randrange(256))
    if kind == "noise":
        return kind, rng.randbytes(rng.randrange(1, 300))
    if kind == "truncated":
        return kind, whole[: rng.randrange(1, len(whole))]
    if kind == "bit_flip":
        data = bytearray(whole)
        data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
        return kind, bytes(data)
    if kind == "announces_more":
        return kind, bytes((codec.STX_V2, 255)) + rng.randbytes(rng.randrange(0, 40))
    if kind == "unsigned_signed":
        return kind, frame(msgid, payload, signed=True)  # the flag says a 13-byte signature follows; none does
    if kind == "any_message":
        return kind, whole
    if kind == "over_long":
        return kind, frame(codec.HIL_ACTUATOR_CONTROLS_ID, rng.randbytes(rng.randrange(82, 256)))
    if kind == "odd_actuator":
        return kind, actuator_answer(rng.randrange(2**63), tuple(_odd_float(rng) for _ in range(16)))
    if kind == "stale_answer":
        return kind, actuator_answer(rng.randrange(1000), (0.0,) * 16)
    small = frame(codec.HIL_SENSOR_ID, rng.randbytes(8))
    return kind, small * rng.randrange(20, 200)
