"""Obstacles of the world: where they are, how far the UAV body is from them, what the range sensor sees.

Positions are in the local north/east/up frame (metres). Clearance is python-fcl's distance
between the UAV body box and each obstacle, negative when they overlap. python-fcl 0.7's own
`Box` primitive gives distances up to 0.6 m too large (e.g. 4.07 m for a true 3.70 m), so
boxes are built as convex hulls, which it measures exactly (tests/test_obstacles.py).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import fcl
import numpy as np

from sim_bridge.spec import Body

_BOX_QUADS = (
    (0, 1, 3, 2),
    (4, 6, 7, 5),
    (0, 4, 5, 1),
    (2, 3, 7, 6),
    (0, 2, 6, 4),
    (1, 5, 7, 3),
)


def convex_box(length_m: float, width_m: float, height_m: float) -> fcl.Convex:
    """A box as a convex hull: vertex index 4*ix + 2*iy + iz for the corner at (+-l/2, +-w/2, +-h/2)."""
    vertices = np.array(
        [[sx * length_m / 2, sy * width_m / 2, sz * height_m / 2] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)],
        dtype=float,
    )
    faces = np.array([value for quad in _BOX_QUADS for value in (4, *quad)], dtype=np.int64)
    return fcl.Convex(vertices, len(_BOX_QUADS), faces)


def yaw_rotation(yaw_rad: float) -> np.ndarray:
    """Rotation of a body yawed clockwise from north, in the north/east/up frame."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


REPEATS = ("back_and_forth", "once")


