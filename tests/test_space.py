"""Search spaces derived from all 32 Table III scenarios: dimensions, bounds, constraints, round trips."""

from __future__ import annotations

import json
import math

import fcl
import numpy as np
import pytest

from conftest import ROOT, TABLE3
from harness.errors import InputError
from harness.scenario.logical import load_logical, logical_from_document
from harness.scenario.space import SearchSpace
from harness.scenario.world import load_concrete, sensor_range_m, world_spec
from harness.tools.cli import main
from sim_bridge.obstacles import yaw_rotation
from sim_bridge.terrain import terrain_height_m

SIZE_DIMS = {"cuboid": 3, "sphere": 1, "cylinder": 2}


def space_for(path, profile) -> SearchSpace:
    return SearchSpace(load_logical(path, profile), profile)


def expected_dimension_count(space: SearchSpace) -> int:
    weather = space.logical.weather
    count = 1  # temperature: every category is a true range
    count += 0 if weather["wind force"].interval.degenerate else 2  # speed and direction
    count += 0 if weather["reduced visibility"].interval.degenerate else 1
    for obstacle in space.logical.obstacles:
        count += SIZE_DIMS[obstacle.form] + 2  # sizes, north, east
        count += 1 if obstacle.form == "cuboid" else 0  # yaw
        count += 4 if obstacle.kind == "dynamic" else 0  # altitude, heading, speed, travel
    return count


@pytest.fixture(scope="module", params=TABLE3, ids=[p.stem for p in TABLE3])
def space(request, profile):
    return space_for(request.param, profile)


def test_dimension_count_follows_the_obstacles(space):
    assert space.n_dimensions == expected_dimension_count(space)
    assert len({d.name for d in space.dimensions}) == space.n_dimensions


def test_bounds_lie_inside_the_profiles_ranges(space, profile):
    weather = space.logical.weather
    for d in space.dimensions:
        assert d.lower < d.upper
        if d.name == "wind_speed_m_s":
            category = profile.parameters["wind force"].categories[weather["wind force"].category]
            assert (d.lower, d.upper) == pytest.approx((category.min / 3.6, category.max / 3.6))
        elif d.name == "visibility_m":
            category = profile.parameters["reduced visibility"].categories[weather["reduced visibility"].category]
            assert (d.lower, d.upper) == (category.min, category.max)
        elif d.name.endswith(("length_m", "width_m", "height_m", "diameter_m")):
            index = int(d.name.split(".")[0].split("_")[1]) - 1
            size = profile.obstacle_sizes[space.logical.obstacles[index].size]
            assert size.min <= d.lower and d.upper <= size.max
        elif d.name.endswith("speed_m_s"):
            assert profile.obstacle_speed_m_s.min <= d.lower and d.upper <= profile.obstacle_speed_m_s.max


def test_ten_thousand_sampled_points_keep_every_constraint(space, profile):
    X = space.sample_feasible(np.random.default_rng(7), 10_000)
    assert X.shape == (10_000, space.n_dimensions)
    assert np.all((X >= space.lower) & (X <= space.upper))
    assert space.feasible(X).all()
    # Independently of the space's own constraint code: distances between the world spec's
    # shapes, with fcl, as tall prisms (footprints), all along a moving obstacle's path.
    keep_out = profile.keep_out_radius_m
    landing = space.mission.landing_point
    for x in X[:100]:
        world = world_spec(space, x, seed=0)
        statics = []
        for obstacle in world.obstacles:
            for north, east in centres_along(obstacle):
                assert footprint_distance(obstacle, (north, east), point=(0.0, 0.0)) >= keep_out - 1e-6
                assert footprint_distance(obstacle, (north, east), point=landing) >= keep_out - 1e-6
            if obstacle["kind"] == "static":
                statics.append(obstacle)
                assert obstacle["speed_m_s"] == 0.0
            else:
                assert profile.obstacle_speed_m_s.min <= obstacle["speed_m_s"] <= profile.obstacle_speed_m_s.max
        for i, a in enumerate(statics):
            for b in statics[i + 1 :]:
                assert footprint_distance(a, (a["a"]["north_m"], a["a"]["east_m"]), other=b) >= profile.min_separation_m - 1e-6


def centres_along(obstacle, step_m: float = 0.25) -> list[tuple[float, float]]:
    """Where an obstacle's centre passes on the ground plan, at most step_m apart."""
    points = obstacle.get("path") or [p for p in (obstacle["a"], obstacle["b"]) if p is not None]
    centres = [(points[0]["north_m"], points[0]["east_m"])]
    for a, b in zip(points, points[1:]):
        length = math.hypot(b["north_m"] - a["north_m"], b["east_m"] - a["east_m"])
        for t in np.linspace(0.0, 1.0, max(2, math.ceil(length / step_m) + 1))[1:]:
            centres.append((a["north_m"] + t * (b["north_m"] - a["north_m"]), a["east_m"] + t * (b["east_m"] - a["east_m"])))
    return centres


