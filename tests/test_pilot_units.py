"""The pilot drive's pieces without processes: the simulated pilot, the bundled autopilot's RC
input and Position mode, and the pilot dimensions of the search space."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pytest

from autopilot.commander import MAIN_AUTO, MAIN_POSCTL, SUB_AUTO_LAND, SUB_AUTO_LOITER, SUB_AUTO_RTL, Commander, VehicleEstimate
from autopilot.manual import PositionMode, Sticks, mode_slot, normalized_channel, sticks_from_rc
from autopilot.params import Params
from conftest import ROOT
from harness.campaigns.campaign import CampaignConfig
from harness.campaigns.regression import load_regression
from harness.scenario.logical import load_logical
from harness.scenario.space import SearchSpace
from harness.scenario.world import load_concrete, world_spec
from sim_bridge.physics import VehicleState as State
from sim_bridge.pilot import BLOCKED_AFTER_S, SETTLE_S, SLOT_HOLD, SLOT_LAND, SLOT_POSITION, SUT_PARAMS, Pilot, RcFrame, pwm, slot_value
from sim_bridge.spec import PilotSpec, Point, Waypoint

WALL = ROOT / "scenarios" / "examples" / "wall.json"
WALL_CONCRETE = ROOT / "scenarios" / "examples" / "wall_concrete.json"


def pilot(**overrides) -> Pilot:
    settings = {"max_stick": 1.0, "aim_offset_m": 0.0, **overrides}
    route = [Waypoint(north_m=60.0, east_m=0.0, altitude_m=8.0)]
    return Pilot(Point(north_m=0.0, east_m=0.0, up_m=0.0), route, 8.0, settings["max_stick"], settings["aim_offset_m"])


def pilot_params() -> Params:
    return Params(dict(SUT_PARAMS))


# -- the pilot's transmitter as the SUT reads it ----------------------------------------------------


@pytest.mark.parametrize("slot", range(1, 7))
def test_each_mode_switch_slot_the_pilot_sends_is_the_slot_px4s_formula_reads(slot):
    params = pilot_params()
    raw = pwm(slot_value(slot))
    assert mode_slot(normalized_channel(raw, params["RC5_MIN"], params["RC5_TRIM"], params["RC5_MAX"], params["RC5_REV"], params["RC5_DZ"])) == slot


@pytest.mark.parametrize("value", [-1.0, -0.55, -0.2, 0.0, 0.3, 0.8, 1.0])
def test_a_stick_value_survives_the_pwm_round_trip_within_a_microsecond(value):
    back = normalized_channel(pwm(value), 1000.0, 1500.0, 2000.0, 1.0, 10.0)
    assert back == pytest.approx(value, abs=1.0 / 490)


def test_the_rc_frame_maps_to_px4s_stick_convention_through_the_pilot_parameters():
    frame = RcFrame(roll=0.25, pitch=0.5, throttle=-0.4, yaw=0.1, slot=SLOT_POSITION)
    sticks = sticks_from_rc(pilot_params(), 3.0, 8, frame.channels())
    assert (sticks.roll, sticks.pitch, sticks.throttle, sticks.yaw) == pytest.approx((0.25, 0.5, -0.4, 0.1), abs=0.003)
    assert sticks.mode_slot == SLOT_POSITION and sticks.received_s == 3.0


def test_an_rc_the_sut_has_not_been_set_up_for_is_ignored_as_in_px4():
    channels = RcFrame(0.0, 1.0, 0.0, 0.0, SLOT_POSITION).channels()
    assert sticks_from_rc(Params(), 0.0, 8, channels) is None  # RC_CHAN_CNT 0, nothing mapped
    assert sticks_from_rc(pilot_params(), 0.0, 3, channels) is None  # fewer than four channels


# -- the bundled autopilot's commander and Position mode ----------------------------------------


def estimate(north=0.0, east=0.0, down=-8.0, yaw=0.0) -> VehicleEstimate:
    return VehicleEstimate(north, east, down, 0.0, 0.0, 0.0, yaw)


def flying_commander() -> Commander:
    commander = Commander(pilot_params())
    commander.armed, commander.landed, commander.home = True, False, (0.0, 0.0, 0.0)
    return commander


def sticks(slot: int, t: float, pitch: float = 0.0) -> Sticks:
    return Sticks(0.0, pitch, 0.0, 0.0, slot, t)


def test_the_mode_switch_changes_the_mode_only_when_its_slot_changes():
    commander = flying_commander()
    commander.on_sticks(sticks(SLOT_HOLD, 1.0), estimate())  # armed: the first position is not applied
    assert commander.mode == (MAIN_AUTO, SUB_AUTO_LOITER)
    commander.set_mode((MAIN_AUTO, SUB_AUTO_RTL), estimate(), 1.0)
    commander.on_sticks(sticks(SLOT_HOLD, 1.02), estimate())  # unchanged switch: Return stays
    assert commander.mode == (MAIN_AUTO, SUB_AUTO_RTL)
    commander.on_sticks(sticks(SLOT_POSITION, 1.04), estimate())
    assert commander.mode == (MAIN_POSCTL, 0)
    commander.on_sticks(sticks(SLOT_LAND, 1.06), estimate())
    assert commander.mode == (MAIN_AUTO, SUB_AUTO_LAND)


def test_position_mode_needs_manual_control_and_losing_it_triggers_nav_rcl_act():
    commander = flying_commander()
    assert not commander.set_mode((MAIN_POSCTL, 0), estimate(), 1.0)
    commander.on_sticks(sticks(SLOT_POSITION, 1.0), estimate())
    commander._mode_slot = SLOT_HOLD
    commander.on_sticks(sticks(SLOT_POSITION, 1.0), estimate())
    assert commander.mode == (MAIN_POSCTL, 0)
    assert commander.update(1.4, estimate(), 0.4).manual
    commander.update(1.0 + commander.params["COM_RC_LOSS_T"] + 0.01, estimate(), 0.4)
    assert commander.mode == (MAIN_AUTO, SUB_AUTO_RTL)  # NAV_RCL_ACT 2, PX4's default
    assert ("statustext", "Manual control lost") in commander.events


def fly_position_mode(seconds: float, pitch: float, yaw: float = 0.0, mode: PositionMode | None = None, dt: float = 0.004):
    """Integrate Position mode's setpoint as if the vehicle followed its velocity exactly."""
    position = [0.0, 0.0, -8.0]
    if mode is None:
        mode = PositionMode(Params())
        mode.reset(0.0, 0.0, tuple(position), yaw)
    setpoint = None
    for _ in range(round(seconds / dt)):
        setpoint = mode.update(dt, Sticks(0.0, pitch, 0.0, 0.0, SLOT_POSITION, 0.0), tuple(position), yaw)
        position[0] += setpoint[3] * dt
        position[1] += setpoint[4] * dt
    return mode, setpoint, position


