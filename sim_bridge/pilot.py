"""The simulated pilot of the `pilot` drive: a person with a remote control flying the route in
Position mode, as in fog, relying on the autopilot's collision prevention instead of steering
around what is in the way.

The harness arms the vehicle and commands a takeoff; once the vehicle is airborne and has
stopped climbing the pilot flips the mode switch to Position and pushes the sticks towards
the route, facing where it flies and holding the route's altitude with the throttle stick; near the goal it slows down and lets go in time to stop over it,
and over the goal it flips the switch to Land. Its aim is a line parallel to the route, `aim_offset_m` to the right of it
(negative: left), which fades into the route over the last CONVERGE_M before the goal; its
aggressiveness is the largest stick deflection it uses, `max_stick` (0..1).

The pilot acts at the simulation's clock: every RC_PERIOD_S of simulated time it reads the
vehicle's true state (a pilot sees the vehicle) and the bridge sends its sticks as an
RC_CHANNELS frame on the simulator link, which PX4's simulator_mavlink publishes as input_rc
(SimulatorMavlink::handle_message_rc_channels) and the bundled autopilot reads the same way.
So a pilot-driven flight is as deterministic as the simulation, whatever the real-time factor.
SUT_PARAMS maps this transmitter's channels in the SUT (PX4's parameter names).

A programme (PilotSpec.programme) comes first: from the start of the cruise the pilot flies its
segments one after the other, each a stick deflection in a direction relative to the route or
to the nearest obstacle for a time, with a yaw stick, as a pilot probing the obstacle would:
a tiny deflection, release and re-push, sliding along it at an angle, backing away from it.
Then it flies the route as above.

Pure logic; the bridge calls `update` and encodes the result.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable, Sequence

from sim_bridge.spec import PilotSegment, Point, Waypoint

if TYPE_CHECKING:  # the harness imports this module for its constants; no JSBSim for that
    from sim_bridge.physics import VehicleState

RC_PERIOD_S = 0.02
CHANNEL_COUNT = 8
ROLL, PITCH, THROTTLE, YAW, MODE_SWITCH = 1, 2, 3, 4, 5
SLOT_HOLD, SLOT_POSITION, SLOT_LAND = 1, 2, 3
# The SUT's RC set-up for this transmitter: RC only, its channels, and its mode-switch slots
# (COM_FLTMODE values: 4 Hold, 2 Position, 11 Land). Channel calibration stays at PX4's
# defaults (1000..1500..2000 us, dead zone 10 us), which the pilot's PWM values assume.
SUT_PARAMS = {
    "COM_RC_IN_MODE": 0,
    "RC_CHAN_CNT": CHANNEL_COUNT,
    "RC_MAP_ROLL": ROLL,
    "RC_MAP_PITCH": PITCH,
    "RC_MAP_THROTTLE": THROTTLE,
    "RC_MAP_YAW": YAW,
    "RC_MAP_FLTMODE": MODE_SWITCH,
    f"COM_FLTMODE{SLOT_HOLD}": 4,
    f"COM_FLTMODE{SLOT_POSITION}": 2,
    f"COM_FLTMODE{SLOT_LAND}": 11,
}
PWM_MIN, PWM_TRIM, PWM_MAX, PWM_DEADZONE = 1000.0, 1500.0, 2000.0, 10.0
MODE_SLOTS = 6

LOOKAHEAD_M = 8.0
CONVERGE_M = 15.0
SLOWDOWN_M = 20.0
MIN_STICK = 0.3  # well above PX4's 0.1 stick dead zone (MPC_HOLD_DZ), so the last metres are flown
GOAL_RADIUS_M = 1.0
SETTLED_SPEED_M_S = 0.5
# The braking the pilot counts on when it lets go of its smallest stick on the last leg: below PX4's
# MPC_ACC_HOR (3) and ArduCopter's LOIT_BRK_ACCEL (2.5), so it lets go early rather than late.
# How fast the smallest stick flies differs by SUT (about 2 m/s in PX4's Position mode, 3.7 m/s in
# ArduCopter's Loiter); a pilot who kept pushing into the goal circle would orbit it.
BRAKE_M_S2 = 2.0
AIRBORNE_M = 1.0
ALTITUDE_GAIN = 0.3  # throttle stick per metre below the route's altitude
YAW_GAIN = 1.0  # yaw stick per radian of heading error
FACE_BEYOND_M = 3.0  # closer to the aim point than this the pilot stops turning
SETTLE_S = 1.0
BLOCKED_AFTER_S = 20.0
PROGRESS_M = 0.5


def pwm(value: float) -> int:
    """A normalised stick value (-1..1) as the pulse width that PX4's default calibration reads back as it."""
    if value > 0.0:
        return int(round(PWM_TRIM + PWM_DEADZONE + value * (PWM_MAX - PWM_TRIM - PWM_DEADZONE)))
    if value < 0.0:
        return int(round(PWM_TRIM - PWM_DEADZONE + value * (PWM_TRIM - PWM_MIN - PWM_DEADZONE)))
    return int(PWM_TRIM)


