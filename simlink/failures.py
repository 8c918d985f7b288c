"""Sensor failure injection, defined once for the simulator and the bundled autopilot.

MAVLink's MAV_CMD_INJECT_FAILURE (param1 FAILURE_UNIT, param2 FAILURE_TYPE, param3 instance,
0 for all) asks an autopilot to act as if a sensor failed; a scenario names the same failures
as words ("gps", "off"). What each type does to a unit's readings is fixed here, as constants
and pure functions of the readings and of simulation time, so that the autopilot (at the intake
of the simulator's data) and the simulator (on readings it owns) give a failure one meaning:

* off: the unit's readings are not delivered (or not used) at all.
* stuck: the unit's last reading before the onset is repeated instead of every new one.
* wrong: a plausible but wrong reading: gyro +0.05 rad/s about z (yaw rate), accelerometer
  +1.0 m/s^2 along x, magnetometer field turned 90 degrees about the vertical so that the
  heading reads 90 degrees clockwise of the truth, barometer altitude 10 m too high, GPS
  position 20 m north of the truth, distance sensor seeing nothing in reach (every covered
  sector max_distance + 1 cm).
* intermittent: the readings are dropped during alternate INTERMITTENT_PERIOD_S windows of
  simulation time counted from the onset, the first window dropped.
* slow: the reading is refreshed only every SLOW_FACTOR-th time it arrives after the onset and
  held in between (the held one is the last reading before the onset until the first refresh).
* ok: clears the unit's failure.

A stuck or slow unit without a reading before the onset holds the first one that arrives after
it. Readings are the unit's own: body-frame vectors (FRD) for gyro (rad/s), accelerometer
(m/s^2) and magnetometer (any unit), pressure altitude (m), latitude and longitude (degrees),
OBSTACLE_DISTANCE's distances (cm). Standard library only; nothing here does I/O.
"""

from __future__ import annotations

import math
from enum import IntEnum
from typing import Callable, Generic, Sequence, TypeVar

MAV_CMD_INJECT_FAILURE = 420


class FailureUnit(IntEnum):
    """MAVLink's FAILURE_UNIT values of the units defined here."""

    SENSOR_GYRO = 0
    SENSOR_ACCEL = 1
    SENSOR_MAG = 2
    SENSOR_BARO = 3
    SENSOR_GPS = 4
    SENSOR_DISTANCE_SENSOR = 7


class FailureType(IntEnum):
    """MAVLink's FAILURE_TYPE values (GARBAGE and DELAYED are not defined here: see SUPPORTED_TYPES)."""

    OK = 0
    OFF = 1
    STUCK = 2
    GARBAGE = 3
    WRONG = 4
    SLOW = 5
    DELAYED = 6
    INTERMITTENT = 7


# The scenario format's names.
UNIT_BY_NAME: dict[str, FailureUnit] = {
    "gyro": FailureUnit.SENSOR_GYRO,
    "accelerometer": FailureUnit.SENSOR_ACCEL,
    "magnetometer": FailureUnit.SENSOR_MAG,
    "barometer": FailureUnit.SENSOR_BARO,
    "gps": FailureUnit.SENSOR_GPS,
    "distance sensor": FailureUnit.SENSOR_DISTANCE_SENSOR,
}
NAME_BY_UNIT: dict[FailureUnit, str] = {unit: name for name, unit in UNIT_BY_NAME.items()}
TYPE_BY_NAME: dict[str, FailureType] = {
    "off": FailureType.OFF,
    "stuck": FailureType.STUCK,
    "wrong": FailureType.WRONG,
    "intermittent": FailureType.INTERMITTENT,
    "slow": FailureType.SLOW,
}
NAME_BY_TYPE: dict[FailureType, str] = {kind: name for name, kind in TYPE_BY_NAME.items()}

SUPPORTED_UNITS: frozenset[FailureUnit] = frozenset(FailureUnit)
SUPPORTED_TYPES: frozenset[FailureType] = frozenset({FailureType.OK, *TYPE_BY_NAME.values()})

INTERMITTENT_PERIOD_S = 0.5
SLOW_FACTOR = 5
WRONG_GYRO_OFFSET_RAD_S = (0.0, 0.0, 0.05)
WRONG_ACCEL_OFFSET_M_S2 = (1.0, 0.0, 0.0)
WRONG_MAG_HEADING_OFFSET_RAD = math.pi / 2  # the heading read from the field, clockwise from above
WRONG_BARO_OFFSET_M = 10.0
WRONG_GPS_NORTH_OFFSET_M = 20.0
WRONG_DISTANCE_BEYOND_MAX_CM = 1
EARTH_RADIUS_M = 6378137.0  # WGS-84's equatorial radius: the north offset in latitude, as the autopilot's estimator converts it
_US_PER_S = 1_000_000


