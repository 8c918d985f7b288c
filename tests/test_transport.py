"""The bundled autopilot inside the simulator's process (--transport memory), and in its own
process over a Unix-domain socket (--transport unix) or through shared memory (--transport shm),
flies the same flights as over TCP, to the last bit: the same bytes on the simulator link, the
same log."""

from __future__ import annotations

import os

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from conftest import ROOT
from harness.flight import logs
from harness.flight.evaluation import evaluate
from harness.flight.results import RunOptions
from harness.flight.stack import in_memory, placed_transport
from harness.scenario.logical import load_logical
from harness.scenario.space import SearchSpace
from harness.tools.cli import main
from autopilot.app import Autopilot
from autopilot.inline import InProcessLink
from autopilot.params import Params
from sim_bridge.sut_link import TRANSPORTS, SutLink
from sut_adapter import SutConfig
from simlink import codec, shared_memory
import sut_adapter

# Everything the simulator records: its link's bytes both ways, the vehicle, the clearance, the
# scene and the events (the API link's traffic follows wall time and is left out).
SIMULATED = ["/mavlink/sim", "/uav/state", "/clearance", "/scene", "/sensor/obstacle_distance", "/events", "/wind", "/pilot"]


def both_ways(tmp_path, space, x, seed):
    flights = {transport: evaluate(space, x, seed=seed, out_dir=tmp_path / transport, options=RunOptions(cores=1, transport=transport))
               for transport in TRANSPORTS[1:]}
    records = {transport: [(topic, ns, message) for topic, ns, message in logs.messages(result.log_path, SIMULATED)]
               for transport, result in flights.items()}
    return flights, records


@pytest.mark.slow
@pytest.mark.parametrize("scenario, seed, drive", [
    (ROOT / "scenarios" / "table3" / "scenario_31.json", 4, None),
    # A SUT-side failure: the bridge stops while MAVSDK tells the autopilot, whose API link is
    # then served between the bridge's polls rather than by its own loop.
    (ROOT / "tests" / "data" / "scenarios" / "wall_baro_wrong_gps_off.json", 2, None),
    (ROOT / "scenarios" / "examples" / "intruder_gusts_failure.json", 7, None),
    # RC frames on the simulator link, Position mode and collision prevention stopping at a wall.
    (ROOT / "scenarios" / "examples" / "wall.json", 3, "pilot"),
])
def test_every_transport_flies_the_same_flight_to_the_last_bit(tmp_path, profile, scenario, seed, drive):
    space = SearchSpace(load_logical(scenario, profile, drive), profile)
    x = space.sample_feasible(np.random.default_rng(seed), 1)[0]
    flights, records = both_ways(tmp_path, space, x, seed)
    for transport in ("memory", "unix", "shm"):
        assert (flights[transport].status, flights[transport].fitness) == (flights["tcp"].status, flights["tcp"].fitness)
        assert len(records["tcp"]) > 1000 and records[transport] == records["tcp"], transport
    for direction in ("to_sut", "from_sut"):
        numbers = sequence_numbers(records["memory"], direction)
        assert len(numbers) > 5000 and all((b - a) % 256 == 1 for a, b in zip(numbers, numbers[1:])), f"{direction} skips or repeats a number"


def sequence_numbers(records, direction: str) -> list[int]:
    """The MAVLink sequence numbers on the simulator link, one way, in the order sent."""
    splitter = codec.FrameSplitter({msgid: cls.crc_extra for msgid, cls in mavlink.mavlink_map.items()})
    return [frame[4] for topic, _ns, message in records if topic == "/mavlink/sim" and message["direction"] == direction
            for _msgid, _payload, frame in splitter.feed(bytes.fromhex(message["hex"]))]


@pytest.mark.slow
@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="an evaluation gets two cores only where there are two")
def test_auto_runs_the_bundled_autopilot_in_memory_on_one_core_and_through_shared_memory_on_two(tmp_path, profile):
    space = SearchSpace(load_logical(ROOT / "scenarios" / "table3" / "scenario_31.json", profile), profile)
    x = space.sample_feasible(np.random.default_rng(4), 1)[0]
    flights = {cores: evaluate(space, x, seed=4, out_dir=tmp_path / str(cores), options=RunOptions(cores=cores)) for cores in (1, 2)}
    assert {cores: logs.json_metadata(result.log_path, "placement") for cores, result in flights.items()} == {
        1: {"cores": 1, "transport": "memory"}, 2: {"cores": 2, "transport": "shm" if shared_memory.AVAILABLE else "unix"}}
    assert flights[1].fitness == flights[2].fitness and flights[2].status == "ok"


