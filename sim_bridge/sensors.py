"""Sensor models: IMU, magnetometer, barometer and GPS from ground truth, with seeded noise and bias.

Real PX4 declares a noiseless barometer stale and refuses to arm, so every sensor is noisy.
Noise is drawn in blocks from one seeded generator: the same seed gives the same readings.
"""

from __future__ import annotations

import math

import numpy as np

from sim_bridge.physics import VehicleState

GRAVITY_M_S2 = 9.80665
# Earth's field near PX4's default home (Zurich): 0.48 gauss, inclination 63.5 deg, declination 3 deg.
_FIELD_GAUSS = 0.48
_INCLINATION = math.radians(63.5)
_DECLINATION = math.radians(3.0)
MAG_NED_GAUSS = (
    _FIELD_GAUSS * math.cos(_INCLINATION) * math.cos(_DECLINATION),
    _FIELD_GAUSS * math.cos(_INCLINATION) * math.sin(_DECLINATION),
    _FIELD_GAUSS * math.sin(_INCLINATION),
)
# HIL_SENSOR.fields_updated: accel, gyro, mag, abs pressure, pressure alt, temperature.
FIELDS_IMU = 0b111111
FIELDS_MAG = 0b111 << 6
FIELDS_BARO = (1 << 9) | (1 << 11) | (1 << 12)
FIELDS_ALL = FIELDS_IMU | FIELDS_MAG | FIELDS_BARO

ACCEL_NOISE_M_S2 = 0.03
GYRO_NOISE_RAD_S = 0.003
MAG_NOISE_GAUSS = 0.002
BARO_NOISE_HPA = 0.012
GPS_NOISE_M = 0.08
GPS_VEL_NOISE_M_S = 0.03
ACCEL_BIAS_M_S2 = 0.02
GYRO_BIAS_RAD_S = 0.0005
_BLOCK = 1024


def pressure_hpa(alt_msl_m: float) -> float:
    """International Standard Atmosphere pressure at an altitude."""
    return 1013.25 * (1.0 - 2.25577e-5 * alt_msl_m) ** 5.25588


def rotation_ned_from_body(roll: float, pitch: float, yaw: float) -> tuple[tuple[float, float, float], ...]:
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return (
        (cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy),
        (cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy),
        (-sp, sr * cp, cr * cp),
    )


def quaternion_from_euler(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


class SensorModel:
    def __init__(self, seed: int, temperature_c: float):
        self._rng = np.random.default_rng(seed)
        self._temperature_c = temperature_c
        bias = self._rng.normal(size=6)
        self._accel_bias = tuple(float(b) * ACCEL_BIAS_M_S2 for b in bias[:3])
        self._gyro_bias = tuple(float(b) * GYRO_BIAS_RAD_S for b in bias[3:])
        self._noise: list[list[float]] = []
        self._gps_noise: list[list[float]] = []
        self._scale = np.array(
            [ACCEL_NOISE_M_S2] * 3 + [GYRO_NOISE_RAD_S] * 3 + [MAG_NOISE_GAUSS] * 3 + [BARO_NOISE_HPA]
        )

    def _next_noise(self) -> list[float]:
        if not self._noise:
            self._noise = (self._rng.standard_normal((_BLOCK, 10)) * self._scale).tolist()[::-1]
        return self._noise.pop()

    def _next_gps_noise(self) -> list[float]:
        if not self._gps_noise:
            scale = np.array([GPS_NOISE_M] * 3 + [GPS_VEL_NOISE_M_S] * 3)
            self._gps_noise = (self._rng.standard_normal((_BLOCK, 6)) * scale).tolist()[::-1]
        return self._gps_noise.pop()

    def hil_sensor_values(self, s: VehicleState) -> tuple[float, ...]:
        """xacc..zacc, xgyro..zgyro, xmag..zmag, abs_pressure, diff_pressure, pressure_alt, temperature."""
        n = self._next_noise()
        if s.on_ground and s.ax_m_s2 == 0.0 and s.az_m_s2 == 0.0:
            # JSBSim reports no specific force before its first step; at rest it is -g along body z.
            ax, ay, az = 0.0, 0.0, -GRAVITY_M_S2
        else:
            ax, ay, az = s.ax_m_s2, s.ay_m_s2, s.az_m_s2
        r = rotation_ned_from_body(s.roll_rad, s.pitch_rad, s.yaw_rad)
        mn, me, md = MAG_NED_GAUSS
        mag_x = r[0][0] * mn + r[1][0] * me + r[2][0] * md
        mag_y = r[0][1] * mn + r[1][1] * me + r[2][1] * md
        mag_z = r[0][2] * mn + r[1][2] * me + r[2][2] * md
        pressure = pressure_hpa(s.alt_msl_m) + n[9]
        pressure_alt = (1.0 - (pressure / 1013.25) ** (1.0 / 5.25588)) / 2.25577e-5
        return (
            ax + self._accel_bias[0] + n[0],
            ay + self._accel_bias[1] + n[1],
            az + self._accel_bias[2] + n[2],
            s.p_rad_s + self._gyro_bias[0] + n[3],
            s.q_rad_s + self._gyro_bias[1] + n[4],
            s.r_rad_s + self._gyro_bias[2] + n[5],
            mag_x + n[6],
            mag_y + n[7],
            mag_z + n[8],
            pressure,
            0.0,
            pressure_alt,
            self._temperature_c - 0.0065 * s.up_m,
        )

    def hil_gps(self, s: VehicleState, to_geodetic) -> dict:
        """HIL_GPS fields (MAVLink units: degE7, mm, cm/s, cdeg)."""
        n = self._next_gps_noise()
        lat, lon = to_geodetic(s.north_m + n[0], s.east_m + n[1])
        vn, ve, vd = s.v_north_m_s + n[3], s.v_east_m_s + n[4], s.v_down_m_s + n[5]
        ground_speed = math.hypot(vn, ve)
        course = math.degrees(math.atan2(ve, vn)) % 360.0
        return {
            "fix_type": 3,
            "lat": int(round(lat * 1e7)),
            "lon": int(round(lon * 1e7)),
            "alt": int(round((s.alt_msl_m + n[2]) * 1000)),
            "eph": 30,
            "epv": 40,
            "vel": int(round(ground_speed * 100)),
            "vn": int(round(vn * 100)),
            "ve": int(round(ve * 100)),
            "vd": int(round(vd * 100)),
            "cog": int(round(course * 100)) % 36000,
            "satellites_visible": 12,
        }
