"""The bundled autopilot's failsafes, as PX4 documents them: the position-loss fallback (Descend,
or Altitude mode by hand) and collision prevention's Hold without range data; then flown, judged
by the failsafe properties, and the seeded fault in them found by its witness."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from autopilot.commander import (MAIN_ALTCTL, MAIN_AUTO, MAIN_POSCTL, SUB_AUTO_LAND, SUB_AUTO_LOITER, SUB_AUTO_MISSION, SUB_AUTO_RTL, Commander,
                                 MissionItem, VehicleEstimate)
from autopilot.manual import Sticks
from autopilot.params import Params
from harness.flight import logs
from harness.tools.cli import main
from pymavlink.dialects.v20.common import MAV_CMD_NAV_WAYPOINT

from conftest import ROOT

WALL_CONCRETE = ROOT / "scenarios" / "examples" / "wall_concrete.json"


def estimate(north: float = 0.0, down: float = -10.0, v_down: float = 0.0) -> VehicleEstimate:
    return VehicleEstimate(north, 0.0, down, 0.0, 0.0, v_down, 0.0)


def on_a_mission() -> Commander:
    commander = Commander(Params())
    commander.armed, commander.landed, commander.home = True, False, (0.0, 0.0, 0.0)
    commander.set_mission([MissionItem(0, MAV_CMD_NAV_WAYPOINT, 80.0, 0.0, 10.0)])
    commander.start_mission(estimate())
    return commander


def test_a_lost_position_makes_a_mission_descend_level_and_the_mission_resumes_once_it_is_back():
    commander = on_a_mission()
    assert commander.update(1.0, estimate(), 0.42, position_valid=True).v_north_m_s > 0
    # WHEN the estimator stops vouching for its position
    descending = commander.update(1.1, estimate(), 0.42, position_valid=False)
    # THEN it descends at the landing speed without holding anything horizontal, reported as PX4 reports Descend
    assert (descending.level, descending.v_down_m_s, descending.north_m) == (True, commander.params["MPC_LAND_SPEED"], None)
    assert commander.reported_mode == (MAIN_AUTO, SUB_AUTO_LAND) and commander.mode == (MAIN_AUTO, SUB_AUTO_MISSION)
    assert ("statustext", "Failsafe: no position, switching to Descend") in commander.events
    # and once the position is back, the mission goes on towards its waypoint
    resumed = commander.update(1.2, estimate(), 0.42, position_valid=True)
    assert commander.reported_mode == (MAIN_AUTO, SUB_AUTO_MISSION) and resumed.v_north_m_s > 0 and not resumed.level


def test_a_descent_without_position_lands_and_disarms_where_it_is():
    commander = on_a_mission()
    commander.update(1.0, estimate(), 0.42, position_valid=False)
    # on the ground: no longer descending, lift well below hover, for the land detector's time
    for step in range(100):
        commander.update(1.0 + step * 0.02, estimate(down=0.0), 0.1, position_valid=False)
    assert commander.landed and not commander.armed


def test_a_lost_data_link_holds_then_returns_with_nav_dll_act_2_and_does_nothing_by_default_or_while_landing():
    commander = on_a_mission()
    commander.data_link_lost(1.0, estimate())
    assert commander.mode == (MAIN_AUTO, SUB_AUTO_MISSION)  # NAV_DLL_ACT 0, PX4's default
    commander.params.set("NAV_DLL_ACT", 2)
    commander.data_link_lost(1.0, estimate())
    assert commander.mode == (MAIN_AUTO, SUB_AUTO_LOITER)
    commander.update(1.0 + commander.params["COM_FAIL_ACT_T"] - 0.1, estimate(), 0.42)
    assert commander.mode == (MAIN_AUTO, SUB_AUTO_LOITER)
    commander.update(1.0 + commander.params["COM_FAIL_ACT_T"], estimate(), 0.42)
    assert commander.mode == (MAIN_AUTO, SUB_AUTO_RTL)
    landing = on_a_mission()
    landing.params.set("NAV_DLL_ACT", 2)
    landing.set_mode((MAIN_AUTO, SUB_AUTO_LAND), estimate())
    landing.data_link_lost(1.0, estimate())
    assert landing.mode == (MAIN_AUTO, SUB_AUTO_LAND)


def test_position_mode_falls_back_to_altitude_mode_while_the_sticks_last_and_to_descend_without_them():
    commander = Commander(Params())
    commander.armed, commander.landed, commander.home = True, False, (0.0, 0.0, 0.0)
    commander.on_sticks(Sticks(0.0, 0.5, 0.0, 0.0, 0, 1.0), estimate())
    assert commander.set_mode((MAIN_POSCTL, 0), estimate(), 1.0)
    by_hand = commander.update(1.1, estimate(), 0.42, position_valid=False)
    assert by_hand.tilt_from_sticks and commander.reported_mode == (MAIN_ALTCTL, 0)
    # the sticks fall silent: manual control is lost (NAV_RCL_ACT's Return cannot run either), so it descends
    lost = commander.update(1.0 + commander.params["COM_RC_LOSS_T"] + 0.1, estimate(), 0.42, position_valid=False)
    assert lost.level and commander.reported_mode == (MAIN_AUTO, SUB_AUTO_LAND)


def flown(tmp_path: Path, capsys, concrete: Path, *argv: str) -> dict:
    capsys.readouterr()
    main(["run", "--concrete", str(concrete), "--out", str(tmp_path), "--json", *argv])
    return json.loads(capsys.readouterr().out)


def wall_off_the_route(tmp_path: Path, failure: dict, route_north_m: float | None = None) -> Path:
    """The wall moved 25 m east, off the route, so that whatever the vehicle does it hits nothing,
    with one failure (and its logical declaration), and the route made longer where asked."""
    document = json.loads(WALL_CONCRETE.read_text())
    document["obstacles"][0]["position"]["east_m"] = 25.0
    if route_north_m is not None:
        document["logical_scenario"]["mission"] = {"waypoints": [{"north_m": route_north_m, "east_m": 0.0, "altitude_m": 8.0}]}
    document["failures"] = [failure]
    document["logical_scenario"]["failures"] = [{"unit": failure["unit"], "type": failure["type"]}]
    path = tmp_path / f"wall_{failure['unit'].replace(' ', '_')}_{failure['type']}.json"
    path.write_text(json.dumps(document))
    return path


def wall_with_the_range_sensor_off(tmp_path: Path) -> Path:
    """The range sensor going silent 6 s into the run for good, on a 150 m route: a vehicle that
    flies on blind is still in Position mode well past the 6 s of range_loss_holds (on the
    wall's 60 m route it could reach the goal just then)."""
    return wall_off_the_route(tmp_path, {"unit": "distance sensor", "type": "off", "onset_s": 6.0, "duration_s": 60.0}, route_north_m=150.0)


@pytest.mark.slow
def test_in_position_mode_a_silent_range_sensor_stops_the_vehicle_and_switches_to_hold_unless_collision_prevention_is_off(tmp_path, capsys):
    concrete = wall_with_the_range_sensor_off(tmp_path)
    judged = ("--drive", "pilot", "--property", "range_loss_stops", "--property", "range_loss_holds", "--property", "clearance")
    # GIVEN a pilot pushing along the route when the range sensor falls silent
    held = flown(tmp_path / "cp", capsys, concrete, *judged)
    # THEN the bundled autopilot stops where it is and switches to Hold, as PX4's collision prevention does
    assert "No obstacle data, switching to Hold" in held["mavsdk"]["status_texts"]
    assert {name: scored["verdict"] for name, scored in held["properties"].items()} == {"range_loss_stops": "kept", "range_loss_holds": "kept", "clearance": "kept"}
    # and without collision prevention the same flight goes on blind, breaking both failsafe
    # properties, which the clearance alone cannot tell
    blind = flown(tmp_path / "no-cp", capsys, concrete, *judged, "--sut-param", "CP_DIST=-1")
    assert {name: scored["verdict"] for name, scored in blind["properties"].items()} == {"range_loss_stops": "violated", "range_loss_holds": "violated", "clearance": "kept"}
    assert blind["properties"]["range_loss_stops"]["robustness"] < -3.0  # m/s faster than the creep allowed


@pytest.mark.slow
def test_a_lost_gps_makes_the_bundled_autopilot_descend_and_the_seeded_unit_slip_flies_on_blind(tmp_path, capsys):
    witness = ROOT / "scenarios" / "faults" / "noaid_timeout_ms.json"
    lost = flown(tmp_path / "clean", capsys, witness, "--property", "gps_loss_lands", "--property", "clearance")
    assert lost["properties"]["gps_loss_lands"]["verdict"] == "kept"
    assert "Failsafe: no position, switching to Descend" in lost["mavsdk"]["status_texts"]
    blind = flown(tmp_path / "fault", capsys, witness, "--sut-fault", "noaid_timeout_ms", "--property", "gps_loss_lands", "--property", "clearance")
    assert blind["properties"]["gps_loss_lands"]["verdict"] == "violated"
    # the clearance alone sees nothing wrong with either flight
    assert lost["properties"]["clearance"]["verdict"] == blind["properties"]["clearance"]["verdict"] == "kept"
    # and explain says when the faulty flight broke it: 5 s into the loss, still flying its mission
    capsys.readouterr()
    assert main(["explain", blind["log_path"], "--property", "gps_loss_lands", "--json"]) == 0
    explained = json.loads(capsys.readouterr().out)["properties"]["gps_loss_lands"]
    onset_s = next(m for _t, _ns, m in logs.messages(Path(blind["log_path"]), ["/events"]) if m["event"] == "failure")["t"]
    assert explained["verdict"] == "violated" and onset_s + 5.0 <= explained["decided"]["time_s"] <= onset_s + 5.1
    assert explained["decided"]["signals"] == {"lost_gps": 1.0, "mode_land": 0.0, "mode_altitude": 0.0, "armed": 1.0}


@pytest.mark.slow
def test_a_property_campaigns_findings_are_triaged_by_what_broke_and_exported_with_their_properties(tmp_path, capsys):
    store = tmp_path / "c.db"
    assert main(["campaign", str(ROOT / "scenarios" / "faults" / "logical" / "gps_loss.json"), "--algorithm", "RANDOM", "--evaluations", "4",
                 "--workers", "2", "--seed", "3", "--store", str(store), "--sut-fault", "noaid_timeout_ms",
                 "--property", "gps_loss_lands", "--property", "clearance", "--json"]) == 0
    capsys.readouterr()
    # THEN triage groups the flights by the properties they broke and the failures injected
    assert main(["triage", str(store), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["by_properties"] and report["violations"] >= 1
    assert all(mode["mode"].startswith("breaks ") and mode["failures"] == "gps off" for mode in report["modes"])
    assert report["modes"][0]["worst"]["robustness"] < 0
    # and each bundle keeps the properties: its case judges them, its FINDING says how to fly and shrink with them
    assert main(["export-findings", str(store), "--out", str(tmp_path / "findings")]) == 0
    capsys.readouterr()
    bundle = sorted((tmp_path / "findings").glob("01-*"))[0]
    case = json.loads((bundle / "case.regression.json").read_text())
    assert [prop["name"] for prop in case["properties"]] == ["gps_loss_lands", "clearance"]
    assert json.loads((bundle / "properties.json").read_text())["gps_loss_lands"]["verdict"] == "violated"
    finding = (bundle / "FINDING.md").read_text()
    assert "--property gps_loss_lands --property clearance" in finding and "--out shrunk --sut-fault noaid_timeout_ms --property gps_loss_lands" in finding


def with_the_data_link_lost(tmp_path: Path) -> Path:
    """The ground station's link lost 8 s into the run for 30 s."""
    return wall_off_the_route(tmp_path, {"unit": "data link", "type": "off", "onset_s": 8.0, "duration_s": 30.0})


@pytest.mark.slow
def test_a_lost_data_link_makes_the_bundled_autopilot_hold_then_return_as_nav_dll_act_says_and_nothing_by_default(tmp_path, capsys):
    concrete = with_the_data_link_lost(tmp_path)
    # GIVEN NAV_DLL_ACT 2 (Return): PX4 holds COM_FAIL_ACT_T, then returns
    acting = flown(tmp_path / "act", capsys, concrete, "--sut-param", "NAV_DLL_ACT=2", "--property", "datalink_loss_acts")
    assert acting["status"] not in ("sut_crashed", "sim_crashed", "timeout", "sut_stalled"), acting["why"]
    assert acting["properties"]["datalink_loss_acts"]["verdict"] == "kept"
    said = sut_status_texts(Path(acting["log_path"]))
    # PX4's 2.5 s link timeout and COM_DL_LOSS_T (10 s) of simulated time after the last heartbeat,
    # which came at most about a simulated second before the loss: heartbeats paced by the
    # flight's clock, not MAVSDK's wall clock (PX4 itself: 11.9-12.9 s, docs/failsafe_campaigns.md)
    lost_after_s = said["Data link lost"] - failure_onset_s(Path(acting["log_path"]))
    assert 10.5 <= lost_after_s <= 13.5
    assert said["Failsafe activated: entering Hold for 5 seconds"] - said["Data link lost"] < 0.5
    # and with PX4's default, 0, the mission carries on: the property (for a SUT set to act) is broken
    default = flown(tmp_path / "default", capsys, concrete, "--property", "datalink_loss_acts")
    assert default["properties"]["datalink_loss_acts"]["verdict"] == "violated"


def sut_status_texts(log: Path) -> dict[str, float]:
    """What the SUT said on its API link and when first (log time, s), as the log recorded it (also
    what MAVSDK did not hear during a link loss)."""
    from pymavlink.dialects.v20 import common as mavlink

    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    texts: dict[str, float] = {}
    for _t, ns, record in logs.messages(log, ["/mavlink/api"]):
        if record["direction"] == "from_sut":
            for message in parser.parse_buffer(bytes.fromhex(record["hex"])) or []:
                if message.get_type() == "STATUSTEXT":
                    texts.setdefault(message.text, ns / 1e9)
    return texts


def failure_onset_s(log: Path) -> float:
    return next(ns / 1e9 for _t, ns, event in logs.messages(log, ["/events"]) if event.get("event") == "failure")
