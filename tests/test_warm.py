"""Warm workers (RunOptions.warm): a worker keeps the simulator between evaluations, with the
autopilot inside it or a fresh SUT process connecting to it for each, and every flight in it is
the flight a cold start flies, to the last bit."""

from __future__ import annotations

import functools
import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT, alive, port_bound
from test_transport import SIMULATED
from harness.flight import logs, stack
from harness.flight.evaluation import evaluate
from harness.flight.results import RunOptions
from harness.flight.mavsdk_session import MavsdkSession
from harness.flight.ports import PortLease
from simlink import shared_memory
import sut_adapter
from sut_adapter import SutConfig
from harness.scenario.logical import load_logical
from harness.scenario.space import SearchSpace

MEMORY = RunOptions(transport="memory")
WARM = RunOptions(transport="memory", warm=True)
KEPT_SLOTS = 140


def point(profile, name: str, seed: int, drive: str | None = None):
    space = SearchSpace(load_logical(ROOT / "scenarios" / name, profile, drive), profile)
    return space, space.sample_feasible(np.random.default_rng(seed), 1)[0]


def simulated(result) -> list:
    return list(logs.messages(result.log_path, SIMULATED))


def simulator_pid(result) -> str:
    return logs.metadata(result.log_path)["bridge"]["pid"]


@pytest.fixture(autouse=True)
def nothing_kept_after():
    yield
    stack.close_kept()


@pytest.mark.slow
def test_warm_flights_are_the_cold_flights_to_the_last_bit_in_one_process(tmp_path, profile):
    points = {
        "wall": (point(profile, "table3/scenario_31.json", 4), 4),
        # Gusts, an intruder and a failure MAVSDK injects: state that must not leak into the next flight.
        "busy": (point(profile, "examples/intruder_gusts_failure.json", 7), 7),
        # The pilot drive sets parameters over MAVLink (its RC mapping, a takeoff altitude of
        # MIS_TAKEOFF_ALT) that the next flight's autopilot must not inherit.
        "pilot": (point(profile, "examples/wall.json", 3, "pilot"), 3),
    }
    order = ("wall", "busy", "pilot", "wall")
    cold = {name: evaluate(*p, seed=seed, out_dir=tmp_path / "cold", options=MEMORY, name=name) for name, (p, seed) in points.items()}
    kept = [evaluate(*points[name][0], seed=points[name][1], out_dir=tmp_path / "warm", options=WARM, name=f"{index}-{name}")
            for index, name in enumerate(order)]
    assert [simulator_pid(r) for r in kept] == [simulator_pid(kept[0])] * len(order)
    assert simulator_pid(kept[0]) not in {simulator_pid(r) for r in cold.values()}
    for result, name in zip(kept, order):
        assert (result.status, result.fitness) == (cold[name].status, cold[name].fitness)
        assert simulated(result) == simulated(cold[name]) and len(simulated(result)) > 1000
    assert "failure" in {m["event"] for topic, _ns, m in simulated(kept[1]) if topic == "/events"}
    # MAVSDK's view is the flight's own: the last flight's mission progress, not the one before.
    assert kept[-1].mavsdk["mission_progress"] == cold["wall"].mavsdk["mission_progress"]
    # A warm flight skips the start: the process, its imports and MAVSDK's discovery.
    assert kept[-1].timings["setup_s"] < cold["wall"].timings["setup_s"]


@pytest.mark.slow
@pytest.mark.parametrize("transport", ["tcp", "shm"])
def test_a_kept_simulator_flies_each_sut_process_as_a_cold_start_would(tmp_path, profile, transport):
    """A SUT in a process of its own (PX4's case, here the bundled autopilot over a socket):
    the simulator is kept, a fresh SUT process connects to it for each flight."""
    if transport == "shm" and not shared_memory.AVAILABLE:
        pytest.skip("shared memory needs Linux on x86-64")
    points = {"wall": (point(profile, "table3/scenario_31.json", 4), 4), "pilot": (point(profile, "examples/wall.json", 3, "pilot"), 3)}
    order = ("wall", "pilot", "wall")
    cold = {name: evaluate(*p, seed=seed, out_dir=tmp_path / "cold", options=RunOptions(transport=transport), name=name)
            for name, (p, seed) in points.items()}
    kept = [evaluate(*points[name][0], seed=points[name][1], out_dir=tmp_path / "warm", options=RunOptions(transport=transport, warm=True),
                     name=f"{index}-{name}") for index, name in enumerate(order)]
    assert [simulator_pid(r) for r in kept] == [simulator_pid(kept[0])] * len(order)
    for result, name in zip(kept, order):
        assert (result.status, result.fitness) == (cold[name].status, cold[name].fitness)
        assert simulated(result) == simulated(cold[name]) and len(simulated(result)) > 1000
        assert json.loads(logs.metadata(result.log_path)["placement"]["json"])["transport"] == transport


