"""The lockstep loop: PX4's simulator protocol on one side, JSBSim and the world on the other.

Protocol (as PX4's simulator_mavlink expects it): the bridge listens on TCP, the SUT connects.
Every physics step the bridge sends HIL_SENSOR (time_usec drives the SUT's clock), about 10 Hz
HIL_GPS, 50 Hz HIL_STATE_QUATERNION (ground truth) and OBSTACLE_DISTANCE at the sensor's rate.
Until the SUT's first HIL_ACTUATOR_CONTROLS the bridge runs at real-time pace with the vehicle
resting on the ground; from then on it waits for one actuator answer per step (lockstep).

Control channel (newline-delimited JSON over TCP, one client, the harness):
  bridge -> harness: {"event": "sut_connected", "t": 0.0} and {"event": "lockstep_started",
      "t": ..., "step": N} as they happen; {"event": "holding", "t": ...} once `hold_after_s` of
      simulation have passed: the harness can now connect, upload and arm while simulated time
      stands still (hold mode "frozen") or runs on at real-time pace (hold mode "paced", for
      SUTs whose threads follow the lockstep clock); {"event": "finished", ...summary} at the
      end. Messages sent before the harness connects wait for it.
  harness -> bridge: {"op": "run"} ends the hold; {"op": "stop"} ends the run;
      {"op": "add_obstacle", "obstacle": {...world-spec obstacle...}, "at_s": T};
      {"op": "move_obstacle", "id": ID, "a": {...}, "b": {...} | null, "speed_m_s": V, "at_s": T};
      {"op": "remove_obstacle", "id": ID, "at_s": T}. `at_s` is run time (simulation seconds
      since "run"); without it the change applies at the next step.
      {"op": "rc_mode_slot", "slot": N}: with the pilot drive, hold the pilot's mode switch in
      slot N from now on (`stella sut check` asks a SUT on the ground for Position mode so).

With the pilot drive (world "drive": "pilot") a simulated pilot (sim_bridge/pilot.py) flies the
route with RC_CHANNELS frames every 20 ms of simulated time, sent before HIL_SENSOR like the
other messages of a step; a pilot that makes no progress for 20 s ends the run ("blocked").

Run time t_run starts at "run" (or at the first step when there is no hold); dynamic obstacles
move and the time limit counts in run time, so the flight is independent of how long the
harness took to set up.
"""

from __future__ import annotations

import json
import logging
import math
import select
import socket
import time
from dataclasses import dataclass, field, replace
from typing import Any, Mapping

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from sim_bridge.obstacles import Obstacle, ObstacleField
from sim_bridge.physics import Multirotor
from sim_bridge.pilot import CHANNEL_COUNT, RC_PERIOD_S, Pilot
from sim_bridge.recording import Recorder, enu, enu_flu_orientation, stamp, yaw_orientation
from sim_bridge.sensors import FIELDS_ALL, SensorModel, quaternion_from_euler
from sim_bridge.terrain import is_water, terrain_height_m
from simlink import codec

log = logging.getLogger(__name__)

SYSTEM_ID = 1
COMPONENT_ID = 51
UINT16_MAX = 65535
SECTORS = 72
SECTOR_DEG = 5.0
RECORD_EVERY_S = 0.04
SCENE_EVERY_S = 0.1
LINK_FLUSH_EVERY_S = 0.1
LANDED_HOLD_S = 1.0
CRASH_SPEED_M_S = 4.0
RANGE_MESSAGES = ("OBSTACLE_DISTANCE", "DISTANCE_SENSOR")
STEP_TIMERS = ("sensors_s", "send_s", "wait_s", "physics_s", "world_s")
# Simulation milestones the harness hears of on the control channel as well (`stella sut check`).
FORWARDED_EVENTS = ("sut_connected", "lockstep_started")
_CRC_EXTRAS = {msgid: cls.crc_extra for msgid, cls in mavlink.mavlink_map.items()}


@dataclass
class BridgeConfig:
    rate_hz: float = 250.0
    hold_after_s: float = 3.0
    # "frozen": simulated time stops during the hold (for SUTs that answer MAVLink regardless of
    # their clock, like the bundled autopilot); "paced": it runs on at real-time pace with the
    # vehicle free to move (for SUTs whose every thread follows the lockstep clock, like PX4).
    hold_mode: str = "frozen"
    # What carries the range sensor's reading to the SUT: only what it reads costs a step's time.
    range_messages: tuple[str, ...] = RANGE_MESSAGES
    stall_timeout_s: float = 10.0
    hold_timeout_s: float = 120.0
    # Poll for the SUT's answer this long before sleeping: only when the SUT has a core of its own.
    spin_s: float = 0.0
    gps_rate_hz: float = 10.0
    ground_truth_rate_hz: float = 50.0


