"""The world spec: everything the simulator needs for one flight, in SI units and the local
north/east/up frame. The harness makes it (harness/scenario/world.py), a job carries it to a
worker, the bridge loads it and records it in the flight's log; every reader of a log reads it
back through `WorldSpec.from_dict`, which names the field of a bad or missing value.

JSON only at the edges (`as_dict`, `from_dict`); in between it is typed and frozen.
"""

from __future__ import annotations

import collections.abc
import dataclasses
import math
import types
import typing
from dataclasses import dataclass, field
from typing import Any, Mapping, Union

WORLD_FORMAT = "stella.world/1"


class SpecError(ValueError):
    """A world spec that cannot be loaded: `pointer` is the JSON pointer of the bad value."""

    def __init__(self, pointer: str, message: str):
        self.pointer = pointer
        self.message = message
        super().__init__(f"{pointer or '/'}: {message}")


@dataclass(frozen=True)
class Origin:
    """The geodetic point of north = east = 0 at the datum's zero height."""

    lat_deg: float
    lon_deg: float
    alt_m: float


@dataclass(frozen=True)
class Point:
    north_m: float
    east_m: float
    up_m: float


@dataclass(frozen=True)
class Surface:
    kind: str
    water: tuple[Mapping[str, float], ...]  # rectangles north_min_m/north_max_m/east_min_m/east_max_m


@dataclass(frozen=True)
class Turbulence:
    """Dryden turbulence: intensities (standard deviations) and scale lengths, horizontal and vertical."""

    sigma_horizontal_m_s: float
    sigma_vertical_m_s: float
    length_horizontal_m: float
    length_vertical_m: float


@dataclass(frozen=True)
class Gust:
    """A discrete 1-cosine gust: from `from_deg`, rising from nothing to `amplitude_m_s` and back
    over `duration_s` from run time `onset_s`."""

    amplitude_m_s: float
    from_deg: float
    onset_s: float
    duration_s: float


@dataclass(frozen=True)
class Atmosphere:
    wind_north_m_s: float
    wind_east_m_s: float
    temperature_c: float
    turbulence: Turbulence | None = None
    gust: Gust | None = None

    @property
    def wind_speed_m_s(self) -> float:
        return math.hypot(self.wind_north_m_s, self.wind_east_m_s)

    @property
    def varies(self) -> bool:
        """Whether the wind changes during the flight (turbulence or a gust), not only steady."""
        return self.turbulence is not None or self.gust is not None


@dataclass(frozen=True)
class RangeSensor:
    """The profile's forward depth sensor; range_m is its reach in this world's visibility."""

    max_range_m: float
    min_range_m: float
    fov_deg: float
    update_hz: float
    full_range_visibility_m: float
    floor_range_m: float
    range_m: float


RIG_MESSAGES = ("DISTANCE_SENSOR", "OBSTACLE_DISTANCE")
RIG_FRAMES = ("body", "local")


@dataclass(frozen=True)
class RigSensor:
    """One range sensor of the vehicle's rig (harness/scenario/rig.py), as the world renders it:
    a DISTANCE_SENSOR device, one reading over its field of view, or an OBSTACLE_DISTANCE
    source, one reading per sector of increment_deg. Its field of view is centred on yaw_deg,
    clockwise from the nose; range_m is its reach in this world's visibility; its readings come
    rate_hz times a second and reach the SUT latency_s after they were measured, each reading of
    an obstacle within reach off by Gaussian noise of standard deviation noise_m. frame: an
    OBSTACLE_DISTANCE source's sectors relative to the nose ("body", MAV_FRAME_BODY_FRD) or to
    north ("local", MAV_FRAME_LOCAL_NED)."""

    name: str
    message: str
    yaw_deg: float
    fov_deg: float
    min_range_m: float
    max_range_m: float
    range_m: float
    rate_hz: float
    latency_s: float = 0.0
    increment_deg: float = 5.0
    frame: str = "body"
    noise_m: float = 0.0


@dataclass(frozen=True)
class Body:
    length_m: float
    width_m: float
    height_m: float


@dataclass(frozen=True)
class Uav:
    start: Point
    body: Body


@dataclass(frozen=True)
class Waypoint:
    north_m: float
    east_m: float
    altitude_m: float
    acceptance_radius_m: float | None = None  # None: the harness's default


@dataclass(frozen=True)
class Landing:
    north_m: float
    east_m: float


@dataclass(frozen=True)
class MissionSpec:
    """The route as the harness flies and scores it; a plan's items also as they are uploaded."""

    takeoff_altitude_m: float
    waypoints: tuple[Waypoint, ...]
    cruise_speed_m_s: float
    land: bool
    landing: Landing | None = None  # where a plan lands, when not at its last waypoint
    plan_items: tuple[Mapping[str, Any], ...] | None = None  # MISSION_ITEM_INT fields of an uploaded plan


FAILURE_DELIVERIES = ("simulator", "sut")


@dataclass(frozen=True)
class FailureSpec:
    """A failure injected from run time `onset_s` for `duration_s`: by the simulator into readings
    it owns, or by MAV_CMD_INJECT_FAILURE to the SUT (simlink/failures.py defines the units and types)."""

    unit: str
    type: str
    onset_s: float
    duration_s: float
    delivery: str
    sensor: str | None = None  # the one rig sensor of the distance sensor that fails (None: every one)


PILOT_REFERENCES = ("route", "obstacle")


@dataclass(frozen=True)
class PilotSegment:
    """One segment of a pilot programme (sim_bridge/pilot.py): for duration_s the pilot pushes the
    stick deflection (0..1) in the direction angle_deg clockwise from the reference, where the
    pilot would push along the route ("route") or towards the nearest obstacle ("obstacle"), and
    turns with the yaw stick at yaw_stick (-1..1)."""

    towards: str
    angle_deg: float
    deflection: float
    duration_s: float
    yaw_stick: float = 0.0


