"""Sensor rigs: the documents and their presets, each sensor rendered into its messages (rate,
latency, layout, failure), and flights with each preset at a wall on the bundled autopilot and,
where STELLA_PX4_BIN is set, on PX4."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from conftest import ROOT
from harness.flight import logs
from harness.flight.evaluation import evaluate
from harness.flight.results import RunOptions
from harness.scenario.profile import load_profile, with_rig_named
from harness.scenario.rig import load_rig, preset_names, rig_sensors
from harness.scenario.space import SearchSpace
from harness.scenario.world import load_concrete
from harness.tools.cli import main
from sim_bridge.failures import FailureSchedule
from sim_bridge.rig import RigFrames
from sim_bridge.spec import FailureSpec
from sut_adapter import SutConfig

EXAMPLES = ROOT / "scenarios" / "examples"
BODY = {"length_m": 0.6, "width_m": 0.6}


def decoded(frames: list[bytes]) -> list:
    parser = mavlink.MAVLink(None)
    return [message for frame in frames for message in parser.parse_buffer(frame) or []]


def wall_north(distance_m: float):
    """A wall across north at distance_m from the vehicle's centre, as World.nearest sees it."""
    def nearest(world_angles_rad: np.ndarray, reach_m: float):
        cosines = np.cos(world_angles_rad)
        with np.errstate(divide="ignore"):
            distances = np.where(cosines > 1e-9, distance_m / cosines, np.inf)
        return distances if np.min(distances) <= reach_m else None
    return nearest