@dataclass
class Summary:
    end_reason: str = "running"
    sim_time_s: float = 0.0
    run_time_s: float = 0.0
    steps: int = 0
    airborne: bool = False
    touchdown: dict[str, Any] | None = None
    bad_frames: int = 0
    skipped_bytes: int = 0
    wall_time_s: float = 0.0
    wall_in_run_s: float = 0.0
    wait_s: float = 0.0
    physics_s: float = 0.0
    world_s: float = 0.0
    sensors_s: float = 0.0
    send_s: float = 0.0
    injections: list[dict[str, Any]] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


class ControlChannel:
    """The harness's side channel; absent until the harness connects."""

    def __init__(self, listener: socket.socket | None):
        self._listener = listener
        self._conn: socket.socket | None = None
        self._buffer = b""
        self._backlog: list[Mapping[str, Any]] = []
        if listener is not None:
            listener.setblocking(False)

    @property
    def connected(self) -> bool:
        return self._conn is not None

    def poll(self, timeout_s: float = 0.0) -> list[dict[str, Any]]:
        sockets = [s for s in (self._listener, self._conn) if s is not None]
        if not sockets:
            if timeout_s:
                time.sleep(timeout_s)
            return []
        readable, _, _ = select.select(sockets, [], [], timeout_s)
        ops = []
        for sock in readable:
            if sock is self._listener:
                self._conn, _ = self._listener.accept()
                self._conn.setblocking(False)
                backlog, self._backlog = self._backlog, []
                for message in backlog:
                    self.send(message)
                continue
            try:
                data = sock.recv(65536)
            except BlockingIOError:
                continue
            if not data:
                self._conn = None
                continue
            self._buffer += data
            *lines, self._buffer = self._buffer.split(b"\n")
            for line in lines:
                if line.strip():
                    try:
                        ops.append(json.loads(line))
                    except json.JSONDecodeError:
                        log.warning("ignoring malformed control line %r", line[:80])
        return ops

    def send(self, message: Mapping[str, Any]) -> None:
        """Send now, or as soon as the harness connects."""
        if self._conn is None:
            self._backlog.append(message)
            return
        self._conn.setblocking(True)
        try:
            self._conn.sendall(json.dumps(message).encode() + b"\n")
        except OSError:
            self._conn = None
        else:
            self._conn.setblocking(False)

    def close(self) -> None:
        for sock in (self._conn, self._listener):
            if sock is not None:
                sock.close()