@dataclass(frozen=True)
class PilotSpec:
    max_stick: float
    aim_offset_m: float
    # Flown from the start of the cruise, before the pilot pushes along the route (None: at once).
    programme: tuple[PilotSegment, ...] | None = None


@dataclass(frozen=True)
class WorldSpec:
    scenario: str
    seed: int
    origin: Origin
    terrain: Mapping[str, Any]  # sim_bridge/terrain.py reads it by its "kind"
    surface: Surface
    atmosphere: Atmosphere
    visibility_m: float
    sensor: RangeSensor
    obstacles: tuple[Mapping[str, Any], ...]  # sim_bridge/obstacles.py's Obstacle.from_spec reads each
    uav: Uav
    mission: MissionSpec
    safety_distance_m: float
    time_limit_s: float
    drive: str = "mission"
    not_simulated: Mapping[str, Any] = field(default_factory=dict)
    pilot: PilotSpec | None = None
    failures: tuple[FailureSpec, ...] | None = None
    # The vehicle's range sensors, each rendered into its own messages; None: the profile's one
    # forward sensor (`sensor`), rendered as the SUT reads it (Capabilities.range_messages).
    rig: tuple[RigSensor, ...] | None = None
    format: str = WORLD_FORMAT

    @property
    def start_msl_m(self) -> float:
        return self.origin.alt_m + self.uav.start.up_m

    def as_dict(self) -> dict[str, Any]:
        """The JSON document (optional parts left out when unset, as older readers expect)."""
        return _plain(self)

    @classmethod
    def from_dict(cls, document: Any) -> "WorldSpec":
        """The spec of a JSON document; SpecError names the first bad or missing field."""
        spec = _decode(cls, document, "")
        if spec.format != WORLD_FORMAT:
            raise SpecError("/format", f"{spec.format!r} is not {WORLD_FORMAT!r}: a world spec of another version of stella")
        if spec.drive not in ("mission", "pilot"):
            raise SpecError("/drive", f"{spec.drive!r} is neither 'mission' nor 'pilot'")
        if spec.drive == "pilot" and spec.pilot is None:
            raise SpecError("/pilot", "missing: the pilot drive needs the pilot's max_stick and aim_offset_m")
        for index, segment in enumerate(spec.pilot.programme or () if spec.pilot is not None else ()):
            if segment.towards not in PILOT_REFERENCES:
                raise SpecError(f"/pilot/programme/{index}/towards", f"{segment.towards!r} is not one of {', '.join(PILOT_REFERENCES)}")
        for index, sensor in enumerate(spec.rig or ()):
            if sensor.message not in RIG_MESSAGES:
                raise SpecError(f"/rig/{index}/message", f"{sensor.message!r} is not one of {', '.join(RIG_MESSAGES)}")
            if sensor.frame not in RIG_FRAMES:
                raise SpecError(f"/rig/{index}/frame", f"{sensor.frame!r} is not one of {', '.join(RIG_FRAMES)}")
        for index, failure in enumerate(spec.failures or ()):
            if failure.delivery not in FAILURE_DELIVERIES:
                raise SpecError(f"/failures/{index}/delivery", f"{failure.delivery!r} is neither 'simulator' nor 'sut'")
        if not spec.mission.waypoints:
            raise SpecError("/mission/waypoints", "empty: a mission needs at least one waypoint")
        return spec


def _plain(value: Any) -> Any:
    if dataclasses.is_dataclass(value):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value) if getattr(value, f.name) is not None}
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    return value


def _decode(kind: Any, value: Any, pointer: str) -> Any:
    """value (parsed JSON) as the type kind, or SpecError at pointer."""
    origin = typing.get_origin(kind)
    if origin in (Union, types.UnionType):
        options = [k for k in typing.get_args(kind) if k is not type(None)]
        return None if value is None else _decode(options[0], value, pointer)
    if dataclasses.is_dataclass(kind):
        if not isinstance(value, Mapping):
            raise SpecError(pointer, f"is not an object: {kind.__name__} expected")
        hints = typing.get_type_hints(kind)
        unknown = sorted(set(value) - set(hints) - {"description"})
        if unknown:
            raise SpecError(f"{pointer}/{unknown[0]}", f"unknown field of {kind.__name__}; known: {', '.join(hints)}")
        arguments = {}
        for f in dataclasses.fields(kind):
            if f.name in value:
                arguments[f.name] = _decode(hints[f.name], value[f.name], f"{pointer}/{f.name}")
            elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise SpecError(f"{pointer}/{f.name}", "missing")
        return kind(**arguments)
    if origin is tuple:
        if not isinstance(value, list):
            raise SpecError(pointer, "is not a list")
        item = typing.get_args(kind)[0]
        return tuple(_decode(item, v, f"{pointer}/{i}") for i, v in enumerate(value))
    if origin is collections.abc.Mapping or kind is Mapping:
        if not isinstance(value, Mapping):
            raise SpecError(pointer, "is not an object")
        return dict(value)
    if kind is bool:
        if not isinstance(value, bool):
            raise SpecError(pointer, f"{value!r} is not true or false")
        return value
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise SpecError(pointer, f"{value!r} is not an integer")
        return value
    if kind is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise SpecError(pointer, f"{value!r} is not a finite number")
        return value
    if kind is str:
        if not isinstance(value, str):
            raise SpecError(pointer, f"{value!r} is not a string")
        return value
    raise TypeError(f"no decoder for {kind!r}")
