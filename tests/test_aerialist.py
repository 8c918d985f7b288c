"""The UAV Testing Competition's test cases in and out: Aerialist's conventions (x north, y east,
l along x, r in degrees towards east, centre position, base on the ground), located errors for
bad files, a hand-written case flown with its clearance checked by hand, and export -> import."""

from __future__ import annotations

import json
import math
import shlex
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from conftest import ROOT, stored_result
from harness.campaigns.store import Store
from harness.errors import InputError
from harness.flight import logs
from harness.flight.mavsdk_session import mission_items
from harness.interop.aerialist import PLAN_FRAMES, export_aerialist, import_aerialist
from harness.interop.competition_score import path_to_polygon, points_for, resampled
from harness.scenario.logical import load_logical
from harness.scenario.space import SearchSpace
from harness.scenario.world import space_from_concrete, world_spec
from harness.tools.cli import main
from sim_bridge.spec import Origin

DATA = ROOT / "tests" / "data" / "aerialist"
HOVER = DATA / "hover_two_boxes.yaml"
LAND_AT = DATA / "takeoff_land_at.yaml"  # takeoff and a land item at a position, no waypoint
THIN_WALLS = DATA / "two_thin_walls.yaml"  # two long, thin boxes 2.5 m apart, beside the way
BODY_M = 0.6  # the default profile's F450 box, length and width


def world_of(concrete: dict) -> dict:
    space = space_from_concrete(concrete, "imported")
    return world_spec(space, space.from_concrete(concrete), 0)


