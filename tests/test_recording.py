"""The bridge's MCAP recorder: a log it writes compressed or not holds the same messages."""

from __future__ import annotations

import io
import json
import os
import signal
import socket

import numpy as np
import pytest
from mcap.reader import make_reader

from conftest import ROOT, chunk_compressions
from harness.flight import logs
from harness.scenario.logical import load_logical
from harness.scenario.profile import load_profile
from harness.scenario.space import SearchSpace
from harness.scenario.world import world_spec
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


def quiet_world():
    profile = load_profile("default")
    space = SearchSpace(load_logical(ROOT / "scenarios" / "table3" / "scenario_31.json", profile), profile)
    return world_spec(space, space.sample_feasible(np.random.default_rng(0), 1)[0], 0)


def test_a_stop_that_arrives_while_the_recording_is_finished_waits_until_the_file_is_complete(tmp_path, monkeypatch):
    """The harness's SIGTERM can land as the simulator finishes a flight's file (closing a warm
    stack after a failed set-up): it is held until the file is complete, then stops the simulator."""
    from sim_bridge import __main__ as simulator
    from sim_bridge.bridge_io import BridgeConfig
    from sim_bridge.channel import ControlChannel

    real_exit = Recorder.__exit__

    def stopped_while_finishing(self, *exc_info):
        os.kill(os.getpid(), signal.SIGTERM)
        real_exit(self, *exc_info)

    monkeypatch.setattr(Recorder, "__exit__", stopped_while_finishing)
    previous = signal.signal(signal.SIGTERM, simulator._interrupt)
    log = tmp_path / "flight.mcap"

    def never_connects():
        raise socket.timeout("no SUT")

    try:
        with pytest.raises(KeyboardInterrupt):
            simulator.fly(quiet_world(), BridgeConfig(), log, ControlChannel(None), never_connects, "none")
    finally:
        signal.signal(signal.SIGTERM, previous)
    recording = logs.Recording(log)  # refuses a file whose end was cut off
    summary = json.loads(dict(recording.metadata)["bridge_summary"]["json"])
    assert summary["end_reason"] == "sut_never_connected"
