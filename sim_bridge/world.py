"""The simulated world, stepped in lockstep: the vehicle's physics (JSBSim) over the terrain and in
the wind, the obstacles and their motion, what the sensors read, the simulated pilot, the
clearance between the vehicle and every obstacle, and when a flight has ended.

No sockets, no wall clock and no MAVLink framing: sim_bridge/bridge.py serves the world to a
SUT over PX4's simulator protocol, holds it while the harness sets up, and records it. Its
readings draw sensor noise from the world's seed, so the same calls in the same order give the
same flight to the last bit.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, Callable

import numpy as np

from sim_bridge.control import AddObstacle, EndReason, MoveObstacle, ObstacleOp, RemoveObstacle
from sim_bridge.obstacles import Obstacle, ObstacleField
from sim_bridge.physics import Multirotor, VehicleState
from sim_bridge.pilot import Pilot, RcFrame
from sim_bridge.sensors import SensorModel
from sim_bridge.terrain import is_water, terrain_height_m
from sim_bridge.wind import WindField

SECTORS = 72
SECTOR_DEG = 5.0
LANDED_HOLD_S = 1.0
CRASH_SPEED_M_S = 4.0
NO_READING = 65535  # UINT16_MAX: a sector the sensor does not cover, as OBSTACLE_DISTANCE has it
PILOT_RAYS_RAD = np.radians(np.arange(0.0, 360.0, 2.0))  # how finely a programme's pilot sees where the nearest obstacle is
PILOT_SIGHT_M = 100.0


def _ignore_event(time_s: float, event: str, detail: dict[str, Any]) -> None:
    pass


def _ignore_change(time_s: float, removed_id: str | None) -> None:
    pass


def vehicle_for(spec: WorldSpec, rate_hz: float) -> Multirotor:
    """JSBSim's F450 at the world's start point and temperature, stepped at rate_hz."""
    return Multirotor(
        lat_deg=spec.origin.lat_deg,
        lon_deg=spec.origin.lon_deg,
        ground_msl_m=spec.start_msl_m,
        rate_hz=rate_hz,
        temperature_c=spec.atmosphere.temperature_c,
    )


class World:
    """The world of one flight, built from its world spec (what the harness's world_spec makes)."""

    def __init__(self, spec: WorldSpec, rate_hz: float, *,
                 on_event: Callable[[float, str, dict[str, Any]], None] = _ignore_event,
                 on_obstacles_changed: Callable[[float, str | None], None] = _ignore_change):
        self.spec = spec
        self.on_event = on_event
        self.on_obstacles_changed = on_obstacles_changed
        atmosphere = spec.atmosphere
        self.terrain = spec.terrain
        self.water = spec.surface.water
        self.wind_field = WindField(atmosphere, spec.seed, 1.0 / rate_hz)
        self.wind_now = self.wind_field.steady  # north, east, down m/s: the air's velocity for the next step
        self._gust_announced = False
        self.vehicle = vehicle_for(spec, rate_hz)
        self.sensors = SensorModel(spec.seed, atmosphere.temperature_c)
        self.field = ObstacleField([Obstacle.from_spec(o) for o in spec.obstacles], spec.uav.body)
        self.range_m = float(spec.sensor.range_m)
        self.min_range_m = float(spec.sensor.min_range_m)
        half_fov = spec.sensor.fov_deg / 2.0
        self.sector_visible = np.array([min(i * SECTOR_DEG, 360.0 - i * SECTOR_DEG) <= half_fov + 1e-9 for i in range(SECTORS)])
        self._sector_angles = np.radians(np.arange(SECTORS) * SECTOR_DEG)[self.sector_visible]
        # The sensors sit on the body's edge: each ray's range starts at the hull, not the centre.
        half_l, half_w = spec.uav.body.length_m / 2.0, spec.uav.body.width_m / 2.0
        with np.errstate(divide="ignore"):
            self._hull_offsets = np.minimum(half_l / np.abs(np.cos(self._sector_angles)), half_w / np.abs(np.sin(self._sector_angles)))
        # Seen from the centre, a reading within range lies at most this far: obstacles beyond need no rays.
        self._reach_from_centre_m = self.range_m + float(np.max(self._hull_offsets, initial=0.0))
        self._nothing_in_reach = [int(self.range_m * 100) + 1 if visible else NO_READING for visible in self.sector_visible.tolist()]
        self.dt = 1.0 / rate_hz
        self.dt_us = int(round(1e6 / rate_hz))
        self.steps = 0
        self.motors = (0.0, 0.0, 0.0, 0.0)  # the SUT's last answer
        self.run_start_s: float | None = None
        self.end_reason = EndReason.RUNNING
        self.airborne = False
        self.touchdown: dict[str, Any] | None = None
        # The first touchdown once airborne, kept through any hop after it: when the flight came
        # down, which the hops of a landing (the SUT's land detector against the skids) do not move.
        self.first_touchdown_s: float | None = None
        self.injections: list[dict[str, Any]] = []
        self.forced_slot: int | None = None
        self._pending_ops: list[ObstacleOp] = []
        self._moved_for_next_step = False
        self._landed_since: float | None = None
        self.pilot: Pilot | None = None
        if spec.drive == "pilot":
            self.pilot = Pilot(spec.uav.start, spec.mission.waypoints, spec.mission.takeoff_altitude_m, spec.pilot.max_stick, spec.pilot.aim_offset_m,
                               spec.pilot.programme or (), self.obstacle_bearing)

    @property
    def state(self) -> VehicleState:
        return self.vehicle.state

    @property
    def time_s(self) -> float:
        return self.steps * self.dt

    @property
    def running(self) -> bool:
        return self.end_reason is EndReason.RUNNING

    def run_time(self, time_s: float) -> float:
        """Simulation seconds since the run began (0 before): obstacles move and the time limit counts in it."""
        return 0.0 if self.run_start_s is None else time_s - self.run_start_s

    def start_run(self, time_s: float) -> None:
        if self.run_start_s is None:
            self.run_start_s = time_s
            self.on_event(time_s, "run", {})

    def end(self, reason: EndReason) -> None:
        self.end_reason = reason

    # -- readings ----------------------------------------------------------------------------

    def imu(self) -> tuple:
        """This step's HIL_SENSOR values (accelerometer, gyro, magnetometer, barometer), with noise."""
        return self.sensors.hil_sensor_values(self.vehicle.state)

    def gps(self) -> dict[str, Any]:
        return self.sensors.hil_gps(self.vehicle.state, self.vehicle.local_to_geodetic)

    def range_cm(self) -> list[int]:
        """The range sensor's reading per 5-degree sector in body FRD (OBSTACLE_DISTANCE's
        convention): centimetres from the hull, range + 1 cm where nothing is in reach, NO_READING
        outside its field of view."""
        s = self.vehicle.state
        reach_cm = int(self.range_m * 100)
        nearest = self.field.sector_distances(s.north_m, s.east_m, s.up_m, self._sector_angles + s.yaw_rad, self._reach_from_centre_m)
        if nearest is None:
            return list(self._nothing_in_reach)
        nearest -= self._hull_offsets
        distances = [NO_READING] * SECTORS
        visible = np.flatnonzero(self.sector_visible)
        for index, distance in zip(visible.tolist(), nearest.tolist()):
            if distance <= self.range_m:
                distances[index] = max(int(self.min_range_m * 100), int(distance * 100))
            else:
                distances[index] = reach_cm + 1
        return distances

    def obstacle_bearing(self, state: VehicleState) -> float | None:
        """Where the nearest obstacle lies from the vehicle (radians clockwise from north), as a
        pilot sees it, to PILOT_SIGHT_M (None: nothing that near)."""
        nearest = self.field.sector_distances(state.north_m, state.east_m, state.up_m, PILOT_RAYS_RAD, PILOT_SIGHT_M)
        if nearest is None or not np.isfinite(np.min(nearest)):
            return None
        return float(PILOT_RAYS_RAD[int(np.argmin(nearest))])

    def hull_offset(self, body_angles_rad: np.ndarray) -> np.ndarray:
        """How far the hull is from the vehicle's centre in each direction of the body."""
        half_l, half_w = self.spec.uav.body.length_m / 2.0, self.spec.uav.body.width_m / 2.0
        with np.errstate(divide="ignore"):
            return np.minimum(half_l / np.abs(np.cos(body_angles_rad)), half_w / np.abs(np.sin(body_angles_rad)))

    def nearest(self, world_angles_rad: np.ndarray, reach_m: float) -> np.ndarray | None:
        """Along each horizontal ray from the vehicle's centre (clockwise from north), the distance
        to the nearest obstacle (inf: none); None: no obstacle within reach_m."""
        s = self.vehicle.state
        return self.field.sector_distances(s.north_m, s.east_m, s.up_m, world_angles_rad, reach_m)

    def pilot_frame(self, time_s: float) -> RcFrame:
        """The simulated pilot's sticks and switch now (its mode switch held where the harness asked)."""
        frame = self.pilot.update(time_s, self.vehicle.state)
        return frame if self.forced_slot is None else replace(frame, slot=self.forced_slot)

    def clearance(self) -> tuple[float | None, str | None]:
        """The clearance from the vehicle's body to the nearest obstacle and which one (None, None
        with no obstacle); negative when they overlap."""
        s = self.vehicle.state
        self.field.place_body(s.north_m, s.east_m, s.up_m, s.roll_rad, s.pitch_rad, s.yaw_rad)
        clearances = self.field.clearances()
        if not clearances:
            return None, None
        nearest = min(range(len(clearances)), key=clearances.__getitem__)
        return clearances[nearest], self.field.obstacles[nearest].id

    # -- stepping ----------------------------------------------------------------------------

    def move_obstacles_for_next_step(self) -> None:
        """The obstacles' motion to the next step's time, which no motor command changes: done
        while the SUT computes its answer, it is off the lockstep's critical path when the SUT
        has a core of its own. step() then leaves it out."""
        self.field.move_to(self.run_time((self.steps + 1) * self.dt))
        self._moved_for_next_step = True

    def step(self, motors: tuple[float, float, float, float]) -> None:
        """One physics step with these motor commands, then the obstacles' changes and motion due
        by the new time. check_end() follows once the step's control messages are handled."""
        s = self.vehicle.state
        if self.wind_field.varies:
            self._advance_wind()
        wind_n, wind_e, wind_d = self.wind_now
        self.vehicle.step(motors, terrain_height_m(self.terrain, s.north_m, s.east_m), wind_n, wind_e, wind_d)
        self.steps += 1
        time_s = self.time_s
        run_time = self.run_time(time_s)
        # A change places its obstacle at this time itself; the others' motion may be done already.
        while self._pending_ops and self._pending_ops[0].at_s <= run_time:
            self.apply(self._pending_ops.pop(0), time_s)
        if not self._moved_for_next_step:
            self.field.move_to(run_time)
        self._moved_for_next_step = False

    def _advance_wind(self) -> None:
        s = self.vehicle.state
        run_time = None if self.run_start_s is None else self.run_time(self.time_s)
        steady_n, steady_e, _ = self.wind_field.steady
        airspeed = math.hypot(s.v_north_m_s - steady_n, s.v_east_m_s - steady_e)
        self.wind_now = self.wind_field.advance(run_time, airspeed)
        gust = self.wind_field.gust
        if gust is not None and not self._gust_announced and run_time is not None and run_time >= gust.onset_s:
            self._gust_announced = True
            self.on_event(self.time_s, "gust", {"amplitude_m_s": gust.amplitude_m_s, "from_deg": gust.from_deg, "duration_s": gust.duration_s})

    def schedule(self, op: ObstacleOp) -> None:
        """An obstacle change to make at run time op.at_s."""
        self._pending_ops.append(op)
        self._pending_ops.sort(key=lambda o: o.at_s)

    def apply(self, op: ObstacleOp, time_s: float) -> None:
        """An obstacle change now (sim_bridge/control.py)."""
        record = {"op": op.NAME, "t": time_s}
        removed = None
        if isinstance(op, AddObstacle):
            obstacle = Obstacle.from_spec(op.obstacle)
            obstacle.move_to(self.run_time(time_s))
            self.field.add(obstacle)
            record["id"] = obstacle.id
        elif isinstance(op, MoveObstacle):
            current = next((o for o in self.field.obstacles if o.id == op.id), None)
            if current is None:
                self.on_event(time_s, "injection_rejected", {"reason": f"no obstacle {op.id!r}"})
                return
            spec = {"id": current.id, "form": current.form, "size": current.size, "yaw_rad": current.yaw_rad if op.yaw_rad is None else op.yaw_rad,
                    "a": op.a, "b": op.b, "speed_m_s": 0.0 if op.speed_m_s is None else op.speed_m_s}
            obstacle = Obstacle.from_spec(spec)
            obstacle.move_to(self.run_time(time_s))
            self.field.add(obstacle)
            record["id"] = obstacle.id
        elif isinstance(op, RemoveObstacle):
            record["id"] = op.id
            if not self.field.remove(op.id):
                self.on_event(time_s, "injection_rejected", {"reason": f"no obstacle {op.id!r}"})
                return
            removed = op.id
        else:
            raise TypeError(f"{op!r} is no obstacle change")
        self.injections.append(record)
        self.on_event(time_s, "injection", record)
        self.on_obstacles_changed(time_s, removed)

    def check_end(self) -> None:
        """Whether the flight has ended: landed (still, motors idle, for a second), crashed (a
        touchdown faster than CRASH_SPEED_M_S), the pilot blocked, or out of time."""
        time_s = self.time_s
        s = self.vehicle.state
        run_time = self.run_time(time_s)
        if s.agl_m > 1.0:
            self.airborne = True
        speed = math.sqrt(s.v_north_m_s**2 + s.v_east_m_s**2 + s.v_down_m_s**2)
        if self.airborne and s.on_ground:
            if self.touchdown is None:
                self.touchdown = {
                    "t": time_s,
                    "north_m": s.north_m,
                    "east_m": s.east_m,
                    "speed_m_s": speed,
                    "surface": "water" if is_water(self.water, s.north_m, s.east_m) else "land",
                }
                self.on_event(time_s, "touchdown", dict(self.touchdown))
                if self.first_touchdown_s is None:
                    self.first_touchdown_s = time_s
                if speed > CRASH_SPEED_M_S:
                    self.end_reason = EndReason.CRASHED
                    return
            if speed < 0.3 and max(self.motors) < 0.15:
                if self._landed_since is None:
                    self._landed_since = time_s
                elif time_s - self._landed_since >= LANDED_HOLD_S:
                    self.end_reason = EndReason.LANDED
                    return
            else:
                self._landed_since = None
        else:
            self._landed_since = None
            if not s.on_ground:
                self.touchdown = None
        if self.pilot is not None and self.pilot.blocked:
            self.end_reason = EndReason.BLOCKED
            self.on_event(time_s, "blocked", {"remaining_m": self.pilot.remaining_m, "north_m": s.north_m, "east_m": s.east_m})
            return
        if self.run_start_s is not None and run_time >= self.spec.time_limit_s:
            self.end_reason = EndReason.TIME_LIMIT