@pytest.mark.slow
def test_a_kept_simulator_flies_whichever_sut_process_each_evaluation_names(tmp_path, profile):
    """Mutation analysis and differential search alternate builds in a worker: the simulator is
    kept across them, and each flight is its own SUT's."""
    wall = point(profile, "table3/scenario_31.json", 4)
    suts = {"default": SutConfig(), "wary": SutConfig(params={"CP_DIST": 8.0})}
    cold = {name: evaluate(*wall, seed=4, out_dir=tmp_path / "cold", options=RunOptions(transport="tcp", sut=sut), name=name)
            for name, sut in suts.items()}
    order = ("default", "wary", "default")
    kept = [evaluate(*wall, seed=4, out_dir=tmp_path / "warm", options=RunOptions(transport="tcp", warm=True, sut=suts[name]), name=f"{index}-{name}")
            for index, name in enumerate(order)]
    assert [simulator_pid(r) for r in kept] == [simulator_pid(kept[0])] * len(order)
    assert cold["default"].min_clearance_m < cold["wary"].min_clearance_m
    for result, name in zip(kept, order):
        assert simulated(result) == simulated(cold[name])


@pytest.mark.slow
def test_a_worker_keeps_two_stacks_warm_for_the_two_kinds_of_flight_a_screened_campaign_alternates(tmp_path, profile):
    """A screened campaign's worker flies the cheap model (the bundled autopilot in memory) and the
    subject (its own process) batch by batch: both simulators stay warm; a third kind of flight
    closes the least recently used."""
    wall = point(profile, "table3/scenario_31.json", 4)
    kinds = {"cheap": WARM, "subject": RunOptions(transport="tcp", warm=True), "third": RunOptions(transport="unix", warm=True)}
    order = ("cheap", "subject", "cheap", "subject", "third", "subject", "cheap")
    kept = [evaluate(*wall, seed=4, out_dir=tmp_path, options=kinds[name], name=f"{index}-{name}") for index, name in enumerate(order)]
    pids = [simulator_pid(result) for result in kept]
    assert pids[0] == pids[2] and pids[1] == pids[3] == pids[5] and len({pids[0], pids[1], pids[4]}) == 3
    assert pids[6] not in pids[:6]  # the cheap one's was the least recently used when the third came
    assert all(simulated(result) == simulated(kept[0]) for result in kept)


@pytest.mark.slow
def test_a_flight_that_went_wrong_is_followed_by_a_fresh_process(tmp_path, profile, monkeypatch):
    wall = point(profile, "table3/scenario_31.json", 4)
    first = evaluate(*wall, seed=4, out_dir=tmp_path, options=WARM, name="first")
    real_upload = MavsdkSession.upload_and_start

    def refused(self, items, arm_retry_s):
        raise RuntimeError("COMMAND_DENIED")

    monkeypatch.setattr(MavsdkSession, "upload_and_start", refused)
    failed = evaluate(*wall, seed=4, out_dir=tmp_path, options=WARM, name="failed")
    assert failed.status == "mission_failed" and "COMMAND_DENIED" in failed.why
    monkeypatch.setattr(MavsdkSession, "upload_and_start", real_upload)
    after = evaluate(*wall, seed=4, out_dir=tmp_path, options=WARM, name="after")
    assert simulator_pid(failed) == simulator_pid(first) != simulator_pid(after)
    assert simulated(after) == simulated(first)


@pytest.mark.slow
def test_a_kept_simulator_that_died_between_evaluations_is_replaced(tmp_path, profile):
    wall = point(profile, "table3/scenario_31.json", 4)
    first = evaluate(*wall, seed=4, out_dir=tmp_path, options=WARM, name="first")
    pid = int(simulator_pid(first))
    subprocess.run(["kill", "-9", str(pid)], check=True)
    deadline = time.monotonic() + 5.0
    while alive(pid) and time.monotonic() < deadline:
        time.sleep(0.01)
    after = evaluate(*wall, seed=4, out_dir=tmp_path, options=WARM, name="after")
    assert after.status == first.status and simulated(after) == simulated(first)
    assert simulator_pid(after) != simulator_pid(first)


