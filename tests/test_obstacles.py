"""Obstacle geometry: python-fcl clearance against analytic distances, dynamic motion, range sensing."""

from __future__ import annotations

import io
import json
import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from conftest import ROOT
from harness.scenario.logical import load_logical
from harness.scenario.space import SearchSpace
from harness.scenario.world import world_spec
from sim_bridge.bridge import Bridge
from sim_bridge.bridge_io import BridgeConfig
from sim_bridge.control import AddObstacle, MoveObstacle
from sim_bridge.frames import UINT16_MAX
from sim_bridge.obstacles import Obstacle, ObstacleField, ray_distances
from sim_bridge.recording import Recorder
from sim_bridge.spec import (Atmosphere, Body, MissionSpec, Origin, Point, RangeSensor, Surface, Uav, Waypoint,
                             WorldSpec)

BODY = Body(length_m=0.6, width_m=0.6, height_m=0.2)


def obstacle(form, size, at, b=None, speed=0.0, yaw=0.0, id_="o"):
    def point(p):
        return None if p is None else {"north_m": p[0], "east_m": p[1], "up_m": p[2]}

    return Obstacle.from_spec({"id": id_, "form": form, "size": size, "yaw_rad": yaw, "a": point(at), "b": point(b), "speed_m_s": speed})


def clearance(o, body_at=(0.0, 0.0, 0.0), yaw=0.0):
    field = ObstacleField([o], BODY)
    field.place_body(*body_at, 0.0, 0.0, yaw)
    return field.clearances()[0]


# The body is a 0.6 x 0.6 x 0.2 m box at the origin; analytic distances from its faces, edges and corners.
CASES = [
    ("sphere", {"diameter_m": 4.0}, (5.0, 0.0, 0.0), 5.0 - 2.0 - 0.3),
    ("sphere", {"diameter_m": 4.0}, (0.0, 0.0, 5.0), 5.0 - 2.0 - 0.1),
    ("sphere", {"diameter_m": 2.0}, (3.0, 3.0, 0.0), math.hypot(2.7, 2.7) - 1.0),
    ("cylinder", {"diameter_m": 2.0, "height_m": 4.0}, (0.0, 5.0, 0.0), 5.0 - 1.0 - 0.3),
    ("cylinder", {"diameter_m": 2.0, "height_m": 4.0}, (0.0, 0.0, 5.0), 5.0 - 2.0 - 0.1),
    ("cylinder", {"diameter_m": 2.0, "height_m": 2.0}, (4.0, 4.0, 0.0), math.hypot(3.7, 3.7) - 1.0),
    ("cuboid", {"length_m": 2.0, "width_m": 2.0, "height_m": 2.0}, (0.0, 5.0, 0.0), 5.0 - 1.0 - 0.3),
    ("cuboid", {"length_m": 2.0, "width_m": 2.0, "height_m": 2.0}, (0.5, 0.5, 5.0), 5.0 - 1.0 - 0.1),
    ("cuboid", {"length_m": 2.0, "width_m": 2.0, "height_m": 2.0}, (3.0, 3.0, 0.0), math.hypot(1.7, 1.7)),
    ("cuboid", {"length_m": 2.0, "width_m": 2.0, "height_m": 2.0}, (3.0, 3.0, 3.0), math.sqrt(1.7**2 + 1.7**2 + 1.9**2)),
]


@pytest.mark.parametrize("form,size,at,expected", CASES, ids=[f"{c[0]}-{i}" for i, c in enumerate(CASES)])
def test_fcl_clearance_equals_the_analytic_distance(form, size, at, expected):
    # GJK converges to within a few micrometres; 10 um is far below anything that matters here.
    assert clearance(obstacle(form, size, at)) == pytest.approx(expected, abs=1e-5)


