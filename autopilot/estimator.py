"""State estimation from the HIL sensors: attitude from gyro, accelerometer and magnetometer
(a Mahony complementary filter), position and velocity from accelerometer, GPS and barometer
(a second-order complementary filter per axis). Time is passed in; nothing here does I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from autopilot.control import GRAVITY, Quat, Vec3, quat_from_euler, quat_normalize, quat_rotate, quat_rotate_inverse

EARTH_RADIUS_M = 6378137.0
ACCEL_GAIN = 0.1  # 1/s, only while the accelerometer reads close to 1 g
MAG_GAIN = 0.3
GYRO_BIAS_GAIN = 0.01
GPS_POS_GAIN = 2.0  # 1/s
GPS_VEL_GAIN = 2.0
BARO_POS_GAIN = 3.0
BARO_VEL_GAIN = 1.0
GPS_TIMEOUT_S = 1.0
SENSOR_TIMEOUT_S = 0.2


@dataclass
class GpsFix:
    lat_deg: float
    lon_deg: float
    alt_m: float
    v_north_m_s: float
    v_east_m_s: float
    v_down_m_s: float
    fix_type: int
    satellites: int


class Estimator:
    def __init__(self, mag_declination_rad: float):
        self.declination = mag_declination_rad
        self.q: Quat = (1.0, 0.0, 0.0, 0.0)
        self.rates: Vec3 = (0.0, 0.0, 0.0)
        self.pos: list[float] = [0.0, 0.0, 0.0]  # NED from the local origin
        self.vel: list[float] = [0.0, 0.0, 0.0]
        self.acc_ned: Vec3 = (0.0, 0.0, 0.0)
        self._gyro_bias = [0.0, 0.0, 0.0]
        self.attitude_ready = False
        self.origin: tuple[float, float, float] | None = None  # lat, lon, GPS altitude at the first fix
        self._baro_ref: float | None = None
        self._baro_alt = 0.0
        self.last_gps_s = -math.inf
        self.last_imu_s = -math.inf
        self.last_gps: GpsFix | None = None

    @property
    def position_ready(self) -> bool:
        return self.origin is not None and self.attitude_ready

    def position_valid(self, now_s: float, dead_reckoning_s: float) -> bool:
        """Whether the horizontal position may still be flown on: a GPS fix fused within
        dead_reckoning_s (PX4's EKF2 declares it invalid after EKF2_NOAID_TOUT without aiding)."""
        return self.origin is not None and now_s - self.last_gps_s <= dead_reckoning_s

    def healthy(self, now_s: float) -> bool:
        return self.position_ready and now_s - self.last_gps_s < GPS_TIMEOUT_S and now_s - self.last_imu_s < SENSOR_TIMEOUT_S

    def _initial_attitude(self, accel: Vec3, mag: Vec3) -> None:
        ax, ay, az = accel
        roll = math.atan2(-ay, -az)
        pitch = math.atan2(ax, math.sqrt(ay * ay + az * az))
        q_level = quat_from_euler(roll, pitch, 0.0)
        mn, me, _ = quat_rotate(q_level, mag)
        yaw = math.atan2(-me, mn) + self.declination
        self.q = quat_from_euler(roll, pitch, yaw)
        self.attitude_ready = True

    def update_imu(self, now_s: float, dt: float, gyro: Vec3, accel: Vec3 | None, mag: Vec3 | None) -> None:
        """One gyro sample propagates the attitude. accel or mag None: that sensor gives no new
        information (failed, or its sample dropped), and what it corrects goes uncorrected:
        without the accelerometer, roll and pitch have no gravity reference and velocity and
        position are predicted at constant velocity (acc_ned zero) between GPS and barometer
        corrections; without the magnetometer, the heading follows the gyro alone."""
        self.last_imu_s = now_s
        if not self.attitude_ready:
            if accel is not None and mag is not None:
                self._initial_attitude(accel, mag)
            return
        q = self.q
        ex = ey = ez = 0.0
        if accel is not None:
            a_norm = math.sqrt(accel[0] ** 2 + accel[1] ** 2 + accel[2] ** 2)
            if abs(a_norm - GRAVITY) < 0.1 * GRAVITY:
                # Measured "up" (-specific force) against predicted up (body view of NED -z).
                ux, uy, uz = -accel[0] / a_norm, -accel[1] / a_norm, -accel[2] / a_norm
                px, py, pz = quat_rotate_inverse(q, (0.0, 0.0, -1.0))
                ex += ACCEL_GAIN * (py * uz - pz * uy)
                ey += ACCEL_GAIN * (pz * ux - px * uz)
                ez += ACCEL_GAIN * (px * uy - py * ux)
        if mag is not None:
            # Heading: the measured field, seen in the world, should point at the declination.
            mn, me, _ = quat_rotate(q, mag)
            yaw_error = self.declination - math.atan2(me, mn)
            yaw_error = math.atan2(math.sin(yaw_error), math.cos(yaw_error))
            bx, by, bz = quat_rotate_inverse(q, (0.0, 0.0, 1.0))
            ex += MAG_GAIN * yaw_error * bx
            ey += MAG_GAIN * yaw_error * by
            ez += MAG_GAIN * yaw_error * bz
        bias = self._gyro_bias
        bias[0] -= GYRO_BIAS_GAIN * ex * dt
        bias[1] -= GYRO_BIAS_GAIN * ey * dt
        bias[2] -= GYRO_BIAS_GAIN * ez * dt
        wx = gyro[0] - bias[0] + ex
        wy = gyro[1] - bias[1] + ey
        wz = gyro[2] - bias[2] + ez
        self.rates = (gyro[0] - bias[0], gyro[1] - bias[1], gyro[2] - bias[2])
        w, x, y, z = q
        half = 0.5 * dt
        self.q = quat_normalize(
            (
                w - half * (x * wx + y * wy + z * wz),
                x + half * (w * wx + y * wz - z * wy),
                y + half * (w * wy - x * wz + z * wx),
                z + half * (w * wz + x * wy - y * wx),
            )
        )
        if accel is None:
            self.acc_ned = (0.0, 0.0, 0.0)
        else:
            fn, fe, fd = quat_rotate(self.q, accel)
            self.acc_ned = (fn, fe, fd + GRAVITY)
        if self.origin is not None:
            for axis in range(3):
                self.vel[axis] += self.acc_ned[axis] * dt
                self.pos[axis] += self.vel[axis] * dt

    def update_baro(self, dt: float, pressure_alt_m: float) -> None:
        if self._baro_ref is None:
            self._baro_ref = pressure_alt_m
        self._baro_alt = pressure_alt_m
        if self.origin is None:
            return
        innovation = -(pressure_alt_m - self._baro_ref) - self.pos[2]
        self.pos[2] += BARO_POS_GAIN * innovation * dt
        self.vel[2] += BARO_VEL_GAIN * innovation * dt

    def update_gps(self, now_s: float, dt: float, fix: GpsFix) -> None:
        if fix.fix_type < 3:
            return
        self.last_gps = fix
        if self.origin is None:
            self.origin = (fix.lat_deg, fix.lon_deg, fix.alt_m)
            self.pos = [0.0, 0.0, 0.0]
            self.vel = [fix.v_north_m_s, fix.v_east_m_s, fix.v_down_m_s]
            self.last_gps_s = now_s
            return
        north, east = self.local_from_geodetic(fix.lat_deg, fix.lon_deg)
        gain = min(1.0, GPS_POS_GAIN * dt)
        self.pos[0] += gain * (north - self.pos[0])
        self.pos[1] += gain * (east - self.pos[1])
        vgain = min(1.0, GPS_VEL_GAIN * dt)
        self.vel[0] += vgain * (fix.v_north_m_s - self.vel[0])
        self.vel[1] += vgain * (fix.v_east_m_s - self.vel[1])
        self.vel[2] += vgain * (fix.v_down_m_s - self.vel[2])
        self.last_gps_s = now_s

    def local_from_geodetic(self, lat_deg: float, lon_deg: float) -> tuple[float, float]:
        lat0, lon0, _ = self.origin
        north = math.radians(lat_deg - lat0) * EARTH_RADIUS_M
        east = math.radians(lon_deg - lon0) * EARTH_RADIUS_M * math.cos(math.radians(lat0))
        return north, east

    def geodetic_from_local(self, north_m: float, east_m: float) -> tuple[float, float]:
        lat0, lon0, _ = self.origin
        return (
            lat0 + math.degrees(north_m / EARTH_RADIUS_M),
            lon0 + math.degrees(east_m / (EARTH_RADIUS_M * math.cos(math.radians(lat0)))),
        )

    def altitude_msl(self) -> float:
        return self.origin[2] - self.pos[2] if self.origin else 0.0

    def set_ground_truth(self, q: Quat, rates: Vec3, lat_deg: float, lon_deg: float, alt_m: float, vel: Vec3, accel_body: Vec3) -> None:
        """EKF2_GT_MODE=1: take the simulator's truth instead of estimating."""
        self.q = q
        self.rates = rates
        self.attitude_ready = True
        if self.origin is None:
            self.origin = (lat_deg, lon_deg, alt_m)
        north, east = self.local_from_geodetic(lat_deg, lon_deg)
        self.pos = [north, east, self.origin[2] - alt_m]
        self.vel = list(vel)
        fn, fe, fd = quat_rotate(q, accel_body)
        self.acc_ned = (fn, fe, fd + GRAVITY)