@pytest.mark.parametrize("motion", ["straight", "arc", "vertical", "waypoints"])
@pytest.mark.parametrize("form", ["cuboid", "cylinder", "sphere"])
def test_a_moving_obstacle_keeps_out_of_start_and_landing_all_along_its_path_exactly_when_the_space_says(profile, form, motion):
    # GIVEN one dynamic obstacle of each form on each kind of path
    document = json.loads((ROOT / "tests" / "data" / "scenarios" / "moving_arc.json").read_text())
    obstacle = document["environment"]["obstacles"][0]
    obstacle.update(form=form, motion=motion)
    space = SearchSpace(logical_from_document(document, profile, "moving.json"), profile)
    keep_out, landing = profile.keep_out_radius_m, space.mission.landing_point
    X = space.sample(np.random.default_rng(11), 60)
    margins = space.constraint_margins(X)
    keep_outs = [name for name in margins if "keeps out of" in name]
    feasible = space.feasible(X)
    assert 0 < feasible.sum() < len(X)
    for x, row in zip(X, range(len(X))):
        if min(abs(margins[name][row]) for name in keep_outs) < 1e-3:
            continue  # on the boundary: either answer is right
        # WHEN its footprint's distance to the start and landing points is measured with fcl
        # along the path the world flies it on
        [moving] = world_spec(space, x, seed=0).obstacles
        nearest = min(footprint_distance(moving, centre, point=point) for centre in centres_along(moving) for point in ((0.0, 0.0), landing))
        # THEN the space calls it clear exactly where it is: a sampled path comes no nearer than
        # the path itself, and at most half a sample's spacing (0.125 m) farther
        said = (form, motion, nearest, {name: margins[name][row] for name in keep_outs})
        if all(margins[name][row] >= 0.0 for name in keep_outs):
            assert nearest >= keep_out - 1e-6, said
        else:
            assert nearest < keep_out + 0.125, said


def test_a_point_with_a_value_that_is_not_a_number_is_infeasible_not_an_error(profile):
    for scenario in ("scenario_12.json", "scenario_07.json"):  # static cuboids; movers
        space = space_for(ROOT / "scenarios" / "table3" / scenario, profile)
        X = space.sample_feasible(np.random.default_rng(0), 3)
        X[1, space._index["obstacle_1.north_m"]] = np.nan
        assert space.feasible(X).tolist() == [True, False, True]
        assert all(margin[1] == -np.inf for margin in space.constraint_margins(X).values())


def prism(obstacle, north: float, east: float) -> fcl.CollisionObject:
    size = obstacle["size"]
    shape = (fcl.Box(size["length_m"], size["width_m"], 1000.0) if obstacle["form"] == "cuboid"
             else fcl.Cylinder(size["diameter_m"] / 2.0, 1000.0))
    return fcl.CollisionObject(shape, fcl.Transform(yaw_rotation(obstacle.get("yaw_rad", 0.0)), np.array([north, east, 0.0])))


def footprint_distance(obstacle, centre, *, point=None, other=None) -> float:
    """Horizontal distance from an obstacle's footprint to a point or to another's footprint."""
    if point is not None:
        target = fcl.CollisionObject(fcl.Cylinder(1e-6, 1000.0), fcl.Transform(np.array([point[0], point[1], 0.0])))
    else:
        target = prism(other, other["a"]["north_m"], other["a"]["east_m"])
    return fcl.distance(prism(obstacle, *centre), target, fcl.DistanceRequest(), fcl.DistanceResult())


def test_vector_to_concrete_json_and_back_is_exact(space):
    X = space.sample(np.random.default_rng(3), 200)
    for x in X:
        document = json.loads(json.dumps(space.to_concrete(x)))
        assert np.array_equal(space.from_concrete(document), x)


def test_infeasible_points_name_the_broken_constraint(profile):
    space = space_for(ROOT / "scenarios" / "table3" / "scenario_05.json", profile)  # two static obstacles
    x = space.sample_feasible(np.random.default_rng(0), 1)[0]
    x[space._index["obstacle_1.north_m"]] = 0.0
    x[space._index["obstacle_1.east_m"]] = 0.0
    assert "obstacle_1 keeps out of the start area" in space.violations(x)
    assert not space.feasible(x[None, :])[0]


def test_static_obstacles_stand_on_the_terrain(profile):
    space = space_for(ROOT / "scenarios" / "table3" / "scenario_22.json", profile)  # steep transition
    terrain = profile.landforms["steep transition"].terrain
    for x in space.sample_feasible(np.random.default_rng(1), 20):
        for obstacle in world_spec(space, x, 0).obstacles:
            height = obstacle["size"].get("height_m", obstacle["size"].get("diameter_m"))
            ground = terrain_height_m(terrain, obstacle["a"]["north_m"], obstacle["a"]["east_m"])
            assert obstacle["a"]["up_m"] == pytest.approx(ground + height / 2)


