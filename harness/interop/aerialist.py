"""The UAV Testing Competition's test cases (Aerialist's YAML) in and out.

Conventions, read from Aerialist's source (skhatiri/Aerialist: aerialist/px4/obstacle.py,
simulator.py, trajectory.py; docs/interop.md has the quotes):
* an obstacle box is `size: {l, w, h}` and `position: {x, y, z, r}`: (x, y) is the centre of its
  footprint in metres from the vehicle's start, x north and y east (PX4's local frame; Aerialist
  swaps them into Gazebo's east/north when it spawns the box); `l` lies along x before rotation,
  `r` is in degrees, positive from north towards east; `z` is the ground (always 0) and the box
  spans 0..h. Our cuboid's length, width and yaw mean exactly that.
* the mission is a QGroundControl `.plan` uploaded by MAVSDK, which ignores plannedHomePosition
  for PX4: the vehicle starts at the simulator's home, PX4's default (Zurich) unless
  `simulation.home_position` says otherwise. That home is our origin.
* parameters: `drone.params` (a mapping) or `drone.params_file` (a NAME,VALUE CSV); `params` wins.
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from typing import Any, Mapping

import yaml

from harness.errors import InputError, Problem
from harness.interop.param_files import load_params_file
from harness.scenario.documents import load_json, read_text
from harness.scenario.logical import logical_from_document, logical_problems
from harness.scenario.plan import AREA_MARGIN_M, plan_from_document, plan_problems
from harness.scenario.profile import load_profile, profile_from_document
from harness.scenario.space import SearchSpace
from harness.scenario.world import world_spec
from sim_bridge.spec import WorldSpec

PX4_DEFAULT_HOME = (47.397742, 8.545594, 488.0)
COMPETITION_SAFETY_DISTANCE_M = 1.5  # its soft-fail threshold
# Mission mode (Aerialist's FlightMode 3) one microsecond in, as the competition's commands file.
# The _INT frames our upload uses are written as the frames QGroundControl saves (same meaning).
PLAN_FRAMES = {5: 0, 6: 3}
START_MISSION = [{"timestamp": 1, "mode": 3, "x": 0, "y": 0, "z": 0.5, "r": 0}]
CLEAR_CALM = {"wind force": "none", "reduced visibility": "none", "lighting": "normal", "temperature": "moderate",
              "precipitation": "none", "lightning": "none", "cloud cover": "none"}
# Temperature is not part of the format; a fixed value keeps an import one concrete scenario.
IMPORT_TEMPERATURE_C = 20.0


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _load_yaml(path: Path) -> Any:
    text = read_text(path)
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        raise InputError([Problem(str(path), "", f"invalid YAML: {where}{getattr(error, 'problem', None) or error}")]) from None


def _obstacles(entries: Any, file: str) -> tuple[list[dict[str, float]], list[Problem]]:
    """Boxes as {l, w, h, x, y, r}; Aerialist also writes them as one flat list [l,w,h,x,y,z,r,...]."""
    at = "/simulation/obstacles"
    if entries is None:
        return [], []
    if isinstance(entries, list) and entries and all(_number(v) for v in entries):
        if len(entries) % 7:
            return [], [Problem(file, at, f"a flat obstacle list holds 7 numbers per box (l, w, h, x, y, z, r); got {len(entries)}")]
        entries = [{"size": dict(zip("lwh", entries[i:i + 3])), "position": dict(zip("xyzr", entries[i + 3:i + 7]))} for i in range(0, len(entries), 7)]
    if not isinstance(entries, list):
        return [], [Problem(file, at, "expected a list of obstacles")]
    boxes, problems = [], []
    for index, entry in enumerate(entries):
        where = f"{at}/{index}"
        if not isinstance(entry, Mapping) or not isinstance(entry.get("size"), Mapping) or not isinstance(entry.get("position"), Mapping):
            problems.append(Problem(file, where, "expected {size: {l, w, h}, position: {x, y, z, r}}"))
            continue
        if entry.get("shape", "box") != "box":
            problems.append(Problem(file, f"{where}/shape", f"{entry['shape']!r} obstacles are not imported: only boxes"))
            continue
        size, position = entry["size"], entry["position"]
        box: dict[str, float] = {}
        for key, part, positive in (("l", size, True), ("w", size, True), ("h", size, True), ("x", position, False), ("y", position, False)):
            value = part.get(key)
            if not _number(value) or (positive and value <= 0):
                section = "size" if part is size else "position"
                problems.append(Problem(file, f"{where}/{section}/{key}", f"expected a {'positive ' if positive else ''}number of metres, got {value!r}"))
            else:
                box[key] = float(value)
        r = position.get("r", 0)
        if not _number(r):
            problems.append(Problem(file, f"{where}/position/r", f"expected the rotation in degrees, got {r!r}"))
        z = position.get("z", 0)
        if not _number(z) or z != 0:
            problems.append(Problem(file, f"{where}/position/z", f"{z!r}: the competition's obstacles stand on the ground (z = 0)"))
        if len(box) == 5 and _number(r):
            boxes.append({**box, "r": float(r)})
    return boxes, problems


def _resolve(reference: Any, base: Path, file: str, at: str) -> Path:
    """A path in a test file: Aerialist resolves it from where it runs, so try the test's folder first."""
    if not isinstance(reference, str) or not reference:
        raise InputError([Problem(file, at, "expected a file path")])
    for candidate in (base / reference, Path(reference)):
        if candidate.is_file():
            return candidate
    raise InputError([Problem(file, at, f"{reference}: no such file beside the test ({base}) or in the working directory")])