def hull(body_angles_rad: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return np.minimum(0.3 / np.abs(np.cos(body_angles_rad)), 0.3 / np.abs(np.sin(body_angles_rad)))


def rendered(rig_name: str, steps: int, distance_m: float = 3.3, yaw_rad: float = 0.0, delivered=None, visibility_m: float = 10000.0):
    """Each step's frames of a preset at 250 Hz before a wall, and what was recorded."""
    profile = load_profile()
    sensors = rig_sensors(load_rig(rig_name), profile.sensor, visibility_m)
    recorded = []
    counter = iter(range(10**6))
    frames = RigFrames(sensors, 250.0, hull, wall_north(distance_m),
                       lambda codec, *fields: codec.encode(next(counter) & 0xFF, 1, 51, *fields),
                       lambda topic, time_us, message: recorded.append((topic, time_us, message)))
    as_sent = delivered or (lambda name, readings, reach_cm: readings)
    return [frames.step_frames(step, step * 4000, yaw_rad, as_sent)[0] for step in range(steps)], recorded


def test_every_preset_is_a_valid_rig_and_the_list_names_its_messages(capsys):
    assert set(preset_names()) >= {"lidar_360", "four_rangefinders", "depth_camera", "lidar_and_rangefinders"}
    assert main(["validate", str(ROOT / "scenarios" / "rigs")]) == 0
    capsys.readouterr()
    assert main(["rigs", "--json"]) == 0
    listed = {rig["name"]: rig for rig in json.loads(capsys.readouterr().out)["rigs"]}
    assert listed["lidar_and_rangefinders"]["messages"] == ["DISTANCE_SENSOR", "OBSTACLE_DISTANCE"]
    assert [s["yaw_deg"] for s in listed["four_rangefinders"]["sensors"]] == [0, 90, 180, 270]


@pytest.mark.parametrize("sensors, pointer, says", [
    ([{"name": "a", "message": "LIDAR", "fov_deg": 10, "min_range_m": 0.1, "max_range_m": 5, "rate_hz": 10}], "/sensors/0/message", "DISTANCE_SENSOR"),
    ([{"name": "a", "message": "DISTANCE_SENSOR", "fov_deg": 10, "min_range_m": 6, "max_range_m": 5, "rate_hz": 10}], "/sensors/0/min_range_m", "below max_range_m"),
    ([{"name": "a", "message": "DISTANCE_SENSOR", "fov_deg": 10, "min_range_m": 0.1, "max_range_m": 5, "rate_hz": 10},
      {"name": "a", "message": "DISTANCE_SENSOR", "fov_deg": 10, "min_range_m": 0.1, "max_range_m": 5, "rate_hz": 10, "yaw_deg": 90}],
     "/sensors/1/name", "names two sensors"),
    ([{"name": "a", "message": "OBSTACLE_DISTANCE", "fov_deg": 360, "increment_deg": 2, "min_range_m": 0.1, "max_range_m": 5, "rate_hz": 10}],
     "/sensors/0/increment_deg", "at least 5"),
    ([{"name": "a", "message": "OBSTACLE_DISTANCE", "fov_deg": 90, "frame": "local", "min_range_m": 0.1, "max_range_m": 5, "rate_hz": 10}],
     "/sensors/0/frame", "fov_deg 360"),
    ([{"name": "a", "message": "DISTANCE_SENSOR", "fov_deg": 10, "increment_deg": 5, "min_range_m": 0.1, "max_range_m": 5, "rate_hz": 10}],
     "/sensors/0/increment_deg", "belongs to an OBSTACLE_DISTANCE source"),
])
def test_a_bad_rig_exits_2_naming_the_field(tmp_path, capsys, sensors, pointer, says):
    path = tmp_path / "rig.json"
    path.write_text(json.dumps({"name": "bad", "sensors": sensors}))
    assert main(["validate", str(path)]) == 2
    out = capsys.readouterr().out
    assert f"{path}: {pointer}:" in out and says in out
    assert main(["run", "--concrete", str(EXAMPLES / "wall_concrete.json"), "--rig", str(path), "--out", str(tmp_path)]) == 2
    assert f"{path}: {pointer}:" in capsys.readouterr().err


def test_a_rig_sensor_reaches_less_far_in_fog_never_below_the_floor():
    profile = load_profile()
    [clear] = rig_sensors(load_rig("depth_camera"), profile.sensor, 10000.0)
    [fog] = rig_sensors(load_rig("depth_camera"), profile.sensor, profile.sensor["full_range_visibility_m"] / 2.0)
    [thick] = rig_sensors(load_rig("depth_camera"), profile.sensor, 1.0)
    assert clear.range_m == 10.0 and fog.range_m == pytest.approx(5.0) and thick.range_m == min(profile.sensor["floor_range_m"], 10.0)


def test_each_sensor_comes_at_its_rate_and_latency_in_its_layout():
    steps, recorded = rendered("lidar_and_rangefinders", 50)
    # 250 Hz lockstep: the lidar every 25 steps, each rangefinder every 10
    lidar_steps = [i for i, frames in enumerate(steps) for m in decoded(frames) if m.get_type() == "OBSTACLE_DISTANCE"]
    front_steps = [i for i, frames in enumerate(steps) for m in decoded(frames) if m.get_type() == "DISTANCE_SENSOR" and m.id == 1]
    assert lidar_steps == [0, 25] and front_steps == [0, 10, 20, 30, 40]
    messages = decoded(steps[0])
    lidar = next(m for m in messages if m.get_type() == "OBSTACLE_DISTANCE")
    front = next(m for m in messages if m.get_type() == "DISTANCE_SENSOR" and m.id == 1)
    back = next(m for m in messages if m.get_type() == "DISTANCE_SENSOR" and m.id == 2)
    # The wall 3.3 m north of the centre, 3.0 m from the hull, ahead; nothing behind
    assert lidar.distances[0] == 300 and lidar.distances[36] == 3001 and lidar.frame == mavlink.MAV_FRAME_BODY_FRD
    assert lidar.increment_f == 5.0 and lidar.angle_offset == 0.0 and lidar.max_distance == 3000
    assert front.current_distance == 300 and back.current_distance == back.max_distance == 800
    assert front.horizontal_fov == pytest.approx(math.radians(10.0)) and back.quaternion[3] == pytest.approx(1.0)
    assert {topic for topic, _t, _m in recorded} == {"/sensor/rig/lidar", "/sensor/rig/front", "/sensor/rig/back"}
    # The depth camera's 30 sectors of 2.9 degrees span its 87 degrees, and each image arrives 0.1 s (25 steps) late
    steps, _recorded = rendered("depth_camera", 40)
    arrivals = [i for i, frames in enumerate(steps) if frames]
    assert arrivals[0] == 25
    [depth] = decoded(steps[25])
    assert depth.angle_offset == pytest.approx(-43.5 + 1.45) and depth.increment_f == pytest.approx(2.9)
    assert depth.distances[29] != 65535 and depth.distances[30] == 65535 and depth.distances[15] == 300


def test_obstacle_distance_goes_to_a_companion_link_where_the_sut_reads_it_there():
    profile = load_profile()
    sensors = rig_sensors(load_rig("lidar_and_rangefinders"), profile.sensor, 10000.0)
    simulator_seq, companion_seq = iter(range(100)), iter(range(100))
    frames = RigFrames(sensors, 250.0, hull, wall_north(3.3), lambda codec, *fields: codec.encode(next(simulator_seq), 1, 51, *fields),
                       lambda topic, time_us, message: None, ("OBSTACLE_DISTANCE",),
                       lambda codec, *fields: codec.encode(next(companion_seq), 1, mavlink.MAV_COMP_ID_OBSTACLE_AVOIDANCE, *fields))
    simulator, companion = frames.step_frames(0, 0, 0.0, lambda name, readings, reach_cm: readings)
    assert [m.get_type() for m in decoded(simulator)] == ["DISTANCE_SENSOR", "DISTANCE_SENSOR"]
    [lidar] = decoded(companion)
    assert lidar.get_type() == "OBSTACLE_DISTANCE" and lidar.get_srcComponent() == mavlink.MAV_COMP_ID_OBSTACLE_AVOIDANCE and lidar.get_seq() == 0


def test_for_ardupilot_every_reading_goes_to_the_companion_link_a_rangefinder_facing_one_of_eight_named_yaws():
    """ArduPilot's MAVLink proximity backend reads DISTANCE_SENSOR's orientation 0-7 (yaw in
    steps of 45 degrees) and drops a custom rotation's quaternion."""
    profile = load_profile()
    sensors = rig_sensors(load_rig("four_rangefinders"), profile.sensor, 10000.0)
    companion_seq = iter(range(100))
    frames = RigFrames(sensors, 250.0, hull, wall_north(3.3), lambda codec, *fields: pytest.fail("nothing goes on the simulator link"),
                       lambda topic, time_us, message: None, ("DISTANCE_SENSOR", "OBSTACLE_DISTANCE"),
                       lambda codec, *fields: codec.encode(next(companion_seq), 1, mavlink.MAV_COMP_ID_OBSTACLE_AVOIDANCE, *fields),
                       distance_sensor_convention="ardupilot")
    simulator, companion = frames.step_frames(0, 0, 0.0, lambda name, readings, reach_cm: readings)
    assert simulator == []
    # Nothing within reach reads beyond it: ArduPilot takes a reading at the maximum as an obstacle there
    assert [(m.orientation, m.current_distance, m.max_distance) for m in decoded(companion)] == [
        (mavlink.MAV_SENSOR_ROTATION_NONE, 300, 1200), (mavlink.MAV_SENSOR_ROTATION_YAW_90, 1201, 1200),
        (mavlink.MAV_SENSOR_ROTATION_YAW_180, 1201, 1200), (mavlink.MAV_SENSOR_ROTATION_YAW_270, 1201, 1200)]


def test_a_companion_link_the_sut_opens_answers_where_it_was_last_heard_from():
    """ArduPilot SITL's `--serial1 udpclient:HOST:PORT` sends from a port of its own: nothing
    reaches it before it is heard, and a restarted SUT is answered at its new port."""
    import socket

    from sim_bridge.companion import CompanionLink

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    link = CompanionLink(port, sut_connects=True)
    suts = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(2)]
    try:
        assert link.send([b"lost"]) == b""
        for sut in suts:
            sut.settimeout(2.0)
            sut.sendto(b"heartbeat", ("127.0.0.1", port))  # on loopback, queued for the link before sendto returns
            assert link.send([b"reading"]) == b"reading"
            assert sut.recv(100) == b"reading"
        suts[0].setblocking(False)
        with pytest.raises(BlockingIOError):  # the second reading went only to the SUT heard last
            suts[0].recv(100)
    finally:
        link.close()
        for sut in suts:
            sut.close()


