"""Paths of moving obstacles and intruders: drawn in the log's /scene for Foxglove and in `stella inspect --plot`.

Fast: no flight; the plot reads a small log written here with the bridge's own Recorder.
"""

from __future__ import annotations

import copy
import json
import math

import jsonschema
import numpy as np
import pytest

from harness.flight import logs
from harness.flight.inspect_log import moving_paths, plot
from sim_bridge.obstacles import Obstacle
from sim_bridge.recording import FOXGLOVE_SCHEMAS, LINE_STRIP, Recorder, enu, path_entity, scene_entity
from sim_bridge.spec import WorldSpec


def point(north_m: float, east_m: float, up_m: float) -> dict[str, float]:
    return {"north_m": north_m, "east_m": east_m, "up_m": up_m}


# An intruder crossing the route on a bent track, 40 m east then 28 m north-east, at 5 m/s, once.
INTRUDER = {
    "id": "intruder_1", "kind": "intruder", "form": "cuboid", "size": {"length_m": 1.0, "width_m": 1.0, "height_m": 0.4}, "yaw_rad": math.pi / 2,
    "a": point(30.0, -40.0, 8.0), "b": point(50.0, 20.0, 8.0), "speed_m_s": 5.0,
    "path": [point(30.0, -40.0, 8.0), point(30.0, 0.0, 8.0), point(50.0, 20.0, 8.0)], "repeat": "once",
}
# A Table III style mover: a sphere back and forth on a straight line.
SPHERE = {
    "id": "obstacle_2", "kind": "dynamic", "form": "sphere", "size": {"diameter_m": 7.5}, "yaw_rad": 0.0,
    "a": point(40.0, 15.0, 9.75), "b": point(7.5, 15.0, 9.75), "speed_m_s": 2.75,
}
BOX = {
    "id": "obstacle_3", "kind": "static", "form": "cuboid", "size": {"length_m": 4.0, "width_m": 2.0, "height_m": 10.0}, "yaw_rad": 0.3,
    "a": point(20.0, -10.0, 5.0), "b": None, "speed_m_s": 0.0,
}


def strict(schema):
    """The schema with every declared field required and no other allowed: catches a field name
    Foxglove would not know, which the embedded schema alone (no `required`) lets pass."""
    schema = copy.deepcopy(schema)

    def tighten(node):
        if isinstance(node, dict):
            if "properties" in node:
                node["required"] = sorted(node["properties"])
                node["additionalProperties"] = False
            for value in node.values():
                tighten(value)
        elif isinstance(node, list):
            for value in node:
                tighten(value)

    tighten(schema)
    return schema


SCENE_UPDATE = FOXGLOVE_SCHEMAS["foxglove.SceneUpdate"]


def test_the_scene_schema_declares_foxglove_line_primitives():
    entity = SCENE_UPDATE["properties"]["entities"]["items"]["properties"]
    line = entity["lines"]["items"]["properties"]
    assert set(line) == {"type", "pose", "thickness", "scale_invariant", "points", "color", "colors", "indices"}
    jsonschema.validate(LINE_STRIP, line["type"])
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(3, line["type"])  # no such foxglove.LineType


def test_an_intruders_path_is_a_line_strip_through_its_track_in_enu():
    # GIVEN an intruder on a three-point path
    intruder = Obstacle.from_spec(INTRUDER)
    # WHEN the bridge draws it
    entity = path_entity(intruder, 2_500_000_000)
    # THEN one thin line strip in the world frame through the ENU of every point of its track
    assert entity["id"] == "intruder_1/path" and entity["frame_id"] == "world"
    assert entity["timestamp"] == {"sec": 2, "nsec": 500_000_000}
    (line,) = entity["lines"]
    assert line["type"] == LINE_STRIP and 0 < line["thickness"] <= 0.1 and not line["scale_invariant"]
    assert line["points"] == [enu(*p) for p in intruder.track.tolist()]
    assert line["points"][1] == {"x": 0.0, "y": 30.0, "z": 8.0}  # east, north, up
    assert entity["cubes"] == entity["spheres"] == entity["cylinders"] == entity["triangles"] == []
    jsonschema.validate({"deletions": [], "entities": [entity]}, strict(SCENE_UPDATE))


def test_intruders_are_told_apart_from_other_moving_obstacles_in_the_3d_panel():
    intruder, sphere, box = (Obstacle.from_spec(spec) for spec in (INTRUDER, SPHERE, BOX))
    rgb = {o.id: tuple(scene_entity(o, 0)[key][0]["color"][c] for c in "rgb") for o, key in ((intruder, "cubes"), (sphere, "spheres"), (box, "cubes"))}
    assert len(set(rgb.values())) == 3
    # a path has its obstacle's colour
    for obstacle in (intruder, sphere):
        assert tuple(path_entity(obstacle, 0)["lines"][0]["color"][c] for c in "rgb") == rgb[obstacle.id]
    message = {"deletions": [], "entities": [scene_entity(o, 0) for o in (intruder, sphere, box)]}
    jsonschema.validate(message, strict(SCENE_UPDATE))


def test_a_straight_mover_draws_a_to_b_and_a_still_obstacle_no_path():
    sphere = Obstacle.from_spec(SPHERE)
    assert path_entity(sphere, 0)["lines"][0]["points"] == [enu(40.0, 15.0, 9.75), enu(7.5, 15.0, 9.75)]
    assert path_entity(Obstacle.from_spec(BOX), 0) is None
    assert path_entity(Obstacle.from_spec({**SPHERE, "speed_m_s": 0.0}), 0) is None  # dynamic, but parked


RUN_START_S = 2.0