def test_full_forward_stick_flies_along_the_heading_at_mpc_vel_manual():
    _, setpoint, _ = fly_position_mode(20.0, pitch=1.0, yaw=math.pi / 2)
    north, east, down, v_north, v_east, v_down, _yaw = setpoint
    assert v_east == pytest.approx(Params()["MPC_VEL_MANUAL"], rel=0.02) and abs(v_north) < 1e-6
    assert north is None and down == -8.0 and v_down == 0.0


def test_released_sticks_brake_to_a_standstill_and_lock_the_position():
    mode, _, _ = fly_position_mode(5.0, pitch=1.0)
    mode, setpoint, position = fly_position_mode(8.0, pitch=0.0, mode=mode)
    assert setpoint[3] == setpoint[4] == 0.0
    assert (setpoint[0], setpoint[1]) == pytest.approx((position[0], position[1]), abs=0.05)


def test_a_stick_inside_the_dead_zone_does_nothing():
    _, setpoint, position = fly_position_mode(3.0, pitch=Params()["MPC_HOLD_DZ"] * 0.9)
    assert setpoint[3] == 0.0 and position[0] == 0.0


# -- the simulated pilot --------------------------------------------------------------------------


def test_the_pilot_waits_for_the_takeoff_then_flies_forward_in_position_mode():
    p = pilot()
    assert p.update(0.0, State(up_m=3.0, v_down_m_s=-1.5)).slot == SLOT_HOLD
    frame = p.update(0.02, State(up_m=8.0))
    assert p.phase == "cruise" and frame.slot == SLOT_POSITION
    assert frame.pitch == pytest.approx(1.0) and frame.roll == pytest.approx(0.0) and frame.yaw == 0.0


def test_the_pilot_steers_towards_its_aim_line_facing_where_it_flies():
    p = pilot(aim_offset_m=6.0, max_stick=0.5)
    p.update(0.0, State(up_m=8.0))
    frame = p.update(0.02, State(north_m=10.0, up_m=8.0))
    assert p.aim == pytest.approx((18.0, 6.0))  # 8 m ahead on the line 6 m to the right of the route
    assert frame.roll > 0 and frame.yaw > 0 and math.hypot(frame.roll, frame.pitch) == pytest.approx(0.5)
    p.update(0.04, State(north_m=58.0, east_m=0.5, up_m=8.0))
    assert p.aim[1] == pytest.approx(0.0)  # the offset has faded into the goal


