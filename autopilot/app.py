"""The autopilot process: the simulator link in lockstep, the flight stack per sensor step, the API link."""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import socket
import time

from pymavlink.dialects.v20 import common as mavlink

from autopilot.api import ApiLink
from autopilot.collision import STALE_HOLD_S, ObstacleMap, constrain_velocity, px4_stick_acceleration
from autopilot.commander import MAIN_AUTO, SUB_AUTO_LOITER, Commander, MissionItem, VehicleEstimate
from autopilot.control import (
    PositionControl,
    Setpoint,
    RateControl,
    attitude_from_thrust,
    attitude_rate_setpoint,
    euler_from_quat,
    mix,
)
from autopilot.estimator import Estimator, GpsFix
from autopilot.manual import PositionMode, altitude_mode_thrust, sticks_from_rc
from autopilot.params import Params
from simlink import codec, shared_memory
from simlink.failures import (
    Failure,
    FailureType,
    FailureUnit,
    wrong_accel,
    wrong_baro_altitude,
    wrong_distances,
    wrong_gps_position,
    wrong_gyro,
    wrong_mag,
)

log = logging.getLogger(__name__)

IDLE_THROTTLE = 0.05  # armed on the ground, motors spin as PX4's do
LOCKSTEP_FLAG = 1
_CRC_EXTRAS = {msgid: cls.crc_extra for msgid, cls in mavlink.mavlink_map.items()}
SIM_LOSS_EXIT_S = 10.0
TELEMETRY_CHECK_S = 0.005
# HIL_ACTUATOR_CONTROLS carries 16 controls; a quadrotor uses the first four.
_UNUSED_CONTROLS = (0.0,) * 12
FRAMES_WITH_POSITION = {
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
    mavlink.MAV_FRAME_GLOBAL,
    mavlink.MAV_FRAME_GLOBAL_INT,
}


# The simulator's messages the autopilot reads besides HIL_SENSOR, by message id.
_SIM_MESSAGES = {message.msgid: message for message in (codec.HIL_GPS, codec.HIL_STATE_QUATERNION, codec.OBSTACLE_DISTANCE, codec.DISTANCE_SENSOR, codec.RC_CHANNELS)}
# DISTANCE_SENSOR orientations (MAV_SENSOR_ORIENTATION) that face along the horizon, as yaw in
# the body; the custom one takes the message's quaternion. PX4 leaves out the upward and
# downward ones, and so does the autopilot.
_SENSOR_YAW_DEG = {orientation: 45.0 * orientation for orientation in range(8)}
_SENSOR_ROTATION_CUSTOM = 100
_NORTH_FRAMES = (mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_LOCAL_NED)


