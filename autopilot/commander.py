"""The commander: arming, flight modes with PX4's custom-mode numbers, mission execution, land detection.

Pure logic: `update(now_s, ...)` returns the setpoint for the controllers; events (mission item
reached, landed, mode changes) are queued for the MAVLink side to report.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from pymavlink.dialects.v20.common import (
    MAV_CMD_DO_CHANGE_SPEED, MAV_CMD_NAV_DELAY, MAV_CMD_NAV_LAND, MAV_CMD_NAV_RETURN_TO_LAUNCH, MAV_CMD_NAV_TAKEOFF, MAV_CMD_NAV_WAYPOINT,
)

from autopilot.control import Setpoint
from autopilot.manual import FLIGHT_MODE_PARAM, Sticks

# PX4 custom main modes and AUTO sub modes (px4_custom_mode.h).
MAIN_ALTCTL = 2
MAIN_POSCTL = 3
MAIN_AUTO = 4
SUB_AUTO_READY = 1
SUB_AUTO_TAKEOFF = 2
SUB_AUTO_LOITER = 3
SUB_AUTO_MISSION = 4
SUB_AUTO_RTL = 5
SUB_AUTO_LAND = 6

MODE_NAMES = {
    (MAIN_POSCTL, 0): "Position",
    (MAIN_AUTO, SUB_AUTO_TAKEOFF): "Takeoff",
    (MAIN_AUTO, SUB_AUTO_LOITER): "Hold",
    (MAIN_AUTO, SUB_AUTO_MISSION): "Mission",
    (MAIN_AUTO, SUB_AUTO_RTL): "Return",
    (MAIN_AUTO, SUB_AUTO_LAND): "Land",
}
SUPPORTED_MODES = set(MODE_NAMES)
# The position-loss failsafe's modes, which no command selects: how PX4 reports them (its
# Descend mode as AUTO/LAND) and their names.
FAILSAFE_MODES = {"descend": ((MAIN_AUTO, SUB_AUTO_LAND), "Descend"), "altitude": ((MAIN_ALTCTL, 0), "Altitude")}
LANDED_CONFIRM_S = 0.6
VERTICAL_ACCEPTANCE_M = 0.8


@dataclass
class MissionItem:
    """A mission item in the local frame (north/east metres, altitude metres above home)."""

    seq: int
    command: int
    north_m: float
    east_m: float
    altitude_m: float
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
    has_position: bool = True


@dataclass
class VehicleEstimate:
    north_m: float
    east_m: float
    down_m: float
    v_north_m_s: float
    v_east_m_s: float
    v_down_m_s: float
    yaw_rad: float


@dataclass
class Commander:
    params: object
    armed: bool = False
    mode: tuple[int, int] = (MAIN_AUTO, SUB_AUTO_LOITER)
    landed: bool = True
    home: tuple[float, float, float] | None = None  # local NED of home
    mission: list[MissionItem] = field(default_factory=list)
    current: int = 0
    mission_finished: bool = False
    events: list[tuple[str, object]] = field(default_factory=list)
    _hold: tuple[float, float, float] | None = None
    _target_alt_m: float = 0.0
    _cruise_m_s: float | None = None
    _land_candidate_s: float | None = None
    _landed_at_s: float | None = None
    _phase: str = ""
    _wait_until_s: float = 0.0  # the end of a waypoint's hold time or of a delay item
    _yaw_sp: float = 0.0
    manual: Sticks | None = None
    _mode_slot: int | None = None
    failsafe: str = ""  # a FAILSAFE_MODES key while the position is lost; `mode` stays what the user chose
    _delayed: tuple[tuple[int, int], float] | None = None  # a failsafe's mode and when Hold gives way to it (COM_FAIL_ACT_T)

    @property
    def reported_mode(self) -> tuple[int, int]:
        """The mode flown, as the heartbeat reports it: a failsafe's, or the user's."""
        return FAILSAFE_MODES[self.failsafe][0] if self.failsafe else self.mode

    # -- manual control -------------------------------------------------------------------------

    def manual_fresh(self, now_s: float) -> bool:
        return self.manual is not None and now_s - self.manual.received_s <= self.params["COM_RC_LOSS_T"]

    def on_sticks(self, sticks: Sticks, estimate: VehicleEstimate) -> None:
        """A new RC frame. As PX4's manual_control: a mode-switch slot is applied when it changes,
        and its first position is applied only before arming."""
        self.manual = sticks
        slot = sticks.mode_slot
        if slot and (slot != self._mode_slot if self._mode_slot is not None else not self.armed):
            wanted = FLIGHT_MODE_PARAM.get(int(self.params[f"COM_FLTMODE{slot}"]))
            if wanted is not None and not self.set_mode(wanted, estimate, sticks.received_s):
                self.events.append(("statustext", f"Switching to {MODE_NAMES[wanted]} is currently not possible"))
        self._mode_slot = slot

    # -- commands -----------------------------------------------------------------------------

    def arm(self, now_s: float, ready: bool, reason: str) -> tuple[bool, str]:
        if self.armed:
            return True, "already armed"
        if not ready:
            return False, f"arming denied: {reason}"
        self.armed = True
        self._landed_at_s = None
        self.events.append(("statustext", "Armed by external command"))
        return True, "armed"

    def disarm(self, force: bool = False) -> tuple[bool, str]:
        if not self.armed:
            return True, "already disarmed"
        if not self.landed and not force:
            return False, "disarming denied: not landed"
        self.armed = False
        self.events.append(("statustext", "Disarmed"))
        return True, "disarmed"

    def set_mode(self, mode: tuple[int, int], estimate: VehicleEstimate, now_s: float | None = None) -> bool:
        if mode not in SUPPORTED_MODES:
            return False
        if mode == (MAIN_AUTO, SUB_AUTO_MISSION) and not self.mission:
            return False
        if mode == (MAIN_POSCTL, 0) and not (now_s is not None and self.manual_fresh(now_s)):
            return False  # PX4 too refuses Position mode without manual control
        previous = self.mode
        self.mode = mode
        if mode != previous:
            self._enter(estimate)
            self.events.append(("mode", MODE_NAMES[mode]))
        return True

    def start_mission(self, estimate: VehicleEstimate, first: int = 0) -> bool:
        if not self.mission:
            return False
        self.current = max(0, min(first, len(self.mission) - 1)) if first else self.current
        if self.mission_finished:
            self.current = 0
            self.mission_finished = False
        return self.set_mode((MAIN_AUTO, SUB_AUTO_MISSION), estimate)

    def set_mission(self, items: list[MissionItem]) -> None:
        self.mission = items
        self.current = 0
        self.mission_finished = False
        self.events.append(("mission_current", 0))

    def takeoff(self, estimate: VehicleEstimate, altitude_m: float) -> bool:
        self._target_alt_m = altitude_m
        self.mode = (MAIN_AUTO, SUB_AUTO_TAKEOFF)
        self._enter(estimate, keep_target=True)
        self.events.append(("mode", "Takeoff"))
        return True

    def set_cruise(self, speed_m_s: float) -> None:
        self._cruise_m_s = speed_m_s if speed_m_s > 0 else None

    # -- state machine ------------------------------------------------------------------------

    def _altitude(self, estimate: VehicleEstimate) -> float:
        return (self.home[2] if self.home else 0.0) - estimate.down_m

    def _down_for(self, altitude_m: float) -> float:
        return (self.home[2] if self.home else 0.0) - altitude_m

    def _enter(self, estimate: VehicleEstimate, keep_target: bool = False) -> None:
        self._hold = (estimate.north_m, estimate.east_m, estimate.down_m)
        self._phase = ""
        self._yaw_sp = estimate.yaw_rad
        self._land_candidate_s = None
        if self.mode == (MAIN_AUTO, SUB_AUTO_TAKEOFF) and not keep_target:
            self._target_alt_m = max(self.params["MIS_TAKEOFF_ALT"], self._altitude(estimate))

    def _cruise(self) -> float:
        return self._cruise_m_s or self.params["MPC_XY_CRUISE"]

    def _fly_to(self, estimate: VehicleEstimate, north: float, east: float, altitude_m: float) -> tuple[Setpoint, float]:
        """Velocity towards a point along the straight line, braking to arrive; yaw along the track."""
        dn, de = north - estimate.north_m, east - estimate.east_m
        distance = math.hypot(dn, de)
        speed = min(self._cruise(), math.sqrt(2.0 * self.params["MPC_ACC_HOR"] * 0.5 * distance), self.params["MPC_XY_P"] * distance + 0.3)
        if distance > 2.0 and self.params.fault != "yaw_fixed_heading":
            self._yaw_sp = math.atan2(de, dn)
        if distance < 1e-6:
            return Setpoint(north_m=north, east_m=east, down_m=self._down_for(altitude_m), yaw_rad=self._yaw_sp), distance
        sp = Setpoint(
            v_north_m_s=speed * dn / distance,
            v_east_m_s=speed * de / distance,
            down_m=self._down_for(altitude_m),
            yaw_rad=self._yaw_sp,
        )
        return sp, distance

    def _hold_setpoint(self) -> Setpoint:
        n, e, d = self._hold
        return Setpoint(north_m=n, east_m=e, down_m=d, yaw_rad=self._yaw_sp)

    def _detect_landing(self, now_s: float, estimate: VehicleEstimate, lift: float, descending_commanded: bool) -> bool:
        """Landed when commanded down but no longer descending, with lift (the vertical part of the
        thrust; a vehicle held back from sliding on the ground tilts, so not the total) well below hover."""
        hover = self.params["MPC_THR_HOVER"]
        if self.params.fault == "land_detect_home_altitude" and abs(self._altitude(estimate)) > 0.5:
            self._land_candidate_s = None
            return False
        if descending_commanded and abs(estimate.v_down_m_s) < 0.15 and lift < 0.8 * hover:
            if self._land_candidate_s is None:
                self._land_candidate_s = now_s
            return now_s - self._land_candidate_s >= LANDED_CONFIRM_S
        self._land_candidate_s = None
        return False

    def _touch_down(self, now_s: float) -> None:
        self.landed = True
        self._landed_at_s = now_s
        self.events.append(("landed", None))
        self.events.append(("statustext", "Landing detected"))

    def _land(self, now_s: float, estimate: VehicleEstimate, lift: float, north: float, east: float) -> Setpoint:
        sp = Setpoint(north_m=north, east_m=east, v_down_m_s=self.params["MPC_LAND_SPEED"], yaw_rad=self._yaw_sp)
        if self._detect_landing(now_s, estimate, lift, True):
            self._touch_down(now_s)
        return sp

    def _advance(self, index: int) -> None:
        self.events.append(("item_reached", index))
        self.current = index + 1
        if self.current >= len(self.mission):
            self.mission_finished = True
            self.current = len(self.mission) - 1
            self.events.append(("statustext", "Mission finished"))
        self.events.append(("mission_current", self.current))
        self._phase = ""

    def _mission(self, now_s: float, estimate: VehicleEstimate, lift: float) -> Setpoint:
        if self.mission_finished:
            return self._hold_setpoint()
        item = self.mission[self.current]
        if item.command == MAV_CMD_DO_CHANGE_SPEED:
            self.set_cruise(item.param2)
            self._advance(self.current)
            return self._hold_setpoint()
        if item.command == MAV_CMD_NAV_RETURN_TO_LAUNCH:
            self._advance(self.current)
            self.set_mode((MAIN_AUTO, SUB_AUTO_RTL), estimate)
            return self._hold_setpoint()
        if self.landed and item.command != MAV_CMD_NAV_LAND:
            # PX4 inserts a takeoff when a mission starts on the ground.
            self._target_alt_m = max(self.params["MIS_TAKEOFF_ALT"], item.altitude_m)
            self.landed = False
            self._hold = (estimate.north_m, estimate.east_m, estimate.down_m)
            self.events.append(("in_air", None))
        if item.command == MAV_CMD_NAV_DELAY:
            if self._phase != "wait":
                self._phase, self._wait_until_s = "wait", now_s + max(0.0, item.param1)
            if now_s >= self._wait_until_s:
                self._advance(self.current)
            return self._hold_setpoint()
        if item.command == MAV_CMD_NAV_TAKEOFF:
            target = item.altitude_m
            n, e, _ = self._hold
            if self._altitude(estimate) >= target - VERTICAL_ACCEPTANCE_M:
                self._hold = (n, e, self._down_for(target))
                self._advance(self.current)
            return Setpoint(north_m=n, east_m=e, down_m=self._down_for(target), v_down_m_s=0.0, yaw_rad=self._yaw_sp)
        if item.command == MAV_CMD_NAV_WAYPOINT:
            if self._phase == "wait":  # PX4's hold time at a reached waypoint (param1, seconds)
                if now_s >= self._wait_until_s:
                    self._advance(self.current)
                return self._hold_setpoint()
            if self._altitude(estimate) < min(item.altitude_m, self._target_alt_m) - VERTICAL_ACCEPTANCE_M and self._phase != "cruise":
                n, e, _ = self._hold
                return Setpoint(north_m=n, east_m=e, down_m=self._down_for(max(item.altitude_m, self._target_alt_m)), yaw_rad=self._yaw_sp)
            self._phase = "cruise"
            sp, distance = self._fly_to(estimate, item.north_m, item.east_m, item.altitude_m)
            radius = (item.param2 if item.param2 > 0 else self.params["NAV_ACC_RAD"]) * (10.0 if self.params.fault == "acceptance_radius_10x" else 1.0)
            if distance <= radius and abs(self._altitude(estimate) - item.altitude_m) <= VERTICAL_ACCEPTANCE_M:
                self._hold = (item.north_m, item.east_m, self._down_for(item.altitude_m))
                if item.param1 > 0:
                    self._phase, self._wait_until_s = "wait", now_s + item.param1
                    return self._hold_setpoint()
                self._advance(self.current)
            return sp
        if item.command == MAV_CMD_NAV_LAND:
            if self.landed:
                self._advance(self.current)
                return Setpoint(idle=True)
            if item.has_position and self._phase != "descend":
                sp, distance = self._fly_to(estimate, item.north_m, item.east_m, self._altitude(estimate))
                if distance > self.params["NAV_ACC_RAD"] / 2:
                    return sp
                self._phase = "descend"
                self._hold = (item.north_m, item.east_m, estimate.down_m)
            n, e, _ = self._hold
            sp = self._land(now_s, estimate, lift, n, e)
            if self.landed:
                self._advance(self.current)
                return Setpoint(idle=True)
            return sp
        self.events.append(("statustext", f"Unsupported mission item {item.command}, skipped"))
        self._advance(self.current)
        return self._hold_setpoint()

    def _rtl(self, now_s: float, estimate: VehicleEstimate, lift: float) -> Setpoint:
        home_n, home_e, _ = self.home or (0.0, 0.0, 0.0)
        if self._phase == "":
            self._target_alt_m = max(self._altitude(estimate), self.params["RTL_RETURN_ALT"])
            self._phase = "climb"
        if self._phase == "climb":
            n, e, _ = self._hold
            if self._altitude(estimate) >= self._target_alt_m - VERTICAL_ACCEPTANCE_M:
                self._phase = "return"
            return Setpoint(north_m=n, east_m=e, down_m=self._down_for(self._target_alt_m), yaw_rad=self._yaw_sp)
        if self._phase == "return":
            sp, distance = self._fly_to(estimate, home_n, home_e, self._target_alt_m)
            if distance < 1.0:
                self._phase = "descend"
            return sp
        return self._land(now_s, estimate, lift, home_n, home_e)

    def _manual_control_lost(self, now_s: float, estimate: VehicleEstimate) -> None:
        """PX4's manual-control-loss failsafe in Position mode, by NAV_RCL_ACT."""
        action = int(self.params["NAV_RCL_ACT"])
        self.events.append(("statustext", "Manual control lost"))
        target = {1: (MAIN_AUTO, SUB_AUTO_LOITER), 2: (MAIN_AUTO, SUB_AUTO_RTL)}.get(action, (MAIN_AUTO, SUB_AUTO_LAND))
        self.set_mode(target, estimate, now_s)

    def data_link_lost(self, now_s: float, estimate: VehicleEstimate) -> None:
        """PX4's data-link loss failsafe (NAV_DLL_ACT), in flight and not while landing: Hold, or
        Hold for COM_FAIL_ACT_T and then Return or Land; it stays when the link comes back (PX4
        clears it on a mode change or disarm)."""
        action = int(self.params["NAV_DLL_ACT"])
        if not action or not self.armed or self.landed or self.mode == (MAIN_AUTO, SUB_AUTO_LAND):
            return
        target = {1: (MAIN_AUTO, SUB_AUTO_LOITER), 2: (MAIN_AUTO, SUB_AUTO_RTL)}.get(action, (MAIN_AUTO, SUB_AUTO_LAND))
        delay = self.params["COM_FAIL_ACT_T"]
        if target == (MAIN_AUTO, SUB_AUTO_LOITER) or delay <= 0.0:
            self.set_mode(target, estimate, now_s)
            return
        self.set_mode((MAIN_AUTO, SUB_AUTO_LOITER), estimate, now_s)
        self._delayed = (target, now_s + delay)
        self.events.append(("statustext", f"Failsafe activated: entering Hold for {delay:.0f} seconds"))

    def _fall_back(self, now_s: float, estimate: VehicleEstimate, position_valid: bool) -> None:
        """PX4's mode fallback when the horizontal position is lost (failsafe.cpp checkModeFallback
        and the action's fallback chain): every mode here needs a position, so Position mode
        falls back to Altitude mode while manual control lasts, and every other to Descend (Hold,
        Return and Land cannot run either, and the Hold delay COM_FAIL_ACT_T is skipped when Hold
        cannot run). The user's mode comes back once the position does (the fallback clears when
        its condition does)."""
        if position_valid:
            if self.failsafe:
                self.failsafe = ""
                self._enter(estimate)
                self.events.append(("statustext", "Position regained"))
                self.events.append(("mode", MODE_NAMES[self.mode]))
            return
        wanted = "altitude" if self.mode == (MAIN_POSCTL, 0) and self.manual_fresh(now_s) else "descend"
        if wanted != self.failsafe:
            self.failsafe = wanted
            self._land_candidate_s = None
            self.events.append(("statustext", f"Failsafe: no position, switching to {FAILSAFE_MODES[wanted][1]}"))
            self.events.append(("mode", FAILSAFE_MODES[wanted][1]))

    def _descend(self, now_s: float, estimate: VehicleEstimate, lift: float) -> Setpoint:
        """PX4's Descend: down at MPC_LAND_SPEED, level, wherever the wind takes it."""
        if self._detect_landing(now_s, estimate, lift, True):
            self._touch_down(now_s)
            return Setpoint(idle=True)
        return Setpoint(v_down_m_s=self.params["MPC_LAND_SPEED"], yaw_rad=self._yaw_sp, level=True)

    def update(self, now_s: float, estimate: VehicleEstimate, lift: float, position_valid: bool = True) -> Setpoint:
        if self.manual is not None and not self.manual_fresh(now_s):
            # As PX4's manual_control: switch positions seen before the loss count for nothing.
            self._mode_slot = None
            if self.mode == (MAIN_POSCTL, 0) and self.armed:
                self._manual_control_lost(now_s, estimate)
        if not self.armed:
            self.landed = True
            return Setpoint(idle=True)
        self._fall_back(now_s, estimate, position_valid)
        if self._delayed is not None and now_s >= self._delayed[1]:
            target, self._delayed = self._delayed[0], None
            if self.mode == (MAIN_AUTO, SUB_AUTO_LOITER):  # not taken over meanwhile
                self.set_mode(target, estimate, now_s)
        if self.landed:
            delay = self.params["COM_DISARM_LAND"]
            if self._landed_at_s is not None and delay >= 0 and now_s - self._landed_at_s >= delay:
                self.disarm()
                return Setpoint(idle=True)
            if self.failsafe:
                return Setpoint(idle=True)
            if self.mode == (MAIN_AUTO, SUB_AUTO_TAKEOFF):
                self.landed = False
                self.events.append(("in_air", None))
            elif self.mode != (MAIN_AUTO, SUB_AUTO_MISSION) or self.mission_finished:
                return Setpoint(idle=True)
        if self._hold is None:
            self._enter(estimate)
        if self.failsafe == "descend":
            return self._descend(now_s, estimate, lift)
        if self.failsafe == "altitude":
            return Setpoint(manual=True, tilt_from_sticks=True)
        mode = self.mode
        if mode == (MAIN_AUTO, SUB_AUTO_MISSION):
            return self._mission(now_s, estimate, lift)
        if mode == (MAIN_AUTO, SUB_AUTO_TAKEOFF):
            n, e, _ = self._hold
            if self._altitude(estimate) >= self._target_alt_m - VERTICAL_ACCEPTANCE_M and self._phase != "done":
                self._phase = "done"
                self.events.append(("statustext", "Takeoff complete"))
                self.mode = (MAIN_AUTO, SUB_AUTO_LOITER)
                self._hold = (n, e, self._down_for(self._target_alt_m))
                self.events.append(("mode", "Hold"))
            return Setpoint(north_m=n, east_m=e, down_m=self._down_for(self._target_alt_m), yaw_rad=self._yaw_sp)
        if mode == (MAIN_AUTO, SUB_AUTO_LAND):
            n, e, _ = self._hold
            return self._land(now_s, estimate, lift, n, e)
        if mode == (MAIN_AUTO, SUB_AUTO_RTL):
            return self._rtl(now_s, estimate, lift)
        if mode == (MAIN_POSCTL, 0):
            return Setpoint(manual=True)
        return self._hold_setpoint()
