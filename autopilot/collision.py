"""Collision prevention in the spirit of PX4's CollisionPrevention, as a pure core with time passed in.

A 72-sector obstacle map in world-fixed bins (5 degrees each, clockwise from north) is filled
from OBSTACLE_DISTANCE (body FRD, centimetres). The horizontal velocity setpoint is first turned
by up to CP_GUIDE_ANG into a gap when its direction is blocked, then in every sector
with an obstacle its component towards the obstacle is limited to the speed from which the
vehicle can still stop CP_DIST before it, after travelling CP_DELAY at its current speed, with
PX4's jerk-limited braking (MPC_ACC_HOR, MPC_JERK_AUTO; math::computeMaxSpeedFromDistance):
v_max(s) = (-b + sqrt(b^2 + 8 a s)) / 2 with b = 4 a^2 / j and s = d - CP_DIST - CP_DELAY v. The component
across the sector is kept, so the vehicle slides along an obstacle; closer than CP_DIST it backs
off at up to 0.5 m/s (PX4 only stops; without this, drift creeps a hovering vehicle closer). Without fresh range data
for 0.5 s horizontal motion stops, and in Position mode after 5 s the vehicle switches to Hold
(autopilot/app.py), as PX4's does. Unlike PX4's, it is applied in every automatic mode.
"""

from __future__ import annotations

import math

BINS = 72
BIN_RAD = 2.0 * math.pi / BINS
BIN_DIRECTIONS = tuple((math.cos(i * BIN_RAD), math.sin(i * BIN_RAD)) for i in range(BINS))
UINT16_MAX = 65535
STALE_AFTER_S = 0.5
STALE_HOLD_S = 5.0  # in Position mode, then Hold (PX4's TIMEOUT_HOLD_US)
MAX_PASSES = 8
BACK_OFF_GAIN = 1.0  # 1/s
BACK_OFF_MAX_M_S = 0.5


MIRRORED_PAST_RAD = math.pi  # seeded fault cp_sector_mirrored
NARROW_VIEW_COS = math.cos(math.radians(15.0))  # seeded fault cp_narrow_view
OFF_ABOVE_M_S = 4.0  # seeded fault cp_off_above_cruise


class ObstacleMap:
    def __init__(self, fault: str | None = None) -> None:
        self.fault = fault
        # None: no data for that direction; math.inf: nothing within range; else metres.
        self.distances: list[float | None] = [None] * BINS
        self.updated_s = -math.inf
        self.max_range_m = 0.0
        # Precomputed for the per-step constraint: (north, east, distance) of bins with an obstacle,
        # and the directions without data.
        self.occupied: list[tuple[float, float, float]] = []
        self.unknown: list[tuple[float, float]] = list(BIN_DIRECTIONS)

    def update(self, now_s: float, yaw_rad: float, distances_cm: list[int], increment_deg: float, angle_offset_deg: float,
               min_cm: int, max_cm: int) -> None:
        """Fuse one OBSTACLE_DISTANCE message measured at heading yaw_rad."""
        bins: list[float | None] = [None] * BINS
        step = math.radians(increment_deg)
        offset = math.radians(angle_offset_deg)
        # Sector i lies at reference + sign * (offset + i * step): the heading and +1, unless a
        # seeded fault takes north as the reference or mirrors the sectors.
        reference, sign = yaw_rad, 1.0
        if self.fault == "range_frame_world":
            reference = 0.0
        elif self.fault == "cp_sector_mirrored" and yaw_rad % (2.0 * math.pi) > MIRRORED_PAST_RAD:
            sign = -1.0
        for index, raw in enumerate(distances_cm):
            if raw == UINT16_MAX:
                continue
            world = (reference + sign * offset + sign * index * step) % (2.0 * math.pi)
            target = int(round(world / BIN_RAD)) % BINS
            value = math.inf if raw > max_cm else max(raw, min_cm) / 100.0
            current = bins[target]
            bins[target] = value if current is None else min(current, value)
        self.distances = bins
        self.updated_s = now_s
        self.max_range_m = max_cm / 100.0
        self.occupied = [(*BIN_DIRECTIONS[i], d) for i, d in enumerate(bins) if d is not None and not math.isinf(d)]
        self.unknown = [BIN_DIRECTIONS[i] for i, d in enumerate(bins) if d is None]

    def fresh(self, now_s: float) -> bool:
        return now_s - self.updated_s <= STALE_AFTER_S


def _bin_of(angle_rad: float) -> int:
    return int(round((angle_rad % (2.0 * math.pi)) / BIN_RAD)) % BINS


