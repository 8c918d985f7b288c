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
from harness.scenario.logical import SIZE_DIMENSIONS, LogicalScenario
from harness.scenario.plan import Plan
from harness.scenario.profile import SIMULATED_WEATHER, Interval, Profile
from sim_bridge.terrain import max_height_on_segment_m

CONCRETE_FORMAT = "stella.concrete/1"


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


@dataclass(frozen=True)
class Mission:
    waypoints: tuple[tuple[float, float, float], ...]  # north_m, east_m, altitude_m above start
    cruise_speed_m_s: float
    land: bool
    drive: str = "mission"  # or "pilot": see README, Drives
    plan: Plan | None = None  # a QGroundControl plan flown item by item

    @property
    def landing_point(self) -> tuple[float, float]:
        if self.plan is not None and self.drive == "mission":
            return self.plan.landing_point
        return self.waypoints[-1][0], self.waypoints[-1][1]


def mission_for(logical: LogicalScenario, profile: Profile) -> Mission:
    """The scenario's mission override, or the landform's: take off, fly to the goal, land."""
    uav = profile.uav
    m = logical.mission or {}
    cruise_speed_m_s = float(m.get("cruise_speed_m_s", uav["cruise_speed_m_s"]))
    plan = logical.plan
    if plan is not None:
        return Mission(
            waypoints=tuple((w.north_m, w.east_m, w.altitude_m) for w in plan.waypoints),
            cruise_speed_m_s=cruise_speed_m_s,
            land=plan.lands,
            drive=logical.drive,
            plan=plan,
        )
    if "waypoints" in m:
        return Mission(
            waypoints=tuple((w["north_m"], w["east_m"], w["altitude_m"]) for w in m["waypoints"]),
            cruise_speed_m_s=cruise_speed_m_s,
            land=bool(m.get("land", True)),
            drive=logical.drive,
        )
    landform = profile.landforms[logical.landform]
    goal = (landform.goal_north_m, landform.goal_east_m)
    highest = max_height_on_segment_m(landform.terrain, (0.0, 0.0), goal)
    altitude_m = uav["cruise_altitude_agl_m"] + max(0.0, highest)
    return Mission(
        waypoints=((goal[0], goal[1], altitude_m),),
        cruise_speed_m_s=cruise_speed_m_s,
        land=bool(m.get("land", True)),
        drive=logical.drive,
    )


