"""System profiles: the system-specific table that turns categories into numbers."""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from types import MappingProxyType
from typing import Any, Mapping

from harness.errors import InputError, Problem
from harness.paths import profile_path
from harness.scenario import units
from harness.scenario.documents import load_json, schema, schema_problems
from harness.scenario.rig import load_rig, rig_problems, with_rig

WEATHER_PARAMETERS = (
    "wind force",
    "reduced visibility",
    "temperature",
    "lighting",
    "precipitation",
    "lightning",
    "cloud cover",
)


@dataclass(frozen=True)
class Interval:
    min: float
    max: float

    @classmethod
    def from_json(cls, document: Mapping[str, Any]) -> "Interval":
        return cls(float(document["min"]), float(document["max"]))

    def scaled(self, factor: float) -> "Interval":
        return Interval(self.min * factor, self.max * factor)

    @property
    def degenerate(self) -> bool:
        return self.min == self.max


@dataclass(frozen=True)
class Parameter:
    name: str
    unit: str
    simulated: bool
    categories: Mapping[str, Interval]


@dataclass(frozen=True)
class Landform:
    name: str
    terrain: Mapping[str, Any]
    goal_north_m: float
    goal_east_m: float
    area: Mapping[str, float]


# Weather parameters the simulation represents, with the name and unit of their quantity; the
# profile's unit is converted into it (harness/scenario/units.py).
SIMULATED_WEATHER = {
    "wind force": ("wind_speed_m_s", "m/s"),
    "reduced visibility": ("visibility_m", "m"),
    "temperature": ("temperature_c", "degC"),
}

# The pilot drive's ranges for a profile written before it existed (the default profile's values).
PILOT_DEFAULTS = {"max_stick": {"min": 0.3, "max": 1.0}, "aim_offset": {"unit": "m", "min": -10.0, "max": 10.0}}


@dataclass(frozen=True)
class Profile:
    """A validated profile. `document` keeps the JSON for embedding in concrete scenarios."""

    name: str
    document: Mapping[str, Any]
    parameters: Mapping[str, Parameter]
    weather_defaults: Mapping[str, str]
    obstacle_sizes: Mapping[str, Interval]
    obstacle_speed_m_s: Interval
    obstacle_speed_factor: float  # a speed in the profile's unit times this is in m/s
    obstacle_travel_m: Interval
    obstacle_altitude_m: Interval
    keep_out_radius_m: float
    min_separation_m: float
    landforms: Mapping[str, Landform]
    safety_distance_m: float

    @property
    def uav(self) -> Mapping[str, Any]:
        return self.document["uav"]

    @property
    def sensor(self) -> Mapping[str, Any]:
        return self.document["sensor"]

    @property
    def rig(self) -> Mapping[str, Any] | None:
        """The vehicle's range sensors, if it declares a rig (harness/scenario/rig.py)."""
        return self.document.get("rig")

    @property
    def surfaces(self) -> Mapping[str, Any]:
        return self.document["surfaces"]

    @property
    def time_limit_s(self) -> float:
        return float(self.document["time_limit_s"])

    def section(self, name: str) -> Mapping[str, Any]:
        """A section a profile written before it existed leaves out: the bundled default's then."""
        return self.document[name] if name in self.document else _bundled_default()[name]

    def obstacle_range(self, key: str) -> Interval:
        """One of the obstacles' ranges (speed, travel, altitude, arc_radius, vertical_travel) in SI units."""
        document = self.document["obstacles"].get(key) or _bundled_default()["obstacles"][key]
        return Interval.from_json(document).scaled(units.factor(document["unit"], "m/s" if key == "speed" else "m"))

    def intruder_range(self, key: str) -> Interval:
        """speed, closing_speed, vertical_offset or turn_rate of the intruder section."""
        return Interval.from_json(self.section("intruder")[key])

    @property
    def climb_speed_m_s(self) -> float:
        return float(self.uav.get("climb_speed_m_s", _bundled_default()["uav"]["climb_speed_m_s"]))

    @property
    def pilot_max_stick(self) -> Interval:
        return Interval.from_json(self.document.get("pilot", PILOT_DEFAULTS)["max_stick"])

    @property
    def pilot_aim_offset_m(self) -> Interval:
        return Interval.from_json(self.document.get("pilot", PILOT_DEFAULTS)["aim_offset"])


