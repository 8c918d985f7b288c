"""The API link's telemetry: PX4's heartbeat and custom modes and the streams MAVSDK subscribes
to, each at its wall-clock period (a client may change it: MAV_CMD_SET_MESSAGE_INTERVAL). At
40x real time, simulated-time rates would flood the client with thousands of messages a second.
"""

from __future__ import annotations

import math
import time
from typing import Any, Protocol

from pymavlink.dialects.v20 import common as mavlink

from autopilot.commander import MAIN_AUTO, SUB_AUTO_LAND

SENSORS = (
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mavlink.MAV_SYS_STATUS_SENSOR_GPS
)
CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
)
FLIGHT_SW_VERSION = (1 << 24) | (15 << 16) | (0 << 8) | 255  # reported as 1.15.0 release
FORCE_DISARM_MAGIC = 21196
# Wall-clock periods of the telemetry streams, seconds.
STREAMS = {
    "heartbeat": 1.0,
    "sys_status": 0.1,  # the health a client checks before arming: it should not wait for it
    "extended_sys_state": 0.5,
    "attitude": 0.1,
    "position": 0.1,
    "gps_raw": 0.2,
    "home": 1.0,
    "battery": 1.0,
    "vfr_hud": 0.2,
    "altitude": 0.2,
    "mission_current": 1.0,
}
MESSAGE_STREAMS = {
    mavlink.MAVLINK_MSG_ID_ATTITUDE: "attitude",
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: "attitude",
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: "position",
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: "position",
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: "gps_raw",
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: "home",
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: "battery",
    mavlink.MAVLINK_MSG_ID_VFR_HUD: "vfr_hud",
    mavlink.MAVLINK_MSG_ID_ALTITUDE: "altitude",
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: "extended_sys_state",
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: "sys_status",
}
MIN_STREAM_PERIOD_S = 0.02


