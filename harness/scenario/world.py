"""From a concrete scenario to the world spec the simulator loads, and loading concrete files."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from harness.errors import InputError, Problem
from harness.scenario.documents import load_json
from harness.scenario.logical import logical_from_document, logical_problems, with_drive, with_plan_embedded, with_rig_embedded
from harness.scenario.motion import PATH_SAMPLES, arc_points, intruder_speed, intruder_track, smooth_points
from harness.scenario.profile import profile_from_document, profile_problems
from harness.scenario.rig import rig_sensors
from harness.scenario.mission import Mission
from harness.scenario.space import CONCRETE_FORMAT, SearchSpace
from sim_bridge.spec import (Atmosphere, Body, FailureSpec, Gust, Landing, MissionSpec, Origin, PilotSegment, PilotSpec, Point, RangeSensor, Surface,
                             Turbulence, Uav, Waypoint, WorldSpec)
from sim_bridge.terrain import terrain_height_m

# PX4 SITL's default home (Zurich), so that logs of either SUT line up on the same map.
ORIGIN = Origin(lat_deg=47.397742, lon_deg=8.545594, alt_m=488.0)
# Failures of readings the simulator owns are applied there, as PX4's simulator does for its own
# sensors; the others reach the SUT as MAV_CMD_INJECT_FAILURE (docs/scenarios.md, Failures).
SIMULATOR_FAILURE_UNITS = ("distance sensor", "gps")


def sensor_range_m(sensor: Mapping[str, Any], visibility_m: float) -> float:
    """The profile's sensor model: reach shrinks linearly below full-range visibility."""
    reach = sensor["max_range_m"] * min(1.0, visibility_m / sensor["full_range_visibility_m"])
    return max(sensor["floor_range_m"], reach)


