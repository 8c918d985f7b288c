"""QGroundControl .plan missions: reading them (and refusing what cannot be flown as planned, with
the item's location), the world and the upload they become, the bundled autopilot's delay and hold
time, and real flights of a plan."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20.common import MAV_CMD_NAV_DELAY, MAV_CMD_NAV_WAYPOINT

from autopilot.commander import Commander, MissionItem, VehicleEstimate
from autopilot.params import Params
from conftest import PLAN_SCENARIO, PLAN_SPEED_M_S, ROOT, plan_flight
from harness.errors import InputError
from harness.flight.mavsdk_session import mission_items
from harness.scenario.logical import load_logical
from harness.scenario.plan import plan_from_document, plan_problems
from harness.scenario.space import SearchSpace
from harness.scenario.world import world_spec
from harness.tools.cli import main
from sim_bridge.geo import geodetic_from_local
from sim_bridge.spec import Origin, WorldSpec

PLAN = ROOT / "scenarios" / "examples" / "two_altitudes.plan"
HOME = {"lat_deg": 47.397742, "lon_deg": 8.545594, "alt_m": 488.0}


def plan_document() -> dict:
    return json.loads(PLAN.read_text())


def item(command: int, frame: int, north: float | None = None, east: float | None = None, altitude: float = 0.0, p1: float = 0.0, p2: float = 0.0) -> dict:
    lat, lon = geodetic_from_local(HOME["lat_deg"], HOME["lon_deg"], north, east) if north is not None else (0.0, 0.0)
    return {"type": "SimpleItem", "command": command, "frame": frame, "autoContinue": True, "params": [p1, p2, 0, None, lat, lon, altitude]}


def with_items(*items: dict) -> dict:
    document = plan_document()
    document["mission"]["items"] = list(items)
    return document


def test_positions_and_altitudes_in_the_local_frame_of_home():
    plan = plan_from_document(with_items(
        item(22, 3, altitude=5.0),
        item(16, 0, 40.0, -12.5, 488.0 + 9.0),  # above mean sea level: 9 m above home
        item(16, 3, 10.0, 30.0, 7.0, p2=3.5),
        item(20, 2),
    ), "t.plan")
    first, second = plan.waypoints
    assert (first.north_m, first.east_m, first.altitude_m) == pytest.approx((40.0, -12.5, 9.0), abs=0.01)
    assert (second.north_m, second.east_m, second.altitude_m) == pytest.approx((10.0, 30.0, 7.0), abs=0.01)
    assert plan.takeoff_altitude_m == 5.0 and plan.lands
    assert plan.landing_point == (0.0, 0.0)  # return to launch ends at home
    area = plan.area()
    assert (area["north_min_m"], area["north_max_m"], area["east_min_m"], area["east_max_m"]) == pytest.approx((-20.0, 60.0, -32.5, 50.0), abs=0.01)


def test_the_world_of_a_plan_has_its_home_as_origin_and_uploads_the_items_as_planned(profile):
    space = SearchSpace(load_logical(PLAN_SCENARIO, profile), profile)
    world = world_spec(space, space.sample_feasible(np.random.default_rng(0), 1)[0], 0)
    assert world.origin == Origin(**HOME)
    mission = world.mission
    assert [w.altitude_m for w in mission.waypoints] == [6.0, 12.0]
    assert (mission.landing.north_m, mission.landing.east_m) == pytest.approx((55.0, -5.0), abs=0.01)
    uploaded = mission_items(WorldSpec.from_dict(json.loads(json.dumps(world.as_dict()))))  # as the worker receives it
    planned = plan_document()["mission"]["items"]
    assert [(i.command, i.frame) for i in uploaded] == [(p["command"], p["frame"]) for p in planned]
    for sent, wanted in zip(uploaded, planned):
        lat, lon, z = wanted["params"][4:]
        assert (sent.x, sent.y, sent.z) == (round(lat * 1e7), round(lon * 1e7), z)
        assert [sent.param1, sent.param2, sent.param3] == wanted["params"][:3]
        assert math.isnan(sent.param4) == (wanted["params"][3] is None)
    # the obstacle is placed around the plan's route, not the landform's
    assert space.area == {"north_min_m": pytest.approx(-20.0), "north_max_m": pytest.approx(75.0, abs=0.01),
                          "east_min_m": pytest.approx(-25.0, abs=0.01), "east_max_m": pytest.approx(30.0, abs=0.01)}


def test_a_long_plan_gets_time_to_be_flown(profile):
    document = with_items(item(22, 3, altitude=10.0), item(178, 2, p1=1, p2=2.0), item(16, 3, 300.0, 0.0, 10.0), item(93, 2, p1=30.0), item(21, 3, 300.0, 0.0))
    plan = plan_from_document(document, "t.plan")
    assert plan.flight_time_estimate_s(5.0) == pytest.approx((10.0 + 300.0 + 10.0) / 2.0 + 30.0, abs=0.1)


def test_mission_plan_replaces_the_route_of_any_scenario(profile, tmp_path):
    fig4 = ROOT / "scenarios" / "examples" / "fig4.json"
    space = SearchSpace(load_logical(fig4, profile, mission_plan=PLAN), profile)
    assert space.mission.plan is not None and len(space.mission.waypoints) == 2
    concrete = space.to_concrete(space.sample_feasible(np.random.default_rng(1), 1)[0])
    assert concrete["logical_scenario"]["mission"]["plan"]["fileType"] == "Plan"  # it travels whole with the scenario


BAD_PLANS = {
    "not_a_plan": (lambda d: d.update(fileType="Mission"), "/fileType", "not a QGroundControl plan"),
    "no_home": (lambda d: d["mission"].pop("plannedHomePosition"), "/mission/plannedHomePosition", "expected [latitude deg"),
    "home_out_of_range": (lambda d: d["mission"].update(plannedHomePosition=[95.0, 8.5, 488]), "/mission/plannedHomePosition", "out of range"),
    "no_items": (lambda d: d["mission"].update(items=[]), "/mission/items", "non-empty list"),
    "survey": (lambda d: d["mission"]["items"].insert(2, {"type": "ComplexItem", "complexItemType": "survey"}), "/mission/items/2/type",
               "survey items are not supported"),
    "loiter_unlimited": (lambda d: d["mission"]["items"][2].update(command=17), "/mission/items/2/command", "command 17 is not supported"),
    "terrain_frame": (lambda d: d["mission"]["items"][3].update(frame=10), "/mission/items/3/frame", "frame 10 (above terrain) is not supported"),
    "local_frame": (lambda d: d["mission"]["items"][2].update(frame=1), "/mission/items/2/frame", "frame 1 (local NED) is not supported"),
    "six_params": (lambda d: d["mission"]["items"][2]["params"].pop(), "/mission/items/2/params", "expected 7 numbers"),
    "waypoint_without_position": (lambda d: d["mission"]["items"][2]["params"].__setitem__(slice(4, 6), [0, 0]), "/mission/items/2/params/4",
                                  "needs a latitude and longitude"),
    "underground": (lambda d: d["mission"]["items"][3]["params"].__setitem__(6, -3), "/mission/items/3/params/6", "is not above home"),
    "amsl_below_home": (lambda d: d["mission"]["items"][3].update(frame=0), "/mission/items/3/params/6", "12 m (above mean sea level) is not above home"),
    "far_away": (lambda d: d["mission"]["items"][3]["params"].__setitem__(4, 47.6), "/mission/items/3/params/4", "km from home"),
    "negative_speed": (lambda d: d["mission"]["items"][1]["params"].__setitem__(1, -4), "/mission/items/1/params/1", "give a positive speed"),
    "waits_for_operator": (lambda d: d["mission"]["items"][2].update(autoContinue=False), "/mission/items/2/autoContinue", "cannot be flown unattended"),
    "after_landing": (lambda d: d["mission"]["items"].append(copy.deepcopy(d["mission"]["items"][2])), "/mission/items/5",
                      "comes after the land item 4"),
    "lands_where_it_took_off": (lambda d: d["mission"].update(items=[d["mission"]["items"][0], item(21, 3)]), "/mission/items",
                                "no waypoint, and the plan lands where it took off"),
    "starts_with_landing": (lambda d: d["mission"].update(items=[d["mission"]["items"][4]]), "/mission/items/0",
                            "the plan starts with landing: add a takeoff item before it (PX4 refuses it too)"),
    "takeoff_after_a_waypoint": (lambda d: d["mission"]["items"].insert(3, copy.deepcopy(d["mission"]["items"][0])), "/mission/items/3",
                                 "a takeoff that is not the first item with a position (item 0 is): remove it or move it first (PX4 refuses it too)"),
    "text_for_command": (lambda d: d["mission"]["items"][0].update(command="takeoff"), "/mission/items/0/command", "'takeoff' is not supported"),
}


@pytest.mark.parametrize("name", sorted(BAD_PLANS))
def test_a_plan_that_cannot_be_flown_as_planned_is_refused_with_the_item_located(name, tmp_path, capsys):
    mutate, at, message = BAD_PLANS[name]
    document = plan_document()
    mutate(document)
    problems = plan_problems(document, "bad.plan")
    assert [p.pointer for p in problems] == [at] and message in problems[0].message, problems
    path = tmp_path / f"{name}.plan"
    path.write_text(json.dumps(document))
    assert main(["space", str(ROOT / "scenarios" / "examples" / "fig4.json"), "--mission-plan", str(path)]) == 2
    assert f"{path}: {at}: " in capsys.readouterr().err


def test_a_plan_error_inside_a_scenario_is_located_in_the_scenario(profile, tmp_path):
    scenario = json.loads(PLAN_SCENARIO.read_text())
    (tmp_path / "two_altitudes.plan").write_text(PLAN.read_text().replace('"command": 178', '"command": 179'))
    (tmp_path / "s.json").write_text(json.dumps(scenario))
    with pytest.raises(InputError) as raised:
        load_logical(tmp_path / "s.json", profile)
    assert str(raised.value).startswith(f"{tmp_path / 'two_altitudes.plan'}: /mission/items/1/command: command 179 is not supported")
    scenario["mission"]["waypoints"] = [{"north_m": 1, "east_m": 1, "altitude_m": 5}]
    (tmp_path / "both.json").write_text(json.dumps(scenario))
    assert main(["validate", str(tmp_path / "both.json")]) == 2


def estimate(north: float = 0.0, east: float = 0.0, down: float = 0.0) -> VehicleEstimate:
    return VehicleEstimate(north, east, down, 0.0, 0.0, 0.0, 0.0)


def test_delay_and_hold_time_keep_the_vehicle_in_place_for_their_seconds():
    commander = Commander(Params())
    commander.home = (0.0, 0.0, 0.0)
    commander.landed = False
    commander.set_mission([MissionItem(0, MAV_CMD_NAV_WAYPOINT, 10.0, 0.0, 5.0, 3.0), MissionItem(1, MAV_CMD_NAV_DELAY, 0.0, 0.0, 0.0, 2.5, has_position=False),
                           MissionItem(2, MAV_CMD_NAV_WAYPOINT, 30.0, 0.0, 5.0)])
    assert commander.arm(0.0, True, "")[0] and commander.start_mission(estimate(down=-5.0))
    there = estimate(north=10.0, down=-5.0)
    t, advanced_at = 10.0, {}
    while commander.current < 2 and t < 20.0:
        sp = commander.update(t, there, 0.42)
        assert (sp.north_m, sp.east_m, sp.down_m) == (10.0, 0.0, -5.0) or commander.current == 2
        for kind, value in commander.events:
            if kind == "item_reached":
                advanced_at.setdefault(value, t)
        t = round(t + 0.1, 1)
    assert advanced_at[0] == pytest.approx(13.0)  # reached at 10 s, held 3 s
    assert advanced_at[1] == pytest.approx(13.1 + 2.5)  # the delay counts from the step its item became current


@pytest.mark.slow
def test_the_bundled_autopilot_flies_a_plan_as_planned_and_repeats_it_bit_for_bit(tmp_path, capsys):
    results = []
    for repeat in range(2):
        assert main(["run", str(PLAN_SCENARIO), "--seed", "2", "--out", str(tmp_path / str(repeat)), "--json"]) == 0
        results.append(json.loads(capsys.readouterr().out))
    result = results[0]
    assert result["status"] == "ok", result["why"]
    flight = plan_flight(Path(result["log_path"]))
    for waypoint in flight["waypoints"]:
        assert waypoint["miss_m"] <= 2.0 and abs(waypoint["altitude_error_m"]) <= 0.5, flight["waypoints"]
    assert flight["waypoints"][1]["at_it_s"] >= 1.5  # held 2 s
    assert 3.5 <= flight["max_speed_m_s"] <= PLAN_SPEED_M_S + 0.6  # the plan's 4 m/s, not the 5 m/s default
    assert results[1]["fitness"] == result["fitness"]
    assert plan_flight(Path(results[1]["log_path"]))["states"] == flight["states"]