def test_rotated_cuboid_and_overlap_give_signed_distances():
    wall = obstacle("cuboid", {"length_m": 1.0, "width_m": 10.0, "height_m": 5.0}, (0.0, 5.0, 0.0), yaw=math.pi / 2)
    # Yawed 90 degrees its 1 m length runs east: near face 4.5 m east, minus the body's half width.
    assert clearance(wall) == pytest.approx(4.5 - 0.3, abs=1e-5)
    inside = obstacle("sphere", {"diameter_m": 2.0}, (0.5, 0.0, 0.0))
    assert clearance(inside) < 0.0


def test_dynamic_obstacle_moves_back_and_forth_on_its_segment():
    moving = obstacle("sphere", {"diameter_m": 1.0}, (0.0, 0.0, 5.0), b=(10.0, 0.0, 5.0), speed=2.0)
    expected = {0.0: 0.0, 2.5: 5.0, 5.0: 10.0, 7.5: 5.0, 10.0: 0.0, 11.0: 2.0}
    for time_s, north in expected.items():
        np.testing.assert_allclose(moving.position_at(time_s), (north, 0.0, 5.0), atol=1e-9)
    field = ObstacleField([moving], BODY)
    field.move_to(2.5)
    field.place_body(0.0, 0.0, 5.0, 0.0, 0.0, 0.0)
    assert field.clearances()[0] == pytest.approx(5.0 - 0.5 - 0.3, abs=1e-6)


def test_world_spec_dynamic_obstacles_follow_their_concrete_motion(profile):
    space = SearchSpace(load_logical(ROOT / "scenarios" / "table3" / "scenario_31.json", profile), profile)
    x = space.sample_feasible(np.random.default_rng(2), 1)[0]
    concrete = space.to_concrete(x)
    for spec, entry in zip(world_spec(space, x, 0).obstacles, concrete["obstacles"]):
        motion = entry["motion"]
        o = Obstacle.from_spec(spec)
        heading = math.radians(motion["heading_deg"])
        t = 0.5 * motion["travel_m"] / motion["speed_m_s"]
        north = entry["position"]["north_m"] + 0.5 * motion["travel_m"] * math.cos(heading)
        east = entry["position"]["east_m"] + 0.5 * motion["travel_m"] * math.sin(heading)
        np.testing.assert_allclose(o.position_at(t)[:2], (north, east), atol=1e-9)


def test_ray_casting_hits_circles_and_rotated_rectangles():
    angles = np.radians([0.0, 90.0, 180.0])
    hits = ray_distances(0.0, 0.0, angles, ("circle", (10.0, 0.0, 2.0)))
    assert hits[0] == pytest.approx(8.0) and math.isinf(hits[1]) and math.isinf(hits[2])
    # A 2 x 6 m box centred 10 m east: along north its 6 m side faces the ray, yawed east its 2 m side.
    assert ray_distances(0.0, 0.0, angles, ("rect", (0.0, 10.0, 1.0, 3.0, 0.0)))[1] == pytest.approx(7.0)
    assert ray_distances(0.0, 0.0, angles, ("rect", (0.0, 10.0, 1.0, 3.0, math.pi / 2)))[1] == pytest.approx(9.0)


def _bridge_with(obstacles, visibility_m=10_000.0, fov_deg=360.0):
    space_profile = json.loads((ROOT / "scenarios" / "profiles" / "default.json").read_text())
    sensor = {**space_profile["sensor"], "fov_deg": fov_deg}
    from harness.scenario.world import sensor_range_m

    sensor["range_m"] = sensor_range_m(sensor, visibility_m)
    world = WorldSpec(
        scenario="sectors", seed=1, origin=Origin(lat_deg=47.397742, lon_deg=8.545594, alt_m=488.0), terrain={"kind": "flat"},
        surface=Surface(kind="land", water=()), atmosphere=Atmosphere(wind_north_m_s=0.0, wind_east_m_s=0.0, temperature_c=15.0),
        visibility_m=visibility_m, sensor=RangeSensor(**{k: v for k, v in sensor.items() if k != "description"}), obstacles=tuple(obstacles),
        uav=Uav(start=Point(north_m=0.0, east_m=0.0, up_m=0.0), body=BODY),
        mission=MissionSpec(takeoff_altitude_m=8.0, waypoints=(Waypoint(north_m=60.0, east_m=0.0, altitude_m=8.0),), cruise_speed_m_s=5.0, land=True),
        safety_distance_m=1.0, time_limit_s=10.0)
    recorder = Recorder(io.BytesIO())
    recorder.__enter__()
    return Bridge(world, BridgeConfig(), recorder)