class SearchSpace:
    """Bounded float dimensions plus the realism constraints of one logical scenario."""

    def __init__(self, logical: LogicalScenario, profile: Profile):
        self.logical = logical
        self.profile = profile
        self.mission = mission_for(logical, profile)
        self.area = logical.document["environment"]["flight area"].get("area") or (
            self.mission.plan.area() if self.mission.plan else profile.landforms[logical.landform].area)
        self._template: dict[str, Any] = {
            "format": CONCRETE_FORMAT,
            "scenario": logical.name,
            "profile": profile.name,
            "environment": {},
            "obstacles": [],
            "not_simulated": {},
        }
        dimensions: list[Dimension] = []
        fixed: list[FixedValue] = []

        def quantity(name: str, interval: Interval, unit: str, path: tuple[Any, ...]) -> None:
            if interval.min > interval.max:
                raise SpaceError(
                    [Problem(logical.file, "", f"lower {interval.min} > upper {interval.max} for `{name}`: swapped bounds in profile {profile.name}?")]
                )
            if interval.degenerate:
                fixed.append(FixedValue(name, interval.min, unit, path))
                _set(self._template, path, interval.min)
            else:
                dimensions.append(Dimension(name, interval.min, interval.max, unit, path))
                _set(self._template, path, None)

        for parameter, (name, unit) in SIMULATED_WEATHER.items():
            weather = logical.weather[parameter]
            scale = units.factor(weather.unit, unit)
            quantity(name, Interval(weather.interval.min * scale, weather.interval.max * scale), unit, ("environment", name))
            if parameter == "wind force":
                calm = weather.interval.max == 0.0
                quantity("wind_from_deg", Interval(0.0, 0.0) if calm else Interval(0.0, 360.0), "deg", ("environment", "wind_from_deg"))
        for weather in logical.not_simulated:
            self._template["not_simulated"][weather.parameter] = {
                "category": weather.category,
                "min": weather.interval.min,
                "max": weather.interval.max,
                "unit": weather.unit,
                "source": weather.source,
            }

        area = self.area
        north = Interval(area["north_min_m"], area["north_max_m"])
        east = Interval(area["east_min_m"], area["east_max_m"])
        for index, obstacle in enumerate(logical.obstacles):
            prefix = f"obstacle_{index + 1}"
            entry: dict[str, Any] = {"kind": obstacle.kind, "form": obstacle.form, "size": {}, "position": {}}
            self._template["obstacles"].append(entry)
            size = obstacle.size_range or profile.obstacle_sizes[obstacle.size]
            for key in SIZE_DIMENSIONS[obstacle.form]:
                quantity(f"{prefix}.{key}", size, "m", ("obstacles", index, "size", key))
            quantity(f"{prefix}.north_m", north, "m", ("obstacles", index, "position", "north_m"))
            quantity(f"{prefix}.east_m", east, "m", ("obstacles", index, "position", "east_m"))
            if obstacle.form == "cuboid":
                quantity(f"{prefix}.yaw_deg", Interval(0.0, 180.0), "deg", ("obstacles", index, "position", "yaw_deg"))
            if obstacle.kind == "dynamic":
                entry["motion"] = {}
                speed = obstacle.speed_range.scaled(profile.obstacle_speed_factor) if obstacle.speed_range else profile.obstacle_speed_m_s
                motion = ("obstacles", index, "motion")
                quantity(f"{prefix}.altitude_m", profile.obstacle_altitude_m, "m", motion + ("altitude_m",))
                quantity(f"{prefix}.heading_deg", Interval(0.0, 360.0), "deg", motion + ("heading_deg",))
                quantity(f"{prefix}.speed_m_s", speed, "m/s", motion + ("speed_m_s",))
                quantity(f"{prefix}.travel_m", profile.obstacle_travel_m, "m", motion + ("travel_m",))

        self._template["drive"] = self.mission.drive
        # Pilot values a concrete scenario made for the mission drive lacks, when it is flown by
        # the pilot (`--drive pilot`): full stick, aiming along the route.
        self.pilot_defaults: dict[str, float] = {}
        if self.mission.drive == "pilot":
            self._template["pilot"] = {}
            stick, offset = profile.pilot_max_stick, profile.pilot_aim_offset_m
            quantity("pilot.max_stick", stick, "", ("pilot", "max_stick"))
            quantity("pilot.aim_offset_m", offset, "m", ("pilot", "aim_offset_m"))
            self.pilot_defaults = {"pilot.max_stick": stick.max, "pilot.aim_offset_m": min(max(0.0, offset.min), offset.max)}

        self.dimensions = tuple(dimensions)
        self.fixed = tuple(fixed)
        self._index = {d.name: i for i, d in enumerate(self.dimensions)}
        self._fixed = {f.name: f.value for f in self.fixed}
        self.lower = np.array([d.lower for d in self.dimensions], dtype=float)
        self.upper = np.array([d.upper for d in self.dimensions], dtype=float)

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

    def _footprint_radius(self, X: np.ndarray, index: int) -> np.ndarray:
        prefix = f"obstacle_{index + 1}"
        if self.logical.obstacles[index].form == "cuboid":
            return 0.5 * np.hypot(self.column(X, f"{prefix}.length_m"), self.column(X, f"{prefix}.width_m"))
        return 0.5 * self.column(X, f"{prefix}.diameter_m")

    def _points(self, X: np.ndarray, index: int) -> list[tuple[np.ndarray, np.ndarray]]:
        """Where an obstacle is placed: its position, and for a dynamic one also its far end."""
        prefix = f"obstacle_{index + 1}"
        north, east = self.column(X, f"{prefix}.north_m"), self.column(X, f"{prefix}.east_m")
        points = [(north, east)]
        if self.logical.obstacles[index].kind == "dynamic":
            heading = np.radians(self.column(X, f"{prefix}.heading_deg"))
            travel = self.column(X, f"{prefix}.travel_m")
            points.append((north + travel * np.cos(heading), east + travel * np.sin(heading)))
        return points

    def constraint_margins(self, X: np.ndarray) -> dict[str, np.ndarray]:
        """Each realism constraint's margin per row; a row is feasible where all are >= 0."""
        X = np.atleast_2d(X)
        margins: dict[str, np.ndarray] = {}
        keep_out = self.profile.keep_out_radius_m
        landing = self.mission.landing_point
        for index, obstacle in enumerate(self.logical.obstacles):
            name = f"obstacle_{index + 1}"
            radius = self._footprint_radius(X, index)
            for which, (north, east) in zip(("start", "end"), self._points(X, index)):
                where = f"{name} ({which} point)" if obstacle.kind == "dynamic" else name
                margins[f"{where} keeps out of the start area"] = np.hypot(north, east) - radius - keep_out
                margins[f"{where} keeps out of the landing area"] = (
                    np.hypot(north - landing[0], east - landing[1]) - radius - keep_out
                )
        static = [i for i, o in enumerate(self.logical.obstacles) if o.kind == "static"]
        for a_pos, a in enumerate(static):
            for b in static[a_pos + 1 :]:
                (na, ea), (nb, eb) = self._points(X, a)[0], self._points(X, b)[0]
                margins[f"obstacle_{a + 1} and obstacle_{b + 1} do not overlap"] = (
                    np.hypot(na - nb, ea - eb) - self._footprint_radius(X, a) - self._footprint_radius(X, b) - self.profile.min_separation_m
                )
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
