"""Logical scenarios: loading, validation against the schema and a profile, and their typed form."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from harness.errors import InputError, Problem
from harness.scenario.documents import load_json, schema_problems
from harness.scenario.plan import Plan, load_plan, plan_from_document, plan_problems
from harness.scenario.profile import WEATHER_PARAMETERS, Interval, Profile, with_rig_document
from harness.scenario.rig import NO_RIG, load_rig, rig_problems, sensor_behaviour_problems

# The ground station's link to the SUT, failed by the harness, which silences the API tap
# (harness/flight/evaluation.py); lost ("off") or not.
DATA_LINK = "data link"

SIZE_DIMENSIONS = {
    "cuboid": ("length_m", "width_m", "height_m"),
    "sphere": ("diameter_m",),
    "cylinder": ("diameter_m", "height_m"),
}


@dataclass(frozen=True)
class LogicalObstacle:
    kind: str  # static, dynamic or intruder
    size: str | None  # None for an intruder: the profile's intruder body
    form: str | None
    size_range: Interval | None
    speed_range: Interval | None
    motion: str = "straight"  # how a dynamic obstacle moves
    encounter: str | None = None  # an intruder's encounter type
    path: str = "straight"  # an intruder's own path


@dataclass(frozen=True)
class LogicalFailure:
    unit: str
    type: str
    sensor: str | None = None  # one range sensor of the rig (unit "distance sensor"); None: all of them


@dataclass(frozen=True)
class WeatherValue:
    """One weather parameter of a logical scenario, resolved against the profile."""

    parameter: str
    category: str
    interval: Interval
    unit: str
    simulated: bool
    source: str  # "scenario", "scenario range" or "profile default"


@dataclass(frozen=True)
class LogicalScenario:
    name: str
    file: str
    document: Mapping[str, Any]
    landform: str
    surface: str
    obstacles: tuple[LogicalObstacle, ...]
    weather: Mapping[str, WeatherValue]
    mission: Mapping[str, Any] | None
    gusts: str = "none"
    failures: tuple[LogicalFailure, ...] = ()
    # Range sensors' behaviour searched, each {"sensor": name, field: {"min", "max"}, ...}
    # (harness/scenario/rig.py: SENSOR_BEHAVIOUR).
    sensors: tuple[Mapping[str, Any], ...] = ()
    rig: Mapping[str, Any] | None = None  # the scenario's own sensor rig, read in on loading; None: the profile's

    @property
    def not_simulated(self) -> list[WeatherValue]:
        return [w for w in self.weather.values() if not w.simulated]

    @property
    def drive(self) -> str:
        return (self.mission or {}).get("drive", "mission")

    @property
    def plan(self) -> Plan | None:
        """The QGroundControl plan the mission flies, embedded on loading (`"plan"`, --mission-plan)."""
        document = (self.mission or {}).get("plan")
        return plan_from_document(document, self.file) if document is not None else None


DRIVES = ("mission", "pilot")
# A pilot programme segment's searched values: their limits, and the range each takes when the
# scenario gives none (mission.programme; sim_bridge/pilot.py).
PROGRAMME_LIMITS = {"angle_deg": (-180.0, 180.0), "deflection": (0.0, 1.0), "duration_s": (0.0, 60.0), "yaw_stick": (-1.0, 1.0)}
PROGRAMME_DEFAULTS = {"angle_deg": (0.0, 0.0), "deflection": (0.0, 1.0), "duration_s": (0.5, 5.0), "yaw_stick": (0.0, 0.0)}


def programme_interval(segment: Mapping[str, Any], field: str) -> Interval:
    """A programme segment's value or range for a field, as an interval (a number: a degenerate one)."""
    given = segment.get(field)
    if given is None:
        return Interval(*PROGRAMME_DEFAULTS[field])
    if isinstance(given, Mapping):
        return Interval(float(given["min"]), float(given["max"]))
    return Interval(float(given), float(given))


def with_drive(document: Mapping[str, Any], drive: str | None) -> Mapping[str, Any]:
    """The logical scenario document with its drive overridden (--drive); unchanged for None."""
    if drive is None:
        return document
    if drive not in DRIVES:
        raise InputError([Problem("--drive", "", f"unknown drive {drive!r}: choose {' or '.join(DRIVES)}")])
    if not isinstance(document, Mapping) or not isinstance(document.get("mission", {}), Mapping):
        return document  # not a scenario: validation names what is wrong with it
    changed = dict(document)
    changed["mission"] = {**document.get("mission", {}), "drive": drive}
    return changed


def with_plan_embedded(document: Any, folder: Path, mission_plan: Path | None = None) -> Any:
    """The logical scenario document with its mission's plan file read into it, so that the
    scenario travels whole (to workers, into concrete scenarios); `mission_plan` replaces the
    mission's route by that plan (--mission-plan). A plan path is relative to the scenario file."""
    if not isinstance(document, Mapping) or not isinstance(document.get("mission", {}), Mapping):
        return document  # not a scenario: validation names what is wrong with it
    mission = dict(document.get("mission", {}))
    if mission_plan is not None:
        mission = {key: value for key, value in mission.items() if key not in ("waypoints", "land")}
        mission["plan"] = load_plan(mission_plan)[0]
    elif isinstance(mission.get("plan"), str):
        mission["plan"] = load_plan(folder / mission["plan"])[0]
    else:
        return document
    return {**document, "mission": mission}