def test_a_sensors_noise_is_drawn_from_the_worlds_seed_and_leaves_nothing_within_reach_as_it_was():
    rig = load_rig("four_rangefinders")
    rig["sensors"][0]["noise_m"] = 0.05
    sensors = rig_sensors(rig, load_profile().sensor, 10000.0)

    def readings(seed: int) -> list[tuple[int, ...]]:
        counter = iter(range(10**6))
        frames = RigFrames(sensors, 250.0, hull, wall_north(3.3), lambda codec, *fields: codec.encode(next(counter) & 0xFF, 1, 51, *fields),
                           lambda topic, time_us, message: None, seed=seed)
        return [tuple(m.current_distance for m in decoded(frames.step_frames(step, step * 4000, 0.0, lambda name, r, reach_cm: r)[0]))
                for step in range(0, 1000, 5)]

    first = readings(7)
    assert first == readings(7) and first != readings(8)
    front = np.array([reading[0] for reading in first])
    # The wall 3.0 m from the hull ahead, read 5 cm off at random; nothing within reach on the other sides, no noise there
    assert abs(front.mean() - 300) < 1.5 and 4.0 < front.std() < 6.0
    assert {reading[1:] for reading in first} == {(1200, 1200, 1200)}


def test_the_distance_sensor_failure_fails_every_sensor_of_the_rig():
    events = []
    schedule = FailureSchedule((FailureSpec(unit="distance sensor", type="wrong", onset_s=0.0, duration_s=10.0, delivery="simulator"),),
                               lambda event, detail: events.append((event, detail)))
    steps, _recorded = rendered("lidar_and_rangefinders", 1, delivered=lambda name, readings, reach_cm: schedule.reading(
        "distance sensor", 1.0, readings, lambda r: [reach_cm + 1 for _ in r], instance=name))
    messages = decoded(steps[0])
    assert all(m.current_distance == m.max_distance for m in messages if m.get_type() == "DISTANCE_SENSOR")
    assert next(m for m in messages if m.get_type() == "OBSTACLE_DISTANCE").distances[0] == 3001
    assert sorted(detail["sensor"] for event, detail in events if event == "failure") == ["back", "front", "lidar"]