def world_document() -> dict:
    return {
        "scenario": "paths drawn", "seed": 0,
        "origin": {"lat_deg": 47.397742, "lon_deg": 8.545594, "alt_m": 488.0},
        "terrain": {"kind": "flat"}, "surface": {"kind": "land", "water": []},
        "atmosphere": {"wind_north_m_s": 0.0, "wind_east_m_s": 0.0, "temperature_c": 20.0},
        "visibility_m": 10000.0,
        "sensor": {"max_range_m": 20.0, "min_range_m": 0.2, "fov_deg": 100.0, "update_hz": 20.0, "full_range_visibility_m": 1000.0,
                   "floor_range_m": 2.0, "range_m": 20.0},
        "obstacles": [INTRUDER, SPHERE, BOX],
        "uav": {"start": point(0.0, 0.0, 0.0), "body": {"length_m": 0.6, "width_m": 0.6, "height_m": 0.2}},
        "mission": {"takeoff_altitude_m": 8.0, "waypoints": [{"north_m": 60.0, "east_m": 0.0, "altitude_m": 8.0}], "cruise_speed_m_s": 5.0, "land": True},
        "safety_distance_m": 1.0, "time_limit_s": 120.0,
    }


@pytest.fixture
def log(tmp_path):
    """A log as the bridge writes it, cut to what the plot reads: the world spec, the run event,
    the UAV flying north along east = 0, and clearances where the intruder is nearest at t = 10 s
    (3 m) and the sphere at t = 12 s (4 m)."""
    world = WorldSpec.from_dict(world_document())
    obstacles = [Obstacle.from_spec(spec) for spec in world.obstacles]
    path = tmp_path / "paths.mcap"
    with open(path, "wb") as stream, Recorder(stream) as recorder:
        recorder.metadata("world", {"json": json.dumps(world.as_dict())})
        scene = [scene_entity(o, 0) for o in obstacles] + [e for e in (path_entity(o, 0) for o in obstacles) if e is not None]
        recorder.write("/scene", time_ns=0, message={"deletions": [], "entities": scene})
        recorder.write("/events", time_ns=int(RUN_START_S * 1e9), message={"t": RUN_START_S, "event": "run", "detail": {}})
        times = [0.5 * i for i in range(41)]
        for t in times:
            recorder.write("/uav/state", time_ns=int(t * 1e9), message={"t": t, "north_m": 3.0 * t, "east_m": 0.0, "up_m": 8.0})
        nearest = {8.0: ("intruder_1", 5.0), 10.0: ("intruder_1", 3.0), 12.0: ("obstacle_2", 4.0)}
        batch = {"t": times, "d": [nearest.get(t, (None, 9.0))[1] for t in times], "o": [nearest.get(t, ("obstacle_3", 0))[0] for t in times],
                 "g": [8.0] * len(times)}
        recorder.write("/clearance", time_ns=0, message=batch)
    return path


def test_the_scene_with_paths_is_what_the_log_channel_declares(log):
    ((_topic, _ns, update),) = list(logs.messages(log, ["/scene"]))
    assert {entity["id"] for entity in update["entities"]} >= {"intruder_1/path", "obstacle_2/path"}
    assert "obstacle_3/path" not in {entity["id"] for entity in update["entities"]}
    jsonschema.validate(update, strict(SCENE_UPDATE))


def test_the_plot_draws_every_moving_obstacles_path_and_where_it_was_at_closest_approach(log, tmp_path):
    out = tmp_path / "plot.png"
    figure = plot(log, out)
    assert out.stat().st_size > 0
    top = figure.axes[0]
    drawn = {line.get_gid(): line for line in top.get_lines() if line.get_gid()}
    # the plan view (x east, y north) has each moving obstacle's track, nothing for the still one
    for spec in (INTRUDER, SPHERE):
        track = Obstacle.from_spec(spec).track
        np.testing.assert_allclose(drawn[f"{spec['id']}/path"].get_xydata(), track[:, [1, 0]])
    assert "obstacle_3/path" not in drawn
    # intruders in their own colour
    assert drawn["intruder_1/path"].get_color() != drawn["obstacle_2/path"].get_color()
    # at the intruder's closest step (t = 10 s, run time 8 s) it had flown 40 m: the end of its first leg
    np.testing.assert_allclose(drawn["intruder_1/closest"].get_xydata(), [[0.0, 30.0]], atol=1e-9)
    # the sphere, 27.5 m from a towards b at run time 10 s
    np.testing.assert_allclose(drawn["obstacle_2/closest"].get_xydata(), [[15.0, 12.5]], atol=1e-9)
    labels = top.get_legend_handles_labels()[1]
    assert {"UAV", "intruder path", "moving obstacle path"} <= set(labels)


def test_no_closest_position_once_an_injection_changed_the_obstacle():
    sphere = Obstacle.from_spec(SPHERE)
    (before,) = moving_paths([sphere], {"obstacle_2": (12.0, 4.0)}, RUN_START_S, {"obstacle_2": 15.0})
    (after,) = moving_paths([sphere], {"obstacle_2": (12.0, 4.0)}, RUN_START_S, {"obstacle_2": 11.0})
    assert before.closest.position == pytest.approx((12.5, 15.0, 9.75)) and before.closest.run_time_s == 10.0
    assert after.closest is None
    np.testing.assert_array_equal(after.track, sphere.track)
    # before the run obstacles stand at their start
    (waiting,) = moving_paths([sphere], {"obstacle_2": (1.0, 4.0)}, RUN_START_S)
    assert waiting.closest.position == pytest.approx((40.0, 15.0, 9.75))
