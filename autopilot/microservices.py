"""Two of the API link's MAVLink microservices as PX4 speaks them: the parameter protocol
(PARAM_REQUEST_LIST/READ, PARAM_SET, each answered with PARAM_VALUE) and the mission protocol
(upload by MISSION_COUNT and MISSION_REQUEST_INT, download, clear, set current).
"""

from __future__ import annotations

from typing import Callable

from pymavlink.dialects.v20 import common as mavlink

from autopilot.params import BY_NAME, ParamError
from autopilot.telemetry import Link


class ParameterProtocol:
    def __init__(self, link: Link):
        self.link = link
        self.ap = link.ap
        self.mav = link.mav

    def _send(self, message) -> None:
        self.link.send(message)

    def handlers(self) -> dict[str, Callable]:
        return {"PARAM_REQUEST_LIST": self._param_list, "PARAM_REQUEST_READ": self._param_read, "PARAM_SET": self._param_set}

    def _param_value(self, name: str) -> None:
        params = self.ap.params
        names = params.names()
        self._send(self.mav.param_value_encode(name.encode(), params.wire_value(name), BY_NAME[name].mav_type, len(names), names.index(name)))

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
            self.link.statustext(f"param rejected: {error}"[:50], mavlink.MAV_SEVERITY_WARNING)
            if name not in params.names():
                return
        if name in params.unmodelled:
            # A PX4 parameter it does not model: acknowledged as sent, so the client does not
            # wait for an answer, and said to have no effect; 65535: not in the list.
            self.link.statustext(f"{name} accepted without effect"[:50], mavlink.MAV_SEVERITY_NOTICE)
            self._send(self.mav.param_value_encode(name.encode(), msg.param_value, msg.param_type, len(params.names()), 65535))
            return
        self._param_value(name)


class MissionProtocol:
    def __init__(self, link: Link):
        self.link = link
        self.ap = link.ap
        self.mav = link.mav
        self._upload: dict | None = None

    def _send(self, message) -> None:
        self.link.send(message)

    def handlers(self) -> dict[str, Callable]:
        return {
            "MISSION_COUNT": self._mission_count,
            "MISSION_ITEM_INT": self._mission_item,
            "MISSION_ITEM": self._mission_item,
            "MISSION_REQUEST_LIST": self._mission_request_list,
            "MISSION_REQUEST_INT": self._mission_request,
            "MISSION_REQUEST": self._mission_request,
            "MISSION_CLEAR_ALL": self._mission_clear,
            "MISSION_SET_CURRENT": self._mission_set_current,
        }


    def _mission_count(self, msg) -> None:
        if msg.mission_type != mavlink.MAV_MISSION_TYPE_MISSION:
            self._send(self.mav.mission_ack_encode(msg.get_srcSystem(), msg.get_srcComponent(), mavlink.MAV_MISSION_UNSUPPORTED, msg.mission_type))
            return
        if msg.count == 0:
            self.ap.commander.set_mission([])
            self._send(self.mav.mission_ack_encode(msg.get_srcSystem(), msg.get_srcComponent(), mavlink.MAV_MISSION_ACCEPTED, 0))
            return
        self._upload = {"count": msg.count, "items": [], "system": msg.get_srcSystem(), "component": msg.get_srcComponent()}
        self._send(self.mav.mission_request_int_encode(msg.get_srcSystem(), msg.get_srcComponent(), 0, 0))

    def _mission_item(self, msg) -> None:
        upload = self._upload
        if upload is None or msg.mission_type != mavlink.MAV_MISSION_TYPE_MISSION:
            return
        expected = len(upload["items"])
        if msg.seq != expected:
            self._send(self.mav.mission_request_int_encode(upload["system"], upload["component"], expected, 0))
            return
        if msg.get_type() == "MISSION_ITEM_INT":
            lat, lon = msg.x * 1e-7, msg.y * 1e-7
        else:
            lat, lon = msg.x, msg.y
        item = self.ap.mission_item_from_global(msg.seq, msg.command, msg.frame, lat, lon, msg.z, (msg.param1, msg.param2, msg.param3, msg.param4))
        if item is None:
            self._send(self.mav.mission_ack_encode(upload["system"], upload["component"], mavlink.MAV_MISSION_ERROR, 0))
            self._upload = None
            return
        upload["items"].append(item)
        if len(upload["items"]) < upload["count"]:
            self._send(self.mav.mission_request_int_encode(upload["system"], upload["component"], len(upload["items"]), 0))
            return
        self.ap.commander.set_mission(upload["items"])
        self._send(self.mav.mission_ack_encode(upload["system"], upload["component"], mavlink.MAV_MISSION_ACCEPTED, 0))
        self._upload = None

    def _mission_request_list(self, msg) -> None:
        count = len(self.ap.commander.mission) if msg.mission_type == mavlink.MAV_MISSION_TYPE_MISSION else 0
        self._send(self.mav.mission_count_encode(msg.get_srcSystem(), msg.get_srcComponent(), count, msg.mission_type))

    def _mission_request(self, msg) -> None:
        mission = self.ap.commander.mission
        if msg.mission_type != mavlink.MAV_MISSION_TYPE_MISSION or not 0 <= msg.seq < len(mission):
            self._send(self.mav.mission_ack_encode(msg.get_srcSystem(), msg.get_srcComponent(), mavlink.MAV_MISSION_INVALID_SEQUENCE, msg.mission_type))
            return
        item = mission[msg.seq]
        lat, lon = self.ap.estimator.geodetic_from_local(item.north_m, item.east_m)
        current = 1 if msg.seq == self.ap.commander.current else 0
        self._send(
            self.mav.mission_item_int_encode(
                msg.get_srcSystem(), msg.get_srcComponent(), item.seq, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, item.command, current, 1,
                item.param1, item.param2, item.param3, item.param4, int(round(lat * 1e7)), int(round(lon * 1e7)), item.altitude_m, 0,
            )
        )

    def _mission_clear(self, msg) -> None:
        self.ap.commander.set_mission([])
        self._send(self.mav.mission_ack_encode(msg.get_srcSystem(), msg.get_srcComponent(), mavlink.MAV_MISSION_ACCEPTED, msg.mission_type))

    def _mission_set_current(self, msg) -> None:
        c = self.ap.commander
        if 0 <= msg.seq < len(c.mission):
            c.current = msg.seq
            c.mission_finished = False
        self.link.streams.mission_current()
