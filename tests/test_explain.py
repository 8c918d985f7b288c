"""`stella explain` on hand-made flights of the bundled stack whose mechanism the physics decides:
a stuck range sensor, a fast intruder from behind, a gust into a wall, collision prevention off,
thick fog; and triage's mechanism column from their logs, with and without the logs."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from conftest import ROOT
from autopilot.collision import max_speed_from_distance
from harness.campaigns.explain import MECHANISMS, Limits, Moment, _classify, explain
from harness.campaigns.store import Store
from harness.campaigns.triage import triage
from harness.flight.evaluation import RunOptions, evaluate
from harness.flight.fitness import COULD_NOT_FINISH
from harness.scenario.logical import load_logical
from harness.scenario.space import SearchSpace
from harness.tools.cli import main
from sut_adapter import SutConfig

DATA = ROOT / "tests" / "data" / "scenarios"
# 20 m wide, 10 m thick, 20 m high, its near face 25 m north: at 5 m/s the bundled stack needs
# about 15 m to stop and its sensor reaches 20 m, so in clear air it is seen in time.
WALL = {"obstacle_1.length_m": 20.0, "obstacle_1.width_m": 10.0, "obstacle_1.height_m": 20.0,
        "obstacle_1.north_m": 30.0, "obstacle_1.east_m": 0.0, "obstacle_1.yaw_deg": 90.0}
# Every closest approach below comes within 15 s of the run's start: a shorter time limit than
# the profile's 120 s only saves the hover in front of the wall that follows it.
TIME_LIMIT_S = 20.0
# The run's wall timeout is its time limit over this: room for a machine busy with other work.
SLOW_MACHINE = 0.1

FLIGHTS = {
    # The sensor freezes at 1 s, before the wall is in reach: it keeps delivering "nothing in reach".
    "stuck_sensor": ("wall_stuck_range.json", {**WALL, "failure_1.onset_s": 1.0, "failure_1.duration_s": 60.0}, {}),
    # Another multirotor on the route's track, 10 m/s from behind, meeting the vehicle 8 s into the run.
    "intruder_from_behind": ("intruder_overtaking.json", {"obstacle_1.closest_approach_s": 8.0, "obstacle_1.crossing_deg": 0.0,
                                                           "obstacle_1.closing_speed_m_s": 5.0, "obstacle_1.vertical_offset_m": 0.0}, {}),
    # An 8 m/s gust from the south at 12 s, when the vehicle has braked to a creep before the wall.
    "gust_into_wall": ("wall_severe_gusts.json", {**WALL, "turbulence_m_s": 2.0, "gust.amplitude_m_s": 8.0, "gust.from_deg": 180.0,
                                                  "gust.duration_s": 2.0, "gust.onset_s": 12.0}, {}),
    # Collision prevention disabled by its own parameter (CP_DIST < 0, as in PX4).
    "cp_off": ("wall.json", WALL, {"CP_DIST": -1.0}),
    # Thick fog: the sensor reaches its 2 m floor, far short of the 15 m the vehicle needs to stop.
    "thick_fog": ("wall_thick_fog.json", {**WALL, "visibility_m": 50.0}, {}),
}


def fly_once(space, x, out, name, options):
    """One flight; flown again where the run could not finish (as executors do), so that a machine
    too busy to start the stack in time does not decide the test."""
    result = evaluate(space, x, seed=2, out_dir=out, name=name, options=options)
    if result.status in COULD_NOT_FINISH:
        result = evaluate(space, x, seed=2, out_dir=out, name=name, options=options)
    return result


@pytest.fixture(scope="module")
def flown(tmp_path_factory, profile):
    """Each hand-made flight once: (its search space, vector, result)."""
    short = replace(profile, document={**profile.document, "time_limit_s": TIME_LIMIT_S})
    out = tmp_path_factory.mktemp("explain")
    flights = {}
    for name, (scenario, values, params) in FLIGHTS.items():
        space = SearchSpace(load_logical(DATA / scenario, short), short)
        x = space.vector_from(values)
        assert space.violations(x) == []
        result = fly_once(space, x, out, name, RunOptions(sut=SutConfig(params=params), min_real_time_factor=SLOW_MACHINE))
        assert result.status == "violation", (name, result.status, result.why)
        flights[name] = (space, x, result)
    return flights


def explained(flown, name: str) -> dict:
    return explain(Path(flown[name][2].log_path))


@pytest.mark.slow
def test_a_stuck_range_sensor_leaves_the_wall_unseen(flown):
    report = explained(flown, "stuck_sensor")
    assert report["mechanism"] == "unseen"
    assert "range sensor had failed (stuck" in report["evidence"][0]
    # The ideal sensor had it in view seconds before the contact; the SUT was never shown it.
    whats = [entry["what"] for entry in report["timeline"]]
    assert "in view" in whats and "reported to the SUT" not in whats
    assert report["context"]["failures"] == [{"unit": "distance sensor", "type": "stuck", "since_s": pytest.approx(1.0, abs=0.05)}]


@pytest.mark.slow
def test_a_fast_intruder_from_behind_outruns_the_vehicle(flown):
    report = explained(flown, "intruder_from_behind")
    assert report["mechanism"] == "outrun"
    numbers = report["numbers"]
    # The vehicle flew away from it at cruise speed; the intruder closed at its own 10 m/s.
    assert numbers["own_closing_final_m_s"] < 0.0 < numbers["obstacle_closing_final_m_s"]
    assert np.hypot(*report["context"]["obstacle_velocity_m_s"][:2]) == pytest.approx(10.0, abs=0.5)


@pytest.mark.slow
def test_a_gust_into_the_wall_pushes_a_vehicle_that_had_braked(flown):
    report = explained(flown, "gust_into_wall")
    assert report["mechanism"] == "pushed"
    numbers = report["numbers"]
    assert numbers["distance_at_report_m"] > numbers["stopping_distance_needed_m"]  # seen in time
    assert numbers["own_closing_at_entry_m_s"] < numbers["own_closing_at_report_m_s"]  # and braking
    assert numbers["wind_towards_obstacle_at_entry_m_s"] > numbers["own_closing_at_entry_m_s"]
    assert report["context"]["gust"]["from_deg"] == pytest.approx(180.0)


@pytest.mark.slow
def test_collision_prevention_off_brakes_too_little_though_the_wall_was_seen_in_time(flown):
    report = explained(flown, "cp_off")
    assert report["mechanism"] == "braked_too_little"
    numbers = report["numbers"]
    assert numbers["distance_at_report_m"] > numbers["stopping_distance_needed_m"]
    assert numbers["own_closing_at_entry_m_s"] > 4.0  # it flew in at about cruise speed
    assert report["context"]["limits"]["cp_dist_m"] == -1.0 and "CP_DIST" not in report["context"]["limits"]["assumed"]
    assert report["context"]["sut"] == {"name": "bundled", "fault": None, "params": {"CP_DIST": -1.0}}
    assert report["context"]["drive"]["into_obstacle"] is True


@pytest.mark.slow
def test_thick_fog_shows_the_wall_too_late_to_stop(flown):
    report = explained(flown, "thick_fog")
    assert report["mechanism"] == "seen_late"
    numbers = report["numbers"]
    assert numbers["distance_at_report_m"] <= 2.5 < numbers["stopping_distance_needed_m"]


@pytest.mark.slow
def test_a_range_sensor_that_goes_off_holds_the_vehicle_so_there_is_nothing_unseen_to_explain(tmp_path, profile):
    # Without range data for 0.5 s the bundled collision prevention stops horizontal motion: an
    # "off" sensor (no readings) keeps the vehicle where it is, unlike a stuck one (above).
    short = replace(profile, document={**profile.document, "time_limit_s": TIME_LIMIT_S})
    space = SearchSpace(load_logical(DATA / "wall_range_off.json", short), short)
    result = fly_once(space, space.vector_from({**WALL, "failure_1.onset_s": 1.0, "failure_1.duration_s": 60.0}), tmp_path, "off",
                      RunOptions(min_real_time_factor=SLOW_MACHINE))
    report = explain(Path(result.log_path))
    assert result.status == "mission_failed" and report["mechanism"] == "none"
    assert report["min_clearance_m"] > 20.0 and report["context"]["failures"][0]["type"] == "off"


@pytest.mark.slow
def test_explain_on_the_command_line_prints_json_and_text(flown, capsys):
    log = flown["cp_off"][2].log_path
    assert main(["explain", log, "--json"]) == 0
    document = json.loads(capsys.readouterr().out)
    assert document["mechanism"] == "braked_too_little" and document["timeline"][-1]["what"] == "closest approach"
    assert main(["explain", log]) == 0
    assert "mechanism: braked_too_little" in capsys.readouterr().out
    assert main(["explain", str(Path(log).with_name("missing.mcap"))]) == 2


@pytest.mark.slow
def test_triage_groups_by_mechanism_and_still_works_when_a_log_is_gone(flown, tmp_path):
    store_path = tmp_path / "hand_made.db"
    with Store.for_campaign(store_path) as store:
        campaign = store.campaign({"hand-made": sorted(FLIGHTS)})
        for index, (name, (space, x, result)) in enumerate(sorted(flown.items())):
            run_id, _ = store.run(campaign, FLIGHTS[name][0], result.scenario, "hand-made", index, 2)
            store.add_evaluation(run_id, ordinal=0, step=0, optimizer="hand-made", vector=x, result=result, concrete=None)
    report = triage(store_path)
    assert sorted(m.keys["mechanism"] for m in report.modes) == ["braked_too_little", "outrun", "pushed", "seen_late", "unseen"]
    assert all(m.mode.startswith(f"{m.keys['mechanism']}: ") and m.keys["mechanism"] in MECHANISMS for m in report.modes)
    # A log deleted since: that violation is listed as not triaged, the others keep their modes.
    Path(flown["thick_fog"][2].log_path).rename(tmp_path / "moved.mcap")
    try:
        report = triage(store_path)
    finally:
        (tmp_path / "moved.mcap").rename(flown["thick_fog"][2].log_path)
    assert sorted(m.keys["mechanism"] for m in report.modes) == ["braked_too_little", "outrun", "pushed", "unseen"]
    assert [s["why"] for s in report.skipped] == ["its log is missing"]


@pytest.mark.parametrize("speed_m_s", [0.5, 2.0, 5.0, 12.0])
@pytest.mark.parametrize("sut, delay_s", [({"params": {}}, 0.4), ({"params": {"CP_DELAY": 0.1, "MPC_ACC_HOR": 5.0, "MPC_JERK_AUTO": 10.0}}, 0.1)])
def test_the_stopping_distance_is_the_one_the_bundled_collision_prevention_plans_with(speed_m_s, sut, delay_s):
    limits = Limits.of(sut)
    braking_m = limits.stopping_distance_m(speed_m_s) - limits.cp_dist_m - delay_s * speed_m_s
    # autopilot/collision.py allows exactly this speed with that much room left to brake in.
    assert max_speed_from_distance(limits.jerk_m_s3, limits.acc_m_s2, braking_m) == pytest.approx(speed_m_s)
    assert ("CP_DELAY" in limits.assumed) == (sut["params"] == {})


@pytest.mark.parametrize(("params", "described"), [
    ({}, "AVOID_MARGIN 1.0 m, AVOID_ACCEL_MAX 3.0 m/s^2 (assumed defaults: AVOID_MARGIN, AVOID_ACCEL_MAX)"),
    ({"AVOID_MARGIN": 2.0, "AVOID_ACCEL_MAX": 1.5}, "AVOID_MARGIN 2.0 m, AVOID_ACCEL_MAX 1.5 m/s^2"),
])
def test_ardupilots_stop_is_modelled_with_its_own_avoidance_parameters(params, described):
    limits = Limits.of({"name": "ardupilot", "params": params})
    assert limits.describe() == described
    margin, acc = params.get("AVOID_MARGIN", 1.0), params.get("AVOID_ACCEL_MAX", 3.0)
    # simple avoidance has no delay or jerk limit: the margin, then v^2 / 2a
    assert limits.stopping_distance_m(6.0) == pytest.approx(margin + 36.0 / (2.0 * acc))
    assert Limits.of({"name": "ardupilot", "params": {**params, "AVOID_ENABLE": 0}}).cp_dist_m < 0


@pytest.mark.parametrize("name, mode", [("px4", "Position mode"), ("ardupilot", "not in Auto")])
def test_real_firmware_on_a_mission_is_not_modelled_as_braking_for_what_it_senses(name, mode):
    on_mission = Limits.of({"name": name, "params": {}}, "mission")
    assert on_mission.cp_dist_m < 0 and on_mission.inactive is not None
    assert on_mission.describe().startswith("no stop: ") and mode in on_mission.describe()
    # the stop a braking vehicle would have needed is to the obstacle itself
    assert on_mission.stopping_distance_m(6.0) < Limits.of({"name": name, "params": {}}, "pilot").stopping_distance_m(6.0)
    assert Limits.of({"name": name, "params": {}}, "pilot").inactive is None


def test_the_bundled_autopilot_brakes_on_missions_too():
    assert Limits.of({"name": "bundled", "params": {}}, "mission") == Limits.of({"name": "bundled", "params": {}}, "pilot")


def test_a_sut_without_its_own_stopping_model_is_described_with_px4s_parameters():
    assert Limits.of({"name": "mavlink", "params": {"CP_DIST": 2.0}}).describe() == (
        "CP_DIST 2.0 m, CP_DELAY 0.4 s, MPC_ACC_HOR 3.0 m/s^2, MPC_JERK_AUTO 4.0 m/s^3 (assumed defaults: CP_DELAY, MPC_ACC_HOR, MPC_JERK_AUTO)")


def _moment(t_s: float, distance_m: float | None) -> Moment:
    return Moment(t_s, distance_m, (0.0, 0.0, -1.0) if distance_m is None else (1.0, 0.0, 0.0), 0.0, 0.0, False, False)


@pytest.mark.parametrize(("distances", "why"), [
    # flown over a low obstacle: at the sensor's height it was far off, the closest approach was from above
    ([44.0, 30.0, 20.0, None, None], "it passed above or below it; at the height the sensor scans it never came within the sensor's reach of 16.5 m"),
    ([None, None], "it was never at the height the sensor scans: it passed above or below it"),
    ([40.0, 20.0, 17.0], "it never came within the sensor's reach of 16.5 m"),
])
def test_an_obstacle_never_reported_is_said_to_be_passed_over_when_the_closest_approach_was_above_or_below(distances, why):
    world = SimpleNamespace(safety_distance_m=1.0, sensor=SimpleNamespace(range_m=16.5, fov_deg=100.0), rig=None)
    moments = [_moment(float(t), d) for t, d in enumerate(distances)]
    mechanism, evidence = _classify(0.5, world, moments, None, None, {"own_closing_final_m_s": 0.0, "obstacle_closing_final_m_s": 0.0},
                                    {"failures": []}, Limits.of({"name": "bundled"}))
    assert mechanism == "unseen" and evidence[0] == f"never reported to the SUT before the closest approach: {why}"
