"""The geometry of an approach, for `stella explain` (harness/campaigns/explain.py): the obstacle
of the closest approach seen from the vehicle as the world spec moves it, and as the profile's
range sensor, or each sensor of the vehicle's rig, would read it alone (an ideal sensor).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from sim_bridge.obstacles import Obstacle, ray_distances
from sim_bridge.rig import sensor_rays

SECTOR_DEG = 5.0  # OBSTACLE_DISTANCE's sectors as sim_bridge/world.py reads them (its SECTOR_DEG)
FULL_CIRCLE = np.radians(np.arange(0.0, 360.0, 1.0))


@dataclass(frozen=True)
class Moment:
    """The geometry at one instant: horizontal distance from the vehicle's hull to the obstacle's
    cut at the vehicle's height (None when the obstacle is not at that height), the unit vector
    towards its nearest point (horizontal at that height; else vertical over or under it, or
    towards its centre), and the speeds towards each other along it."""

    t_s: float
    distance_m: float | None
    towards: tuple[float, float, float]  # north, east, up
    own_closing_m_s: float
    obstacle_closing_m_s: float
    in_fov: bool
    in_view: bool  # in the field of view and within the sensor's reach


def _hull_offset(body: Any, relative_rad: float) -> float:
    half_l, half_w = body.length_m / 2.0, body.width_m / 2.0
    c, s = abs(math.cos(relative_rad)), abs(math.sin(relative_rad))
    return min(half_l / c if c > 1e-9 else math.inf, half_w / s if s > 1e-9 else math.inf)


@dataclass(frozen=True)
class RigView:
    """One sensor of a rig as an ideal sensor reads the obstacle: its rays (radians from the nose,
    or from north where world_fixed), which of its readings each is part of, and its reach."""

    name: str
    reach_m: float
    reading: np.ndarray
    angles_rad: np.ndarray
    world_fixed: bool

    @classmethod
    def of(cls, sensor: Any) -> "RigView":
        rays = sensor_rays(sensor)
        return cls(sensor.name, sensor.range_m, np.array([reading for reading, _ in rays]), np.radians([angle for _, angle in rays]),
                   sensor.message == "OBSTACLE_DISTANCE" and sensor.frame == "local")


class Geometry:
    """The obstacle of the closest approach seen from the vehicle, as the world spec moves it,
    and as the profile's sensor or each sensor of the vehicle's rig would read it."""

    def __init__(self, world: Any, spec: Mapping[str, Any], run_start_s: float):
        self.world, self.run_start_s = world, run_start_s
        self.obstacle = Obstacle.from_spec(spec)
        self.half_fov_rad = math.radians(world.sensor.fov_deg / 2.0 + SECTOR_DEG / 2.0)
        half = world.sensor.fov_deg / 2.0
        self.sectors = [i for i in range(int(360 / SECTOR_DEG)) if min(i * SECTOR_DEG, 360.0 - i * SECTOR_DEG) <= half + 1e-9]
        self.sector_angles = np.radians(np.array(self.sectors) * SECTOR_DEG)
        self.rig = [RigView.of(sensor) for sensor in world.rig or ()]

    def placed(self, t_s: float) -> Obstacle:
        self.obstacle.move_to(max(0.0, t_s - self.run_start_s))
        return self.obstacle

    def velocity(self, t_s: float) -> np.ndarray:
        run = max(0.0, t_s - self.run_start_s)
        return (self.obstacle.position_at(run + 0.05) - self.obstacle.position_at(max(0.0, run - 0.05))) / (run + 0.05 - max(0.0, run - 0.05))

    def moment(self, state: Mapping[str, Any]) -> Moment:
        t, yaw = state["t"], state["rpy_rad"][2]
        obstacle = self.placed(t)
        cut = obstacle.cross_section(state["up_m"])
        distance, towards = None, None
        if cut is not None:
            rays = ray_distances(state["north_m"], state["east_m"], FULL_CIRCLE, cut)
            nearest = int(np.argmin(rays))
            if math.isfinite(rays[nearest]):
                bearing = float(FULL_CIRCLE[nearest])
                towards = (math.cos(bearing), math.sin(bearing), 0.0)
                distance = max(0.0, float(rays[nearest]) - _hull_offset(self.world.uav.body, bearing - yaw))
        if towards is None:  # above or below the vehicle (landing on it, climbing into it)
            towards = self._vertical_or_centre(obstacle, state)
        vn, ve, vd = state["v_ned_m_s"]
        own = vn * towards[0] + ve * towards[1] - vd * towards[2]
        moving = self.velocity(t)
        if self.rig:
            # In a sensor's view where one of its rays meets it; in view where that is within its reach.
            seen = self._rig_rays(state, cut)
            in_fov = any(np.isfinite(distances).any() for _view, distances in seen)
            in_view = any((distances <= view.reach_m).any() for view, distances in seen)
        else:
            relative = (math.atan2(towards[1], towards[0]) - yaw + math.pi) % (2.0 * math.pi) - math.pi
            in_fov = cut is not None and abs(relative) <= self.half_fov_rad
            in_view = in_fov and distance is not None and distance <= self.world.sensor.range_m
        return Moment(t, distance, towards, own, -float(np.dot(moving, towards)), in_fov, in_view)

    def _rig_rays(self, state: Mapping[str, Any], cut) -> list[tuple[RigView, np.ndarray]]:
        """Each rig sensor's rays' distances from the hull to this obstacle alone (inf: a miss)."""
        if cut is None:
            return []
        yaw = state["rpy_rad"][2]
        seen = []
        for view in self.rig:
            world_angles = view.angles_rad if view.world_fixed else view.angles_rad + yaw
            rays = ray_distances(state["north_m"], state["east_m"], world_angles, cut)
            hull = np.array([_hull_offset(self.world.uav.body, angle - yaw) for angle in world_angles.tolist()])
            seen.append((view, np.maximum(0.0, rays - hull)))
        return seen

    def ideal_readings(self, state: Mapping[str, Any]) -> dict[tuple[str, int], float]:
        """(rig sensor, reading) -> the distance from the hull at which an ideal sensor would read
        this obstacle alone, for the readings that reach it."""
        found: dict[tuple[str, int], float] = {}
        for view, distances in self._rig_rays(state, self.placed(state["t"]).cross_section(state["up_m"])):
            for reading, distance in zip(view.reading.tolist(), distances.tolist()):
                if distance <= view.reach_m:
                    found[(view.name, reading)] = min(found.get((view.name, reading), math.inf), distance)
        return found

    @staticmethod
    def _vertical_or_centre(obstacle: Obstacle, state: Mapping[str, Any]) -> tuple[float, float, float]:
        """Straight up or down over or under its footprint, else towards its centre."""
        n, e, u = obstacle.position.tolist()
        middle = obstacle.cross_section(u)
        if middle is not None and ray_distances(state["north_m"], state["east_m"], np.zeros(1), middle)[0] == 0.0:
            return (0.0, 0.0, 1.0 if u > state["up_m"] else -1.0)
        dn, de, du = n - state["north_m"], e - state["east_m"], u - state["up_m"]
        norm = math.sqrt(dn * dn + de * de + du * du) or 1.0
        return (dn / norm, de / norm, du / norm)

    def ideal_sectors(self, state: Mapping[str, Any]) -> dict[int, float]:
        """Sector -> the distance from the hull at which an ideal sensor would read this obstacle
        alone, for the sectors that reach it."""
        cut = self.placed(state["t"]).cross_section(state["up_m"])
        if cut is None:
            return {}
        rays = ray_distances(state["north_m"], state["east_m"], self.sector_angles + state["rpy_rad"][2], cut)
        found = {}
        for sector, angle, distance in zip(self.sectors, self.sector_angles.tolist(), rays.tolist()):
            distance -= _hull_offset(self.world.uav.body, angle)
            if distance <= self.world.sensor.range_m:
                found[sector] = max(0.0, distance)
        return found
