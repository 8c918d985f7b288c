"""The bridge's MCAP recorder: a log it writes compressed or not holds the same messages."""

from __future__ import annotations

import io

from mcap.reader import make_reader

from conftest import chunk_compressions
from sim_bridge.recording import Recorder


def recorded(compression: str) -> bytes:
    stream = io.BytesIO()
    with Recorder(stream, compression=compression) as recorder:
        recorder.metadata("bridge", {"rate_hz": "250.0"})
        for step in range(2000):
            recorder.write("/uav/state", time_ns=step * 4_000_000, message={"t": step * 0.004, "north_m": step * 0.01, "east_m": 0.0, "up_m": 8.0})
    return stream.getvalue()


def contents(data: bytes) -> tuple[list, list]:
    reader = make_reader(io.BytesIO(data))
    messages = [(channel.topic, message.log_time, message.data) for _schema, channel, message in reader.iter_messages()]
    return messages, [(record.name, record.metadata) for record in reader.iter_metadata()]


def test_an_uncompressed_recording_holds_the_same_messages_as_a_compressed_one():
    compressed, plain = recorded("zstd"), recorded("none")
    assert chunk_compressions(io.BytesIO(compressed)) == {"zstd"}
    assert chunk_compressions(io.BytesIO(plain)) == {""}
    assert len(plain) > 3 * len(compressed)
    assert contents(plain) == contents(compressed)
    assert len(contents(plain)[0]) == 2000
