"""The UAV Testing Competition's distance and points, computed from one of our logs.

As the competition scores a flight (Aerialist's trajectory.py and obstacle.py, its README):
the trajectory is averaged over 0.5 s windows, drawn as a 2D line widened by 0.125 m (the
vehicle's half width), and its distance to each box's footprint taken in the horizontal plane;
below 1.5 m is a soft fail and a collision a hard fail; points per flight: 5 below 0.25 m, 2 below
1 m, 1 below 1.5 m, else 0.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

from harness.errors import InputError, Problem
from harness.flight import logs

RESAMPLE_S = 0.5
HALF_WIDTH_M = 0.125
SOFT_FAIL_M = 1.5
POINT_BANDS = ((0.25, 5), (1.0, 2), (1.5, 1))

Point = tuple[float, float]


def _segment_distance(p: Point, a: Point, b: Point) -> float:
    dn, de = b[0] - a[0], b[1] - a[1]
    length2 = dn * dn + de * de
    t = 0.0 if length2 == 0.0 else max(0.0, min(1.0, ((p[0] - a[0]) * dn + (p[1] - a[1]) * de) / length2))
    return math.hypot(p[0] - a[0] - t * dn, p[1] - a[1] - t * de)


def _cross(o: Point, a: Point, b: Point) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def _segments_cross(a: Point, b: Point, c: Point, d: Point) -> bool:
    return _cross(a, b, c) * _cross(a, b, d) < 0 and _cross(c, d, a) * _cross(c, d, b) < 0


def _inside(p: Point, polygon: Sequence[Point]) -> bool:
    signs = [_cross(polygon[i], polygon[(i + 1) % len(polygon)], p) for i in range(len(polygon))]
    return all(s >= 0 for s in signs) or all(s <= 0 for s in signs)


def path_to_polygon(path: Sequence[Point], polygon: Sequence[Point]) -> float:
    """2D distance between a polyline and a convex polygon (0 where they touch)."""
    edges = [(polygon[i], polygon[(i + 1) % len(polygon)]) for i in range(len(polygon))]
    segments = list(zip(path, path[1:])) or [(path[0], path[0])]
    if any(_inside(p, polygon) for p in path):
        return 0.0
    if any(_segments_cross(a, b, c, d) for a, b in segments for c, d in edges):
        return 0.0
    return min(min(_segment_distance(p, a, b) for p in (c for c, _ in edges) for a, b in segments),
               min(_segment_distance(p, c, d) for p in path for c, d in edges))


def footprint(obstacle: dict[str, Any]) -> list[Point]:
    """A static cuboid's corners (north, east) from the world spec."""
    n, e = obstacle["a"]["north_m"], obstacle["a"]["east_m"]
    half_l, half_w = obstacle["size"]["length_m"] / 2.0, obstacle["size"]["width_m"] / 2.0
    c, s = math.cos(obstacle["yaw_rad"]), math.sin(obstacle["yaw_rad"])
    return [(n + x * c - y * s, e + x * s + y * c) for x, y in ((half_l, half_w), (half_l, -half_w), (-half_l, -half_w), (-half_l, half_w))]


def resampled(states: Sequence[dict[str, Any]]) -> list[Point]:
    """The mean position over each 0.5 s window, as the competition resamples its trajectory."""
    windows: dict[int, list[Point]] = {}
    for state in states:
        windows.setdefault(int(state["t"] // RESAMPLE_S), []).append((state["north_m"], state["east_m"]))
    return [(sum(p[0] for p in ps) / len(ps), sum(p[1] for p in ps) / len(ps)) for _k, ps in sorted(windows.items())]


def points_for(distance_m: float) -> int:
    return next((points for limit, points in POINT_BANDS if distance_m < limit), 0)


def competition_score(path: Path) -> dict[str, Any]:
    """Per box the competition's distance, and the flight's minimum, verdict and points."""
    world = logs.world_of(path)
    if not world.obstacles or any(o["kind"] != "static" or o["form"] != "cuboid" for o in world.obstacles):
        raise InputError([Problem(str(path), "", "the competition scores static boxes only; this flight had other obstacles or none")])
    trajectory = resampled([m for _t, _ns, m in logs.messages(path, ["/uav/state"])])
    if not trajectory:
        raise InputError([Problem(str(path), "", "no trajectory recorded")])
    distances = {o["id"]: max(0.0, path_to_polygon(trajectory, footprint(o)) - HALF_WIDTH_M) for o in world.obstacles}
    nearest = min(distances.values())
    verdict = "hard fail (collision)" if nearest == 0.0 else "soft fail" if nearest < SOFT_FAIL_M else "pass"
    return {"distances_m": distances, "min_distance_m": nearest, "verdict": verdict, "points": points_for(nearest)}
