"""Logical scenarios: loading, validation against the schema and a profile, and their typed form."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from harness.errors import InputError, Problem
from harness.scenario.documents import load_json, schema_problems
from harness.scenario.profile import WEATHER_PARAMETERS, Interval, Profile

SIZE_DIMENSIONS = {
    "cuboid": ("length_m", "width_m", "height_m"),
    "sphere": ("diameter_m",),
    "cylinder": ("diameter_m", "height_m"),
}


@dataclass(frozen=True)
class LogicalObstacle:
    kind: str
    size: str
    form: str
    size_range: Interval | None
    speed_range: Interval | None


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

    @property
    def not_simulated(self) -> list[WeatherValue]:
        return [w for w in self.weather.values() if not w.simulated]

    @property
    def drive(self) -> str:
        return (self.mission or {}).get("drive", "mission")


DRIVES = ("mission", "pilot")


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
        if "speed range" in obstacle:
            if obstacle["kind"] != "dynamic":
                problems.append(
                    Problem(file, f"{at}/speed range", 'only a "dynamic" obstacle has a speed; remove it or make the obstacle dynamic')
                )
            problems += _range_problems(file, f"{at}/speed range", obstacle["speed range"], profile.document["obstacles"]["speed"]["unit"])
            if obstacle["speed range"]["min"] < 0:
                problems.append(Problem(file, f"{at}/speed range/min", "speeds cannot be negative"))
    maneuvers = document["system"]["UAVs"][0]["maneuvers"]
    if "move to waypoint" not in maneuvers and "waypoints" not in document.get("mission", {}):
        problems.append(
            Problem(file, "/system/UAVs/0/maneuvers", 'add "move to waypoint" or mission waypoints: the UAV has nowhere to fly')
        )
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
            size=o["size"],
            form=o["form"],
            size_range=_range(o.get("size range")),
            speed_range=_range(o.get("speed range")),
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
    )


def load_logical(path: Path, profile: Profile, drive: str | None = None) -> LogicalScenario:
    """A logical scenario file; `drive` overrides its mission's drive (`--drive`)."""
    document = with_drive(load_json(path), drive)
    problems = logical_problems(document, profile, str(path))
    if problems:
        raise InputError(problems)
    return logical_from_document(document, profile, str(path))
