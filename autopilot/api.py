"""The API link (what MAVSDK talks to): PX4's heartbeat and custom modes, parameters, missions,
commands and telemetry. Telemetry rates are wall-clock rates: at 40x real time, sim-time rates
would flood the client with thousands of messages a second.
"""

from __future__ import annotations

import logging
import math
import socket
import time
from typing import Protocol

from pymavlink.dialects.v20 import common as mavlink

from autopilot.commander import MAIN_AUTO, SUB_AUTO_LAND, SUB_AUTO_LOITER, SUB_AUTO_RTL, Commander, MissionItem, VehicleEstimate
from autopilot.estimator import Estimator
from autopilot.params import BY_NAME, ParamError, Params
from simlink.failures import MAV_CMD_INJECT_FAILURE, SUPPORTED_TYPES, SUPPORTED_UNITS, FailureType, FailureUnit, failure_text

log = logging.getLogger(__name__)

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
SENSOR_INSTANCES = 1  # of each unit failures can be injected into (MAV_CMD_INJECT_FAILURE's param3: 0 all, 1 the first)


class Vehicle(Protocol):
    """What the API link reads and commands of the autopilot (autopilot.app.Autopilot is one)."""

    now_s: float
    collective: float
    sensors_seen: bool
    params: Params
    estimator: Estimator
    commander: Commander

    def euler(self) -> tuple[float, float, float]: ...

    def yaw_rad(self) -> float: ...

    def home_geodetic(self) -> tuple[float, float, float] | None: ...

    def vehicle_estimate(self) -> VehicleEstimate: ...

    def ready_to_arm(self) -> tuple[bool, str]: ...

    def on_armed(self) -> None: ...

    def mission_item_from_global(self, seq: int, command: int, frame: int, lat: float, lon: float, z: float, params) -> MissionItem | None: ...

    def inject_failure(self, unit: FailureUnit, kind: FailureType) -> None: ...