class Autopilot:
    def __init__(self, params: Params):
        self.params = params
        self.estimator = Estimator(math.radians(params["EKF2_MAG_DECL"]))
        self.commander = Commander(params)
        self.position_control = PositionControl(params)
        self.rate_control = RateControl(params)
        self.obstacles = ObstacleMap(params.fault)
        self.position_mode = PositionMode(params)
        self._manual_active = False
        self._position_mode_since_s = 0.0
        self.now_s = 0.0
        self.collective = 0.0
        self.lift = 0.0
        self.sensors_seen = False
        self._last_time_us: int | None = None
        self._ground_truth = None
        self._controlling = False
        self.api: ApiLink | None = None
        self._seq = 0
        # Injected failures (MAV_CMD_INJECT_FAILURE) by unit, applied to the simulator's data as it
        # comes in; empty, as almost always, they cost a step one truth test. The last raw
        # readings are kept (one reference each) for the onset of a stuck or slow failure.
        self.failures: dict[FailureUnit, Failure] = {}
        self._last_sensor_values: tuple | None = None
        self._last_gps_fix: GpsFix | None = None
        self._last_obstacle_reading: tuple | None = None
        self._wanted_sim_messages = {codec.HIL_GPS.msgid, codec.OBSTACLE_DISTANCE.msgid, codec.DISTANCE_SENSOR.msgid, codec.RC_CHANNELS.msgid}
        if params["EKF2_GT_MODE"]:
            self._wanted_sim_messages.add(codec.HIL_STATE_QUATERNION.msgid)

    # -- state helpers used by the API --------------------------------------------------------

    def euler(self) -> tuple[float, float, float]:
        return euler_from_quat(self.estimator.q)

    def yaw_rad(self) -> float:
        return self.euler()[2]

    def vehicle_estimate(self) -> VehicleEstimate:
        pos, vel = self.estimator.pos, self.estimator.vel
        return VehicleEstimate(pos[0], pos[1], pos[2], vel[0], vel[1], vel[2], self.yaw_rad())

    def ready_to_arm(self) -> tuple[bool, str]:
        if not self.sensors_seen:
            return False, "no sensor data"
        if not self.estimator.healthy(self.now_s):
            return False, "position estimate not ready"
        if self.commander.home is None:
            return False, "no home position"
        return True, ""

    def home_geodetic(self) -> tuple[float, float, float] | None:
        home = self.commander.home
        if home is None or self.estimator.origin is None:
            return None
        lat, lon = self.estimator.geodetic_from_local(home[0], home[1])
        return lat, lon, self.estimator.origin[2] - home[2]

    def on_armed(self) -> None:
        pos = self.estimator.pos
        self.commander.home = (pos[0], pos[1], pos[2])

    def mission_item_from_global(self, seq: int, command: int, frame: int, lat: float, lon: float, z: float, params) -> MissionItem | None:
        if self.estimator.origin is None:
            return None
        has_position = frame in FRAMES_WITH_POSITION and command in (mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_LAND, mavlink.MAV_CMD_NAV_TAKEOFF) and (lat != 0.0 or lon != 0.0)
        if has_position:
            north, east = self.estimator.local_from_geodetic(lat, lon)
        else:
            north = east = 0.0
        if frame in (mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT):
            home = self.home_geodetic()
            z = z - (home[2] if home else self.estimator.origin[2])
        if command not in (mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_LAND, mavlink.MAV_CMD_NAV_TAKEOFF, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, mavlink.MAV_CMD_DO_CHANGE_SPEED, mavlink.MAV_CMD_NAV_DELAY):
            log.info("mission item %d: command %d will be skipped", seq, command)
        return MissionItem(seq, command, north, east, z, *params, has_position=has_position)

    # -- failure injection ---------------------------------------------------------------------

    def inject_failure(self, unit: FailureUnit, kind: FailureType) -> None:
        """An accepted MAV_CMD_INJECT_FAILURE: from now (the onset, this simulation time) on, the
        unit's readings reach the flight stack as simlink.failures defines; FailureType.OK
        clears the unit's failure. A new failure of a unit replaces its old one."""
        if kind == FailureType.OK:
            self.failures.pop(unit, None)
            return
        self.failures[unit] = Failure(kind, onset_s=self.now_s, last_reading=self._last_reading(unit), wrong=_WRONG[unit])

    def _last_reading(self, unit: FailureUnit):
        if unit == FailureUnit.SENSOR_GPS:
            return self._last_gps_fix
        if unit == FailureUnit.SENSOR_DISTANCE_SENSOR:
            return self._last_obstacle_reading
        values = self._last_sensor_values
        return None if values is None else _sensor_reading(unit, values)

    def _delivered(self, unit: FailureUnit, reading):
        """The reading as the unit's failure, if any, leaves it; None: nothing is delivered."""
        failure = self.failures.get(unit)
        return reading if failure is None else failure.apply(self.now_s, reading)

    def _estimate_with_failures(self, dt: float, values: tuple) -> None:
        """The estimator's sensor step while a failure is active; a unit without a delivered
        reading gives the estimator no new information, as a real estimator has none:
        * gyro: no IMU step at all. A strapdown estimator predicts with the gyro's rotation
          (PX4's EKF2 with the IMU's delta angles); without it the attitude cannot follow the
          vehicle, and accelerometer readings cannot be turned into north-east-down without it.
          Attitude, rates and the inertial prediction stay as they were, GPS and barometer still
          correct position and velocity, and the estimate turns unhealthy after
          SENSOR_TIMEOUT_S, as an estimator whose IMU stopped does.
        * accelerometer: no gravity reference for roll and pitch, and a constant-velocity
          prediction between GPS and barometer corrections (Estimator.update_imu, accel None).
        * magnetometer: the heading follows the gyro alone (update_imu, mag None).
        * barometer: no barometer update; height follows the inertial prediction, and its
          vertical velocity the GPS's.
        With EKF2_GT_MODE=1 the simulator's truth stands in for the IMU and the barometer, and
        their failures do not act (GPS and distance sensor failures still do)."""
        est = self.estimator
        gyro, accel, mag, pressure_alt = (self._delivered(unit, _sensor_reading(unit, values)) for unit in
                                          (FailureUnit.SENSOR_GYRO, FailureUnit.SENSOR_ACCEL, FailureUnit.SENSOR_MAG, FailureUnit.SENSOR_BARO))
        if gyro is not None:
            est.update_imu(self.now_s, dt, gyro, accel, mag)
        if pressure_alt is not None:
            est.update_baro(dt, pressure_alt + self._baro_drift_m(values[12]))

    # -- the flight stack, once per HIL_SENSOR --------------------------------------------------

    def _handle_sim_message(self, msgid: int, payload: bytes) -> None:
        kind = _SIM_MESSAGES[msgid]
        message = kind.decode(payload)
        if kind is codec.HIL_GPS:
            fix = GpsFix(message.lat * 1e-7, message.lon * 1e-7, message.alt / 1000.0, message.vn / 100.0, message.ve / 100.0, message.vd / 100.0, message.fix_type, message.satellites_visible)
            self._last_gps_fix = fix
            if self.failures:
                fix = self._delivered(FailureUnit.SENSOR_GPS, fix)
                if fix is None:
                    return
            if not self.params["EKF2_GT_MODE"]:
                self.estimator.update_gps(self.now_s, 0.1, fix)
            else:
                self.estimator.last_gps = fix
                self.estimator.last_gps_s = self.now_s
        elif kind is codec.HIL_STATE_QUATERNION:
            self._ground_truth = message
        elif kind is codec.OBSTACLE_DISTANCE:
            increment = message.increment_f if message.increment_f > 0 else float(message.increment)
            reading = (list(message.distances), increment, message.angle_offset, message.min_distance, message.max_distance)
            self._last_obstacle_reading = reading
            if self.failures:
                reading = self._delivered(FailureUnit.SENSOR_DISTANCE_SENSOR, reading)
                if reading is None:
                    return
            distances, increment, angle_offset, min_cm, max_cm = reading
            # Sectors from north (MAV_FRAME_LOCAL_NED, or GLOBAL as PX4 takes it too) or from the nose.
            heading = 0.0 if message.frame in _NORTH_FRAMES else self.yaw_rad()
            self.obstacles.update(self.now_s, heading, distances, increment, angle_offset, min_cm, max_cm)
        elif kind is codec.DISTANCE_SENSOR:
            self._distance_sensor(message)
        elif kind is codec.RC_CHANNELS and self.params["COM_RC_IN_MODE"] in (0, 2, 3):
            raw = [getattr(message, f"chan{n}_raw") for n in range(1, 9)]
            sticks = sticks_from_rc(self.params, self.now_s, message.chancount, raw)
            if sticks is not None:
                self.commander.on_sticks(sticks, self.vehicle_estimate())

    def _distance_sensor(self, message) -> None:
        """One DISTANCE_SENSOR reading into the obstacle map, where it faces along the horizon."""
        if message.orientation == _SENSOR_ROTATION_CUSTOM:
            w, x, y, z = message.quaternion
            sensor_yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
        elif message.orientation in _SENSOR_YAW_DEG:
            sensor_yaw = math.radians(_SENSOR_YAW_DEG[message.orientation])
        else:
            return
        roll, pitch, yaw = self.euler()
        # The vertical part of the sensor's direction in the world (ZYX Euler angles), which PX4's
        # project_distance_on_horizontal_plane takes off a reading.
        vertical = -math.sin(pitch) * math.cos(sensor_yaw) + math.sin(roll) * math.cos(pitch) * math.sin(sensor_yaw)
        self.obstacles.update_distance_sensor(self.now_s, yaw, message.id, message.current_distance / 100.0, message.min_distance / 100.0,
                                              message.max_distance / 100.0, sensor_yaw, message.horizontal_fov,
                                              max(math.sqrt(max(0.0, 1.0 - vertical * vertical)), 1e-7))

    def _stick_collision_prevention(self, accel_ne: tuple, velocity_ne: tuple) -> tuple:
        return px4_stick_acceleration(self.params, self.obstacles, self.now_s, accel_ne, velocity_ne)

    def _hold_without_range_data(self, estimate: VehicleEstimate) -> None:
        """PX4's collision prevention in Position mode: once range data has been stale for
        STALE_HOLD_S (TIMEOUT_HOLD_US), with the module active that long, it switches to Hold."""
        now_s = self.now_s
        if not self._manual_active:
            self._position_mode_since_s = now_s
        if (self.params["CP_DIST"] >= 0.0 and now_s - self.obstacles.updated_s > STALE_HOLD_S and now_s - self._position_mode_since_s > STALE_HOLD_S
                and self.commander.set_mode((MAIN_AUTO, SUB_AUTO_LOITER), estimate, now_s)):
            self.commander.events.append(("statustext", "No obstacle data, switching to Hold"))

    @property
    def _dead_reckoning_s(self) -> float:
        """EKF2_NOAID_TOUT in seconds; the seeded fault noaid_timeout_ms reads its microseconds as milliseconds."""
        return self.params["EKF2_NOAID_TOUT"] * (1e-3 if self.params.fault == "noaid_timeout_ms" else 1e-6)

    def _baro_drift_m(self, temperature_c: float) -> float:
        """Seeded fault baro_temperature_drift: an uncompensated sensor reads high as it warms up
        after power-on, by 0.4 m per degC above 15 degC over its first minute."""
        if self.params.fault != "baro_temperature_drift":
            return 0.0
        return 0.4 * max(0.0, temperature_c - 15.0) * min(1.0, self.now_s / 60.0)

    def step(self, time_us: int, values: tuple) -> tuple[float, float, float, float]:
        dt = 0.004 if self._last_time_us is None else max(1e-4, (time_us - self._last_time_us) / 1e6)
        self._last_time_us = time_us
        self.now_s = time_us / 1e6
        self.sensors_seen = True
        est = self.estimator
        if self.params["EKF2_GT_MODE"] and self._ground_truth is not None:
            gt = self._ground_truth
            est.set_ground_truth(tuple(gt.attitude_quaternion), (gt.rollspeed, gt.pitchspeed, gt.yawspeed), gt.lat * 1e-7, gt.lon * 1e-7, gt.alt / 1000.0,
                                 (gt.vx / 100.0, gt.vy / 100.0, gt.vz / 100.0), (values[0], values[1], values[2]))
            est.last_imu_s = self.now_s
        elif self.failures:
            self._estimate_with_failures(dt, values)
        else:
            est.update_imu(self.now_s, dt, (values[3], values[4], values[5]), (values[0], values[1], values[2]), (values[6], values[7], values[8]))
            est.update_baro(dt, values[11] + self._baro_drift_m(values[12]))
        self._last_sensor_values = values
        commander = self.commander
        if commander.home is None and est.position_ready and not commander.armed:
            commander.home = (est.pos[0], est.pos[1], est.pos[2])
        if not est.position_ready:
            return (0.0, 0.0, 0.0, 0.0)
        estimate = self.vehicle_estimate()
        sp = commander.update(self.now_s, estimate, self.lift, est.position_valid(self.now_s, self._dead_reckoning_s))
        if sp.idle:
            self._controlling = self._manual_active = False
            self.collective = self.lift = 0.0
            return (IDLE_THROTTLE,) * 4 if commander.armed else (0.0, 0.0, 0.0, 0.0)
        if not self._controlling:
            self.position_control.reset()
            self.rate_control.reset()
            self._controlling = True
        params = self.params
        manual = sp.manual
        positioned = not (sp.level or sp.tilt_from_sticks)
        if sp.tilt_from_sticks:
            horizontal = altitude_mode_thrust(params, commander.manual, estimate.yaw_rad)
        else:
            horizontal = (0.0, 0.0)
        # PX4 since v1.15 (CP_STICK_ACCEL): collision prevention reshapes the sticks' acceleration
        # in Position mode, instead of limiting the velocity setpoint.
        stick_cp = manual and positioned and not commander.landed and params["CP_STICK_ACCEL"] > 0 and params["CP_DIST"] >= 0.0
        if manual:
            if not self._manual_active:
                self.position_mode.reset(est.vel[0], est.vel[1], est.pos, estimate.yaw_rad)
            north, east, down, vn, ve, vd, yaw = self.position_mode.update(dt, commander.manual, est.pos, estimate.yaw_rad,
                                                                           self._stick_collision_prevention if stick_cp else None)
            sp = Setpoint(north_m=north, east_m=east, down_m=down, v_north_m_s=vn, v_east_m_s=ve, v_down_m_s=vd, yaw_rad=yaw)
            if positioned:
                self._hold_without_range_data(estimate)
        self._manual_active = manual
        vel_sp = self.position_control.velocity_setpoint(sp, est.pos, params["MPC_XY_VEL_MAX"])
        if not commander.landed and positioned and not stick_cp:
            vn, ve = constrain_velocity(params, self.obstacles, self.now_s, (vel_sp[0], vel_sp[1]), (est.vel[0], est.vel[1]))
            vel_sp = (vn, ve, vel_sp[2])
            if manual and self.position_mode.hold_ne is None:
                self.position_mode.constrained(vn, ve)
        thrust = self.position_control.thrust(dt, vel_sp, est.vel, est.acc_ned)
        if not positioned:
            thrust = (horizontal[0], horizontal[1], thrust[2])
            self.position_control.hold_level()
        self.lift = -thrust[2]
        yaw_sp = sp.yaw_rad if sp.yaw_rad is not None else estimate.yaw_rad
        q_sp, collective = attitude_from_thrust(thrust, yaw_sp)
        self.collective = collective
        rates_sp = attitude_rate_setpoint(params, est.q, q_sp)
        torque = self.rate_control.update(dt, est.rates, rates_sp, commander.landed)
        return mix(collective, torque, IDLE_THROTTLE)

    # -- the process loop -----------------------------------------------------------------------

    def serve(self, sim_address: tuple[str, int] | str, api_address: tuple[str, int], connect_timeout_s: float, spin_s: float = 0.0,
              over_shared_memory: bool = False) -> int:
        """sim_address: (host, port) over TCP, or a Unix-domain socket's path; over_shared_memory:
        the simulator hands over shared memory on that socket for the link's bytes
        (simlink/shared_memory.py)."""
        sim = _connect(sim_address, connect_timeout_s)
        if over_shared_memory:
            try:
                sim = shared_memory.accept(sim, TELEMETRY_CHECK_S, connect_timeout_s)
            except OSError:
                sim.close()
                raise
            receive = sim.receive
        else:
            codec.send_at_once(sim)
            codec.set_receive_timeout(sim, TELEMETRY_CHECK_S)
            receive = functools.partial(codec.receive, sim)
        self.api = api = ApiLink(self, api_address)
        splitter = codec.FrameSplitter(_CRC_EXTRAS)
        perf = time.perf_counter
        next_check = 0.0
        sim_lost_at: float | None = None
        sim_silent = False
        # Blocking reads on the simulator link (it drives the clock), polled for spin_s first when
        # the simulator has a core of its own; the API link is served between steps at most
        # every TELEMETRY_CHECK_S of wall time, and whenever the simulator is silent. Once it has
        # been silent that long (a frozen hold), the wait also ends when the API link has
        # something, so that the harness's set-up is answered at once; in lockstep that second
        # socket would cost every step a select().
        try:
            while True:
                data = None
                if sim_lost_at is None:
                    try:
                        if sim_silent:  # no spin: on a silent simulator it would only delay the API's answer
                            data = receive(also=api.sock, wait_s=TELEMETRY_CHECK_S)
                        else:
                            data = receive(spin_s)
                    except BlockingIOError:
                        sim_silent = True
                        next_check = 0.0
                    else:
                        sim_silent = False
                        if data:
                            self._on_sim_data(sim, splitter, data)
                        else:
                            sim_lost_at = perf()
                            api.statustext("Simulator link lost: stopping", mavlink.MAV_SEVERITY_CRITICAL)
                else:
                    time.sleep(TELEMETRY_CHECK_S)
                wall = perf()
                if wall >= next_check:
                    api.receive()
                    api.check_link(self.params["COM_DL_LOSS_T"])  # before the events: its failsafe's are reported at once
                    api.report_events()
                    api.telemetry(wall)
                    next_check = wall + TELEMETRY_CHECK_S
                if sim_lost_at is not None and wall - sim_lost_at > SIM_LOSS_EXIT_S:
                    return 0
        finally:
            sim.close()
            api.sock.close()

    def _on_sim_data(self, sim: socket.socket, splitter: codec.FrameSplitter, data: bytes) -> None:
        for msgid, payload, _frame in splitter.feed(data):
            if msgid == codec.HIL_SENSOR_ID:
                fields = codec.decode_hil_sensor(payload)
                motors = self.step(fields[0], fields[1:14])
                controls = (*motors, *_UNUSED_CONTROLS)
                mode = mavlink.MAV_MODE_FLAG_SAFETY_ARMED if self.commander.armed else 0
                sim.sendall(
                    codec.encode_hil_actuator_controls(seq=self._seq, sysid=1, compid=1, time_usec=fields[0], controls=controls, mode=mode, flags=LOCKSTEP_FLAG)
                )
                self._seq = (self._seq + 1) & 0xFF
            elif msgid in self._wanted_sim_messages:
                self._handle_sim_message(msgid, payload)


