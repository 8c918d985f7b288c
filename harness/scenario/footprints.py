"""Obstacles' footprints on the ground plan, exact, for the realism constraints of a whole population.

A footprint is a core shape grown by a radius: a cuboid's rotated rectangle (radius 0), a
sphere's or cylinder's centre point (radius half its diameter). Distances are shapely's, over
arrays of geometries (one per row of a population), so a long thin box counts as the box it is,
not as the disc around it. A moving obstacle keeps its yaw, so its swept footprint is its
footprint slid along its centre's path; the distance from a point P to it is that of the
footprint at the origin to the polyline P - path (a Minkowski difference), one shapely call
for the whole population.

Each distance is signed: where the shapes overlap it is minus a depth (how deep a point or a
path lies inside a rectangle, the square root of two rectangles' common area), so that a search
that placed two obstacles on each other is led apart, not left on a flat zero.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import shapely

# A path inside a rectangle is sampled this finely for its depth there.
DEPTH_STEP_M = 0.25


@dataclass(frozen=True)
class Footprints:
    """One obstacle's footprint in each of n rows: its core at the origin, its radius, and the
    path of its centre (n x samples, one sample for an obstacle that stays where it is)."""

    core: np.ndarray  # (n,) shapely geometries centred at the origin: polygons or points
    radius_m: np.ndarray  # (n,)
    path_north_m: np.ndarray  # (n, samples)
    path_east_m: np.ndarray  # (n, samples)

    @classmethod
    def rectangles(cls, *, length_m, width_m, yaw_deg, path_north_m, path_east_m) -> "Footprints":
        """Cuboids: length along the heading yaw_deg (clockwise from north), width across it."""
        yaw = np.radians(np.asarray(yaw_deg, dtype=float))
        half_l, half_w = 0.5 * np.asarray(length_m, dtype=float), 0.5 * np.asarray(width_m, dtype=float)
        along = np.stack([np.cos(yaw), np.sin(yaw)], axis=-1)  # (north, east) of the length axis
        across = np.stack([-np.sin(yaw), np.cos(yaw)], axis=-1)
        signs = np.array([(1, 1), (1, -1), (-1, -1), (-1, 1), (1, 1)], dtype=float)
        corners = (signs[None, :, 0, None] * (half_l[:, None] * along)[:, None, :]
                   + signs[None, :, 1, None] * (half_w[:, None] * across)[:, None, :])
        return cls(shapely.polygons(_xy(corners[..., 0], corners[..., 1])), np.zeros_like(half_l), *_paths(path_north_m, path_east_m))

    @classmethod
    def discs(cls, *, diameter_m, path_north_m, path_east_m) -> "Footprints":
        radius = 0.5 * np.asarray(diameter_m, dtype=float)
        return cls(shapely.points(np.zeros((len(radius), 2))), radius, *_paths(path_north_m, path_east_m))

    @property
    def moving(self) -> bool:
        return self.path_north_m.shape[1] > 1

    def clearance_to(self, north_m: float, east_m: float) -> np.ndarray:
        """Signed distance from the point to the footprint swept along its path, per row."""
        rel_north, rel_east = north_m - self.path_north_m, east_m - self.path_east_m
        if self.moving:
            relative = shapely.linestrings(_xy(rel_north, rel_east))
        else:
            relative = shapely.points(_xy(rel_north[:, 0], rel_east[:, 0]))
        distance = shapely.distance(self.core, relative)
        touching = distance == 0.0
        if touching.any():
            distance[touching] = -_deepest_inside(self.core[touching], relative[touching])
        return distance - self.radius_m

    @cached_property
    def placed(self) -> np.ndarray:
        """The cores where they stand (the first sample of the path)."""
        return _translated(self.core, _xy(self.path_north_m[:, 0], self.path_east_m[:, 0]))

    def separation_from(self, other: "Footprints") -> np.ndarray:
        """Signed distance between two footprints where they stand, per row: where they overlap,
        minus the square root of their common area, or how deep a round one's centre lies in a
        rectangle."""
        distance = shapely.distance(self.placed, other.placed)
        touching = distance == 0.0
        if touching.any():
            mine, theirs = self.placed[touching], other.placed[touching]
            both_areas = (shapely.area(mine) > 0.0) & (shapely.area(theirs) > 0.0)
            distance[touching] = -np.where(both_areas, np.sqrt(shapely.area(shapely.intersection(mine, theirs))), _depth_of_point(mine, theirs))
        return distance - self.radius_m - other.radius_m


def _xy(north, east) -> np.ndarray:
    """Coordinates as shapely takes them: x east, y north."""
    return np.stack([np.asarray(east, dtype=float), np.asarray(north, dtype=float)], axis=-1)


def _paths(north, east) -> tuple[np.ndarray, np.ndarray]:
    north, east = np.asarray(north, dtype=float), np.asarray(east, dtype=float)
    return (north[:, None], east[:, None]) if north.ndim == 1 else (north, east)


def _translated(geometries: np.ndarray, offset_xy: np.ndarray) -> np.ndarray:
    """Each geometry moved by its own row of offsets (shapely's transform takes one function for
    all coordinates, so the offsets are repeated per coordinate)."""
    counts = shapely.get_num_coordinates(geometries)
    repeated = np.repeat(offset_xy, counts, axis=0)
    return shapely.transform(geometries, lambda xy: xy + repeated)


def _deepest_inside(polygons: np.ndarray, shapes: np.ndarray) -> np.ndarray:
    """How far inside each polygon the deepest point of its shape (a point, or a path made dense
    to DEPTH_STEP_M) lies, from the polygon's edge; 0 for a round footprint's core (a point)."""
    dense = shapely.segmentize(shapes, DEPTH_STEP_M)
    coordinates, row = shapely.get_coordinates(dense, return_index=True)
    points = shapely.points(coordinates)
    inside = shapely.contains(polygons[row], points)
    depth = np.where(inside, np.nan_to_num(shapely.distance(shapely.get_exterior_ring(polygons[row]), points), nan=0.0), 0.0)
    deepest = np.zeros(len(polygons))
    np.maximum.at(deepest, row, depth)
    return deepest


def _depth_of_point(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Where one of a pair is a point inside the other, a polygon, how far inside; else 0."""
    a_is_point = shapely.area(a) == 0.0
    point, polygon = np.where(a_is_point, a, b), np.where(a_is_point, b, a)
    # A point's exterior ring is None, its distance NaN: two points have no depth.
    return np.nan_to_num(shapely.distance(point, shapely.get_exterior_ring(polygon)), nan=0.0)