@dataclass
class Obstacle:
    """One obstacle. A dynamic one moves at constant speed back and forth between a and b, or,
    with a `path` (a polyline from a to b, as arcs, smooth curves and intruders' tracks are
    sampled), along it: back and forth, or once and then stays at its end."""

    id: str
    form: str
    size: Mapping[str, float]
    yaw_rad: float
    a: np.ndarray
    b: np.ndarray | None
    speed_m_s: float
    kind: str = "static"
    path: np.ndarray | None = None  # N x 3 north/east/up
    repeat: str = "back_and_forth"
    position: np.ndarray = field(init=False)
    collision: fcl.CollisionObject = field(init=False)
    # Derived in __post_init__; declared as fields because the compiled module (obstacles.pxd)
    # makes this an extension type, whose attributes are all fields.
    _leg_m: float = field(init=False, repr=False, compare=False)
    _cumulative_m: list[float] = field(init=False, repr=False, compare=False)
    _path_points: list[tuple[float, float, float]] = field(init=False, repr=False, compare=False)
    _a_tuple: tuple[float, float, float] = field(init=False, repr=False, compare=False)
    _delta: tuple[float, float, float] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.repeat not in REPEATS:
            raise ValueError(f"obstacle {self.id}: repeat {self.repeat!r} is not one of {REPEATS}")
        if self.path is not None:
            self.a, self.b = self.path[0].copy(), self.path[-1].copy()
            self._cumulative_m = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(self.path, axis=0), axis=1)))).tolist()
            self._path_points = [tuple(p) for p in self.path.tolist()]
        else:
            self._cumulative_m, self._path_points = [], []
        self.position = self.a.copy()
        self.collision = fcl.CollisionObject(self._geometry(), fcl.Transform(yaw_rotation(self.yaw_rad), self.position))
        if self.path is not None:
            self._leg_m = self._cumulative_m[-1]
        else:
            self._leg_m = 0.0 if self.b is None else float(np.linalg.norm(self.b - self.a))
        self._a_tuple = tuple(self.a.tolist())
        self._delta = (0.0, 0.0, 0.0) if self.b is None else tuple((self.b - self.a).tolist())

    @classmethod
    def from_spec(cls, spec: Mapping[str, Any]) -> "Obstacle":
        def point(p: Mapping[str, float] | None) -> np.ndarray | None:
            return None if p is None else np.array([p["north_m"], p["east_m"], p["up_m"]], dtype=float)

        path = spec.get("path")
        if path is not None and len(path) < 2:
            raise ValueError(f"obstacle {spec['id']}: a path needs at least two points")
        return cls(
            id=spec["id"],
            form=spec["form"],
            size=dict(spec["size"]),
            yaw_rad=float(spec.get("yaw_rad", 0.0)),
            a=point(spec["a"]),
            b=point(spec.get("b")),
            speed_m_s=float(spec.get("speed_m_s", 0.0)),
            kind=spec.get("kind", "static" if spec.get("b") is None and path is None else "dynamic"),
            path=None if path is None else np.array([[p["north_m"], p["east_m"], p["up_m"]] for p in path], dtype=float),
            repeat=spec.get("repeat", "back_and_forth"),
        )

    @property
    def track(self) -> np.ndarray | None:
        """The points a moving obstacle's centre passes through (N x 3 north/east/up); None when still."""
        if not self.moving:
            return None
        return self.path if self.path is not None else np.array([self.a, self.b])

    def _geometry(self):
        size = self.size
        if self.form == "cuboid":
            return convex_box(size["length_m"], size["width_m"], size["height_m"])
        if self.form == "sphere":
            return fcl.Sphere(size["diameter_m"] / 2.0)
        if self.form == "cylinder":
            return fcl.Cylinder(size["diameter_m"] / 2.0, size["height_m"])
        raise ValueError(f"unknown obstacle form {self.form!r}")

    @property
    def moving(self) -> bool:
        return self.b is not None and self.speed_m_s > 0.0 and self._leg_m > 0.0

    @property
    def half_height_m(self) -> float:
        return self.size.get("height_m", self.size.get("diameter_m", 0.0)) / 2.0

    def position_at(self, time_s: float) -> np.ndarray:
        return np.array(self._coordinates_at(time_s)) if self.moving else self.a

    def _coordinates_at(self, time_s: float) -> tuple[float, float, float]:
        """A moving obstacle's centre (north, east, up) at time_s."""
        leg = self._leg_m
        if self.path is not None:
            travelled = self.speed_m_s * time_s
            if self.repeat == "once":
                travelled = min(travelled, leg)
            else:
                travelled %= 2.0 * leg
                travelled = travelled if travelled <= leg else 2.0 * leg - travelled
            return self._along_path(travelled)
        travelled = (self.speed_m_s * time_s) % (2.0 * leg)
        fraction = (travelled if travelled <= leg else 2.0 * leg - travelled) / leg
        (an, ae, au), (dn, de, du) = self._a_tuple, self._delta
        return an + dn * fraction, ae + de * fraction, au + du * fraction

    def _along_path(self, travelled_m: float) -> tuple[float, float, float]:
        cumulative = self._cumulative_m
        segment = min(max(bisect.bisect_right(cumulative, travelled_m) - 1, 0), len(cumulative) - 2)
        length = cumulative[segment + 1] - cumulative[segment]
        fraction = 0.0 if length <= 0.0 else (travelled_m - cumulative[segment]) / length
        (pn, pe, pu), (qn, qe, qu) = self._path_points[segment], self._path_points[segment + 1]
        return pn + (qn - pn) * fraction, pe + (qe - pe) * fraction, pu + (qu - pu) * fraction

    def move_to(self, time_s: float) -> None:
        if self.moving:
            # In place, as ObstacleField.place_body sets the body's pose: no new array every step.
            north, east, up = self._coordinates_at(time_s)
            position = self.position
            position[0], position[1], position[2] = north, east, up
            self.collision.setTranslation(self.position)

    def cross_section(self, up_m: float) -> tuple[str, tuple[float, ...]] | None:
        """The obstacle's horizontal cut at a height: ("circle", (n, e, r)) or ("rect", (n, e, hl, hw, yaw))."""
        n, e, u = self.position
        dz = up_m - u
        if self.form == "sphere":
            radius = self.size["diameter_m"] / 2.0
            return ("circle", (n, e, math.sqrt(radius * radius - dz * dz))) if abs(dz) < radius else None
        if abs(dz) > self.half_height_m:
            return None
        if self.form == "cylinder":
            return "circle", (n, e, self.size["diameter_m"] / 2.0)
        return "rect", (n, e, self.size["length_m"] / 2.0, self.size["width_m"] / 2.0, self.yaw_rad)


# Beyond rounding: a ray's computed distance never falls short of the geometric bound by this.
CULL_MARGIN_M = 1e-6


def _nearest_possible_m(origin_n: float, origin_e: float, cut: tuple[str, tuple[float, ...]]) -> float:
    """A lower bound of every ray's distance to a cross-section: to its centre, less its bounding radius."""
    kind, values = cut
    bounding_m = values[2] if kind == "circle" else math.hypot(values[2], values[3])
    return math.hypot(values[0] - origin_n, values[1] - origin_e) - bounding_m