def test_a_campaigns_rig_replaces_each_scenarios_and_is_part_of_its_identity():
    from harness.campaigns.campaign import CampaignConfig

    plain = CampaignConfig((str(ROOT / "scenarios" / "table3" / "scenario_05.json"),), ("RANDOM",), 4)
    rigged = CampaignConfig(plain.scenarios, plain.algorithms, 4, rig="four_rangefinders")
    assert rigged.read().scenarios[0].rig["name"] == "four_rangefinders" and plain.read().scenarios[0].rig is None
    assert SearchSpace(rigged.read().scenarios[0], rigged.read().profile).profile.rig["name"] == "four_rangefinders"
    assert plain.identity() != rigged.identity()


def test_a_rigged_campaigns_store_from_when_the_rig_went_into_the_profile_still_resumes(tmp_path):
    """Until 2026-11-29 --rig changed the profile; a profile carrying the rig gives that identity."""
    from harness.campaigns.campaign import CampaignConfig
    from harness.scenario.rig import with_rig

    profile = tmp_path / "rigged_profile.json"
    profile.write_text(json.dumps(with_rig(load_profile().document, load_rig("four_rangefinders"))))
    scenarios = (str(ROOT / "scenarios" / "table3" / "scenario_05.json"),)
    then = CampaignConfig(scenarios, ("RANDOM",), 4, profile=str(profile)).identity()
    now = CampaignConfig(scenarios, ("RANDOM",), 4, rig="four_rangefinders")
    assert then != now.identity() and then in now.legacy_identities()


@pytest.mark.slow
def test_each_preset_rig_keeps_the_pilot_off_a_wall_with_px4s_collision_prevention(tmp_path):
    """PX4's Position-mode semantics (CP_STICK_ACCEL 1) on the bundled autopilot: whatever the rig,
    the pilot is stopped before the wall or slides past it, outside the safety distance; the
    sensors' readings are in the log as the autopilot got them."""
    space, x = load_concrete(EXAMPLES / "wall_concrete.json", "pilot")
    for name in preset_names():
        rigged = SearchSpace(space.logical, with_rig_named(space.profile, name))
        result = evaluate(rigged, x, seed=0, out_dir=tmp_path, options=RunOptions(cores=1, sut=SutConfig("bundled", {"CP_STICK_ACCEL": 1})),
                          name=name)
        assert result.min_clearance_m > 1.0, (name, result.status, result.min_clearance_m)
        topics = {f"/sensor/rig/{sensor['name']}" for sensor in load_rig(name)["sensors"]}
        assert {topic for topic in topics if any(True for _ in logs.messages(Path(result.log_path), [topic]))} == topics


