"""The vehicle's range-sensor rig (sim_bridge/spec.py: RigSensor) rendered into the messages the
SUT reads: each DISTANCE_SENSOR device's one reading over its field of view, each
OBSTACLE_DISTANCE source's sectors, every sensor at its own rate, delivered its latency after it
was measured, and recorded as the SUT gets it (/sensor/rig/NAME).

Rays are cast from the vehicle's hull, as for the profile's one forward sensor (sim_bridge/world.py):
a sector of 5 degrees or less is one ray at its centre, as that sensor's are; a wider sector or a
DISTANCE_SENSOR's field of view is as close as the closest of rays at most MAX_RAY_GAP_DEG apart.
"""

from __future__ import annotations

import collections
import math
from typing import Callable

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from sim_bridge.spec import RigSensor
from simlink import codec
from simlink.failures import wrong_distances

SECTORS = 72  # OBSTACLE_DISTANCE's distances array
NO_READING = 65535
MAX_RAY_GAP_DEG = 2.5
FRAMES = {"body": mavlink.MAV_FRAME_BODY_FRD, "local": mavlink.MAV_FRAME_LOCAL_NED}


def sector_layout(sensor: RigSensor) -> tuple[int, float]:
    """An OBSTACLE_DISTANCE source's number of sectors and the angle of the first one's centre:
    as many sectors of increment_deg as its field of view holds (at most 72), the field of view
    centred on yaw_deg; a full circle starts at yaw_deg."""
    if sensor.fov_deg >= 360.0:
        return min(SECTORS, int(round(360.0 / sensor.increment_deg))), sensor.yaw_deg
    count = min(SECTORS, max(1, int(round(sensor.fov_deg / sensor.increment_deg))))
    return count, sensor.yaw_deg - count * sensor.increment_deg / 2.0 + sensor.increment_deg / 2.0


# How an autopilot reads DISTANCE_SENSOR, which MAVLink leaves open: the direction as a custom
# rotation's quaternion (PX4; a named rotation too) or as one of the eight yaws
# MAV_SENSOR_ROTATION_NONE..YAW_315 names (ArduPilot's proximity backend drops any other), and
# "nothing within reach" as a reading at the maximum (PX4 takes current_distance < max_distance
# as an obstacle) or beyond it (ArduPilot takes a reading at the maximum as an obstacle there).
DISTANCE_SENSOR_CONVENTIONS = {"px4": (False, 0), "ardupilot": (True, 1)}


def named_rotation_of(yaw_deg: float) -> int:
    """MAV_SENSOR_ROTATION_NONE .. YAW_315 for a yaw that is a multiple of 45 degrees."""
    eighths = yaw_deg / 45.0
    if not float(eighths).is_integer():
        raise ValueError(f"a named sensor rotation faces a multiple of 45 degrees, not {yaw_deg}")
    return int(eighths) % 8


def sensor_rays(sensor: RigSensor) -> list[tuple[int, float]]:
    """A sensor's rays as (which of its readings, angle in degrees from the nose, or from north for
    a `local` source): a sector of 5 degrees or less one ray at its centre, a wider sector or a
    DISTANCE_SENSOR's field of view a fan of rays."""
    if sensor.message == "OBSTACLE_DISTANCE":
        count, first_deg = sector_layout(sensor)
        return [(sector, angle) for sector in range(count)
                for angle in _fan(first_deg + sector * sensor.increment_deg, sensor.increment_deg if sensor.increment_deg > 5.0 else 0.0)]
    return [(0, angle) for angle in _fan(sensor.yaw_deg, sensor.fov_deg)]


def _fan(centre_deg: float, width_deg: float) -> list[float]:
    """Ray angles across a width centred on centre_deg, its edges included, at most MAX_RAY_GAP_DEG apart."""
    if width_deg <= 0.0:
        return [centre_deg]
    gaps = max(1, int(math.ceil(width_deg / MAX_RAY_GAP_DEG)))
    return [centre_deg - width_deg / 2.0 + width_deg * k / gaps for k in range(gaps + 1)]


