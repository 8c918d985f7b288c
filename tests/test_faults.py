"""Seeded faults: each switches on the bug it documents in the autopilot's own code path, and
nothing else; selecting one is checked at every door; every witness reveals its fault."""

from __future__ import annotations

import json
import math

import pytest
from pymavlink.dialects.v20.common import MAV_CMD_NAV_WAYPOINT

from test_autopilot_units import UNKNOWN, wall_ahead
from autopilot.app import Autopilot
from autopilot.collision import BINS, ObstacleMap, constrain_velocity
from autopilot.commander import Commander, MissionItem, VehicleEstimate
from autopilot.faults import BY_NAME, FAULTS, markdown_table
from autopilot.params import ParamError, Params
from conftest import ROOT
from harness.faults.checks import witness_path
from harness.tools.cli import main

AREAS = {"collision prevention", "sensing", "estimation", "control", "commander", "failsafe"}


def test_at_least_ten_documented_faults_over_every_area():
    assert len(FAULTS) >= 10 and {fault.area for fault in FAULTS} == AREAS
    assert all(fault.breaks and fault.kin and fault.revealed_by for fault in FAULTS)


def test_the_fault_documentation_is_generated_from_the_declarations():
    assert (ROOT / "docs" / "seeded_faults.md").read_text() == markdown_table(), "run: python -m autopilot.faults > docs/seeded_faults.md"


def test_a_fault_is_chosen_by_name_and_an_unknown_one_refused(capsys):
    assert Params().fault is None and Params(fault="cp_ignores_delay").fault == "cp_ignores_delay"
    with pytest.raises(ParamError, match="unknown fault 'cp_typo'"):
        Params(fault="cp_typo")
    assert main(["run", "scenarios/examples/fig4.json", "--sut-fault", "cp_typo"]) == 2
    assert "no seeded fault 'cp_typo'" in capsys.readouterr().err
    assert main(["run", "scenarios/examples/fig4.json", "--sut", "px4", "--sut-fault", "cp_ignores_delay"]) == 2
    assert "seeded faults live in the bundled autopilot" in capsys.readouterr().err


def allowed_speed(params: Params, wall_m: float) -> float:
    """The speed collision prevention allows towards a wall while flying at it at 5 m/s."""
    return constrain_velocity(params, wall_ahead(wall_m), 0.0, (5.0, 0.0), (5.0, 0.0))[0]


@pytest.mark.parametrize("fault", ["cp_ignores_delay", "cp_braking_without_jerk", "cp_off_above_cruise"])
def test_braking_faults_allow_more_speed_than_the_vehicle_can_stop_from(fault):
    for wall_m in (4.0, 6.0, 8.0):
        assert allowed_speed(Params(fault=fault), wall_m) > allowed_speed(Params(), wall_m) + 0.3


def test_narrow_view_ignores_an_obstacle_beside_the_direction_of_travel():
    distances = [UNKNOWN] * BINS
    for sector in range(-10, 11):
        distances[sector % BINS] = 2001
    distances[6] = 200  # 30 degrees right, 2 m
    seen = ObstacleMap()
    seen.update(0.0, 0.0, distances, 5.0, 0.0, 20, 2000)
    direction = (math.cos(math.radians(30.0)), math.sin(math.radians(30.0)))
    setpoint = (3.0, 0.0)  # north: 2.6 m/s of it towards the obstacle
    towards = lambda v: v[0] * direction[0] + v[1] * direction[1]
    assert towards(constrain_velocity(Params(), seen, 0.0, setpoint, (0.0, 0.0))) < 1.0
    faulty = ObstacleMap("cp_narrow_view")
    faulty.update(0.0, 0.0, distances, 5.0, 0.0, 20, 2000)
    assert constrain_velocity(Params(fault="cp_narrow_view"), faulty, 0.0, setpoint, (0.0, 0.0)) == pytest.approx(setpoint)