def slot_value(slot: int) -> float:
    """The mode-switch value in the middle of a slot, by inverting rc_update's slot formula."""
    return ((slot - 0.5 - 1.0 / MODE_SLOTS) * 2.1 - 1.0 / MODE_SLOTS) / MODE_SLOTS - 1.05


@dataclass(frozen=True)
class RcFrame:
    roll: float
    pitch: float
    throttle: float
    yaw: float
    slot: int

    def channels(self) -> list[int]:
        """Raw channel values 1..CHANNEL_COUNT (microseconds)."""
        values = [pwm(0.0)] * CHANNEL_COUNT
        for channel, value in ((ROLL, self.roll), (PITCH, self.pitch), (THROTTLE, self.throttle), (YAW, self.yaw), (MODE_SWITCH, slot_value(self.slot))):
            values[channel - 1] = pwm(value)
        return values


def _clip(value: float, limit: float) -> float:
    return max(-limit, min(limit, value))


class Pilot:
    def __init__(self, start: Point, route: Sequence[Waypoint], takeoff_altitude_m: float, max_stick: float, aim_offset_m: float,
                 programme: Sequence[PilotSegment] = (), obstacle_bearing: Callable[[VehicleState], float | None] | None = None):
        """start: the take-off point; route: waypoints with altitudes above the start, the last one
        the goal; programme: segments flown first; obstacle_bearing(state): the direction (radians
        clockwise from north) of the nearest obstacle the pilot sees, None where there is none."""
        self.start_up_m = start.up_m
        self.points = [(start.north_m, start.east_m)] + [(w.north_m, w.east_m) for w in route]
        self.altitudes = [takeoff_altitude_m] + [w.altitude_m for w in route]
        self.max_stick = max_stick
        self.aim_offset_m = aim_offset_m
        self.leg = 0
        self.phase = "takeoff"
        self.blocked = False
        self.aim = self.points[1]
        self.remaining_m = self._remaining(*self.points[0])
        self._best_remaining_m = math.inf
        self._progress_at_s = 0.0
        self._settled_at_s = 0.0
        self.programme = tuple(programme)
        self.obstacle_bearing = obstacle_bearing
        self.segment: int | None = None  # the programme's segment flown now
        self._programme_from_s = 0.0

    def _leg_geometry(self, leg: int) -> tuple[float, float, float, float, float]:
        """The leg's start, unit direction and length; right of a direction (un, ue) is (-ue, un)."""
        (n0, e0), (n1, e1) = self.points[leg], self.points[leg + 1]
        length = math.hypot(n1 - n0, e1 - e0)
        if length < 1e-9:
            return n0, e0, 1.0, 0.0, length
        return n0, e0, (n1 - n0) / length, (e1 - e0) / length, length

    def _remaining(self, north: float, east: float) -> float:
        """How far the pilot still has to go: to the end of its leg, then along the route."""
        leg_end = self.points[self.leg + 1]
        rest = sum(math.hypot(b[0] - a[0], b[1] - a[1]) for a, b in zip(self.points[self.leg + 1 :], self.points[self.leg + 2 :]))
        return math.hypot(leg_end[0] - north, leg_end[1] - east) + rest

    def _aim_point(self, north: float, east: float) -> tuple[float, float]:
        n0, e0, un, ue, length = self._leg_geometry(self.leg)
        along = (north - n0) * un + (east - e0) * ue
        while along >= length - GOAL_RADIUS_M and self.leg < len(self.points) - 2:
            self.leg += 1
            n0, e0, un, ue, length = self._leg_geometry(self.leg)
            along = (north - n0) * un + (east - e0) * ue
        target = min(max(along, 0.0) + LOOKAHEAD_M, length)
        last_leg = self.leg == len(self.points) - 2
        offset = self.aim_offset_m
        if last_leg:
            offset *= min(1.0, max(0.0, (length - target) / CONVERGE_M))
        return n0 + target * un - offset * ue, e0 + target * ue + offset * un

    def update(self, time_s: float, state: VehicleState) -> RcFrame:
        """The sticks for the vehicle's true state (north_m, east_m, up_m, v_*_m_s, yaw_rad)."""
        altitude = state.up_m - self.start_up_m
        north, east = state.north_m, state.east_m
        if self.phase == "takeoff":
            climbed = altitude >= AIRBORNE_M and abs(state.v_down_m_s) < SETTLED_SPEED_M_S
            if not climbed:
                return RcFrame(0.0, 0.0, 0.0, 0.0, SLOT_HOLD)
            self.phase = "programme" if self.programme else "cruise"
            self._progress_at_s = self._programme_from_s = time_s
        if self.phase == "programme":
            frame = self._programme(time_s, state, altitude)
            if frame is not None:
                return frame
            self.phase, self.segment, self._progress_at_s = "cruise", None, time_s
        if self.phase == "settle" and time_s - self._settled_at_s >= SETTLE_S:
            self.phase = "land"
        if self.phase == "settle":
            return RcFrame(0.0, 0.0, 0.0, 0.0, SLOT_POSITION)
        if self.phase == "land":
            return RcFrame(0.0, 0.0, 0.0, 0.0, SLOT_LAND)
        self.aim = self._aim_point(north, east)
        self.remaining_m = self._remaining(north, east)
        if self.remaining_m < self._best_remaining_m - PROGRESS_M:
            self._best_remaining_m = self.remaining_m
            self._progress_at_s = time_s
        elif time_s - self._progress_at_s >= BLOCKED_AFTER_S:
            self.blocked = True
        goal_n, goal_e = self.points[-1]
        to_goal = math.hypot(goal_n - north, goal_e - east)
        speed = math.hypot(state.v_north_m_s, state.v_east_m_s)
        if to_goal <= GOAL_RADIUS_M and speed < SETTLED_SPEED_M_S:
            self.phase, self._settled_at_s = "settle", time_s
            return RcFrame(0.0, 0.0, 0.0, 0.0, SLOT_POSITION)
        throttle = _clip(ALTITUDE_GAIN * (self.altitudes[self.leg + 1] - altitude), self.max_stick)
        slowed = self.max_stick * min(1.0, to_goal / SLOWDOWN_M)
        # Above the smallest stick the SUT slows down with the stick; at it, only letting go does.
        if slowed <= MIN_STICK and self.leg == len(self.points) - 2 \
                and to_goal <= GOAL_RADIUS_M / 2 + self._stopping_m(goal_n - north, goal_e - east, to_goal, state):
            return RcFrame(0.0, 0.0, throttle, 0.0, SLOT_POSITION)
        d_n, d_e = self.aim[0] - north, self.aim[1] - east
        distance = math.hypot(d_n, d_e)
        stick = min(self.max_stick, max(MIN_STICK, slowed))
        cos_y, sin_y = math.cos(state.yaw_rad), math.sin(state.yaw_rad)
        forward, right = (d_n * cos_y + d_e * sin_y, -d_n * sin_y + d_e * cos_y) if distance > 1e-9 else (0.0, 0.0)
        scale = stick / distance if distance > 1e-9 else 0.0
        yaw = 0.0
        if distance > FACE_BEYOND_M:
            error = math.atan2(right, forward)
            yaw = _clip(YAW_GAIN * error, self.max_stick)
        return RcFrame(right * scale, forward * scale, throttle, yaw, SLOT_POSITION)

    def _programme(self, time_s: float, state: VehicleState, altitude: float) -> RcFrame | None:
        """The sticks of the programme's segment at this time (None: the programme is over)."""
        elapsed = time_s - self._programme_from_s
        for index, segment in enumerate(self.programme):
            if elapsed < segment.duration_s:
                break
            elapsed -= segment.duration_s
        else:
            return None
        self.segment = index
        north, east = state.north_m, state.east_m
        self.aim = self._aim_point(north, east)
        bearing = self.obstacle_bearing(state) if segment.towards == "obstacle" and self.obstacle_bearing is not None else None
        if bearing is None:  # towards the route, or no obstacle in sight
            bearing = math.atan2(self.aim[1] - east, self.aim[0] - north)
        direction = bearing + math.radians(segment.angle_deg) - state.yaw_rad
        throttle = _clip(ALTITUDE_GAIN * (self.altitudes[self.leg + 1] - altitude), self.max_stick)
        return RcFrame(segment.deflection * math.sin(direction), segment.deflection * math.cos(direction), throttle, segment.yaw_stick, SLOT_POSITION)

    @staticmethod
    def _stopping_m(d_n: float, d_e: float, to_goal: float, state: VehicleState) -> float:
        """How far towards the goal the vehicle would still go if the pilot let go now."""
        closing = (d_n * state.v_north_m_s + d_e * state.v_east_m_s) / to_goal if to_goal > 1e-9 else 0.0
        return max(0.0, closing) ** 2 / (2.0 * BRAKE_M_S2)
