"""The fitness and status policy, as a pure function of the recorded trace, and which statuses
keep the SUT's own flight log."""

from __future__ import annotations

import pytest

from harness.flight.fitness import CLEARANCE_CAP_M, PENALTY, Status, infeasible_fitness, judge, min_clearance, mission_check
from harness.flight.results import RunOptions
from sim_bridge.control import EndReason
from sim_bridge.spec import MissionSpec, Waypoint

MISSION = MissionSpec(takeoff_altitude_m=8.0, waypoints=(Waypoint(north_m=60.0, east_m=0.0, altitude_m=8.0),), cruise_speed_m_s=5.0, land=True)


def batch(*samples):
    return {"t": [s[0] for s in samples], "d": [s[1] for s in samples], "o": [s[2] for s in samples], "g": [0.0] * len(samples)}


def test_min_clearance_finds_the_first_smallest_sample_across_batches():
    clearance = min_clearance([batch((0.0, 5.0, "a"), (0.004, 2.0, "b")), batch((0.008, 2.0, "a"), (0.012, None, None))])
    assert (clearance.min_clearance_m, clearance.at_s, clearance.obstacle, clearance.samples) == (2.0, 0.004, "b", 4)


def test_without_obstacles_the_clearance_is_capped():
    assert min_clearance([batch((0.0, None, None))]).min_clearance_m == CLEARANCE_CAP_M


def test_a_violation_is_never_hidden_behind_a_failure():
    clearance = min_clearance([batch((1.0, 0.4, "a"))])
    status, fitness, why = judge(clearance, 1.0, ("mission_failed", "landed far away"))
    assert status == "violation" and fitness == pytest.approx(-0.6) and why == "landed far away"


def test_failures_get_the_penalty_on_top_of_the_clearance_and_ok_keeps_it():
    clearance = min_clearance([batch((1.0, 4.0, "a"))])
    assert judge(clearance, 1.0, ("timeout", "too slow")) == ("timeout", 3.0 + PENALTY, "too slow")
    assert judge(clearance, 1.0, None) == ("ok", 3.0, None)
    assert judge(None, 1.0, None) == ("sim_crashed", PENALTY, "nothing was recorded")
    assert infeasible_fitness(2.5) == PENALTY + 2.5


def states(*points):
    return [{"north_m": n, "east_m": e} for n, e in points]


def test_the_mission_check_names_what_was_not_performed():
    flown = states((0.0, 0.0), (30.0, 0.0), (59.5, 0.2))
    landed = {"end_reason": "landed", "touchdown": {"north_m": 59.8, "east_m": 0.1}}
    assert mission_check(flown, MISSION, 2.0, landed) is None
    assert "waypoint 1 missed by" in mission_check(states((0.0, 0.0), (40.0, 0.0)), MISSION, 2.0, landed)
    assert "landed 5.0 m from the goal" in mission_check(flown, MISSION, 2.0, {"end_reason": "landed", "touchdown": {"north_m": 55.0, "east_m": 0.0}})
    assert mission_check(flown, MISSION, 2.0, {"end_reason": "time_limit"}) == "not landed within the time limit"
    assert "crashed" in mission_check(flown, MISSION, 2.0, {"end_reason": "crashed", "touchdown": {"speed_m_s": 6.0}})


@pytest.mark.parametrize(("sut_logs", "kept"), [
    ("all", {"ok", "violation", "blocked", "time limit", "ground crash", "sut crashed"}),
    ("failures", {"violation", "blocked", "time limit", "ground crash", "sut crashed"}),
    # a foggy scenario's pilot flights all end mission_failed (blocked, time limit): CP at work,
    # 19 MB of ULog each, which filled a disk once
    ("violations", {"violation", "ground crash", "sut crashed"}),
])
def test_sut_logs_chooses_which_flights_keep_the_suts_own_log(sut_logs, kept):
    flights = {"ok": (Status.OK, EndReason.LANDED), "violation": (Status.VIOLATION, EndReason.LANDED),
               "blocked": (Status.MISSION_FAILED, EndReason.BLOCKED), "time limit": (Status.MISSION_FAILED, EndReason.TIME_LIMIT),
               "ground crash": (Status.MISSION_FAILED, EndReason.CRASHED), "sut crashed": (Status.SUT_CRASHED, EndReason.SUT_DISCONNECTED)}
    options = RunOptions(sut_logs=sut_logs)
    assert {name for name, (status, end) in flights.items() if options.keeps_sut_log(status, end)} == kept
