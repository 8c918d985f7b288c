"""The harness's MAVSDK client (MAVSDK-Python 4.x, the native binding): connect, check health,
configure, upload the mission, arm and start. Every wait has a timeout.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import TYPE_CHECKING, Callable, Mapping, Sequence

from mavsdk import ComponentType, Configuration, ConnectionResult, LogLevel, Mavsdk, log_subscribe
from mavsdk.plugins.action import Action
from mavsdk.plugins.action.action import ActionError, ActionResult
from mavsdk.plugins.failure import Failure, FailureType, FailureUnit
from mavsdk.plugins.mission_raw import MissionItem, MissionRaw
from mavsdk.plugins.param import Param
from mavsdk.plugins.telemetry import Telemetry
from pymavlink.dialects.v20.common import (
    MAV_CMD_DO_CHANGE_SPEED, MAV_CMD_NAV_LAND, MAV_CMD_NAV_TAKEOFF, MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, MAV_FRAME_MISSION)

from harness.errors import InfrastructureError
from sim_bridge.geo import geodetic_from_local
from simlink.failures import TYPE_BY_NAME, UNIT_BY_NAME

if TYPE_CHECKING:
    from sim_bridge.spec import WorldSpec

log = logging.getLogger(__name__)

ACCEPTANCE_RADIUS_M = 2.0
# A SUT that denies arming is asked again this often, within the caller's window.
ARM_RETRY_INTERVAL_S = 0.1
# How a SUT refuses an arming its pre-arm checks fail: PX4 says DENIED, ArduPilot FAILED.
REFUSED_FOR_NOW = (ActionResult.COMMAND_DENIED, ActionResult.FAILED)
# MAVSDK's health is polled this often: health usually comes within one poll of the hold, and
# each poll is a call into MAVSDK's memory, so a coarse poll only adds to every set-up.
HEALTH_POLL_S = 0.005


_MAVSDK_LEVELS = {LogLevel.DEBUG: logging.DEBUG, LogLevel.INFO: logging.DEBUG, LogLevel.WARN: logging.WARNING, LogLevel.ERROR: logging.ERROR}
_mavsdk_log = logging.getLogger("mavsdk")


def _route_mavsdk_log(level, message: str, _file, _line) -> bool:
    """MAVSDK's own log into Python logging (its info chatter at debug level), not onto stderr."""
    _mavsdk_log.log(_MAVSDK_LEVELS.get(level, logging.INFO), message)
    return True


log_subscribe(_route_mavsdk_log)


def mission_items(world: WorldSpec, home_item: bool = False) -> list[MissionItem]:
    """MISSION_ITEM_INTs for the world's mission: a plan's items as they are, or take off, set
    speed, waypoints, land at the last. With home_item, item 0 is the start, for a SUT that takes
    item 0 for home (ArduPilot) and flies from item 1."""
    items = _mission_items(world)
    if not home_item:
        return items
    lat, lon = geodetic_from_local(world.origin.lat_deg, world.origin.lon_deg, world.uav.start.north_m, world.uav.start.east_m)
    home = MissionItem(seq=0, frame=0, command=MAV_CMD_NAV_WAYPOINT, current=1, autocontinue=1, param1=0.0, param2=0.0, param3=0.0, param4=0.0,
                       x=int(round(lat * 1e7)), y=int(round(lon * 1e7)), z=float(world.start_msl_m), mission_type=0)
    return [home] + [MissionItem(seq=item.seq + 1, frame=item.frame, command=item.command, current=0, autocontinue=item.autocontinue,
                                 param1=item.param1, param2=item.param2, param3=item.param3, param4=item.param4, x=item.x, y=item.y, z=item.z,
                                 mission_type=item.mission_type) for item in items]