class _Sensor:
    """One sensor's rays (degrees from the nose or from north, by frame) and which reading each is part of."""

    def __init__(self, sensor: RigSensor, sensor_id: int, every_steps: int, latency_steps: int, companion: bool, convention: str, seed: int):
        self.spec = sensor
        # Its noise, a stream of its own per sensor: the other sensors' and the IMU's stay as they were.
        self.noise = np.random.default_rng([seed, 0x7267, sensor_id]) if sensor.noise_m > 0.0 else None
        self.companion = companion
        self.sensor_id = sensor_id
        self.every_steps = every_steps
        self.latency_steps = latency_steps
        self.reach_cm = int(sensor.range_m * 100)
        self.min_cm = int(sensor.min_range_m * 100)
        if sensor.message == "OBSTACLE_DISTANCE":
            self.count, self.first_deg = sector_layout(sensor)
        rays = sensor_rays(sensor)
        self.ray_reading = np.array([reading for reading, _angle in rays])
        self.ray_rad = np.radians([angle for _reading, angle in rays])
        self.world_fixed = sensor.message == "OBSTACLE_DISTANCE" and sensor.frame == "local"
        half_fov = math.radians(sensor.fov_deg) / 2.0
        self.quaternion = [math.cos(math.radians(sensor.yaw_deg) / 2.0), 0.0, 0.0, math.sin(math.radians(sensor.yaw_deg) / 2.0)]
        named_rotation, beyond_cm = DISTANCE_SENSOR_CONVENTIONS[convention]
        self.orientation = named_rotation_of(sensor.yaw_deg) if named_rotation else mavlink.MAV_SENSOR_ROTATION_CUSTOM
        # A DISTANCE_SENSOR's reading where nothing is within its reach.
        self.nothing_cm = self.reach_cm + beyond_cm
        self.fov_rad = 2.0 * half_fov