def test_over_the_goal_the_pilot_lets_go_then_switches_to_land():
    p = pilot()
    p.update(0.0, State(up_m=8.0))
    over = State(north_m=59.6, up_m=8.0)
    assert p.update(10.0, over) == RcFrame(0.0, 0.0, 0.0, 0.0, SLOT_POSITION)
    assert p.update(10.0 + SETTLE_S / 2, over).slot == SLOT_POSITION
    assert p.update(10.0 + SETTLE_S, over).slot == SLOT_LAND


def test_a_pilot_held_back_for_twenty_seconds_is_blocked_and_one_moving_on_is_not():
    p = pilot()
    p.update(0.0, State(up_m=8.0))
    for step in range(int(BLOCKED_AFTER_S / 0.02)):
        p.update(step * 0.02, State(north_m=10.0 + step * 0.02 * 0.1, up_m=8.0))  # 0.1 m/s: slow but moving
    assert not p.blocked
    held = State(north_m=20.0, up_m=8.0)
    start = BLOCKED_AFTER_S
    p.update(start, held)
    p.update(start + BLOCKED_AFTER_S - 0.02, held)
    assert not p.blocked
    p.update(start + BLOCKED_AFTER_S, held)
    assert p.blocked


# -- the search space and the data around it ---------------------------------------------------


def test_the_pilot_drive_adds_the_pilots_stick_and_aim_to_the_space(profile):
    mission = SearchSpace(load_logical(WALL, profile), profile)
    piloted = SearchSpace(load_logical(WALL, profile, "pilot"), profile)
    names = [d.name for d in piloted.dimensions]
    assert names == [d.name for d in mission.dimensions] + ["pilot.max_stick", "pilot.aim_offset_m"]
    assert (piloted.lower[-2:].tolist(), piloted.upper[-2:].tolist()) == ([0.3, -10.0], [1.0, 10.0])
    x = piloted.vector_from({"pilot.max_stick": 0.7, "pilot.aim_offset_m": -3.0})
    concrete = piloted.to_concrete(x)
    assert concrete["drive"] == "pilot" and concrete["pilot"] == {"max_stick": 0.7, "aim_offset_m": -3.0}
    assert concrete["logical_scenario"]["mission"]["drive"] == "pilot"
    world = world_spec(piloted, x, 0)
    assert world.drive == "pilot" and world.pilot == PilotSpec(max_stick=0.7, aim_offset_m=-3.0)
    assert mission.to_concrete(mission.lower)["drive"] == "mission" and "pilot" not in world_spec(mission, mission.lower, 0).as_dict()


def test_a_mission_concrete_scenario_flown_by_the_pilot_gets_full_stick_along_the_route():
    space, x = load_concrete(WALL_CONCRETE, "pilot")
    assert space.mission.drive == "pilot"
    assert dict(zip([d.name for d in space.dimensions], x))["pilot.max_stick"] == 1.0
    assert x[-1] == 0.0
    mission_space, mission_x = load_concrete(WALL_CONCRETE)
    assert mission_space.mission.drive == "mission" and len(mission_x) == len(x) - 2


def test_the_drive_override_is_part_of_the_campaign_identity():
    base = CampaignConfig((str(ROOT / "scenarios" / "examples" / "fig4.json"),), ("NSGAII",), 10)
    assert "drive" not in base.identity()
    assert replace(base, drive="pilot").identity()["drive"] == "pilot"
    assert replace(base, drive="pilot").identity() != replace(base, drive="mission").identity()


