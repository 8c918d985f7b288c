"""QGroundControl `.plan` missions: checked item by item with located errors, and turned into the
mission the harness flies and scores, in the local frame whose origin is the plan's home.

A plan's SimpleItems are uploaded as they are (command, frame, params, position), as
QGroundControl uploads them, so PX4 sees the mission its user planned. Supported: takeoff,
waypoint (hold time, acceptance radius), land (at a position or where the vehicle is), return to
launch, change speed and delay, with altitudes relative to home (frame 3) or above mean sea level
(frame 0). A plan without a waypoint flies to its land item's position, as PX4 does: that
position is its goal.

Everything else is refused with the item's location, rather than flown differently from what the
plan says, and each refusal says whose it is: PX4's (its mission protocol,
src/modules/mavlink/mavlink_mission.cpp, or its feasibility checker,
src/modules/navigator/MissionFeasibility/) or the simulator's (what it cannot fly or score as
planned, though PX4 would take it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from pymavlink.dialects.v20.common import (
    MAV_CMD_DO_CHANGE_SPEED, MAV_CMD_NAV_DELAY, MAV_CMD_NAV_LAND, MAV_CMD_NAV_RETURN_TO_LAUNCH, MAV_CMD_NAV_TAKEOFF, MAV_CMD_NAV_WAYPOINT,
    MAV_FRAME_BODY_NED, MAV_FRAME_GLOBAL, MAV_FRAME_GLOBAL_RELATIVE_ALT, MAV_FRAME_GLOBAL_TERRAIN_ALT, MAV_FRAME_LOCAL_NED, MAV_FRAME_MISSION)

from harness.errors import InputError, Problem
from harness.scenario.documents import load_json
from sim_bridge.geo import local_from_geodetic

COMMANDS = {
    MAV_CMD_NAV_TAKEOFF: "takeoff",
    MAV_CMD_NAV_WAYPOINT: "waypoint",
    MAV_CMD_NAV_LAND: "land",
    MAV_CMD_NAV_RETURN_TO_LAUNCH: "return to launch",
    MAV_CMD_DO_CHANGE_SPEED: "change speed",
    MAV_CMD_NAV_DELAY: "delay",
}
POSITION_COMMANDS = (MAV_CMD_NAV_TAKEOFF, MAV_CMD_NAV_WAYPOINT, MAV_CMD_NAV_LAND)
ENDING_COMMANDS = (MAV_CMD_NAV_LAND, MAV_CMD_NAV_RETURN_TO_LAUNCH)
FRAME_NAMES = {MAV_FRAME_GLOBAL: "above mean sea level", MAV_FRAME_MISSION: "mission", MAV_FRAME_GLOBAL_RELATIVE_ALT: "relative to home",
               MAV_FRAME_GLOBAL_TERRAIN_ALT: "above terrain", MAV_FRAME_LOCAL_NED: "local NED", MAV_FRAME_BODY_NED: "body NED"}
ALTITUDE_FRAMES = (MAV_FRAME_GLOBAL, MAV_FRAME_GLOBAL_RELATIVE_ALT)
# The simulated world is a local tangent plane around home, good to centimetres over a few km.
MAX_DISTANCE_FROM_HOME_M = 5000.0
# Where obstacles may be placed around a plan's route (the landforms give their 60 m route 20 m
# before and after it).
AREA_MARGIN_M = 20.0
PX4_REFUSES = " (PX4 refuses it too)"
SIMULATOR_LIMIT = " (a limit of the simulator, not PX4's)"


@dataclass(frozen=True)
class PlanItem:
    """One item as uploaded, with its position in the local frame where it has one."""

    index: int
    command: int
    frame: int
    params: tuple[float, float, float, float]
    lat_deg: float | None
    lon_deg: float | None
    z: float
    north_m: float | None = None
    east_m: float | None = None
    altitude_m: float | None = None  # above home

    @property
    def has_position(self) -> bool:
        return self.north_m is not None


@dataclass(frozen=True)
class Plan:
    file: str
    home: tuple[float, float, float]  # lat_deg, lon_deg, alt_m above mean sea level
    items: tuple[PlanItem, ...]

    @property
    def origin(self) -> dict[str, float]:
        return {"lat_deg": self.home[0], "lon_deg": self.home[1], "alt_m": self.home[2]}

    @property
    def waypoints(self) -> tuple[PlanItem, ...]:
        return tuple(item for item in self.items if item.command == MAV_CMD_NAV_WAYPOINT)

    @property
    def lands(self) -> bool:
        return self.items[-1].command in ENDING_COMMANDS

    @property
    def landing_point(self) -> tuple[float, float]:
        """Where the plan ends: home after a return, the land item's position, or the last
        position flown to before a land item without one."""
        if self.items[-1].command == MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return 0.0, 0.0
        positioned = [item for item in self.items if item.has_position]
        return (positioned[-1].north_m, positioned[-1].east_m) if positioned else (0.0, 0.0)

    @property
    def route(self) -> tuple[tuple[float, float, float, float | None], ...]:
        """north_m, east_m, altitude_m and acceptance radius (None: the default) of each position
        the flight must pass: the waypoints, or in a plan without any, the land item's position,
        which PX4 flies to at the altitude it took off to before it descends."""
        if self.waypoints:
            return tuple((w.north_m, w.east_m, w.altitude_m, w.params[1] if w.params[1] > 0 else None) for w in self.waypoints)
        return (*self.landing_point, self.takeoff_altitude_m, None),

    @property
    def takeoff_altitude_m(self) -> float:
        altitudes = [item.altitude_m for item in self.items if item.command in (MAV_CMD_NAV_TAKEOFF, MAV_CMD_NAV_WAYPOINT)]
        return altitudes[0]

    def area(self) -> dict[str, float]:
        """The rectangle obstacles are placed in: home and every position, with a margin."""
        norths = [0.0] + [item.north_m for item in self.items if item.has_position]
        easts = [0.0] + [item.east_m for item in self.items if item.has_position]
        return {"north_min_m": min(norths) - AREA_MARGIN_M, "north_max_m": max(norths) + AREA_MARGIN_M,
                "east_min_m": min(easts) - AREA_MARGIN_M, "east_max_m": max(easts) + AREA_MARGIN_M}

    def flight_time_estimate_s(self, cruise_speed_m_s: float) -> float:
        """A generous estimate of the plan's duration: its path at its slowest commanded speed,
        plus its delays and hold times."""
        speed, slowest, path, waits = cruise_speed_m_s, cruise_speed_m_s, 0.0, 0.0
        here = (0.0, 0.0, 0.0)
        for item in self.items:
            if item.command == MAV_CMD_DO_CHANGE_SPEED and item.params[1] > 0:
                speed = item.params[1]
                slowest = min(slowest, speed)
            elif item.command == MAV_CMD_NAV_DELAY:
                waits += item.params[0]
            elif item.has_position:
                there = (item.north_m, item.east_m, item.altitude_m if item.command != MAV_CMD_NAV_LAND else 0.0)
                path += math.dist(here, there)
                here = there
                if item.command == MAV_CMD_NAV_WAYPOINT:
                    waits += item.params[0]
            elif item.command == MAV_CMD_NAV_RETURN_TO_LAUNCH:
                path += math.dist(here, (0.0, 0.0, here[2])) + here[2]
        return path / slowest + waits

    def upload_items(self) -> list[dict[str, Any]]:
        """The items as QGroundControl uploads them (MISSION_ITEM_INT fields; null for NaN, as JSON
        has no NaN), for the world spec."""
        return [{"command": item.command, "frame": item.frame, "params": [None if math.isnan(v) else v for v in item.params],
                 "x": 0 if item.lat_deg is None else int(round(item.lat_deg * 1e7)),
                 "y": 0 if item.lon_deg is None else int(round(item.lon_deg * 1e7)), "z": item.z}
                for item in self.items]


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _param(value: Any) -> float:
    """QGroundControl writes NaN ("unchanged") as null."""
    return math.nan if value is None else float(value)


def _home_problems(mission: Mapping[str, Any], file: str, at: str) -> list[Problem]:
    home = mission.get("plannedHomePosition")
    if not isinstance(home, list) or len(home) != 3 or not all(_number(v) for v in home):
        return [Problem(file, f"{at}/mission/plannedHomePosition", "expected [latitude deg, longitude deg, altitude m AMSL]: "
                                                                   "QGroundControl writes it when the plan has a home position; "
                                                                   "the simulator builds its world around it")]
    if not (-90.0 <= home[0] <= 90.0 and -180.0 <= home[1] <= 180.0):
        return [Problem(file, f"{at}/mission/plannedHomePosition", f"latitude {home[0]} / longitude {home[1]} out of range")]
    return []


def _item_problems(item: Any, index: int, home: Mapping[str, float], file: str, at: str) -> list[Problem]:
    where = f"{at}/mission/items/{index}"
    if not isinstance(item, Mapping):
        return [Problem(file, where, "expected an object (a SimpleItem)")]
    kind = item.get("type")
    if kind != "SimpleItem":
        what = f'{item.get("complexItemType", kind)!s}' if kind == "ComplexItem" else repr(kind)
        return [Problem(file, f"{where}/type", f"{what} items are not supported (surveys, corridor scans and other complex items): "
                                                f"plan the route as single waypoints{SIMULATOR_LIMIT}: QGroundControl expands them "
                                                f"into single items when it uploads, this reader does not")]
    command = item.get("command")
    if command not in COMMANDS or isinstance(command, bool):
        supported = ", ".join(f"{name} ({number})" for number, name in COMMANDS.items())
        return [Problem(file, f"{where}/command", f"command {command!r} is not supported: use {supported}{SIMULATOR_LIMIT}: "
                                                   "PX4 flies more commands, the simulator models and scores these")]
    problems = []
    frame = item.get("frame")
    wanted = ALTITUDE_FRAMES if command in POSITION_COMMANDS else (MAV_FRAME_MISSION, *ALTITUDE_FRAMES)
    if frame not in wanted or isinstance(frame, bool):
        name = FRAME_NAMES.get(frame, "unknown") if isinstance(frame, int) else "not a number"
        choices = " or ".join(f"{f} ({FRAME_NAMES[f]})" for f in wanted)
        problems.append(Problem(file, f"{where}/frame", f"frame {frame!r} ({name}) is not supported for {COMMANDS[command]}: use {choices}"
                                                        f"{PX4_REFUSES}"))
    if item.get("autoContinue", True) is not True:
        problems.append(Problem(file, f"{where}/autoContinue", "a mission that waits for the operator cannot be flown unattended: set it true"
                                                               f"{SIMULATOR_LIMIT}"))
    params = item.get("params")
    if not isinstance(params, list) or len(params) != 7 or not all(p is None or _number(p) for p in params):
        problems.append(Problem(file, f"{where}/params", "expected 7 numbers (null for unset): param1-4, latitude, longitude, altitude"))
        return problems
    p = [_param(v) for v in params]
    if command == MAV_CMD_DO_CHANGE_SPEED and not (p[1] > 0 or p[1] == -1):
        problems.append(Problem(file, f"{where}/params/1", f"speed {params[1]} m/s: give a positive speed (-1 keeps the current one)"
                                                            f"{SIMULATOR_LIMIT}: its time limit follows from the speeds"))
    if command == MAV_CMD_NAV_DELAY and not p[0] >= 0:
        problems.append(Problem(file, f"{where}/params/0", f"delay {params[0]}: give the seconds to wait (a time of day is not supported"
                                                            f"{SIMULATOR_LIMIT}: simulated time has no time of day)"))
    if command == MAV_CMD_NAV_WAYPOINT:
        for number, what in ((0, "hold time (s)"), (1, "acceptance radius (m)")):
            if math.isfinite(p[number]) and p[number] < 0:
                problems.append(Problem(file, f"{where}/params/{number}", f"{what} {params[number]} must not be negative{SIMULATOR_LIMIT}: "
                                                                          "its mission check needs a meaning for it"))
    if command in POSITION_COMMANDS and not problems:
        problems += _position_problems(command, frame, p, home, file, where)
    return problems


def _position_problems(command: int, frame: int, p: list[float], home: Mapping[str, float], file: str, where: str) -> list[Problem]:
    lat, lon, z = p[4], p[5], p[6]
    located = math.isfinite(lat) and math.isfinite(lon) and (lat, lon) != (0.0, 0.0)
    if command == MAV_CMD_NAV_WAYPOINT and not located:
        return [Problem(file, f"{where}/params/4", f"a waypoint needs a latitude and longitude{SIMULATOR_LIMIT}: "
                                                    "PX4 would fly to 0, 0, outside the simulated world")]
    problems = []
    if located:
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            return [Problem(file, f"{where}/params/4", f"latitude {lat} / longitude {lon} out of range{SIMULATOR_LIMIT}")]
        distance = math.hypot(*local_from_geodetic(home["lat_deg"], home["lon_deg"], lat, lon))
        if distance > MAX_DISTANCE_FROM_HOME_M:
            problems.append(Problem(file, f"{where}/params/4", f"{distance / 1000:.1f} km from home: the simulated world reaches "
                                                                f"{MAX_DISTANCE_FROM_HOME_M / 1000:.0f} km; is plannedHomePosition right?{SIMULATOR_LIMIT}"))
    if command != MAV_CMD_NAV_LAND:
        if not math.isfinite(z):
            problems.append(Problem(file, f"{where}/params/6", f"an altitude is needed{SIMULATOR_LIMIT}"))
        elif _altitude_above_home(frame, z, home) <= 0.0:
            # PX4's feasibility checker refuses a takeoff below home; a waypoint there is in the simulated ground.
            whose = PX4_REFUSES if command == MAV_CMD_NAV_TAKEOFF else f"{SIMULATOR_LIMIT}: its ground is at home's altitude"
            problems.append(Problem(file, f"{where}/params/6", f"altitude {z:g} m ({FRAME_NAMES[frame]}) is not above home "
                                                                f"({home['alt_m']:g} m AMSL){whose}"))
    return problems


def _altitude_above_home(frame: int, z: float, home: Mapping[str, float]) -> float:
    return z - home["alt_m"] if frame == MAV_FRAME_GLOBAL else z


def plan_problems(document: Any, file: str, at: str = "") -> list[Problem]:
    """Every problem of a .plan document, located by JSON pointer (under `at` when embedded)."""
    if not isinstance(document, Mapping) or document.get("fileType") != "Plan":
        return [Problem(file, f"{at}/fileType", 'not a QGroundControl plan: expected "fileType": "Plan"')]
    mission = document.get("mission")
    if not isinstance(mission, Mapping):
        return [Problem(file, f"{at}/mission", "missing: a plan's mission holds its home position and items")]
    problems = _home_problems(mission, file, at)
    if problems:
        return problems
    home = dict(zip(("lat_deg", "lon_deg", "alt_m"), mission["plannedHomePosition"]))
    items = mission.get("items")
    if not isinstance(items, list) or not items:
        return [Problem(file, f"{at}/mission/items", "expected a non-empty list of mission items")]
    for index, item in enumerate(items):
        problems += _item_problems(item, index, home, file, at)
    if problems:
        return problems
    commands = [item["command"] for item in items]
    positioned = [i for i, c in enumerate(commands) if c in (*POSITION_COMMANDS, MAV_CMD_NAV_RETURN_TO_LAUNCH)]
    if positioned and commands[positioned[0]] == MAV_CMD_NAV_LAND:
        whose = PX4_REFUSES if positioned[0] == 0 else f"{SIMULATOR_LIMIT}: it needs an altitude to fly to the land item at"
        problems.append(Problem(file, f"{at}/mission/items/{positioned[0]}", f"the plan starts with landing: add a takeoff item before it{whose}"))
    late_takeoff = next((i for i in positioned[1:] if commands[i] == MAV_CMD_NAV_TAKEOFF), None)
    if late_takeoff is not None:
        problems.append(Problem(file, f"{at}/mission/items/{late_takeoff}", f"a takeoff that is not the first item with a position "
                                                                            f"(item {positioned[0]} is): remove it or move it first{PX4_REFUSES}"))
    ending = next((i for i, c in enumerate(commands) if c in ENDING_COMMANDS), None)
    if ending is not None and ending != len(items) - 1:
        problems.append(Problem(file, f"{at}/mission/items/{ending + 1}", f"comes after the {COMMANDS[commands[ending]]} item "
                                                                          f"{ending}, so it would never be flown: remove it or move it before"
                                                                          f"{SIMULATOR_LIMIT}"))
    # Within a metre of home it lands where it took off.
    if not problems and MAV_CMD_NAV_WAYPOINT not in commands and math.hypot(*plan_from_document(document, file).landing_point) < 1.0:
        problems.append(Problem(file, f"{at}/mission/items", "no waypoint, and the plan lands where it took off: the UAV has nowhere to "
                                                             "fly; add a waypoint or give the land item a position"
                                                             f"{SIMULATOR_LIMIT}: a scenario needs a goal away from home"))
    return problems


def plan_from_document(document: Mapping[str, Any], file: str) -> Plan:
    """A plan from a document plan_problems() accepted."""
    home = tuple(float(v) for v in document["mission"]["plannedHomePosition"])
    origin = {"lat_deg": home[0], "lon_deg": home[1], "alt_m": home[2]}
    items = []
    for index, item in enumerate(document["mission"]["items"]):
        p = [_param(v) for v in item["params"]]
        command, frame = item["command"], item["frame"]
        located = command in POSITION_COMMANDS and math.isfinite(p[4]) and math.isfinite(p[5]) and (p[4], p[5]) != (0.0, 0.0)
        position: dict[str, float] = {}
        if located:
            north, east = local_from_geodetic(origin["lat_deg"], origin["lon_deg"], p[4], p[5])
            altitude = 0.0 if command == MAV_CMD_NAV_LAND else _altitude_above_home(frame, p[6], origin)
            position = {"north_m": north, "east_m": east, "altitude_m": altitude}
        elif command == MAV_CMD_NAV_TAKEOFF:
            position = {"north_m": 0.0, "east_m": 0.0, "altitude_m": _altitude_above_home(frame, p[6], origin)}
        items.append(PlanItem(index, command, frame, (p[0], p[1], p[2], p[3]), p[4] if located else None, p[5] if located else None,
                              0.0 if math.isnan(p[6]) else p[6], **position))
    return Plan(file, home, tuple(items))


def load_plan(path: Path) -> tuple[dict[str, Any], Plan]:
    """A .plan file: its document (to embed in a scenario) and the plan it describes."""
    document = load_json(path)
    problems = plan_problems(document, str(path))
    if problems:
        raise InputError(problems)
    return document, plan_from_document(document, str(path))