def _range_messages(bridge) -> list:
    """The bridge's range frames of this step, as pymavlink reads them."""
    return [mavlink.MAVLink(None).decode(bytearray(frame)) for frame in bridge.frames.obstacle_distance(0)]


def _sectors(bridge):
    message = _range_messages(bridge)[0]
    assert message.get_type() == "OBSTACLE_DISTANCE"
    return list(message.distances), message.max_distance


def test_an_obstacle_at_bearing_30_degrees_appears_in_sector_6():
    north, east = 8.0 * math.cos(math.radians(30)), 8.0 * math.sin(math.radians(30))
    bridge = _bridge_with([{"id": "pole", "form": "cylinder", "size": {"diameter_m": 0.5, "height_m": 10.0}, "a": {"north_m": north, "east_m": east, "up_m": 5.0}, "b": None}])
    distances, max_cm = _sectors(bridge)
    hit = [i for i, d in enumerate(distances) if d <= max_cm]
    assert 6 in hit and all(5 <= i <= 7 for i in hit)
    # 8 m to the axis, minus the 0.25 m radius, minus the hull: 0.3 / cos(30 deg) from the centre.
    assert distances[6] == pytest.approx(775 - 100 * 0.3 / math.cos(math.radians(30)), abs=3)


def test_the_same_reading_goes_out_as_distance_sensor_wedges_for_px4():
    north, east = 8.0 * math.cos(math.radians(30)), 8.0 * math.sin(math.radians(30))
    bridge = _bridge_with([{"id": "pole", "form": "cylinder", "size": {"diameter_m": 0.5, "height_m": 10.0}, "a": {"north_m": north, "east_m": east, "up_m": 5.0}, "b": None}],
                          fov_deg=100.0)
    sectors, *wedges = _range_messages(bridge)
    assert [w.get_type() for w in wedges] == ["DISTANCE_SENSOR"] * 6 and [w.id for w in wedges] == list(range(6))
    yaws = [math.degrees(2 * math.atan2(w.quaternion[3], w.quaternion[0])) for w in wedges]
    assert yaws == pytest.approx([-42.5, -22.5, -2.5, 17.5, 37.5, 50.0])  # 4 sectors of 5 degrees each, the last one alone
    assert all(w.orientation == 100 and w.max_distance == sectors.max_distance for w in wedges)  # MAV_SENSOR_ROTATION_CUSTOM
    # each wedge reports the nearest of its sectors; the pole at 30 degrees only in the 37.5-degree one
    assert [w.current_distance for w in wedges] == [min(min(sectors.distances[i] for i in group), sectors.max_distance) for _q, _fov, group in bridge.frames.wedges]
    assert [w.current_distance < w.max_distance for w in wedges] == [False, False, False, False, True, False]
    assert wedges[4].current_distance == sectors.distances[6]


def test_fog_shortens_the_sensed_range_as_the_profile_says():
    wall = [{"id": "wall", "form": "cuboid", "size": {"length_m": 1.0, "width_m": 30.0, "height_m": 10.0}, "a": {"north_m": 12.0, "east_m": 0.0, "up_m": 5.0}, "b": None}]
    clear, clear_max = _sectors(_bridge_with(wall, visibility_m=10_000.0))
    foggy, foggy_max = _sectors(_bridge_with(wall, visibility_m=300.0))
    assert clear_max == 2000 and foggy_max == 600  # 20 m * 300 / 1000
    assert clear[0] == pytest.approx(1150 - 30, abs=2)  # seen through clear air, from the hull
    assert foggy[0] == foggy_max + 1  # beyond reach in fog: reported as free up to the reduced range