@lru_cache(maxsize=1)
def _bundled_default() -> Mapping[str, Any]:
    return load_json(profile_path("default"))


def _semantic_problems(document: Mapping[str, Any], file: str) -> list[Problem]:
    problems = []

    def check_interval(path: str, interval: Mapping[str, float], what: str) -> None:
        if interval["min"] > interval["max"]:
            problems.append(
                Problem(
                    file,
                    path,
                    f"lower {interval['min']} > upper {interval['max']} for {what}: swapped bounds?",
                )
            )

    enums = schema("logical_scenario")["properties"]["environment"]["properties"]["weather"]["properties"]
    for name, parameter in document["parameters"].items():
        for category, interval in parameter["categories"].items():
            check_interval(f"/parameters/{name}/categories/{category}", interval, f"{name!r} {category!r}")
        missing = [c for c in enums[name]["enum"] if c not in parameter["categories"]]
        for category in missing:
            problems.append(
                Problem(
                    file,
                    f"/parameters/{name}/categories",
                    f"no range for category {json.dumps(category)}; every value a logical scenario may use needs one",
                )
            )
    for name, category in document["weather_defaults"].items():
        if name == "description":
            continue
        allowed = list(document["parameters"][name]["categories"])
        if category not in allowed:
            problems.append(
                Problem(
                    file,
                    f"/weather_defaults/{name}",
                    f"{json.dumps(category)} is not a category of {name!r}; allowed values: "
                    + ", ".join(json.dumps(a) for a in allowed),
                )
            )
    for size, interval in document["obstacles"]["size"]["categories"].items():
        check_interval(f"/obstacles/size/categories/{size}", interval, f"obstacle size {size!r}")
        if interval["min"] <= 0:
            problems.append(Problem(file, f"/obstacles/size/categories/{size}/min", "obstacle sizes must be positive"))
    for key in ("speed", "travel", "altitude", "arc_radius", "vertical_travel"):
        if key in document["obstacles"]:
            check_interval(f"/obstacles/{key}", document["obstacles"][key], f"obstacle {key}")
    for key in ("speed", "closing_speed", "vertical_offset", "turn_rate"):
        if "intruder" in document:
            check_interval(f"/intruder/{key}", document["intruder"][key], f"the intruder's {key}")
    if "gusts" in document:
        check_interval("/gusts/gust_duration", document["gusts"]["gust_duration"], "the gust's duration")
        for band, values in document["gusts"]["categories"].items():
            for key in ("turbulence", "gust"):
                check_interval(f"/gusts/categories/{band}/{key}", values[key], f"{band} {key}")
                if values[key]["min"] < 0:
                    problems.append(Problem(file, f"/gusts/categories/{band}/{key}/min", "an intensity cannot be negative"))
    if "failures" in document:
        check_interval("/failures/duration", document["failures"]["duration"], "a failure's duration")
    expected_units = [("intruder", key, unit) for key, unit in (("speed", "m/s"), ("closing_speed", "m/s"), ("vertical_offset", "m"), ("turn_rate", "deg/s"))]
    expected_units += [("gusts", "gust_duration", "s"), ("failures", "duration", "s")]
    for section, key, unit in expected_units:
        if section in document and document[section][key]["unit"] != unit:
            problems.append(Problem(file, f"/{section}/{key}/unit", f'must be "{unit}", got "{document[section][key]["unit"]}"'))
    for name, landform in document["landforms"].items():
        area = landform["area"]
        check_interval(
            f"/landforms/{name}/area",
            {"min": area["north_min_m"], "max": area["north_max_m"]},
            "the area's north extent",
        )
        check_interval(
            f"/landforms/{name}/area",
            {"min": area["east_min_m"], "max": area["east_max_m"]},
            "the area's east extent",
        )
        for label, north, east in (("start (0, 0)", 0.0, 0.0), ("goal", landform["goal"]["north_m"], landform["goal"]["east_m"])):
            if not (area["north_min_m"] <= north <= area["north_max_m"] and area["east_min_m"] <= east <= area["east_max_m"]):
                problems.append(Problem(file, f"/landforms/{name}/area", f"the {label} lies outside the flight area"))
    quantities = [(f"/parameters/{name}/unit", document["parameters"][name]["unit"], unit) for name, (_n, unit) in SIMULATED_WEATHER.items()]
    quantities += [(f"/obstacles/{key}/unit", document["obstacles"][key]["unit"], unit)
                   for key, unit in (("speed", "m/s"), ("travel", "m"), ("altitude", "m"), ("arc_radius", "m"), ("vertical_travel", "m"))
                   if key in document["obstacles"]]
    for pointer, unit, simulation_unit in quantities:
        try:
            units.factor(unit, simulation_unit)
        except ValueError as error:
            problems.append(Problem(file, pointer, str(error)))
    for key in ("max_stick", "aim_offset"):
        if "pilot" in document:
            check_interval(f"/pilot/{key}", document["pilot"][key], f"the pilot's {key}")
    sensor = document["sensor"]
    if sensor["min_range_m"] >= sensor["max_range_m"]:
        problems.append(Problem(file, "/sensor/min_range_m", "must be below max_range_m"))
    if "rig" in document:
        problems.extend(rig_problems(document["rig"], file, at="/rig"))
    return problems


