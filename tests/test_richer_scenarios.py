"""Richer scenarios without flying: curved and vertical motion, intruders placed by their encounter,
gusts and turbulence, injected failures: how they enter the search space, the world spec and the
simulator's world."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from conftest import ROOT
from harness.scenario.logical import load_logical, logical_problems
from harness.scenario.motion import arc_points, intruder_speed, smooth_points
from harness.scenario.space import SearchSpace
from harness.scenario.world import space_from_concrete, world_spec
from sim_bridge.failures import FailureSchedule
from sim_bridge.obstacles import Obstacle
from sim_bridge.spec import Atmosphere, FailureSpec, Gust, Turbulence, WorldSpec
from sim_bridge.wind import WindField

DATA = ROOT / "tests" / "data" / "scenarios"
COMBINED = ROOT / "scenarios" / "examples" / "intruder_gusts_failure.json"


def space_for(name, profile) -> SearchSpace:
    return SearchSpace(load_logical(DATA / name, profile), profile)


def test_the_combined_example_gives_every_new_dimension_and_round_trips(profile):
    space = SearchSpace(load_logical(COMBINED, profile), profile)
    names = [d.name for d in space.dimensions]
    assert names == [
        "wind_speed_m_s", "wind_from_deg", "temperature_c",
        "turbulence_m_s", "gust.amplitude_m_s", "gust.from_deg", "gust.onset_s", "gust.duration_s",
        "failure_1.onset_s", "failure_1.duration_s",
        "obstacle_1.closest_approach_s", "obstacle_1.crossing_deg", "obstacle_1.closing_speed_m_s", "obstacle_1.vertical_offset_m",
        "obstacle_1.turn_rate_deg_s",
        "obstacle_2.length_m", "obstacle_2.width_m", "obstacle_2.height_m", "obstacle_2.north_m", "obstacle_2.east_m", "obstacle_2.yaw_deg",
    ]
    moderate = profile.document["gusts"]["categories"]["moderate"]
    assert (space.lower[3], space.upper[3]) == (moderate["turbulence"]["min"], moderate["turbulence"]["max"])
    # The crossing's range spans both sides; the head-on sector is cut out by a constraint.
    assert (space.lower[11], space.upper[11]) == (30.0, 330.0)
    x = space.sample_feasible(np.random.default_rng(5), 20)
    assert np.all(np.abs(x[:, 11] - 180.0) >= 30.0)
    concrete = space.to_concrete(x[0])
    assert concrete["failures"][0]["unit"] == "distance sensor" and concrete["obstacles"][0]["encounter"] == "crossing"
    again = space_from_concrete(json.loads(json.dumps(concrete)), "combined.json")
    assert np.array_equal(again.from_concrete(concrete), x[0])


def test_scenarios_without_the_new_elements_keep_their_concrete_form(profile):
    space = SearchSpace(load_logical(ROOT / "scenarios" / "table3" / "scenario_09.json", profile), profile)
    concrete = space.to_concrete(space.sample_feasible(np.random.default_rng(1), 1)[0])
    assert "failures" not in concrete and "gust" not in concrete["environment"] and "turbulence_m_s" not in concrete["environment"]
    assert all(set(o["motion"]) == {"altitude_m", "heading_deg", "speed_m_s", "travel_m"} for o in concrete["obstacles"] if o["kind"] == "dynamic")
    world = world_spec(space, space.vector_from({}), seed=1)
    assert world.failures is None and world.atmosphere.turbulence is None and all("path" not in o for o in world.obstacles)


@pytest.mark.parametrize("obstacle, pointer, says", [
    ({"kind": "intruder", "encounter": "any", "size": "small"}, "/environment/obstacles/0/size", "an intruder is another multirotor"),
    ({"kind": "static", "size": "small", "form": "sphere", "motion": "arc"}, "/environment/obstacles/0/motion", 'only a "dynamic" obstacle moves'),
    ({"kind": "dynamic", "size": "small", "form": "sphere", "encounter": "crossing"}, "/environment/obstacles/0/encounter", 'only an "intruder"'),
    ({"kind": "intruder"}, "/environment/obstacles/0", "encounter"),
    ({"kind": "intruder", "encounter": "sideways"}, "/environment/obstacles/0/encounter", "sideways"),
])
def test_a_misdescribed_obstacle_is_refused_where_it_is_wrong(profile, obstacle, pointer, says):
    document = json.loads((DATA / "intruder_head_on.json").read_text())
    document["environment"]["obstacles"] = [obstacle]
    problems = logical_problems(document, profile, "s.json")
    assert any(p.pointer == pointer and says in p.message for p in problems), problems


def test_two_failures_of_one_unit_and_an_unknown_gust_band_are_refused(profile):
    document = json.loads((DATA / "wall_baro_wrong_gps_off.json").read_text())
    document["failures"].append({"unit": "gps", "type": "stuck"})
    problems = logical_problems(document, profile, "s.json")
    assert [(p.pointer, "one failure per unit" in p.message) for p in problems] == [("/failures/2/unit", True)]
    document["failures"].pop()
    document["environment"]["weather"]["gusts"] = "hurricane"
    assert [p.pointer for p in logical_problems(document, profile, "s.json")] == ["/environment/weather/gusts"]


def test_the_data_link_is_lost_or_not_and_a_stuck_one_is_refused_where_it_is_written(profile):
    document = json.loads((DATA / "wall_baro_wrong_gps_off.json").read_text())
    document["failures"].append({"unit": "data link", "type": "off"})
    assert logical_problems(document, profile, "s.json") == []
    document["failures"][-1]["type"] = "stuck"
    problems = logical_problems(document, profile, "s.json")
    assert [(p.pointer, '"off"' in p.message) for p in problems] == [("/failures/2/type", True)]


def test_arc_and_smooth_paths_go_where_they_are_described():
    north, east = arc_points(30.0, 12.0, 270.0, 12.0, 180.0, 65)
    # A right turn from heading west: the centre 12 m to the north, half a circle to (54, 12).
    assert np.allclose(np.hypot(north - 42.0, east - 12.0), 12.0)
    assert (north[0], east[0]) == pytest.approx((30.0, 12.0)) and (north[-1], east[-1]) == pytest.approx((54.0, 12.0))
    assert (north[32], east[32]) == pytest.approx((42.0, 0.0))
    left_north, _ = arc_points(30.0, 12.0, 270.0, 12.0, -180.0, 65)
    assert left_north[-1] == pytest.approx(6.0)
    north, east = smooth_points([(0.0, 0.0), (10.0, 5.0), (20.0, 0.0)], 16)
    assert (north[16], east[16]) == pytest.approx((10.0, 5.0)) and (north[-1], east[-1]) == pytest.approx((20.0, 0.0))


def test_an_obstacle_moves_along_its_path_back_and_forth_or_once():
    path = [{"north_m": 0.0, "east_m": 0.0, "up_m": 5.0}, {"north_m": 3.0, "east_m": 4.0, "up_m": 5.0}, {"north_m": 3.0, "east_m": 14.0, "up_m": 5.0}]
    spec = {"id": "o", "kind": "dynamic", "form": "sphere", "size": {"diameter_m": 1.0}, "a": path[0], "b": path[-1], "speed_m_s": 2.0, "path": path}
    mover = Obstacle.from_spec(spec)
    assert mover.position_at(1.0) == pytest.approx([1.2, 1.6, 5.0])  # 2 m along the first 5 m leg
    assert mover.position_at(5.0) == pytest.approx([3.0, 9.0, 5.0])  # 10 m: 5 m into the second leg
    assert mover.position_at(10.0) == pytest.approx([3.0, 9.0, 5.0])  # back: 20 m is 10 m short of the 30 m round trip
    once = Obstacle.from_spec({**spec, "kind": "intruder", "repeat": "once"})
    assert once.position_at(100.0) == pytest.approx([3.0, 14.0, 5.0])
    assert np.array_equal(once.track, np.array([[0.0, 0.0, 5.0], [3.0, 4.0, 5.0], [3.0, 14.0, 5.0]]))


@pytest.mark.parametrize("crossing_deg, closing_m_s, speed_m_s", [(180.0, 10.0, 5.0), (0.0, 3.0, 8.0), (90.0, 13.0, 12.0)])
def test_an_intruder_closes_at_its_closing_speed(crossing_deg, closing_m_s, speed_m_s):
    assert float(intruder_speed(5.0, crossing_deg, closing_m_s)) == pytest.approx(speed_m_s)


def test_an_intruder_passes_where_the_uav_is_expected_at_the_time_of_closest_approach(profile):
    space = space_for("intruder_crossing_arc.json", profile)
    geometry = {"obstacle_1.closest_approach_s": 8.0, "obstacle_1.crossing_deg": 90.0, "obstacle_1.closing_speed_m_s": 13.0,
                "obstacle_1.vertical_offset_m": 1.5, "obstacle_1.turn_rate_deg_s": 10.0}
    world = world_spec(space, space.vector_from(geometry), seed=1)
    intruder = Obstacle.from_spec(world.obstacles[0])
    expected_north = (8.0 - space.timing.takeoff_s) * space.mission.cruise_speed_m_s
    assert intruder.position_at(8.0) == pytest.approx([expected_north, 0.0, 8.0 + 1.5], abs=0.05)
    # At that moment it flies east (90 degrees from the north-bound route) at 12 m/s, turning right.
    velocity = (intruder.position_at(8.05) - intruder.position_at(7.95)) / 0.1
    assert velocity[:2] == pytest.approx([0.0, 12.0], abs=0.15)
    later = (intruder.position_at(17.05) - intruder.position_at(16.95)) / 0.1
    assert math.degrees(math.atan2(later[1], later[0])) % 360.0 == pytest.approx(90.0 + 90.0, abs=1.0)  # 9 s at 10 deg/s later
    assert space.violations(space.vector_from({**geometry, "obstacle_1.crossing_deg": 170.0})) == ["obstacle_1 crosses rather than meets head-on"]
    assert "obstacle_1 can close at its closing speed from its crossing angle" in space.violations(
        space.vector_from({**geometry, "obstacle_1.closing_speed_m_s": 3.0}))


def test_a_curved_path_is_kept_out_of_the_start_and_landing_areas(profile):
    space = space_for("moving_arc.json", profile)
    arc = {"obstacle_1.diameter_m": 5.0, "obstacle_1.north_m": 30.0, "obstacle_1.east_m": 15.0, "obstacle_1.heading_deg": 270.0,
           "obstacle_1.radius_m": 15.0, "obstacle_1.turn_deg": 180.0}
    assert space.violations(space.vector_from(arc)) == ["obstacle_1 (path) keeps out of the landing area"]
    assert space.violations(space.vector_from({**arc, "obstacle_1.turn_deg": 90.0})) == []


def test_a_gust_rises_and_falls_as_one_minus_cosine_and_turbulence_has_its_intensity():
    gust = Gust(amplitude_m_s=6.0, from_deg=180.0, onset_s=10.0, duration_s=2.0)
    field = WindField(Atmosphere(1.0, 0.0, 15.0, gust=gust), seed=3, dt_s=0.004)
    assert field.advance(None, 0.0) == (1.0, 0.0, 0.0)  # before the run: the steady wind only
    assert field.advance(9.9, 5.0) == (1.0, 0.0, 0.0)
    north, east, _ = field.advance(11.0, 5.0)  # the peak, blowing north
    assert (north, east) == pytest.approx((7.0, 0.0))
    assert field.advance(11.5, 5.0)[0] == pytest.approx(1.0 + 3.0)
    turbulence = Turbulence(sigma_horizontal_m_s=2.0, sigma_vertical_m_s=1.0, length_horizontal_m=55.0, length_vertical_m=8.0)
    samples = np.array([WindField(Atmosphere(0.0, 0.0, 15.0, turbulence=turbulence), seed=s, dt_s=0.004).advance(0.0, 5.0) for s in range(400)])
    assert samples.std(axis=0) == pytest.approx([2.0, 2.0, 1.0], rel=0.15)
    first = WindField(Atmosphere(0.0, 0.0, 15.0, turbulence=turbulence), seed=7, dt_s=0.004)
    second = WindField(Atmosphere(0.0, 0.0, 15.0, turbulence=turbulence), seed=7, dt_s=0.004)
    assert [first.advance(t * 0.004, 5.0) for t in range(500)] == [second.advance(t * 0.004, 5.0) for t in range(500)]


def test_the_simulator_fails_a_reading_it_owns_from_onset_to_end():
    events = []
    schedule = FailureSchedule((FailureSpec("gps", "stuck", 2.0, 1.0, "simulator"), FailureSpec("barometer", "off", 1.0, 3.0, "sut")),
                               lambda event, detail: events.append((event, detail["unit"])))
    delivered = [schedule.reading("gps", t, t, wrong=lambda r: r) for t in (None, 1.5, 2.0, 2.5, 3.0, 3.5)]
    assert delivered == [None, 1.5, 1.5, 1.5, 3.0, 3.5]  # held at the last reading before the onset
    assert events == [("failure", "gps"), ("failure_cleared", "gps")]
    assert schedule.command_due(0.5) is None
    assert [(spec.unit, kind) for spec, kind in (schedule.command_due(1.0), schedule.command_due(9.0))] == [("barometer", "off"), ("barometer", "ok")]
    assert schedule.command_due(9.0) is None


def test_a_world_spec_with_every_new_part_round_trips_and_names_a_bad_delivery(profile):
    space = SearchSpace(load_logical(COMBINED, profile), profile)
    world = world_spec(space, space.sample_feasible(np.random.default_rng(2), 1)[0], seed=2)
    assert world.atmosphere.gust is not None and world.failures[0].delivery == "simulator"
    assert WorldSpec.from_dict(json.loads(json.dumps(world.as_dict()))) == world
    document = world.as_dict()
    document["failures"][0]["delivery"] = "radio"
    with pytest.raises(ValueError, match="/failures/0/delivery"):
        WorldSpec.from_dict(document)
