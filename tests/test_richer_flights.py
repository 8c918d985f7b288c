"""Each richer scenario element flown against the bundled stack: hand-made concrete scenarios
whose outcome the element decides, deterministic to the last bit."""

from __future__ import annotations

import json
import math
import struct
import sys

import pytest
from pymavlink.dialects.v20 import common as mavlink

from conftest import ROOT
from harness.flight import logs
from harness.flight.evaluation import evaluate
from harness.scenario.logical import load_logical
from harness.scenario.space import SearchSpace
from harness.tools.cli import main
from simlink import codec

pytestmark = pytest.mark.slow
DATA = ROOT / "tests" / "data" / "scenarios"
# 20 m wide (east), 10 m thick, 20 m high, centred 30 m north: the bundled stack stops at CP_DIST
# (1 m) from its near face at 25 m (tests/test_e2e.py).
WALL = {"obstacle_1.length_m": 20.0, "obstacle_1.width_m": 10.0, "obstacle_1.height_m": 20.0,
        "obstacle_1.north_m": 30.0, "obstacle_1.east_m": 0.0, "obstacle_1.yaw_deg": 90.0}
SPHERE = {"obstacle_1.diameter_m": 5.0, "obstacle_1.altitude_m": 5.5}  # centred at the 8 m cruise altitude


def fly(tmp_path, profile, scenario: str, values: dict, name: str):
    space = SearchSpace(load_logical(DATA / scenario, profile), profile)
    x = space.vector_from(values)
    assert space.violations(x) == []
    result = evaluate(space, x, seed=2, out_dir=tmp_path, name=name)
    assert result.status in ("ok", "violation", "mission_failed"), result.why
    return result


def events(result) -> list[dict]:
    return [m for _t, _ns, m in logs.messages(result.log_path, ["/events"])]


def run_start(result) -> float:
    return next(e["t"] for e in events(result) if e["event"] == "run")


def test_a_head_on_intruder_collides_and_the_same_three_metres_higher_passes(tmp_path, profile):
    head_on = {"obstacle_1.closest_approach_s": 8.0, "obstacle_1.crossing_deg": 180.0, "obstacle_1.closing_speed_m_s": 10.0,
               "obstacle_1.vertical_offset_m": 0.0}
    met = fly(tmp_path, profile, "intruder_head_on.json", head_on, "met")
    above = fly(tmp_path, profile, "intruder_head_on.json", {**head_on, "obstacle_1.vertical_offset_m": 3.0}, "above")
    assert met.status == "violation" and met.min_clearance_m < 0.0
    assert above.status == "ok" and above.min_clearance_m > 2.0


def test_a_crossing_intruder_on_an_arc_is_sensed_drawn_and_met_near_its_time(tmp_path, profile):
    crossing = {"obstacle_1.closest_approach_s": 8.0, "obstacle_1.crossing_deg": 90.0, "obstacle_1.closing_speed_m_s": 8.0,
                "obstacle_1.vertical_offset_m": 0.0, "obstacle_1.turn_rate_deg_s": 10.0}
    result = fly(tmp_path, profile, "intruder_crossing_arc.json", crossing, "crossing")
    assert result.status == "violation" and result.min_clearance_m < 0.5
    assert result.min_clearance_obstacle == "obstacle_1"
    assert abs(result.min_clearance_at_s - run_start(result) - 8.0) < 2.0
    scene = [m for _t, _ns, m in logs.messages(result.log_path, ["/scene"])]
    paths = [e for m in scene for e in m["entities"] if e["id"] == "obstacle_1/path"]
    assert paths and len(paths[0]["lines"][0]["points"]) > 100  # its turning track, drawn for Foxglove


def test_a_range_sensor_stuck_before_the_wall_flies_into_it_where_the_vehicle_otherwise_stops(tmp_path, profile):
    calm = fly(tmp_path, profile, "wall.json", WALL, "sensing")
    stuck = fly(tmp_path, profile, "wall_stuck_range.json", {**WALL, "failure_1.onset_s": 1.0, "failure_1.duration_s": 60.0}, "stuck")
    assert calm.min_clearance_m > 0.85
    assert stuck.status == "violation" and stuck.min_clearance_m < -1.0
    failure = next(e for e in events(stuck) if e["event"] == "failure")
    assert failure["detail"] == {"unit": "distance sensor", "type": "stuck", "delivery": "simulator", "duration_s": 60.0}
    assert failure["t"] - run_start(stuck) == pytest.approx(1.0, abs=0.05)  # at the sensor's first reading from the onset