def test_auto_counts_the_cores_the_machine_has(monkeypatch):
    """Two cores asked for on a one-core machine: the pair would share it, so in memory."""
    bundled, command = sut_adapter.system_for(SutConfig()), sut_adapter.system_for(SutConfig(name="command", command="my-autopilot --sim {sim_port} --api {api_port}"))
    monkeypatch.setattr(shared_memory, "AVAILABLE", True)
    monkeypatch.setattr(os, "sched_getaffinity", lambda _pid: {0})
    assert placed_transport(RunOptions(cores=2), bundled) == "memory" and in_memory(RunOptions(cores=2), bundled)
    assert placed_transport(RunOptions(cores=2), command) == "tcp"
    monkeypatch.setattr(os, "sched_getaffinity", lambda _pid: {0, 1})
    assert placed_transport(RunOptions(cores=2), bundled) == "shm" and not in_memory(RunOptions(cores=2), bundled)
    assert placed_transport(RunOptions(cores=1), bundled) == "memory" and placed_transport(RunOptions(cores=2), command) == "tcp"
    assert placed_transport(RunOptions(cores=2, transport="unix"), bundled) == "unix"
    for transport in ("unix", "shm"):
        with pytest.raises(sut_adapter.SutError, match=f"{transport} carries the bundled autopilot only; command connects to the simulator over TCP"):
            placed_transport(RunOptions(transport=transport), command)
    with pytest.raises(ValueError, match="transport 'Unix' is not one of auto, tcp, memory, unix, shm"):
        RunOptions(transport="Unix")


def test_auto_takes_a_unix_socket_where_shared_memory_is_not_available(monkeypatch):
    bundled = sut_adapter.system_for(SutConfig())
    monkeypatch.setattr(os, "sched_getaffinity", lambda _pid: {0, 1})
    monkeypatch.setattr(shared_memory, "AVAILABLE", False)
    assert placed_transport(RunOptions(cores=2), bundled) == "unix"
    with pytest.raises(sut_adapter.SutError, match="shm needs Linux on x86-64, which this machine is not: use --transport unix"):
        placed_transport(RunOptions(transport="shm"), bundled)


def test_unix_is_refused_for_a_sut_that_connects_over_tcp_only(capsys):
    assert main(["run", str(ROOT / "scenarios" / "table3" / "scenario_05.json"), "--sut", "command",
                 "--sut-command", "my-autopilot --sim {sim_port} --api {api_port}", "--transport", "unix"]) == 2
    assert "--transport: unix carries the bundled autopilot only; command connects to the simulator over TCP" in capsys.readouterr().err


def test_memory_is_refused_for_a_sut_in_a_process_of_its_own(capsys):
    assert main(["run", str(ROOT / "scenarios" / "table3" / "scenario_05.json"), "--sut", "command",
                 "--sut-command", "my-autopilot --sim {sim_port} --api {api_port}", "--transport", "memory"]) == 2
    assert "--transport: memory carries the bundled autopilot only; command runs in a process of its own" in capsys.readouterr().err


def test_an_autopilot_that_raises_inside_the_bridge_is_a_crashed_sut_not_a_crashed_simulator(capsys):
    """The bridge ends a run whose SUT link raises OSError as sut_disconnected, which the harness
    reports as a crashed SUT with the traceback from stderr."""
    class Broken(Autopilot):
        def _on_sim_data(self, *_args):
            raise ZeroDivisionError("a bug in the autopilot")

    link: SutLink = InProcessLink(Broken(Params()), ("127.0.0.1", 9))
    try:
        with pytest.raises(ConnectionAbortedError, match="the autopilot crashed"):
            link.send(b"frames")
        assert "ZeroDivisionError: a bug in the autopilot" in capsys.readouterr().err
    finally:
        link.close()
