"""Paths of moving obstacles and intruders, and the route's nominal timing they are placed against.

Every function takes numpy arrays or floats alike (broadcasting), so the search space checks its
realism constraints for a whole population at once with the same geometry the world spec flies.
Angles are degrees clockwise from north; a positive turn is to the right (clockwise seen from above).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

# Points per curved path: the world spec flies them, the realism constraints check them; about
# 0.5 m apart for a 30 m arc.
PATH_SAMPLES = 64


def arc_points(north, east, heading_deg, radius_m, turn_deg, samples: int) -> tuple[np.ndarray, np.ndarray]:
    """`samples` points along a circle arc that starts at (north, east) heading `heading_deg` and
    turns through `turn_deg` (its sign the direction) on a circle of `radius_m`: arrays (..., samples)."""
    heading = np.radians(np.asarray(heading_deg, dtype=float))[..., None]
    radius = np.asarray(radius_m, dtype=float)[..., None]
    turn = np.radians(np.asarray(turn_deg, dtype=float))[..., None]
    side = np.where(turn >= 0.0, 1.0, -1.0)
    # The centre lies a radius to the side of the start, square to the heading.
    centre_n = np.asarray(north, dtype=float)[..., None] + side * radius * np.cos(heading + math.pi / 2)
    centre_e = np.asarray(east, dtype=float)[..., None] + side * radius * np.sin(heading + math.pi / 2)
    swept = turn * np.linspace(0.0, 1.0, samples)
    bearing_from_centre = heading - side * math.pi / 2 + swept
    return centre_n + radius * np.cos(bearing_from_centre), centre_e + radius * np.sin(bearing_from_centre)


def smooth_points(points: Sequence[tuple], samples_per_segment: int) -> tuple[np.ndarray, np.ndarray]:
    """A uniform Catmull-Rom curve through the (north, east) points, its end
    tangents pointing at the neighbours: arrays (..., (len(points) - 1) * samples_per_segment + 1)."""
    north = [np.asarray(p[0], dtype=float) for p in points]
    east = [np.asarray(p[1], dtype=float) for p in points]
    # Phantom end points mirror the neighbours, so the curve starts and ends heading at them.
    north = [2 * north[0] - north[1], *north, 2 * north[-1] - north[-2]]
    east = [2 * east[0] - east[1], *east, 2 * east[-1] - east[-2]]
    t = np.linspace(0.0, 1.0, samples_per_segment + 1)
    basis = (
        -0.5 * t**3 + t**2 - 0.5 * t,
        1.5 * t**3 - 2.5 * t**2 + 1.0,
        -1.5 * t**3 + 2.0 * t**2 + 0.5 * t,
        0.5 * t**3 - 0.5 * t**2,
    )
    curves_n, curves_e = [], []
    for segment in range(len(points) - 1):
        keep = slice(0, None) if segment == len(points) - 2 else slice(0, -1)
        curves_n.append(sum(b * north[segment + j][..., None] for j, b in enumerate(basis))[..., keep])
        curves_e.append(sum(b * east[segment + j][..., None] for j, b in enumerate(basis))[..., keep])
    return np.concatenate(curves_n, axis=-1), np.concatenate(curves_e, axis=-1)


@dataclass(frozen=True)
class RouteTiming:
    """Where the UAV is expected along its route at a run time: climbing on the spot for
    `takeoff_s`, then along the waypoints at cruise speed. Turns, braking and wind are left out:
    a searched time of closest approach or onset covers the difference."""

    waypoints: tuple[tuple[float, float, float], ...]  # north_m, east_m, altitude_m above the start
    cruise_speed_m_s: float
    takeoff_s: float

    @property
    def legs(self) -> list[tuple[tuple[float, float, float], tuple[float, float, float], float]]:
        points = [(0.0, 0.0, self.waypoints[0][2]), *self.waypoints]
        return [(a, b, math.hypot(b[0] - a[0], b[1] - a[1])) for a, b in zip(points, points[1:])]

    @property
    def length_m(self) -> float:
        return sum(length for _a, _b, length in self.legs)

    @property
    def duration_s(self) -> float:
        """Run time at which the UAV is expected at its last waypoint."""
        return self.takeoff_s + self.length_m / self.cruise_speed_m_s

    def at(self, time_s):
        """(north_m, east_m, altitude_m above the start, heading_deg) expected at run time `time_s` (arrays broadcast)."""
        travelled = np.clip((np.asarray(time_s, dtype=float) - self.takeoff_s) * self.cruise_speed_m_s, 0.0, self.length_m)
        north = np.zeros_like(travelled)
        east = np.zeros_like(travelled)
        altitude = np.zeros_like(travelled)
        heading = np.zeros_like(travelled)
        done = 0.0
        legs = [leg for leg in self.legs if leg[2] > 0.0] or self.legs[-1:]
        for index, (a, b, length) in enumerate(legs):
            inside = (travelled >= done) if index == 0 else (travelled > done)
            fraction = np.clip((travelled - done) / length, 0.0, 1.0) if length > 0.0 else np.zeros_like(travelled)
            north = np.where(inside, a[0] + (b[0] - a[0]) * fraction, north)
            east = np.where(inside, a[1] + (b[1] - a[1]) * fraction, east)
            altitude = np.where(inside, a[2] + (b[2] - a[2]) * fraction, altitude)
            heading = np.where(inside, math.degrees(math.atan2(b[1] - a[1], b[0] - a[0])) % 360.0, heading)
            done += length
        return north, east, altitude, heading


def intruder_speed(own_speed_m_s, crossing_deg, closing_speed_m_s):
    """The intruder's ground speed that closes on the UAV at `closing_speed_m_s` when their tracks
    meet at `crossing_deg` (0: same direction, 180: head-on); NaN where no speed can."""
    angle = np.radians(np.asarray(crossing_deg, dtype=float))
    own = np.asarray(own_speed_m_s, dtype=float)
    closing = np.asarray(closing_speed_m_s, dtype=float)
    # |v_i - v_o| = closing with v_i at `angle` to v_o: the larger root of
    # s^2 - 2 s v_o cos(angle) + v_o^2 - closing^2 = 0.
    discriminant = closing**2 - (own * np.sin(angle)) ** 2
    with np.errstate(invalid="ignore"):
        return np.where(discriminant >= 0.0, own * np.cos(angle) + np.sqrt(np.maximum(discriminant, 0.0)), np.nan)


def intruder_track(meet: tuple[float, float, float], heading_deg: float, speed_m_s: float, turn_rate_deg_s: float,
                   closest_approach_s: float, until_s: float, step_s: float = 0.25) -> list[tuple[float, float, float]]:
    """The intruder's positions from run time 0 to `until_s`: it passes `meet` (north, east, up)
    heading `heading_deg` at `closest_approach_s`, flying level at constant speed, straight or
    turning at a constant rate."""
    north0, east0, up = meet
    if turn_rate_deg_s == 0.0:
        times = [0.0, until_s]
    else:
        times = [min(until_s, i * step_s) for i in range(int(math.ceil(until_s / step_s)) + 1)]
    heading = math.radians(heading_deg)
    rate = math.radians(turn_rate_deg_s)
    track = []
    for time_s in times:
        since = time_s - closest_approach_s
        if rate == 0.0:
            north = north0 + speed_m_s * since * math.cos(heading)
            east = east0 + speed_m_s * since * math.sin(heading)
        else:
            now = heading + rate * since
            north = north0 + speed_m_s / rate * (math.sin(now) - math.sin(heading))
            east = east0 - speed_m_s / rate * (math.cos(now) - math.cos(heading))
        track.append((north, east, up))
    return track