def _clearance_around(distances: list[float | None], index: int) -> float | None:
    """Smallest distance in a bin and its neighbours; None if none of them has data."""
    values = [distances[(index + k) % BINS] for k in (-1, 0, 1)]
    known = [v for v in values if v is not None]
    return min(known) if known else None


def max_speed_from_distance(jerk: float, accel: float, distance: float) -> float:
    """The speed from which a jerk-limited stop comes to rest within distance (PX4's formula)."""
    b = 4.0 * accel * accel / jerk
    return 0.5 * (-b + math.sqrt(b * b + 8.0 * accel * max(0.0, distance)))


def guided_direction(obstacles: ObstacleMap, direction_rad: float, guide_angle_rad: float, needed_m: float) -> float:
    """Turn a blocked direction by the smallest angle, at most guide_angle_rad, that leads into a
    gap with the clearance needed to stop; keep it when there is no such gap. A wall seen at
    slant d / cos(angle) never qualifies: the clearance needed grows by the same 1 / cos(angle)."""
    home = _bin_of(direction_rad)
    clearance = _clearance_around(obstacles.distances, home)
    if clearance is None or clearance >= needed_m:
        return direction_rad
    span = int(guide_angle_rad / BIN_RAD)
    for offset in sorted(range(-span, span + 1), key=abs):
        candidate = _clearance_around(obstacles.distances, home + offset)
        if candidate is not None and candidate >= needed_m / math.cos(offset * BIN_RAD):
            return direction_rad + offset * BIN_RAD
    return direction_rad


def constrain_velocity(
    params,
    obstacles: ObstacleMap,
    now_s: float,
    setpoint_ne: tuple[float, float],
    velocity_ne: tuple[float, float],
) -> tuple[float, float]:
    """The horizontal velocity setpoint (north, east) that keeps CP_DIST to every sensed obstacle."""
    cp_dist = params["CP_DIST"]
    if cp_dist < 0.0:
        return setpoint_ne
    if not obstacles.fresh(now_s):
        return 0.0, 0.0
    vn, ve = setpoint_ne
    speed = math.hypot(vn, ve)
    fault = params.fault
    if fault == "cp_off_above_cruise" and speed > OFF_ABOVE_M_S:
        return setpoint_ne
    acc = params["MPC_ACC_HOR"]
    jerk = math.inf if fault == "cp_braking_without_jerk" else params["MPC_JERK_AUTO"]
    delay = 0.0 if fault == "cp_ignores_delay" else params["CP_DELAY"]
    narrow_view = fault == "cp_narrow_view" and speed > 1e-3
    if speed > 1e-3:
        # Distance to stop from this speed: the inverse of max_speed_from_distance.
        braking_m = (speed * speed + speed * 4.0 * acc * acc / jerk) / (2.0 * acc)
        direction = guided_direction(obstacles, math.atan2(ve, vn), math.radians(params["CP_GUIDE_ANG"]), cp_dist + delay * speed + braking_m)
        vn, ve = speed * math.cos(direction), speed * math.sin(direction)
    limits = [(bin_n, bin_e, 0.0) for bin_n, bin_e in obstacles.unknown] if params["CP_GO_NO_DATA"] < 1 else []
    for bin_n, bin_e, distance in obstacles.occupied:
        if narrow_view and (bin_n * vn + bin_e * ve) < NARROW_VIEW_COS * speed:
            continue
        if distance < cp_dist:
            # Closer than CP_DIST: back off gently instead of only refusing to go closer, or
            # estimation drift creeps the vehicle towards the obstacle while it holds position.
            limits.append((bin_n, bin_e, -min(BACK_OFF_MAX_M_S, BACK_OFF_GAIN * (cp_dist - distance))))
            continue
        towards = max(0.0, velocity_ne[0] * bin_n + velocity_ne[1] * bin_e)
        stop_distance = max(0.0, distance - cp_dist - delay * towards)
        limits.append((bin_n, bin_e, max_speed_from_distance(jerk, acc, stop_distance)))
    # Each sector is a half-plane v . direction <= allowed that contains v = 0; cyclic projection
    # onto them converges into their intersection, usually within one or two passes.
    for _ in range(MAX_PASSES):
        changed = False
        for bin_n, bin_e, allowed in limits:
            along = vn * bin_n + ve * bin_e
            if along > allowed + 1e-9:
                vn -= (along - allowed) * bin_n
                ve -= (along - allowed) * bin_e
                changed = True
        if not changed:
            break
    return vn, ve
