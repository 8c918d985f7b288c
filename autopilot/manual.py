"""Manual control as PX4 does it: RC channels into sticks and a mode slot, and Position mode.

* `sticks_from_rc` is PX4's rc_update: each raw channel (microseconds) is normalised with its
  RCn_MIN / RCn_TRIM / RCn_MAX / RCn_REV / RCn_DZ, the RC_MAP_* parameters say which channel is
  which stick, and the RC_MAP_FLTMODE channel selects one of six mode slots with PX4's formula.
  Without RC_CHAN_CNT and a stick mapping the input counts as uncalibrated, as in PX4.
* `PositionMode` is PX4's FlightTaskManualPosition with MPC_POS_MODE 4 (StickAccelerationXY):
  the sticks, with PX4's dead zone and expo, command an acceleration in the heading frame, a
  drag term limits the speed to MPC_VEL_MANUAL and brakes when the sticks are released, the
  jerk is limited by MPC_JERK_MAX, and the position and altitude are locked when the vehicle
  stands still. Collision prevention constrains the velocity setpoint this produces (app.py),
  and `constrained` feeds the constrained value back; or, with CP_STICK_ACCEL, it reshapes the
  sticks' acceleration before the drag, as PX4's does since v1.15.

Pure logic over floats with time passed in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

GRAVITY = 9.80665
RC_CHANNELS = 8
MODE_SLOTS = 6
# PX4's COM_FLTMODEn values (manual_control's navStateFromParam) of the modes the bundled
# autopilot has, as (main mode, sub mode) of px4_custom_mode.h.
FLIGHT_MODE_PARAM = {2: (3, 0), 3: (4, 4), 4: (4, 3), 5: (4, 5), 10: (4, 2), 11: (4, 6)}
BRAKE_BOOST_TAU_S = 0.8


@dataclass(frozen=True)
class Sticks:
    """Stick positions in PX4's manual_control_setpoint convention, each -1..1: roll right,
    pitch forward, yaw clockwise and throttle up positive (throttle 0 at the centre); and the
    mode slot (1-6, 0 none)."""

    roll: float
    pitch: float
    yaw: float
    throttle: float
    mode_slot: int
    received_s: float


def normalized_channel(raw: float, minimum: float, trim: float, maximum: float, reverse: float, deadzone: float) -> float:
    """One channel to -1..1 as rc_update scales it (linear on each side of the trim)."""
    raw = min(max(raw, minimum), maximum)
    if raw > trim + deadzone:
        value = (raw - trim - deadzone) / (maximum - trim - deadzone)
    elif raw < trim - deadzone:
        value = (raw - trim + deadzone) / (trim - minimum - deadzone)
    else:
        value = 0.0
    value = -value if reverse < 0.0 else value
    return value if math.isfinite(value) else 0.0


def mode_slot(value: float) -> int:
    """rc_update's mode slot (1-6) of a normalised mode-switch channel."""
    slot_width_half = 1.0 / MODE_SLOTS
    slot_min, slot_max = -1.05, 1.05
    slot = int(((value - slot_min) * MODE_SLOTS + slot_width_half) / (slot_max - slot_min) + slot_width_half) + 1
    return min(slot, MODE_SLOTS)


def sticks_from_rc(params, now_s: float, channel_count: int, raw: list[int]) -> Sticks | None:
    """The sticks an RC frame gives, or None when PX4 would not use it (too few channels, or the
    RC not set up: RC_CHAN_CNT 0 or no stick mapped)."""
    mapped = [int(params[f"RC_MAP_{name}"]) for name in ("ROLL", "PITCH", "YAW", "THROTTLE")]
    if channel_count < 4 or params["RC_CHAN_CNT"] <= 0 or not any(mapped):
        return None

    def channel(number: int) -> float:
        if number < 1 or number > min(channel_count, RC_CHANNELS):
            return 0.0
        n = number
        return normalized_channel(raw[n - 1], params[f"RC{n}_MIN"], params[f"RC{n}_TRIM"], params[f"RC{n}_MAX"], params[f"RC{n}_REV"], params[f"RC{n}_DZ"])

    roll, pitch, yaw, throttle = (channel(number) for number in mapped)
    mode_channel = int(params["RC_MAP_FLTMODE"])
    slot = mode_slot(channel(mode_channel)) if mode_channel > 0 else 0
    return Sticks(roll, pitch, yaw, throttle, slot, now_s)


def expo(value: float, e: float) -> float:
    x = min(max(value, -1.0), 1.0)
    return (1.0 - e) * x + e * x * x * x


def deadzone(value: float, dz: float) -> float:
    x = min(max(value, -1.0), 1.0)
    return math.copysign(max(0.0, abs(x) - dz) / (1.0 - dz), x) if abs(x) > dz else 0.0


def expo_deadzone(value: float, e: float, dz: float) -> float:
    return expo(deadzone(value, dz), e)


def _sign(value: float) -> int:
    return (value > 0.0) - (value < 0.0)


def _slew(current: float, target: float, rate: float, dt: float) -> float:
    step = rate * dt
    return min(max(target, current - step), current + step)


