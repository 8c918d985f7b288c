"""The search space derived from a logical scenario and a profile, and concrete scenarios in it.

A concrete scenario is a vector of floats (what optimizers see) and, equivalently, a readable
JSON document. Every dimension names the place in that document where its value lives, so the
mapping vector <-> JSON is exact in both directions.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from harness.errors import InputError, Problem
from harness.scenario import units
from harness.scenario.documents import pointer
from harness.scenario.logical import SIZE_DIMENSIONS, LogicalScenario, programme_interval, rigged_profile
from harness.scenario.mission import mission_for
from harness.scenario.footprints import Footprints
from harness.scenario.motion import PATH_SAMPLES, RouteTiming, arc_points, intruder_speed, smooth_points
from harness.scenario.profile import SIMULATED_WEATHER, Interval, Profile
from harness.scenario.rig import SENSOR_BEHAVIOUR

CONCRETE_FORMAT = "stella.concrete/1"
# An intruder's track relative to the route's at closest approach, per encounter type (degrees,
# clockwise; 0 flies the route's way). A crossing is anything between overtaking and head-on
# on either side: its range spans both sides and a realism constraint cuts the head-on sector out.
ENCOUNTER_CROSSING_DEG = {"head-on": (150.0, 210.0), "overtaking": (-30.0, 30.0), "crossing": (30.0, 330.0), "any": (0.0, 360.0)}


@dataclass(frozen=True)
class Dimension:
    name: str
    lower: float
    upper: float
    unit: str
    path: tuple[Any, ...]


@dataclass(frozen=True)
class FixedValue:
    """A quantity whose range has collapsed to one value (e.g. no wind): not a dimension."""

    name: str
    value: float
    unit: str
    path: tuple[Any, ...]


class SpaceError(InputError):
    """A profile or scenario produced an unusable search space."""


def _set(document: dict, path: tuple[Any, ...], value: Any) -> None:
    target = document
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value


def _get(document: Any, path: tuple[Any, ...]) -> Any:
    for key in path:
        document = document[key]
    return document


class _Builder:
    """Collects a space's dimensions in order, with the concrete-scenario template their values go into."""

    def __init__(self, logical: LogicalScenario, profile: Profile):
        self.file = logical.file
        self.profile_name = profile.name
        self.template: dict[str, Any] = {
            "format": CONCRETE_FORMAT,
            "scenario": logical.name,
            "profile": profile.name,
            "environment": {},
            "obstacles": [],
            "not_simulated": {},
        }
        self.dimensions: list[Dimension] = []
        self.fixed: list[FixedValue] = []

    def quantity(self, name: str, interval: Interval, unit: str, path: tuple[Any, ...]) -> None:
        """A free quantity: a dimension, or a fixed value where its range has collapsed."""
        if interval.min > interval.max:
            raise SpaceError([Problem(self.file, "", f"lower {interval.min} > upper {interval.max} for `{name}`: swapped bounds in profile {self.profile_name}?")])
        if interval.degenerate:
            self.fixed.append(FixedValue(name, interval.min, unit, path))
            _set(self.template, path, interval.min)
        else:
            self.dimensions.append(Dimension(name, interval.min, interval.max, unit, path))
            _set(self.template, path, None)