def _home(simulation: Mapping[str, Any], file: str) -> tuple[float, float, float]:
    home = simulation.get("home_position")
    if home is None:
        return PX4_DEFAULT_HOME
    if not isinstance(home, list) or len(home) != 3 or not all(_number(v) for v in home):
        raise InputError([Problem(file, "/simulation/home_position", "expected [latitude deg, longitude deg, altitude m]")])
    return float(home[0]), float(home[1]), float(home[2])


def import_aerialist(path: Path, safety_distance_m: float = COMPETITION_SAFETY_DISTANCE_M) -> tuple[dict[str, Any], dict[str, int | float]]:
    """A competition test file -> (concrete scenario, SUT parameters)."""
    file = str(path)
    document = _load_yaml(path)
    if not isinstance(document, Mapping):
        raise InputError([Problem(file, "", "not an Aerialist test: expected a mapping with drone (or robot) and simulation")])
    section = "drone" if "drone" in document else "robot"
    drone, simulation = document.get(section), document.get("simulation") or {}
    if not isinstance(drone, Mapping):
        raise InputError([Problem(file, "/drone", "missing: a test names its mission_file (and params) under drone")])
    if not isinstance(simulation, Mapping):
        raise InputError([Problem(file, "/simulation", "expected a mapping")])
    if simulation.get("wind"):
        raise InputError([Problem(file, "/simulation/wind", "wind is not imported; remove it, or fly the scenario in a logical scenario with a wind category")])
    boxes, problems = _obstacles(simulation.get("obstacles"), file)
    if problems:
        raise InputError(problems)
    plan_path = _resolve(drone.get("mission_file"), path.parent, file, f"/{section}/mission_file")
    plan_document = load_json(plan_path)
    plan_found = plan_problems(plan_document, str(plan_path))
    if plan_found:
        raise InputError(plan_found)
    params = _params(drone, section, path.parent, file)
    plan_document = copy.deepcopy(plan_document)
    plan_document["mission"]["plannedHomePosition"] = list(_home(simulation, file))
    return _concrete(path.stem, file, plan_document, boxes, safety_distance_m), params


def _params(drone: Mapping[str, Any], section: str, base: Path, file: str) -> dict[str, int | float]:
    if drone.get("params") is not None:
        params = drone["params"]
        if not isinstance(params, Mapping):
            raise InputError([Problem(file, f"/{section}/params", "expected a mapping NAME: value")])
        bad = [name for name, value in params.items() if not _number(value)]
        if bad:
            raise InputError([Problem(file, f"/{section}/params/{bad[0]}", f"{params[bad[0]]!r} is not a finite number")])
        return dict(params)
    if drone.get("params_file") is not None:
        return load_params_file(_resolve(drone["params_file"], base, file, f"/{section}/params_file"))
    return {}


def _concrete(name: str, file: str, plan_document: dict[str, Any], boxes: list[dict[str, float]], safety_distance_m: float) -> dict[str, Any]:
    plan = plan_from_document(plan_document, file)
    area = plan.area()
    for box in boxes:
        area = {"north_min_m": min(area["north_min_m"], box["x"] - AREA_MARGIN_M), "north_max_m": max(area["north_max_m"], box["x"] + AREA_MARGIN_M),
                "east_min_m": min(area["east_min_m"], box["y"] - AREA_MARGIN_M), "east_max_m": max(area["east_max_m"], box["y"] + AREA_MARGIN_M)}
    logical_document = {
        "name": name,
        "description": f"Imported from the UAV Testing Competition test {Path(file).name}: its plan, its boxes, calm and clear.",
        "system": {"UAVs": [{"maneuvers": ["take off", "move to waypoint", "land"]}]},
        "environment": {
            "flight area": {"landform": "flat", "surface nature": "land", "area": area},
            "obstacles": [{"kind": "static", "size": "large", "form": "cuboid",
                           "size range": {"min": min(b["l"], b["w"], b["h"]), "max": max(b["l"], b["w"], b["h"]), "unit": "m"}} for b in boxes],
            "weather": dict(CLEAR_CALM),
            "ranges": {"temperature": {"min": IMPORT_TEMPERATURE_C, "max": IMPORT_TEMPERATURE_C, "unit": "degC"}},
        },
        "mission": {"plan": plan_document},
    }
    profile = _competition_profile(safety_distance_m)
    problems = logical_problems(logical_document, profile, file)
    if problems:
        raise InputError(problems)
    space = SearchSpace(logical_from_document(logical_document, profile, file), profile)
    values = {}
    for index, box in enumerate(boxes):
        prefix = f"obstacle_{index + 1}"
        values.update({f"{prefix}.length_m": box["l"], f"{prefix}.width_m": box["w"], f"{prefix}.height_m": box["h"],
                       f"{prefix}.north_m": box["x"], f"{prefix}.east_m": box["y"], f"{prefix}.yaw_deg": box["r"] % 180.0})
    dimensions = {d.name for d in space.dimensions}
    x = space.with_values(space.lower, {k: v for k, v in values.items() if k in dimensions})
    overlapping = [name for name in space.violations(x) if "do not overlap" in name]
    if overlapping:
        raise InputError([Problem(file, "/simulation/obstacles", f"{overlapping[0].replace(' do not overlap', ' overlap')}: the competition forbids it too")])
    return space.to_concrete(x)


