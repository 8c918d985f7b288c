"""`stella explain`: why a flight came as close as it did, from its log alone.

The log holds the world (obstacles and their motion, the range sensor's reach and field of view,
or the sensors of the vehicle's rig, wind, gust and failures), the ground truth every physics
step, what the range sensor delivered to the SUT (/sensor/obstacle_distance, or each rig
sensor's /sensor/rig/NAME, measured its latency before the SUT got it: what the SUT's collision
prevention got, after any failure), the wind the vehicle flew in (/wind), the pilot's sticks
(/pilot) and the run's events. From these, at the closest approach to its obstacle, the timeline:

* in view: the obstacle first inside the sensor's field of view and reach (with a rig, met by a
  ray of any of its sensors within that sensor's reach), computed from the world as an ideal
  sensor would see it (the final sighting: an earlier glimpse that was lost again does not count);
* reported: the first delivered reading that shows it (a sector holding a distance no farther
  than the ideal one); a failed sensor delivers nothing, or values that do not show it;
* entered: the clearance fell below the safety distance; closest: the least clearance.

and the mechanism, the first of these that holds (docs/explain.md argues each):

* outrun: over the final approach the obstacle's own motion closed the gap faster than the
  vehicle's (collision prevention does not predict moving obstacles);
* unseen: never reported before the closest approach; why: the sensor had failed, the obstacle
  was never inside the field of view, or never within reach;
* seen_late: reported closer than the vehicle needed to stop from its speed towards it then;
* pushed: reported in time and the vehicle slowed down, yet at the entry into the safety distance
  the air moved towards the obstacle faster than the vehicle did: wind or gust carried it in;
* braked_too_little: reported in time, nothing pushed, and the vehicle itself flew in;
* other: none of these (a vehicle drifting in without wind, no obstacle at the closest point).

A flight that kept the safety distance has mechanism "none".

The stopping distance is the bundled autopilot's (PX4's jerk-limited stop plus CP_DIST and
CP_DELAY at the current speed) with the SUT's parameters from the log's `sut` metadata, else
the bundled defaults; the report names which values it assumed.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from harness.errors import InputError, Problem
from harness.flight import logs
from harness.flight.fitness import min_clearance
from harness.campaigns.approach import Geometry, Moment
from sim_bridge.obstacles import Obstacle, ray_distances
from sim_bridge.recording import RIG_TOPIC

MECHANISMS = ("unseen", "seen_late", "braked_too_little", "outrun", "pushed", "other", "none")
# A delivered sector shows the obstacle when it is no farther than the ideal reading by more
# than the vehicle moves between a reading and the pose it is compared with (25 Hz states).
SHOWS_TOLERANCE_M = 0.5
# Readings or views apart by more than this belong to different sightings: collision prevention
# drops range data this old (autopilot/collision.py STALE_AFTER_S).
SIGHTING_GAP_S = 0.5
SLOWED_M_S = 0.5  # for the timeline only: a drop in speed towards the obstacle that is braking, not jitter
TOPICS = ["/clearance", "/uav/state", "/events", "/sensor/obstacle_distance", "/wind", "/pilot"]
FINAL_APPROACH_S = 1.0  # before entering the safety distance: who closed the gap
# The parameters a SUT's collision prevention plans its stop with (distance kept, reaction delay,
# braking acceleration, jerk), with the defaults its adapter flies, for the SUTs stella starts:
# PX4's names and the bundled autopilot's defaults (autopilot/params.py) for every SUT but
# ArduPilot, whose simple avoidance keeps AVOID_MARGIN (1 m as sut_adapter/ardupilot.py sets it)
# and brakes at up to AVOID_ACCEL_MAX, without a delay or a jerk limit of its own.
LIMIT_PARAMS: dict[str, dict[str, tuple[str, float] | None]] = {
    "px4": {"distance": ("CP_DIST", 1.0), "delay": ("CP_DELAY", 0.4), "acc": ("MPC_ACC_HOR", 3.0), "jerk": ("MPC_JERK_AUTO", 4.0)},
    "ardupilot": {"distance": ("AVOID_MARGIN", 1.0), "delay": None, "acc": ("AVOID_ACCEL_MAX", 3.0), "jerk": None},
}
# The parameter and value that switch a SUT's collision prevention off where its kept distance
# does not (PX4's CP_DIST below 0 does).
OFF_PARAMS: dict[str, tuple[str, float]] = {"ardupilot": ("AVOID_ENABLE", 0.0)}
# Real firmware whose collision prevention does not act in missions: there the vehicle does not
# brake for what it senses at all, whatever the parameters (the bundled autopilot's does act).
NOT_IN_MISSIONS = {
    "px4": "PX4's collision prevention acts only in Position mode, not in missions",
    "ardupilot": "ArduPilot's simple avoidance acts in Loiter, AltHold and Guided, not in Auto; its path planner (OA_TYPE) steers, it does not brake",
}
UNITS = {"distance": "m", "delay": "s", "acc": "m/s^2", "jerk": "m/s^3"}


@dataclass(frozen=True)
class Limits:
    cp_dist_m: float  # negative: collision prevention off
    cp_delay_s: float
    acc_m_s2: float
    jerk_m_s3: float  # inf: no jerk limit
    assumed: tuple[str, ...]  # the parameters taken from the defaults, not from the log
    named: tuple[tuple[str, str], ...] = ()  # (the SUT's parameter, which limit) for the limits it has
    inactive: str | None = None  # why collision prevention does not act in this flight's drive

    @classmethod
    def of(cls, sut: Mapping[str, Any] | None, drive: str = "pilot") -> "Limits":
        params = dict((sut or {}).get("params") or {})
        name = str((sut or {}).get("name"))
        kind = LIMIT_PARAMS.get(name, LIMIT_PARAMS["px4"])
        value = {"distance": 0.0, "delay": 0.0, "acc": math.inf, "jerk": math.inf}
        for limit, named in kind.items():
            if named is not None:
                value[limit] = float(params.get(named[0], named[1]))
        off = OFF_PARAMS.get(name)
        inactive = NOT_IN_MISSIONS.get(name) if drive == "mission" else None
        if inactive is not None or (off is not None and off[0] in params and float(params[off[0]]) == off[1]):
            value["distance"] = -1.0
        named = tuple((named[0], limit) for limit, named in kind.items() if named is not None)
        return cls(value["distance"], value["delay"], value["acc"], value["jerk"], tuple(name for name, _ in named if name not in params), named,
                   inactive)

    @property
    def distance_name(self) -> str:
        return next(name for name, limit in self.named if limit == "distance")

    def stopping_distance_m(self, speed_m_s: float) -> float:
        """From a reading to standing still the kept distance before the obstacle: the delay
        flown at this speed, then PX4's jerk-limited stop (the inverse of
        math::computeMaxSpeedFromDistance; without a jerk limit, v^2 / 2a). With collision
        prevention off the same stop to the obstacle itself."""
        v = max(0.0, speed_m_s)
        braking = (v * v + v * 4.0 * self.acc_m_s2 ** 2 / self.jerk_m_s3) / (2.0 * self.acc_m_s2)
        return max(0.0, self.cp_dist_m) + self.cp_delay_s * v + braking

    def describe(self) -> str:
        if self.inactive is not None:
            return f"no stop: {self.inactive}"
        value = {"distance": self.cp_dist_m, "delay": self.cp_delay_s, "acc": self.acc_m_s2, "jerk": self.jerk_m_s3}
        assumed = f" (assumed defaults: {', '.join(self.assumed)})" if self.assumed else ""
        return ", ".join(f"{name} {value[limit]} {UNITS[limit]}" for name, limit in self.named) + assumed

    @property
    def kept(self) -> str:
        """What the SUT keeps from an obstacle, for the evidence."""
        if self.inactive is not None:
            return self.inactive
        return "collision prevention off" if self.cp_dist_m < 0 else f"{self.distance_name} {self.cp_dist_m:.2f} m"


def _sightings(times: Sequence[float]) -> list[tuple[float, float]]:
    """Times grouped into (first, last) runs without a gap longer than SIGHTING_GAP_S."""
    runs: list[tuple[float, float]] = []
    for t in times:
        if runs and t - runs[-1][1] <= SIGHTING_GAP_S:
            runs[-1] = (runs[-1][0], t)
        else:
            runs.append((t, t))
    return runs


def _final_sighting_start(times: Sequence[float]) -> float | None:
    runs = _sightings(times)
    return runs[-1][0] if runs else None


def _nearest(states: Sequence[Mapping[str, Any]], times: Sequence[float], t: float) -> Mapping[str, Any]:
    index = min(bisect.bisect_left(times, t), len(states) - 1)
    if index > 0 and abs(times[index - 1] - t) < abs(times[index] - t):
        index -= 1
    return states[index]


def _first_report(readings: Sequence[Mapping[str, Any]], geometry: Geometry, states: Sequence[Mapping[str, Any]], times: Sequence[float],
                  run_start_s: float, t_closest: float) -> tuple[float | None, float | None]:
    """When the final sighting in the delivered readings (the profile's sensor's, or each rig
    sensor's, in the order the SUT got them) began, and the distance they showed then."""
    shown = []
    for reading in readings:
        delivered_t = reading.get("delivered_t", reading["t"])
        if not run_start_s <= delivered_t <= t_closest:
            continue
        state = _nearest(states, times, reading["t"])
        if "sensor" in reading:  # a rig sensor's reading: sectors, or one over its field of view
            name = reading["sensor"]
            values = reading["distances_cm"] if "distances_cm" in reading else [reading["distance_cm"]]
            ideal = {index: distance for (sensor, index), distance in geometry.ideal_readings(state).items() if sensor == name}
        else:
            values, ideal = reading["distances_cm"], geometry.ideal_sectors(state)
        # Beyond range_m is "nothing in reach" (and 65535 no reading): never a sighting.
        delivered = {i: values[i] / 100.0 for i in ideal if values[i] / 100.0 <= reading["range_m"]}
        seen = [value for i, value in delivered.items() if value <= ideal[i] + SHOWS_TOLERANCE_M]
        if seen:
            shown.append((delivered_t, min(seen)))
    started = _final_sighting_start([t for t, _d in shown])
    return started, next((d for t, d in shown if t == started), None)


def _active(events: Sequence[Mapping[str, Any]], t: float, run_start_s: float) -> dict[str, Any]:
    """The failures in force and the gust blowing at simulation time t."""
    failures: dict[tuple[str, str], float] = {}
    gust = None
    for event in events:
        if event["t"] > t:
            break
        detail = event.get("detail") or {}
        if event["event"] == "failure":
            failures[(detail["unit"], detail["type"])] = event["t"]
        elif event["event"] == "failure_cleared":
            failures.pop((detail["unit"], detail["type"]), None)
        elif event["event"] == "gust" and t - event["t"] <= detail.get("duration_s", 0.0):
            gust = {**detail, "onset_s": event["t"] - run_start_s}
    return {"failures": [{"unit": unit, "type": kind, "since_s": round(since - run_start_s, 3)} for (unit, kind), since in failures.items()],
            "gust": gust}


def _drive(world: Any, state: Mapping[str, Any], pilot: Mapping[str, Any] | None, towards: tuple[float, float, float], obstacle: Obstacle) -> dict[str, Any]:
    """What the drive asked at this instant, and whether it led into the obstacle."""
    n, e = state["north_m"], state["east_m"]
    if world.drive == "pilot" and pilot is not None:
        yaw = state["rpy_rad"][2]
        fwd, right = pilot["pitch"], pilot["roll"]
        stick_n, stick_e = fwd * math.cos(yaw) - right * math.sin(yaw), fwd * math.sin(yaw) + right * math.cos(yaw)
        into = stick_n * towards[0] + stick_e * towards[1]
        return {"drive": "pilot", "stick_towards_obstacle": round(into, 3), "stick": round(math.hypot(stick_n, stick_e), 3),
                "phase": pilot.get("phase"), "into_obstacle": into > 0.0}
    route = [(world.uav.start.north_m, world.uav.start.east_m)] + [(w.north_m, w.east_m) for w in world.mission.waypoints]
    legs = list(zip(route, route[1:]))
    if not legs:
        return {"drive": world.drive, "leg": None, "into_obstacle": False}

    def off_leg(leg) -> float:
        (an, ae), (bn, be) = leg
        length2 = (bn - an) ** 2 + (be - ae) ** 2 or 1e-9
        f = min(1.0, max(0.0, ((n - an) * (bn - an) + (e - ae) * (be - ae)) / length2))
        return math.hypot(n - an - f * (bn - an), e - ae - f * (be - ae))

    index = min(range(len(legs)), key=lambda i: off_leg(legs[i]))
    (_an, _ae), (bn, be) = legs[index]
    remaining = math.hypot(bn - n, be - e)
    cut = obstacle.cross_section(state["up_m"])
    into = False
    if cut is not None and remaining > 1e-6:
        along = ray_distances(n, e, np.array([math.atan2(be - e, bn - n)]), cut)[0]
        into = bool(along <= remaining)
    return {"drive": world.drive, "leg": index + 1, "leg_to": {"north_m": bn, "east_m": be}, "remaining_m": round(remaining, 2),
            "into_obstacle": into}


def explain(path: Path) -> dict[str, Any]:
    """The causal timeline of the log's closest approach and its mechanism, with the numbers."""
    world = logs.world_of(path)
    if world is None:
        raise InputError([Problem(str(path), "", "no world metadata: not an evaluation log of this tool (give a log of `stella run` or a campaign)")])
    recorded, readings = _recorded(path, world)
    clearance = min_clearance(recorded["/clearance"])
    states, events = recorded["/uav/state"], recorded["/events"]
    run_start_s = next((e["t"] for e in events if e["event"] == "run"), states[0]["t"] if states else 0.0)
    base = {"log": str(path), "scenario": world.scenario, "safety_distance_m": world.safety_distance_m,
            "min_clearance_m": clearance.min_clearance_m, "obstacle": clearance.obstacle}
    if not states or clearance.obstacle is None or clearance.at_s is None:
        return {**base, "mechanism": "other", "evidence": ["no obstacle at the closest approach (or no trajectory in the log)"], "timeline": []}
    spec = next((o for o in world.obstacles if o["id"] == clearance.obstacle), None)
    if spec is None:
        return {**base, "mechanism": "other", "evidence": [f"{clearance.obstacle} is not in the world spec: an injection added it"], "timeline": []}
    sut = logs.json_metadata(path, "sut") or {}
    limits = Limits.of(sut, world.drive)
    geometry = Geometry(world, spec, run_start_s)
    times = [s["t"] for s in states]
    t_closest = clearance.at_s
    flown = [s for s in states if run_start_s <= s["t"] <= t_closest]
    moments = [geometry.moment(s) for s in flown]
    in_view_at = _final_sighting_start([m.t_s for m in moments if m.in_view])
    reported_at, reported_distance = _first_report(sorted(readings, key=lambda r: r.get("delivered_t", r["t"])), geometry, states, times, run_start_s,
                                                   t_closest)
    if reported_at is not None and (in_view_at is None or reported_at < in_view_at):
        # A reading that shows it was taken in view: the poses, 25 a second, fell either side of it.
        in_view_at = reported_at
    entered_at = _entry(recorded["/clearance"], world.safety_distance_m, t_closest)
    wind = {m["t"]: m["wind_ned_m_s"] for m in recorded["/wind"]}
    pilots = recorded["/pilot"]

    def at(t: float) -> Moment:
        return geometry.moment(_nearest(states, times, t))

    def wind_towards(t: float, towards: tuple[float, float, float]) -> tuple[float, list[float]]:
        if wind:
            keys = sorted(wind)
            air = wind[keys[min(bisect.bisect_left(keys, t), len(keys) - 1)]]
        else:
            air = [world.atmosphere.wind_north_m_s, world.atmosphere.wind_east_m_s, 0.0]
        return air[0] * towards[0] + air[1] * towards[1] - air[2] * towards[2], air

    closest = at(t_closest)
    first = at(reported_at) if reported_at is not None else None
    needed = limits.stopping_distance_m(first.own_closing_m_s) if first else None
    window = [m for m in moments if m.t_s >= (entered_at if entered_at is not None else t_closest) - FINAL_APPROACH_S]
    own_final = float(np.mean([m.own_closing_m_s for m in window])) if window else closest.own_closing_m_s
    obstacle_final = float(np.mean([m.obstacle_closing_m_s for m in window])) if window else closest.obstacle_closing_m_s
    entry = at(entered_at) if entered_at is not None else closest
    wind_in, air = wind_towards(entry.t_s, entry.towards)
    pilot_then = None
    if pilots:
        pilot_then = pilots[min(bisect.bisect_left([p["t"] for p in pilots], t_closest), len(pilots) - 1)]
    situation = _active(events, t_closest, run_start_s)
    context = {
        "drive": _drive(world, _nearest(states, times, t_closest), pilot_then, closest.towards, geometry.placed(t_closest)),
        "obstacle_kind": spec.get("kind"), "obstacle_form": spec.get("form"),
        "obstacle_velocity_m_s": [round(v, 3) for v in geometry.velocity(t_closest).tolist()],
        "wind_ned_m_s": [round(v, 3) for v in air], "wind_towards_obstacle_m_s": round(wind_in, 3), **situation,
        "sut": {"name": sut.get("name"), "fault": sut.get("fault"), "params": dict(sut.get("params") or {})},
        "limits": {**asdict(limits), "jerk_m_s3": limits.jerk_m_s3 if math.isfinite(limits.jerk_m_s3) else None,  # JSON has no infinity
                   "assumed": list(limits.assumed), "named": [list(pair) for pair in limits.named], "described": limits.describe()},
        "sensor": ({"rig": [{"name": s.name, "message": s.message, "range_m": s.range_m, "fov_deg": s.fov_deg} for s in world.rig]}
                   if world.rig else {"range_m": world.sensor.range_m, "fov_deg": world.sensor.fov_deg}),
    }
    numbers = {
        "own_closing_at_report_m_s": first.own_closing_m_s if first else None, "distance_at_report_m": reported_distance,
        "stopping_distance_needed_m": needed, "own_closing_at_entry_m_s": entry.own_closing_m_s,
        "own_closing_final_m_s": own_final, "obstacle_closing_final_m_s": obstacle_final, "wind_towards_obstacle_at_entry_m_s": wind_in,
    }
    mechanism, evidence = _classify(clearance.min_clearance_m, world, moments, in_view_at, reported_at, numbers, situation, limits)
    # The SUT's reaction as its flight shows it (the bundled autopilot publishes no collision
    # prevention state): its speed towards the obstacle first SLOWED_M_S below that at the report.
    slowed_at = next((m.t_s for m in moments if first is not None and m.t_s > first.t_s
                      and m.own_closing_m_s < first.own_closing_m_s - SLOWED_M_S), None)
    timeline = [entry_ for entry_ in (
        ("run", run_start_s, None),
        ("in view", in_view_at, at(in_view_at).distance_m if in_view_at is not None else None),
        ("reported to the SUT", reported_at, reported_distance),
        ("the vehicle slowed towards it", slowed_at, at(slowed_at).distance_m if slowed_at is not None else None),
        ("entered the safety distance", entered_at, None),
        ("closest approach", t_closest, clearance.min_clearance_m),
    ) if entry_[1] is not None]
    return {
        **base, "status": (logs.json_metadata(path, "result") or {}).get("status"), "mechanism": mechanism, "evidence": evidence,
        "timeline": [{"what": what, "t_s": round(t, 3), "run_time_s": round(t - run_start_s, 3),
                      **({"distance_m": round(d, 3)} if d is not None else {})} for what, t, d in sorted(timeline, key=lambda e: e[1])],
        "numbers": {key: None if value is None else round(value, 3) for key, value in numbers.items()}, "context": context,
    }


def _recorded(path: Path, world: Any) -> tuple[dict[str, list[Any]], list[Mapping[str, Any]]]:
    """The log's messages of TOPICS by topic, and the range readings the SUT got (the profile
    sensor's, or each rig sensor's with the time it was delivered)."""
    rig_topics = [f"{RIG_TOPIC}{sensor.name}" for sensor in world.rig or ()]
    latency_s = {sensor.name: sensor.latency_s for sensor in world.rig or ()}
    recorded: dict[str, list[Any]] = {topic: [] for topic in TOPICS}
    readings: list[Mapping[str, Any]] = []
    # One pass: each pass over a log decompresses every chunk, whichever topics it wants.
    for topic, _ns, message in logs.messages(path, TOPICS + rig_topics):
        if topic.startswith(RIG_TOPIC):
            # A rig reading is recorded when it was measured and reaches the SUT its latency later.
            name = topic[len(RIG_TOPIC):]
            readings.append({**message, "sensor": name, "delivered_t": message["t"] + latency_s[name]})
        else:
            recorded[topic].append(message)
    return recorded, readings if rig_topics else recorded["/sensor/obstacle_distance"]


def _entry(batches: Sequence[Mapping[str, Any]], safety_distance_m: float, t_closest: float) -> float | None:
    """The last time before the closest approach that the clearance fell below the safety distance."""
    entered, outside = None, True
    for batch in batches:
        for t, d in zip(batch["t"], batch["d"]):
            if t > t_closest:
                return entered
            inside = d is not None and d < safety_distance_m
            if inside and outside:
                entered = t
            outside = not inside
    return entered


def _classify(min_clearance_m: float, world: Any, moments: Sequence[Moment], in_view_at: float | None, reported_at: float | None,
              numbers: Mapping[str, Any], situation: Mapping[str, Any], limits: Limits) -> tuple[str, list[str]]:
    s = world.safety_distance_m
    if min_clearance_m >= s:
        return "none", [f"least clearance {min_clearance_m:.2f} m kept the safety distance {s:.2f} m"]
    own, theirs = numbers["own_closing_final_m_s"], numbers["obstacle_closing_final_m_s"]
    if theirs > 0.0 and theirs > own:
        return "outrun", [f"over the final approach the obstacle closed at {theirs:.2f} m/s, the vehicle at {own:.2f} m/s "
                          "(collision prevention does not predict a moving obstacle)"]
    sensor_failed = [f for f in situation["failures"] if f["unit"] == "distance sensor"]
    if world.rig:
        reach_m = max(sensor.range_m for sensor in world.rig)
        reach, field_of_view = f"the rig's reach of {reach_m:.1f} m", "any rig sensor's field of view"
    else:
        reach_m = world.sensor.range_m
        reach, field_of_view = f"the sensor's reach of {reach_m:.1f} m", f"the {world.sensor.fov_deg:.0f} degree field of view"
    if reported_at is None:
        if in_view_at is not None and sensor_failed:
            why = f"the range sensor had failed ({sensor_failed[0]['type']} since run time {sensor_failed[0]['since_s']:.1f} s)"
        elif in_view_at is not None:
            why = "it was in view but no delivered reading showed it"
        elif all(m.distance_m is None for m in moments):
            why = "it was never at the height the sensor scans: it passed above or below it"
        elif any(m.distance_m is not None and m.distance_m <= reach_m for m in moments):
            why = f"it was within reach but never inside {field_of_view}"
        elif moments[-1].distance_m is None:
            why = f"it passed above or below it; at the height the sensor scans it never came within {reach}"
        else:
            why = f"it never came within {reach}"
        seen = f"while in view from run time {in_view_at - moments[0].t_s:.1f} s" if in_view_at is not None and moments else "it was never in view"
        return "unseen", [f"never reported to the SUT before the closest approach: {why}", seen]
    distance, needed, first = numbers["distance_at_report_m"], numbers["stopping_distance_needed_m"], numbers["own_closing_at_report_m_s"]
    if distance < needed:
        return "seen_late", [f"first reported {distance:.2f} m away at {first:.2f} m/s towards it; stopping needed {needed:.2f} m"] + (
            [limits.inactive] if limits.inactive else [])
    in_time = f"first reported {distance:.2f} m away at {first:.2f} m/s towards it; stopping needed only {needed:.2f} m"
    entry, wind_in = numbers["own_closing_at_entry_m_s"], numbers["wind_towards_obstacle_at_entry_m_s"]
    if entry < first and wind_in > 0.0 and wind_in >= entry:
        gust = situation["gust"]
        carried = f"gust of {gust['amplitude_m_s']:.1f} m/s from {gust['from_deg']:.0f} deg" if gust else "wind"
        return "pushed", [in_time, f"the vehicle slowed from {first:.2f} to {entry:.2f} m/s towards it, but the air moved towards it at "
                          f"{wind_in:.2f} m/s when the safety distance was entered ({carried})"]
    if own > 0.0:
        return "braked_too_little", [in_time, f"the vehicle itself still closed at {entry:.2f} m/s when it entered the safety distance "
                                     f"({own:.2f} m/s over the final approach); {limits.kept}"]
    return "other", [in_time, f"neither the vehicle ({own:.2f} m/s), the obstacle ({theirs:.2f} m/s) nor the wind ({wind_in:.2f} m/s) "
                     "closed the gap over the final approach"]


def explain_text(report: Mapping[str, Any]) -> str:
    lines = [f"{report['log']}: {report['scenario']}",
             f"closest approach {report['min_clearance_m']:.2f} m to {report['obstacle']} (safety distance {report['safety_distance_m']:.2f} m)",
             f"mechanism: {report['mechanism']}"]
    lines += [f"  because {line}" for line in report["evidence"]]
    if report["timeline"]:
        lines.append("timeline (run time):")
        for entry in report["timeline"]:
            distance = f"  {entry['distance_m']:.2f} m" if "distance_m" in entry else ""
            lines.append(f"  {entry['run_time_s']:8.2f} s  {entry['what']}{distance}")
    context = report.get("context")
    if context:
        drive = context["drive"]
        asked = (f"pilot stick {drive['stick']:.2f}, {drive['stick_towards_obstacle']:+.2f} towards the obstacle" if drive["drive"] == "pilot"
                 else f"mission leg {drive.get('leg')}" + (", straight into the obstacle" if drive["into_obstacle"] else ", not into the obstacle"))
        lines.append(f"at the closest approach: drive {asked}; obstacle {context['obstacle_kind']} {context['obstacle_form']} moving "
                     f"{math.hypot(*context['obstacle_velocity_m_s'][:2]):.2f} m/s; wind {math.hypot(*context['wind_ned_m_s'][:2]):.2f} m/s "
                     f"({context['wind_towards_obstacle_m_s']:+.2f} towards it)" + (f"; gust {context['gust']['amplitude_m_s']:.1f} m/s" if context["gust"] else ""))
        failures = ", ".join(f"{f['unit']} {f['type']} since {f['since_s']:.1f} s" for f in context["failures"]) or "none"
        lines.append(f"failures active: {failures}")
        sut = context["sut"]
        lines.append(f"SUT: {sut['name']}" + (f", seeded fault {sut['fault']}" if sut["fault"] else "")
                     + (f", parameters {', '.join(f'{k}={v}' for k, v in sut['params'].items())}" if sut["params"] else ""))
        lines.append(f"stopping model: {context['limits']['described']}")
    return "\n".join(lines)