def with_rig_embedded(document: Any, file: Path, rig: str | None = None) -> Any:
    """The logical scenario document with its rig (a preset's name, or a file relative to the
    scenario) read into it, so that the scenario travels whole; `rig` (--rig, a preset or a file)
    replaces the scenario's own."""
    if not isinstance(document, Mapping):
        return document  # not a scenario: validation names what is wrong with it
    if rig is not None:
        return {**document, "rig": load_rig(rig)}
    if not isinstance(document.get("rig"), str):
        return document
    return {**document, "rig": load_rig(document["rig"], file.parent, named_at=(str(file), "/rig"))}


def rigged_profile(profile: Profile, document: Mapping[str, Any]) -> Profile:
    """The profile a logical scenario flies: with the scenario's own rig, if it has one."""
    rig = document.get("rig")
    return profile if not isinstance(rig, Mapping) else with_rig_document(profile, rig)


def _range(document: Mapping[str, Any] | None) -> Interval | None:
    return None if document is None else Interval.from_json(document)


def _range_problems(file: str, at: str, document: Mapping[str, Any], unit: str) -> list[Problem]:
    problems = []
    if document["unit"] != unit:
        problems.append(Problem(file, f"{at}/unit", f'unit must be the profile\'s "{unit}", got "{document["unit"]}"'))
    if document["min"] > document["max"]:
        problems.append(Problem(file, at, f"min {document['min']} > max {document['max']}: swapped bounds?"))
    return problems


def semantic_problems(document: Mapping[str, Any], profile: Profile, file: str) -> list[Problem]:
    """Checks the schema cannot express: override units and order, and obstacle overrides."""
    if isinstance(document.get("rig"), str):
        return [Problem(file, "/rig", "a rig's name or path is read when the scenario file is loaded; here it must be the rig itself")]
    if "rig" in document:
        problems = rig_problems(document["rig"], file, at="/rig")
        if problems:
            return problems
        profile = rigged_profile(profile, document)
    problems = []
    environment = document["environment"]
    for name, override in environment.get("ranges", {}).items():
        problems += _range_problems(file, f"/environment/ranges/{name}", override, profile.parameters[name].unit)
    for index, obstacle in enumerate(environment["obstacles"]):
        at = f"/environment/obstacles/{index}"
        if "size range" in obstacle:
            problems += _range_problems(file, f"{at}/size range", obstacle["size range"], "m")
            if obstacle["size range"]["min"] <= 0:
                problems.append(Problem(file, f"{at}/size range/min", "obstacle sizes must be positive"))
        if obstacle["kind"] == "intruder":
            for key in ("size", "form", "size range", "speed range", "motion"):
                if key in obstacle:
                    problems.append(Problem(file, f"{at}/{key}", "an intruder is another multirotor of the profile's intruder size and speeds, "
                                                                 "placed by its encounter: remove this"))
            continue
        for key in ("encounter", "path"):
            if key in obstacle:
                problems.append(Problem(file, f"{at}/{key}", 'only an "intruder" has an encounter and a path; remove it or make the obstacle an intruder'))
        if "motion" in obstacle and obstacle["kind"] != "dynamic":
            problems.append(Problem(file, f"{at}/motion", 'only a "dynamic" obstacle moves; remove it or make the obstacle dynamic'))
        if "speed range" in obstacle:
            if obstacle["kind"] != "dynamic":
                problems.append(
                    Problem(file, f"{at}/speed range", 'only a "dynamic" obstacle has a speed; remove it or make the obstacle dynamic')
                )
            problems += _range_problems(file, f"{at}/speed range", obstacle["speed range"], profile.document["obstacles"]["speed"]["unit"])
            if obstacle["speed range"]["min"] < 0:
                problems.append(Problem(file, f"{at}/speed range/min", "speeds cannot be negative"))
    area = environment["flight area"].get("area")
    if area:
        for axis in ("north", "east"):
            if area[f"{axis}_min_m"] >= area[f"{axis}_max_m"]:
                problems.append(Problem(file, f"/environment/flight area/area/{axis}_min_m",
                                        f"{area[f'{axis}_min_m']} is not below {axis}_max_m {area[f'{axis}_max_m']}: swapped bounds?"))
    seen_units: dict[tuple[str, str | None], int] = {}
    rig_sensors = [sensor["name"] for sensor in profile.rig["sensors"]] if profile.rig is not None else []
    for index, failure in enumerate(document.get("failures", [])):
        unit, sensor = failure["unit"], failure.get("sensor")
        # One failure per unit; the distance sensor's may instead name sensors of the rig, one each.
        clash = next((i for (u, s), i in seen_units.items() if u == unit and (s is None or sensor is None or s == sensor)), None)
        if clash is not None:
            problems.append(Problem(file, f"/failures/{index}/unit", f'{unit!r} already fails in /failures/{clash}: '
                                                                      "one failure per unit (per sensor of the rig, for the distance sensor)"))
        seen_units.setdefault((unit, sensor), index)
        if "sensor" in failure:
            if failure["unit"] != "distance sensor":
                problems.append(Problem(file, f"/failures/{index}/sensor", 'names a range sensor of the rig: only with "unit": "distance sensor"'))
            elif failure["sensor"] not in rig_sensors:
                have = f"the rig's sensors are {', '.join(rig_sensors)}" if rig_sensors else NO_RIG
                problems.append(Problem(file, f"/failures/{index}/sensor", f'{failure["sensor"]!r} is no sensor of the vehicle: {have}'))
        if failure["unit"] == DATA_LINK and failure["type"] != "off":
            problems.append(Problem(file, f"/failures/{index}/type", f'the data link is lost ("off") or not: {failure["type"]!r} is no failure of it'))
    problems += sensor_behaviour_problems(document.get("sensors", []), profile.rig, file)
    for index, segment in enumerate(document.get("mission", {}).get("programme", [])):
        for field, (low_limit, high_limit) in PROGRAMME_LIMITS.items():
            value = programme_interval(segment, field)
            where = f"/mission/programme/{index}/{field}"
            if value.min > value.max:
                problems.append(Problem(file, where, f"min {value.min:g} is above max {value.max:g}: swapped bounds?"))
            elif value.min < low_limit or value.max > high_limit or (field == "duration_s" and value.min <= 0.0):
                problems.append(Problem(file, where, f"must lie within {low_limit:g}..{high_limit:g}" + (" and above 0" if field == "duration_s" else "")))
    mission = document.get("mission", {})
    maneuvers = document["system"]["UAVs"][0]["maneuvers"]
    if "move to waypoint" not in maneuvers and "waypoints" not in mission and "plan" not in mission:
        problems.append(
            Problem(file, "/system/UAVs/0/maneuvers", 'add "move to waypoint", mission waypoints or a mission plan: the UAV has nowhere to fly')
        )
    if "plan" in mission:
        for key in ("waypoints", "land", "cruise_speed_m_s"):
            if key in mission:
                problems.append(Problem(file, f"/mission/{key}", "a mission plan sets the route, its speeds and its ending: remove this or the plan"))
        if isinstance(mission["plan"], str):
            problems.append(Problem(file, "/mission/plan", "a plan path is read when the scenario file is loaded; here it must be the plan itself"))
        else:
            problems += plan_problems(mission["plan"], file, "/mission/plan")
    return problems