def test_an_unknown_drive_is_a_located_error(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text(Path(WALL).read_text().replace('"system"', '"mission": {"drive": "autopilot"}, "system"'))
    from harness.tools.cli import main

    assert main(["validate", str(bad)]) == 2


def test_a_regression_case_flies_with_the_drive_the_plugin_asks_for():
    case = load_regression(ROOT / "tests" / "data" / "regressions" / "safe_fig4.json", "pilot")
    assert case.space.mission.drive == "pilot" and case.concrete["drive"] == "pilot"
    assert case.concrete["pilot"] == {"max_stick": 1.0, "aim_offset_m": 0.0}
    assert load_regression(ROOT / "tests" / "data" / "regressions" / "safe_fig4.json").space.mission.drive == "mission"


def test_one_seed_samples_the_same_world_with_either_drive(profile):
    import numpy as np

    scenario = ROOT / "scenarios" / "table3" / "scenario_09.json"
    mission = SearchSpace(load_logical(scenario, profile), profile)
    piloted = SearchSpace(load_logical(scenario, profile, "pilot"), profile)
    for seed in range(5):
        a = mission.sample_feasible(np.random.default_rng(seed), 3)
        b = piloted.sample_feasible(np.random.default_rng(seed), 3)
        assert (b[:, : mission.n_dimensions] == a).all()


def test_a_concrete_scenario_whose_recorded_drive_contradicts_its_logical_scenario_is_refused():
    import json

    from harness.errors import InputError

    document = json.loads(WALL_CONCRETE.read_text())
    document["drive"] = "pilot"
    space, _x = load_concrete(WALL_CONCRETE)
    with pytest.raises(InputError) as error:
        space.from_concrete(document, "wall.json")
    assert error.value.problems[0].pointer == "/drive"


@pytest.mark.parametrize("text", ['"not an object"', '{"name": "x", "mission": "pilot"}'])
def test_a_malformed_scenario_with_drive_override_gets_a_located_error_not_a_traceback(tmp_path, capsys, text):
    from harness.tools.cli import main

    bad = tmp_path / "bad.json"
    bad.write_text(text)
    assert main(["space", str(bad), "--drive", "pilot"]) == 2
    assert str(bad) in capsys.readouterr().err


def test_bench_refuses_a_drive_it_would_not_use(capsys):
    from harness.tools.cli import main

    assert main(["bench", "--executor", "local", "--drive", "pilot"]) == 2
    assert "--drive" in capsys.readouterr().err


def _fly_to_the_goal(p: Pilot, full_stick_m_s: float, dead_zone: float, accel_m_s2: float, seconds: float) -> float:
    """A vehicle in Position mode as a point mass: the stick outside the dead zone asks for a
    velocity (PX4's MPC_VEL_MANUAL, ArduPilot's LOIT_SPEED at full stick), which it reaches at
    `accel_m_s2`; sticks let go, it brakes at that rate to a standstill. The time the pilot
    switches to Land, or inf."""
    dt, north, east, v_n, v_e, yaw = 0.02, 40.0, 0.0, 0.0, 0.0, 0.0
    for step in range(int(seconds / dt)):
        t = step * dt
        frame = p.update(t, State(north_m=north, east_m=east, up_m=8.0, v_north_m_s=v_n, v_east_m_s=v_e, yaw_rad=yaw))
        if frame.slot == SLOT_LAND:
            return t
        stick = math.hypot(frame.pitch, frame.roll)
        wanted = max(0.0, (stick - dead_zone) / (1.0 - dead_zone)) * full_stick_m_s
        heading = yaw + math.atan2(frame.roll, frame.pitch)
        want_n, want_e = (wanted * math.cos(heading), wanted * math.sin(heading)) if stick > dead_zone else (0.0, 0.0)
        d_n, d_e = want_n - v_n, want_e - v_e
        change = math.hypot(d_n, d_e)
        if change > accel_m_s2 * dt:
            d_n, d_e = d_n * accel_m_s2 * dt / change, d_e * accel_m_s2 * dt / change
        v_n, v_e = v_n + d_n, v_e + d_e
        north, east = north + v_n * dt, east + v_e * dt
        yaw += frame.yaw * dt
    return math.inf


@pytest.mark.parametrize(("full_stick_m_s", "dead_zone", "accel_m_s2"), [
    (10.0, 0.1, 3.0),  # PX4's defaults: MPC_VEL_MANUAL, MPC_HOLD_DZ, MPC_ACC_HOR
    (12.5, 0.06, 2.5),  # ArduCopter's Loiter: LOIT_SPEED, RC_DZ 30 of 500 us, LOIT_BRK_ACCEL
    (20.0, 0.0, 2.0),  # a SUT faster at small sticks and slower to brake than either
])
def test_the_pilot_settles_over_the_goal_and_lands_whatever_speed_the_sut_gives_its_smallest_stick(full_stick_m_s, dead_zone, accel_m_s2):
    p = Pilot(Point(north_m=0.0, east_m=0.0, up_m=0.0), [Waypoint(north_m=60.0, east_m=0.0, altitude_m=8.0)], 8.0, 1.0, 0.0)
    p.update(0.0, State(up_m=8.0))
    landed_at = _fly_to_the_goal(p, full_stick_m_s, dead_zone, accel_m_s2, seconds=BLOCKED_AFTER_S)
    assert landed_at < BLOCKED_AFTER_S and not p.blocked


def test_while_a_smaller_stick_still_slows_the_vehicle_the_pilot_keeps_pushing_towards_the_goal():
    p = pilot()
    p.update(0.0, State(up_m=8.0))
    fast = p.update(1.0, State(north_m=45.0, up_m=8.0, v_north_m_s=10.0))  # 15 m to go at 10 m/s: its stopping distance is longer
    assert fast.pitch == pytest.approx(0.75)
    # at the smallest stick's speed: it pushes while the vehicle would stop short, lets go once it would coast in
    assert p.update(2.0, State(north_m=56.0, up_m=8.0, v_north_m_s=3.0)).pitch == pytest.approx(0.3)  # 4 m to go, 2.25 m to stop
    near = p.update(2.5, State(north_m=57.5, up_m=8.0, v_north_m_s=3.0))  # 2.5 m to go
    assert near.pitch == 0.0 and near.slot == SLOT_POSITION
