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
    """The range data in world-fixed bins, fused from every source as PX4's collision prevention
    fuses them (CollisionPrevention::_updateObstacleMap): each source's latest reading, an
    OBSTACLE_DISTANCE message's sectors or a DISTANCE_SENSOR's field of view, is binned at the
    heading it was measured at, and each bin holds, of the sources heard within STALE_AFTER_S,
    what PX4's _enterData leaves there once each has reported: an obstacle seen by the sensor of
    the shortest reach that sees one (the latest of those), else nothing within the longest
    reach, else no data. One source alone is its own reading, as before sources were fused."""

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
        # For PX4's Position-mode prevention, which takes nothing within range as an obstacle at
        # the reach of the sensor that saw nothing: the distances clamped so, and (north, east,
        # distance) of every bin seen.
        self.view_at_reach: list[float | None] = [None] * BINS
        self.seen_at_reach: list[tuple[float, float, float, bool]] = []
        # Each source's latest reading, by source: (when, its reach in metres, its bins).
        self.sources: dict[tuple, tuple[float, float, list]] = {}

    def _frame(self, yaw_rad: float) -> tuple[float, float]:
        """Body angle a lies at reference + sign * a: the heading and +1, unless a seeded fault
        takes north as the reference or mirrors the sectors."""
        if self.fault == "range_frame_world":
            return 0.0, 1.0
        if self.fault == "cp_sector_mirrored" and yaw_rad % (2.0 * math.pi) > MIRRORED_PAST_RAD:
            return yaw_rad, -1.0
        return yaw_rad, 1.0

    def update(self, now_s: float, yaw_rad: float, distances_cm: list[int], increment_deg: float, angle_offset_deg: float,
               min_cm: int, max_cm: int) -> None:
        """Fuse one OBSTACLE_DISTANCE message (body FRD) measured at heading yaw_rad. A source is
        told apart by its geometry: PX4's obstacle_distance topic has one instance, so sources
        of one geometry are one source to it too."""
        bins: list[float | None] = [None] * BINS
        step = math.radians(increment_deg)
        offset = math.radians(angle_offset_deg)
        reference, sign = self._frame(yaw_rad)
        for index, raw in enumerate(distances_cm):
            if raw == UINT16_MAX:
                continue
            world = (reference + sign * offset + sign * index * step) % (2.0 * math.pi)
            target = int(round(world / BIN_RAD)) % BINS
            value = math.inf if raw > max_cm else max(raw, min_cm) / 100.0
            current = bins[target]
            bins[target] = value if current is None else min(current, value)
        self._enter(("obstacle_distance", increment_deg, angle_offset_deg, max_cm), now_s, max_cm / 100.0, bins)

    def update_distance_sensor(self, now_s: float, yaw_rad: float, sensor_id: int, distance_m: float, min_m: float, max_m: float,
                               sensor_yaw_rad: float, fov_rad: float, horizontal_scale: float) -> None:
        """Fuse one DISTANCE_SENSOR reading as PX4's _addDistanceSensorData does: clamped at the
        sensor's reach, which reads as nothing within range; dropped at or below its minimum; an
        obstacle's distance projected on the horizontal plane (horizontal_scale, the horizontal
        part of the sensor's direction in the world); every bin whose centre PX4 rounds into the
        field of view gets it."""
        reading = min(distance_m, max_m)
        if reading <= min_m:
            return
        value = math.inf if reading >= max_m else reading * horizontal_scale
        centre_deg = math.degrees(sensor_yaw_rad % (2.0 * math.pi))
        half_deg = math.degrees(fov_rad) / 2.0
        bin_deg = math.degrees(BIN_RAD)
        reference, sign = self._frame(yaw_rad)
        bins: list[float | None] = [None] * BINS
        for body_bin in range(_round_half_away((centre_deg - half_deg) / bin_deg), _round_half_away((centre_deg + half_deg) / bin_deg) + 1):
            world = (reference + sign * body_bin * BIN_RAD) % (2.0 * math.pi)
            bins[int(round(world / BIN_RAD)) % BINS] = value
        self._enter(("distance_sensor", sensor_id), now_s, max_m, bins)

    def _enter(self, source: tuple, now_s: float, reach_m: float, bins: list) -> None:
        self.sources[source] = (now_s, reach_m, bins)
        if len(self.sources) > 1:
            for key in [key for key, heard in self.sources.items() if now_s - heard[0] > STALE_AFTER_S]:
                del self.sources[key]
        heard = list(self.sources.values())
        if len(heard) == 1:
            reaches = [reach_m] * BINS
        else:
            bins, reaches = _fused(heard)
        self.distances = bins
        self.updated_s = max([when for when, _reach, _bins in heard])
        self.max_range_m = max([reach for _when, reach, _bins in heard])
        self.occupied = [(*BIN_DIRECTIONS[i], d) for i, d in enumerate(bins) if d is not None and not math.isinf(d)]
        self.unknown = [BIN_DIRECTIONS[i] for i, d in enumerate(bins) if d is None]
        self.view_at_reach = [None if d is None else min(d, reaches[i]) for i, d in enumerate(bins)]
        # With whether the bin's reading is within its own sensor's reach: only such a reading's age delays braking.
        self.seen_at_reach = ([(*BIN_DIRECTIONS[i], d, d < reaches[i]) for i, d in enumerate(bins) if d is not None and not math.isinf(d)]
                              + [(*BIN_DIRECTIONS[i], reaches[i], False) for i, d in enumerate(bins) if d is not None and math.isinf(d)])

    def fresh(self, now_s: float) -> bool:
        return now_s - self.updated_s <= STALE_AFTER_S