def test_a_severe_gust_in_the_final_approach_shortens_the_clearance(tmp_path, profile):
    calm = fly(tmp_path, profile, "wall.json", WALL, "calm")
    gust = {**WALL, "turbulence_m_s": 2.0, "gust.amplitude_m_s": 8.0, "gust.from_deg": 180.0, "gust.duration_s": 2.0}
    # The vehicle brakes from about 6 s and creeps to CP_DIST from the wall until about 20 s.
    approach = fly(tmp_path, profile, "wall_severe_gusts.json", {**gust, "gust.onset_s": 12.0}, "in_approach")
    on_ground = fly(tmp_path, profile, "wall_severe_gusts.json", {**gust, "gust.onset_s": 0.0}, "on_ground")
    assert approach.min_clearance_m < calm.min_clearance_m - 0.15
    assert approach.min_clearance_m < on_ground.min_clearance_m - 0.15
    start = run_start(approach)
    wind = [(m["t"] - start, m["wind_ned_m_s"]) for _t, _ns, m in logs.messages(approach.log_path, ["/wind"])]
    peak = max(wind, key=lambda w: w[1][0])
    assert 12.5 <= peak[0] <= 13.5 and peak[1][0] > 8.0 - 3 * 2.0  # the gust's crest through the turbulence
    assert next(e for e in events(approach) if e["event"] == "gust")["t"] - start == pytest.approx(12.0, abs=0.01)


def test_an_arc_turning_across_the_route_collides_and_the_same_arc_turned_away_does_not(tmp_path, profile):
    arc = {**SPHERE, "obstacle_1.north_m": 30.0, "obstacle_1.east_m": 12.0, "obstacle_1.heading_deg": 270.0, "obstacle_1.speed_m_s": 2.0,
           "obstacle_1.radius_m": 12.0, "obstacle_1.turn_deg": -180.0}
    across = fly(tmp_path, profile, "moving_arc.json", arc, "across")
    away = fly(tmp_path, profile, "moving_arc.json", {**arc, "obstacle_1.heading_deg": 90.0}, "away")
    assert across.status == "violation" and across.min_clearance_m < 0.5
    # Turned away, its circle keeps 12 m east of the route: less its radius and the body's half width.
    assert away.status == "ok" and away.min_clearance_m > 12.0 - 2.5 - 0.3 - 0.5
    # The simulator moved it on its circle: a left turn from heading west, centred 12 m south.
    positions = [(s["pose"]["position"]["y"], s["pose"]["position"]["x"]) for _t, _ns, m in logs.messages(across.log_path, ["/scene"])
                 for e in m["entities"] if e["id"] == "obstacle_1" for s in e["spheres"]]
    assert len(positions) > 50 and all(abs(math.hypot(n - 18.0, e - 12.0) - 12.0) < 0.05 for n, e in positions)


@pytest.mark.parametrize("scenario, into, clear, margin_m", [
    ("moving_vertical.json",
     {"obstacle_1.diameter_m": 5.0, "obstacle_1.altitude_m": 0.0, "obstacle_1.north_m": 30.0, "obstacle_1.east_m": 0.0,
      "obstacle_1.speed_m_s": 0.64, "obstacle_1.rise_m": 10.0},
     {"obstacle_1.altitude_m": 12.0, "obstacle_1.rise_m": 5.0}, 4.0),
    ("moving_waypoints.json",
     {**SPHERE, "obstacle_1.north_m": 20.0, "obstacle_1.east_m": 20.0, "obstacle_1.speed_m_s": 2.0,
      "obstacle_1.via_1.north_m": 40.0, "obstacle_1.via_1.east_m": 0.0, "obstacle_1.via_2.north_m": 50.0, "obstacle_1.via_2.east_m": -20.0},
     {"obstacle_1.via_1.east_m": 20.0, "obstacle_1.via_2.east_m": 25.0}, 10.0),
])
def test_a_mover_whose_path_meets_the_route_comes_closer_than_one_whose_path_does_not(tmp_path, profile, scenario, into, clear, margin_m):
    meeting = fly(tmp_path, profile, scenario, into, "meeting")
    apart = fly(tmp_path, profile, scenario, {**into, **clear}, "apart")
    assert meeting.min_clearance_m < 3.5
    assert apart.min_clearance_m > meeting.min_clearance_m + margin_m


