"""Triage: a campaign's violations grouped into failure modes by what happened, not by how close
their vectors are.

A violation's mode is read from its log at the moment of least clearance: the mechanism `stella
explain` finds (harness/campaigns/explain.py: unseen, seen_late, braked_too_little, outrun,
pushed, other), the obstacle involved (kind and form), the flight phase (climb, cruise, braking, hover, descent), where the obstacle's
centre was relative to the direction of flight (ahead, beside, behind; the vehicle hovering; or
inside the obstacle, for a contact), the
closing speed band, and the environment: the wind and visibility categories of the profile the
scenario was flown in (what a user searched over; not bands of the sampled values, which would
split one category's violations at a made-up edge). Each mode has its count, its
severity (near miss: 0 < clearance < safety distance; contact: clearance <= 0), its worst and its
most typical example (the one whose trajectory is closest to the others'), with their logs.
The campaign's diversity is the number of modes and, as the UAV Testing Competition measures
it, the mean pairwise distance between the violating trajectories.

A campaign that searched safety properties (`--property`) is triaged by them instead: its
findings are the flights that broke a property, and a mode is which properties they broke, the
failures the scenario injected (unit and type), and the wind and visibility; its worst example
is the flight of least robustness.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from harness.campaigns.store import Store, StoredEvaluation
from harness.errors import InputError, Problem
from harness.flight import logs
from harness.flight.fitness import Status, min_clearance
from harness.scenario.world import space_from_concrete
from sim_bridge.obstacles import Obstacle

TRAJECTORY_POINTS = 50  # a trajectory is compared at this many instants spread over its flight
BRAKING_M_S2 = 0.5  # deceleration above this along the velocity is braking
MOVING_M_S = 0.5
CLIMB_M_S = 0.3
SPEED_BANDS = ((1.0, "slow (< 1 m/s)"), (3.0, "medium (1-3 m/s)"), (math.inf, "fast (> 3 m/s)"))


def _band(value: float, bands: Sequence[tuple[float, str]]) -> str:
    return next(name for limit, name in bands if value < limit)


def _phase(before: Mapping[str, Any], at: Mapping[str, Any]) -> str:
    vn, ve, vd = at["v_ned_m_s"]
    horizontal = math.hypot(vn, ve)
    if vd < -CLIMB_M_S and horizontal < MOVING_M_S:
        return "climb"
    if vd > CLIMB_M_S and horizontal < MOVING_M_S:
        return "descent"
    if horizontal < MOVING_M_S:
        return "hover"
    dt = max(1e-6, at["t"] - before["t"])
    along = ((vn - before["v_ned_m_s"][0]) * vn + (ve - before["v_ned_m_s"][1]) * ve) / (horizontal * dt)
    return "braking" if along < -BRAKING_M_S2 else "cruise"


def _approach(at: Mapping[str, Any], obstacle_at: np.ndarray) -> str:
    vn, ve, _vd = at["v_ned_m_s"]
    speed = math.hypot(vn, ve)
    dn, de = obstacle_at[0] - at["north_m"], obstacle_at[1] - at["east_m"]
    distance = math.hypot(dn, de)
    if speed < MOVING_M_S or distance < 1e-6:
        return "while hovering"
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (vn * dn + ve * de) / (speed * distance)))))
    return "ahead" if angle < 45.0 else "beside" if angle < 135.0 else "behind"


def trajectory(states: Sequence[Mapping[str, Any]]) -> np.ndarray:
    """TRAJECTORY_POINTS positions (north, east, up) at evenly spread instants of the flight."""
    t = np.array([s["t"] for s in states])
    points = np.array([[s["north_m"], s["east_m"], s["up_m"]] for s in states])
    instants = np.linspace(t[0], t[-1], TRAJECTORY_POINTS)
    return np.stack([np.interp(instants, t, points[:, axis]) for axis in range(3)], axis=1)


def trajectory_distance(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.mean(np.linalg.norm(a - b, axis=1)))


def features(log_path: Path) -> dict[str, Any]:
    """What happened at the moment of least clearance of one flight."""
    world = logs.world_of(log_path)
    clearance = min_clearance(batch for _t, _ns, batch in logs.messages(log_path, ["/clearance"]))
    states = [m for _t, _ns, m in logs.messages(log_path, ["/uav/state"])]
    if world is None or not states or clearance.obstacle is None:
        raise InputError([Problem(str(log_path), "", "no world, trajectory or clearance in this log: it cannot be triaged")])
    index = min(range(len(states)), key=lambda i: abs(states[i]["t"] - clearance.at_s))
    at, before = states[index], states[max(0, index - 1)]
    spec = next(o for o in world.obstacles if o["id"] == clearance.obstacle)
    obstacle = Obstacle.from_spec(spec)
    here = obstacle.position_at(at["t"])
    obstacle_velocity = (obstacle.position_at(at["t"] + 0.1) - obstacle.position_at(max(0.0, at["t"] - 0.1))) / 0.2
    closing = math.hypot(at["v_ned_m_s"][0] - obstacle_velocity[0], at["v_ned_m_s"][1] - obstacle_velocity[1])
    return {
        "mechanism": _mechanism(log_path),
        "obstacle": f"{spec['kind']} {spec['form']}",
        "phase": _phase(before, at),
        # Inside the obstacle, where its centre lies says nothing of how the vehicle got there.
        "approach": "inside" if clearance.min_clearance_m <= 0.0 else _approach(at, here),
        "speed": _band(closing, SPEED_BANDS),
        **_environment(logs.json_metadata(log_path, "concrete_scenario"), log_path),
        "min_clearance_m": clearance.min_clearance_m,
        "trajectory": trajectory(states),
    }


def _environment(concrete: Mapping[str, Any], log_path: Path) -> dict[str, str]:
    """The wind and visibility categories of the profile the scenario was flown in, in words."""
    weather = space_from_concrete(concrete, str(log_path)).logical.weather
    wind, visibility = weather["wind force"].category, weather["reduced visibility"].category
    return {"wind": "no wind" if wind == "none" else f"{wind} wind", "visibility": "clear" if visibility == "none" else visibility}


def _mechanism(log_path: Path) -> str:
    """How the flight came too close (`stella explain`); "unexplained" where its log cannot say."""
    from harness.campaigns.explain import explain

    try:
        return explain(log_path)["mechanism"]
    except (InputError, KeyError):  # KeyError: a log from a recorder older than a field explain reads
        return "unexplained"


MODE_KEYS = ("mechanism", "obstacle", "phase", "approach", "speed", "wind", "visibility")


def mode_name(entry: Mapping[str, Any]) -> str:
    return (f"{entry['mechanism']}: {entry['obstacle']}, {entry['approach']}, {entry['phase']}, {entry['speed']}, {entry['wind']}, "
            f"{entry['visibility']}")


@dataclass(frozen=True)
class Example:
    """The evaluation that stands for a failure mode (its worst or its most typical)."""

    id: int  # the evaluation's id in the store, the number in its log's name
    scenario: str
    scenario_file: str
    algorithm: str
    run: int
    fitness: float
    min_clearance_m: float | None
    log: str
    robustness: float | None = None  # in a property campaign: the least robustness of the properties it broke


@dataclass(frozen=True)
class FailureMode:
    mode: str  # its name: the keys' values in words
    keys: Mapping[str, Any]  # MODE_KEYS' values (and, in a differential campaign, what it reveals)
    count: int
    contacts: int
    near_misses: int
    worst: Example
    typical: Example

    def as_dict(self) -> dict[str, Any]:
        return {"mode": self.mode, **self.keys, "count": self.count, "contacts": self.contacts, "near_misses": self.near_misses,
                "worst": asdict(self.worst), "typical": asdict(self.typical)}


@dataclass(frozen=True)
class Triage:
    store: str
    violations: int
    modes: tuple[FailureMode, ...]
    skipped: tuple[Mapping[str, Any], ...]  # evaluations that could not be triaged, with why
    differential: bool
    mean_pairwise_trajectory_distance_m: float | None
    by_properties: bool = False  # a property campaign's: the flights that broke a property

    def as_dict(self) -> dict[str, Any]:
        return {"store": self.store, "violations": self.violations, "modes": [mode.as_dict() for mode in self.modes], "skipped": list(self.skipped),
                "differential": self.differential, "by_properties": self.by_properties,
                "diversity": {"modes": len(self.modes), "mean_pairwise_trajectory_distance_m": self.mean_pairwise_trajectory_distance_m}}


@dataclass(frozen=True)
class _Violation:
    evaluation: StoredEvaluation
    features: Mapping[str, Any]  # read from its log (features())

    def example(self) -> Example:
        e = self.evaluation
        return Example(e.id, e.scenario, e.scenario_file, e.algorithm, e.run_index, e.fitness, self.features["min_clearance_m"], e.log_path,
                       self.features.get("robustness"))

    @property
    def severity(self) -> float:
        """What makes one worse than another: its least robustness, else its fitness."""
        return self.features.get("robustness", self.evaluation.fitness)


PROPERTY_MODE_KEYS = ("broken", "failures", "wind", "visibility")


def broken_properties(evaluation: StoredEvaluation) -> dict[str, float]:
    """The properties a flight broke, with their robustness."""
    return {name: scored["robustness"] for name, scored in evaluation.properties.items()
            if scored["verdict"] == "violated" and scored.get("robustness") is not None}


def property_features(evaluation: StoredEvaluation) -> dict[str, Any]:
    """What a flight that broke safety properties broke, under which failures and weather."""
    log_path = Path(evaluation.log_path)
    states = [m for _t, _ns, m in logs.messages(log_path, ["/uav/state"])]
    if not states or evaluation.concrete is None:
        raise InputError([Problem(str(log_path), "", "no trajectory or concrete scenario for this flight: it cannot be triaged")])
    broken = broken_properties(evaluation)
    failures = [f"{failure['unit']} {failure['type']}" for failure in evaluation.concrete.get("failures", [])]
    return {
        "broken": ", ".join(sorted(broken)),
        "failures": ", ".join(failures) or "no failure",
        **_environment(evaluation.concrete, log_path),
        "robustness": min(broken.values()),
        "min_clearance_m": evaluation.min_clearance_m,
        "trajectory": trajectory(states),
    }


def triage(store_path: Path) -> Triage:
    """The campaign's violations grouped into failure modes, most frequent first; of a
    differential campaign, its revealing candidates (the subject's flights), grouped also by
    the level they reveal."""
    with Store.existing(store_path) as store:
        differential = store.is_differential()
        by_properties = not differential and bool(store.campaign_config().get("properties"))
        if differential:
            found = sorted(store.revealing_cases(), key=lambda e: (e.run_id, e.ordinal))
        elif by_properties:
            found = [e for e in store.all_evaluations() if broken_properties(e)]
        else:
            found = store.evaluations_with(Status.VIOLATION)
    keys = ("reveals", *MODE_KEYS) if differential else PROPERTY_MODE_KEYS if by_properties else MODE_KEYS
    violations: list[_Violation] = []
    skipped: list[dict[str, Any]] = []
    seen = set()
    for evaluation in found:
        if evaluation.vector_key in seen:
            continue
        seen.add(evaluation.vector_key)
        if not evaluation.log_path or not Path(evaluation.log_path).is_file():
            skipped.append(_skipped(evaluation, "its log is missing"))
            continue
        try:
            seen_in_log = property_features(evaluation) if by_properties else features(Path(evaluation.log_path))
            violations.append(_Violation(evaluation, {"reveals": evaluation.reveals, **seen_in_log}))
        except InputError as error:
            skipped.append(_skipped(evaluation, str(error)))
    modes: dict[tuple, list[_Violation]] = {}
    for violation in violations:
        modes.setdefault(tuple(violation.features[key] for key in keys), []).append(violation)
    described = []
    for key, members in sorted(modes.items(), key=lambda item: (-len(item[1]), item[0])):
        worst = min(members, key=lambda v: v.severity)
        typical = min(members, key=lambda v: sum(trajectory_distance(v.features["trajectory"], o.features["trajectory"]) for o in members))
        fields = dict(zip(keys, key))
        contacts = sum(v.features["min_clearance_m"] is not None and v.features["min_clearance_m"] <= 0.0 for v in members)
        # A property's finding need not have come near an obstacle: its near misses are those inside the safety distance.
        near_misses = (sum(v.evaluation.status == Status.VIOLATION for v in members) - contacts) if by_properties else len(members) - contacts
        name = (f"breaks {fields['broken']}: {fields['failures']}, {fields['wind']}, {fields['visibility']}" if by_properties
                else (f"reveals {fields['reveals']}: " if differential else "") + mode_name(fields))
        described.append(FailureMode(name, fields, len(members), contacts, near_misses, worst.example(), typical.example()))
    pairs = list(itertools.combinations([v.features["trajectory"] for v in violations], 2))
    return Triage(str(store_path), len(violations), tuple(described), tuple(skipped), differential,
                  float(np.mean([trajectory_distance(a, b) for a, b in pairs])) if pairs else None, by_properties)


def _skipped(evaluation: StoredEvaluation, why: str) -> dict[str, Any]:
    return {"id": evaluation.id, "scenario": evaluation.scenario, "scenario_file": evaluation.scenario_file, "algorithm": evaluation.algorithm,
            "run": evaluation.run_index, "fitness": evaluation.fitness, "log": evaluation.log_path,
            "reveals": evaluation.reveals, "why": why}


def triage_text(report: Triage) -> str:
    spread = report.mean_pairwise_trajectory_distance_m
    what = ("revealing candidates (differential campaign)" if report.differential else "flights breaking a property" if report.by_properties
            else "violations")
    lines = [f"{report.violations} distinct {what} in {len(report.modes)} failure modes; mean pairwise trajectory distance "
             + (f"{spread:.1f} m" if spread is not None else "-")]
    for mode in report.modes:
        lines.append(f"{mode.count:>4}  {mode.mode}" + ("" if report.by_properties else f"  ({mode.contacts} contact, {mode.near_misses} near miss)"))
        lines.append(f"      worst: evaluation {mode.worst.id}, {_severity(mode.worst)}, {mode.worst.log}")
        lines.append(f"      typical: evaluation {mode.typical.id}, {_severity(mode.typical)}, {mode.typical.log}")
    for skipped in report.skipped:
        lines.append(f"not triaged: evaluation {skipped['id']} ({skipped['algorithm']} run {skipped['run']}): {skipped['why']}")
    return "\n".join(lines)


def _severity(example: Example) -> str:
    return f"least robustness {example.robustness:.3f}" if example.robustness is not None else f"fitness {example.fitness:.3f}"