class PositionMode:
    """Sticks to a setpoint: (north, east, down position or None, velocity north, east, down, yaw)."""

    def __init__(self, params):
        self.params = params
        self.reset(0.0, 0.0, (0.0, 0.0, 0.0), 0.0)

    def reset(self, v_north: float, v_east: float, position: tuple[float, float, float], yaw: float) -> None:
        self.v_north, self.v_east = v_north, v_east
        self._a_prev = (0.0, 0.0)
        self._brake_boost = 1.0
        self.hold_ne: tuple[float, float] | None = None
        self.hold_down: float | None = position[2]
        self.yaw_sp = yaw

    def constrained(self, v_north: float, v_east: float) -> None:
        """Collision prevention's velocity setpoint replaces the one the sticks built up."""
        self.v_north, self.v_east = v_north, v_east

    def update(self, dt: float, sticks: Sticks, position: tuple[float, float, float], yaw: float, collision_prevention=None):
        """collision_prevention, where given, reshapes the sticks' acceleration (north, east) given
        the velocity setpoint, as PX4's acts in StickAccelerationXY (collision.px4_stick_acceleration)."""
        p = self.params
        dz = p["MPC_HOLD_DZ"]
        vel_manual = p["MPC_VEL_MANUAL"]
        acc_scale = 2.0 * p["MPC_ACC_HOR"]  # drag halves the average acceleration
        forward = expo_deadzone(sticks.pitch, p["MPC_XY_MAN_EXPO"], dz)
        right = expo_deadzone(sticks.roll, p["MPC_XY_MAN_EXPO"], dz)
        length = math.hypot(forward, right)
        if length > 1.0:
            forward, right = forward / length, right / length
        cos_y, sin_y = math.cos(yaw), math.sin(yaw)
        stick_n, stick_e = forward * cos_y - right * sin_y, forward * sin_y + right * cos_y
        a_n, a_e = stick_n * acc_scale, stick_e * acc_scale
        if collision_prevention is not None:
            a_n, a_e = collision_prevention((a_n, a_e), (self.v_north, self.v_east))
        stick_released = forward == 0.0 and right == 0.0
        alpha = dt / (BRAKE_BOOST_TAU_S + dt)
        boost_target = max(2.0, math.sqrt(vel_manual)) if stick_released else 1.0
        self._brake_boost += alpha * (boost_target - self._brake_boost)
        coefficient = acc_scale / vel_manual * self._brake_boost
        speed = math.hypot(self.v_north, self.v_east)
        brake_scale = min(1.0, max(0.0, self._brake_boost - 1.0))
        boosted = math.sqrt(speed) if speed < 1.0 else speed
        mixed = (brake_scale * boosted + (1.0 - brake_scale) * speed) / speed if speed > 0.0 else 0.0
        drag_n, drag_e = coefficient * self.v_north * mixed, coefficient * self.v_east * mixed
        sign_changed = _sign(a_n) != _sign(self._a_prev[0]) or _sign(a_e) != _sign(self._a_prev[1])
        if (a_n == 0.0 and a_e == 0.0 or sign_changed) and speed * speed < (drag_n * drag_n + drag_e * drag_e) * dt * dt:
            drag_n = drag_e = 0.0
            self.v_north = self.v_east = 0.0
        a_n, a_e = a_n - drag_n, a_e - drag_e
        d_n, d_e = a_n - self._a_prev[0], a_e - self._a_prev[1]
        d_norm = math.hypot(d_n, d_e)
        if d_norm > 0.0:
            jerk = p["MPC_JERK_MAX"]
            a_n = _slew(self._a_prev[0], a_n, abs(d_n) / d_norm * jerk, dt)
            a_e = _slew(self._a_prev[1], a_e, abs(d_e) / d_norm * jerk, dt)
        tilt_acc = math.tan(math.radians(p["MPC_TILTMAX_AIR"])) * GRAVITY
        norm = math.hypot(a_n, a_e)
        if norm > tilt_acc:
            a_n, a_e = a_n * tilt_acc / norm, a_e * tilt_acc / norm
        self.v_north += a_n * dt
        self.v_east += a_e * dt
        self._a_prev = (a_n, a_e)
        moving = self.v_north != 0.0 or self.v_east != 0.0
        if not moving and self.hold_ne is None:
            self.hold_ne = (position[0], position[1])
        elif moving:
            self.hold_ne = None

        climb = expo_deadzone(sticks.throttle, p["MPC_Z_MAN_EXPO"], dz)
        v_down = -climb * (p["MPC_Z_VEL_MAX_UP"] if climb > 0.0 else p["MPC_Z_VEL_MAX_DN"])
        if climb != 0.0:
            self.hold_down = None
        elif self.hold_down is None:
            self.hold_down = position[2]
        yaw_rate = expo_deadzone(sticks.yaw, p["MPC_YAW_EXPO"], dz) * math.radians(p["MPC_MAN_Y_MAX"])
        self.yaw_sp = (self.yaw_sp + yaw_rate * dt + math.pi) % (2.0 * math.pi) - math.pi
        hold_n, hold_e = self.hold_ne if self.hold_ne is not None else (None, None)
        return hold_n, hold_e, self.hold_down, self.v_north, self.v_east, v_down, self.yaw_sp


def altitude_mode_thrust(params, sticks: Sticks, yaw: float) -> tuple[float, float]:
    """Altitude mode's horizontal thrust (north, east; collective units at hover): the roll and
    pitch sticks tilt the vehicle, MPC_MAN_TILT_MAX at full deflection, and nothing holds its
    position or velocity, so it drifts with the wind."""
    dz = params["MPC_HOLD_DZ"]
    forward, right = deadzone(sticks.pitch, dz), deadzone(sticks.roll, dz)
    length = math.hypot(forward, right)
    if length > 1.0:
        forward, right = forward / length, right / length
    lean = math.tan(math.radians(params["MPC_MAN_TILT_MAX"])) * params["MPC_THR_HOVER"]
    cos_y, sin_y = math.cos(yaw), math.sin(yaw)
    return lean * (forward * cos_y - right * sin_y), lean * (forward * sin_y + right * cos_y)
