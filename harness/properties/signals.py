"""The signals a property speaks of, as time series on one time base, from a flight's recording:
the simulator's (the bridge's, during a flight; the evaluation's log, afterwards) and what the SUT
said on its API link. Both read the same messages, so a property scores a log as it scored the
flight.

The time base is the vehicle state's samples (/uav/state, simulated seconds). The clearance,
recorded at every physics step, is folded into them as the least of the steps since the sample
before, so that the least clearance of the series is the flight's (the fitness f). Flight mode
and arming are the SUT's last heartbeat at or before each sample (PX4's custom modes, ArduCopter's
and the bundled autopilot's, which speaks PX4's); a failure is on from the simulator's "failure"
event for its unit to its "failure_cleared".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from harness.scenario.logical import DATA_LINK
from sim_bridge.spec import WorldSpec
from simlink.failures import UNIT_BY_NAME

# Every unit a scenario fails: the sensors, and the ground station's data link.
FAILING_UNITS = (*UNIT_BY_NAME, DATA_LINK)

Recorded = Callable[[Sequence[str]], Iterable[tuple[str, int, Any]]]


@dataclass(frozen=True)
class Signal:
    unit: str
    meaning: str


MODES = ("manual", "altitude", "position", "hold", "mission", "takeoff", "land", "rtl")
# PX4's custom_mode: main mode in bits 16-23, sub mode in bits 24-31 (px4_custom_mode.h). PX4's
# Descend (the position-loss failsafe) reports itself as AUTO/LAND.
PX4_MAIN = {1: "manual", 2: "altitude", 3: "position", 5: "manual", 7: "manual", 8: "manual"}
PX4_AUTO = 4
PX4_AUTO_SUB = {2: "takeoff", 3: "hold", 4: "mission", 5: "rtl", 6: "land", 9: "land"}
ARDUCOPTER = {0: "manual", 1: "manual", 2: "altitude", 3: "mission", 5: "position", 6: "rtl", 9: "land", 16: "position", 17: "hold", 21: "rtl"}
ARMED_FLAG = mavlink.MAV_MODE_FLAG_SAFETY_ARMED


def _failure_signal(unit: str) -> str:
    return "failed_" + unit.replace(" ", "_")


def _loss_signal(unit: str) -> str:
    return "lost_" + unit.replace(" ", "_")


SIGNALS: dict[str, Signal] = {
    "margin_m": Signal("m", "clearance to the nearest obstacle less the safety distance (its least value is the fitness f)"),
    "clearance_m": Signal("m", "distance from the vehicle's body to the nearest obstacle"),
    "altitude_m": Signal("m", "height above the take-off point's ground level"),
    "agl_m": Signal("m", "height above the ground below the vehicle"),
    "speed_m_s": Signal("m/s", "speed over ground, in three dimensions"),
    "horizontal_speed_m_s": Signal("m/s", "horizontal speed"),
    "climb_rate_m_s": Signal("m/s", "vertical speed, up positive"),
    "tilt_deg": Signal("deg", "angle between the vehicle's vertical axis and the vertical"),
    "distance_from_home_m": Signal("m", "horizontal distance from the take-off point"),
    "distance_to_goal_m": Signal("m", "horizontal distance to where the flight is to land (the goal)"),
    "distance_from_route_m": Signal("m", "horizontal distance from the route (take-off point, waypoints, landing point)"),
    "armed": Signal("1/0", "1 while the SUT reports itself armed"),
    **{f"mode_{mode}": Signal("1/0", f"1 while the SUT reports its {mode} mode") for mode in MODES},
    **{_failure_signal(unit): Signal("1/0", f"1 while a failure of the {unit} is injected") for unit in FAILING_UNITS},
    **{_loss_signal(unit): Signal("1/0", f"1 while an injected failure stops the {unit}'s readings altogether (type off)") for unit in FAILING_UNITS},
}


@dataclass(frozen=True)
class Series:
    """Every signal of SIGNALS sampled at `time_s`."""

    time_s: np.ndarray
    values: Mapping[str, np.ndarray]

    @property
    def period_s(self) -> float:
        return float(np.median(np.diff(self.time_s))) if len(self.time_s) > 1 else 0.0


def extract(recorded: Recorded, api_from_sut: Iterable[tuple[int, bytes]], world: WorldSpec) -> Series:
    """The signals of a recording (recorded(topics): its messages) and the SUT's API datagrams
    with their simulated time in ns."""
    states = [message for _topic, _ns, message in recorded(["/uav/state"])]
    time_s = np.array([s["t"] for s in states], dtype=float)
    north = np.array([s["north_m"] for s in states], dtype=float)
    east = np.array([s["east_m"] for s in states], dtype=float)
    velocity = np.array([s["v_ned_m_s"] for s in states], dtype=float).reshape(-1, 3)
    roll, pitch = (np.array([s["rpy_rad"][i] for s in states], dtype=float) for i in (0, 1))
    start = world.uav.start
    # Where fitness.mission_check wants the landing: a pilot lands where its route ends.
    goal = world.mission.waypoints[-1] if world.drive == "pilot" else world.mission.landing or world.mission.waypoints[-1]
    route = [(start.north_m, start.east_m), *((w.north_m, w.east_m) for w in world.mission.waypoints)]
    if world.mission.landing is not None:
        route.append((world.mission.landing.north_m, world.mission.landing.east_m))
    clearance = _folded_clearance(recorded, time_s)
    values = {
        "clearance_m": clearance,
        "margin_m": clearance - world.safety_distance_m,
        "altitude_m": np.array([s["up_m"] for s in states], dtype=float) - start.up_m,
        "agl_m": np.array([s["agl_m"] for s in states], dtype=float),
        "speed_m_s": np.linalg.norm(velocity, axis=1),
        "horizontal_speed_m_s": np.hypot(velocity[:, 0], velocity[:, 1]),
        "climb_rate_m_s": -velocity[:, 2],
        "tilt_deg": np.degrees(np.arccos(np.clip(np.cos(roll) * np.cos(pitch), -1.0, 1.0))),
        "distance_from_home_m": np.hypot(north - start.north_m, east - start.east_m),
        "distance_to_goal_m": np.hypot(north - goal.north_m, east - goal.east_m),
        "distance_from_route_m": _distance_from_polyline(north, east, route),
        **_heartbeat_signals(api_from_sut, time_s),
        **_failure_signals(recorded, time_s),
    }
    return Series(time_s, values)


def _folded_clearance(recorded: Recorded, time_s: np.ndarray) -> np.ndarray:
    """The least clearance of the steps up to each state sample since the one before (steps after
    the last sample go to it); where no step was recorded, the one before's (or no obstacle)."""
    steps_t, steps_d = [], []
    for _topic, _ns, batch in recorded(["/clearance"]):
        for t, d in zip(batch["t"], batch["d"]):
            if d is not None:
                steps_t.append(t)
                steps_d.append(d)
    folded = np.full(len(time_s), math.inf)
    if not len(time_s) or not steps_t:
        return folded
    slots = np.minimum(np.searchsorted(time_s, np.array(steps_t), side="left"), len(time_s) - 1)
    np.minimum.at(folded, slots, np.array(steps_d))
    for i in range(1, len(folded)):
        if math.isinf(folded[i]) and not math.isinf(folded[i - 1]):
            folded[i] = folded[i - 1]
    return folded


