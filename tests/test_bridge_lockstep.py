"""The bridge as a real process against a scripted SUT over real sockets."""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import ROOT, port_bound
from scripted_sut import clock_command
from harness.flight import logs
from harness.flight.ports import PortLease
from sim_bridge.control import AddObstacle, FailureInjected, Finished, Holding, InjectFailure, MoveObstacle, RemoveObstacle, Run, Stop

SCRIPTED_SUT = ROOT / "tests" / "scripted_sut.py"
BODY = {"length_m": 0.6, "width_m": 0.6, "height_m": 0.2}


def world(*, time_limit_s=9.0, wind_north=0.0, seed=1, obstacles=()):
    return {
        "scenario": "bridge test",
        "seed": seed,
        "origin": {"lat_deg": 47.397742, "lon_deg": 8.545594, "alt_m": 488.0},
        "terrain": {"kind": "flat"},
        "surface": {"kind": "land", "water": []},
        "atmosphere": {"wind_north_m_s": wind_north, "wind_east_m_s": 0.0, "temperature_c": 15.0},
        "visibility_m": 10000.0,
        "sensor": {"max_range_m": 20.0, "min_range_m": 0.2, "fov_deg": 100.0, "update_hz": 20.0, "full_range_visibility_m": 1000.0, "floor_range_m": 2.0, "range_m": 20.0},
        "obstacles": list(obstacles),
        "uav": {"start": {"north_m": 0.0, "east_m": 0.0, "up_m": 0.0}, "body": BODY},
        "mission": {"takeoff_altitude_m": 3.0, "waypoints": [{"north_m": 0.0, "east_m": 0.0, "altitude_m": 3.0}], "cruise_speed_m_s": 1.0, "land": False},
        "safety_distance_m": 1.0,
        "time_limit_s": time_limit_s,
    }


def fly(tmp_path: Path, spec: dict, mode: str, steps: int = 100, stall_timeout_s: float = 10.0, name: str = "run", bridge_args: tuple[str, ...] = (),
        late_first_s: float = 0.0):
    """Run the bridge and the scripted SUT to the end; returns (exit code, summary, log path)."""
    world_path = tmp_path / f"{name}.world.json"
    world_path.write_text(json.dumps(spec))
    log_path = tmp_path / f"{name}.mcap"
    with PortLease(first_slot=100) as ports:
        bridge = subprocess.Popen(
            [sys.executable, "-m", "sim_bridge", "--world", str(world_path), "--sim-port", str(ports.sim), "--mcap", str(log_path),
             "--hold-after-s", "0", "--stall-timeout-s", str(stall_timeout_s), "--connect-timeout-s", "20", *bridge_args],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT,
        )
        sut = subprocess.Popen([sys.executable, str(SCRIPTED_SUT), "--port", str(ports.sim), "--mode", mode, "--steps", str(steps),
                                "--late-first-s", str(late_first_s)], cwd=ROOT)
        try:
            out, err = bridge.communicate(timeout=60)
        finally:
            sut.kill()
            sut.wait()
            bridge.kill()
        assert not port_bound(ports.sim), "the bridge left its simulator port bound"
    summary = json.loads(out.decode().strip().splitlines()[-1])
    return bridge.returncode, summary, log_path


def states(log_path: Path) -> list[dict]:
    return [m for _t, _ns, m in logs.messages(log_path, ["/uav/state"])]


@pytest.mark.slow
def test_hover_throttle_holds_altitude(tmp_path):
    code, summary, log_path = fly(tmp_path, world(), "hover")
    assert code == 0 and summary["end_reason"] == "time_limit"
    track = states(log_path)
    handover = next(s for s in track if s["t"] >= 5.0)  # the SUT switches to the hover throttle
    at_end = track[-1]
    assert handover["up_m"] == pytest.approx(3.0, abs=0.5)
    # Stated tolerance: 0.3 m of altitude change over 4 s at the hover throttle.
    assert abs(at_end["up_m"] - handover["up_m"]) < 0.3
    assert abs(at_end["north_m"]) < 0.5 and abs(at_end["east_m"]) < 0.5