@pytest.mark.slow
def test_closing_what_is_kept_frees_its_process_and_ports(tmp_path, profile, monkeypatch):
    # Slots of its own: from slot 0, a test in another worker may lease the block as soon as it
    # is freed, binding its ports before they are looked at.
    monkeypatch.setattr(stack, "PortLease", functools.partial(PortLease, first_slot=KEPT_SLOTS))
    with PortLease(first_slot=KEPT_SLOTS) as free:
        slot = free.slot
    result = evaluate(*point(profile, "table3/scenario_31.json", 4), seed=4, out_dir=tmp_path, options=WARM)
    pid = int(simulator_pid(result))
    assert port_bound(free.control)
    stack.close_kept()
    deadline = time.monotonic() + 5.0
    while alive(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not alive(pid)
    assert not port_bound(free.control) and not port_bound(free.api, socket.SOCK_DGRAM)
    with PortLease(first_slot=KEPT_SLOTS) as again:
        assert again.slot == slot


def test_a_serving_simulator_refuses_a_world_it_cannot_load_and_flies_on(tmp_path):
    """The serving protocol itself (python -m sut_adapter.inline --serve): a load request whose
    world does not load, or that names none, is refused with the reason; the process then waits
    for the next and quits when asked."""
    with PortLease(first_slot=130) as ports:
        argv = [sys.executable, "-m", "sut_adapter.inline", "--serve", "--control-port", str(ports.control), "--",
                "--api", f"udp:127.0.0.1:{ports.api}"]
        process = subprocess.Popen(argv, stderr=subprocess.PIPE, cwd=ROOT)
        try:
            refused = _exchange(ports.control, {"op": "load", "world": str(tmp_path / "missing.json"), "mcap": str(tmp_path / "x.mcap")})
            assert refused["event"] == "load_refused" and "missing.json" in refused["why"]
            incomplete = _exchange(ports.control, {"op": "load", "world": str(tmp_path / "missing.json")})
            assert incomplete["event"] == "load_refused" and "names a world and an mcap file" in incomplete["why"]
            _exchange(ports.control, {"op": "quit"}, expect_answer=False)
            assert process.wait(timeout=10) == 0
        finally:
            process.kill()


def _exchange(port: int, request: dict, expect_answer: bool = True) -> dict | None:
    deadline = time.monotonic() + 20.0
    while True:
        try:
            connection = socket.create_connection(("127.0.0.1", port), timeout=10.0)
            break
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)
    with connection:
        connection.sendall(json.dumps(request).encode() + b"\n")
        if not expect_answer:
            return None
        return json.loads(connection.makefile().readline())


def test_each_flight_of_a_serving_process_starts_from_the_start_up_parameters():
    from autopilot.params import Params
    from sut_adapter.inline import fresh_autopilots

    start_up = Params({"MPC_XY_CRUISE": 4.0})
    autopilots = fresh_autopilots(start_up, ("127.0.0.1", 9))
    first, second = autopilots(), autopilots()
    try:
        first.autopilot.params.set("MIS_TAKEOFF_ALT", 12.0)  # as MAVSDK's PARAM_SET during the first flight
        assert second.autopilot.params["MIS_TAKEOFF_ALT"] == Params()["MIS_TAKEOFF_ALT"] != 12.0
        assert second.autopilot.params["MPC_XY_CRUISE"] == 4.0 and start_up["MIS_TAKEOFF_ALT"] != 12.0
    finally:
        first.close()
        second.close()


