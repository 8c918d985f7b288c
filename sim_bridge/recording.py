"""Ground truth to MCAP with Foxglove's well-known JSON schemas, so a log opens in Foxglove's 3D panel.

Foxglove's scene frame "world" is ENU (x east, y north, z up) and the vehicle frame "uav" is
FLU; the simulation's north/east/up and NED/FRD values are converted here, at the edge.
Log times are simulation time in nanoseconds from the start of the run.
"""

from __future__ import annotations

import json
import math
from typing import Any, BinaryIO, Mapping

import orjson
from mcap.writer import CompressionType, Writer

from sim_bridge.obstacles import Obstacle
from sim_bridge.sensors import rotation_ned_from_body
from sim_bridge.terrain import is_water, terrain_height_m

_TIME = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}
_VECTOR3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_QUATERNION = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}
_POSE = {"type": "object", "properties": {"position": _VECTOR3, "orientation": _QUATERNION}}
_COLOR = {"type": "object", "properties": {k: {"type": "number"} for k in "rgba"}}
_PRIMITIVE = {"type": "object", "properties": {"pose": _POSE, "size": _VECTOR3, "color": _COLOR}}
# foxglove.LineType, as Foxglove's own JSON schema spells the enumeration.
_LINE_TYPE = {
    "title": "foxglove.LineType",
    "oneOf": [{"title": "LINE_STRIP", "const": 0}, {"title": "LINE_LOOP", "const": 1}, {"title": "LINE_LIST", "const": 2}],
}
LINE_STRIP = 0

FOXGLOVE_SCHEMAS: dict[str, dict[str, Any]] = {
    "foxglove.FrameTransform": {
        "title": "foxglove.FrameTransform",
        "type": "object",
        "properties": {
            "timestamp": _TIME,
            "parent_frame_id": {"type": "string"},
            "child_frame_id": {"type": "string"},
            "translation": _VECTOR3,
            "rotation": _QUATERNION,
        },
    },
    "foxglove.PoseInFrame": {
        "title": "foxglove.PoseInFrame",
        "type": "object",
        "properties": {"timestamp": _TIME, "frame_id": {"type": "string"}, "pose": _POSE},
    },
    "foxglove.LocationFix": {
        "title": "foxglove.LocationFix",
        "type": "object",
        "properties": {
            "timestamp": _TIME,
            "frame_id": {"type": "string"},
            "latitude": {"type": "number"},
            "longitude": {"type": "number"},
            "altitude": {"type": "number"},
            "position_covariance": {"type": "array", "items": {"type": "number"}},
            "position_covariance_type": {"type": "integer"},
        },
    },
    "foxglove.SceneUpdate": {
        "title": "foxglove.SceneUpdate",
        "type": "object",
        "properties": {
            "deletions": {
                "type": "array",
                "items": {"type": "object", "properties": {"timestamp": _TIME, "type": {"type": "integer"}, "id": {"type": "string"}}},
            },
            "entities": {
                "type": "array",
                "items": {
                    "type": "object",
                    "properties": {
                        "timestamp": _TIME,
                        "frame_id": {"type": "string"},
                        "id": {"type": "string"},
                        "lifetime": _TIME,
                        "frame_locked": {"type": "boolean"},
                        "metadata": {"type": "array", "items": {"type": "object"}},
                        "cubes": {"type": "array", "items": _PRIMITIVE},
                        "spheres": {"type": "array", "items": _PRIMITIVE},
                        "cylinders": {
                            "type": "array",
                            "items": {
                                "type": "object",
                                "properties": {
                                    "pose": _POSE,
                                    "size": _VECTOR3,
                                    "bottom_scale": {"type": "number"},
                                    "top_scale": {"type": "number"},
                                    "color": _COLOR,
                                },
                            },
                        },
                        "triangles": {
                            "type": "array",
                            "items": {
                                "type": "object",
                                "properties": {
                                    "pose": _POSE,
                                    "points": {"type": "array", "items": _VECTOR3},
                                    "color": _COLOR,
                                    "colors": {"type": "array", "items": _COLOR},
                                    "indices": {"type": "array", "items": {"type": "integer"}},
                                },
                            },
                        },
                        "lines": {
                            "type": "array",
                            "items": {
                                "type": "object",
                                "properties": {
                                    "type": _LINE_TYPE,
                                    "pose": _POSE,
                                    "thickness": {"type": "number", "minimum": 0},
                                    "scale_invariant": {"type": "boolean"},
                                    "points": {"type": "array", "items": _VECTOR3},
                                    "color": _COLOR,
                                    "colors": {"type": "array", "items": _COLOR},
                                    "indices": {"type": "array", "items": {"type": "integer"}},
                                },
                            },
                        },
                    },
                },
            },
        },
    },
}

