"""End to end: the bridge, the bundled autopilot and MAVSDK as real processes, real flights, real numbers."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import jsonschema
import pytest
from mcap.reader import make_reader

from conftest import ROOT, chunk_compressions
from harness.flight import logs
from harness.flight.bridge_control import BridgeControl
from harness.flight.evaluation import evaluate
from harness.flight.results import RunOptions
from harness.flight.fitness import PENALTY
from harness.flight.inspect_log import summarize
from harness.flight.mavsdk_session import MavsdkSession, mission_items
from harness.flight.ports import PortLease
from harness.scenario.logical import load_logical
from harness.scenario.space import SearchSpace
from harness.scenario.world import world_spec
from sim_bridge.control import EndReason, Finished, Holding, Run
from sim_bridge.recording import TOPICS
from sut_adapter.processes import ManagedProcess

pytestmark = pytest.mark.slow
DATA = ROOT / "tests" / "data" / "scenarios"


def space_for(path, profile) -> SearchSpace:
    return SearchSpace(load_logical(path, profile), profile)


def test_static_obstacles_only_end_ok_or_violation_with_a_finite_fitness(tmp_path, profile):
    space = space_for(ROOT / "scenarios" / "table3" / "scenario_05.json", profile)
    x = space.sample_feasible(__import__("numpy").random.default_rng(3), 1)[0]
    result = evaluate(space, x, seed=3, out_dir=tmp_path)
    assert result.status in ("ok", "violation"), result.why
    assert math.isfinite(result.fitness) and result.fitness < PENALTY
    assert result.min_clearance_m == pytest.approx(result.fitness + 1.0)
    # It came down at the goal before its flight ended (landed: still, motors idle, for a second).
    assert result.first_touchdown_s is not None and result.first_touchdown_s <= result.sim_time_s - 1.0


def test_the_log_opens_as_foxglove_expects_every_message_matches_its_schema(tmp_path, profile):
    space = space_for(DATA / "one_dynamic_sphere.json", profile)
    result = evaluate(space, space.vector_from({"obstacle_1.north_m": 40.0, "obstacle_1.east_m": 15.0}), seed=1, out_dir=tmp_path)
    counts = {}
    validators = {}  # one per schema, checked once: jsonschema.validate checks the schema again at every call
    with open(result.log_path, "rb") as stream:
        reader = make_reader(stream)
        for schema, channel, message in reader.iter_messages():
            assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
            if schema.id not in validators:
                document = json.loads(schema.data)
                validator_class = jsonschema.validators.validator_for(document)
                validator_class.check_schema(document)
                validators[schema.id] = validator_class(document)
            validators[schema.id].validate(json.loads(message.data))
            counts[(channel.topic, schema.name)] = counts.get((channel.topic, schema.name), 0) + 1
    # every channel the log declares carries messages under the schema the bridge documents
    assert set(counts) == set(TOPICS.items())
    # The simulator records uncompressed for the harness to rewrite; the evaluation's log is compressed.
    with open(result.log_path, "rb") as stream:
        assert chunk_compressions(stream) == {"zstd"}
    meta = logs.metadata(result.log_path)
    assert {"world", "concrete_scenario", "sut", "result", "bridge_summary"} <= set(meta)
    assert json.loads(meta["result"]["json"])["fitness"] == result.fitness


def test_a_dynamic_obstacle_aimed_at_the_path_scores_lower_than_one_far_away(tmp_path, profile):
    space = space_for(DATA / "one_dynamic_sphere.json", profile)
    head_on = {"obstacle_1.diameter_m": 5.0, "obstacle_1.north_m": 50.0, "obstacle_1.east_m": 0.0, "obstacle_1.altitude_m": 5.5,
               "obstacle_1.heading_deg": 180.0, "obstacle_1.speed_m_s": 2.0, "obstacle_1.travel_m": 35.0}
    aimed = evaluate(space, space.vector_from(head_on), seed=1, out_dir=tmp_path, name="aimed")
    far = evaluate(space, space.vector_from({**head_on, "obstacle_1.east_m": 25.0}), seed=1, out_dir=tmp_path, name="far")
    assert aimed.status != "infeasible" and far.status == "ok", (aimed.why, far.why)
    assert aimed.fitness < far.fitness - 5.0
    assert aimed.min_clearance_m < 2.0 < far.min_clearance_m


def test_three_repeats_are_identical_and_inspect_reproduces_the_fitness(tmp_path, profile):
    space = space_for(ROOT / "scenarios" / "table3" / "scenario_31.json", profile)
    x = space.sample_feasible(__import__("numpy").random.default_rng(4), 1)[0]
    # Both placements: polling on two cores must not change what is simulated.
    results = [evaluate(space, x, seed=4, out_dir=tmp_path / str(i), options=RunOptions(cores=cores)) for i, cores in enumerate((1, 2, 2))]
    assert len({r.fitness for r in results}) == 1
    traces = [[m for _t, _ns, m in logs.messages(r.log_path, ["/clearance"])] for r in results]
    assert traces[0] == traces[1] == traces[2]
    inspected = summarize(results[0].log_path)
    assert inspected["fitness"] == results[0].fitness and inspected["fitness_reproduced"]
    assert inspected["status"] == results[0].status


def test_a_wall_across_the_path_stops_the_vehicle_at_cp_dist(tmp_path, profile):
    space = space_for(DATA / "wall.json", profile)
    # 20 m wide (east), 10 m thick (north), 20 m high, centred 30 m north: its near face is at 25 m.
    wall = {"obstacle_1.length_m": 20.0, "obstacle_1.width_m": 10.0, "obstacle_1.height_m": 20.0,
            "obstacle_1.north_m": 30.0, "obstacle_1.east_m": 0.0, "obstacle_1.yaw_deg": 90.0}
    result = evaluate(space, space.vector_from(wall), seed=2, out_dir=tmp_path)
    states = [m for _t, _ns, m in logs.messages(result.log_path, ["/uav/state"])]
    furthest_north = max(s["north_m"] for s in states)
    cp_dist = 1.0
    # The body's front (0.3 m ahead of its centre) stays CP_DIST from the face, within 0.15 m of dynamics.
    assert 25.0 - (furthest_north + 0.3) >= cp_dist - 0.15
    assert result.min_clearance_m >= cp_dist - 0.15
    assert furthest_north > 20.0  # it did fly up to the wall
    assert result.status in ("mission_failed", "violation") and "waypoint 1" in (result.why or "")


def test_mavsdk_flies_a_three_waypoint_mission_and_uses_the_param_plugin(tmp_path, profile):
    space = space_for(DATA / "three_waypoints.json", profile)
    world = world_spec(space, space.vector_from({}), seed=5)
    world_path = tmp_path / "world.json"
    world_path.write_text(json.dumps(world.as_dict()))
    log_path = tmp_path / "flight.mcap"
    with PortLease() as ports:
        bridge_argv = [__import__("sys").executable, "-m", "sim_bridge", "--world", str(world_path), "--sim-port", str(ports.sim),
                       "--control-port", str(ports.control), "--mcap", str(log_path)]
        autopilot_argv = [__import__("sys").executable, "-m", "autopilot", "--sim", f"tcp:127.0.0.1:{ports.sim}", "--api", f"udp:127.0.0.1:{ports.api}"]
        with ManagedProcess("bridge", bridge_argv, log_dir=tmp_path) as bridge, ManagedProcess("autopilot", autopilot_argv, log_dir=tmp_path) as autopilot:
            control = BridgeControl(ports.control)
            assert control.wait_for(Holding, 30.0) is not None
            session = MavsdkSession(ports.api).discover()
            try:
                session.wait_healthy(20.0)
                assert session.param.get_param_float("CP_DIST") == pytest.approx(1.0)
                session.param.set_param_float("CP_DIST", 2.5)
                assert session.param.get_param_float("CP_DIST") == pytest.approx(2.5)
                assert session.param.get_param_int("CP_GO_NO_DATA") == 1
                items = mission_items(world)
                session.upload_and_start(items, 0.0)
                downloaded = session.mission.download_mission()
                assert [i.command for i in downloaded] == [i.command for i in items]
                control.send(Run())
                finished = control.wait_for(Finished, 120.0)
                time.sleep(0.5)
                texts = list(session.status_texts)
            finally:
                session.close()
                control.close()
            assert bridge.wait(10.0) == 0
            assert autopilot.poll() is None or autopilot.poll() == 0
    assert finished.end_reason == EndReason.LANDED
    states = [m for _t, _ns, m in logs.messages(log_path, ["/uav/state"])]
    for waypoint in world.mission.waypoints:
        closest = min(math.hypot(s["north_m"] - waypoint.north_m, s["east_m"] - waypoint.east_m) for s in states)
        assert closest <= 2.0, (waypoint, closest)
    touchdown = finished.summary["touchdown"]
    assert math.hypot(touchdown["north_m"] - 0.0, touchdown["east_m"] - 15.0) < 1.5
    assert "Landing detected" in texts and "Disarmed" in texts


@pytest.mark.slow
def test_repeats_of_one_concrete_scenario_report_their_spread(tmp_path, capsys):
    from conftest import FIG4, FIG4_SEED1_FITNESS
    from harness.tools.cli import main

    assert main(["run", str(FIG4), "--seed", "1", "--repeat", "2", "--out", str(tmp_path), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert (report["repeats"], report["statuses"], report["violations"], report["flaky"]) == (2, {"ok": 2}, 0, False)
    # the bundled autopilot is deterministic: no spread at all
    assert report["fitness"] == {"min": FIG4_SEED1_FITNESS, "median": FIG4_SEED1_FITNESS, "max": FIG4_SEED1_FITNESS}
    assert len({run["log_path"] for run in report["runs"]}) == 2 and all(summarize(Path(run["log_path"]))["fitness_reproduced"] for run in report["runs"])


@pytest.mark.slow
def test_confirm_re_flies_each_violation_and_stores_how_often_it_came_back(tmp_path, capsys):
    import sqlite3

    from harness.tools.cli import main

    store = tmp_path / "confirm.db"
    # Collision prevention off (CP_DIST < 0, as in PX4), and seed 13, whose first random sample
    # stands the wall across the route: the bundled autopilot flies into it.
    assert main(["campaign", str(ROOT / "scenarios" / "examples" / "wall.json"), "--algorithm", "RANDOM", "--evaluations", "2", "--population", "2",
                 "--seed", "13", "--confirm", "2", "--sut-param", "CP_DIST=-1", "--executor", "sequential", "--store", str(store), "--json"]) == 0
    capsys.readouterr()
    with sqlite3.connect(store) as db:
        rows = db.execute("SELECT status, fitness, confirmations FROM evaluations ORDER BY ordinal").fetchall()
    assert len(rows) == 2 and any(status == "violation" for status, _f, _c in rows)
    for status, fitness, confirmations in rows:
        if status != "violation":
            assert confirmations is None
            continue
        record = json.loads(confirmations)
        # the bundled autopilot is deterministic: every re-flight violates by exactly as much
        assert (record["repeats"], record["violations"], record["fitness"]) == (2, 2, [fitness, fitness])
    assert main(["export-regressions", str(store), "--out", str(tmp_path / "cases"), "--expect", "violation", "--json"]) == 0
    capsys.readouterr()
    cases = [json.loads(p.read_text()) for p in (tmp_path / "cases").glob("*.json")]
    assert cases and all(case["found"]["flaky"] is False and case["found"]["confirmations"]["repeats"] == 2 for case in cases if case["found"]["status"] == "violation")