def profile_problems(document: Any, file: str) -> list[Problem]:
    problems = schema_problems(document, "profile", file)
    if problems:
        return problems
    return _semantic_problems(document, file)


def profile_from_document(document: Mapping[str, Any]) -> Profile:
    parameters = {
        name: Parameter(
            name=name,
            unit=p["unit"],
            simulated=p["simulated"],
            categories=MappingProxyType({c: Interval.from_json(i) for c, i in p["categories"].items()}),
        )
        for name, p in document["parameters"].items()
    }
    obstacles = document["obstacles"]
    landforms = {
        name: Landform(
            name=name,
            terrain=MappingProxyType(dict(lf["terrain"])),
            goal_north_m=float(lf["goal"]["north_m"]),
            goal_east_m=float(lf["goal"]["east_m"]),
            area=MappingProxyType({k: float(v) for k, v in lf["area"].items()}),
        )
        for name, lf in document["landforms"].items()
    }
    return Profile(
        name=document["name"],
        document=document,
        parameters=MappingProxyType(parameters),
        weather_defaults=MappingProxyType({k: v for k, v in document["weather_defaults"].items() if k != "description"}),
        obstacle_sizes=MappingProxyType({k: Interval.from_json(v) for k, v in obstacles["size"]["categories"].items()}),
        obstacle_speed_m_s=Interval.from_json(obstacles["speed"]).scaled(units.factor(obstacles["speed"]["unit"], "m/s")),
        obstacle_speed_factor=units.factor(obstacles["speed"]["unit"], "m/s"),
        obstacle_travel_m=Interval.from_json(obstacles["travel"]).scaled(units.factor(obstacles["travel"]["unit"], "m")),
        obstacle_altitude_m=Interval.from_json(obstacles["altitude"]).scaled(units.factor(obstacles["altitude"]["unit"], "m")),
        keep_out_radius_m=float(obstacles["keep_out_radius_m"]),
        min_separation_m=float(obstacles["min_separation_m"]),
        landforms=MappingProxyType(landforms),
        safety_distance_m=float(document["uav"]["safety_distance_m"]),
    )


def load_profile(name_or_path: str = "default") -> Profile:
    """Load and validate a profile by name (scenarios/profiles/NAME.json) or by path."""
    path = profile_path(name_or_path)
    document = load_json(path)
    problems = profile_problems(document, str(path))
    if problems:
        raise InputError(problems)
    return profile_from_document(document)


def is_profile_document(document: Any) -> bool:
    return isinstance(document, dict) and "parameters" in document and "landforms" in document


def with_rig_named(profile: Profile, name_or_path: str) -> Profile:
    """The profile with a rig (a preset's name or a file, `--rig`) as its vehicle's range sensors."""
    return with_rig_document(profile, load_rig(name_or_path))


def with_rig_document(profile: Profile, rig: Mapping[str, Any]) -> Profile:
    return profile if profile.rig == rig else profile_from_document(with_rig(profile.document, rig))
