"""Real ArduCopter SITL flying against our bridge through its JSON physics backend. Runs where
STELLA_ARDUPILOT_BIN names an ArduCopter SITL build (the arducopter binary or build/sitl);
ArduPilot is built from source, see docs/suts.md."""

from __future__ import annotations

import json
import math
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink import DFReader
from pymavlink.dialects.v20 import common as mavlink

from conftest import ROOT, alive, described, descendants
from harness.flight import logs
from harness.flight.fitness import PENALTY
from harness.flight.inspect_log import summarize
from harness.tools.cli import main
from harness.tools.sut_alone import recorded_link, sut_alone
from simlink.failures import UNIT_BY_NAME
from sut_adapter import SutConfig
from sut_adapter.ardupilot_failures import failure_params

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not os.environ.get("STELLA_ARDUPILOT_BIN"), reason="STELLA_ARDUPILOT_BIN is not set: no ArduCopter SITL build to fly against"),
]
SCENARIO = str(ROOT / "scenarios" / "table3" / "scenario_05.json")
WALL = str(ROOT / "scenarios" / "examples" / "wall_concrete.json")


def timed_api_messages(log_path: Path, kind: str) -> list[tuple[float, object]]:
    """(simulated time in s, message) of each message of a kind ArduPilot sent on its API link."""
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    return [(ns / 1e9, message) for _t, ns, m in logs.messages(log_path, ["/mavlink/api"]) if m["direction"] == "from_sut"
            for message in parser.parse_buffer(bytes.fromhex(m["hex"])) or [] if message.get_type() == kind]


def api_messages(log_path: Path, kind: str) -> list:
    return [message for _t_s, message in timed_api_messages(log_path, kind)]