def _obstacle(space: SearchSpace, concrete: Mapping[str, Any], index: int) -> dict[str, Any]:
    entry = concrete["obstacles"][index]
    terrain = space.profile.landforms[space.logical.landform].terrain
    size = dict(entry["size"])
    height_m = size.get("height_m", size.get("diameter_m"))
    north, east = entry["position"]["north_m"], entry["position"]["east_m"]
    ground = terrain_height_m(terrain, north, east)
    obstacle: dict[str, Any] = {
        "id": f"obstacle_{index + 1}",
        "kind": entry["kind"],
        "form": entry["form"],
        "size": size,
        "yaw_rad": math.radians(entry["position"].get("yaw_deg", 0.0)),
    }
    if entry["kind"] == "static":
        obstacle["a"] = {"north_m": north, "east_m": east, "up_m": ground + height_m / 2.0}
        obstacle["b"] = None
        obstacle["speed_m_s"] = 0.0
        return obstacle
    motion = entry["motion"]
    up = ground + motion["altitude_m"] + height_m / 2.0
    kind = motion.get("type", "straight")
    if kind == "vertical":
        obstacle["a"] = {"north_m": north, "east_m": east, "up_m": up}
        obstacle["b"] = {"north_m": north, "east_m": east, "up_m": up + motion["rise_m"]}
        obstacle["speed_m_s"] = motion["speed_m_s"]
        return obstacle
    if kind == "straight":
        heading = math.radians(motion["heading_deg"])
        obstacle["a"] = {"north_m": north, "east_m": east, "up_m": up}
        obstacle["b"] = {
            "north_m": north + motion["travel_m"] * math.cos(heading),
            "east_m": east + motion["travel_m"] * math.sin(heading),
            "up_m": up,
        }
        obstacle["speed_m_s"] = motion["speed_m_s"]
        return obstacle
    obstacle["speed_m_s"] = motion["speed_m_s"]
    if kind == "arc":
        path_n, path_e = arc_points(north, east, motion["heading_deg"], motion["radius_m"], motion["turn_deg"], PATH_SAMPLES + 1)
    else:
        vias = [(motion[via]["north_m"], motion[via]["east_m"]) for via in ("via_1", "via_2")]
        path_n, path_e = smooth_points([(north, east), *vias], PATH_SAMPLES // 2)
    return _with_path(obstacle, [(n, e, up) for n, e in zip(path_n.tolist(), path_e.tolist())], "back_and_forth")


def _with_path(obstacle: dict[str, Any], points: list[tuple[float, float, float]], repeat: str) -> dict[str, Any]:
    path = [{"north_m": n, "east_m": e, "up_m": u} for n, e, u in points]
    return {**obstacle, "a": path[0], "b": path[-1], "path": path, "repeat": repeat}


def _intruder(space: SearchSpace, concrete: Mapping[str, Any], index: int, start_up_m: float, until_s: float) -> dict[str, Any]:
    """Another multirotor flying level at constant speed that passes the point where the UAV is
    expected at the time of closest approach, crossing the route at the searched angle."""
    entry = concrete["obstacles"][index]
    geometry = entry["geometry"]
    meet_n, meet_e, meet_altitude, route_heading = (float(v) for v in space.timing.at(geometry["closest_approach_s"]))
    speed = float(intruder_speed(space.mission.cruise_speed_m_s, geometry["crossing_deg"], geometry["closing_speed_m_s"]))
    heading_deg = (route_heading + geometry["crossing_deg"]) % 360.0
    track = intruder_track((meet_n, meet_e, start_up_m + meet_altitude + geometry["vertical_offset_m"]), heading_deg, speed,
                           geometry.get("turn_rate_deg_s", 0.0), geometry["closest_approach_s"], until_s)
    obstacle = {"id": f"obstacle_{index + 1}", "kind": "intruder", "form": "cuboid", "size": dict(entry["size"]),
                "yaw_rad": math.radians(heading_deg), "speed_m_s": speed}
    return _with_path(obstacle, track, "once")


def _atmosphere(environment: Mapping[str, Any], gusts: Mapping[str, Any]) -> Atmosphere:
    wind_toward = math.radians(environment["wind_from_deg"] + 180.0)
    turbulence = gust = None
    if "turbulence_m_s" in environment:
        sigma = environment["turbulence_m_s"]
        lengths = gusts["turbulence_length_m"]
        turbulence = Turbulence(sigma_horizontal_m_s=sigma, sigma_vertical_m_s=sigma * gusts["vertical_ratio"],
                                length_horizontal_m=lengths["horizontal"], length_vertical_m=lengths["vertical"])
    if "gust" in environment:
        gust = Gust(**environment["gust"])
    return Atmosphere(
        wind_north_m_s=environment["wind_speed_m_s"] * math.cos(wind_toward),
        wind_east_m_s=environment["wind_speed_m_s"] * math.sin(wind_toward),
        temperature_c=environment["temperature_c"],
        turbulence=turbulence,
        gust=gust,
    )


def world_spec(space: SearchSpace, x: np.ndarray, seed: int) -> WorldSpec:
    """Everything the simulator needs for one run, in SI units and the local north/east/up frame."""
    concrete = space.to_concrete(x)
    environment = concrete["environment"]
    profile = space.profile
    landform = profile.landforms[space.logical.landform]
    mission = space.mission
    start_up_m = terrain_height_m(landform.terrain, 0.0, 0.0)
    sensor = {k: v for k, v in profile.sensor.items() if k != "description"}
    # A pilot's programme is flown before the route: the route gets its time on top.
    programme_s = sum(segment["duration_s"] for segment in concrete.get("pilot", {}).get("programme", ())) if mission.drive == "pilot" else 0.0
    time_limit_s = _time_limit_s(mission, profile.time_limit_s) + programme_s
    obstacles = tuple(_intruder(space, concrete, i, start_up_m, time_limit_s) if entry["kind"] == "intruder" else _obstacle(space, concrete, i)
                      for i, entry in enumerate(concrete["obstacles"]))
    failures = tuple(FailureSpec(unit=f["unit"], type=f["type"], onset_s=f["onset_s"], duration_s=f["duration_s"],
                                 delivery="simulator" if f["unit"] in SIMULATOR_FAILURE_UNITS else "sut", sensor=f.get("sensor"))
                     for f in concrete.get("failures", ()))
    return WorldSpec(
        scenario=space.logical.name,
        seed=int(seed),
        origin=ORIGIN if mission.plan is None else Origin(**{**mission.plan.origin, "alt_m": mission.plan.home[2] - start_up_m}),
        terrain=dict(landform.terrain),
        surface=Surface(kind=space.logical.surface, water=tuple(profile.surfaces[space.logical.surface]["water"])),
        atmosphere=_atmosphere(environment, profile.section("gusts")),
        visibility_m=environment["visibility_m"],
        sensor=RangeSensor(**sensor, range_m=sensor_range_m(profile.sensor, environment["visibility_m"])),
        obstacles=obstacles,
        uav=Uav(start=Point(north_m=0.0, east_m=0.0, up_m=start_up_m),
                body=Body(**{k: v for k, v in profile.uav["body"].items() if k != "description"})),
        mission=_mission(mission),
        safety_distance_m=profile.safety_distance_m,
        time_limit_s=time_limit_s,
        not_simulated=concrete["not_simulated"],
        drive=mission.drive,
        pilot=_pilot(concrete["pilot"]) if mission.drive == "pilot" else None,
        failures=failures or None,
        rig=None if profile.rig is None else rig_sensors(profile.rig, profile.sensor, environment["visibility_m"], concrete.get("sensors", ())),
    )


def _pilot(pilot: Mapping[str, Any]) -> PilotSpec:
    programme = tuple(PilotSegment(**segment) for segment in pilot.get("programme", ()))
    return PilotSpec(max_stick=pilot["max_stick"], aim_offset_m=pilot["aim_offset_m"], programme=programme or None)


def _mission(mission: Mission) -> MissionSpec:
    """The route as the harness flies and scores it; a plan's items also as they are uploaded."""
    if mission.plan is None:
        return MissionSpec(
            takeoff_altitude_m=mission.waypoints[0][2],
            waypoints=tuple(Waypoint(north_m=n, east_m=e, altitude_m=a) for n, e, a in mission.waypoints),
            cruise_speed_m_s=mission.cruise_speed_m_s,
            land=mission.land,
        )
    plan = mission.plan
    landing_north, landing_east = plan.landing_point
    return MissionSpec(
        takeoff_altitude_m=plan.takeoff_altitude_m,
        waypoints=tuple(Waypoint(north_m=north, east_m=east, altitude_m=altitude, acceptance_radius_m=radius)
                        for north, east, altitude, radius in plan.route),
        cruise_speed_m_s=mission.cruise_speed_m_s,
        land=plan.lands,
        landing=Landing(north_m=landing_north, east_m=landing_east),
        plan_items=tuple(plan.upload_items()),
    )


def _time_limit_s(mission: Mission, profile_limit_s: float) -> float:
    """The profile's limit, stretched for a plan that needs longer (twice its estimated duration
    plus a minute for take-off, landing and braking)."""
    if mission.plan is None:
        return profile_limit_s
    return max(profile_limit_s, 2.0 * mission.plan.flight_time_estimate_s(mission.cruise_speed_m_s) + 60.0)


def with_drive_recorded(document: Any, drive: str | None) -> Any:
    """A concrete scenario document whose recorded drive is `drive` (unchanged for None)."""
    return {**document, "drive": drive} if drive is not None and isinstance(document, dict) else document


def space_with_rig(space: SearchSpace, rig: str) -> SearchSpace:
    """The space with a rig's sensors (a preset or file, --rig), its logical scenario checked
    against them again: a failure of one sensor, or a sensor's searched behaviour, must name one
    of the rig's."""
    document = with_rig_embedded(space.logical.document, Path(space.logical.file), rig)
    problems = logical_problems(document, space.profile, space.logical.file)
    if problems:
        raise InputError(problems)
    return SearchSpace(logical_from_document(document, space.profile, space.logical.file), space.profile)


def space_from_concrete(document: Any, file: str, drive: str | None = None, mission_plan: Path | None = None) -> SearchSpace:
    """Rebuild the search space from the logical scenario and profile a concrete file embeds;
    `drive` overrides the logical scenario's drive (`--drive`), `mission_plan` its route."""
    if not isinstance(document, dict) or document.get("format") != CONCRETE_FORMAT:
        raise InputError([Problem(file, "/format", f'not a concrete scenario: expected "format": "{CONCRETE_FORMAT}"')])
    for key in ("logical_scenario", "profile_document"):
        if key not in document:
            raise InputError([Problem(file, f"/{key}", "missing: a concrete scenario embeds its logical scenario and profile")])
    problems = profile_problems(document["profile_document"], file)
    if problems:
        raise InputError([Problem(p.file, "/profile_document" + p.pointer, p.message) for p in problems])
    profile = profile_from_document(document["profile_document"])
    logical = with_rig_embedded(with_plan_embedded(with_drive(document["logical_scenario"], drive), Path(file).parent, mission_plan), Path(file))
    problems = logical_problems(logical, profile, file)
    if problems:
        raise InputError([Problem(p.file, "/logical_scenario" + p.pointer, p.message) for p in problems])
    return SearchSpace(logical_from_document(logical, profile, file), profile)


def load_concrete(path: Path, drive: str | None = None, mission_plan: Path | None = None) -> tuple[SearchSpace, np.ndarray]:
    """A concrete scenario file; `drive` flies it with another drive than it was made for,
    `mission_plan` along another route."""
    document = with_drive_recorded(load_json(path), drive)
    space = space_from_concrete(document, str(path), drive, mission_plan)
    return space, space.from_concrete(document, str(path))