def _sensor_reading(unit: FailureUnit, values: tuple):
    """A HIL_SENSOR unit's reading from values (time_usec left out, as Autopilot.step takes them):
    accelerometer 0:3, gyro 3:6, magnetometer 6:9, pressure altitude 11."""
    if unit == FailureUnit.SENSOR_ACCEL:
        return (values[0], values[1], values[2])
    if unit == FailureUnit.SENSOR_GYRO:
        return (values[3], values[4], values[5])
    if unit == FailureUnit.SENSOR_MAG:
        return (values[6], values[7], values[8])
    return values[11]


def _wrong_fix(fix: GpsFix) -> GpsFix:
    lat_deg, lon_deg = wrong_gps_position(fix.lat_deg, fix.lon_deg)
    return dataclasses.replace(fix, lat_deg=lat_deg, lon_deg=lon_deg)


def _wrong_obstacle_reading(reading: tuple) -> tuple:
    distances, increment, angle_offset, min_cm, max_cm = reading
    return (wrong_distances(distances, max_distance_cm=max_cm), increment, angle_offset, min_cm, max_cm)


# Each unit's wrong reading (simlink.failures) in the form the autopilot takes it in.
_WRONG = {
    FailureUnit.SENSOR_GYRO: wrong_gyro,
    FailureUnit.SENSOR_ACCEL: wrong_accel,
    FailureUnit.SENSOR_MAG: wrong_mag,
    FailureUnit.SENSOR_BARO: wrong_baro_altitude,
    FailureUnit.SENSOR_GPS: _wrong_fix,
    FailureUnit.SENSOR_DISTANCE_SENSOR: _wrong_obstacle_reading,
}


def _connect(address: tuple[str, int] | str, timeout_s: float) -> socket.socket:
    """Connect to the simulator as PX4 does: keep retrying until it accepts."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            if isinstance(address, str):
                sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
                sock.settimeout(2.0)
                try:
                    sock.connect(address)
                except OSError:
                    sock.close()
                    raise
                return sock
            return socket.create_connection(address, timeout=2.0)
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)