@pytest.mark.slow
def test_wind_drifts_the_vehicle_downwind(tmp_path):
    _code, _summary, log_path = fly(tmp_path, world(wind_north=5.0), "hover")
    end = states(log_path)[-1]
    assert end["north_m"] > 2.0  # pushed towards where the air moves
    assert abs(end["east_m"]) < 0.5 * end["north_m"]
    assert end["v_ned_m_s"][0] > 1.0


# What the harness tells the bridge of a SUT that, like the bundled autopilot and the scripted
# SUT, answers every HIL_SENSOR from the first with its time_usec.
ANSWERS_EVERY_STEP = ("--lockstep-from-start", "--answer-times-echoed")


@pytest.mark.slow
def test_same_world_and_seed_give_an_identical_trace(tmp_path):
    """GIVEN a SUT that answers every step WHEN the same world is flown twice, its first answer
    coming at once, then 50 ms late, as from a process still coming up on a busy machine THEN
    both flights are identical to the last bit: the simulation waited for it."""
    obstacle = {"id": "ball", "form": "sphere", "size": {"diameter_m": 2.0}, "yaw_rad": 0.0,
                "a": {"north_m": 6.0, "east_m": -5.0, "up_m": 3.0}, "b": {"north_m": 6.0, "east_m": 5.0, "up_m": 3.0}, "speed_m_s": 2.0}
    traces = []
    for run, late in enumerate((0.0, 0.05)):
        _code, _summary, log_path = fly(tmp_path, world(time_limit_s=5.0, obstacles=[obstacle]), "hover", name=f"run{run}", bridge_args=ANSWERS_EVERY_STEP,
                                       late_first_s=late)
        traces.append([(topic, ns, message) for topic, ns, message in logs.messages(log_path, ["/clearance", "/uav/state", "/sensor/obstacle_distance"])])
    assert traces[0] == traces[1]
    assert len(traces[0]) > 100


@pytest.mark.slow
def test_a_late_first_answer_does_not_leave_the_flight_a_step_behind(tmp_path):
    """GIVEN a SUT that, like PX4, gets real-time pace until it answers and echoes each step's time
    WHEN its first answer comes 50 ms (a dozen steps) late, on its own THEN lockstep starts after
    it, and from then on every step flies the motor commands that answer that step's sensors,
    not the previous step's."""
    _code, summary, log_path = fly(tmp_path, world(time_limit_s=3.0), "clock", bridge_args=("--answer-times-echoed",), late_first_s=0.05)
    assert summary["end_reason"] == "time_limit" and summary["late_answers"] >= 1
    started = next(m for _t, _ns, m in logs.messages(log_path, ["/events"]) if m["event"] == "lockstep_started")
    assert started["detail"]["step"] >= 5
    dt = 0.004
    # A state at t was recorded after the step from t - dt, flown with that step's answer.
    flown = [(round(s["t"] / dt), s["motors"][0]) for s in states(log_path) if s["motors"][0] != 0.0]
    assert len(flown) > 0.8 * 3.0 / 0.04
    assert [command for _step, command in flown] == pytest.approx([clock_command((step - 1) * 4000) for step, _command in flown], abs=1e-6)


@pytest.mark.slow
def test_a_disconnecting_sut_ends_the_run_promptly(tmp_path):
    started = time.monotonic()
    code, summary, log_path = fly(tmp_path, world(), "disconnect", steps=200)
    assert summary["end_reason"] == "sut_disconnected" and code == 3
    assert time.monotonic() - started < 15
    assert summary["steps"] == pytest.approx(200, abs=2)
    assert logs.json_metadata(log_path, "bridge_summary")["end_reason"] == "sut_disconnected"  # the log is finished