def _gps_times_s(result) -> list[float]:
    """When HIL_GPS went to the SUT, from the simulator link's bytes in the log."""
    splitter = codec.FrameSplitter({m: c.crc_extra for m, c in mavlink.mavlink_map.items()})
    times = []
    for _t, _ns, message in logs.messages(result.log_path, ["/mavlink/sim"]):
        if message["direction"] == "to_sut":
            for msgid, payload, _frame in splitter.feed(bytes.fromhex(message["hex"])):
                if msgid == mavlink.MAVLINK_MSG_ID_HIL_GPS:
                    times.append(struct.unpack_from("<Q", payload)[0] / 1e6)
    return times


def test_a_barometer_failure_reaches_the_autopilot_and_a_gps_failure_is_the_simulators(tmp_path, profile):
    wrong = fly(tmp_path, profile, "wall_baro_wrong_gps_off.json",
                {**WALL, "failure_1.onset_s": 6.0, "failure_1.duration_s": 60.0, "failure_2.onset_s": 4.0, "failure_2.duration_s": 1.0}, "baro")
    start = run_start(wrong)
    told = next(e for e in events(wrong) if e["event"] == "failure" and e["detail"]["unit"] == "barometer")
    assert told["detail"]["delivery"] == "sut" and told["detail"]["result"] == "SUCCESS"
    assert told["t"] - start == pytest.approx(6.0, abs=0.005)  # simulated time stood still while the SUT was told
    # Reading 10 m too high, the autopilot descends into the ground before the wall.
    touchdown = next(e for e in events(wrong) if e["event"] == "touchdown")
    assert touchdown["t"] - start < 15.0 and touchdown["detail"]["north_m"] < 24.0
    gps = [t - start for t in _gps_times_s(wrong)]
    assert not [t for t in gps if 4.0 + 0.004 < t < 5.0]  # off for its second
    assert [t for t in gps if 3.0 < t < 4.0] and [t for t in gps if 5.0 < t < 6.0]


def test_the_combined_example_flies_the_same_twice(tmp_path, profile):
    space = SearchSpace(load_logical(ROOT / "scenarios" / "examples" / "intruder_gusts_failure.json", profile), profile)
    x = space.sample_feasible(__import__("numpy").random.default_rng(11), 1)[0]
    first, second = (evaluate(space, x, seed=11, out_dir=tmp_path / str(i)) for i in range(2))
    assert first.fitness == second.fitness
    traces = [[m for _t, _ns, m in logs.messages(r.log_path, ["/clearance", "/wind", "/events"])] for r in (first, second)]
    assert traces[0] == traces[1]


# The bundled autopilot refusing every injection, as PX4 refuses a unit or type it cannot fail.
REFUSING_SUT = ["--sut", "command", "--sut-command", f"{sys.executable} {ROOT / 'tests' / 'refusing_sut.py'} {{sim_port}} {{api_port}}", "--sut-hold", "frozen"]


def test_a_failure_the_sut_refuses_shows_in_the_result_and_a_campaign_counts_such_flights(tmp_path, capsys):
    scenario = str(DATA / "wall_baro_wrong_gps_off.json")  # its barometer failure is told to the SUT, at 0-15 s: always in flight
    assert main(["run", scenario, "--seed", "3", *REFUSING_SUT, "--out", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert "warning: the SUT refused the barometer wrong failure at t=" in text and "(UNSUPPORTED): it flew on without it" in text
    (log,) = tmp_path.glob("*.mcap")
    assert main(["inspect", str(log), "--json"]) == 0
    assert [(f["unit"], f["type"], f["result"]) for f in json.loads(capsys.readouterr().out)["failures_refused"]] == [("barometer", "wrong", "UNSUPPORTED")]
    store = str(tmp_path / "c.db")
    assert main(["campaign", scenario, "--algorithm", "RANDOM", "--evaluations", "2", "--population", "2", "--workers", "1", *REFUSING_SUT,
                 "--store", store, "--json"]) == 0
    (run,) = json.loads(capsys.readouterr().out)["runs"]
    assert run["flown"] > 0 and run["failures_refused"] == run["flown"]
    assert main(["compare", store]) == 0
    assert f"the SUT refused a failure injection: RANDOM in {run['flown']} flights" in capsys.readouterr().out
    assert main(["report", store, "--out", str(tmp_path / "c.html")]) == 0
    assert f"RANDOM in {run['flown']} flights; they flew without the failure their scenario asks for" in (tmp_path / "c.html").read_text()