STELLA_SCHEMAS: dict[str, dict[str, Any]] = {
    "stella.Clearance": {
        "title": "stella.Clearance",
        "description": "Every physics step of a batch: simulation time (s), the smallest UAV-body-to-obstacle distance (m, negative when overlapping; null without obstacles), which obstacle, and the gear's height above the terrain (m).",
        "type": "object",
        "required": ["t", "d", "o", "g"],
        "properties": {
            "t": {"type": "array", "items": {"type": "number"}},
            "d": {"type": "array", "items": {"type": ["number", "null"]}},
            "o": {"type": "array", "items": {"type": ["string", "null"]}},
            "g": {"type": "array", "items": {"type": "number"}},
        },
    },
    "stella.VehicleState": {
        "title": "stella.VehicleState",
        "type": "object",
        "properties": {
            "t": {"type": "number"},
            "north_m": {"type": "number"},
            "east_m": {"type": "number"},
            "up_m": {"type": "number"},
            "v_ned_m_s": {"type": "array", "items": {"type": "number"}},
            "rpy_rad": {"type": "array", "items": {"type": "number"}},
            "motors": {"type": "array", "items": {"type": "number"}},
            "agl_m": {"type": "number"},
        },
    },
    "stella.ObstacleDistance": {
        "title": "stella.ObstacleDistance",
        "type": "object",
        "properties": {"t": {"type": "number"}, "range_m": {"type": "number"}, "distances_cm": {"type": "array", "items": {"type": "integer"}}},
    },
    "stella.Event": {
        "title": "stella.Event",
        "type": "object",
        "properties": {"t": {"type": "number"}, "event": {"type": "string"}, "detail": {"type": "object"}},
    },
    "stella.MavlinkBytes": {
        "title": "stella.MavlinkBytes",
        "description": "Raw MAVLink frames of one link in one direction, hex encoded, batched.",
        "type": "object",
        "properties": {"link": {"type": "string"}, "direction": {"type": "string"}, "hex": {"type": "string"}},
    },
}

# Schemas of topics a log has only when the run needs them.
OPTIONAL_SCHEMAS: dict[str, dict[str, Any]] = {
    "stella.Wind": {
        "title": "stella.Wind",
        "description": "The air's velocity over the ground (NED, m/s) the vehicle flies in: steady wind, turbulence and gust.",
        "type": "object",
        "properties": {"t": {"type": "number"}, "wind_ned_m_s": {"type": "array", "items": {"type": "number"}}},
    },
    "stella.RigReading": {
        "title": "stella.RigReading",
        "description": "One range sensor of the rig, as the SUT got it: an OBSTACLE_DISTANCE source's sectors (cm, from the hull; range + 1 cm: nothing within reach) or a DISTANCE_SENSOR's one reading.",
        "type": "object",
        "properties": {
            "t": {"type": "number"},
            "message": {"type": "string"},
            "range_m": {"type": "number"},
            "increment_deg": {"type": "number"},
            "angle_offset_deg": {"type": "number"},
            "frame": {"type": "string"},
            "distances_cm": {"type": "array", "items": {"type": "integer"}},
            "yaw_deg": {"type": "number"},
            "fov_deg": {"type": "number"},
            "distance_cm": {"type": "integer"},
        },
    },
    "stella.PilotSticks": {
        "title": "stella.PilotSticks",
        "description": "The simulated pilot's RC frame (sticks -1..1 in PX4's manual_control convention, mode-switch slot, raw channels) and where it aims.",
        "type": "object",
        "properties": {
            "t": {"type": "number"},
            "phase": {"type": "string"},
            "roll": {"type": "number"},
            "pitch": {"type": "number"},
            "throttle": {"type": "number"},
            "yaw": {"type": "number"},
            "mode_slot": {"type": "integer"},
            "channels_us": {"type": "array", "items": {"type": "integer"}},
            "segment": {"type": "integer", "description": "the programme's segment flown, from 1 (absent: the route)"},
            "aim_north_m": {"type": "number"},
            "aim_east_m": {"type": "number"},
            "remaining_m": {"type": "number"},
        },
    },
}