@pytest.mark.slow
def test_a_stalled_sut_ends_the_run_after_the_stall_timeout(tmp_path):
    started = time.monotonic()
    code, summary, _log = fly(tmp_path, world(), "stall", steps=150, stall_timeout_s=1.0)
    assert summary["end_reason"] == "sut_stalled" and code == 3
    assert time.monotonic() - started < 15


@pytest.mark.slow
def test_garbage_bytes_are_counted_and_skipped(tmp_path):
    code, summary, _log = fly(tmp_path, world(time_limit_s=3.0), "garbage")
    assert code == 0 and summary["end_reason"] == "time_limit"
    assert summary["bad_frames"] > 0 and summary["skipped_bytes"] > 0
    assert summary["steps"] == 750


@pytest.mark.slow
def test_obstacles_are_injected_moved_and_removed_through_the_control_channel(tmp_path):
    """GIVEN a hovering vehicle WHEN the harness adds a pole 3 m away at t=2 s, moves it to 6 m at
    t=3 s and removes it at t=4 s THEN the recorded clearance follows exactly that."""
    from harness.flight.bridge_control import BridgeControl

    world_path = tmp_path / "world.json"
    world_path.write_text(json.dumps(world(time_limit_s=6.0)))
    log_path = tmp_path / "inject.mcap"
    pole = {"id": "pole", "form": "cylinder", "size": {"diameter_m": 1.0, "height_m": 20.0}, "yaw_rad": 0.0,
            "a": {"north_m": 3.5, "east_m": 0.0, "up_m": 10.0}, "b": None, "speed_m_s": 0.0}
    with PortLease(first_slot=120) as ports:
        bridge = subprocess.Popen(
            [sys.executable, "-m", "sim_bridge", "--world", str(world_path), "--sim-port", str(ports.sim), "--control-port", str(ports.control),
             "--mcap", str(log_path), "--hold-after-s", "0.5"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT,
        )
        sut = subprocess.Popen([sys.executable, str(SCRIPTED_SUT), "--port", str(ports.sim), "--mode", "hover"], cwd=ROOT)
        try:
            control = BridgeControl(ports.control)
            assert control.wait_for(Holding, 20.0) is not None
            control.send(AddObstacle(pole, at_s=2.0))
            control.send(MoveObstacle("pole", {"north_m": 6.5, "east_m": 0.0, "up_m": 10.0}, at_s=3.0))
            control.send(RemoveObstacle("pole", at_s=4.0))
            control.send(Run())
            finished = control.wait_for(Finished, 60.0)
            control.close()
            bridge.communicate(timeout=30)
        finally:
            sut.kill()
            sut.wait()
            bridge.kill()
    assert [i["op"] for i in finished.summary["injections"]] == ["add_obstacle", "move_obstacle", "remove_obstacle"]
    samples = [(t, d) for _topic, _ns, m in logs.messages(log_path, ["/clearance"]) for t, d in zip(m["t"], m["d"])]
    run_start = 0.5
    def clearance_at(run_time):
        return next(d for t, d in samples if t >= run_start + run_time)
    assert clearance_at(1.9) is None  # no obstacle yet
    # The hovering body (0.3 m half length) is within centimetres of the origin.
    assert clearance_at(2.5) == pytest.approx(3.5 - 0.5 - 0.3, abs=0.1)
    assert clearance_at(3.5) == pytest.approx(6.5 - 0.5 - 0.3, abs=0.1)
    assert clearance_at(4.5) is None


@contextlib.contextmanager
def bridge_and_hovering_sut(tmp_path: Path, spec: dict, *bridge_arguments: str, slot: int = 120):
    """The bridge flying spec (its log at tmp_path/run.mcap, its control port leased) and the
    scripted SUT hovering against it; both are killed on exit. Yields (bridge, sut, ports, log)."""
    world_path = tmp_path / "world.json"
    world_path.write_text(json.dumps(spec))
    log_path = tmp_path / "run.mcap"
    with PortLease(first_slot=slot) as ports:
        bridge = subprocess.Popen(
            [sys.executable, "-m", "sim_bridge", "--world", str(world_path), "--sim-port", str(ports.sim), "--control-port", str(ports.control),
             "--mcap", str(log_path), "--connect-timeout-s", "20", *bridge_arguments],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT,
        )
        sut = subprocess.Popen([sys.executable, str(SCRIPTED_SUT), "--port", str(ports.sim), "--mode", "hover"], stdout=subprocess.PIPE, cwd=ROOT)
        try:
            yield bridge, sut, ports, log_path
        finally:
            sut.kill()
            sut.wait()
            bridge.kill()
            bridge.wait()


@pytest.mark.slow
def test_after_its_flight_the_bridge_keeps_the_link_open_until_the_sut_hangs_up(tmp_path):
    """--linger-s (as the harness runs it): the log is finished and the SUT still connected, so
    that the harness can stop a SUT that spins on a closed simulator link (PX4) before that."""
    with bridge_and_hovering_sut(tmp_path, world(time_limit_s=2.0), "--hold-after-s", "0", "--linger-s", "60", slot=100) as (bridge, sut, _ports, log_path):
        deadline = time.monotonic() + 60
        while not (log_path.exists() and log_path.stat().st_size >= len(logs.MCAP_MAGIC) and logs.truncation(log_path) is None):
            assert time.monotonic() < deadline and bridge.poll() is None, "the flight's log was never finished"
            time.sleep(0.1)
        time.sleep(1.0)
        assert bridge.poll() is None and sut.poll() is None, "the bridge closed the SUT's link after its flight"
        sut.terminate()
        out, _err = bridge.communicate(timeout=5)
    assert bridge.returncode == 0
    assert json.loads(out.decode().strip().splitlines()[-1])["end_reason"] == "time_limit"


@pytest.mark.slow
@pytest.mark.parametrize("moment", ["holding", "flying"])
def test_a_harness_that_hangs_up_mid_flight_ends_the_run_at_once(tmp_path, moment):
    """A harness killed before its death signal could be armed never stops us: holding for it
    until the hold timeout (two minutes), or flying on to the time limit, would keep its port
    block and a core from the rest of the campaign (seen in CI: a warm server left behind)."""
    from harness.flight.bridge_control import BridgeControl

    with bridge_and_hovering_sut(tmp_path, world(time_limit_s=120.0), "--hold-after-s", "0.5") as (bridge, _sut, ports, _log):
        control = BridgeControl(ports.control)
        assert control.wait_for(Holding, 20.0) is not None
        if moment == "flying":
            control.send(Run())
            time.sleep(0.5)
        hung_up_at = time.monotonic()
        control.close()
        out, _err = bridge.communicate(timeout=30)
        ended_after_s = time.monotonic() - hung_up_at
    assert bridge.returncode == 3
    assert json.loads(out.decode().strip().splitlines()[-1])["end_reason"] == "harness_gone"
    assert ended_after_s < 10.0


@pytest.mark.parametrize("protocol", ["mavlink", "ardupilot-json"])
@pytest.mark.parametrize("harness", ["says stop", "hangs up"])
def test_a_simulator_waiting_for_a_sut_that_never_comes_ends_when_the_harness_gives_up(tmp_path, protocol, harness):
    """A harness that saw its SUT die at once, or never hear of it, stops the simulator waiting for
    it: ended at once with a whole log that says so, not after its connect timeout or by a signal
    that would leave no log (and a campaign's try 5 s longer)."""
    from harness.flight.bridge_control import BridgeControl

    world_path = tmp_path / "world.json"
    world_path.write_text(json.dumps(world()))
    log_path = tmp_path / "never.mcap"
    with PortLease(first_slot=120) as ports:
        bridge = subprocess.Popen(
            [sys.executable, "-m", "sim_bridge", "--world", str(world_path), "--sim-port", str(ports.sim), "--control-port", str(ports.control),
             "--mcap", str(log_path), "--sim-protocol", protocol, "--connect-timeout-s", "120"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT)
        try:
            control = BridgeControl(ports.control)
            time.sleep(0.3)  # the simulator is waiting for its SUT by now
            given_up_at = time.monotonic()
            if harness == "says stop":
                control.send(Stop())
                assert control.wait_for(Finished, 30.0).summary["end_reason"] == "sut_never_connected"
            control.close()
            out, _err = bridge.communicate(timeout=30)
            ended_after_s = time.monotonic() - given_up_at
        finally:
            bridge.kill()
    assert bridge.returncode == 3 and json.loads(out.decode().strip().splitlines()[-1])["end_reason"] == "sut_never_connected"
    assert json.loads(logs.metadata(log_path)["bridge_summary"]["json"])["end_reason"] == "sut_never_connected"
    assert ended_after_s < 10.0


@pytest.mark.slow
@pytest.mark.parametrize("pace", [1.0, 4.0])
def test_a_paced_hold_runs_simulated_time_at_its_pace(tmp_path, pace):
    """--hold-mode paced --hold-pace P: while the harness sets up, simulated time runs on at
    about P times real time, no faster (a slow machine may fall short of it)."""
    from harness.flight.bridge_control import BridgeControl

    with bridge_and_hovering_sut(tmp_path, world(time_limit_s=60.0), "--hold-after-s", "0.5", "--hold-mode", "paced", "--hold-pace", str(pace)) as (
            bridge, _sut, ports, _log):
        control = BridgeControl(ports.control)
        holding = control.wait_for(Holding, 20.0)
        assert holding is not None
        held_since = time.monotonic()
        time.sleep(1.0)
        control.send(Stop())
        finished = control.wait_for(Finished, 30.0)
        held_s = time.monotonic() - held_since  # more than the hold lasted in the bridge
        assert finished is not None
        control.close()
        bridge.communicate(timeout=30)
    simulated_in_hold_s = finished.summary["sim_time_s"] - holding.t
    assert simulated_in_hold_s <= pace * held_s * 1.05
    assert simulated_in_hold_s >= pace * 0.5


@pytest.mark.slow
def test_a_paced_bridge_waits_for_a_failure_injection_at_real_time_whatever_its_hold_pace(tmp_path):
    """While the harness tells a paced SUT of a failure, simulated time runs at most as fast as
    the wall clock: the faster it ran, the later in simulated time the failure would act."""
    from harness.flight.bridge_control import BridgeControl

    spec = world(time_limit_s=60.0)
    spec["failures"] = [{"unit": "barometer", "type": "off", "onset_s": 1.0, "duration_s": 60.0, "delivery": "sut"}]
    with bridge_and_hovering_sut(tmp_path, spec, "--hold-after-s", "0.5", "--hold-mode", "paced", "--hold-pace", "10") as (bridge, _sut, ports, log_path):
        control = BridgeControl(ports.control)
        assert control.wait_for(Holding, 20.0) is not None
        control.send(Run())
        asked = control.wait_for(InjectFailure, 20.0)
        assert asked is not None
        asked_at = time.monotonic()
        time.sleep(0.5)
        control.send(FailureInjected("SUCCESS"))
        waited_s = time.monotonic() - asked_at
        control.send(Stop())
        assert control.wait_for(Finished, 30.0) is not None
        control.close()
        bridge.communicate(timeout=30)
    told = next(m for _t, _ns, m in logs.messages(log_path, ["/events"]) if m["event"] == "failure")
    assert told["detail"]["result"] == "SUCCESS"
    assert told["t"] - asked.t <= waited_s * 1.1 + 0.2


def test_a_recording_that_cannot_be_written_is_refused_before_any_flight(tmp_path):
    world_path = tmp_path / "world.json"
    world_path.write_text(json.dumps(world()))
    missing = tmp_path / "no such folder" / "run:1.mcap"
    done = subprocess.run([sys.executable, "-m", "sim_bridge", "--world", str(world_path), "--mcap", str(missing), "--sim-port", "0"],
                          capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert done.returncode == 2
    assert f"--mcap {missing}: cannot write the recording there" in done.stderr and "Traceback" not in done.stderr