def failure_text(unit: FailureUnit, kind: FailureType) -> str:
    """What PX4 reports when it accepts the injection, "CMD_INJECT_FAILURE, gps off" (at most 50 characters: a STATUSTEXT)."""
    return f"CMD_INJECT_FAILURE, {NAME_BY_UNIT[unit]} {kind.name.lower()}"


def intermittent_dropped(*, onset_s: float, now_s: float) -> bool:
    """Whether an intermittent unit's reading at now_s is dropped: during the first
    INTERMITTENT_PERIOD_S after the onset, the third, and so on. Elapsed time is taken in whole
    microseconds (simulation time's resolution on the wire), so window edges are exact."""
    elapsed_us = round((now_s - onset_s) * _US_PER_S)
    if elapsed_us < 0:
        return False
    return (elapsed_us // round(INTERMITTENT_PERIOD_S * _US_PER_S)) % 2 == 0


def slow_refreshed(arrival: int) -> bool:
    """Whether a slow unit's arrival-th reading since the onset (1 for the first) is taken."""
    return arrival % SLOW_FACTOR == 0


def wrong_gyro(rates_rad_s: Sequence[float]) -> tuple[float, float, float]:
    return _offset(rates_rad_s, WRONG_GYRO_OFFSET_RAD_S)


def wrong_accel(specific_force_m_s2: Sequence[float]) -> tuple[float, float, float]:
    return _offset(specific_force_m_s2, WRONG_ACCEL_OFFSET_M_S2)


def wrong_mag(field: Sequence[float]) -> tuple[float, float, float]:
    """The body field turned about body z by -WRONG_MAG_HEADING_OFFSET_RAD: the heading it gives
    (atan2(-y, x) when level) is WRONG_MAG_HEADING_OFFSET_RAD more than the truth's."""
    c, s = math.cos(WRONG_MAG_HEADING_OFFSET_RAD), math.sin(WRONG_MAG_HEADING_OFFSET_RAD)
    x, y, z = field
    return (c * x + s * y, -s * x + c * y, z)


def wrong_baro_altitude(altitude_m: float) -> float:
    return altitude_m + WRONG_BARO_OFFSET_M


def wrong_gps_position(lat_deg: float, lon_deg: float) -> tuple[float, float]:
    return lat_deg + math.degrees(WRONG_GPS_NORTH_OFFSET_M / EARTH_RADIUS_M), lon_deg


def wrong_distances(distances_cm: Sequence[int], *, max_distance_cm: int, unknown_cm: int = 65535) -> list[int]:
    """OBSTACLE_DISTANCE's sectors with nothing in reach: every covered sector (not unknown_cm,
    UINT16_MAX) reads max_distance_cm + 1."""
    beyond = max_distance_cm + WRONG_DISTANCE_BEYOND_MAX_CM
    return [d if d == unknown_cm else beyond for d in distances_cm]


def _offset(vector: Sequence[float], offset: tuple[float, float, float]) -> tuple[float, float, float]:
    return (vector[0] + offset[0], vector[1] + offset[1], vector[2] + offset[2])


Reading = TypeVar("Reading")


class Failure(Generic[Reading]):
    """One unit's active failure from its onset: apply() turns each arriving reading into what
    is delivered, or None when nothing is. Stateful only where the type is (the held reading,
    the count of arrivals); deterministic in simulation time and arrival order.

    wrong: the unit's wrong reading from the true one (one of the wrong_* functions, or the
    caller's adapter of one to its own reading type); needed for FailureType.WRONG only.
    """

    def __init__(self, kind: FailureType, *, onset_s: float, last_reading: Reading | None,
                 wrong: Callable[[Reading], Reading] | None = None) -> None:
        if kind not in SUPPORTED_TYPES or kind == FailureType.OK:
            raise ValueError(f"{kind!r} is not a failure defined here; defined: {', '.join(NAME_BY_TYPE.values())}")
        if kind == FailureType.WRONG and wrong is None:
            raise ValueError("a wrong failure needs its unit's wrong reading (wrong=...)")
        self.kind = kind
        self.onset_s = onset_s
        self.held = last_reading
        self.arrivals = 0
        self._wrong = wrong

    def apply(self, now_s: float, reading: Reading) -> Reading | None:
        kind = self.kind
        if kind == FailureType.OFF:
            return None
        if kind == FailureType.WRONG:
            return self._wrong(reading)
        if kind == FailureType.INTERMITTENT:
            return None if intermittent_dropped(onset_s=self.onset_s, now_s=now_s) else reading
        if self.held is None:
            self.held = reading
        if kind == FailureType.SLOW:
            self.arrivals += 1
            if slow_refreshed(self.arrivals):
                self.held = reading
        return self.held