@pytest.mark.parametrize("argv, why", [
    (["--serve"], "--serve needs a --control-port"),
    (["--serve", "--control-port", "99999"], "99999 is not a port: give 0 to 65535"),
    (["--serve", "--control-port", "24999", "--sim-port", "0", "--sim-protocol", "ardupilot-json"],
     "ArduPilot's JSON link (UDP) is served one flight per process"),
])
def test_serving_is_refused_where_it_cannot_work(argv, why):
    # In a process of its own: a simulator that took the request would serve until stopped.
    refused = subprocess.run([sys.executable, "-m", "sim_bridge", *argv], capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert refused.returncode == 2 and why in refused.stderr


def test_a_kept_stack_is_kept_for_whichever_sut_process_flies_but_not_for_other_placements():
    px4_config = SutConfig(name="command", command="px4 --sim {sim_port} --api {api_port}")
    px4 = sut_adapter.system_for(px4_config)
    key = stack._kept_for(RunOptions(transport="tcp", warm=True, sut=px4_config), px4)
    other_build = SutConfig(name="command", command="px4-mutant --sim {sim_port} --api {api_port}", params={"CP_DIST": 3.0})
    assert stack._kept_for(RunOptions(transport="tcp", warm=True, sut=other_build), sut_adapter.system_for(other_build)) == key
    for other in (RunOptions(transport="tcp", warm=True, sut=px4_config, cores=2), RunOptions(transport="tcp", warm=True, sut=px4_config, rate_hz=400.0),
                  RunOptions(transport="tcp", warm=True, sut=px4_config, pin_cpu=False), RunOptions(transport="tcp", warm=True, sut=px4_config, hold_after_s=1.0)):
        assert stack._kept_for(other, px4) != key
    frozen = SutConfig(name="command", command="px4 --sim {sim_port} --api {api_port}", hold="frozen")
    assert stack._kept_for(RunOptions(transport="tcp", warm=True, sut=frozen), sut_adapter.system_for(frozen)) != key
    # With the SUT inside the simulator, which SUT is what the simulator is.
    bundled, mutant = SutConfig(), SutConfig(params={"CP_DIST": 3.0})
    assert stack._kept_for(RunOptions(transport="memory", sut=bundled), sut_adapter.system_for(bundled)) != \
        stack._kept_for(RunOptions(transport="memory", sut=mutant), sut_adapter.system_for(mutant))


def test_only_a_connection_is_served_warm():
    assert stack.serves_warm(RunOptions(transport="tcp"), sut_adapter.system_for(SutConfig(name="command", command="x {sim_port} {api_port}")))
    assert not stack.serves_warm(RunOptions(), sut_adapter.system_for(SutConfig(name="ardupilot", ardupilot_bin=sys.executable)))


def test_a_sut_that_does_not_start_leaves_nothing_kept(tmp_path, profile):
    """Its evaluation says so; the next warm evaluation starts a fresh simulator."""
    missing = SutConfig(name="command", command=f"{tmp_path}/no-such-autopilot --sim {{sim_port}} --api {{api_port}}")
    wall = point(profile, "table3/scenario_31.json", 4)
    for warm in (False, True):
        result = evaluate(*wall, seed=4, out_dir=tmp_path, options=RunOptions(transport="tcp", warm=warm, sut=missing), name=f"warm-{warm}")
        assert result.status == "sut_crashed" and "no-such-autopilot" in result.why
        assert stack._kept == []


@pytest.mark.slow
def test_the_first_repeat_flies_on_a_simulator_started_before_it(tmp_path, profile):
    """`stella run --repeat` compares its flights: the first must not share its start with the simulator's."""
    options = RunOptions(transport="tcp", warm=True)
    stack.start_kept(options)
    serving = [pid for pid in _children() if "--serve" in Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace").split("\0")]
    result = evaluate(*point(profile, "table3/scenario_31.json", 4), seed=4, out_dir=tmp_path, options=options)
    assert [int(simulator_pid(result))] == serving


def _children() -> list[int]:
    return [int(pid) for task in Path("/proc/self/task").iterdir() for pid in (task / "children").read_text().split()]


def test_a_serving_simulator_whose_harness_is_gone_quits(tmp_path):
    """Its harness's death normally signals it; if that signal never came (a harness killed
    while it was being started), it must not wait forever on its port block."""
    with PortLease(first_slot=131) as ports:
        bridge = [sys.executable, "-m", "sut_adapter.inline", "--serve", "--control-port", str(ports.control)]
        autopilot = ["--", "--api", f"udp:127.0.0.1:{ports.api}"]
        # A harness that starts it without the death signal (naming itself, as the harness
        # does), sees it serving, and dies.
        start = (f"import os, subprocess, time; p = subprocess.Popen({bridge!r} + ['--harness-pid', str(os.getpid())] + {autopilot!r}, "
                 "start_new_session=True, stdout=subprocess.DEVNULL); time.sleep(1.5); print(p.pid, p.poll() is None)")
        harness = subprocess.run([sys.executable, "-c", start], capture_output=True, text=True, cwd=ROOT, timeout=30, check=True)
        server, serving = harness.stdout.split()
        server = int(server)
        assert serving == "True"
        deadline = time.monotonic() + 20.0
        while alive(server) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not alive(server)