class RigFrames:
    """A rig's messages step by step. rate_hz: the lockstep rate; hull_offset(body_angles_rad):
    how far from the vehicle's centre the hull is in each direction; nearest(world_angles_rad,
    reach_m): the distance from the centre to the nearest obstacle along each ray (None: none
    within reach); encode(codec, *fields): a MAVLink frame of the simulator link;
    record(topic, time_us, message). The sensors whose message is one of companion_messages go
    to a companion computer's link instead, each frame made by encode_companion. A
    DISTANCE_SENSOR is written as the SUT reads it: distance_sensor_convention, one of
    DISTANCE_SENSOR_CONVENTIONS. A sensor's noise is drawn from the world's seed."""

    def __init__(self, rig: tuple[RigSensor, ...], rate_hz: float, hull_offset: Callable[[np.ndarray], np.ndarray],
                 nearest: Callable[[np.ndarray, float], np.ndarray | None], encode, record,
                 companion_messages: tuple[str, ...] = (), encode_companion=None, distance_sensor_convention: str = "px4", seed: int = 0):
        self.sensors = [_Sensor(sensor, index, max(1, int(round(rate_hz / sensor.rate_hz))), int(round(sensor.latency_s * rate_hz)),
                                sensor.message in companion_messages, distance_sensor_convention, seed)
                        for index, sensor in enumerate(rig)]
        self.hull_offset = hull_offset
        self.nearest = nearest
        self.encode = encode
        self.encode_companion = encode_companion
        self.record = record
        # (step due, companion link?, the message and its fields), in order of due step: encoded
        # when sent, so that each link's sequence numbers count up in the order frames go out.
        self._in_flight: collections.deque[tuple[int, bool, tuple]] = collections.deque()

    def step_frames(self, step: int, time_us: int, yaw_rad: float, delivered) -> tuple[list[bytes], list[bytes]]:
        """The frames due at this step, for the simulator link and for the companion link:
        readings measured now with no latency, and those measured their latency ago.
        delivered(name, distances_cm, reach_cm): the reading as a failure leaves it (None:
        nothing is sent)."""
        for sensor in self.sensors:
            if step % sensor.every_steps == 0:
                message = self._measure(sensor, time_us, yaw_rad, delivered)
                if message is not None:
                    self._queue(step + sensor.latency_steps, sensor.companion, message)
        simulator: list[bytes] = []
        companion: list[bytes] = []
        while self._in_flight and self._in_flight[0][0] <= step:
            _due, to_companion, (kind, fields) = self._in_flight.popleft()
            if to_companion:
                companion.append(self.encode_companion(kind, *fields))
            else:
                simulator.append(self.encode(kind, *fields))
        return simulator, companion

    def _queue(self, due_step: int, to_companion: bool, message: tuple) -> None:
        if not self._in_flight or self._in_flight[-1][0] <= due_step:
            self._in_flight.append((due_step, to_companion, message))
            return
        ordered = sorted([*self._in_flight, (due_step, to_companion, message)], key=lambda entry: entry[0])
        self._in_flight = collections.deque(ordered)

    def _readings_cm(self, sensor: _Sensor, yaw_rad: float) -> list[int]:
        """Each reading's centimetres from the hull (the sensor's reach + 1 where nothing is within it)."""
        world = sensor.ray_rad if sensor.world_fixed else sensor.ray_rad + yaw_rad
        body = world - yaw_rad
        hull = self.hull_offset(body)
        count = sensor.count if sensor.spec.message == "OBSTACLE_DISTANCE" else 1
        nothing = sensor.reach_cm + 1
        nearest = self.nearest(world, sensor.spec.range_m + float(np.max(hull)))
        if nearest is None:
            return [nothing] * count
        closest = [math.inf] * count
        for reading, distance in zip(sensor.ray_reading.tolist(), (nearest - hull).tolist()):
            if distance <= sensor.spec.range_m:
                closest[reading] = min(closest[reading], distance)
        if sensor.noise is not None:
            # Off by the noise, still within the range it reads: within reach an obstacle stays one.
            closest = [min(sensor.spec.range_m, d + sensor.noise.normal(0.0, sensor.spec.noise_m)) if d < math.inf else d for d in closest]
        return [max(sensor.min_cm, int(d * 100)) if d < math.inf else nothing for d in closest]

    def _measure(self, sensor: _Sensor, time_us: int, yaw_rad: float, delivered) -> tuple | None:
        """A reading as a message to send, (codec, fields), recorded; None: nothing is sent."""
        spec = sensor.spec
        readings = delivered(spec.name, self._readings_cm(sensor, yaw_rad), sensor.reach_cm)
        if readings is None:
            return None
        if spec.message == "OBSTACLE_DISTANCE":
            distances = readings + [NO_READING] * (SECTORS - len(readings))
            self.record(f"/sensor/rig/{spec.name}", time_us, {"t": time_us / 1e6, "message": spec.message, "range_m": spec.range_m,
                                                               "increment_deg": spec.increment_deg, "angle_offset_deg": sensor.first_deg,
                                                               "frame": spec.frame, "distances_cm": readings})
            increment = int(spec.increment_deg) if float(spec.increment_deg).is_integer() else 0
            return codec.OBSTACLE_DISTANCE, (time_us, mavlink.MAV_DISTANCE_SENSOR_LASER, distances, increment, sensor.min_cm, sensor.reach_cm,
                                             spec.increment_deg, sensor.first_deg, FRAMES[spec.frame])
        current_cm = min(readings[0], sensor.nothing_cm)
        self.record(f"/sensor/rig/{spec.name}", time_us, {"t": time_us / 1e6, "message": spec.message, "range_m": spec.range_m,
                                                           "yaw_deg": spec.yaw_deg, "fov_deg": spec.fov_deg, "distance_cm": current_cm})
        return codec.DISTANCE_SENSOR, (time_us // 1000, sensor.min_cm, sensor.reach_cm, current_cm, mavlink.MAV_DISTANCE_SENSOR_LASER,
                                       sensor.sensor_id, sensor.orientation, 0, sensor.fov_rad, sensor.fov_rad, sensor.quaternion, 0)


def wrong_rig_reading(readings: list[int], reach_cm: int) -> list[int]:
    """A failed unit's wrong reading: nothing within reach in every direction it covers."""
    return wrong_distances(readings, max_distance_cm=reach_cm)
