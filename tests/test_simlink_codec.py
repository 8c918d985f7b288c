"""The fast per-step codec is byte-for-byte pymavlink, and the splitter survives garbage."""

from __future__ import annotations

import random
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink

from simlink import codec


def pymavlink_encoder(sysid=1, compid=1):
    mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    mav.robust_parsing = True
    return mav


def random_sensor_values(rng: random.Random) -> tuple[float, ...]:
    values = [rng.uniform(-20, 20) for _ in range(13)]
    values[rng.randrange(13)] = 0.0  # zeros exercise payload truncation
    return tuple(values)


def test_hil_sensor_bytes_equal_pymavlink():
    rng = random.Random(1)
    mav = pymavlink_encoder(sysid=1, compid=51)
    for seq in range(300):
        values = random_sensor_values(rng)
        time_usec = rng.randrange(0, 2**40)
        fields = rng.randrange(0, 2**13)
        expected = mav.hil_sensor_encode(time_usec, *values, fields, 0).pack(mav)
        ours = codec.encode_hil_sensor(seq=seq, sysid=1, compid=51, time_usec=time_usec, values=values, fields_updated=fields)
        assert ours == bytes(expected)
        mav.seq = (mav.seq + 1) % 256


# The simulator link's 10-50 Hz messages, with the range of each C type.
SIM_MESSAGES = ("HIL_GPS", "HIL_STATE_QUATERNION", "OBSTACLE_DISTANCE", "DISTANCE_SENSOR", "RC_CHANNELS")
INTEGER_RANGES = {"uint8_t": (0, 2**8 - 1), "uint16_t": (0, 2**16 - 1), "uint32_t": (0, 2**32 - 1), "uint64_t": (0, 2**64 - 1),
                  "int8_t": (-(2**7), 2**7 - 1), "int16_t": (-(2**15), 2**15 - 1), "int32_t": (-(2**31), 2**31 - 1)}


def random_fields(rng: random.Random, message_class) -> list:
    """Declared-order values; about a third are zero, which exercises MAVLink 2's truncation."""
    values = []
    for name, kind in zip(message_class.fieldnames, message_class.fieldtypes):
        length = message_class.array_lengths[message_class.ordered_fieldnames.index(name)]
        def one():
            if rng.random() < 0.3:
                return 0 if kind != "float" else 0.0
            if kind == "float":
                return float(struct.unpack("<f", struct.pack("<f", rng.uniform(-1e4, 1e4)))[0])
            return rng.randint(*INTEGER_RANGES[kind])
        values.append([one() for _ in range(length)] if length else one())
    return values


@pytest.mark.parametrize("name", SIM_MESSAGES)
def test_message_codec_bytes_and_fields_equal_pymavlink(name):
    message_class = mavlink.mavlink_map[getattr(mavlink, f"MAVLINK_MSG_ID_{name}")]
    ours = codec.MessageCodec(message_class)
    rng = random.Random(name)
    mav = pymavlink_encoder(sysid=1, compid=51)
    decoder = pymavlink_encoder()
    encode = getattr(mav, f"{name.lower()}_encode")
    for seq in range(200):
        values = random_fields(rng, message_class)
        frame = ours.encode(seq, 1, 51, *values)
        assert frame == bytes(encode(*values).pack(mav))
        mav.seq = (mav.seq + 1) % 256
        theirs = decoder.decode(bytearray(frame))
        decoded = ours.decode(frame[codec.HEADER_LEN : codec.HEADER_LEN + frame[1]])
        for field in message_class.fieldnames:
            value = getattr(decoded, field)
            assert (list(value) if isinstance(value, tuple) else value) == getattr(theirs, field), field


def test_message_codec_refuses_text_fields():
    with pytest.raises(ValueError, match="STATUSTEXT: char fields"):
        codec.MessageCodec(mavlink.MAVLink_statustext_message)


