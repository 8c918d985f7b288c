"""The cascaded multicopter controller: position -> velocity -> attitude -> rate -> mixer.

Pure functions and small classes over plain floats (size-3 numpy arrays cost several times
more per step), with time passed in. Frames: NED for the world, FRD for the body.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

GRAVITY = 9.80665
FEED_FORWARD_TAU_S = 0.1

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]  # w, x, y, z; rotates body FRD into NED

# PX4's quad-X: motor 0 front-right, 1 aft-left, 2 front-left, 3 aft-right. Columns: roll, pitch, yaw.
QUAD_X_MIX = (
    (-1.0, 1.0, 1.0),
    (1.0, -1.0, 1.0),
    (1.0, 1.0, -1.0),
    (-1.0, -1.0, -1.0),
)


def quat_multiply(a: Quat, b: Quat) -> Quat:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def quat_conjugate(q: Quat) -> Quat:
    return (q[0], -q[1], -q[2], -q[3])


def quat_normalize(q: Quat) -> Quat:
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def quat_rotate(q: Quat, v: Vec3) -> Vec3:
    """Rotate a body vector into the world."""
    w, x, y, z = q
    vx, vy, vz = v
    # t = 2 * cross(q.xyz, v); v' = v + w * t + cross(q.xyz, t)
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return (
        vx + w * tx + (y * tz - z * ty),
        vy + w * ty + (z * tx - x * tz),
        vz + w * tz + (x * ty - y * tx),
    )


def quat_rotate_inverse(q: Quat, v: Vec3) -> Vec3:
    return quat_rotate(quat_conjugate(q), v)


def quat_from_euler(roll: float, pitch: float, yaw: float) -> Quat:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy)


def euler_from_quat(q: Quat) -> Vec3:
    w, x, y, z = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def wrap_pi(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def limit_norm2(x: float, y: float, limit: float) -> tuple[float, float]:
    norm = math.hypot(x, y)
    if norm > limit > 0.0:
        return x * limit / norm, y * limit / norm
    return x, y


@dataclass
class Setpoint:
    """What the commander asks for. Horizontal: a position or a velocity; vertical likewise."""

    north_m: float | None = None
    east_m: float | None = None
    down_m: float | None = None
    v_north_m_s: float = 0.0
    v_east_m_s: float = 0.0
    v_down_m_s: float = 0.0
    yaw_rad: float | None = None
    idle: bool = False  # armed on the ground: motors at idle, no control
    manual: bool = False  # Position mode: the sticks make the setpoint (autopilot.manual)
    # Without a valid horizontal position (the position-loss failsafe) nothing horizontal is
    # controlled: level flies level (PX4's Descend), tilt_from_sticks tilts as the sticks say
    # (PX4's Altitude mode, whose vertical and yaw are Position mode's).
    level: bool = False
    tilt_from_sticks: bool = False


class PositionControl:
    """Position and velocity loops; output: thrust vector in NED (normalized collective units)."""

    def __init__(self, params):
        self.params = params
        self.reset()

    def reset(self) -> None:
        self._int_n = self._int_e = self._int_d = 0.0
        self._last_sp: tuple[float, float] | None = None
        self._ff_n = self._ff_e = 0.0

    def hold_level(self) -> None:
        """Nothing horizontal is controlled (no position): the horizontal loop starts afresh when
        it is again, rather than from what it integrated of a dead-reckoned velocity."""
        self._int_n = self._int_e = 0.0
        self._last_sp = None
        self._ff_n = self._ff_e = 0.0

    def _feed_forward(self, dt: float, vel_sp: Vec3) -> tuple[float, float]:
        """The horizontal setpoint's own acceleration, low-passed: without it the velocity loop
        lags a braking setpoint by MPC_ACC_HOR / MPC_XY_VEL_P_ACC and overshoots the stop."""
        if self._last_sp is not None and dt > 0.0:
            alpha = dt / (FEED_FORWARD_TAU_S + dt)
            limit = 2.0 * self.params["MPC_ACC_HOR"]
            raw_n = max(-limit, min(limit, (vel_sp[0] - self._last_sp[0]) / dt))
            raw_e = max(-limit, min(limit, (vel_sp[1] - self._last_sp[1]) / dt))
            self._ff_n += alpha * (raw_n - self._ff_n)
            self._ff_e += alpha * (raw_e - self._ff_e)
        self._last_sp = (vel_sp[0], vel_sp[1])
        return self._ff_n, self._ff_e

    def velocity_setpoint(self, sp: Setpoint, pos: Vec3, limit_xy_m_s: float) -> Vec3:
        p = self.params
        vn, ve = sp.v_north_m_s, sp.v_east_m_s
        if sp.north_m is not None:
            vn += p["MPC_XY_P"] * (sp.north_m - pos[0])
            ve += p["MPC_XY_P"] * (sp.east_m - pos[1])
        vn, ve = limit_norm2(vn, ve, min(limit_xy_m_s, p["MPC_XY_VEL_MAX"]))
        vd = sp.v_down_m_s
        if sp.down_m is not None:
            vd += p["MPC_Z_P"] * (sp.down_m - pos[2])
        vd = max(-p["MPC_Z_VEL_MAX_UP"], min(p["MPC_Z_VEL_MAX_DN"], vd))
        return vn, ve, vd

    def thrust(self, dt: float, vel_sp: Vec3, vel: Vec3, acc: Vec3) -> Vec3:
        p = self.params
        hover = p["MPC_THR_HOVER"]
        en, ee, ed = vel_sp[0] - vel[0], vel_sp[1] - vel[1], vel_sp[2] - vel[2]
        kp, ki, kd = p["MPC_XY_VEL_P_ACC"], p["MPC_XY_VEL_I_ACC"], p["MPC_XY_VEL_D_ACC"]
        ff_n, ff_e = self._feed_forward(dt, vel_sp)
        acc_n = ff_n + kp * en + ki * self._int_n - kd * acc[0]
        acc_e = ff_e + kp * ee + ki * self._int_e - kd * acc[1]
        acc_d = p["MPC_Z_VEL_P_ACC"] * ed + p["MPC_Z_VEL_I_ACC"] * self._int_d
        tilt_max = math.tan(math.radians(p["MPC_TILTMAX_AIR"]))
        # Horizontal acceleration is limited by the tilt the vertical thrust allows.
        acc_n, acc_e = limit_norm2(acc_n, acc_e, tilt_max * GRAVITY)
        thr_n = acc_n * hover / GRAVITY
        thr_e = acc_e * hover / GRAVITY
        thr_d = (acc_d - GRAVITY) * hover / GRAVITY
        thr_d = max(-1.0, min(-p["MPC_THR_MIN"], thr_d))
        saturated_z = thr_d in (-1.0, -p["MPC_THR_MIN"])
        if not saturated_z:
            self._int_d = max(-5.0, min(5.0, self._int_d + ed * dt))
        self._int_n = max(-3.0, min(3.0, self._int_n + en * dt))
        self._int_e = max(-3.0, min(3.0, self._int_e + ee * dt))
        return thr_n, thr_e, thr_d


def attitude_from_thrust(thrust_ned: Vec3, yaw: float) -> tuple[Quat, float]:
    """Attitude whose body -z points along the thrust vector with the given heading; and the collective."""
    tn, te, td = thrust_ned
    norm = math.sqrt(tn * tn + te * te + td * td)
    if norm < 1e-6:
        return quat_from_euler(0.0, 0.0, yaw), 0.0
    zb = (-tn / norm, -te / norm, -td / norm)
    # y_c is the heading's perpendicular in the horizontal plane.
    yc = (-math.sin(yaw), math.cos(yaw), 0.0)
    xb = (yc[1] * zb[2] - yc[2] * zb[1], yc[2] * zb[0] - yc[0] * zb[2], yc[0] * zb[1] - yc[1] * zb[0])
    nx = math.sqrt(xb[0] ** 2 + xb[1] ** 2 + xb[2] ** 2)
    xb = (xb[0] / nx, xb[1] / nx, xb[2] / nx)
    yb = (zb[1] * xb[2] - zb[2] * xb[1], zb[2] * xb[0] - zb[0] * xb[2], zb[0] * xb[1] - zb[1] * xb[0])
    m = ((xb[0], yb[0], zb[0]), (xb[1], yb[1], zb[1]), (xb[2], yb[2], zb[2]))
    trace = m[0][0] + m[1][1] + m[2][2]
    if trace > 0:
        s = 0.5 / math.sqrt(trace + 1.0)
        q = (0.25 / s, (m[2][1] - m[1][2]) * s, (m[0][2] - m[2][0]) * s, (m[1][0] - m[0][1]) * s)
    elif m[0][0] > m[1][1] and m[0][0] > m[2][2]:
        s = 2.0 * math.sqrt(1.0 + m[0][0] - m[1][1] - m[2][2])
        q = ((m[2][1] - m[1][2]) / s, 0.25 * s, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s)
    elif m[1][1] > m[2][2]:
        s = 2.0 * math.sqrt(1.0 + m[1][1] - m[0][0] - m[2][2])
        q = ((m[0][2] - m[2][0]) / s, (m[0][1] + m[1][0]) / s, 0.25 * s, (m[1][2] + m[2][1]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m[2][2] - m[0][0] - m[1][1])
        q = ((m[1][0] - m[0][1]) / s, (m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, 0.25 * s)
    # Collective is the thrust component along the current body axis in PX4; the norm is close enough here.
    return quat_normalize(q), norm


def attitude_rate_setpoint(params, q: Quat, q_sp: Quat) -> Vec3:
    """P control on the quaternion error, body rates in rad/s."""
    qe = quat_multiply(quat_conjugate(q), q_sp)
    sign = 1.0 if qe[0] >= 0.0 else -1.0
    ex, ey, ez = 2.0 * sign * qe[1], 2.0 * sign * qe[2], 2.0 * sign * qe[3]
    yaw_max = math.radians(params["MC_YAWRATE_MAX"])
    rz = max(-yaw_max, min(yaw_max, params["MC_YAW_P"] * ez))
    return params["MC_ROLL_P"] * ex, params["MC_PITCH_P"] * ey, rz


class RateControl:
    def __init__(self, params):
        self.params = params
        self.reset()

    def reset(self) -> None:
        self._int = [0.0, 0.0, 0.0]
        self._last = (0.0, 0.0, 0.0)

    def update(self, dt: float, rates: Vec3, rates_sp: Vec3, landed: bool) -> Vec3:
        p = self.params
        gains = (
            (p["MC_ROLLRATE_P"], p["MC_ROLLRATE_I"], p["MC_ROLLRATE_D"]),
            (p["MC_PITCHRATE_P"], p["MC_PITCHRATE_I"], p["MC_PITCHRATE_D"]),
            (p["MC_YAWRATE_P"], p["MC_YAWRATE_I"], 0.0),
        )
        out = []
        for axis in range(3):
            kp, ki, kd = gains[axis]
            error = rates_sp[axis] - rates[axis]
            derivative = (rates[axis] - self._last[axis]) / dt if dt > 0 else 0.0
            value = kp * error + self._int[axis] - kd * derivative
            if not landed:
                self._int[axis] = max(-0.3, min(0.3, self._int[axis] + ki * error * dt))
            out.append(max(-1.0, min(1.0, value)))
        self._last = rates
        return out[0], out[1], out[2]


def mix(collective: float, torque: Vec3, idle: float = 0.0) -> tuple[float, float, float, float]:
    """Quad-X mixer with thrust-priority desaturation: torques shrink before collective suffers."""
    roll, pitch, yaw = torque
    raw = [collective + r * roll + p * pitch + y * yaw for r, p, y in QUAD_X_MIX]
    high, low = max(raw), min(raw)
    if high > 1.0 or low < idle:
        spread = high - low
        room = 1.0 - idle
        if spread > room and spread > 0.0:
            scale = room / spread
            raw = [collective + (m - collective) * scale for m in raw]
            high, low = max(raw), min(raw)
        if high > 1.0:
            raw = [m - (high - 1.0) for m in raw]
        elif low < idle:
            raw = [m + (idle - low) for m in raw]
    return max(0.0, min(1.0, raw[0])), max(0.0, min(1.0, raw[1])), max(0.0, min(1.0, raw[2])), max(0.0, min(1.0, raw[3]))