def logical_problems(document: Any, profile: Profile, file: str) -> list[Problem]:
    problems = schema_problems(document, "logical_scenario", file)
    if problems:
        return problems
    return semantic_problems(document, profile, file)


def _weather(document: Mapping[str, Any], profile: Profile) -> dict[str, WeatherValue]:
    weather = document["environment"]["weather"]
    overrides = document["environment"].get("ranges", {})
    resolved = {}
    for name in WEATHER_PARAMETERS:
        parameter = profile.parameters[name]
        if name in weather:
            category, source = weather[name], "scenario"
        else:
            category, source = profile.weather_defaults[name], "profile default"
        interval = parameter.categories[category]
        if name in overrides:
            interval, source = Interval.from_json(overrides[name]), "scenario range"
        resolved[name] = WeatherValue(name, category, interval, parameter.unit, parameter.simulated, source)
    return resolved


def logical_from_document(document: Mapping[str, Any], profile: Profile, file: str) -> LogicalScenario:
    environment = document["environment"]
    obstacles = tuple(
        LogicalObstacle(
            kind=o["kind"],
            size=o.get("size"),
            form=o.get("form"),
            size_range=_range(o.get("size range")),
            speed_range=_range(o.get("speed range")),
            motion=o.get("motion", "straight"),
            encounter=o.get("encounter"),
            path=o.get("path", "straight"),
        )
        for o in environment["obstacles"]
    )
    return LogicalScenario(
        name=document["name"],
        file=file,
        document=document,
        landform=environment["flight area"]["landform"],
        surface=environment["flight area"]["surface nature"],
        obstacles=obstacles,
        weather=_weather(document, profile),
        mission=document.get("mission"),
        gusts=environment["weather"].get("gusts", "none"),
        failures=tuple(LogicalFailure(f["unit"], f["type"], f.get("sensor")) for f in document.get("failures", [])),
        sensors=tuple(document.get("sensors", [])),
        rig=document.get("rig"),
    )


def load_logical(path: Path, profile: Profile, drive: str | None = None, mission_plan: Path | None = None,
                 rig: str | None = None) -> LogicalScenario:
    """A logical scenario file; `drive` overrides its mission's drive (`--drive`), `mission_plan`
    its route (`--mission-plan`), `rig` its range sensors (`--rig`)."""
    document = with_rig_embedded(with_plan_embedded(with_drive(load_json(path), drive), path.parent, mission_plan), path, rig)
    problems = logical_problems(document, profile, str(path))
    if problems:
        raise InputError(problems)
    return logical_from_document(document, profile, str(path))