def _fused(sources: list) -> tuple[list, list]:
    """Each bin's reading and the reach of the sensor it came from, of several sources' (when,
    reach, bins): what PX4's _enterData leaves once each has reported. An obstacle seen replaces
    nothing-in-range and is replaced only by one seen by a sensor of the same or a shorter
    reach, or by later nothing-in-range of a sensor of the same reach; nothing-in-range replaces
    nothing-in-range of the same or a shorter reach."""
    bins: list[float | None] = [None] * BINS
    reaches = [0.0] * BINS
    latest = [-math.inf] * BINS
    for heard_s, reach_m, readings in sources:
        for i, value in enumerate(readings):
            if value is None:
                continue
            current = bins[i]
            if current is None:
                better = True
            elif math.isinf(value):
                # Nothing in range replaces nothing in range of the same or a shorter reach, and
                # an obstacle only where it is later news from a sensor of the same reach.
                better = reach_m >= reaches[i] if math.isinf(current) else (reach_m == reaches[i] and heard_s > latest[i])
            elif math.isinf(current):
                better = True
            else:
                better = reach_m < reaches[i] or (reach_m == reaches[i] and (heard_s > latest[i] or (heard_s == latest[i] and value < current)))
            if better:
                bins[i], reaches[i], latest[i] = value, reach_m, heard_s
    return bins, reaches


def _round_half_away(x: float) -> int:
    """C's round(): halves away from zero (Python's round() takes them to the even integer)."""
    return int(math.floor(x + 0.5)) if x >= 0.0 else -int(math.floor(-x + 0.5))


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


def _stick_scale(distance: float, keep: float, scale_distance: float) -> float:
    """PX4's CollisionPrevention::_getScale: 1 far away, quadratically less within scale_distance
    beyond the distance to keep, negative (away) inside it."""
    scale = distance - keep
    return min(1.0, (scale / scale_distance) ** 2 if scale > 0.0 else scale)