class Link(Protocol):
    """What the telemetry and the microservices send through (autopilot.api.ApiLink): looked up
    at each message, so that what replaces the link's send (a test keeping what is sent) counts."""

    ap: Any  # the autopilot (autopilot.api.Vehicle)
    mav: mavlink.MAVLink
    streams: "Telemetry"

    def send(self, message) -> None: ...

    def statustext(self, text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> None: ...


class Telemetry:
    """The streams of one API link, sent through it (link.send), of what its autopilot knows."""

    def __init__(self, link: Link):
        self.link = link
        self.ap = link.ap
        self.mav = link.mav
        self.periods = dict(STREAMS)
        self._next = {name: 0.0 for name in STREAMS}
        self._reported_health = -1
        self._home_reported = False
        self._system_time_due_s = 0.0

    def _send(self, message) -> None:
        self.link.send(message)

    def _time_boot_ms(self) -> int:
        return int(self.ap.now_s * 1000) & 0xFFFFFFFF

    def system_time(self) -> None:
        """The flight's clock: sent before what carries none (a heartbeat, a status text), and at
        least once per simulated second. A recorder stamps a frame with the latest time_boot_ms it
        heard, and a ground station paced by that clock (the harness's API tap) sends its
        heartbeat by it, while the streams that carry one are paced by the wall clock: a tenth of
        a second, two or more simulated seconds at 20 times real time."""
        self._send(self.mav.system_time_encode(int(time.time() * 1e6), self._time_boot_ms()))
        self._system_time_due_s = self.ap.now_s + 1.0

    def heartbeat(self) -> None:
        self.system_time()
        c = self.ap.commander
        main, sub = c.reported_mode
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED | mavlink.MAV_MODE_FLAG_AUTO_ENABLED
        if c.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        state = mavlink.MAV_STATE_ACTIVE if c.armed else mavlink.MAV_STATE_STANDBY
        self._send(self.mav.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base, (sub << 24) | (main << 16), state))

    def _health_bits(self) -> int:
        ap = self.ap
        health = 0
        if ap.sensors_seen:
            health |= SENSORS & ~mavlink.MAV_SYS_STATUS_SENSOR_GPS
        if ap.estimator.healthy(ap.now_s):
            health |= mavlink.MAV_SYS_STATUS_SENSOR_GPS
        ready, _ = ap.ready_to_arm()
        if ready or ap.commander.armed:
            health |= mavlink.MAV_SYS_STATUS_PREARM_CHECK
        return health

    def _sys_status(self) -> None:
        health = self._health_bits()
        self._reported_health = health
        present = SENSORS | mavlink.MAV_SYS_STATUS_PREARM_CHECK
        self._send(self.mav.sys_status_encode(present, present, health, 200, 16000, 500, 90, 0, 0, 0, 0, 0, 0))

    def _position(self) -> None:
        ap, est = self.ap, self.ap.estimator
        if not est.position_ready:
            return
        n, e, d = est.pos
        vn, ve, vd = est.vel
        lat, lon = est.geodetic_from_local(n, e)
        home_d = ap.commander.home[2] if ap.commander.home else 0.0
        yaw = ap.yaw_rad()
        heading = int(math.degrees(yaw) % 360.0 * 100)
        t = self._time_boot_ms()
        self._send(self.mav.global_position_int_encode(t, int(lat * 1e7), int(lon * 1e7), int(est.altitude_msl() * 1000), int((home_d - d) * 1000), int(vn * 100), int(ve * 100), int(vd * 100), heading))
        self._send(self.mav.local_position_ned_encode(t, n, e, d, vn, ve, vd))

    def _attitude(self) -> None:
        est = self.ap.estimator
        roll, pitch, yaw = self.ap.euler()
        t = self._time_boot_ms()
        self._send(self.mav.attitude_encode(t, roll, pitch, yaw, *est.rates))
        self._send(self.mav.attitude_quaternion_encode(t, *est.q, *est.rates, [0.0, 0.0, 0.0, 0.0]))

    def _gps_raw(self) -> None:
        fix = self.ap.estimator.last_gps
        if fix is None:
            return
        course = int(math.degrees(math.atan2(fix.v_east_m_s, fix.v_north_m_s)) % 360.0 * 100)
        speed = int(math.hypot(fix.v_north_m_s, fix.v_east_m_s) * 100)
        self._send(self.mav.gps_raw_int_encode(int(self.ap.now_s * 1e6), fix.fix_type, int(fix.lat_deg * 1e7), int(fix.lon_deg * 1e7), int(fix.alt_m * 1000), 30, 40, speed, course, fix.satellites))

    def _home(self) -> None:
        home = self.ap.home_geodetic()
        if home is None:
            return
        lat, lon, alt = home
        n, e, d = self.ap.commander.home
        self._send(self.mav.home_position_encode(int(lat * 1e7), int(lon * 1e7), int(alt * 1000), n, e, d, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int(self.ap.now_s * 1e6)))

    def extended_sys_state(self) -> None:
        c = self.ap.commander
        if not c.armed or c.landed:
            landed = mavlink.MAV_LANDED_STATE_ON_GROUND
        elif c.reported_mode == (MAIN_AUTO, SUB_AUTO_LAND):
            landed = mavlink.MAV_LANDED_STATE_LANDING
        else:
            landed = mavlink.MAV_LANDED_STATE_IN_AIR
        self._send(self.mav.extended_sys_state_encode(mavlink.MAV_VTOL_STATE_UNDEFINED, landed))

    def _battery(self) -> None:
        voltages = [4000, 4000, 4000, 4000] + [65535] * 6
        self._send(self.mav.battery_status_encode(0, mavlink.MAV_BATTERY_FUNCTION_ALL, mavlink.MAV_BATTERY_TYPE_LIPO, 2500, voltages, 500, -1, -1, 90))

    def _vfr_hud(self) -> None:
        est = self.ap.estimator
        speed = math.hypot(est.vel[0], est.vel[1])
        heading = int(math.degrees(self.ap.yaw_rad()) % 360.0)
        self._send(self.mav.vfr_hud_encode(speed, speed, heading, int(self.ap.collective * 100), est.altitude_msl(), -est.vel[2]))

    def _altitude(self) -> None:
        est, c = self.ap.estimator, self.ap.commander
        relative = (c.home[2] if c.home else 0.0) - est.pos[2]
        amsl = est.altitude_msl()
        self._send(self.mav.altitude_encode(int(self.ap.now_s * 1e6), amsl, amsl, -est.pos[2], relative, relative, float("nan")))

    def mission_current(self) -> None:
        c = self.ap.commander
        state = mavlink.MISSION_STATE_COMPLETE if c.mission_finished else (mavlink.MISSION_STATE_ACTIVE if c.mission else mavlink.MISSION_STATE_NO_MISSION)
        self._send(self.mav.mission_current_encode(c.current, len(c.mission), state))

    def autopilot_version(self) -> None:
        self._send(self.mav.autopilot_version_encode(CAPABILITIES, FLIGHT_SW_VERSION, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 1, [0] * 18))

    def stream(self, name: str) -> None:
        {
            "heartbeat": self.heartbeat,
            "sys_status": self._sys_status,
            "extended_sys_state": self.extended_sys_state,
            "attitude": self._attitude,
            "position": self._position,
            "gps_raw": self._gps_raw,
            "home": self._home,
            "battery": self._battery,
            "vfr_hud": self._vfr_hud,
            "altitude": self._altitude,
            "mission_current": self.mission_current,
        }[name]()

    def send_due(self, wall_s: float) -> None:
        """Every stream whose period has passed at wall-clock time wall_s."""
        # Health and home go out as soon as they change: a client waiting to arm should not wait
        # for the next periodic message.
        if self._health_bits() != self._reported_health:
            self._next["sys_status"] = 0.0
        if not self._home_reported and self.ap.home_geodetic() is not None:
            self._home_reported = True
            self._next["home"] = 0.0
        if self.ap.now_s >= self._system_time_due_s:
            self.system_time()
        for name, due in self._next.items():
            if wall_s >= due and self.periods[name] > 0:
                self.stream(name)
                self._next[name] = wall_s + self.periods[name]

    def all_at_once(self) -> None:
        """Every stream at the next send_due: a client that starts asking listens now, and should
        not wait up to a period for the health and position it waits on before arming."""
        self._next = {name: 0.0 for name in self._next}

    def set_interval(self, stream: str, interval_us: float) -> None:
        """MAV_CMD_SET_MESSAGE_INTERVAL: -1 stops a stream, 0 restores its default period."""
        if interval_us < 0:
            self.periods[stream] = 0.0
        elif interval_us > 0:
            self.periods[stream] = max(MIN_STREAM_PERIOD_S, interval_us / 1e6)
        else:
            self.periods[stream] = STREAMS[stream]
