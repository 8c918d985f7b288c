"""Fitness and status from the recorded trace alone, so a log can always be re-scored.

f = min over t of (d(t) - s): d is the clearance between the UAV body and the nearest obstacle
(python-fcl, negative when they overlap) recorded by the simulator every physics step, s the
profile's safety distance. With no obstacle d is taken as CLEARANCE_CAP_M.

Status policy (README: "Fitness and status"):
  violation       f < 0, whatever else happened: a violation is never hidden behind a penalty.
  ok              the mission was performed (every waypoint passed within the acceptance
                  radius, landed within LANDING_TOLERANCE_M of the goal; with the pilot drive
                  the goal reached and landed) and f >= 0.
  mission_failed  not performed (why says which part, e.g. "blocked: no progress for 20 s" when
                  collision prevention held the pilot back); fitness = f + PENALTY.
  timeout / sut_crashed / sim_crashed   the run could not finish; fitness = f + PENALTY, or
                  PENALTY when nothing was recorded.
  infeasible      never flown; fitness = PENALTY + the total constraint violation in metres,
                  so that optimizers are led back towards feasible scenarios.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, Iterable, Mapping, Sequence

from sim_bridge.control import EndReason
from sim_bridge.pilot import BLOCKED_AFTER_S
from sim_bridge.spec import MissionSpec

CLEARANCE_CAP_M = 100.0
PENALTY = 1000.0
LANDING_TOLERANCE_M = 3.0


class Status(StrEnum):
    """An evaluation's outcome (the policy above). A str, so it is its own JSON and SQLite value."""

    OK = "ok"
    VIOLATION = "violation"
    MISSION_FAILED = "mission_failed"
    INFEASIBLE = "infeasible"
    SUT_CRASHED = "sut_crashed"
    SIM_CRASHED = "sim_crashed"
    TIMEOUT = "timeout"



STATUSES = tuple(Status)
# The run ended before its flight did; executors try these again.
COULD_NOT_FINISH = frozenset({Status.SUT_CRASHED, Status.SIM_CRASHED, Status.TIMEOUT})


@dataclass(frozen=True)
class Clearance:
    min_clearance_m: float
    at_s: float | None
    obstacle: str | None
    samples: int

    def fitness(self, safety_distance_m: float) -> float:
        return self.min_clearance_m - safety_distance_m


def min_clearance(batches: Iterable[Mapping[str, Any]]) -> Clearance:
    """The smallest recorded clearance, when, and to which obstacle (first occurrence wins).

    batches are /clearance messages: parallel arrays t, d, o over consecutive physics steps.
    """
    best, at, which, count = CLEARANCE_CAP_M, None, None, 0
    for batch in batches:
        count += len(batch["t"])
        for t, d, o in zip(batch["t"], batch["d"], batch["o"]):
            if d is not None and d < best:
                best, at, which = d, t, o
    return Clearance(best, at, which, count)


def mission_check(states: Sequence[Mapping[str, Any]], mission: MissionSpec, acceptance_radius_m: float, summary: Mapping[str, Any],
                  drive: str = "mission") -> str | None:
    """None if the recorded flight performed the mission, else why not. A pilot (drive "pilot")
    steers its own line to the goal, so only the goal and the landing count for it."""
    reason = summary.get("end_reason")
    if reason == EndReason.BLOCKED:
        return f"blocked: no progress for {BLOCKED_AFTER_S:.0f} s"
    waypoints = list(enumerate(mission.waypoints, 1))
    for number, waypoint in waypoints if drive == "mission" else waypoints[-1:]:
        closest = min(
            (math.hypot(s["north_m"] - waypoint.north_m, s["east_m"] - waypoint.east_m) for s in states),
            default=math.inf,
        )
        radius = acceptance_radius_m if waypoint.acceptance_radius_m is None else waypoint.acceptance_radius_m
        if closest > radius:
            what = f"waypoint {number}" if drive == "mission" else "the goal"
            return f"{what} missed by {closest:.1f} m (acceptance radius {radius} m); run ended: {reason}"
    if not mission.land:
        return None
    if reason == EndReason.CRASHED:
        touchdown = summary.get("touchdown") or {}
        return f"crashed into the ground at {touchdown.get('speed_m_s', float('nan')):.1f} m/s"
    if reason != EndReason.LANDED:
        return "not landed within the time limit" if reason == EndReason.TIME_LIMIT else f"run ended: {reason}"
    # The pilot lands where its route ends; a mission where its plan ends (home after a return).
    goal = mission.waypoints[-1] if drive == "pilot" else mission.landing or mission.waypoints[-1]
    touchdown = summary.get("touchdown") or {}
    miss = math.hypot(touchdown.get("north_m", math.inf) - goal.north_m, touchdown.get("east_m", math.inf) - goal.east_m)
    if miss > LANDING_TOLERANCE_M:
        return f"landed {miss:.1f} m from the goal (tolerance {LANDING_TOLERANCE_M} m)"
    return None


def judge(clearance: Clearance | None, safety_distance_m: float, failure: tuple[Status, str] | None) -> tuple[Status, float, str | None]:
    """(status, fitness, why) from the clearance and the first failure found, if any.

    failure is (status, why) with status one of mission_failed, timeout, sut_crashed, sim_crashed.
    """
    if clearance is None or clearance.samples == 0:
        status, why = failure or (Status.SIM_CRASHED, "nothing was recorded")
        return Status(status), PENALTY, why
    f = clearance.fitness(safety_distance_m)
    if f < 0.0:
        return Status.VIOLATION, f, failure[1] if failure else None
    if failure is not None:
        return Status(failure[0]), f + PENALTY, failure[1]
    return Status.OK, f, None


def unpenalized(fitness: float, status: str) -> float:
    """A flight's f without the penalty of a mission not performed (how close it came)."""
    return fitness - PENALTY if status == Status.MISSION_FAILED else fitness


def infeasible_fitness(total_violation_m: float) -> float:
    return PENALTY + total_violation_m