def _competition_profile(safety_distance_m: float):
    """The default profile with the competition's rules: its soft-fail distance, and no keep-out
    zone around start and landing (the competition has none; obstacles may stand anywhere)."""
    document = copy.deepcopy(load_profile("default").document)
    document["name"] = "default-competition"
    document["uav"]["safety_distance_m"] = safety_distance_m
    document["obstacles"]["keep_out_radius_m"] = 0.0
    return profile_from_document(document)


def not_expressible(world: WorldSpec) -> list[str]:
    """Why a flown world cannot be written as a competition test (empty when it can)."""
    reasons = []
    for obstacle in world.obstacles:
        if obstacle["kind"] != "static" or obstacle["form"] != "cuboid":
            reasons.append(f"{obstacle['id']} is a {obstacle['kind']} {obstacle['form']}: the format has static boxes only")
    if world.terrain.get("kind", "flat") != "flat":
        reasons.append(f"the terrain is {world.terrain['kind']}: the competition's world is flat")
    wind = world.atmosphere.wind_speed_m_s
    if wind > 0.0:
        reasons.append(f"wind {wind:.1f} m/s: the competition flies in calm air")
    if world.sensor.range_m < world.sensor.max_range_m:
        reasons.append(f"visibility {world.visibility_m:.0f} m shortens the range sensor: the competition has no fog")
    if world.drive != "mission":
        reasons.append("flown by the pilot drive: the competition flies missions")
    return reasons


def plan_of(world: WorldSpec) -> dict[str, Any]:
    """A QGroundControl plan of the mission the world's flight uploads."""
    from harness.flight.mavsdk_session import mission_items

    origin = world.origin
    items = []
    for item in mission_items(world):
        located = item.x != 0 or item.y != 0
        params = [item.param1, item.param2, item.param3, item.param4, item.x / 1e7 if located else 0, item.y / 1e7 if located else 0, item.z]
        items.append({"autoContinue": True, "command": item.command, "doJumpId": item.seq + 1, "frame": PLAN_FRAMES.get(item.frame, item.frame),
                      "params": [None if isinstance(p, float) and math.isnan(p) else p for p in params], "type": "SimpleItem"})
    home_alt = world.start_msl_m
    return {"fileType": "Plan", "geoFence": {"circles": [], "polygons": [], "version": 2}, "groundStation": "QGroundControl",
            "mission": {"cruiseSpeed": 15, "firmwareType": 12, "globalPlanAltitudeMode": 1, "hoverSpeed": world.mission.cruise_speed_m_s,
                        "items": items, "plannedHomePosition": [origin.lat_deg, origin.lon_deg, home_alt], "vehicleType": 2, "version": 2},
            "rallyPoints": {"points": [], "version": 2}, "version": 1}


def export_aerialist(name: str, concrete: Mapping[str, Any], sut_params: Mapping[str, float], out_dir: Path) -> tuple[Path | None, list[str]]:
    """Write NAME.yaml and NAME.plan for a concrete scenario, or say why it cannot be."""
    from harness.scenario.world import space_from_concrete

    space = space_from_concrete(concrete, name)
    world = world_spec(space, space.from_concrete(concrete, name), 0)
    reasons = not_expressible(world)
    if reasons:
        return None, reasons
    plan = plan_of(world)
    plan_path = out_dir / f"{name}.plan"
    plan_path.write_text(json.dumps(plan, indent=4) + "\n")
    home = plan["mission"]["plannedHomePosition"]
    # As the competition's own cases: PX4 with its avoidance set-up (port and simulator "ros").
    test = {
        "drone": {"port": "ros", "params": dict(sut_params), "mission_file": plan_path.name},
        "simulation": {
            "simulator": "ros", "speed": 1, "headless": True,
            **({"home_position": home} if tuple(home) != PX4_DEFAULT_HOME else {}),
            "obstacles": [{"size": {"l": o["size"]["length_m"], "w": o["size"]["width_m"], "h": o["size"]["height_m"]},
                           "position": {"x": o["a"]["north_m"], "y": o["a"]["east_m"], "z": 0, "r": math.degrees(o["yaw_rad"])}}
                          for o in world.obstacles],
        },
        "mission": {"commands": START_MISSION},
    }
    path = out_dir / f"{name}.yaml"
    path.write_text(yaml.safe_dump(test, sort_keys=False))
    return path, []