def test_sut_check_passes_every_stage(capsys):
    assert main(["sut", "check", "--sut", "ardupilot", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert all(stage["ok"] for stage in report["stages"]), report["stages"]


def dataflash_params(bin_path: Path) -> dict[str, float]:
    """The parameters ArduPilot logged (PARM) in its dataflash log."""
    reader = DFReader.DFReader_binary(str(bin_path))
    values = {}
    while (message := reader.recv_match(type="PARM")) is not None:
        values[message.Name] = message.Value
    return values


def test_ardupilot_flies_a_table3_mission_with_a_finite_fitness_and_its_dataflash_log(capsys, tmp_path):
    # Inert parameters (the fence is off) in ArduPilot's own .parm layouts: they reach ArduPilot.
    parm = tmp_path / "fence.parm"
    parm.write_text("# the fence as a .parm file writes it\nFENCE_RADIUS    150\nFENCE_ALT_MAX\t120 # metres\n")
    assert main(["run", SCENARIO, "--sut", "ardupilot", "--seed", "3", "--out", str(tmp_path), "--json", "--sut-params-file", str(parm)]) in (0, 1)
    result = json.loads(capsys.readouterr().out)
    assert result["status"] in ("ok", "violation"), result["why"]
    assert math.isfinite(result["fitness"]) and result["fitness"] < PENALTY
    assert summarize(Path(result["log_path"]))["fitness"] == result["fitness"]
    dataflash = [Path(a) for a in result["artifacts"] if a.endswith(".BIN")]
    assert dataflash and dataflash[0].stat().st_size > 0
    logged = dataflash_params(dataflash[0])
    assert (logged["FENCE_RADIUS"], logged["FENCE_ALT_MAX"]) == (150.0, 120.0)
    # Every parameter a failure sets is ArduPilot's, and the end of a failure sets back its own value.
    unfailed = {name: value for unit in UNIT_BY_NAME for name, value in (failure_params(unit, "ok") or {}).items()}
    assert {name: logged.get(name) for name in unfailed} == pytest.approx(unfailed)
    # Every servo frame was one, each step answered in lockstep.
    assert logs.json_metadata(Path(result["log_path"]), "bridge_summary")["bad_frames"] == 0
    # Armed and started once its AHRS settled (25 s of simulated time; 42 s at ArduPilot's default EK3_YAW_M_NSE).
    started_at_s = next(m["t"] for _t, _ns, m in logs.messages(Path(result["log_path"]), ["/events"]) if m["event"] == "run")
    assert started_at_s < 30.0


def run_wall(capsys, tmp_path, name: str, *arguments: str) -> dict:
    assert main(["run", "--concrete", WALL, "--sut", "ardupilot", "--out", str(tmp_path / name), "--json", *arguments]) in (0, 1)
    return json.loads(capsys.readouterr().out)


def test_ardupilot_flies_into_the_wall_on_a_mission_without_its_path_planner(capsys, tmp_path):
    mission = run_wall(capsys, tmp_path, "mission", "--drive", "mission")
    assert mission["min_clearance_m"] <= 0.0 and mission["status"] == "violation", mission["why"]


def test_arducopter_alone_replays_a_recorded_flight_in_lockstep(capsys, tmp_path):
    # GIVEN a wall mission flown through the bridge
    flown = run_wall(capsys, tmp_path, "flown", "--drive", "mission")
    # WHEN its JSON link is replayed to a fresh ArduCopter, as `stella bench --sut ardupilot --limit` does
    alone = sut_alone(Path(flown["log_path"]), SutConfig("ardupilot"), cores=2, repeats=1)
    # THEN ArduCopter answered every timed line with its next frame, and ran faster than in the flight
    recorded = recorded_link(Path(flown["log_path"]), "ardupilot-json")
    assert alone["in_step"] and alone["timed_steps"] == len(recorded["steps"]) - recorded["run_step"] > 0
    assert alone["real_time_factor"] > 1.0


def test_ardupilots_path_planner_and_its_simple_avoidance_keep_it_off_the_wall(capsys, tmp_path):
    """BendyRuler (OA_TYPE 1) steers the Auto mission around the wall; in Loiter the pilot's
    sticks are stopped short of it, and ArduPilot's proximity sees what our sensor sees."""
    planner = run_wall(capsys, tmp_path, "planner", "--drive", "mission", "--sut-param", "OA_TYPE=1")
    assert planner["min_clearance_m"] > 0.0 and planner["status"] == "ok", planner["why"]
    pilot = run_wall(capsys, tmp_path, "pilot", "--drive", "pilot")
    assert pilot["min_clearance_m"] > 0.0, pilot["why"]
    log_path = Path(pilot["log_path"])
    relayed_cm = min(m.current_distance for m in api_messages(log_path, "DISTANCE_SENSOR") if m.orientation == 0)
    sensed_cm = min(m["distances_cm"][0] for _t, _ns, m in logs.messages(log_path, ["/sensor/obstacle_distance"]))
    assert abs(relayed_cm - sensed_cm) <= 2


def proximity_relayed_cm(log_path: Path, orientation: int) -> list[int]:
    """What ArduPilot's proximity itself (component 1) reports facing one way on its API link; the
    rig's own messages, which it forwards from SERIAL1, are the obstacle-avoidance component's."""
    return [m.current_distance for m in api_messages(log_path, "DISTANCE_SENSOR")
            if m.orientation == orientation and m.get_srcComponent() == mavlink.MAV_COMP_ID_AUTOPILOT1]


def test_ardupilots_proximity_backend_reads_a_rig_on_its_serial1(capsys, tmp_path):
    """A 360-degree lidar (OBSTACLE_DISTANCE) and four single-beam rangefinders (DISTANCE_SENSOR)
    reach ArduPilot's MAVLink proximity backend: its proximity reports the wall ahead as the rig
    read it. With the lidar, simple avoidance stops the pilot short of it, as with its own
    rangefinders; a beam reaching 12 m leaves it too little room at the pilot's speed."""
    lidar = run_wall(capsys, tmp_path, "lidar", "--drive", "pilot", "--rig", "lidar_360")
    assert lidar["min_clearance_m"] > 0.3 and "blocked" in (lidar["why"] or ""), lidar["why"]
    log_path = Path(lidar["log_path"])
    read_cm = min(m["distances_cm"][0] for _t, _ns, m in logs.messages(log_path, ["/sensor/rig/lidar"]))
    assert abs(min(proximity_relayed_cm(log_path, mavlink.MAV_SENSOR_ROTATION_NONE)) - read_cm) <= 2
    beams = run_wall(capsys, tmp_path, "beams", "--drive", "pilot", "--rig", "four_rangefinders")
    log_path = Path(beams["log_path"])
    read_cm = min(m["distance_cm"] for _t, _ns, m in logs.messages(log_path, ["/sensor/rig/front"]))
    assert abs(min(proximity_relayed_cm(log_path, mavlink.MAV_SENSOR_ROTATION_NONE)) - read_cm) <= 2
    assert beams["min_clearance_m"] < lidar["min_clearance_m"]


def test_a_gps_failure_reaches_ardupilots_sitl_through_its_parameters_and_one_without_a_means_is_refused(capsys, tmp_path):
    """GPS off is SIM_GPS1_ENABLE 0 from the onset to the end: ArduPilot's own GPS reports no fix
    on its API link then, a 3D fix before and after. A gyro failing intermittently has no SITL
    parameter: refused, and the flight says so."""
    from harness.scenario.logical import load_logical
    from harness.scenario.profile import load_profile
    from harness.scenario.space import SearchSpace

    profile = load_profile("default")
    space = SearchSpace(load_logical(ROOT / "tests" / "data" / "scenarios" / "wall_gps_off_gyro_intermittent.json", profile), profile)
    onset_s, duration_s = 8.0, 4.0
    x = space.vector_from({"obstacle_1.length_m": 20.0, "obstacle_1.width_m": 10.0, "obstacle_1.height_m": 20.0, "obstacle_1.north_m": 30.0,
                           "obstacle_1.east_m": 0.0, "obstacle_1.yaw_deg": 90.0, "failure_1.onset_s": onset_s, "failure_1.duration_s": duration_s,
                           "failure_2.onset_s": 10.0, "failure_2.duration_s": 2.0})
    concrete = tmp_path / "failures.json"
    concrete.write_text(json.dumps(space.to_concrete(x)))
    assert main(["run", "--concrete", str(concrete), "--sut", "ardupilot", "--out", str(tmp_path), "--json"]) in (0, 1)
    result = json.loads(capsys.readouterr().out)
    log_path = Path(result["log_path"])
    events = [m for _t, _ns, m in logs.messages(log_path, ["/events"])]
    told = {(e["event"], e["detail"]["unit"]) for e in events if e["event"].startswith("failure")}
    assert told == {("failure", "gps"), ("failure_cleared", "gps"), ("failure_refused", "gyro")}, events
    assert {(f["unit"], f["type"]) for f in result["failures_refused"]} == {("gyro", "intermittent")}
    start_s = next(e["t"] for e in events if e["event"] == "run")
    fixes = [(t_s - start_s, m.fix_type) for t_s, m in timed_api_messages(log_path, "GPS_RAW_INT")]
    assert all(fix >= 3 for t, fix in fixes if 2.0 < t < onset_s)
    assert [t for t, _ in fixes if onset_s + 0.5 < t < onset_s + duration_s] and all(
        fix < 3 for t, fix in fixes if onset_s + 0.5 < t < onset_s + duration_s)
    assert all(fix >= 3 for t, fix in fixes if onset_s + duration_s + 1.0 < t < onset_s + duration_s + 5.0)


def arducopters(pids: list[int]) -> list[str]:
    """Those of the processes that run arducopter, described."""
    found = []
    for pid in pids:
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as handle:
                argv = handle.read().split(b"\0")
        except OSError:
            continue
        if alive(pid) and os.path.basename(argv[0]) == b"arducopter":
            found.append(f"{pid}: {b' '.join(argv).decode(errors='replace')[:200]}")
    return found


@pytest.mark.parametrize("moment", ["starting", "flying"])
def test_kill_9_of_an_ardupilot_campaign_leaves_no_arducopter(tmp_path, moment):
    """kill -9 of a two-worker campaign while ArduPilot starts up (its first seconds) or flies:
    the arducopters its workers started go with it (PR_SET_PDEATHSIG, then their workers' going)."""
    command = [sys.executable, "-m", "harness.tools.cli", "campaign", SCENARIO, "--sut", "ardupilot", "--algorithm", "NSGAII", "--evaluations", "4",
               "--population", "2", "--seed", "5", "--workers", "2", "--store", str(tmp_path / "killed.db"), "--json"]
    campaign = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not arducopters(descendants(campaign.pid)):
            assert campaign.poll() is None and time.monotonic() < deadline, "the campaign started no arducopter"
            time.sleep(0.05)
        if moment == "flying":
            time.sleep(20.0)  # through ArduPilot's set-up (25 s of simulated time) into its flight
        # Frozen first, so that the processes seen are those the kill leaves.
        os.killpg(campaign.pid, signal.SIGSTOP)
        family = descendants(campaign.pid)
        assert arducopters(family), "no arducopter ran at the kill"
        os.kill(campaign.pid, signal.SIGKILL)  # the campaign alone: what it started must follow by itself
        os.killpg(campaign.pid, signal.SIGCONT)
        campaign.wait(timeout=10)
        deadline = time.monotonic() + 15
        while any(alive(pid) for pid in family) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert arducopters(family) == []
        assert [described(pid) for pid in family if alive(pid)] == []
    finally:
        if campaign.poll() is None:
            campaign.kill()


def test_an_ardupilot_campaign_is_screened_by_the_bundled_autopilot_with_loiters_counterparts(capsys, tmp_path):
    store = tmp_path / "screened.db"
    assert main(["campaign", SCENARIO, "--algorithm", "NSGAII", "--evaluations", "3", "--population", "6", "--batch", "6", "--seed", "3",
                 "--workers", "2", "--drive", "pilot", "--sut", "ardupilot", "--sut-param", "LOIT_SPEED=800", "--screen", "bundled",
                 "--store", str(store), "--json"]) == 0
    run = json.loads(capsys.readouterr().out)["runs"][0]
    # ArduCopter flew 3 candidates, the cheap model every candidate of the first batch
    assert run["flown"] == 3 and run["screen"]["flights"] >= 6 and run["screen"]["pairs"] == 3
    # configured as Loiter flies: simple avoidance's margin (the adapter's 1 m) and the speed given, in m/s
    cheap = json.loads(sqlite3.connect(store).execute("SELECT config FROM campaigns").fetchone()[0])["screen"]["sut"]
    assert cheap["name"] == "bundled" and (cheap["params"]["CP_DIST"], cheap["params"]["MPC_VEL_MANUAL"]) == (1.0, 8.0)