class SearchSpace:
    """Bounded float dimensions plus the realism constraints of one logical scenario."""

    def __init__(self, logical: LogicalScenario, profile: Profile):
        self.logical = logical
        self.profile = profile = rigged_profile(profile, logical.document)
        self.mission = mission_for(logical, profile)
        self.area = logical.document["environment"]["flight area"].get("area") or (
            self.mission.plan.area() if self.mission.plan else profile.landforms[logical.landform].area)
        self.timing = RouteTiming(self.mission.waypoints, self.mission.cruise_speed_m_s, self.mission.waypoints[0][2] / profile.climb_speed_m_s)
        during_route = Interval(0.0, round(self.timing.duration_s, 1))
        # The order of the groups is the order of the dimensions: a vector's meaning.
        space = _Builder(logical, profile)
        self._weather(space)
        if logical.gusts != "none":
            self._gusts(space, during_route)
        if logical.failures:
            self._failures(space, during_route)
        if logical.sensors:
            self._sensors(space)
        for index, obstacle in enumerate(logical.obstacles):
            if obstacle.kind == "intruder":
                self._intruder(space, index, obstacle, during_route)
            else:
                self._obstacle(space, index, obstacle)
        space.template["drive"] = self.mission.drive
        self.pilot_defaults: dict[str, float] = {}
        if self.mission.drive == "pilot":
            self._pilot(space)
        self._template = space.template
        self.dimensions = tuple(space.dimensions)
        self.fixed = tuple(space.fixed)
        self._index = {d.name: i for i, d in enumerate(self.dimensions)}
        self._fixed = {f.name: f.value for f in self.fixed}
        self.lower = np.array([d.lower for d in self.dimensions], dtype=float)
        self.upper = np.array([d.upper for d in self.dimensions], dtype=float)

    def _weather(self, space: _Builder) -> None:
        logical = self.logical
        for parameter, (name, unit) in SIMULATED_WEATHER.items():
            weather = logical.weather[parameter]
            scale = units.factor(weather.unit, unit)
            space.quantity(name, Interval(weather.interval.min * scale, weather.interval.max * scale), unit, ("environment", name))
            if parameter == "wind force":
                calm = weather.interval.max == 0.0
                space.quantity("wind_from_deg", Interval(0.0, 0.0) if calm else Interval(0.0, 360.0), "deg", ("environment", "wind_from_deg"))
        for weather in logical.not_simulated:
            space.template["not_simulated"][weather.parameter] = {
                "category": weather.category,
                "min": weather.interval.min,
                "max": weather.interval.max,
                "unit": weather.unit,
                "source": weather.source,
            }

    def _gusts(self, space: _Builder, during_route: Interval) -> None:
        gusts = self.profile.section("gusts")
        band = gusts["categories"][self.logical.gusts]
        space.quantity("turbulence_m_s", Interval.from_json(band["turbulence"]), "m/s", ("environment", "turbulence_m_s"))
        space.template["environment"]["gust"] = {}
        gust = ("environment", "gust")
        space.quantity("gust.amplitude_m_s", Interval.from_json(band["gust"]), "m/s", gust + ("amplitude_m_s",))
        space.quantity("gust.from_deg", Interval(0.0, 360.0), "deg", gust + ("from_deg",))
        space.quantity("gust.onset_s", during_route, "s", gust + ("onset_s",))
        space.quantity("gust.duration_s", Interval.from_json(gusts["gust_duration"]), "s", gust + ("duration_s",))

    def _failures(self, space: _Builder, during_route: Interval) -> None:
        space.template["failures"] = []
        duration = Interval.from_json(self.profile.section("failures")["duration"])
        for index, failure in enumerate(self.logical.failures):
            space.template["failures"].append({"unit": failure.unit, "type": failure.type, **({"sensor": failure.sensor} if failure.sensor else {})})
            space.quantity(f"failure_{index + 1}.onset_s", during_route, "s", ("failures", index, "onset_s"))
            space.quantity(f"failure_{index + 1}.duration_s", duration, "s", ("failures", index, "duration_s"))

    def _sensors(self, space: _Builder) -> None:
        """Each searched behaviour of a rig sensor: its value replaces the rig's in the world."""
        space.template["sensors"] = []
        for index, entry in enumerate(self.logical.sensors):
            space.template["sensors"].append({"sensor": entry["sensor"]})
            for field, (unit, _lowest, _highest) in SENSOR_BEHAVIOUR.items():
                if field in entry:
                    space.quantity(f"sensor.{entry['sensor']}.{field}", Interval(float(entry[field]["min"]), float(entry[field]["max"])), unit,
                                   ("sensors", index, field))

    def _intruder(self, space: _Builder, index: int, obstacle, during_route: Interval) -> None:
        """An intruder UAV by its encounter geometry: when and how it meets the route."""
        profile, prefix = self.profile, f"obstacle_{index + 1}"
        space.template["obstacles"].append(self._intruder_entry(obstacle))
        geometry = ("obstacles", index, "geometry")
        timeline = Interval(round(self.timing.takeoff_s + 0.15 * (during_route.max - self.timing.takeoff_s), 1),
                            round(self.timing.takeoff_s + 0.85 * (during_route.max - self.timing.takeoff_s), 1))
        space.quantity(f"{prefix}.closest_approach_s", timeline, "s", geometry + ("closest_approach_s",))
        space.quantity(f"{prefix}.crossing_deg", Interval(*ENCOUNTER_CROSSING_DEG[obstacle.encounter]), "deg", geometry + ("crossing_deg",))
        space.quantity(f"{prefix}.closing_speed_m_s", profile.intruder_range("closing_speed"), "m/s", geometry + ("closing_speed_m_s",))
        space.quantity(f"{prefix}.vertical_offset_m", profile.intruder_range("vertical_offset"), "m", geometry + ("vertical_offset_m",))
        if obstacle.path == "arc":
            space.quantity(f"{prefix}.turn_rate_deg_s", profile.intruder_range("turn_rate"), "deg/s", geometry + ("turn_rate_deg_s",))

    def _obstacle(self, space: _Builder, index: int, obstacle) -> None:
        """A static or dynamic obstacle: its size, where it stands, and how a dynamic one moves."""
        profile, prefix = self.profile, f"obstacle_{index + 1}"
        north = Interval(self.area["north_min_m"], self.area["north_max_m"])
        east = Interval(self.area["east_min_m"], self.area["east_max_m"])
        entry: dict[str, Any] = {"kind": obstacle.kind, "form": obstacle.form, "size": {}, "position": {}}
        space.template["obstacles"].append(entry)
        size = obstacle.size_range or profile.obstacle_sizes[obstacle.size]
        for key in SIZE_DIMENSIONS[obstacle.form]:
            space.quantity(f"{prefix}.{key}", size, "m", ("obstacles", index, "size", key))
        space.quantity(f"{prefix}.north_m", north, "m", ("obstacles", index, "position", "north_m"))
        space.quantity(f"{prefix}.east_m", east, "m", ("obstacles", index, "position", "east_m"))
        if obstacle.form == "cuboid":
            space.quantity(f"{prefix}.yaw_deg", Interval(0.0, 180.0), "deg", ("obstacles", index, "position", "yaw_deg"))
        if obstacle.kind != "dynamic":
            return
        # A straight motion keeps the paper's four quantities and no "type", so concrete
        # scenarios of Table III read as they always have.
        entry["motion"] = {} if obstacle.motion == "straight" else {"type": obstacle.motion}
        speed = obstacle.speed_range.scaled(profile.obstacle_speed_factor) if obstacle.speed_range else profile.obstacle_speed_m_s
        motion = ("obstacles", index, "motion")
        space.quantity(f"{prefix}.altitude_m", profile.obstacle_altitude_m, "m", motion + ("altitude_m",))
        if obstacle.motion in ("straight", "arc"):
            space.quantity(f"{prefix}.heading_deg", Interval(0.0, 360.0), "deg", motion + ("heading_deg",))
        space.quantity(f"{prefix}.speed_m_s", speed, "m/s", motion + ("speed_m_s",))
        if obstacle.motion == "straight":
            space.quantity(f"{prefix}.travel_m", profile.obstacle_travel_m, "m", motion + ("travel_m",))
        elif obstacle.motion == "arc":
            space.quantity(f"{prefix}.radius_m", profile.obstacle_range("arc_radius"), "m", motion + ("radius_m",))
            space.quantity(f"{prefix}.turn_deg", Interval(-180.0, 180.0), "deg", motion + ("turn_deg",))
        elif obstacle.motion == "vertical":
            space.quantity(f"{prefix}.rise_m", profile.obstacle_range("vertical_travel"), "m", motion + ("rise_m",))
        else:
            for via in ("via_1", "via_2"):
                entry["motion"][via] = {}
                space.quantity(f"{prefix}.{via}.north_m", north, "m", motion + (via, "north_m"))
                space.quantity(f"{prefix}.{via}.east_m", east, "m", motion + (via, "east_m"))

    def _pilot(self, space: _Builder) -> None:
        """The pilot drive's quantities, and the values a concrete scenario made for the mission
        drive lacks when it is flown by the pilot (`--drive pilot`): full stick, aiming along the route."""
        space.template["pilot"] = {}
        stick, offset = self.profile.pilot_max_stick, self.profile.pilot_aim_offset_m
        space.quantity("pilot.max_stick", stick, "", ("pilot", "max_stick"))
        space.quantity("pilot.aim_offset_m", offset, "m", ("pilot", "aim_offset_m"))
        self.pilot_defaults = {"pilot.max_stick": stick.max, "pilot.aim_offset_m": min(max(0.0, offset.min), offset.max)}
        programme = (self.logical.mission or {}).get("programme", [])
        if programme:
            space.template["pilot"]["programme"] = []
        for index, segment in enumerate(programme):
            space.template["pilot"]["programme"].append({"towards": segment["towards"]})
            for field, unit in (("angle_deg", "deg"), ("deflection", ""), ("duration_s", "s"), ("yaw_stick", "")):
                interval = programme_interval(segment, field)
                space.quantity(f"pilot.segment_{index + 1}.{field}", interval, unit, ("pilot", "programme", index, field))
                # A concrete scenario made for the mission drive and flown by the pilot: a short, gentle programme.
                self.pilot_defaults[f"pilot.segment_{index + 1}.{field}"] = interval.min

    def _intruder_entry(self, obstacle) -> dict[str, Any]:
        body = self.profile.section("intruder")["body"]
        return {"kind": "intruder", "form": "cuboid", "encounter": obstacle.encounter, "path": obstacle.path,
                "size": {key: float(body[key]) for key in SIZE_DIMENSIONS["cuboid"]}, "geometry": {}}

    @property
    def n_dimensions(self) -> int:
        return len(self.dimensions)

    # -- sampling and constraints -------------------------------------------------------------

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """n uniform points in the box, feasible or not. The pilot's dimensions come from a
        generator of their own, so one seed gives the same world with either drive."""
        pilot = [i for i, d in enumerate(self.dimensions) if d.path[0] == "pilot"]
        world = [i for i in range(self.n_dimensions) if i not in pilot]
        unit = np.empty((n, self.n_dimensions))
        unit[:, world] = rng.random((n, len(world)))
        if pilot:
            unit[:, pilot] = rng.spawn(1)[0].random((n, len(pilot)))
        return self.lower + (self.upper - self.lower) * unit

    def sample_feasible(self, rng: np.random.Generator, n: int, max_rounds: int = 1000) -> np.ndarray:
        """n uniform points that satisfy every realism constraint (rejection sampling)."""
        accepted: list[np.ndarray] = []
        count = 0
        for _ in range(max_rounds):
            batch = self.sample(rng, max(64, 2 * (n - count)))
            good = batch[self.feasible(batch)]
            accepted.append(good)
            count += len(good)
            if count >= n:
                return np.concatenate(accepted)[:n]
        raise SpaceError(
            [Problem(self.logical.file, "/environment/obstacles", f"found only {count} of {n} feasible placements: the obstacles do not fit the flight area with the profile's keep-out radius")]
        )

    def column(self, X: np.ndarray, name: str) -> np.ndarray:
        if name in self._index:
            return X[:, self._index[name]]
        return np.full(X.shape[0], self._fixed[name])

    def _footprints(self, X: np.ndarray, index: int) -> Footprints:
        """An obstacle's footprint in each row, swept along the path the world spec flies it on."""
        prefix = f"obstacle_{index + 1}"
        obstacle = self.logical.obstacles[index]
        north, east = self.column(X, f"{prefix}.north_m"), self.column(X, f"{prefix}.east_m")
        if obstacle.kind != "dynamic" or obstacle.motion == "vertical":  # stays over its spot
            path_n, path_e = north, east
        elif obstacle.motion == "straight":
            heading = np.radians(self.column(X, f"{prefix}.heading_deg"))
            travel = self.column(X, f"{prefix}.travel_m")
            path_n, path_e = np.stack([north, north + travel * np.cos(heading)], axis=1), np.stack([east, east + travel * np.sin(heading)], axis=1)
        elif obstacle.motion == "arc":
            path_n, path_e = arc_points(north, east, self.column(X, f"{prefix}.heading_deg"), self.column(X, f"{prefix}.radius_m"),
                                        self.column(X, f"{prefix}.turn_deg"), PATH_SAMPLES + 1)
        else:
            vias = [(self.column(X, f"{prefix}.{via}.north_m"), self.column(X, f"{prefix}.{via}.east_m")) for via in ("via_1", "via_2")]
            path_n, path_e = smooth_points([(north, east), *vias], PATH_SAMPLES // 2)
        if obstacle.form == "cuboid":
            return Footprints.rectangles(length_m=self.column(X, f"{prefix}.length_m"), width_m=self.column(X, f"{prefix}.width_m"),
                                         yaw_deg=self.column(X, f"{prefix}.yaw_deg"), path_north_m=path_n, path_east_m=path_e)
        return Footprints.discs(diameter_m=self.column(X, f"{prefix}.diameter_m"), path_north_m=path_n, path_east_m=path_e)

    def intruder_speeds(self, X: np.ndarray, index: int) -> np.ndarray:
        """The ground speed of intruder `index` in each row (NaN where its closing speed cannot be had)."""
        prefix = f"obstacle_{index + 1}"
        return intruder_speed(self.mission.cruise_speed_m_s, self.column(X, f"{prefix}.crossing_deg"), self.column(X, f"{prefix}.closing_speed_m_s"))

    def constraint_margins(self, X: np.ndarray) -> dict[str, np.ndarray]:
        """Each realism constraint's margin per row; a row is feasible where all are >= 0, and a
        row with a value that is not a number breaks every one (-inf)."""
        X = np.atleast_2d(X)
        finite = np.isfinite(X).all(axis=1)
        if finite.all():
            return self._margins(X)
        margins = {}
        for name, margin in self._margins(X[finite]).items():
            margins[name] = np.full(len(X), -np.inf)
            margins[name][finite] = margin
        return margins

    def _margins(self, X: np.ndarray) -> dict[str, np.ndarray]:
        margins: dict[str, np.ndarray] = {}
        keep_out = self.profile.keep_out_radius_m
        landing = self.mission.landing_point
        footprints = {}
        for index, obstacle in enumerate(self.logical.obstacles):
            name = f"obstacle_{index + 1}"
            if obstacle.kind == "intruder":
                margins.update(self._intruder_margins(X, index))
                continue
            footprint = footprints[index] = self._footprints(X, index)
            where = f"{name} (path)" if footprint.moving else name
            margins[f"{where} keeps out of the start area"] = footprint.clearance_to(0.0, 0.0) - keep_out
            margins[f"{where} keeps out of the landing area"] = footprint.clearance_to(*landing) - keep_out
        static = [i for i, o in enumerate(self.logical.obstacles) if o.kind == "static"]
        for a_pos, a in enumerate(static):
            for b in static[a_pos + 1 :]:
                margins[f"obstacle_{a + 1} and obstacle_{b + 1} do not overlap"] = (
                    footprints[a].separation_from(footprints[b]) - self.profile.min_separation_m
                )
        return margins

    def _intruder_margins(self, X: np.ndarray, index: int) -> dict[str, np.ndarray]:
        name = f"obstacle_{index + 1}"
        speeds = self.intruder_speeds(X, index)
        lowest, highest = self.profile.intruder_range("speed").min, self.profile.intruder_range("speed").max
        # An unreachable closing speed scores by how far it falls short, so a search is led back.
        crossing = np.radians(self.column(X, f"{name}.crossing_deg"))
        shortfall = self.column(X, f"{name}.closing_speed_m_s") - self.mission.cruise_speed_m_s * np.abs(np.sin(crossing))
        margins = {
            f"{name} can close at its closing speed from its crossing angle": shortfall,
            f"{name} flies within the intruder's speeds": np.where(np.isnan(speeds), np.minimum(shortfall, -1e-6), np.minimum(speeds - lowest, highest - speeds)),
        }
        if self.logical.obstacles[index].encounter == "crossing":
            head_on_half_width = 180.0 - ENCOUNTER_CROSSING_DEG["head-on"][0]
            margins[f"{name} crosses rather than meets head-on"] = np.abs(self.column(X, f"{name}.crossing_deg") - 180.0) - head_on_half_width
        return margins

    def feasible(self, X: np.ndarray) -> np.ndarray:
        X = np.atleast_2d(X)
        mask = np.ones(X.shape[0], dtype=bool)
        for margin in self.constraint_margins(X).values():
            mask &= margin >= 0.0
        return mask

    def violations(self, x: np.ndarray) -> list[str]:
        """The realism constraints one point breaks, by name."""
        return [name for name, margin in self.constraint_margins(np.asarray(x, dtype=float)[None, :]).items() if margin[0] < 0.0]

    def vector_from(self, values: Mapping[str, float], default: float = 0.5) -> np.ndarray:
        """A vector from named values; unnamed dimensions at `default` of their range (0 lower, 1 upper)."""
        return self.with_values(self.lower + default * (self.upper - self.lower), values)

    def with_values(self, x: np.ndarray, values: Mapping[str, float]) -> np.ndarray:
        """A copy of x with the named dimensions set."""
        unknown = set(values) - set(self._index)
        if unknown:
            raise KeyError(f"no dimensions {sorted(unknown)}; this space has {[d.name for d in self.dimensions]}")
        x = np.array(x, dtype=float)
        for name, value in values.items():
            x[self._index[name]] = value
        return x

    # -- concrete scenarios ------------------------------------------------------------------

    def to_concrete(self, x: np.ndarray) -> dict[str, Any]:
        x = np.asarray(x, dtype=float)
        if x.shape != (self.n_dimensions,):
            raise ValueError(f"expected a vector of {self.n_dimensions} values, got shape {x.shape}")
        document = copy.deepcopy(self._template)
        for dimension, value in zip(self.dimensions, x):
            _set(document, dimension.path, float(value))
        document["logical_scenario"] = copy.deepcopy(dict(self.logical.document))
        document["profile_document"] = copy.deepcopy(dict(self.profile.document))
        return document

    def from_concrete(self, document: Mapping[str, Any], file: str = "<concrete>") -> np.ndarray:
        """The vector of a concrete scenario document; every value is checked against its bounds."""
        problems = []
        values = []
        if document.get("drive", self.mission.drive) != self.mission.drive:
            problems.append(Problem(file, "/drive", f'"{document["drive"]}" but its logical scenario is flown with the {self.mission.drive} drive '
                                                    f'(/logical_scenario/mission/drive, or --drive): make them agree'))
        for section in ("obstacles", "failures"):
            # What its logical scenario does not declare would not be flown: say so rather than fly without it.
            declared, given = self._template.get(section, []), document.get(section, [])
            kinds = [(entry.get("unit"), entry.get("type")) if section == "failures" else entry.get("kind") for entry in given if isinstance(entry, Mapping)]
            wanted = [(entry["unit"], entry["type"]) if section == "failures" else entry["kind"] for entry in declared]
            if kinds != wanted:
                problems.append(Problem(file, f"/{section}", f"{len(given)} {section} ({_listed(kinds)}) but its logical scenario declares "
                                                             f"{len(declared)} ({_listed(wanted)}): declare them in /logical_scenario, which is what is flown"))
        for dimension in self.dimensions:
            at = pointer(dimension.path)
            try:
                value = _get(document, dimension.path)
            except (KeyError, IndexError, TypeError):
                if dimension.name in self.pilot_defaults and "pilot" not in document:
                    values.append(self.pilot_defaults[dimension.name])
                    continue
                problems.append(Problem(file, at, f"missing value for `{dimension.name}` ({dimension.unit})"))
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                problems.append(Problem(file, at, f"expected a finite number for `{dimension.name}`, got {value!r}"))
                continue
            if not dimension.lower <= value <= dimension.upper:
                problems.append(
                    Problem(file, at, f"{value} lies outside [{dimension.lower}, {dimension.upper}] {dimension.unit} for `{dimension.name}`")
                )
            values.append(float(value))
        if problems:
            raise InputError(problems)
        return np.array(values, dtype=float)

    def describe(self) -> dict[str, Any]:
        return {
            "scenario": self.logical.name,
            "profile": self.profile.name,
            "dimensions": [
                {"name": d.name, "lower": d.lower, "upper": d.upper, "unit": d.unit} for d in self.dimensions
            ],
            "fixed": [{"name": f.name, "value": f.value, "unit": f.unit} for f in self.fixed],
            "not_simulated": [
                {"parameter": w.parameter, "category": w.category, "min": w.interval.min, "max": w.interval.max, "unit": w.unit}
                for w in self.logical.not_simulated
            ],
            "constraints": sorted(self.constraint_margins(self.lower[None, :]).keys()),
            "constraint_policy": "infeasible",
        }


def _listed(entries: list) -> str:
    return ", ".join(" ".join(e) if isinstance(e, tuple) else str(e) for e in entries) or "none"