@pytest.mark.slow
def test_a_depth_cameras_short_reach_and_latency_let_the_default_autopilot_into_the_wall(tmp_path):
    """What a rig shows that the profile's forward sensor (20 m, no latency) does not: the bundled
    autopilot's default collision prevention takes nothing seen within reach as free, and at the
    pilot's full stick a 10 m depth camera seen 0.1 s late leaves it too little room to stop."""
    space, x = load_concrete(EXAMPLES / "wall_concrete.json", "pilot")
    options = RunOptions(cores=1)
    plain = evaluate(space, x, seed=0, out_dir=tmp_path, options=options, name="profile-sensor")
    camera = evaluate(SearchSpace(space.logical, with_rig_named(space.profile, "depth_camera")), x, seed=0, out_dir=tmp_path, options=options,
                      name="depth-camera")
    assert plain.min_clearance_m > 1.0 and camera.status == "violation" and camera.min_clearance_m < 1.0
    # Explained from the camera's readings: seen within its 10 m, got 0.1 s later, too late to stop from the pilot's speed
    from harness.campaigns.explain import explain

    report = explain(Path(camera.log_path))
    timeline = {entry["what"]: entry for entry in report["timeline"]}
    assert report["mechanism"] == "seen_late" and report["context"]["sensor"]["rig"][0]["name"] == "depth"
    assert timeline["in view"]["distance_m"] <= 10.0 and timeline["reported to the SUT"]["t_s"] >= timeline["in view"]["t_s"] + 0.1 - 0.04
    assert report["numbers"]["stopping_distance_needed_m"] > report["numbers"]["distance_at_report_m"] > 8.0


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("STELLA_PX4_BIN"), reason="needs a PX4 SITL build (STELLA_PX4_BIN)")
def test_px4_reads_rangefinders_on_its_simulator_link_and_a_lidar_on_its_companion_link(tmp_path):
    space, x = load_concrete(EXAMPLES / "wall_concrete.json", "pilot")
    options = RunOptions(sut=SutConfig("px4", px4_bin=os.environ["STELLA_PX4_BIN"]), sut_logs="failures")
    rangefinders = evaluate(SearchSpace(space.logical, with_rig_named(space.profile, "four_rangefinders")), x, seed=0, out_dir=tmp_path,
                            options=options, name="px4-rangefinders")
    # Stopped before the wall: PX4 creeps a few centimetres into CP_DIST while the pilot pushes on
    assert "blocked" in (rangefinders.why or "") and rangefinders.min_clearance_m > 0.8
    # Without range data PX4 would not let the pilot move at all (CP_GO_NO_DATA 0): it flew to the
    # wall and round it on the lidar's OBSTACLE_DISTANCE, which went to its onboard link
    lidar = evaluate(SearchSpace(space.logical, with_rig_named(space.profile, "lidar_360")), x, seed=0, out_dir=tmp_path, options=options,
                     name="px4-lidar")
    assert 1.0 < lidar.min_clearance_m < 10.0
    parser = mavlink.MAVLink(None)
    sent = [m for _t, _ns, record in logs.messages(Path(lidar.log_path), ["/mavlink/companion"])
            for m in parser.parse_buffer(bytes.fromhex(record["hex"])) or []]
    assert len(sent) > 100 and {m.get_type() for m in sent} == {"OBSTACLE_DISTANCE"}


def test_a_mutation_runs_suite_and_searches_fly_with_its_rig():
    from harness.campaigns.regression import suite_cases
    from harness.firmware.mutation import MutationPlan

    [(_name, space, _x, _seed)] = suite_cases([str(EXAMPLES / "wall_concrete.json")], "pilot", "lidar_360")
    assert space.profile.rig["name"] == "lidar_360"
    plain = MutationPlan((str(EXAMPLES / "wall_concrete.json"),))
    # A folder screened without a rig keeps its identity; one with a rig is another screening
    assert "rig" not in plain.screening() and MutationPlan(plain.suite, rig="lidar_360").screening()["rig"] == "lidar_360"


def test_a_failure_may_fail_one_sensor_of_the_rig(tmp_path, capsys):
    events = []
    schedule = FailureSchedule((FailureSpec(unit="distance sensor", type="wrong", onset_s=0.0, duration_s=10.0, delivery="simulator", sensor="front"),),
                               lambda event, detail: events.append((event, detail)))
    steps, _recorded = rendered("lidar_and_rangefinders", 1, delivered=lambda name, readings, reach_cm: schedule.reading(
        "distance sensor", 1.0, readings, lambda r: [reach_cm + 1 for _ in r], instance=name))
    messages = decoded(steps[0])
    assert next(m for m in messages if m.get_type() == "DISTANCE_SENSOR" and m.id == 1).current_distance == 800  # front: nothing in reach
    assert next(m for m in messages if m.get_type() == "OBSTACLE_DISTANCE").distances[0] == 300  # the lidar still sees the wall
    assert [detail["sensor"] for event, detail in events if event == "failure"] == ["front"]
    # A logical scenario names the sensor; it must be one of the rig's
    scenario = json.loads((EXAMPLES / "wall.json").read_text())
    scenario["failures"] = [{"unit": "distance sensor", "type": "off", "sensor": "front"}]
    path = tmp_path / "front_off.json"
    path.write_text(json.dumps(scenario))
    assert main(["space", str(path), "--drive", "pilot"]) == 2
    assert "/failures/0/sensor" in capsys.readouterr().err
    assert main(["run", str(path), "--rig", "lidar_360", "--out", str(tmp_path)]) == 2
    assert "the rig's sensors are lidar" in capsys.readouterr().err
    from harness.scenario.logical import load_logical
    from harness.scenario.world import world_spec

    profile = with_rig_named(load_profile(), "four_rangefinders")
    space = SearchSpace(load_logical(path, profile, "pilot"), profile)
    assert {d["name"] for d in space.describe()["dimensions"]} >= {"failure_1.onset_s", "failure_1.duration_s"}
    [failure] = world_spec(space, space.sample_feasible(np.random.default_rng(0), 1)[0], 0).failures
    assert failure.sensor == "front" and failure.delivery == "simulator"


