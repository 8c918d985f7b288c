"""Real PX4 SITL flying against our bridge. Runs where STELLA_PX4_BIN names a PX4 SITL build
(the px4 binary or build/px4_sitl_default); PX4 is built from source, see the README."""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections import Counter
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink

from conftest import PLAN_SCENARIO, PLAN_SPEED_M_S, ROOT, plan_flight
from harness.campaigns.store import Store
from harness.flight import logs
from harness.flight.fitness import PENALTY
from harness.flight.inspect_log import summarize
from harness.scenario.world import load_concrete, world_spec
from harness.tools.cli import main
from sut_adapter.px4 import API_STREAM_RATES_HZ, resolve_binary

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not os.environ.get("STELLA_PX4_BIN"), reason="STELLA_PX4_BIN is not set: no PX4 SITL build to fly against"),
]
SCENARIO = str(ROOT / "scenarios" / "table3" / "scenario_05.json")


def test_sut_check_passes_every_stage(capsys):
    assert main(["sut", "check", "--sut", "px4", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert all(stage["ok"] for stage in report["stages"]), report["stages"]


def test_px4_flies_a_table3_scenario_with_a_finite_fitness_a_log_and_its_ulog(capsys, tmp_path):
    # CP_DIST as the adapter's default: a user's parameter that changes nothing, but goes over MAVLink.
    assert main(["run", SCENARIO, "--sut", "px4", "--seed", "3", "--sut-param", "CP_DIST=1.0", "--out", str(tmp_path), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["status"] in ("ok", "violation"), result["why"]
    assert math.isfinite(result["fitness"]) and result["fitness"] < PENALTY
    assert summarize(Path(result["log_path"]))["fitness"] == result["fitness"]
    assert any(a.endswith(".ulg") and Path(a).stat().st_size > 0 for a in result["artifacts"])
    # PX4 relays the distance_sensor topic our DISTANCE_SENSOR wedges create onto its API link.
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    api = [message for _t, _ns, m in logs.messages(Path(result["log_path"]), ["/mavlink/api"]) if m["direction"] == "from_sut"
           for message in parser.parse_buffer(bytes.fromhex(m["hex"])) or []]
    received = Counter(message.get_type() for message in api)
    wedges = len({message.id for message in api if message.get_type() == "DISTANCE_SENSOR"})
    assert wedges == 6 and received["DISTANCE_SENSOR"] > 100
    # Its API link's high-rate streams came at the rates the adapter set (DISTANCE_SENSOR's for
    # each wedge; PX4's stream SERVO_OUTPUT_RAW_0 sends SERVO_OUTPUT_RAW), not at PX4's 10-100 Hz,
    # once its start-up had set them (before, PX4 streams at its own rates for a moment).
    settled = Counter(message.get_type() for _t, ns, m in logs.messages(Path(result["log_path"]), ["/mavlink/api"])
                      if m["direction"] == "from_sut" and ns >= 5e9 for message in parser.parse_buffer(bytes.fromhex(m["hex"])) or [])
    for stream, rate_hz in API_STREAM_RATES_HZ.items():
        name = stream.removesuffix("_0")
        assert settled[name] <= 1.2 * rate_hz * (result["sim_time_s"] - 5.0) * (wedges if name == "DISTANCE_SENSOR" else 1), (name, settled[name])
    assert received["ATTITUDE"] >= 0.8 * API_STREAM_RATES_HZ["ATTITUDE"] * (result["sim_time_s"] - 5.0)
    # Only the user's parameter went over MAVLink (PX4's start-up took the adapter's defaults from
    # its environment), and once: PX4 had finished starting up and answered it.
    asked = Counter(message.param_id for _t, _ns, m in logs.messages(Path(result["log_path"]), ["/mavlink/api"]) if m["direction"] == "to_sut"
                    for message in parser.parse_buffer(bytes.fromhex(m["hex"])) or [] if message.get_type() == "PARAM_SET")
    assert asked == {"CP_DIST": 1}, asked


def test_a_small_campaign_completes_against_px4_with_two_instances_keeping_the_ulogs_of_failing_flights_only(tmp_path):
    store = tmp_path / "px4.db"
    assert main(["campaign", SCENARIO, "--algorithm", "RANDOM", "--evaluations", "4", "--workers", "2", "--sut", "px4", "--store", str(store),
                 "--sut-logs", "failures", "--json"]) == 0
    with Store(store) as opened:
        [run] = opened.runs()
        flown = list(opened.db.execute("SELECT status, log_path FROM evaluations WHERE status != 'infeasible'"))
    assert run.evaluations == 4 and run.finished is not None
    assert not {status for status, _log in flown} & {"sut_crashed", "sim_crashed", "timeout"}, flown
    for status, log_path in flown:
        kept = {path.suffix for path in Path(log_path).with_suffix(".artifacts").iterdir()}
        assert ".log" in kept and (".ulg" in kept) == (status != "ok"), (status, kept)


WALL = str(ROOT / "scenarios" / "examples" / "wall_concrete.json")


def run_wall(capsys, tmp_path, drive: str) -> dict:
    assert main(["run", "--concrete", WALL, "--sut", "px4", "--drive", drive, "--out", str(tmp_path / drive), "--json"]) in (0, 1)
    return json.loads(capsys.readouterr().out)


def test_px4_flies_into_a_wall_on_a_mission_and_its_collision_prevention_stops_the_pilot(capsys, tmp_path):
    """The evidence that the pilot drive tests PX4's own collision prevention: it acts in Position
    mode with stick input only."""
    mission = run_wall(capsys, tmp_path, "mission")
    assert mission["min_clearance_m"] <= 0.0 and mission["status"] == "violation"
    pilot = run_wall(capsys, tmp_path, "pilot")
    assert pilot["min_clearance_m"] > 0.0 and pilot["status"] != "violation", pilot["why"]
    assert pilot["status"] in ("ok", "mission_failed"), pilot["why"]
    # to the scenario's take-off altitude, not PX4's default 2.5 m (a parameter set just before
    # the take-off command reaches PX4's navigator too late)
    space, x = load_concrete(Path(WALL), drive="pilot")
    altitude = world_spec(space, x, 0).mission.takeoff_altitude_m
    [console] = (tmp_path / "pilot").rglob("px4.stdout.log")
    assert f"Using default takeoff altitude: {altitude:.1f} m" in console.read_text()


def test_sut_check_with_the_pilot_drive_sees_px4_accept_position_mode_from_the_rc_link(capsys):
    assert main(["sut", "check", "--sut", "px4", "--drive", "pilot", "--json"]) == 0
    stages = json.loads(capsys.readouterr().out)["stages"]
    assert stages[-1]["name"] == "position mode with stick input accepted" and stages[-1]["ok"], stages


def test_a_scenario_whose_name_has_a_colon_and_spaces_is_flown_by_px4(capsys, tmp_path):
    """PX4's start-up script cannot run in a working directory whose path holds ':' or a space."""
    document = json.loads((ROOT / "scenarios" / "table3" / "scenario_05.json").read_text())
    document["name"] = "Holdout 2: three static obstacles"
    scenario = tmp_path / "holdout.json"
    scenario.write_text(json.dumps(document))
    assert main(["run", str(scenario), "--sut", "px4", "--seed", "3", "--out", str(tmp_path), "--json"]) in (0, 1)
    result = json.loads(capsys.readouterr().out)
    assert result["status"] in ("ok", "violation", "mission_failed"), result["why"]
    assert Path(result["log_path"]).name == "Holdout_2_three_static_obstacles-seed3.mcap"


def test_px4_flies_a_qgroundcontrol_plan_as_planned(capsys, tmp_path):
    assert main(["run", str(PLAN_SCENARIO), "--sut", "px4", "--seed", "2", "--out", str(tmp_path), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["status"] == "ok", result["why"]
    flight = plan_flight(Path(result["log_path"]))
    for waypoint in flight["waypoints"]:
        assert waypoint["miss_m"] <= 2.0 and abs(waypoint["altitude_error_m"]) <= 0.5, flight["waypoints"]
    assert flight["waypoints"][1]["at_it_s"] >= 1.5  # held 2 s
    assert 3.5 <= flight["max_speed_m_s"] <= PLAN_SPEED_M_S + 0.6


def test_px4_flies_an_imported_competition_case_with_the_clearance_computed_by_hand(capsys, tmp_path):
    from test_aerialist import check_hover_clearances, fly_hover_case

    check_hover_clearances(fly_hover_case(tmp_path, capsys, "--sut", "px4"))


def test_px4_flies_an_imported_takeoff_and_land_at_case_with_the_printed_command_and_the_competition_scores_it(capsys, tmp_path):
    from test_aerialist import fly_land_at_case

    fly_land_at_case(tmp_path, capsys, "--sut", "px4")


def test_an_injected_range_sensor_failure_reaches_px4_and_px4_answers_a_barometer_one(capsys, tmp_path):
    """The range sensor fails in the simulator: PX4's distance_sensor topic, which it relays on
    its API link, falls silent for the failure's span. The barometer's goes to PX4 as
    MAV_CMD_INJECT_FAILURE, with SYS_FAILURE_EN set: /events records PX4's answer."""
    from harness.scenario.logical import load_logical
    from harness.scenario.profile import load_profile
    from harness.scenario.space import SearchSpace

    profile = load_profile("default")
    space = SearchSpace(load_logical(ROOT / "tests" / "data" / "scenarios" / "wall_range_off_baro_off.json", profile), profile)
    x = space.vector_from({"obstacle_1.length_m": 20.0, "obstacle_1.width_m": 10.0, "obstacle_1.height_m": 20.0, "obstacle_1.north_m": 30.0,
                           "obstacle_1.east_m": 0.0, "obstacle_1.yaw_deg": 90.0, "failure_1.onset_s": 4.0, "failure_1.duration_s": 4.0,
                           "failure_2.onset_s": 10.0, "failure_2.duration_s": 2.0})
    concrete = tmp_path / "failures.json"
    concrete.write_text(json.dumps(space.to_concrete(x)))
    assert main(["run", "--concrete", str(concrete), "--sut", "px4", "--out", str(tmp_path), "--json"]) in (0, 1)
    result = json.loads(capsys.readouterr().out)
    log = Path(result["log_path"])
    events = [m for _t, _ns, m in logs.messages(log, ["/events"])]
    start = next(e["t"] for e in events if e["event"] == "run")
    told = [e for e in events if e["event"] in ("failure", "failure_refused") and e["detail"]["unit"] == "barometer"]
    assert told and told[0]["detail"]["result"], events
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    relayed = [message.time_boot_ms / 1000.0 - start for _t, _ns, m in logs.messages(log, ["/mavlink/api"]) if m["direction"] == "from_sut"
               for message in parser.parse_buffer(bytes.fromhex(m["hex"])) or [] if message.get_type() == "DISTANCE_SENSOR"]
    assert [t for t in relayed if 2.0 < t < 4.0] and [t for t in relayed if 9.0 < t < 11.0]
    assert not [t for t in relayed if 5.0 < t < 8.0]


def test_bench_limit_replays_a_px4_flight_to_px4_alone_in_lockstep_and_reports_the_flight_as_a_share_of_it(capsys):
    assert main(["bench", "--sut", "px4", "--limit", "--runs", "1", "--cores", "2", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    alone = report["sut_alone"]
    assert alone["in_step"], "PX4 answered a replayed step with another step's time"
    [placement] = report["placements"]
    # Timed: the replayed flight's steps from its "run" on, as its real-time factor counts them
    # (not PX4's paced set-up before it, whose simulated length follows the wall clock).
    assert abs(alone["timed_steps"] - placement["per_run"][0]["run_steps"]) <= 2
    assert 0.0 < placement["median"]["flight_speed_of_sut_alone"] < math.inf
    # PX4's CPU time a step, in the flight and alone: PX4 is pinned to one core, so it computes
    # in at most the step's wall time (give or take a 10 ms clock tick over a second's run).
    run = placement["per_run"][0]
    assert 0.0 < run["sut_cpu_share_of_step"] < 1.02
    replayed_step_us = 1e6 / (report["rate_hz"] * run["sut_alone_real_time_factor"])
    assert 0.0 < run["sut_alone_cpu_us"] < 1.02 * replayed_step_us


def test_a_px4_campaigns_failure_mode_becomes_a_bundle_with_px4s_ulog_and_the_binarys_digest(capsys, tmp_path):
    store = tmp_path / "px4.db"
    scenario = str(ROOT / "tests" / "data" / "scenarios" / "wall_range_off_baro_off.json")
    assert main(["campaign", scenario, "--algorithm", "RANDOM", "--evaluations", "3", "--seed", "3", "--executor", "sequential", "--sut", "px4",
                 "--store", str(store), "--json"]) == 0
    capsys.readouterr()
    out = tmp_path / "findings"
    assert main(["export-findings", str(store), "--out", str(out), "--json"]) == 0
    exported = json.loads(capsys.readouterr().out)
    assert exported["findings"], "with its range sensor off, PX4 meets the wall on the mission in one of these candidates"
    first = out / exported["findings"][0]
    assert any(path.stat().st_size > 0 for path in (first / "sut").glob("**/*.ulg")), "PX4's own log goes with the bundle"
    finding = (first / "FINDING.md").read_text()
    binary = resolve_binary(os.environ["STELLA_PX4_BIN"])[0]
    assert hashlib.sha256(binary.read_bytes()).hexdigest() in finding
    assert f"--px4-bin {binary.parent.parent}" in finding or f"--px4-bin {binary}" in finding


def mode_changes(log: Path) -> list[tuple[float, str]]:
    """PX4's flight modes as its API heartbeats told them, with the log time of each change."""
    from harness.properties.signals import mode_of

    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    changes: list[tuple[float, str]] = []
    for _t, ns, record in logs.messages(log, ["/mavlink/api"]):
        if record["direction"] == "from_sut":
            for message in parser.parse_buffer(bytes.fromhex(record["hex"])) or []:
                if message.get_type() == "HEARTBEAT" and message.autopilot == mavlink.MAV_AUTOPILOT_PX4:
                    mode = mode_of(message)
                    if not changes or changes[-1][1] != mode:
                        changes.append((ns / 1e9, mode))
    return changes


def test_px4_set_to_return_holds_then_returns_after_a_lost_data_link_and_never_without_one(capsys, tmp_path):
    """The API tap sends the ground station's heartbeat on PX4's clock, so PX4 keeps its
    documented COM_DL_LOSS_T (10 s) at 20 times real time and loses the link only when the
    scenario takes it away."""
    from harness.scenario.logical import load_logical
    from harness.scenario.profile import load_profile
    from harness.scenario.space import SearchSpace

    profile = load_profile("default")
    space = SearchSpace(load_logical(ROOT / "scenarios" / "examples" / "datalink_loss.json", profile), profile)
    x = space.vector_from({"obstacle_1.diameter_m": 5.0, "obstacle_1.north_m": 60.0, "obstacle_1.east_m": 30.0,
                           "failure_1.onset_s": 8.0, "failure_1.duration_s": 30.0})
    concrete = tmp_path / "link_lost.json"
    concrete.write_text(json.dumps(space.to_concrete(x)))
    main(["run", "--concrete", str(concrete), "--sut", "px4", "--sut-param", "NAV_DLL_ACT=2", "--property", "datalink_loss_acts",
          "--out", str(tmp_path / "lost"), "--json"])
    result = json.loads(capsys.readouterr().out)
    assert result["properties"]["datalink_loss_acts"]["verdict"] == "kept", result
    log = Path(result["log_path"])
    onset = next(ns / 1e9 for _t, ns, event in logs.messages(log, ["/events"]) if event.get("event") == "failure")
    after_onset = [(t - onset, mode) for t, mode in mode_changes(log) if t > onset]
    (held_after, held), (returned_after, returned) = after_onset[:2]
    assert (held, returned) == ("hold", "rtl"), after_onset
    assert 10.0 <= held_after <= 14.0  # COM_DL_LOSS_T, plus PX4's own 2.5 s link timeout and 1 Hz report
    assert returned_after - held_after == pytest.approx(5.0, abs=1.2)  # COM_FAIL_ACT_T
    # the same PX4 on the wall's mission, no link lost: it flies its mission and nothing else
    assert main(["run", "--concrete", str(ROOT / "scenarios" / "examples" / "wall_concrete.json"), "--sut", "px4", "--sut-param", "NAV_DLL_ACT=2",
                 "--out", str(tmp_path / "kept"), "--json"]) in (0, 1)
    kept = json.loads(capsys.readouterr().out)
    assert {mode for _t, mode in mode_changes(Path(kept["log_path"]))} <= {"hold", "takeoff", "mission", "land"}