def _mission_items(world: WorldSpec) -> list[MissionItem]:
    origin = world.origin
    mission = world.mission
    if mission.plan_items is not None:
        items = []
        for seq, item in enumerate(mission.plan_items):
            p = [float("nan") if v is None else float(v) for v in item["params"]]
            items.append(MissionItem(seq=seq, frame=item["frame"], command=item["command"], current=1 if seq == 0 else 0, autocontinue=1,
                                     param1=p[0], param2=p[1], param3=p[2], param4=p[3], x=item["x"], y=item["y"], z=float(item["z"]), mission_type=0))
        return items
    start = world.uav.start
    items: list[MissionItem] = []

    def add(command: int, frame: int, north: float | None, east: float | None, z: float, *params: float) -> None:
        x = y = 0
        if north is not None:
            lat, lon = geodetic_from_local(origin.lat_deg, origin.lon_deg, north, east)
            x, y = int(round(lat * 1e7)), int(round(lon * 1e7))
        p = list(params) + [0.0] * (4 - len(params))
        items.append(MissionItem(seq=len(items), frame=frame, command=command, current=1 if not items else 0, autocontinue=1,
                                 param1=p[0], param2=p[1], param3=p[2], param4=p[3], x=x, y=y, z=float(z), mission_type=0))

    add(MAV_CMD_NAV_TAKEOFF, MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, start.north_m, start.east_m, mission.takeoff_altitude_m, 0.0, 0.0, 0.0, float("nan"))
    add(MAV_CMD_DO_CHANGE_SPEED, MAV_FRAME_MISSION, None, None, 0.0, 1.0, mission.cruise_speed_m_s, -1.0)
    for waypoint in mission.waypoints:
        add(MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, waypoint.north_m, waypoint.east_m, waypoint.altitude_m, 0.0, ACCEPTANCE_RADIUS_M, 0.0, float("nan"))
    if mission.land:
        last = mission.waypoints[-1]
        add(MAV_CMD_NAV_LAND, MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, last.north_m, last.east_m, 0.0, 0.0, 0.0, 0.0, float("nan"))
    return items