def searched_depth_camera(tmp_path: Path, **behaviour) -> Path:
    scenario = json.loads((EXAMPLES / "wall.json").read_text())
    scenario["sensors"] = [{"sensor": "depth", **behaviour}]
    path = tmp_path / "wall_depth.json"
    path.write_text(json.dumps(scenario))
    return path


def test_a_sensors_reach_rate_latency_and_view_are_search_dimensions_that_reach_the_world(tmp_path):
    from harness.scenario.logical import load_logical
    from harness.scenario.world import world_spec

    path = searched_depth_camera(tmp_path, max_range_m={"min": 4, "max": 10}, latency_s={"min": 0, "max": 0.4}, fov_deg={"min": 30, "max": 87})
    profile = with_rig_named(load_profile(), "depth_camera")
    space = SearchSpace(load_logical(path, profile, "pilot"), profile)
    names = [d["name"] for d in space.describe()["dimensions"]]
    assert {"sensor.depth.max_range_m", "sensor.depth.latency_s", "sensor.depth.fov_deg"} <= set(names) and "sensor.depth.rate_hz" not in names
    x = space.vector_from({"sensor.depth.max_range_m": 10.0, "sensor.depth.latency_s": 0.2, "sensor.depth.fov_deg": 30.0})
    [depth] = world_spec(space, x, 0).rig
    assert (depth.max_range_m, depth.range_m, depth.latency_s, depth.fov_deg, depth.rate_hz) == (10.0, 10.0, 0.2, 30.0, 15.0)
    # The concrete scenario carries the values, and flies the same world again
    from harness.scenario.world import space_from_concrete

    concrete = space.to_concrete(x)
    again = space_from_concrete(concrete, "concrete")
    assert world_spec(again, again.from_concrete(concrete, "concrete"), 0).rig == (depth,)


def test_a_sources_mounting_yaw_and_sector_width_are_search_dimensions_that_reach_its_message(tmp_path):
    from harness.scenario.logical import load_logical
    from harness.scenario.world import world_spec

    path = searched_depth_camera(tmp_path, yaw_deg={"min": -90, "max": 90}, increment_deg={"min": 2, "max": 5}, fov_deg={"min": 20, "max": 87})
    profile = with_rig_named(load_profile(), "depth_camera")
    space = SearchSpace(load_logical(path, profile, "pilot"), profile)
    names = {d["name"] for d in space.describe()["dimensions"]}
    assert {"sensor.depth.yaw_deg", "sensor.depth.increment_deg"} <= names
    x = space.vector_from({"sensor.depth.yaw_deg": 30.0, "sensor.depth.increment_deg": 4.0, "sensor.depth.fov_deg": 40.0})
    [depth] = world_spec(space, x, 0).rig
    assert (depth.yaw_deg, depth.increment_deg, depth.fov_deg) == (30.0, 4.0, 40.0)
    counter = iter(range(10**6))
    frames = RigFrames((depth,), 250.0, hull, wall_north(3.3), lambda codec, *fields: codec.encode(next(counter) & 0xFF, 1, 51, *fields),
                       lambda topic, time_us, message: None)
    [message] = [m for step in range(40) for m in decoded(frames.step_frames(step, step * 4000, 0.0, lambda name, readings, reach_cm: readings)[0])]
    # Ten sectors of 4 degrees from 10 to 50 degrees right of the nose, the first centred at 12
    assert message.increment == 4 and message.increment_f == 4.0 and message.angle_offset == pytest.approx(12.0)
    assert message.distances[9] != 65535 and message.distances[10] == 65535
    # The wall across north: its sector at 12 degrees reads 3.0 m / cos(12 degrees) from the hull's face
    assert message.distances[0] == pytest.approx(100 * (3.3 / math.cos(math.radians(12.0)) - 0.3 / math.cos(math.radians(12.0))), abs=2)