def test_hil_actuator_controls_bytes_equal_pymavlink_and_round_trip():
    rng = random.Random(2)
    mav = pymavlink_encoder(sysid=1, compid=1)
    splitter = codec.FrameSplitter({93: codec.HIL_ACTUATOR_CONTROLS_CRC_EXTRA})
    for seq in range(300):
        controls = tuple([rng.uniform(0, 1) for _ in range(4)] + [0.0] * 12)
        time_usec = rng.randrange(0, 2**40)
        expected = bytes(mav.hil_actuator_controls_encode(time_usec, controls, 0, 1).pack(mav))
        ours = codec.encode_hil_actuator_controls(seq=seq, sysid=1, compid=1, time_usec=time_usec, controls=controls, mode=0, flags=1)
        assert ours == expected
        ((msgid, payload, frame),) = splitter.feed(ours)
        assert msgid == 93 and frame == ours
        decoded_time, flags, decoded, mode = codec.decode_hil_actuator_controls(payload)
        assert (decoded_time, flags, mode) == (time_usec, 1, 0)
        assert decoded == pytest.approx(controls, rel=1e-6)
        mav.seq = (mav.seq + 1) % 256


def test_splitter_skips_garbage_and_bad_checksums_and_keeps_partial_frames():
    mav = pymavlink_encoder()
    good = bytes(mav.heartbeat_encode(2, 12, 0, 0, 3).pack(mav))
    corrupted = bytearray(good)
    corrupted[-1] ^= 0xFF
    splitter = codec.FrameSplitter({0: mavlink.MAVLink_heartbeat_message.crc_extra})
    stream = b"\x00garbage\xfd" + bytes(corrupted) + good
    frames = splitter.feed(stream[:-3])
    assert frames == []
    frames = splitter.feed(stream[-3:])
    assert [f[2] for f in frames] == [good]
    assert splitter.bad_frames == 1
    assert splitter.skipped_bytes > 0


ANSWER_EXTRAS = {codec.HIL_ACTUATOR_CONTROLS_ID: codec.HIL_ACTUATOR_CONTROLS_CRC_EXTRA}


# Junk that starts like a frame: a frame-start byte, any announced length and flags (signed too).
FRAME_LIKE = st.builds(lambda length, flags, rest: bytes((codec.STX_V2, length, flags)) + rest, st.integers(0, 255), st.integers(0, 255), st.binary(max_size=80))
JUNK = st.lists(st.one_of(st.binary(max_size=300), FRAME_LIKE), min_size=1, max_size=4).map(b"".join)


@settings(max_examples=1000, deadline=None)
@given(junk=st.lists(JUNK, min_size=1, max_size=8), cuts=st.lists(st.integers(min_value=0), max_size=6), seed=st.integers(0, 2**32 - 1))
def test_every_answer_between_any_junk_is_recovered_however_the_stream_is_cut(junk, cuts, seed):
    """Property: junk between well-formed answers never costs an answer nor invents one, for any
    junk (frame-start bytes, announced lengths and all) and any way the stream arrives in pieces."""
    rng = random.Random(seed)
    answers = [codec.encode_hil_actuator_controls(seq=i, sysid=1, compid=1, time_usec=rng.randrange(2**40),
                                                  controls=tuple(rng.uniform(0, 1) for _ in range(16)), mode=0, flags=1) for i in range(len(junk))]
    stream = b"".join(bad + answer for bad, answer in zip(junk, answers))
    splitter = codec.FrameSplitter(ANSWER_EXTRAS)
    positions = sorted({min(c, len(stream)) for c in cuts} | {0, len(stream)})
    frames = [f for a, b in zip(positions, positions[1:]) for f in splitter.feed(stream[a:b])]
    assert [frame for _msgid, _payload, frame in frames] == answers


def test_a_receive_that_also_watches_a_second_socket_ends_when_that_one_has_input():
    """The bundled autopilot waits on its simulator link and its API link at once: MAVSDK's
    requests during a frozen hold are answered when they come, not at the next periodic check."""
    import socket
    import time

    sim, simulator = socket.socketpair()
    api, ground_station = socket.socket(socket.AF_INET, socket.SOCK_DGRAM), socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    with sim, simulator, api, ground_station:
        api.bind(("127.0.0.1", 0))
        codec.set_receive_timeout(sim, 5.0)
        ground_station.sendto(b"heartbeat", api.getsockname())
        started = time.monotonic()
        with pytest.raises(BlockingIOError):
            codec.receive(sim, also=api, wait_s=5.0)
        assert time.monotonic() - started < 1.0  # woken by the datagram, not by the 5 s wait
        simulator.sendall(b"sensors")
        assert codec.receive(sim, also=api, wait_s=5.0) == b"sensors"  # the simulator first, whatever else waits
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as silent, pytest.raises(BlockingIOError):
            codec.receive(sim, also=silent, wait_s=0.05)  # nothing anywhere: the wait ends