def test_mission_clears_the_highest_terrain_and_lands_at_the_goal(profile):
    space = space_for(ROOT / "scenarios" / "table3" / "scenario_04.json", profile)  # steep transition, 8 m step
    (north, east, altitude), = space.mission.waypoints
    assert (north, east) == (60.0, 0.0)
    assert altitude == pytest.approx(8.0 + profile.uav["cruise_altitude_agl_m"], abs=0.01)


def test_fog_shortens_the_sensor_range(profile):
    sensor = profile.sensor
    assert sensor_range_m(sensor, 10_000.0) == sensor["max_range_m"]
    assert sensor_range_m(sensor, 500.0) == pytest.approx(sensor["max_range_m"] / 2)
    assert sensor_range_m(sensor, 50.0) == sensor["floor_range_m"]


def test_sample_is_deterministic_and_writes_a_loadable_concrete_file(tmp_path, capsys):
    scenario = str(ROOT / "scenarios" / "examples" / "fig4.json")
    out = tmp_path / "c.json"
    assert main(["sample", scenario, "--seed", "5", "--json", "--out", str(out)]) == 0
    first = capsys.readouterr().out
    assert main(["sample", scenario, "--seed", "5", "--json"]) == 0
    assert capsys.readouterr().out == first
    space, x = load_concrete(out)
    assert x.tolist() == json.loads(first)["vector"]
    assert space.n_dimensions == 17


def test_concrete_file_out_of_bounds_is_a_located_error(tmp_path, profile):
    space = space_for(ROOT / "scenarios" / "examples" / "fig4.json", profile)
    document = space.to_concrete(space.sample_feasible(np.random.default_rng(0), 1)[0])
    document["obstacles"][0]["motion"]["speed_m_s"] = 50.0
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(document))
    with pytest.raises(InputError) as error:
        load_concrete(path)
    assert f"{path}: /obstacles/0/motion/speed_m_s: 50.0 lies outside [0.5, 5.0] m/s" in str(error.value)


def test_space_command_lists_dimensions_and_not_simulated_parameters(capsys):
    assert main(["space", str(ROOT / "scenarios" / "table3" / "scenario_31.json"), "--json"]) == 0
    description = json.loads(capsys.readouterr().out)
    assert [n["parameter"] for n in description["not_simulated"]] == ["lighting", "precipitation", "lightning", "cloud cover"]
    assert description["constraint_policy"] == "infeasible"


def _changed_profile_document(profile, change):
    import copy

    document = copy.deepcopy(dict(profile.document))
    change(document)
    return document


def test_units_come_from_what_the_profile_declares_not_from_the_parameter_name(profile):
    """Issue 18, defect 8: a profile giving wind in m/s was divided by 3.6 all the same."""
    from harness.scenario.documents import load_json
    from harness.scenario.logical import logical_from_document
    from harness.scenario.profile import profile_from_document

    def wind_in(unit, low, high):
        def change(document):
            document["parameters"]["wind force"]["unit"] = unit
            document["parameters"]["wind force"]["categories"]["moderate"] = {"min": low, "max": high}
        return change

    fig4 = load_json(ROOT / "scenarios" / "examples" / "fig4.json")
    bounds = {}
    for unit, low, high in (("km/h", 3.6, 7.2), ("m/s", 1.0, 2.0), ("kn", 1.0, 2.0)):
        changed = profile_from_document(_changed_profile_document(profile, wind_in(unit, low, high)))
        space = SearchSpace(logical_from_document(fig4, changed, "fig4.json"), changed)
        dimension = next(d for d in space.dimensions if d.name == "wind_speed_m_s")
        bounds[unit] = (dimension.lower, dimension.upper, dimension.unit)
    assert {unit for *_bounds, unit in bounds.values()} == {"m/s"}
    assert bounds["km/h"][:2] == pytest.approx((1.0, 2.0)) and bounds["m/s"][:2] == (1.0, 2.0)
    assert bounds["kn"][:2] == pytest.approx((0.514444, 1.028889), rel=1e-5)


def test_a_unit_that_does_not_measure_the_quantity_is_a_located_profile_error(profile):
    from harness.scenario.profile import profile_problems

    document = _changed_profile_document(profile, lambda d: d["parameters"]["wind force"].update(unit="m"))
    [problem] = profile_problems(document, "p.json")
    assert problem.pointer == "/parameters/wind force/unit" and "m/s" in problem.message and "km/h" in problem.message
    document = _changed_profile_document(profile, lambda d: d["parameters"]["wind force"].update(unit="furlongs/fortnight"))
    assert profile_problems(document, "p.json")[0].pointer == "/parameters/wind force/unit"