class Bridge:
    def __init__(self, world: Mapping[str, Any], config: BridgeConfig, recorder: Recorder):
        self.world = world
        self.config = config
        self.recorder = recorder
        self.summary = Summary()
        origin = world["origin"]
        start = world["uav"]["start"]
        self._terrain = world["terrain"]
        atmosphere = world["atmosphere"]
        self._wind = (atmosphere["wind_north_m_s"], atmosphere["wind_east_m_s"])
        self.vehicle = Multirotor(
            lat_deg=origin["lat_deg"],
            lon_deg=origin["lon_deg"],
            ground_msl_m=origin["alt_m"] + start["up_m"],
            rate_hz=config.rate_hz,
            temperature_c=atmosphere["temperature_c"],
        )
        self._origin_alt = origin["alt_m"]
        self.sensors = SensorModel(world["seed"], atmosphere["temperature_c"])
        self.field = ObstacleField([Obstacle.from_spec(o) for o in world["obstacles"]], world["uav"]["body"])
        sensor = world["sensor"]
        self._range_m = float(sensor["range_m"])
        self._min_range_m = float(sensor["min_range_m"])
        half_fov = sensor["fov_deg"] / 2.0
        self._sector_visible = np.array(
            [min(i * SECTOR_DEG, 360.0 - i * SECTOR_DEG) <= half_fov + 1e-9 for i in range(SECTORS)]
        )
        self._sector_angles = np.radians(np.arange(SECTORS) * SECTOR_DEG)[self._sector_visible]
        # The sensors sit on the body's edge: each ray's range starts at the hull, not the centre.
        body = world["uav"]["body"]
        half_l, half_w = body["length_m"] / 2.0, body["width_m"] / 2.0
        with np.errstate(divide="ignore"):
            self._hull_offsets = np.minimum(half_l / np.abs(np.cos(self._sector_angles)), half_w / np.abs(np.sin(self._sector_angles)))
        self._wedges = _wedges(np.flatnonzero(self._sector_visible).tolist())
        self._dt = 1.0 / config.rate_hz
        self._dt_us = int(round(1e6 / config.rate_hz))
        self._every = {
            "gps": max(1, round(config.rate_hz / config.gps_rate_hz)),
            "truth": max(1, round(config.rate_hz / config.ground_truth_rate_hz)),
            "sensor": max(1, round(config.rate_hz / sensor["update_hz"])),
            "record": max(1, round(RECORD_EVERY_S * config.rate_hz)),
            "scene": max(1, round(SCENE_EVERY_S * config.rate_hz)),
            "flush": max(1, round(LINK_FLUSH_EVERY_S * config.rate_hz)),
            "control": max(1, round(0.05 * config.rate_hz)),
        }
        self._mav = mavlink.MAVLink(None, srcSystem=SYSTEM_ID, srcComponent=COMPONENT_ID)
        self._motors = (0.0, 0.0, 0.0, 0.0)
        self._pending_ops: list[dict[str, Any]] = []
        self._link_out = bytearray()
        self._link_in = bytearray()
        self._landed_since: float | None = None
        self._clearance_batch: tuple[list, list, list, list] = ([], [], [], [])
        self._run_start_s: float | None = None
        self._hold_deadline: float | None = None
        self._control: ControlChannel | None = None
        self._hold_announced = False
        self._water = world["surface"]["water"]
        self.pilot: Pilot | None = None
        self._forced_slot: int | None = None
        if world.get("drive") == "pilot":
            mission = world["mission"]
            self.pilot = Pilot(start, mission["waypoints"], mission["takeoff_altitude_m"], world["pilot"]["max_stick"], world["pilot"]["aim_offset_m"])
            self._every["rc"] = max(1, round(RC_PERIOD_S * config.rate_hz))

    # -- recording ---------------------------------------------------------------------------

    def _event(self, time_s: float, event: str, **detail: Any) -> None:
        log.info("t=%.3f %s %s", time_s, event, detail)
        self.recorder.write("/events", time_ns=int(time_s * 1e9), message={"t": time_s, "event": event, "detail": detail})
        if event in FORWARDED_EVENTS and self._control is not None:
            self._control.send({"event": event, "t": time_s, **detail})

    def _scene_entity(self, obstacle: Obstacle, time_ns: int) -> dict[str, Any]:
        n, e, u = obstacle.position
        pose = {"position": enu(n, e, u), "orientation": yaw_orientation(obstacle.yaw_rad)}
        color = {"r": 0.9, "g": 0.4, "b": 0.1, "a": 0.8} if obstacle.moving else {"r": 0.5, "g": 0.5, "b": 0.55, "a": 0.9}
        size = obstacle.size
        entity: dict[str, Any] = {
            "timestamp": stamp(time_ns),
            "frame_id": "world",
            "id": obstacle.id,
            "lifetime": stamp(0),
            "frame_locked": False,
            "metadata": [{"key": "form", "value": obstacle.form}],
            "cubes": [],
            "spheres": [],
            "cylinders": [],
            "triangles": [],
        }
        if obstacle.form == "cuboid":
            entity["cubes"].append({"pose": pose, "size": {"x": size["length_m"], "y": size["width_m"], "z": size["height_m"]}, "color": color})
        elif obstacle.form == "sphere":
            d = size["diameter_m"]
            entity["spheres"].append({"pose": pose, "size": {"x": d, "y": d, "z": d}, "color": color})
        else:
            d = size["diameter_m"]
            entity["cylinders"].append(
                {"pose": pose, "size": {"x": d, "y": d, "z": size["height_m"]}, "bottom_scale": 1.0, "top_scale": 1.0, "color": color}
            )
        return entity

    def _terrain_entity(self) -> dict[str, Any]:
        area = 120.0
        cells = 24
        step = 2 * area / cells
        points, colors = [], []

        def vertex(n: float, e: float) -> None:
            water = is_water(self._water, n, e)
            points.append(enu(n, e, terrain_height_m(self._terrain, n, e)))
            colors.append({"r": 0.2, "g": 0.4, "b": 0.8, "a": 1.0} if water else {"r": 0.35, "g": 0.55, "b": 0.3, "a": 1.0})

        for i in range(cells):
            for j in range(cells):
                n0, e0 = -area + 30 + i * step, -area + j * step
                for n, e in ((n0, e0), (n0 + step, e0), (n0 + step, e0 + step), (n0, e0), (n0 + step, e0 + step), (n0, e0 + step)):
                    vertex(n, e)
        identity = {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}
        return {
            "timestamp": stamp(0),
            "frame_id": "world",
            "id": "terrain",
            "lifetime": stamp(0),
            "frame_locked": False,
            "metadata": [{"key": "landform", "value": self._terrain["kind"]}],
            "cubes": [],
            "spheres": [],
            "cylinders": [],
            "triangles": [{"pose": identity, "points": points, "color": {"r": 0.35, "g": 0.55, "b": 0.3, "a": 1.0}, "colors": colors, "indices": []}],
        }

    def _record_scene(self, time_ns: int, everything: bool) -> None:
        entities = [self._scene_entity(o, time_ns) for o in self.field.obstacles if everything or o.moving]
        if everything:
            entities.append(self._terrain_entity())
        if entities:
            self.recorder.write("/scene", time_ns=time_ns, message={"deletions": [], "entities": entities})

    def _record_pose(self, time_ns: int) -> None:
        s = self.vehicle.state
        position = enu(s.north_m, s.east_m, s.up_m)
        orientation = enu_flu_orientation(s.roll_rad, s.pitch_rad, s.yaw_rad)
        self.recorder.write(
            "/tf",
            time_ns=time_ns,
            message={"timestamp": stamp(time_ns), "parent_frame_id": "world", "child_frame_id": "uav", "translation": position, "rotation": orientation},
        )
        self.recorder.write("/uav/pose", time_ns=time_ns, message={"timestamp": stamp(time_ns), "frame_id": "world", "pose": {"position": position, "orientation": orientation}})
        self.recorder.write("/uav/fix", time_ns=time_ns, message={"timestamp": stamp(time_ns), "frame_id": "uav", "latitude": s.lat_deg, "longitude": s.lon_deg,
                                                               "altitude": s.alt_msl_m, "position_covariance_type": 0})
        self.recorder.write(
            "/uav/state",
            time_ns=time_ns,
            message={
                "t": time_ns / 1e9,
                "north_m": s.north_m,
                "east_m": s.east_m,
                "up_m": s.up_m,
                "v_ned_m_s": [s.v_north_m_s, s.v_east_m_s, s.v_down_m_s],
                "rpy_rad": [s.roll_rad, s.pitch_rad, s.yaw_rad],
                "motors": list(self._motors),
                "agl_m": s.agl_m,
            },
        )

    def _flush_clearance(self) -> None:
        """One /clearance message per batch of physics steps: every step's value, few MCAP records."""
        times, distances, obstacles, heights = self._clearance_batch
        if times:
            self.recorder.write("/clearance", time_ns=int(round(times[0] * 1e9)), message={"t": times, "d": distances, "o": obstacles, "g": heights})
            self._clearance_batch = ([], [], [], [])

    def _flush_link(self, time_ns: int) -> None:
        for direction, buffer in (("to_sut", self._link_out), ("from_sut", self._link_in)):
            if buffer:
                self.recorder.write("/mavlink/sim", time_ns=time_ns, message={"link": "sim", "direction": direction, "hex": buffer.hex()})
                buffer.clear()

    # -- messages ----------------------------------------------------------------------------

    def _sensor_frames(self, step: int, time_us: int) -> bytes:
        s = self.vehicle.state
        sensor = codec.encode_hil_sensor(
            seq=self._mav.seq, sysid=SYSTEM_ID, compid=COMPONENT_ID, time_usec=time_us, values=self.sensors.hil_sensor_values(s), fields_updated=FIELDS_ALL
        )
        self._mav.seq = (self._mav.seq + 1) & 0xFF
        every = self._every
        extra = []
        if step % every["gps"] == 0:
            g = self.sensors.hil_gps(s, self.vehicle.local_to_geodetic)
            extra.append(
                self._mav.hil_gps_encode(
                    time_us, g["fix_type"], g["lat"], g["lon"], g["alt"], g["eph"], g["epv"], g["vel"], g["vn"], g["ve"], g["vd"], g["cog"], g["satellites_visible"]
                )
            )
        if step % every["truth"] == 0:
            q = quaternion_from_euler(s.roll_rad, s.pitch_rad, s.yaw_rad)
            extra.append(
                self._mav.hil_state_quaternion_encode(
                    time_us,
                    q,
                    s.p_rad_s,
                    s.q_rad_s,
                    s.r_rad_s,
                    int(round(s.lat_deg * 1e7)),
                    int(round(s.lon_deg * 1e7)),
                    int(round(s.alt_msl_m * 1000)),
                    int(round(s.v_north_m_s * 100)),
                    int(round(s.v_east_m_s * 100)),
                    int(round(s.v_down_m_s * 100)),
                    0,
                    0,
                    int(round(s.ax_m_s2 / 9.80665 * 1000)),
                    int(round(s.ay_m_s2 / 9.80665 * 1000)),
                    int(round(s.az_m_s2 / 9.80665 * 1000)),
                )
            )
        if step % every["sensor"] == 0:
            extra.extend(self._obstacle_distance(time_us))
        if self.pilot is not None and step % every["rc"] == 0:
            extra.append(self._pilot_rc(time_us))
        if not extra:
            return sensor
        # HIL_SENSOR goes last: a SUT that steps on it has then seen this step's other messages,
        # however TCP splits the stream.
        return b"".join(bytes(m.pack(self._mav)) for m in extra) + sensor

    def _obstacle_distance(self, time_us: int):
        s = self.vehicle.state
        distances = [UINT16_MAX] * SECTORS
        reach_cm = int(self._range_m * 100)
        nearest = self.field.sector_distances(s.north_m, s.east_m, s.up_m, self._sector_angles + s.yaw_rad) - self._hull_offsets
        visible = np.flatnonzero(self._sector_visible)
        for index, distance in zip(visible.tolist(), nearest.tolist()):
            if distance <= self._range_m:
                distances[index] = max(int(self._min_range_m * 100), int(distance * 100))
            else:
                distances[index] = reach_cm + 1
        self.recorder.write("/sensor/obstacle_distance", time_ns=time_us * 1000, message={"t": time_us / 1e6, "range_m": self._range_m, "distances_cm": distances})
        min_cm = int(self._min_range_m * 100)
        messages = []
        if "OBSTACLE_DISTANCE" in self.config.range_messages:
            messages.append(self._mav.obstacle_distance_encode(
                time_us, mavlink.MAV_DISTANCE_SENSOR_LASER, distances, 0, min_cm, reach_cm, SECTOR_DEG, 0.0, mavlink.MAV_FRAME_BODY_FRD
            ))
        # The same reading as DISTANCE_SENSOR wedges: PX4's simulator link ignores OBSTACLE_DISTANCE
        # but turns DISTANCE_SENSOR into the distance_sensor topic its collision prevention reads.
        for sensor_id, (quaternion, fov_rad, sectors) in enumerate(self._wedges if "DISTANCE_SENSOR" in self.config.range_messages else ()):
            nearest_cm = min(min(distances[i] for i in sectors), reach_cm)
            messages.append(self._mav.distance_sensor_encode(
                time_us // 1000, min_cm, reach_cm, nearest_cm, mavlink.MAV_DISTANCE_SENSOR_LASER, sensor_id, mavlink.MAV_SENSOR_ROTATION_CUSTOM, 0,
                fov_rad, fov_rad, quaternion,
            ))
        return messages

    def _pilot_rc(self, time_us: int):
        pilot = self.pilot
        frame = pilot.update(time_us / 1e6, self.vehicle.state)
        if self._forced_slot is not None:
            frame = replace(frame, slot=self._forced_slot)
        slot = frame.slot
        channels = frame.channels()
        self.recorder.write("/pilot", time_ns=time_us * 1000, message={
            "t": time_us / 1e6, "phase": pilot.phase, "roll": frame.roll, "pitch": frame.pitch, "throttle": frame.throttle, "yaw": frame.yaw,
            "mode_slot": slot, "channels_us": channels, "aim_north_m": pilot.aim[0], "aim_east_m": pilot.aim[1], "remaining_m": pilot.remaining_m,
        })
        unused = [UINT16_MAX] * (18 - CHANNEL_COUNT)
        return self._mav.rc_channels_encode(time_us // 1000, CHANNEL_COUNT, *channels, *unused, 255)

    # -- obstacle injection ------------------------------------------------------------------

    def _apply_op(self, op: Mapping[str, Any], time_s: float) -> None:
        kind = op.get("op")
        record = {"op": kind, "t": time_s}
        if kind == "add_obstacle":
            obstacle = Obstacle.from_spec(op["obstacle"])
            obstacle.move_to(self._run_time(time_s))
            self.field.add(obstacle)
            record["id"] = obstacle.id
        elif kind == "move_obstacle":
            current = next((o for o in self.field.obstacles if o.id == op["id"]), None)
            if current is None:
                self._event(time_s, "injection_rejected", reason=f"no obstacle {op['id']!r}")
                return
            spec = {"id": current.id, "form": current.form, "size": current.size, "yaw_rad": op.get("yaw_rad", current.yaw_rad),
                    "a": op["a"], "b": op.get("b"), "speed_m_s": op.get("speed_m_s", 0.0)}
            obstacle = Obstacle.from_spec(spec)
            obstacle.move_to(self._run_time(time_s))
            self.field.add(obstacle)
            record["id"] = obstacle.id
        elif kind == "remove_obstacle":
            record["id"] = op["id"]
            if not self.field.remove(op["id"]):
                self._event(time_s, "injection_rejected", reason=f"no obstacle {op['id']!r}")
                return
            self.recorder.write("/scene", time_ns=int(time_s * 1e9), message={"deletions": [{"timestamp": stamp(int(time_s * 1e9)), "type": 1, "id": op["id"]}], "entities": []})
        else:
            self._event(time_s, "injection_rejected", reason=f"unknown op {kind!r}")
            return
        self.summary.injections.append(record)
        self._event(time_s, "injection", **record)
        self._record_scene(int(time_s * 1e9), everything=True)

    def _handle_ops(self, ops: list[dict[str, Any]], time_s: float) -> None:
        for op in ops:
            kind = op.get("op")
            if kind == "run":
                if self._run_start_s is None:
                    self._run_start_s = time_s
                    self._event(time_s, "run")
            elif kind == "stop":
                self.summary.end_reason = "stopped"
            elif kind == "rc_mode_slot":
                self._forced_slot = int(op["slot"])
            elif "at_s" in op:
                self._pending_ops.append(op)
                self._pending_ops.sort(key=lambda o: o["at_s"])
            else:
                self._apply_op(op, time_s)

    def _run_time(self, time_s: float) -> float:
        return 0.0 if self._run_start_s is None else time_s - self._run_start_s

    # -- end conditions ----------------------------------------------------------------------

    def _check_end(self, time_s: float) -> None:
        s = self.vehicle.state
        run_time = self._run_time(time_s)
        if s.agl_m > 1.0:
            self.summary.airborne = True
        speed = math.sqrt(s.v_north_m_s**2 + s.v_east_m_s**2 + s.v_down_m_s**2)
        if self.summary.airborne and s.on_ground:
            if self.summary.touchdown is None:
                self.summary.touchdown = {
                    "t": time_s,
                    "north_m": s.north_m,
                    "east_m": s.east_m,
                    "speed_m_s": speed,
                    "surface": "water" if is_water(self._water, s.north_m, s.east_m) else "land",
                }
                self._event(time_s, "touchdown", **self.summary.touchdown)
                if speed > CRASH_SPEED_M_S:
                    self.summary.end_reason = "crashed"
                    return
            if speed < 0.3 and max(self._motors) < 0.15:
                if self._landed_since is None:
                    self._landed_since = time_s
                elif time_s - self._landed_since >= LANDED_HOLD_S:
                    self.summary.end_reason = "landed"
                    return
            else:
                self._landed_since = None
        else:
            self._landed_since = None
            if not s.on_ground:
                self.summary.touchdown = None
        if self.pilot is not None and self.pilot.blocked:
            self.summary.end_reason = "blocked"
            self._event(time_s, "blocked", remaining_m=self.pilot.remaining_m, north_m=s.north_m, east_m=s.east_m)
            return
        if self._run_start_s is not None and run_time >= self.world["time_limit_s"]:
            self.summary.end_reason = "time_limit"

    # -- the loop ----------------------------------------------------------------------------

    def run(self, sut: socket.socket, control: ControlChannel) -> Summary:
        summary = self.summary
        config = self.config
        self._control = control
        splitter = codec.FrameSplitter(_CRC_EXTRAS)
        sut.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        codec.set_receive_timeout(sut, config.stall_timeout_s)
        wall_start = time.perf_counter()
        perf = time.perf_counter
        hold_after_s = config.hold_after_s
        hold_enabled = hold_after_s > 0
        if not hold_enabled:
            self._run_start_s = 0.0
        paced_hold = config.hold_mode == "paced"
        lockstep = False
        step = 0
        every = self._every
        self._record_scene(0, everything=True)
        self._event(0.0, "sut_connected")
        field_ = self.field
        vehicle = self.vehicle
        terrain = self._terrain
        wind_n, wind_e = self._wind
        wall_run_started = None
        spin_s = config.spin_s
        # The step just simulated is scored and recorded after the next sensor messages went out,
        # while the SUT computes its answer: on two cores this work costs the step nothing.
        unobserved_step: int | None = None
        while summary.end_reason == "running":
            time_us = step * self._dt_us
            time_s = time_us / 1e6
            holding = hold_enabled and self._run_start_s is None and time_s >= hold_after_s
            if holding and not paced_hold:
                self._hold(sut, splitter, control, time_s)
                if summary.end_reason != "running":
                    break
                holding = False
            elif holding:
                self._paced_hold(control, time_s)
                if summary.end_reason != "running":
                    break
            if wall_run_started is None and hold_enabled and self._run_start_s is not None:
                wall_run_started = perf()
                # Step timers count the run only: before it the loop runs at real-time pace.
                setup_timers = {name: getattr(summary, name) for name in STEP_TIMERS}
            ts = perf()
            frames_out = self._sensor_frames(step, time_us)
            t_send = perf()
            summary.sensors_s += t_send - ts
            try:
                sut.sendall(frames_out)
            except OSError:
                summary.end_reason = "sut_disconnected"
                break
            self._link_out += frames_out
            t_sent = perf()
            summary.send_s += t_sent - t_send
            if unobserved_step is not None:
                self._observe(unobserved_step)
                unobserved_step = None
            t0 = perf()
            summary.world_s += t0 - t_sent
            got_answer = False
            while not got_answer:
                if not lockstep:
                    readable, _, _ = select.select([sut], [], [], self._dt)
                    if not readable:
                        break
                try:
                    data = codec.receive(sut, spin_s if lockstep else 0.0)
                except BlockingIOError:
                    summary.end_reason = "sut_stalled"
                    break
                except OSError:
                    summary.end_reason = "sut_disconnected"
                    break
                if not data:
                    summary.end_reason = "sut_disconnected"
                    break
                self._link_in += data
                for msgid, payload, _frame in splitter.feed(data):
                    if msgid == codec.HIL_ACTUATOR_CONTROLS_ID:
                        _, _flags, controls, _mode = codec.decode_hil_actuator_controls(payload)
                        self._motors = controls[:4]
                        got_answer = True
                if not got_answer:
                    if not lockstep:
                        break  # before lockstep the step goes on at real-time pace, answered or not
                    if perf() - t0 > config.stall_timeout_s:
                        # Bytes keep coming but no answer among them: a flood stalls a step as silence does.
                        summary.end_reason = "sut_stalled"
                        break
                if not lockstep and got_answer:
                    lockstep = True
                    self._event(time_s, "lockstep_started", step=step)
            if summary.end_reason != "running":
                break
            t1 = perf()
            summary.wait_s += t1 - t0
            s = vehicle.state
            vehicle.step(self._motors if lockstep else (0.0, 0.0, 0.0, 0.0), terrain_height_m(terrain, s.north_m, s.east_m), wind_n, wind_e)
            t2 = perf()
            summary.physics_s += t2 - t1
            step += 1
            time_s = step * self._dt
            run_time = self._run_time(time_s)
            while self._pending_ops and self._pending_ops[0]["at_s"] <= run_time:
                self._apply_op(self._pending_ops.pop(0), time_s)
            field_.move_to(run_time)
            if step % every["control"] == 0:
                self._handle_ops(control.poll(), time_s)
            self._check_end(time_s)
            unobserved_step = step
            summary.world_s += perf() - t2
            if not lockstep or holding:
                time.sleep(max(0.0, self._dt - (perf() - t_sent)))
        if unobserved_step is not None:
            self._observe(unobserved_step)
        summary.steps = step
        summary.sim_time_s = step * self._dt
        summary.run_time_s = self._run_time(summary.sim_time_s)
        summary.bad_frames = splitter.bad_frames
        summary.skipped_bytes = splitter.skipped_bytes
        summary.wall_time_s = time.perf_counter() - wall_start
        if wall_run_started is not None:
            summary.wall_in_run_s = time.perf_counter() - wall_run_started
            for name, before in setup_timers.items():
                setattr(summary, name, getattr(summary, name) - before)
        self._flush_link(int(summary.sim_time_s * 1e9))
        self._flush_clearance()
        self._event(summary.sim_time_s, "finished", reason=summary.end_reason)
        return summary

    def _observe(self, step: int) -> None:
        """Score and record the state after `step` physics steps: the UAV's clearance to each
        obstacle, and at their rates its pose, the moving obstacles and the link traffic."""
        field_ = self.field
        s = self.vehicle.state
        every = self._every
        time_s = step * self._dt
        field_.place_body(s.north_m, s.east_m, s.up_m, s.roll_rad, s.pitch_rad, s.yaw_rad)
        clearances = field_.clearances()
        time_ns = int(round(time_s * 1e9))
        batch = self._clearance_batch
        batch[0].append(time_s)
        if clearances:
            nearest = min(range(len(clearances)), key=clearances.__getitem__)
            batch[1].append(clearances[nearest])
            batch[2].append(field_.obstacles[nearest].id)
        else:
            batch[1].append(None)
            batch[2].append(None)
        batch[3].append(s.agl_m)
        if step % every["record"] == 0:
            self._record_pose(time_ns)
        if step % every["scene"] == 0:
            self._record_scene(time_ns, everything=False)
        if step % every["flush"] == 0:
            self._flush_link(time_ns)
            self._flush_clearance()

    def _paced_hold(self, control: ControlChannel, time_s: float) -> None:
        """One step of a paced hold: announce it once the harness listens, give up after the timeout."""
        if self._hold_deadline is None:
            self._event(time_s, "holding")
            self._hold_deadline = time.monotonic() + self.config.hold_timeout_s
        if not self._hold_announced and control.connected:
            control.send({"event": "holding", "t": time_s})
            self._hold_announced = True
        if time.monotonic() > self._hold_deadline:
            self.summary.end_reason = "hold_timeout"

    def _hold(self, sut: socket.socket, splitter: codec.FrameSplitter, control: ControlChannel, time_s: float) -> None:
        """Pause the simulation until the harness says run; keep reading what the SUT sends."""
        self._event(time_s, "holding")
        announced = False
        deadline = time.monotonic() + self.config.hold_timeout_s
        while self._run_start_s is None and self.summary.end_reason == "running":
            if not announced and control.connected:
                control.send({"event": "holding", "t": time_s})
                announced = True
            if time.monotonic() > deadline:
                self.summary.end_reason = "hold_timeout"
                return
            readable, _, _ = select.select([sut], [], [], 0.0)
            if readable:
                data = sut.recv(65536)
                if not data:
                    self.summary.end_reason = "sut_disconnected"
                    return
                self._link_in += data
                splitter.feed(data)
            self._handle_ops(control.poll(0.01), time_s)


WEDGE_SECTORS = 4


def _wedges(visible: list[int]) -> list[tuple[list[float], float, list[int]]]:
    """Visible sectors grouped WEDGE_SECTORS at a time from left to right: (body-yaw quaternion
    w, x, y, z of the wedge's centre, its width in radians, its sector indices)."""
    signed = sorted(visible, key=lambda i: ((i * SECTOR_DEG + 180.0) % 360.0) - 180.0)
    wedges = []
    for start in range(0, len(signed), WEDGE_SECTORS):
        sectors = signed[start : start + WEDGE_SECTORS]
        angles = [math.radians(((i * SECTOR_DEG + 180.0) % 360.0) - 180.0) for i in sectors]
        centre = (angles[0] + angles[-1]) / 2.0
        width = angles[-1] - angles[0] + math.radians(SECTOR_DEG)
        wedges.append(([math.cos(centre / 2.0), 0.0, 0.0, math.sin(centre / 2.0)], width, sectors))
    return wedges