class ApiLink:
    def __init__(self, autopilot: Vehicle, remote: tuple[str, int]):
        self.ap = autopilot
        self.remote = remote
        self.partner_chosen = False
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((remote[0], 0))
        self.sock.setblocking(False)
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=mavlink.MAV_COMP_ID_AUTOPILOT1)
        self.mav.robust_parsing = True
        self.periods = dict(STREAMS)
        self._next = {name: 0.0 for name in STREAMS}
        self._upload: dict | None = None
        self.last_gcs_heartbeat = None
        self.link_lost_reported = False
        self._reported_health = -1
        self._home_reported = False
        self._client_greeted = False

    # -- sending ------------------------------------------------------------------------------

    def send(self, message) -> None:
        try:
            self.sock.sendto(message.pack(self.mav), self.remote)
        except OSError as error:
            log.debug("api send failed: %s", error)

    def statustext(self, text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> None:
        self.send(self.mav.statustext_encode(severity, text.encode()[:50]))

    def _time_boot_ms(self) -> int:
        return int(self.ap.now_s * 1000) & 0xFFFFFFFF

    def heartbeat(self) -> None:
        c = self.ap.commander
        main, sub = c.mode
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED | mavlink.MAV_MODE_FLAG_AUTO_ENABLED
        if c.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        state = mavlink.MAV_STATE_ACTIVE if c.armed else mavlink.MAV_STATE_STANDBY
        self.send(self.mav.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base, (sub << 24) | (main << 16), state))

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
        self.send(self.mav.sys_status_encode(present, present, health, 200, 16000, 500, 90, 0, 0, 0, 0, 0, 0))

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
        self.send(self.mav.global_position_int_encode(t, int(lat * 1e7), int(lon * 1e7), int(est.altitude_msl() * 1000), int((home_d - d) * 1000), int(vn * 100), int(ve * 100), int(vd * 100), heading))
        self.send(self.mav.local_position_ned_encode(t, n, e, d, vn, ve, vd))

    def _attitude(self) -> None:
        est = self.ap.estimator
        roll, pitch, yaw = self.ap.euler()
        t = self._time_boot_ms()
        self.send(self.mav.attitude_encode(t, roll, pitch, yaw, *est.rates))
        self.send(self.mav.attitude_quaternion_encode(t, *est.q, *est.rates, [0.0, 0.0, 0.0, 0.0]))

    def _gps_raw(self) -> None:
        fix = self.ap.estimator.last_gps
        if fix is None:
            return
        course = int(math.degrees(math.atan2(fix.v_east_m_s, fix.v_north_m_s)) % 360.0 * 100)
        speed = int(math.hypot(fix.v_north_m_s, fix.v_east_m_s) * 100)
        self.send(self.mav.gps_raw_int_encode(int(self.ap.now_s * 1e6), fix.fix_type, int(fix.lat_deg * 1e7), int(fix.lon_deg * 1e7), int(fix.alt_m * 1000), 30, 40, speed, course, fix.satellites))

    def _home(self) -> None:
        home = self.ap.home_geodetic()
        if home is None:
            return
        lat, lon, alt = home
        n, e, d = self.ap.commander.home
        self.send(self.mav.home_position_encode(int(lat * 1e7), int(lon * 1e7), int(alt * 1000), n, e, d, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int(self.ap.now_s * 1e6)))

    def _extended_sys_state(self) -> None:
        c = self.ap.commander
        if not c.armed or c.landed:
            landed = mavlink.MAV_LANDED_STATE_ON_GROUND
        elif c.mode == (MAIN_AUTO, SUB_AUTO_LAND):
            landed = mavlink.MAV_LANDED_STATE_LANDING
        else:
            landed = mavlink.MAV_LANDED_STATE_IN_AIR
        self.send(self.mav.extended_sys_state_encode(mavlink.MAV_VTOL_STATE_UNDEFINED, landed))

    def _battery(self) -> None:
        voltages = [4000, 4000, 4000, 4000] + [65535] * 6
        self.send(self.mav.battery_status_encode(0, mavlink.MAV_BATTERY_FUNCTION_ALL, mavlink.MAV_BATTERY_TYPE_LIPO, 2500, voltages, 500, -1, -1, 90))

    def _vfr_hud(self) -> None:
        est = self.ap.estimator
        speed = math.hypot(est.vel[0], est.vel[1])
        heading = int(math.degrees(self.ap.yaw_rad()) % 360.0)
        self.send(self.mav.vfr_hud_encode(speed, speed, heading, int(self.ap.collective * 100), est.altitude_msl(), -est.vel[2]))

    def _altitude(self) -> None:
        est, c = self.ap.estimator, self.ap.commander
        relative = (c.home[2] if c.home else 0.0) - est.pos[2]
        amsl = est.altitude_msl()
        self.send(self.mav.altitude_encode(int(self.ap.now_s * 1e6), amsl, amsl, -est.pos[2], relative, relative, float("nan")))

    def _mission_current(self) -> None:
        c = self.ap.commander
        state = mavlink.MISSION_STATE_COMPLETE if c.mission_finished else (mavlink.MISSION_STATE_ACTIVE if c.mission else mavlink.MISSION_STATE_NO_MISSION)
        self.send(self.mav.mission_current_encode(c.current, len(c.mission), state))

    def _autopilot_version(self) -> None:
        self.send(self.mav.autopilot_version_encode(CAPABILITIES, FLIGHT_SW_VERSION, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 1, [0] * 18))

    def _stream(self, name: str) -> None:
        {
            "heartbeat": self.heartbeat,
            "sys_status": self._sys_status,
            "extended_sys_state": self._extended_sys_state,
            "attitude": self._attitude,
            "position": self._position,
            "gps_raw": self._gps_raw,
            "home": self._home,
            "battery": self._battery,
            "vfr_hud": self._vfr_hud,
            "altitude": self._altitude,
            "mission_current": self._mission_current,
        }[name]()

    def telemetry(self, wall_s: float) -> None:
        # Health and home go out as soon as they change: a client waiting to arm should not wait
        # for the next periodic message.
        if self._health_bits() != self._reported_health:
            self._next["sys_status"] = 0.0
        if not self._home_reported and self.ap.home_geodetic() is not None:
            self._home_reported = True
            self._next["home"] = 0.0
        for name, due in self._next.items():
            if wall_s >= due and self.periods[name] > 0:
                self._stream(name)
                self._next[name] = wall_s + self.periods[name]

    def report_events(self) -> None:
        c = self.ap.commander
        for kind, value in c.events:
            if kind == "statustext":
                self.statustext(str(value))
            elif kind == "item_reached":
                self.send(self.mav.mission_item_reached_encode(int(value)))
            elif kind == "mission_current":
                self._mission_current()
            elif kind in ("mode", "landed", "in_air"):
                self.heartbeat()
                self._extended_sys_state()
        c.events.clear()

    # -- receiving ----------------------------------------------------------------------------

    def receive(self) -> None:
        while True:
            try:
                data, address = self.sock.recvfrom(65536)
            except BlockingIOError:
                return
            except OSError:
                return
            # A datagram holds whole frames: what a bad one left half-parsed must not swallow the next.
            self.mav.buf, self.mav.buf_index, self.mav.expected_length = bytearray(), 0, mavlink.HEADER_LEN_V1 + 2
            messages = [m for m in self.mav.parse_buffer(data) or [] if m.get_type() != "BAD_DATA"]
            if messages and not self.partner_chosen:
                # As PX4's UDP link: the first peer to speak MAVLink becomes the partner, for good;
                # others are still heard, but neither they nor stray datagrams divert the telemetry.
                self.remote = address
                self.partner_chosen = True
            for message in messages:
                self.handle(message)

    def handle(self, msg) -> None:
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            self.last_gcs_heartbeat = time.monotonic()
            self.link_lost_reported = False
            return
        handler = {
            "PARAM_REQUEST_LIST": self._param_list,
            "PARAM_REQUEST_READ": self._param_read,
            "PARAM_SET": self._param_set,
            "MISSION_COUNT": self._mission_count,
            "MISSION_ITEM_INT": self._mission_item,
            "MISSION_ITEM": self._mission_item,
            "MISSION_REQUEST_LIST": self._mission_request_list,
            "MISSION_REQUEST_INT": self._mission_request,
            "MISSION_REQUEST": self._mission_request,
            "MISSION_CLEAR_ALL": self._mission_clear,
            "MISSION_SET_CURRENT": self._mission_set_current,
            "COMMAND_LONG": self._command,
            "COMMAND_INT": self._command,
            "TIMESYNC": self._timesync,
        }.get(kind)
        if handler is not None:
            handler(msg)

    def check_link(self, timeout_s: float) -> None:
        if self.last_gcs_heartbeat is None or self.link_lost_reported:
            return
        if time.monotonic() - self.last_gcs_heartbeat > timeout_s:
            self.link_lost_reported = True
            self.statustext("Connection to ground station lost; continuing", mavlink.MAV_SEVERITY_WARNING)

    def _timesync(self, msg) -> None:
        if msg.tc1 == 0:
            self.send(self.mav.timesync_encode(int(time.monotonic() * 1e9), msg.ts1))

    # parameters

    def _param_value(self, name: str) -> None:
        params = self.ap.params
        names = params.names()
        self.send(self.mav.param_value_encode(name.encode(), params.wire_value(name), BY_NAME[name].mav_type, len(names), names.index(name)))

    def _param_list(self, msg) -> None:
        for name in self.ap.params.names():
            self._param_value(name)

    def _param_read(self, msg) -> None:
        names = self.ap.params.names()
        if msg.param_index >= 0:
            if msg.param_index < len(names):
                self._param_value(names[msg.param_index])
            return
        name = msg.param_id.rstrip("\x00") if isinstance(msg.param_id, str) else msg.param_id.decode().rstrip("\x00")
        if name in names:
            self._param_value(name)

    def _param_set(self, msg) -> None:
        name = msg.param_id.rstrip("\x00") if isinstance(msg.param_id, str) else msg.param_id.decode().rstrip("\x00")
        params = self.ap.params
        try:
            params.set(name, params.from_wire(name, msg.param_value, msg.param_type))
        except ParamError as error:
            self.statustext(f"param rejected: {error}"[:50], mavlink.MAV_SEVERITY_WARNING)
            if name not in params.names():
                return
        if name in params.unmodelled:
            # A PX4 parameter it does not model: acknowledged as sent, so the client does not
            # wait for an answer, and said to have no effect; 65535: not in the list.
            self.statustext(f"{name} accepted without effect"[:50], mavlink.MAV_SEVERITY_NOTICE)
            self.send(self.mav.param_value_encode(name.encode(), msg.param_value, msg.param_type, len(params.names()), 65535))
            return
        self._param_value(name)

    # missions

    def _mission_count(self, msg) -> None:
        if msg.mission_type != mavlink.MAV_MISSION_TYPE_MISSION:
            self.send(self.mav.mission_ack_encode(msg.get_srcSystem(), msg.get_srcComponent(), mavlink.MAV_MISSION_UNSUPPORTED, msg.mission_type))
            return
        if msg.count == 0:
            self.ap.commander.set_mission([])
            self.send(self.mav.mission_ack_encode(msg.get_srcSystem(), msg.get_srcComponent(), mavlink.MAV_MISSION_ACCEPTED, 0))
            return
        self._upload = {"count": msg.count, "items": [], "system": msg.get_srcSystem(), "component": msg.get_srcComponent()}
        self.send(self.mav.mission_request_int_encode(msg.get_srcSystem(), msg.get_srcComponent(), 0, 0))

    def _mission_item(self, msg) -> None:
        upload = self._upload
        if upload is None or msg.mission_type != mavlink.MAV_MISSION_TYPE_MISSION:
            return
        expected = len(upload["items"])
        if msg.seq != expected:
            self.send(self.mav.mission_request_int_encode(upload["system"], upload["component"], expected, 0))
            return
        if msg.get_type() == "MISSION_ITEM_INT":
            lat, lon = msg.x * 1e-7, msg.y * 1e-7
        else:
            lat, lon = msg.x, msg.y
        item = self.ap.mission_item_from_global(msg.seq, msg.command, msg.frame, lat, lon, msg.z, (msg.param1, msg.param2, msg.param3, msg.param4))
        if item is None:
            self.send(self.mav.mission_ack_encode(upload["system"], upload["component"], mavlink.MAV_MISSION_ERROR, 0))
            self._upload = None
            return
        upload["items"].append(item)
        if len(upload["items"]) < upload["count"]:
            self.send(self.mav.mission_request_int_encode(upload["system"], upload["component"], len(upload["items"]), 0))
            return
        self.ap.commander.set_mission(upload["items"])
        self.send(self.mav.mission_ack_encode(upload["system"], upload["component"], mavlink.MAV_MISSION_ACCEPTED, 0))
        self._upload = None

    def _mission_request_list(self, msg) -> None:
        count = len(self.ap.commander.mission) if msg.mission_type == mavlink.MAV_MISSION_TYPE_MISSION else 0
        self.send(self.mav.mission_count_encode(msg.get_srcSystem(), msg.get_srcComponent(), count, msg.mission_type))

    def _mission_request(self, msg) -> None:
        mission = self.ap.commander.mission
        if msg.mission_type != mavlink.MAV_MISSION_TYPE_MISSION or not 0 <= msg.seq < len(mission):
            self.send(self.mav.mission_ack_encode(msg.get_srcSystem(), msg.get_srcComponent(), mavlink.MAV_MISSION_INVALID_SEQUENCE, msg.mission_type))
            return
        item = mission[msg.seq]
        lat, lon = self.ap.estimator.geodetic_from_local(item.north_m, item.east_m)
        current = 1 if msg.seq == self.ap.commander.current else 0
        self.send(
            self.mav.mission_item_int_encode(
                msg.get_srcSystem(), msg.get_srcComponent(), item.seq, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, item.command, current, 1,
                item.param1, item.param2, item.param3, item.param4, int(round(lat * 1e7)), int(round(lon * 1e7)), item.altitude_m, 0,
            )
        )

    def _mission_clear(self, msg) -> None:
        self.ap.commander.set_mission([])
        self.send(self.mav.mission_ack_encode(msg.get_srcSystem(), msg.get_srcComponent(), mavlink.MAV_MISSION_ACCEPTED, msg.mission_type))

    def _mission_set_current(self, msg) -> None:
        c = self.ap.commander
        if 0 <= msg.seq < len(c.mission):
            c.current = msg.seq
            c.mission_finished = False
        self._mission_current()

    # commands

    def _ack(self, msg, result: int) -> None:
        self.send(self.mav.command_ack_encode(msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))

    def _command(self, msg) -> None:
        if not self._client_greeted:
            # A client's first command (MAVSDK's telemetry plugin asks for messages as it starts)
            # means it listens now: every stream goes out at once, so that it need not wait up to
            # a period for the health and position it waits on before arming.
            self._client_greeted = True
            self._next = {name: 0.0 for name in self._next}
        ap = self.ap
        c = ap.commander
        command = msg.command
        accepted, denied = mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_DENIED
        estimate = ap.vehicle_estimate()
        if command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            if msg.param1 >= 0.5:
                ready, reason = ap.ready_to_arm()
                ok, text = c.arm(ap.now_s, ready, reason)
                if ok:
                    ap.on_armed()
            else:
                ok, text = c.disarm(force=_rounded(msg.param2) == FORCE_DISARM_MAGIC)  # MAVSDK sends NaN: not forced
            if not ok:
                self.statustext(text, mavlink.MAV_SEVERITY_CRITICAL)
            self._ack(msg, accepted if ok else denied)
            self.heartbeat()
        elif command == mavlink.MAV_CMD_DO_SET_MODE:
            ok = c.set_mode((int(msg.param2), int(msg.param3)), estimate, ap.now_s)
            self._ack(msg, accepted if ok else denied)
            self.heartbeat()
        elif command == mavlink.MAV_CMD_MISSION_START:
            ok = c.start_mission(estimate, int(msg.param1))
            self._ack(msg, accepted if ok else denied)
            self.heartbeat()
        elif command == mavlink.MAV_CMD_NAV_TAKEOFF:
            home = ap.home_geodetic()
            if home is None or not c.armed:
                self._ack(msg, denied)
                return
            # COMMAND_LONG carries the altitude in param7, COMMAND_INT in z.
            amsl = msg.z if msg.get_type() == "COMMAND_INT" else msg.param7
            altitude = amsl - home[2] if math.isfinite(amsl) else ap.params["MIS_TAKEOFF_ALT"]
            c.takeoff(estimate, altitude)
            self._ack(msg, accepted)
            self.heartbeat()
        elif command == mavlink.MAV_CMD_NAV_LAND:
            self._ack(msg, accepted if c.set_mode((MAIN_AUTO, SUB_AUTO_LAND), estimate) else denied)
        elif command == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            self._ack(msg, accepted if c.set_mode((MAIN_AUTO, SUB_AUTO_RTL), estimate) else denied)
        elif command == mavlink.MAV_CMD_NAV_LOITER_UNLIM:
            self._ack(msg, accepted if c.set_mode((MAIN_AUTO, SUB_AUTO_LOITER), estimate) else denied)
        elif command == mavlink.MAV_CMD_DO_CHANGE_SPEED:
            c.set_cruise(msg.param2)
            self._ack(msg, accepted)
        elif command in (mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, mavlink.MAV_CMD_GET_HOME_POSITION):
            wanted = {
                mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
                mavlink.MAV_CMD_GET_HOME_POSITION: mavlink.MAVLINK_MSG_ID_HOME_POSITION,
            }.get(command, int(msg.param1))
            if wanted == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
                self._ack(msg, accepted)
                self._autopilot_version()
            elif wanted in MESSAGE_STREAMS:
                self._ack(msg, accepted)
                self._stream(MESSAGE_STREAMS[wanted])
            else:
                self._ack(msg, mavlink.MAV_RESULT_UNSUPPORTED)
        elif command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            stream = MESSAGE_STREAMS.get(int(msg.param1))
            if stream is None:
                self._ack(msg, mavlink.MAV_RESULT_UNSUPPORTED)
                return
            interval_us = msg.param2
            if interval_us < 0:
                self.periods[stream] = 0.0
            elif interval_us > 0:
                self.periods[stream] = max(MIN_STREAM_PERIOD_S, interval_us / 1e6)
            else:
                self.periods[stream] = STREAMS[stream]
            self._ack(msg, accepted)
        elif command == MAV_CMD_INJECT_FAILURE:
            self._inject_failure(msg)
        else:
            self._ack(msg, mavlink.MAV_RESULT_UNSUPPORTED)

    def _inject_failure(self, msg) -> None:
        """As PX4: refused (DENIED) unless SYS_FAILURE_EN is 1; a unit, type or instance it does
        not have is UNSUPPORTED; an accepted one is reported in a STATUSTEXT, a warning (ok, the
        unit's recovery, as information). The parameters are rounded as PX4 rounds them."""
        if not self.ap.params["SYS_FAILURE_EN"]:
            self._ack(msg, mavlink.MAV_RESULT_DENIED)
            return
        unit, kind, instance = (_rounded(value) for value in (msg.param1, msg.param2, msg.param3))
        if unit not in SUPPORTED_UNITS or kind not in SUPPORTED_TYPES or instance is None or not 0 <= instance <= SENSOR_INSTANCES:
            self._ack(msg, mavlink.MAV_RESULT_UNSUPPORTED)
            return
        unit, kind = FailureUnit(unit), FailureType(kind)
        self.ap.inject_failure(unit, kind)
        self.statustext(failure_text(unit, kind), mavlink.MAV_SEVERITY_INFO if kind == FailureType.OK else mavlink.MAV_SEVERITY_WARNING)
        self._ack(msg, mavlink.MAV_RESULT_ACCEPTED)


def _rounded(value: float) -> int | None:
    """A command's float parameter as the whole number PX4 takes it for (value + 0.5, truncated); None if not finite."""
    return int(value + 0.5) if math.isfinite(value) else None