def test_sectors_outside_the_field_of_view_are_unknown():
    distances, _ = _sectors(_bridge_with([], fov_deg=100.0))
    visible = [i for i, d in enumerate(distances) if d != UINT16_MAX]
    assert visible == list(range(0, 11)) + list(range(62, 72))


def test_obstacles_beyond_the_sensors_reach_are_left_out_without_changing_a_reading():
    """Every ray that meets an obstacle within reach meets it at the same distance with or
    without the obstacles wholly beyond reach; None only where no ray meets one within reach."""
    rng = np.random.default_rng(5)
    angles = np.radians(np.arange(72) * 5.0)
    forms = [("sphere", {"diameter_m": 2.0}), ("cylinder", {"diameter_m": 1.0, "height_m": 20.0}), ("cuboid", {"length_m": 4.0, "width_m": 1.0, "height_m": 20.0})]
    for trial in range(300):
        obstacles = []
        for index in range(3):
            form, size = forms[rng.integers(3)]
            north, east = rng.uniform(-25.0, 25.0, 2)
            obstacles.append(Obstacle.from_spec({"id": f"o{index}", "form": form, "size": size, "yaw_rad": float(rng.uniform(0, 3)),
                                                 "a": {"north_m": float(north), "east_m": float(east), "up_m": 5.0}, "b": None}))
        field = ObstacleField(obstacles, BODY)
        reach = float(rng.uniform(5.0, 20.0))
        everything = field.sector_distances(0.0, 0.0, 5.0, angles)
        within_reach = field.sector_distances(0.0, 0.0, 5.0, angles, reach)
        seen = everything <= reach
        if within_reach is None:
            assert not seen.any(), trial
        else:
            assert np.array_equal(within_reach[seen], everything[seen]) and (within_reach[~seen] > reach).all(), trial


def test_obstacles_moved_while_the_sut_computes_are_where_the_step_would_have_put_them():
    """The bridge moves the obstacles on to the next step's time before the SUT's answer
    (World.move_obstacles_for_next_step); changes scheduled for that step still apply in it."""
    def world_with_changes():
        pole = {"id": "pole", "form": "cylinder", "size": {"diameter_m": 0.5, "height_m": 10.0}, "a": {"north_m": 8.0, "east_m": 0.0, "up_m": 5.0},
                "b": {"north_m": 8.0, "east_m": 6.0, "up_m": 5.0}, "speed_m_s": 1.5}
        world = _bridge_with([pole]).world
        world.start_run(0.0)
        ball = {"id": "ball", "form": "sphere", "size": {"diameter_m": 1.0}, "a": {"north_m": 4.0, "east_m": 4.0, "up_m": 5.0},
                "b": {"north_m": 4.0, "east_m": -4.0, "up_m": 5.0}, "speed_m_s": 3.0}
        world.schedule(AddObstacle(ball, at_s=0.1))
        world.schedule(MoveObstacle("pole", {"north_m": 9.0, "east_m": 0.0, "up_m": 5.0}, None, at_s=0.2))
        return world

    def positions(world):
        return {o.id: o.position.tolist() for o in world.field.obstacles}

    plain, early = world_with_changes(), world_with_changes()
    for _ in range(100):
        early.move_obstacles_for_next_step()
        for world in (plain, early):
            world.step((0.0, 0.0, 0.0, 0.0))
        assert positions(early) == positions(plain)
    assert set(positions(plain)) == {"pole", "ball"} and positions(plain)["pole"] == [9.0, 0.0, 5.0]