class MavsdkSession:
    """One MAVSDK instance talking to one SUT; close() releases it."""

    def __init__(self, port: int):
        """Listen on the port at once, so that no heartbeat sent before discover() is lost."""
        self.sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        self.port = port
        result = self.sdk.add_any_connection(f"udpin://127.0.0.1:{port}")
        if result != ConnectionResult.SUCCESS:
            self.close()
            raise InfrastructureError(f"MAVSDK could not listen on UDP {port}: {result.name}")
        self.status_texts: list[str] = []
        self.mission_progress: tuple[int, int] = (0, 0)
        self._lock = threading.Lock()
        self.system = None
        self.failure: Failure | None = None
        # The answer to an injection while the failure plugin is off: a SUT without
        # MAV_CMD_INJECT_FAILURE (ArduPilot) says UNSUPPORTED.
        self.answer_without_injection = "NOT_ENABLED"
        # A SUT that fails its units through parameters instead (ArduPilot's SITL): (unit, type)
        # -> parameters, None where it has no means; and what each unit's failure set.
        self.failure_params: Callable[[str, str], Mapping[str, float] | None] | None = None
        self._failed_params: dict[str, Mapping[str, float]] = {}
        # What the harness last asked of the SUT, in words: a SUT that stops answering is
        # reported with it ("after arming was requested").
        self.last_request: str | None = None

    def restart(self) -> None:
        """A new flight with the same connection (a warm stack's next evaluation): forget what the
        last one's autopilot said."""
        with self._lock:
            self.status_texts = []
            self.mission_progress = (0, 0)
        self.failure = None
        self._failed_params = {}
        self.last_request = None

    def discover(self, timeout_s: float = 20.0, alive=lambda: True) -> "MavsdkSession":
        """Wait for the autopilot's heartbeat, giving up early when alive() turns false; with a
        system found before (a warm stack), until MAVSDK counts it connected."""
        deadline = time.monotonic() + timeout_s
        if self.system is not None:
            while not self.system.is_connected():
                if time.monotonic() > deadline or not alive():
                    raise InfrastructureError(f"the autopilot on UDP {self.port} did not reconnect within {timeout_s:.0f} s")
                time.sleep(0.01)
            return self
        while self.system is None and time.monotonic() < deadline and alive():
            self.system = self.sdk.first_autopilot(timeout_s=0.25)
        if self.system is None:
            raise InfrastructureError(f"no autopilot heartbeat on UDP {self.port} within {timeout_s:.0f} s")
        self.telemetry = Telemetry(self.system)
        self.action = Action(self.system)
        self.mission = MissionRaw(self.system)
        self.param = Param(self.system)
        self.telemetry.subscribe_status_text(self._on_status_text)
        self.mission.subscribe_mission_progress(self._on_progress)
        return self

    def _on_status_text(self, status, _user_data) -> None:
        with self._lock:
            self.status_texts.append(status.text)

    def _on_progress(self, progress, _user_data) -> None:
        with self._lock:
            self.mission_progress = (progress.current, progress.total)

    def wait_healthy(self, timeout_s: float) -> float:
        """Seconds until MAVSDK reports every health check ok and the vehicle armable."""
        self.last_request = "its health was awaited"
        start = time.monotonic()
        while time.monotonic() - start < timeout_s:
            if self.telemetry.health_all_ok():
                return time.monotonic() - start
            time.sleep(HEALTH_POLL_S)
        health = self.telemetry.health()
        raise InfrastructureError(f"the SUT did not become healthy within {timeout_s:.0f} s: {vars(health)}")

    def set_params(self, values: Mapping[str, float | int]) -> None:
        """Set each parameter with the type its value has; a whole-number value the SUT refuses
        as one type is tried as the other (a user's --sut-param cannot know PX4's types)."""
        as_int, as_float = (self.param.set_param_int, int), (self.param.set_param_float, float)
        for name, value in values.items():
            self.last_request = f"parameter {name} was set"
            attempts = [as_int, as_float] if isinstance(value, int) else [as_float, as_int]
            if not float(value).is_integer():
                attempts = attempts[:1]
            for attempt, (setter, cast) in enumerate(attempts):
                try:
                    setter(name, cast(value))
                    break
                except Exception as error:  # MAVSDK's ParamError; the last attempt's is the one to report
                    if attempt == len(attempts) - 1:
                        raise InfrastructureError(f"the SUT refused parameter {name} = {value}: {error}") from None

    def upload_and_start(self, items: Sequence[MissionItem], arm_retry_s: float) -> None:
        self.last_request = "the mission was uploaded"
        self.mission.upload_mission(list(items))
        self.arm(arm_retry_s)
        self.last_request = "the mission was started"
        self.mission.start_mission()

    def arm_and_take_off(self, arm_retry_s: float, command_altitude_m: float | None = None) -> None:
        """The pilot drive's start: the rest is the simulated pilot's, at the simulation's clock.
        A SUT that reads its take-off altitude from a parameter (PX4's and the bundled
        autopilot's MIS_TAKEOFF_ALT) has it set with the set-up's parameters; one without such a
        parameter (ArduPilot) gets command_altitude_m in the take-off command."""
        if command_altitude_m is not None:
            self.action.set_takeoff_altitude(float(command_altitude_m))
        self.arm(arm_retry_s)
        self.last_request = "take-off was requested"
        self.action.takeoff()

    def arm(self, retry_for_s: float) -> None:
        """Arm, asking again while the SUT denies it, for up to retry_for_s. PX4's position
        estimate or heading can turn invalid for a second or two just after MAVSDK first reported
        it healthy and armable, so that it denies arming then (its own MAVSDK tests ask again
        for 30 s; here up to half of PX4 main's flights did, 2026-11). ArduCopter answers an
        arming its pre-arm checks fail with MAV_RESULT_FAILED: on a loaded machine MAVSDK can
        call it healthy a second before its AHRS has settled ("Arm: Gyros inconsistent")."""
        self.last_request = "arming was requested"
        deadline = time.monotonic() + retry_for_s
        denials = 0
        while True:
            try:
                self.action.arm()
                break
            except ActionError as error:
                if error.result not in REFUSED_FOR_NOW or time.monotonic() >= deadline:
                    raise
            denials += 1
            time.sleep(ARM_RETRY_INTERVAL_S)
        if denials:
            log.info("armed after %d denials", denials)

    def enable_failure_injection(self) -> None:
        """SYS_FAILURE_EN = 1, then MAVSDK's failure plugin: it reads the parameter once, when made."""
        self.set_params({"SYS_FAILURE_EN": 1})
        self.failure = Failure(self.system)

    def inject_failure(self, unit: str, kind: str) -> str:
        """MAV_CMD_INJECT_FAILURE for a scenario's unit and type ("ok" clears it); the SUT's
        answer by name (SUCCESS, DENIED, UNSUPPORTED, ...)."""
        failure_type = FailureType.OK if kind == "ok" else FailureType(int(TYPE_BY_NAME[kind]))
        self.last_request = f"the failure of its {unit} was injected" if kind != "ok" else f"its {unit} was restored"
        if self.failure is None and self.failure_params is not None:
            return self._fail_by_params(unit, kind)
        if self.failure is None:
            return self.answer_without_injection
        try:
            self.failure.inject(FailureUnit(int(UNIT_BY_NAME[unit])), failure_type, 0)
        except Exception as error:  # MAVSDK's FailureError carries the SUT's answer
            return getattr(getattr(error, "result", None), "name", str(error))
        return "SUCCESS"

    def _fail_by_params(self, unit: str, kind: str) -> str:
        """A failure through the SUT's parameters; its end sets back those its onset set."""
        if kind == "ok":
            failed = self._failed_params.pop(unit, None)
            unfailed = self.failure_params(unit, "ok") if failed is not None else None
            params = None if unfailed is None else {name: unfailed[name] for name in failed}
        else:
            params = self.failure_params(unit, kind)
        if params is None:
            return self.answer_without_injection
        try:
            self.set_params(params)
        except InfrastructureError as error:
            return f"DENIED: {error}"
        if kind != "ok":
            self._failed_params[unit] = params
        return "SUCCESS"

    def close(self) -> None:
        sdk = getattr(self, "sdk", None)
        if sdk is not None:
            sdk.destroy()
            self.sdk = None
