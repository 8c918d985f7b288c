"""Sensor rigs: the vehicle's range sensors, declared in its profile ("rig"), in a logical scenario
("rig", which wins) or given with --rig (which wins over both): a preset's name,
scenarios/rigs/NAME.json, or a file. Each sensor is rendered by the simulator into the
messages its kind is (sim_bridge/rig.py): DISTANCE_SENSOR devices, one reading over a field of
view, and OBSTACLE_DISTANCE sources, a reading per sector. A profile without a rig flies its one
forward sensor ("sensor") as before, rendered as each SUT reads it.

A rig is part of the profile document, so a concrete scenario and a campaign's identity carry it.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any, Mapping, Sequence

from harness.errors import InputError, Problem
from harness.paths import scenarios_dir
from harness.scenario.documents import load_json, schema_problems
from sim_bridge.spec import RigSensor

SECTORS = 72  # OBSTACLE_DISTANCE's distances array
NO_RIG = 'the vehicle has no rig: name one in the scenario\'s "rig" or with --rig (`stella rigs`)'
# A sensor's behaviour a logical scenario may search ("sensors"), with its unit and the values a
# sensor of the rig can take (the rig schema's bounds).
SENSOR_BEHAVIOUR = {"max_range_m": ("m", 0.0, 655.0), "fov_deg": ("deg", 0.0, 360.0), "rate_hz": ("Hz", 0.0, 250.0), "latency_s": ("s", 0.0, 2.0),
                    "yaw_deg": ("deg", -360.0, 360.0), "increment_deg": ("deg", 1.0, 90.0)}
DEFAULT_INCREMENT_DEG = 5.0


def rigs_dir() -> Path:
    return scenarios_dir() / "rigs"


def rig_path(name_or_path: str, folder: Path | None = None) -> Path:
    """A preset by name (`lidar_360`) or a rig file by path (relative to `folder` if given: a
    logical scenario's rig lies beside it)."""
    candidate = Path(name_or_path)
    if folder is not None and not candidate.is_absolute():
        candidate = folder / candidate
    if candidate.suffix == ".json" or candidate.exists():
        return candidate
    return rigs_dir() / f"{name_or_path}.json"


def preset_names() -> list[str]:
    return sorted(path.stem for path in rigs_dir().glob("*.json"))


def is_rig_document(document: Any) -> bool:
    """A rig, not a profile ("landforms") or a logical scenario ("system", which may search "sensors")."""
    return isinstance(document, dict) and "sensors" in document and "landforms" not in document and "system" not in document


def rig_problems(document: Any, file: str, at: str = "") -> list[Problem]:
    """Every problem of a rig document, located by JSON pointer (under `at` where it sits inside a profile)."""
    problems = [Problem(p.file, at + p.pointer, p.message) for p in schema_problems(document, "rig", file)]
    if problems:
        return problems
    seen_names: set[str] = set()
    geometries: dict[tuple, int] = {}
    for index, sensor in enumerate(document["sensors"]):
        where = f"{at}/sensors/{index}"
        if sensor["name"] in seen_names:
            problems.append(Problem(file, f"{where}/name", f'"{sensor["name"]}" names two sensors: each needs its own name (its log topic is /sensor/rig/NAME)'))
        seen_names.add(sensor["name"])
        if sensor["min_range_m"] >= sensor["max_range_m"]:
            problems.append(Problem(file, f"{where}/min_range_m", "must be below max_range_m"))
        if sensor["message"] == "DISTANCE_SENSOR":
            for key in ("increment_deg", "frame"):
                if key in sensor:
                    problems.append(Problem(file, f"{where}/{key}", "belongs to an OBSTACLE_DISTANCE source: a DISTANCE_SENSOR has one reading over its fov_deg"))
            continue
        increment = sensor.get("increment_deg", DEFAULT_INCREMENT_DEG)
        covered = 360.0 if sensor["fov_deg"] >= 360.0 else sensor["fov_deg"]
        if covered / increment > SECTORS + 1e-9:
            problems.append(Problem(file, f"{where}/increment_deg",
                                    f"{covered:g} degrees in sectors of {increment:g} make more than the {SECTORS} an OBSTACLE_DISTANCE message holds: "
                                    f"at least {covered / SECTORS:g}"))
        if sensor["fov_deg"] < increment:
            problems.append(Problem(file, f"{where}/fov_deg", f"is narrower than one sector of {increment:g} degrees"))
        if sensor.get("frame", "body") == "local" and sensor["fov_deg"] < 360.0:
            problems.append(Problem(file, f"{where}/frame", '"local" (sectors from north) needs fov_deg 360: a field of view turns with the vehicle'))
        geometry = (increment, sensor.get("yaw_deg", 0.0), sensor["fov_deg"], sensor["max_range_m"], sensor.get("frame", "body"))
        if geometry in geometries:
            problems.append(Problem(file, f"{where}", f"has the geometry of /sensors/{geometries[geometry]}: an autopilot cannot tell two "
                                                      "OBSTACLE_DISTANCE sources apart by anything else (PX4's obstacle_distance topic has one instance)"))
        geometries.setdefault(geometry, index)
    return problems


def sensor_behaviour_problems(entries: list, rig: Mapping[str, Any] | None, file: str) -> list[Problem]:
    """A logical scenario's searched sensor behaviour ("sensors"): each entry names a sensor of
    the rig once, each range lies within what that sensor can be, and every corner of the box
    is a sensor that exists (an OBSTACLE_DISTANCE source's field of view holds 1 to 72 sectors)."""
    problems = []
    sensors = {sensor["name"]: sensor for sensor in rig["sensors"]} if rig is not None else {}
    seen: dict[str, int] = {}
    for index, entry in enumerate(entries):
        name = entry["sensor"]
        if name not in sensors:
            have = f"the rig's sensors are {', '.join(sensors)}" if sensors else NO_RIG
            problems.append(Problem(file, f"/sensors/{index}/sensor", f"{name!r} is no sensor of the vehicle: {have}"))
            continue
        if name in seen:
            problems.append(Problem(file, f"/sensors/{index}/sensor", f"{name!r} is searched in /sensors/{seen[name]} already: one entry per sensor"))
        seen.setdefault(name, index)
        field_problems = [_searched_field_problem(file, f"/sensors/{index}/{field}", field, entry[field], sensors[name])
                          for field in SENSOR_BEHAVIOUR if field in entry]
        field_problems = [problem for problem in field_problems if problem is not None]
        problems += field_problems or _sector_problems(file, f"/sensors/{index}", entry, sensors[name])
    return problems


def _searched_field_problem(file: str, where: str, field: str, bounds: Mapping[str, float], sensor: Mapping[str, Any]) -> Problem | None:
    unit, lowest, highest = SENSOR_BEHAVIOUR[field]
    low, high = bounds["min"], bounds["max"]
    if low > high:
        return Problem(file, where, f"min {low:g} is above max {high:g}: swapped bounds?")
    if field == "max_range_m" and low <= sensor["min_range_m"]:
        return Problem(file, f"{where}/min", f"must be above the sensor's min_range_m, {sensor['min_range_m']:g} m")
    if high > highest:
        return Problem(file, f"{where}/max", f"a sensor's {field} is at most {highest:g} {unit}")
    if low < lowest or (field == "rate_hz" and low <= lowest):
        return Problem(file, f"{where}/min", "a sensor reads more than 0 times a second" if field == "rate_hz" else f"a sensor's {field} is at least {lowest:g} {unit}")
    if field == "increment_deg" and sensor["message"] != "OBSTACLE_DISTANCE":
        return Problem(file, where, "belongs to an OBSTACLE_DISTANCE source: a DISTANCE_SENSOR has one reading over its fov_deg")
    if field == "fov_deg" and sensor.get("frame") == "local" and low < 360.0:
        return Problem(file, where, 'a "local" source covers all around: its field of view stays 360')
    return None


def _sector_problems(file: str, where: str, entry: Mapping[str, Any], sensor: Mapping[str, Any]) -> list[Problem]:
    """An OBSTACLE_DISTANCE source's searched field of view and sector width, taken together: the
    narrowest view must hold one of the widest sectors, the widest view at most 72 of the narrowest."""
    if sensor["message"] != "OBSTACLE_DISTANCE" or ("fov_deg" not in entry and "increment_deg" not in entry):
        return []
    fixed_fov = {"min": sensor["fov_deg"], "max": sensor["fov_deg"]}
    fixed_increment = {"min": sensor.get("increment_deg", DEFAULT_INCREMENT_DEG), "max": sensor.get("increment_deg", DEFAULT_INCREMENT_DEG)}
    fov, increment = entry.get("fov_deg", fixed_fov), entry.get("increment_deg", fixed_increment)
    searched = "fov_deg" if "fov_deg" in entry else "increment_deg"
    widest_view = min(fov["max"], 360.0)
    if fov["min"] < increment["max"] or widest_view / increment["min"] > SECTORS + 1e-9:
        return [Problem(file, f"{where}/{searched}",
                        f"every searched sensor must be one an OBSTACLE_DISTANCE message can carry: a field of view of "
                        f"{fov['min']:g}-{widest_view:g} degrees in sectors of {increment['min']:g}-{increment['max']:g} needs "
                        f"fov_deg min >= increment_deg max and fov_deg max <= {SECTORS} x increment_deg min "
                        f"({SECTORS} sectors of {increment['min']:g} cover at most {SECTORS * increment['min']:g} degrees)")]
    return []


def load_rig(name_or_path: str, folder: Path | None = None, named_at: tuple[str, str] = ("--rig", "")) -> dict[str, Any]:
    """A validated rig document, by preset name or path (relative to `folder`, if given);
    InputError names the file, the field and the fix, and `named_at` (file, JSON pointer) where
    the name was given."""
    path = rig_path(name_or_path, folder)
    if not path.exists():
        raise InputError([Problem(*named_at, f"{name_or_path}: no such rig file or preset: give a file or one of {', '.join(preset_names())} (`stella rigs`)")])
    document = load_json(path)
    problems = rig_problems(document, str(path))
    if problems:
        raise InputError(problems)
    return document


def with_rig(profile_document: Mapping[str, Any], rig: Mapping[str, Any]) -> dict[str, Any]:
    """The profile document with this rig as its vehicle's range sensors."""
    return {**copy.deepcopy(dict(profile_document)), "rig": copy.deepcopy(dict(rig))}


def reach_m(sensor: Mapping[str, Any], profile_sensor: Mapping[str, Any], visibility_m: float) -> float:
    """A rig sensor's reach in this visibility, by the profile's sensor model (world.sensor_range_m):
    linear below its full-range visibility (the profile sensor's unless it gives its own), never
    below the profile's floor or its own reach, whichever is less."""
    full = sensor.get("full_range_visibility_m", profile_sensor["full_range_visibility_m"])
    reach = sensor["max_range_m"] * min(1.0, visibility_m / full)
    return max(min(profile_sensor["floor_range_m"], sensor["max_range_m"]), reach)


def rig_sensors(rig: Mapping[str, Any], profile_sensor: Mapping[str, Any], visibility_m: float,
                behaviour: Sequence[Mapping[str, Any]] = ()) -> tuple[RigSensor, ...]:
    """The world spec's sensors of a rig document in this world's visibility, with a concrete
    scenario's values of their searched behaviour ({"sensor": name, field: value, ...})."""
    values = {entry["sensor"]: {k: v for k, v in entry.items() if k != "sensor"} for entry in behaviour}
    rig = {**rig, "sensors": [{**s, **values.get(s["name"], {})} for s in rig["sensors"]]}
    return tuple(RigSensor(name=s["name"], message=s["message"], yaw_deg=float(s.get("yaw_deg", 0.0)), fov_deg=float(s["fov_deg"]),
                           min_range_m=float(s["min_range_m"]), max_range_m=float(s["max_range_m"]),
                           range_m=reach_m(s, profile_sensor, visibility_m), rate_hz=float(s["rate_hz"]),
                           latency_s=float(s.get("latency_s", 0.0)), increment_deg=float(s.get("increment_deg", 5.0)),
                           frame=s.get("frame", "body"), noise_m=float(s.get("noise_m", 0.0)))
                 for s in rig["sensors"])


def rig_problem_for(rig: Mapping[str, Any] | None, sut: str, capabilities) -> str | None:
    """Why this SUT (its adapter's Capabilities) cannot fly with this rig (None: it can): a
    sensor whose message it does not read, or one it cannot read otherwise, or more
    DISTANCE_SENSOR devices than it tells apart."""
    if rig is None:
        return None
    devices = sum(1 for s in rig["sensors"] if s["message"] == "DISTANCE_SENSOR")
    limit = capabilities.distance_sensor_limit
    if limit is not None and devices > limit:
        return f"rig {rig['name']}: {devices} DISTANCE_SENSOR devices, of which {sut} reads the first {limit} only"
    refused = [s for s in rig["sensors"] if s["message"] not in capabilities.rig_messages]
    if refused:
        names = ", ".join(f'{s["name"]} ({s["message"]})' for s in refused)
        if not capabilities.rig_messages:
            why = f"{sut} takes its range data another way than the simulator's MAVLink messages; rigs do not reach it yet"
        else:
            why = f"{sut} reads only {', '.join(capabilities.rig_messages)}"
        return f"rig {rig['name']}: {names}: {why}"
    unreadable = [(s, capabilities.rig_sensor_problem(s)) for s in rig["sensors"]] if capabilities.rig_sensor_problem is not None else []
    problems = [f'{s["name"]} ({s["message"]}): {why}' for s, why in unreadable if why is not None]
    return f"rig {rig['name']}: {'; '.join(problems)}" if problems else None


def describe(rig: Mapping[str, Any]) -> dict[str, Any]:
    """A rig as `stella rigs --json` lists it."""
    return {"name": rig["name"], "description": rig.get("description", ""),
            "messages": sorted({s["message"] for s in rig["sensors"]}),
            "sensors": [{k: v for k, v in s.items() if k != "description"} for s in rig["sensors"]]}


def presets() -> list[dict[str, Any]]:
    return [describe(load_rig(name)) for name in preset_names()]


def summary_line(sensor: Mapping[str, Any]) -> str:
    where = f'{sensor["fov_deg"]:g} deg field of view at {sensor.get("yaw_deg", 0):g} deg' if sensor["fov_deg"] < 360 else "all around"
    sectors = f', sectors of {sensor.get("increment_deg", 5):g} deg' if sensor["message"] == "OBSTACLE_DISTANCE" else ""
    latency = f', {sensor["latency_s"]:g} s late' if sensor.get("latency_s") else ""
    return (f'{sensor["name"]}: {sensor["message"]}, {where}{sectors}, '
            f'{sensor["min_range_m"]:g}-{sensor["max_range_m"]:g} m, {sensor["rate_hz"]:g} Hz{latency}')
