"""The API link (what MAVSDK talks to): its UDP socket and partner, what it receives and the
commands it answers (COMMAND_LONG/INT: arming, modes, takeoff, land, return, speed, message
requests and intervals, failure injection). Its telemetry (telemetry.py) and its parameter and
mission protocols (microservices.py) send through it.
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
from autopilot.microservices import MissionProtocol, ParameterProtocol
from autopilot.params import Params
from autopilot.telemetry import MESSAGE_STREAMS, Telemetry
from simlink.failures import MAV_CMD_INJECT_FAILURE, SUPPORTED_TYPES, SUPPORTED_UNITS, FailureType, FailureUnit, failure_text

log = logging.getLogger(__name__)

FORCE_DISARM_MAGIC = 21196
# PX4's MAVLink link counts a ground station present until 2.5 s after its last heartbeat
# (telemetry_status HEARTBEAT_TIMEOUT_US), and its commander starts COM_DL_LOSS_T only then:
# PX4 holds 11.9-12.9 s after the link went silent (docs/failsafe_campaigns.md).
LINK_HEARTBEAT_TIMEOUT_S = 2.5
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
        self.last_gcs_heartbeat = None
        self.link_lost_reported = False
        self._client_greeted = False
        self.streams = Telemetry(self)
        self._handlers = {**ParameterProtocol(self).handlers(), **MissionProtocol(self).handlers(),
                          "COMMAND_LONG": self._command, "COMMAND_INT": self._command, "TIMESYNC": self._timesync}

    # -- sending ------------------------------------------------------------------------------

    def send(self, message) -> None:
        try:
            self.sock.sendto(message.pack(self.mav), self.remote)
        except OSError as error:
            log.debug("api send failed: %s", error)

    def statustext(self, text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> None:
        self.streams.system_time()  # a status text carries no time of its own
        self.send(self.mav.statustext_encode(severity, text.encode()[:50]))

    def heartbeat(self) -> None:
        self.streams.heartbeat()

    def telemetry(self, wall_s: float) -> None:
        self.streams.send_due(wall_s)

    def report_events(self) -> None:
        c = self.ap.commander
        for kind, value in c.events:
            if kind == "statustext":
                self.statustext(str(value))
            elif kind == "item_reached":
                self.streams.system_time()  # when it was reached, for the recorder
                self.send(self.mav.mission_item_reached_encode(int(value)))
            elif kind == "mission_current":
                self.streams.mission_current()
            elif kind in ("mode", "landed", "in_air"):
                self.heartbeat()
                self.streams.extended_sys_state()
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
            # Simulated time, as PX4's is in lockstep: the loss is declared after COM_DL_LOSS_T of the flight, however fast it runs.
            self.last_gcs_heartbeat = self.ap.now_s
            if self.link_lost_reported:
                self.link_lost_reported = False
                self.statustext("Data link regained")
            return
        handler = self._handlers.get(kind)
        if handler is not None:
            handler(msg)

    def check_link(self, timeout_s: float) -> None:
        """The ground station's link lost after timeout_s (COM_DL_LOSS_T) of simulated time
        without it, counted as PX4 counts it: from when the link gave the ground station up,
        LINK_HEARTBEAT_TIMEOUT_S after its last heartbeat. The commander's NAV_DLL_ACT acts."""
        if self.last_gcs_heartbeat is None or self.link_lost_reported:
            return
        if self.ap.now_s - self.last_gcs_heartbeat > LINK_HEARTBEAT_TIMEOUT_S + timeout_s:
            self.link_lost_reported = True
            self.statustext("Data link lost", mavlink.MAV_SEVERITY_WARNING)
            self.ap.commander.data_link_lost(self.ap.now_s, self.ap.vehicle_estimate())

    def _timesync(self, msg) -> None:
        if msg.tc1 == 0:
            self.send(self.mav.timesync_encode(int(time.monotonic() * 1e9), msg.ts1))

    # commands

    def _ack(self, msg, result: int) -> None:
        self.send(self.mav.command_ack_encode(msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))

    def _command(self, msg) -> None:
        if not self._client_greeted:
            # A client's first command (MAVSDK's telemetry plugin asks for messages as it starts)
            # means it listens now: every stream goes out at once, so that it need not wait up to
            # a period for the health and position it waits on before arming.
            self._client_greeted = True
            self.streams.all_at_once()
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
                self.streams.autopilot_version()
            elif wanted in MESSAGE_STREAMS:
                self._ack(msg, accepted)
                self.streams.stream(MESSAGE_STREAMS[wanted])
            else:
                self._ack(msg, mavlink.MAV_RESULT_UNSUPPORTED)
        elif command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            stream = MESSAGE_STREAMS.get(int(msg.param1))
            if stream is None:
                self._ack(msg, mavlink.MAV_RESULT_UNSUPPORTED)
                return
            self.streams.set_interval(stream, msg.param2)
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