SCHEMAS = {**FOXGLOVE_SCHEMAS, **STELLA_SCHEMAS}

TOPICS = {
    "/tf": "foxglove.FrameTransform",
    "/uav/pose": "foxglove.PoseInFrame",
    "/uav/fix": "foxglove.LocationFix",
    "/scene": "foxglove.SceneUpdate",
    "/clearance": "stella.Clearance",
    "/uav/state": "stella.VehicleState",
    "/sensor/obstacle_distance": "stella.ObstacleDistance",
    "/events": "stella.Event",
    "/mavlink/sim": "stella.MavlinkBytes",
    "/mavlink/api": "stella.MavlinkBytes",
}
# Topics a log has only when the run needs them.
COMPANION_TOPIC = "/mavlink/companion"  # a companion computer's link, where a rig's sensor has one
OPTIONAL_TOPICS = {"/pilot": "stella.PilotSticks", "/wind": "stella.Wind", COMPANION_TOPIC: "stella.MavlinkBytes"}
RIG_TOPIC = "/sensor/rig/"  # + a rig sensor's name: stella.RigReading


def optional_schema(topic: str) -> str:
    return "stella.RigReading" if topic.startswith(RIG_TOPIC) else OPTIONAL_TOPICS[topic]


def stamp(time_ns: int) -> dict[str, int]:
    return {"sec": time_ns // 1_000_000_000, "nsec": time_ns % 1_000_000_000}


def quaternion_from_matrix(m) -> dict[str, float]:
    trace = m[0][0] + m[1][1] + m[2][2]
    if trace > 0:
        s = 0.5 / math.sqrt(trace + 1.0)
        return {"w": 0.25 / s, "x": (m[2][1] - m[1][2]) * s, "y": (m[0][2] - m[2][0]) * s, "z": (m[1][0] - m[0][1]) * s}
    if m[0][0] > m[1][1] and m[0][0] > m[2][2]:
        s = 2.0 * math.sqrt(1.0 + m[0][0] - m[1][1] - m[2][2])
        return {"w": (m[2][1] - m[1][2]) / s, "x": 0.25 * s, "y": (m[0][1] + m[1][0]) / s, "z": (m[0][2] + m[2][0]) / s}
    if m[1][1] > m[2][2]:
        s = 2.0 * math.sqrt(1.0 + m[1][1] - m[0][0] - m[2][2])
        return {"w": (m[0][2] - m[2][0]) / s, "x": (m[0][1] + m[1][0]) / s, "y": 0.25 * s, "z": (m[1][2] + m[2][1]) / s}
    s = 2.0 * math.sqrt(1.0 + m[2][2] - m[0][0] - m[1][1])
    return {"w": (m[1][0] - m[0][1]) / s, "x": (m[0][2] + m[2][0]) / s, "y": (m[1][2] + m[2][1]) / s, "z": 0.25 * s}


def enu_flu_orientation(roll: float, pitch: float, yaw: float) -> dict[str, float]:
    """Orientation of the FLU body in the ENU world, from NED/FRD Euler angles."""
    r = rotation_ned_from_body(roll, pitch, yaw)
    # ENU = P * NED with P swapping north/east and negating down; FLU = D * FRD with D = diag(1,-1,-1).
    enu = (r[1], r[0], tuple(-v for v in r[2]))
    m = tuple((row[0], -row[1], -row[2]) for row in enu)
    return quaternion_from_matrix(m)


def yaw_orientation(yaw_from_north_rad: float) -> dict[str, float]:
    """A shape's local x axis pointing yaw clockwise from north, in ENU."""
    angle = math.pi / 2 - yaw_from_north_rad
    return {"x": 0.0, "y": 0.0, "z": math.sin(angle / 2), "w": math.cos(angle / 2)}


def enu(north_m: float, east_m: float, up_m: float) -> dict[str, float]:
    return {"x": east_m, "y": north_m, "z": up_m}


COMPRESSIONS = {"zstd": CompressionType.ZSTD, "none": CompressionType.NONE}


class Recorder:
    """An MCAP writer with the project's channels; use as a context manager so the file is always finished."""

    def __init__(self, stream: BinaryIO, optional_topics: tuple[str, ...] = (), compression: str = "zstd"):
        """compression: "zstd", or "none" for a log that is read once and rewritten (the harness
        compresses the evaluation's log itself)."""
        self._stream = stream
        self._topics = {**TOPICS, **{topic: optional_schema(topic) for topic in optional_topics}}
        self._writer = Writer(stream, compression=COMPRESSIONS[compression])
        self._channels: dict[str, int] = {}

    def __enter__(self) -> "Recorder":
        self._writer.start(profile="", library="stella-uav")
        wanted = set(self._topics.values())
        schema_ids = {
            name: self._writer.register_schema(name=name, encoding="jsonschema", data=json.dumps(schema).encode())
            for name, schema in {**SCHEMAS, **OPTIONAL_SCHEMAS}.items() if name in SCHEMAS or name in wanted
        }
        for topic, schema in self._topics.items():
            self._channels[topic] = self._writer.register_channel(topic=topic, message_encoding="json", schema_id=schema_ids[schema])
        return self

    def __exit__(self, *exc_info) -> None:
        self._writer.finish()

    def write(self, topic: str, *, time_ns: int, message: Mapping[str, Any]) -> None:
        # orjson: a sixth of json.dumps's time, which was a tenth of a lockstep step. The same
        # values (shortest round-trip floats), and numpy's floats as Python's; a NaN or an
        # infinity would be written as null, as JSON has neither (json.dumps wrote tokens no
        # JSON reader takes), but the simulation stays finite (tests/test_fuzz_links.py).
        self.write_raw(topic, time_ns=time_ns, data=orjson.dumps(message, option=orjson.OPT_SERIALIZE_NUMPY))

    def write_raw(self, topic: str, *, time_ns: int, data: bytes) -> None:
        self._writer.add_message(self._channels[topic], log_time=time_ns, data=data, publish_time=time_ns)

    def metadata(self, name: str, values: Mapping[str, str]) -> None:
        self._writer.add_metadata(name, dict(values))


# One colour per kind of obstacle, for its shape and its path, here and in `stella inspect --plot`.
KIND_COLORS: dict[str, dict[str, float]] = {
    "static": {"r": 0.5, "g": 0.5, "b": 0.55, "a": 0.9},  # grey
    "dynamic": {"r": 0.9, "g": 0.4, "b": 0.1, "a": 0.8},  # orange
    "intruder": {"r": 0.75, "g": 0.2, "b": 0.85, "a": 0.8},  # violet: another aircraft, not a moving object
}
PATH_THICKNESS_M = 0.05


def obstacle_kind_color(obstacle: Obstacle) -> dict[str, float]:
    """An intruder's colour, a moving obstacle's, or a still one's (a dynamic obstacle at speed 0 stands still)."""
    if obstacle.kind == "intruder":
        return KIND_COLORS["intruder"]
    return KIND_COLORS["dynamic"] if obstacle.moving else KIND_COLORS["static"]


def _entity(entity_id: str, time_ns: int, metadata: list[dict[str, str]]) -> dict[str, Any]:
    return {
        "timestamp": stamp(time_ns),
        "frame_id": "world",
        "id": entity_id,
        "lifetime": stamp(0),
        "frame_locked": False,
        "metadata": metadata,
        "cubes": [],
        "spheres": [],
        "cylinders": [],
        "triangles": [],
        "lines": [],
    }


def _identity_pose() -> dict[str, dict[str, float]]:
    return {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}


def scene_entity(obstacle: Obstacle, time_ns: int) -> dict[str, Any]:
    """An obstacle as a Foxglove SceneEntity: intruders violet, other moving ones orange, still ones grey."""
    n, e, u = obstacle.position
    pose = {"position": enu(n, e, u), "orientation": yaw_orientation(obstacle.yaw_rad)}
    color = dict(obstacle_kind_color(obstacle))
    size = obstacle.size
    entity = _entity(obstacle.id, time_ns, [{"key": "form", "value": obstacle.form}, {"key": "kind", "value": obstacle.kind}])
    if obstacle.form == "cuboid":
        entity["cubes"].append({"pose": pose, "size": {"x": size["length_m"], "y": size["width_m"], "z": size["height_m"]}, "color": color})
    elif obstacle.form == "sphere":
        d = size["diameter_m"]
        entity["spheres"].append({"pose": pose, "size": {"x": d, "y": d, "z": d}, "color": color})
    else:
        d = size["diameter_m"]
        entity["cylinders"].append(
            {"pose": pose, "size": {"x": d, "y": d, "z": size["height_m"]}, "bottom_scale": 1.0, "top_scale": 1.0, "color": color}
        )
    return entity


def path_entity(obstacle: Obstacle, time_ns: int) -> dict[str, Any] | None:
    """The track a moving obstacle's centre follows, as a thin Foxglove line strip in its kind's
    colour (entity id "<obstacle id>/path"); None for an obstacle that does not move."""
    track = obstacle.track
    if track is None:
        return None
    entity = _entity(f"{obstacle.id}/path", time_ns, [{"key": "kind", "value": obstacle.kind}, {"key": "repeat", "value": obstacle.repeat}])
    entity["lines"].append(
        {
            "type": LINE_STRIP,
            "pose": _identity_pose(),
            "thickness": PATH_THICKNESS_M,
            "scale_invariant": False,
            "points": [enu(n, e, u) for n, e, u in track.tolist()],
            "color": {**obstacle_kind_color(obstacle), "a": 1.0},
            "colors": [],
            "indices": [],
        }
    )
    return entity


def terrain_entity(terrain: Mapping[str, Any], water: Any) -> dict[str, Any]:
    """The terrain around the route as a Foxglove triangle list, water in blue."""
    area = 120.0
    cells = 24
    step = 2 * area / cells
    points, colors = [], []

    def vertex(n: float, e: float) -> None:
        points.append(enu(n, e, terrain_height_m(terrain, n, e)))
        colors.append({"r": 0.2, "g": 0.4, "b": 0.8, "a": 1.0} if is_water(water, n, e) else {"r": 0.35, "g": 0.55, "b": 0.3, "a": 1.0})

    for i in range(cells):
        for j in range(cells):
            n0, e0 = -area + 30 + i * step, -area + j * step
            for n, e in ((n0, e0), (n0 + step, e0), (n0 + step, e0 + step), (n0, e0), (n0 + step, e0 + step), (n0, e0 + step)):
                vertex(n, e)
    entity = _entity("terrain", 0, [{"key": "landform", "value": terrain["kind"]}])
    entity["triangles"].append({"pose": _identity_pose(), "points": points, "color": {"r": 0.35, "g": 0.55, "b": 0.3, "a": 1.0}, "colors": colors, "indices": []})
    return entity