@pytest.mark.parametrize("fault, yaw_deg, expected_bin", [
    (None, 270.0, 54 + 2), ("range_frame_world", 270.0, 2), ("cp_sector_mirrored", 270.0, 54 - 2),
    ("cp_sector_mirrored", 90.0, 18 + 2),  # below 180 degrees the mirror does not apply
])
def test_sector_faults_put_an_obstacle_in_the_wrong_world_bin(fault, yaw_deg, expected_bin):
    distances = [UNKNOWN] * BINS
    distances[2] = 500  # 10 degrees right of the nose
    m = ObstacleMap(fault)
    m.update(0.0, math.radians(yaw_deg), distances, 5.0, 0.0, 20, 2000)
    assert [i for i, d in enumerate(m.distances) if d is not None] == [expected_bin]


def estimate(north=0.0, east=0.0, down=-8.0, yaw=0.0) -> VehicleEstimate:
    return VehicleEstimate(north, east, down, 0.0, 0.0, 0.0, yaw)


def commander(fault: str | None) -> Commander:
    c = Commander(Params(fault=fault))
    c.home, c.landed = (0.0, 0.0, 0.0), False
    c.set_mission([MissionItem(0, MAV_CMD_NAV_WAYPOINT, 30.0, 0.0, 8.0), MissionItem(1, MAV_CMD_NAV_WAYPOINT, 30.0, 40.0, 8.0)])
    assert c.arm(0.0, True, "")[0] and c.start_mission(estimate())
    return c


def test_yaw_fixed_heading_keeps_the_take_off_heading_after_a_turn():
    for fault, heading in ((None, 90.0), ("yaw_fixed_heading", 0.0)):
        c = commander(fault)
        c.update(1.0, estimate(north=30.0), 0.42)  # first waypoint reached
        sp = c.update(1.1, estimate(north=30.0), 0.42)
        assert math.degrees(sp.yaw_rad) == pytest.approx(heading)


def test_acceptance_radius_10x_takes_a_waypoint_20_m_early():
    for fault, current in ((None, 0), ("acceptance_radius_10x", 1)):
        c = commander(fault)
        c.update(1.0, estimate(north=11.0), 0.42)
        assert c.current == current


def test_land_detect_home_altitude_never_lands_off_the_home_altitude():
    for fault, landed in ((None, True), ("land_detect_home_altitude", False)):
        c = Commander(Params(fault=fault))
        c.home, c.landed = (0.0, 0.0, 0.0), False
        c.armed = True
        on_hill = estimate(down=-6.0)  # resting on ground 6 m above home
        assert any(c._detect_landing(t / 10, on_hill, 0.1, True) for t in range(20)) == landed


def test_baro_temperature_drift_grows_with_heat_over_the_first_minute():
    for fault, at_30s in ((None, 0.0), ("baro_temperature_drift", 0.4 * 20.0 * 0.5)):
        autopilot = Autopilot(Params(fault=fault))
        autopilot.now_s = 30.0
        assert autopilot._baro_drift_m(35.0) == pytest.approx(at_30s)
        assert autopilot._baro_drift_m(10.0) == 0.0


@pytest.mark.slow
def test_every_witness_reveals_its_fault(tmp_path, capsys):
    assert all(witness_path(fault.name).is_file() for fault in FAULTS)
    code = main(["faults", "check", "--out", str(tmp_path), "--json"])
    report = json.loads(capsys.readouterr().out)
    assert code == 0 and report["all_revealed"], [(e["fault"], e.get("with_fault"), e.get("without")) for e in report["witnesses"] if not e["revealed"]]
    assert {e["fault"] for e in report["witnesses"]} == set(BY_NAME)


def test_faults_list_names_each_fault_with_its_documentation_and_witness(capsys):
    assert main(["faults", "list", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)["faults"]
    assert [f["name"] for f in listed] == [f.name for f in FAULTS]
    assert all(f["witness"] == str(witness_path(f["name"])) and f["breaks"] and f["revealed_by"] for f in listed)


def test_each_faults_action_shows_and_takes_only_its_own_options(capsys):
    with pytest.raises(SystemExit) as shown:
        main(["faults", "check", "--help"])
    text = capsys.readouterr().out
    assert shown.value.code == 0
    assert "--workers" in text and "--tries" not in text and "--algorithm" not in text
    # an option of another action is refused, not silently ignored
    with pytest.raises(SystemExit) as refused:
        main(["faults", "list", "--tries", "3"])
    assert refused.value.code == 2 and "unrecognized arguments: --tries 3" in capsys.readouterr().err