def px4_guided_bin(view: list, home: int, keep: float, guide_angle_deg: float) -> int:
    """The sector PX4's CollisionPrevention::_adaptSetpointDirection turns a setpoint in sector
    `home` into: of the sectors with data within CP_GUIDE_ANG, the one with the least cost, in
    centimetres, 50 CP_DIST per sector turned less the sector's distance and the mean over it and
    its neighbours (a neighbour without data counting as CP_DIST). view: metres or None per sector."""
    best_cost, best = 9999.0, home
    span = int(guide_angle_deg // 5.0)
    for i in range(home - span, home + span + 1):
        mean = 0.0
        for j in (i - 1, i, i + 1):
            near = view[j % BINS]
            mean += keep * 100.0 if near is None else near * 100.0
        here = view[i % BINS]
        if here is None:
            continue
        cost = keep * 50.0 * abs(i - home) - mean / 3.0 - here * 100.0
        if cost < best_cost:
            best_cost, best = cost, i % BINS
    return best


def px4_stick_acceleration(params, obstacles: ObstacleMap, now_s: float, accel_ne: tuple[float, float], velocity_ne: tuple[float, float]) -> tuple[float, float]:
    """The stick's acceleration setpoint in Position mode as PX4's collision prevention leaves it
    since v1.15 (CollisionPrevention::modifySetpoint on StickAccelerationXY, MPC_POS_MODE 4), for
    CP_STICK_ACCEL 1:

    * A direction the sensor sees nothing in holds an obstacle at the sensor's reach
      (_addDistanceSensorData clamps a reading to max_distance): in fog, the vehicle sees a wall
      a few metres ahead wherever it looks.
    * The acceleration towards the closest obstacle, and along it by the obstacle in that
      direction, is scaled by ((d - CP_DIST) / max(CP_DIST, MPC_VEL_MANUAL / MPC_XY_P))^2, at most
      1: PX4 slows down from about 11 m before anything it sees, not only where it must brake.
    * A direction without data is refused unless CP_GO_NO_DATA.
    * A braking acceleration MPC_XY_VEL_P_ACC (v_max - v) in the direction where the velocity
      setpoint most exceeds the speed v_max from which a stop (MPC_ACC_HOR, MPC_JERK_MAX) still
      keeps CP_DIST, after CP_DELAY and the data's age.

    * The setpoint's direction turned by up to CP_GUIDE_ANG into the sector PX4's
      _adaptSetpointDirection picks (px4_guided_bin)."""
    a_n, a_e = accel_ne
    length = math.hypot(a_n, a_e)
    if length <= 0.001:  # PX4's is_stick_deflected
        return accel_ne
    if not obstacles.fresh(now_s):
        return 0.0, 0.0
    seen = obstacles.seen_at_reach
    if not seen:
        return accel_ne
    keep = params["CP_DIST"]
    scale_distance = max(keep, params["MPC_VEL_MANUAL"] / params["MPC_XY_P"])
    view = obstacles.view_at_reach
    closest_n, closest_e, closest, _in_range = seen[0]
    for bin_n, bin_e, distance, _in_range in seen:
        if distance < closest:
            closest_n, closest_e, closest = bin_n, bin_e, distance
    home = _bin_of(math.atan2(a_e, a_n))
    index = px4_guided_bin(view, home, keep, params["CP_GUIDE_ANG"])
    if index == home:
        dir_n, dir_e = a_n / length, a_e / length
    else:
        dir_n, dir_e = BIN_DIRECTIONS[index]
    new_n = new_e = 0.0
    if view[index] is not None or params["CP_GO_NO_DATA"] >= 1:
        towards = dir_n * closest_n + dir_e * closest_e
        if towards > 0.0:
            normal_n, normal_e = closest_n * towards, closest_e * towards
            tangential_n, tangential_e = dir_n - normal_n, dir_e - normal_e
            along = math.inf
            if math.hypot(tangential_n, tangential_e) > 1e-6:
                found = view[_bin_of(math.atan2(tangential_e, tangential_n))]
                along = math.inf if found is None else found
            normal_scale = _stick_scale(closest, keep, scale_distance)
            tangential_scale = _stick_scale(along, keep, scale_distance)
            new_n = (tangential_n * tangential_scale + normal_n * normal_scale) * length
            new_e = (tangential_e * tangential_scale + normal_e * normal_scale) * length
        else:
            new_n, new_e = a_n, a_e
    delay = params["CP_DELAY"]
    age = max(0.0, now_s - obstacles.updated_s)
    gain = params["MPC_XY_VEL_P_ACC"]
    braking, brake_n, brake_e = math.inf, 0.0, 0.0
    for bin_n, bin_e, distance, in_range in seen:
        parallel = max(0.0, velocity_ne[0] * bin_n + velocity_ne[1] * bin_e)
        delay_m = parallel * (delay + (age if in_range else 0.0))
        stop_distance = distance - keep - delay_m
        if stop_distance >= 0.0:
            constraint = gain * min(max_speed_from_distance(params["MPC_JERK_MAX"], params["MPC_ACC_HOR"], stop_distance) - parallel, 0.0)
        else:
            constraint = -gain * parallel
        if constraint < braking:
            braking, brake_n, brake_e = constraint, bin_n, bin_e
    return new_n + braking * brake_n, new_e + braking * brake_e