@pytest.mark.parametrize("behaviour, rig, pointer, says", [
    ({"latency_s": {"min": 0, "max": 0.2}}, None, "/sensors/0/sensor", "has no rig"),
    ({"latency_s": {"min": 0, "max": 0.2}}, "lidar_360", "/sensors/0/sensor", "the rig's sensors are lidar"),
    ({"latency_s": {"min": 0.3, "max": 0.2}}, "depth_camera", "/sensors/0/latency_s", "swapped bounds"),
    ({"max_range_m": {"min": 0.2, "max": 5}}, "depth_camera", "/sensors/0/max_range_m/min", "min_range_m, 0.3 m"),
    ({"rate_hz": {"min": 0, "max": 5}}, "depth_camera", "/sensors/0/rate_hz/min", "more than 0"),
    ({"fov_deg": {"min": 30, "max": 300}}, "depth_camera", "/sensors/0/fov_deg", "72 sectors of 2.9 cover at most 208.8 degrees"),
    ({"increment_deg": {"min": 1, "max": 3}}, "depth_camera", "/sensors/0/increment_deg", "72 sectors of 1 cover at most 72 degrees"),
    ({"increment_deg": {"min": 5, "max": 10}, "fov_deg": {"min": 8, "max": 87}}, "depth_camera", "/sensors/0/fov_deg", "fov_deg min >= increment_deg max"),
    ({"increment_deg": {"min": 0.5, "max": 3}}, "depth_camera", "/sensors/0/increment_deg/min", "at least 1 deg"),
    ({"yaw_deg": {"min": -400, "max": 0}}, "depth_camera", "/sensors/0/yaw_deg/min", "-360"),
    ({"latency_s": {"min": 0, "max": 3}}, "depth_camera", "/sensors/0/latency_s/max", "at most 2 s"),
])
def test_bad_searched_sensor_behaviour_exits_2_naming_the_field(tmp_path, capsys, behaviour, rig, pointer, says):
    path = searched_depth_camera(tmp_path, **behaviour)
    assert main(["space", str(path), *(["--rig", rig] if rig else [])]) == 2
    err = capsys.readouterr().err
    assert f"{path}: {pointer}:" in err and says in err


ARDUPILOT_UNREADABLE = {"name": "askew", "sensors": [
    {"name": "front_left", "message": "DISTANCE_SENSOR", "yaw_deg": -30, "fov_deg": 5, "min_range_m": 0.1, "max_range_m": 12, "rate_hz": 50},
    {"name": "lidar", "message": "OBSTACLE_DISTANCE", "fov_deg": 360, "frame": "local", "min_range_m": 0.2, "max_range_m": 30, "rate_hz": 10},
    {"name": "back", "message": "DISTANCE_SENSOR", "yaw_deg": 180, "fov_deg": 5, "min_range_m": 0.1, "max_range_m": 12, "rate_hz": 50}]}


def test_a_rig_a_sut_cannot_read_is_refused_naming_each_sensor_and_why():
    from harness.scenario.rig import rig_problem_for
    from sut_adapter.ardupilot import ArduPilotSitl
    from sut_adapter.base import Capabilities
    from sut_adapter.px4 import Px4Sitl

    for rig in preset_names():
        assert rig_problem_for(load_rig(rig), "px4", Px4Sitl.capabilities) is None
        assert rig_problem_for(load_rig(rig), "ardupilot", ArduPilotSitl.capabilities) is None
    problem = rig_problem_for(ARDUPILOT_UNREADABLE, "ardupilot", ArduPilotSitl.capabilities)
    assert "front_left (DISTANCE_SENSOR): ArduPilot reads a rangefinder's direction only as one of eight yaws" in problem
    assert "lidar (OBSTACLE_DISTANCE): ArduPilot reads OBSTACLE_DISTANCE's sectors from the nose" in problem and "back" not in problem
    assert rig_problem_for(ARDUPILOT_UNREADABLE, "px4", Px4Sitl.capabilities) is None
    problem = rig_problem_for(load_rig("lidar_and_rangefinders"), "simple", Capabilities(hold_mode="frozen", range_messages=()))
    assert "lidar (OBSTACLE_DISTANCE), front (DISTANCE_SENSOR), back (DISTANCE_SENSOR)" in problem and "simple" in problem


def test_validate_checks_a_scenario_that_searches_sensors_as_a_scenario_against_the_rig_given(tmp_path, capsys):
    path = searched_depth_camera(tmp_path, latency_s={"min": 0, "max": 0.2})
    assert main(["validate", str(path)]) == 2
    assert f"{path}: /sensors/0/sensor: 'depth' is no sensor of the vehicle: the vehicle has no rig" in capsys.readouterr().out
    assert main(["validate", str(path), "--rig", "depth_camera"]) == 0
    assert "(logical scenario)" in capsys.readouterr().out