def ray_distances(origin_n: float, origin_e: float, angles_rad: np.ndarray, cut: tuple[str, tuple[float, ...]]) -> np.ndarray:
    """Distance along horizontal rays (angles clockwise from north) to one cross-section; inf on a miss."""
    un, ue = np.cos(angles_rad), np.sin(angles_rad)
    kind, values = cut
    with np.errstate(divide="ignore", invalid="ignore"):
        if kind == "circle":
            cn, ce, radius = values
            pn, pe = origin_n - cn, origin_e - ce
            b = un * pn + ue * pe
            c = pn * pn + pe * pe - radius * radius
            if c <= 0.0:
                return np.zeros_like(angles_rad)
            disc = b * b - c
            t = -b - np.sqrt(np.where(disc >= 0.0, disc, 0.0))
            return np.where((disc >= 0.0) & (t >= 0.0), t, np.inf)
        cn, ce, half_l, half_w, yaw = values
        cy, sy = math.cos(yaw), math.sin(yaw)
        pn, pe = origin_n - cn, origin_e - ce
        # Into the box frame: x along its length (heading yaw), y along its width.
        px, py = cy * pn + sy * pe, -sy * pn + cy * pe
        if abs(px) <= half_l and abs(py) <= half_w:
            return np.zeros_like(angles_rad)
        dx, dy = cy * un + sy * ue, -sy * un + cy * ue
        t1, t2 = (-half_l - px) / dx, (half_l - px) / dx
        t3, t4 = (-half_w - py) / dy, (half_w - py) / dy
        t_near = np.maximum(np.minimum(t1, t2), np.minimum(t3, t4))
        t_far = np.minimum(np.maximum(t1, t2), np.maximum(t3, t4))
        hit = (t_far >= t_near) & (t_far >= 0.0) & np.isfinite(t_near)
        return np.where(hit, np.maximum(t_near, 0.0), np.inf)


class ObstacleField:
    """All obstacles plus the UAV body; one clearance query per obstacle per step, no allocation."""

    def __init__(self, obstacles: list[Obstacle], body: Body):
        self.obstacles = obstacles
        self._body = fcl.CollisionObject(
            convex_box(body.length_m, body.width_m, body.height_m), fcl.Transform()
        )
        self._request = fcl.DistanceRequest(enable_nearest_points=False, enable_signed_distance=True)
        self._result = fcl.DistanceResult()
        # Filled in place every step: building them anew cost a tenth of the clearance's time.
        self._rotation = np.empty((3, 3))
        self._translation = np.empty(3)

    def add(self, obstacle: Obstacle) -> None:
        self.obstacles = [o for o in self.obstacles if o.id != obstacle.id] + [obstacle]

    def remove(self, obstacle_id: str) -> bool:
        before = len(self.obstacles)
        self.obstacles = [o for o in self.obstacles if o.id != obstacle_id]
        return len(self.obstacles) < before

    def move_to(self, time_s: float) -> None:
        for obstacle in self.obstacles:
            obstacle.move_to(time_s)

    def place_body(self, north_m: float, east_m: float, up_m: float, roll: float, pitch: float, yaw: float) -> None:
        """The body box at the vehicle's pose: NED/FRD Euler angles expressed in north/east/up."""
        cr, sr = math.cos(roll), math.sin(roll)
        cp, sp = math.cos(pitch), math.sin(pitch)
        cy, sy = math.cos(yaw), math.sin(yaw)
        # R_ned_frd with its third row and column negated: the same rotation seen with up instead of down.
        r, t = self._rotation, self._translation
        r[0, 0], r[0, 1], r[0, 2] = cp * cy, sr * sp * cy - cr * sy, -(cr * sp * cy + sr * sy)
        r[1, 0], r[1, 1], r[1, 2] = cp * sy, sr * sp * sy + cr * cy, -(cr * sp * sy - sr * cy)
        r[2, 0], r[2, 1], r[2, 2] = sp, -sr * cp, cr * cp
        t[0], t[1], t[2] = north_m, east_m, up_m
        # The arrays themselves: compiled, r and t are typed views of them, which fcl does not take.
        # Set in place rather than through a new fcl.Transform: a third of this call's time.
        self._body.setRotation(self._rotation)
        self._body.setTranslation(self._translation)

    def clearances(self) -> list[float]:
        distance, body, request, result = fcl.distance, self._body, self._request, self._result
        return [distance(body, o.collision, request, result) for o in self.obstacles]

    def sector_distances(self, north_m: float, east_m: float, up_m: float, angles_rad: np.ndarray, reach_m: float = math.inf) -> np.ndarray | None:
        """Per ray, the distance to the nearest obstacle (inf: none); an obstacle wholly farther
        than reach_m is left out, as every ray would find it farther than that. None: no
        obstacle at this height within reach_m."""
        nearest = None
        for obstacle in self.obstacles:
            cut = obstacle.cross_section(up_m)
            if cut is not None and _nearest_possible_m(north_m, east_m, cut) <= reach_m + CULL_MARGIN_M:
                distances = ray_distances(north_m, east_m, angles_rad, cut)
                nearest = distances if nearest is None else np.minimum(nearest, distances, out=nearest)
        return nearest