def _distance_from_polyline(north: np.ndarray, east: np.ndarray, route: list[tuple[float, float]]) -> np.ndarray:
    points = np.stack([north, east], axis=1)
    if len(route) == 1:
        return np.linalg.norm(points - np.array(route[0]), axis=1)
    best = np.full(len(points), math.inf)
    for a, b in zip(route, route[1:]):
        a, b = np.array(a), np.array(b)
        span = b - a
        length2 = float(span @ span)
        along = np.clip(((points - a) @ span) / length2, 0.0, 1.0) if length2 > 0 else np.zeros(len(points))
        best = np.minimum(best, np.linalg.norm(points - (a + along[:, None] * span), axis=1))
    return best


def mode_of(heartbeat: Any) -> str | None:
    """The MODES name of a heartbeat's custom mode (None: a mode not among them)."""
    if heartbeat.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA:
        return ARDUCOPTER.get(heartbeat.custom_mode)
    main, sub = (heartbeat.custom_mode >> 16) & 0xFF, (heartbeat.custom_mode >> 24) & 0xFF
    return PX4_AUTO_SUB.get(sub) if main == PX4_AUTO else PX4_MAIN.get(main)


def _heartbeat_signals(api_from_sut: Iterable[tuple[int, bytes]], time_s: np.ndarray) -> dict[str, np.ndarray]:
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    changes: list[tuple[float, str | None, bool]] = []
    for time_ns, datagram in api_from_sut:
        for message in parser.parse_buffer(datagram) or []:
            if message.get_type() == "HEARTBEAT" and message.type != mavlink.MAV_TYPE_GCS:
                changes.append((time_ns / 1e9, mode_of(message), bool(message.base_mode & ARMED_FLAG)))
    values = {f"mode_{mode}": np.zeros(len(time_s)) for mode in MODES}
    values["armed"] = np.zeros(len(time_s))
    if changes:
        at = np.array([c[0] for c in changes])
        latest = np.searchsorted(at, time_s, side="right") - 1
        for i, index in enumerate(latest):
            if index >= 0:
                _t, mode, armed = changes[index]
                values["armed"][i] = float(armed)
                if mode is not None:
                    values[f"mode_{mode}"][i] = 1.0
    return values


def _failure_signals(recorded: Recorded, time_s: np.ndarray) -> dict[str, np.ndarray]:
    values = {name(unit): np.zeros(len(time_s)) for unit in FAILING_UNITS for name in (_failure_signal, _loss_signal)}
    # A unit is failed while any of its failures is on: a rig's sensors fail one by one (the
    # event's "sensor"), each cleared on its own.
    failing: dict[str, set] = {}
    lost: dict[str, set] = {}
    for _topic, _ns, event in recorded(["/events"]):
        if event.get("event") in ("failure", "failure_cleared"):
            detail = event["detail"]
            unit, which = detail["unit"], detail.get("sensor")
            if _failure_signal(unit) not in values:
                continue
            if event["event"] == "failure":
                failing.setdefault(unit, set()).add(which)
                if detail.get("type") == "off":
                    lost.setdefault(unit, set()).add(which)
            else:
                failing.get(unit, set()).discard(which)
                lost.get(unit, set()).discard(which)
            values[_failure_signal(unit)][time_s >= event["t"]] = 1.0 if failing.get(unit) else 0.0
            values[_loss_signal(unit)][time_s >= event["t"]] = 1.0 if lost.get(unit) else 0.0
    return values