def test_a_rig_given_for_a_concrete_scenario_is_checked_against_its_logical_scenario(tmp_path, capsys):
    from harness.scenario.logical import load_logical

    path = searched_depth_camera(tmp_path, latency_s={"min": 0, "max": 0.2})
    profile = with_rig_named(load_profile(), "depth_camera")
    space = SearchSpace(load_logical(path, profile, "pilot"), profile)
    concrete = tmp_path / "concrete.json"
    concrete.write_text(json.dumps(space.to_concrete(space.sample_feasible(np.random.default_rng(0), 1)[0])))
    assert main(["run", "--concrete", str(concrete), "--rig", "four_rangefinders", "--out", str(tmp_path)]) == 2
    assert "/sensors/0/sensor: 'depth' is no sensor of the vehicle: the rig's sensors are front, right, back, left" in capsys.readouterr().err


def scenario_with_rig(tmp_path: Path, rig, **extra) -> Path:
    scenario = {**json.loads((EXAMPLES / "wall.json").read_text()), "rig": rig, **extra}
    path = tmp_path / "wall_rigged.json"
    path.write_text(json.dumps(scenario))
    return path


def test_a_scenario_names_its_own_rig_which_its_flights_and_concrete_scenarios_carry(tmp_path, capsys):
    from harness.scenario.logical import load_logical
    from harness.scenario.world import space_from_concrete, world_spec

    path = scenario_with_rig(tmp_path, "depth_camera", sensors=[{"sensor": "depth", "latency_s": {"min": 0, "max": 0.2}}])
    assert main(["validate", str(path)]) == 0
    space = SearchSpace(load_logical(path, load_profile(), "pilot"), load_profile())
    x = space.sample_feasible(np.random.default_rng(0), 1)[0]
    assert [sensor.name for sensor in world_spec(space, x, 0).rig] == ["depth"]
    concrete = space.to_concrete(x)
    assert concrete["logical_scenario"]["rig"] == load_rig("depth_camera") == concrete["profile_document"]["rig"]
    again = space_from_concrete(json.loads(json.dumps(concrete)), "concrete")
    assert world_spec(again, again.from_concrete(concrete, "concrete"), 0).rig == world_spec(space, x, 0).rig
    # --rig replaces the scenario's: its searched sensor is then no sensor of the vehicle
    assert main(["space", str(path), "--rig", "lidar_360"]) == 2
    assert f"{path}: /sensors/0/sensor: 'depth' is no sensor of the vehicle: the rig's sensors are lidar" in capsys.readouterr().err


def test_a_scenarios_rig_file_lies_beside_it_and_a_rig_without_its_preset_exits_2_at_its_pointer(tmp_path, capsys):
    from harness.scenario.logical import load_logical

    (tmp_path / "rigs").mkdir()
    (tmp_path / "rigs" / "mine.json").write_text(json.dumps({**load_rig("four_rangefinders"), "name": "mine"}))
    path = scenario_with_rig(tmp_path, "rigs/mine.json")
    assert load_logical(path, load_profile()).rig["name"] == "mine"
    path = scenario_with_rig(tmp_path, "sf45")
    assert main(["validate", str(path)]) == 2
    assert f"{path}: /rig: sf45: no such rig file or preset: give a file or one of depth_camera" in capsys.readouterr().out
    broken = {**load_rig("depth_camera")}
    broken["sensors"] = [{**broken["sensors"][0], "min_range_m": 20.0}]
    path = scenario_with_rig(tmp_path, broken)
    assert main(["run", str(path), "--out", str(tmp_path)]) == 2
    assert f"{path}: /rig/sensors/0/min_range_m: must be below max_range_m" in capsys.readouterr().err


def test_a_campaign_refuses_a_scenarios_rig_its_sut_cannot_read(tmp_path, capsys):
    path = scenario_with_rig(tmp_path, ARDUPILOT_UNREADABLE)
    arducopter = tmp_path / "bin" / "arducopter"  # never started: the rig is refused first
    arducopter.parent.mkdir()
    arducopter.write_text("#!/bin/sh\n")
    arducopter.chmod(0o755)
    assert main(["campaign", str(path), "--algorithm", "RANDOM", "--sut", "ardupilot", "--ardupilot-bin", str(tmp_path), "--evaluations", "2",
                 "--store", str(tmp_path / "c.db")]) == 2
    assert "rig askew: front_left (DISTANCE_SENSOR): ArduPilot reads" in capsys.readouterr().err