def rotated_rectangle(north: float, east: float, length: float, width: float, angle_rad: float) -> list[tuple[float, float]]:
    """Corners as Aerialist builds a box (shapely: box(-l/2, -w/2, l/2, w/2) rotated by r in the
    x-y plane, x north and y east, then moved to its centre)."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return [(north + x * c - y * s, east + x * s + y * c) for x, y in ((length / 2, width / 2), (length / 2, -width / 2), (-length / 2, -width / 2), (-length / 2, width / 2))]


def point_to_segment(p, a, b) -> float:
    ab = (b[0] - a[0], b[1] - a[1])
    t = max(0.0, min(1.0, ((p[0] - a[0]) * ab[0] + (p[1] - a[1]) * ab[1]) / (ab[0] ** 2 + ab[1] ** 2)))
    return math.hypot(p[0] - a[0] - t * ab[0], p[1] - a[1] - t * ab[1])


def polygon_distance(p: list, q: list) -> float:
    """Distance between two disjoint convex polygons: the nearest vertex-edge pair."""
    edges = lambda poly: [(poly[i], poly[(i + 1) % len(poly)]) for i in range(len(poly))]
    return min(min(point_to_segment(v, *e) for v in p for e in edges(q)), min(point_to_segment(v, *e) for v in q for e in edges(p)))


def test_a_box_lands_where_aerialist_puts_it(tmp_path):
    concrete, params = import_aerialist(HOVER)
    assert params == {"NAV_ACC_RAD": 0.5, "MIS_TAKEOFF_ALT": 1.0}
    world = world_of(concrete)
    first, second = world.obstacles
    assert first["a"] == pytest.approx({"north_m": 20.0, "east_m": 8.0, "up_m": 7.5})  # centre, base on the ground
    assert first["size"] == {"length_m": 10.0, "width_m": 4.0, "height_m": 15.0} and math.degrees(first["yaw_rad"]) == pytest.approx(30.0)
    assert second["a"] == pytest.approx({"north_m": 45.0, "east_m": -10.0, "up_m": 6.0})
    # The competition's vehicle starts at PX4's default home, not at the plan's plannedHomePosition.
    assert world.origin == Origin(lat_deg=47.397742, lon_deg=8.545594, alt_m=488.0)
    assert world.safety_distance_m == 1.5 and world.atmosphere.wind_north_m_s == 0.0
    # A corner computed Aerialist's way lies on our box: a probe 1 m beyond it along the
    # diagonal is 1 m from the obstacle the simulator scores clearance to.
    from sim_bridge.obstacles import Obstacle
    import fcl

    corner = rotated_rectangle(20.0, 8.0, 10.0, 4.0, math.radians(30.0))[0]
    out = np.array(corner) - np.array([20.0, 8.0])
    probe_at = np.array(corner) + out / np.linalg.norm(out)
    probe = fcl.CollisionObject(fcl.Sphere(1e-6), fcl.Transform(np.array([probe_at[0], probe_at[1], 5.0])))
    result = fcl.DistanceResult()
    fcl.distance(Obstacle.from_spec(first).collision, probe, fcl.DistanceRequest(), result)
    assert result.min_distance == pytest.approx(1.0, abs=1e-4)


def test_rotation_by_180_degrees_and_the_flat_obstacle_list_mean_the_same_box(tmp_path):
    for name in ("hover_two_boxes.plan", "hover_two_boxes-params.csv"):
        shutil.copy(DATA / name, tmp_path / name)
    test = yaml.safe_load(HOVER.read_text())
    test["simulation"]["obstacles"] = [10, 4, 15, 20, 8, 0, 210, 6, 6, 12, 45, -10, 0, 0]
    (tmp_path / "flat.yaml").write_text(yaml.safe_dump(test))
    flat, _ = import_aerialist(tmp_path / "flat.yaml")
    original, _ = import_aerialist(HOVER)
    for a, b in zip(world_of(flat).obstacles, world_of(original).obstacles):
        assert a["a"] == pytest.approx(b["a"]) and a["size"] == b["size"] and a["yaw_rad"] == pytest.approx(b["yaw_rad"])


def mutated(tmp_path: Path, change) -> Path:
    for name in ("hover_two_boxes.plan", "hover_two_boxes-params.csv"):
        shutil.copy(DATA / name, tmp_path / name)
    test = yaml.safe_load(HOVER.read_text())
    replaced = change(test)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(test if replaced is None else replaced))
    return path


BAD_TESTS = {
    "not_a_mapping": (lambda t: [t], "", "not an Aerialist test"),
    "no_drone": (lambda t: t.pop("drone"), "/drone", "missing"),
    "missing_plan": (lambda t: t["drone"].update(mission_file="nowhere.plan"), "/drone/mission_file", "nowhere.plan: no such file"),
    "negative_length": (lambda t: t["simulation"]["obstacles"][0]["size"].update(l=-1), "/simulation/obstacles/0/size/l", "positive number"),
    "floating_box": (lambda t: t["simulation"]["obstacles"][1]["position"].update(z=3), "/simulation/obstacles/1/position/z", "stand on the ground"),
    "cylinder": (lambda t: t["simulation"]["obstacles"][0].update(shape="cylinder"), "/simulation/obstacles/0/shape", "only boxes"),
    "rotation_text": (lambda t: t["simulation"]["obstacles"][0]["position"].update(r="thirty"), "/simulation/obstacles/0/position/r", "in degrees"),
    "flat_list_of_six": (lambda t: t["simulation"].update(obstacles=[1, 2, 3, 4, 5, 6]), "/simulation/obstacles", "7 numbers per box"),
    "wind": (lambda t: t["simulation"].update(wind={"velocity_mean": 3.0}), "/simulation/wind", "wind is not imported"),
    "overlapping_boxes": (lambda t: t["simulation"]["obstacles"][1]["position"].update(x=21, y=7), "/simulation/obstacles", "overlap"),
    "params_not_numbers": (lambda t: t["drone"].update(params={"CP_DIST": "far"}), "/drone/params/CP_DIST", "not a finite number"),
    "bad_home": (lambda t: t["simulation"].update(home_position=[47.4]), "/simulation/home_position", "expected [latitude"),
}


@pytest.mark.parametrize("name", sorted(BAD_TESTS))
def test_a_bad_test_file_is_refused_with_the_key_located(name, tmp_path, capsys):
    change, at, message = BAD_TESTS[name]
    path = mutated(tmp_path, change)
    with pytest.raises(InputError) as raised:
        import_aerialist(path)
    located = f"{path}: {at}: " if at else f"{path}: "  # the file as a whole has no pointer
    assert str(raised.value).startswith(located) and message in str(raised.value), str(raised.value)
    assert main(["import", "aerialist", str(path), "--out", str(tmp_path / "c.json")]) == 2
    assert not (tmp_path / "c.json").exists()
    assert located in capsys.readouterr().err


def test_invalid_yaml_names_its_line(tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text("drone:\n  mission_file: [unclosed\n")
    with pytest.raises(InputError, match=r"broken.yaml: invalid YAML: line 3, column 1"):
        import_aerialist(path)


def check_hover_clearances(log: Path) -> None:
    """At rest beside each box of hover_two_boxes, the recorded clearance is the 2D distance
    between the vehicle's 0.6 m footprint and the box, computed here the way Aerialist places it."""
    states = [m for _t, _ns, m in logs.messages(log, ["/uav/state"])]
    clearance = {round(t, 6): (d, o) for _t, _ns, batch in logs.messages(log, ["/clearance"]) for t, d, o in zip(batch["t"], batch["d"], batch["o"])}
    boxes = [((20.0, 8.0), 10.0, 4.0, 30.0, "obstacle_1", (20.0, 0.0)), ((45.0, -10.0), 6.0, 6.0, 0.0, "obstacle_2", (45.0, -3.0))]
    for (north, east), length, width, r, name, waypoint in boxes:
        hovering = [s for s in states if math.hypot(s["north_m"] - waypoint[0], s["east_m"] - waypoint[1]) < 0.3 and math.hypot(*s["v_ned_m_s"]) < 0.05]
        assert len(hovering) >= 10, f"no hover beside {name}"
        state = hovering[len(hovering) // 2]
        body = rotated_rectangle(state["north_m"], state["east_m"], BODY_M, BODY_M, state["rpy_rad"][2])
        by_hand = polygon_distance(body, rotated_rectangle(north, east, length, width, math.radians(r)))
        recorded, nearest = clearance[round(state["t"], 6)]
        assert nearest == name and recorded == pytest.approx(by_hand, abs=0.01), (name, state)


def fly_hover_case(tmp_path: Path, capsys, *sut: str) -> Path:
    out = tmp_path / "hover.json"
    assert main(["import", "aerialist", str(HOVER), "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["run", "--concrete", str(out), "--sut-params-file", str(tmp_path / "hover.params.csv"), *sut, "--out", str(tmp_path), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["status"] == "ok", result["why"]
    return Path(result["log_path"])


@pytest.mark.slow
def test_a_hand_written_case_flies_and_its_clearance_to_each_box_matches_hand_computation(tmp_path, capsys):
    log = fly_hover_case(tmp_path, capsys)
    check_hover_clearances(log)
    # The competition's 2D distance of the path (0.125 m half width) exceeds our body's clearance
    # (0.3 m half width, up to 0.42 m across its diagonal) by about the difference.
    assert main(["inspect", str(log), "--competition", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert 0.1 <= summary["competition"]["min_distance_m"] - summary["min_clearance_m"] <= 0.35, summary
    assert (summary["competition"]["verdict"], summary["competition"]["points"]) == ("pass", 0)


def test_a_case_that_takes_off_and_lands_at_a_position_has_that_position_as_its_goal():
    concrete, params = import_aerialist(LAND_AT)
    assert params["MIS_YAW_ERR"] == 12.0  # the competition's PX4 parameter file, carried whole
    mission = world_of(concrete).mission
    (goal,) = mission.waypoints
    # PX4 climbs to the takeoff altitude, flies to the land item's position at it and lands there.
    assert (goal.north_m, goal.east_m, goal.altitude_m) == pytest.approx((50.0, 10.0, 5.0), abs=0.5)
    assert mission.land and (mission.landing.north_m, mission.landing.east_m) == (goal.north_m, goal.east_m)


@pytest.mark.slow
def test_a_takeoff_and_land_at_case_flies_with_the_printed_command_and_the_competition_scores_it(tmp_path, capsys):
    fly_land_at_case(tmp_path, capsys)


def fly_land_at_case(tmp_path, capsys, *sut_options: str) -> None:
    """The printed command of the imported takeoff + land-at case, with sut_options after it."""
    out = tmp_path / "land_at.json"
    assert main(["import", "aerialist", str(LAND_AT), "--out", str(out), "--json"]) == 0
    command = shlex.split(json.loads(capsys.readouterr().out)["fly"])
    assert command[0] == "stella" and "--sut-params-file" in command
    assert main([*command[1:], *sut_options, "--out", str(tmp_path), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["status"] == "ok", result["why"]  # it reached the land position and landed within 3 m of it
    assert main(["inspect", result["log_path"], "--competition", "--json"]) == 0
    competition = json.loads(capsys.readouterr().out)["competition"]
    # The box stands about 6 m beside the way: the competition passes the flight and gives no points.
    assert (competition["verdict"], competition["points"]) == ("pass", 0) and 4.0 < competition["min_distance_m"] < 9.0, competition


def test_long_thin_boxes_apart_are_not_refused_as_overlapping():
    # GIVEN two 16 x 1 m boxes side by side with 2.5 m between their footprints, whose
    # circumscribed discs (radius 8 m, centres 3.5 m apart) overlap
    concrete, _params = import_aerialist(THIN_WALLS)
    # THEN both stand where the test puts them, their footprints the test's gap apart
    boxes = [o for o in world_of(concrete).obstacles]
    assert [(o["a"]["north_m"], o["a"]["east_m"]) for o in boxes] == [(20.0, -8.0), (20.0, -11.5)]
    walls = [rotated_rectangle(20.0, east, 16.0, 1.0, 0.0) for east in (-8.0, -11.5)]
    assert polygon_distance(*walls) == pytest.approx(2.5)


def test_boxes_whose_footprints_touch_are_refused_however_thin(tmp_path, capsys):
    test = yaml.safe_load(THIN_WALLS.read_text())
    test["simulation"]["obstacles"][1]["position"]["y"] = -8.9  # 0.1 m from the first: no gap left
    bad = tmp_path / "touching.yaml"
    bad.write_text(yaml.safe_dump(test))
    for name in ("takeoff_land_at-params.csv", "takeoff_land_at.plan"):
        shutil.copy(DATA / name, tmp_path / name)
    assert main(["import", "aerialist", str(bad), "--out", str(tmp_path / "out.json")]) == 2
    assert "/simulation/obstacles: obstacle_1 and obstacle_2 overlap" in capsys.readouterr().err


@pytest.mark.slow
def test_long_thin_boxes_import_and_fly_with_the_printed_command(tmp_path, capsys):
    out = tmp_path / "walls.json"
    assert main(["import", "aerialist", str(THIN_WALLS), "--out", str(out), "--json"]) == 0
    command = shlex.split(json.loads(capsys.readouterr().out)["fly"])
    assert main([*command[1:], "--out", str(tmp_path), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["status"] == "ok", result["why"]
    assert main(["inspect", result["log_path"], "--competition", "--json"]) == 0
    competition = json.loads(capsys.readouterr().out)["competition"]
    assert competition["verdict"] == "pass" and 8.0 < competition["min_distance_m"] < 11.0, competition


SQUARE = [(1.0, 1.0), (1.0, -1.0), (-1.0, -1.0), (-1.0, 1.0)]  # 2 m box at the origin


@pytest.mark.parametrize("path, expected", [
    ([(5.0, 0.0), (5.0, 10.0)], 4.0),  # beside a face
    ([(4.0, 5.0), (8.0, 5.0)], 5.0),  # beyond a corner, nearest at the path's end: hypot(3, 4)
    ([(-5.0, 0.0), (5.0, 0.0)], 0.0),  # through it
    ([(0.5, 0.5)], 0.0),  # inside
    ([(3.0, 3.0)], math.hypot(2.0, 2.0)),  # one point off a corner
])
def test_the_competitions_path_to_box_distance(path, expected):
    assert path_to_polygon(path, SQUARE) == pytest.approx(expected)


def test_the_competitions_resampling_and_points():
    states = [{"t": t / 10, "north_m": float(t), "east_m": 0.0} for t in range(10)]
    assert resampled(states) == [(2.0, 0.0), (7.0, 0.0)]  # means of 0-0.4 s and 0.5-0.9 s
    assert [points_for(d) for d in (0.0, 0.24, 0.25, 0.99, 1.49, 1.5, 7.0)] == [5, 5, 2, 2, 1, 0, 0]


def wall_store(path: Path, profile) -> None:
    """A store holding one expressible case (the wall: a static box, calm, clear, flat) and one
    that is not (Fig. 4's dynamic sphere in wind and fog)."""
    store = Store(path)
    campaign = store.campaign({"scenarios": ["wall.json"], "algorithms": ["RANDOM"], "sut": "px4", "sut_params": {"CP_DIST": 1.5}})
    for index, name in enumerate(("wall", "fig4")):
        space = SearchSpace(load_logical(ROOT / "scenarios" / "examples" / f"{name}.json", profile), profile)
        run_id, _ = store.run(campaign, f"/somewhere/{name}.json", space.logical.name, "RANDOM", index, 1)
        x = space.sample_feasible(np.random.default_rng(3), 1)[0]
        store.add_evaluation(run_id, ordinal=0, step=0, optimizer="RANDOM", vector=x, result=stored_result(-0.5, "violation", 1),
                             concrete=space.to_concrete(x))
    store.close()


def test_export_then_import_gives_back_the_same_flight(tmp_path, profile, capsys):
    wall_store(tmp_path / "c.db", profile)
    assert main(["export-regressions", str(tmp_path / "c.db"), "--format", "aerialist", "--out", str(tmp_path / "out"), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    [exported] = report["files"]
    [skipped] = report["not_expressible"]
    assert skipped["name"].startswith("fig4") and any("dynamic sphere" in r for r in skipped["reasons"])
    test = yaml.safe_load(Path(exported).read_text())
    assert test["drone"]["params"] == {"CP_DIST": 1.5} and (tmp_path / "out" / test["drone"]["mission_file"]).is_file()

    with Store.existing(tmp_path / "c.db") as store:
        original = next(c for c in store.worst_cases(0.0, 0) if "wall" in c.scenario_file).concrete
    imported, params = import_aerialist(Path(exported))
    assert params == {"CP_DIST": 1.5}
    before, after = world_of(original), world_of(imported)
    assert after.origin == before.origin
    for a, b in zip(after.obstacles, before.obstacles):
        assert a["a"] == pytest.approx(b["a"], abs=1e-9) and a["size"] == pytest.approx(b["size"], abs=1e-9)
        assert math.cos(2 * a["yaw_rad"]) == pytest.approx(math.cos(2 * b["yaw_rad"])) and math.sin(2 * a["yaw_rad"]) == pytest.approx(math.sin(2 * b["yaw_rad"]))
    assert _same_items(mission_items(after), mission_items(before))

    # and once in the format, a case goes round unchanged
    out_again = tmp_path / "again"
    out_again.mkdir()
    path, reasons = export_aerialist(Path(exported).stem, imported, params, out_again)
    assert not reasons and import_aerialist(path)[0] == imported


def _same_items(a, b) -> bool:
    """Item by item the same, a frame and its _INT twin (the .plan's and our upload's) counted equal."""
    fields = ("seq", "command", "current", "autocontinue", "param1", "param2", "param3", "param4", "x", "y", "z", "mission_type")
    same = lambda u, v: (isinstance(u, float) and isinstance(v, float) and math.isnan(u) and math.isnan(v)) or u == v
    frame = lambda item: PLAN_FRAMES.get(item.frame, item.frame)
    return len(a) == len(b) and all(same(getattr(i, f), getattr(j, f)) for i, j in zip(a, b) for f in fields) and all(frame(i) == frame(j) for i, j in zip(a, b))
