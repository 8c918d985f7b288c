"""The bundled autopilot's parameters, declared once with PX4's names; docs/autopilot_parameters.md is generated from here.

Regenerate the table with `python -m autopilot.params > docs/autopilot_parameters.md`.
"""

from __future__ import annotations

import json
import math
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

MAV_PARAM_TYPE_INT32 = 6
MAV_PARAM_TYPE_REAL32 = 9


@dataclass(frozen=True)
class ParamSpec:
    name: str
    kind: str  # "INT32" or "FLOAT"
    default: float
    min: float
    max: float
    unit: str
    description: str

    @property
    def mav_type(self) -> int:
        return MAV_PARAM_TYPE_INT32 if self.kind == "INT32" else MAV_PARAM_TYPE_REAL32


def _f(name, default, lo, hi, unit, description) -> ParamSpec:
    return ParamSpec(name, "FLOAT", default, lo, hi, unit, description)


def _i(name, default, lo, hi, unit, description) -> ParamSpec:
    return ParamSpec(name, "INT32", default, lo, hi, unit, description)


SPECS: tuple[ParamSpec, ...] = (
    _f("CP_DIST", 1.0, -1.0, 15.0, "m", "Minimum distance the vehicle keeps to sensed obstacles; negative disables collision prevention (the paper's setting: 1 m)."),
    _f("CP_DELAY", 0.4, 0.0, 1.0, "s", "Sensor and estimation delay the stopping distance accounts for."),
    _f("CP_GUIDE_ANG", 30.0, 0.0, 90.0, "deg", "Largest angle by which collision prevention turns a blocked velocity setpoint towards free space."),
    _i("CP_GO_NO_DATA", 1, 0, 1, "", "1: allow moving in directions without range data (outside the sensor's field of view). The bundled sensor looks forward only and missions yaw into the direction of travel, so the default is 1 (PX4's is 0)."),
    _i("CP_STICK_ACCEL", 0, 0, 1, "", "1: in Position mode, collision prevention acts on the sticks' acceleration as PX4's does since v1.15 (autopilot/collision.py: px4_stick_acceleration): slowing down quadratically within MPC_VEL_MANUAL / MPC_XY_P of anything seen, a direction the sensor sees nothing in counting as an obstacle at its reach (in fog, slowly everywhere). 0 (the default): the bundled autopilot's velocity limits, in every mode. Not a PX4 parameter: the screen sets it for a PX4 subject (docs/screening.md)."),
    _f("MPC_XY_CRUISE", 5.0, 0.5, 20.0, "m/s", "Horizontal speed in missions."),
    _f("MPC_XY_VEL_MAX", 12.0, 0.5, 20.0, "m/s", "Largest horizontal velocity setpoint."),
    _f("MPC_Z_VEL_MAX_UP", 3.0, 0.5, 8.0, "m/s", "Largest climb rate."),
    _f("MPC_Z_VEL_MAX_DN", 1.5, 0.5, 4.0, "m/s", "Largest descent rate."),
    _f("MPC_TKO_SPEED", 1.5, 0.5, 5.0, "m/s", "Climb rate during takeoff."),
    _f("MPC_LAND_SPEED", 0.7, 0.3, 3.0, "m/s", "Descent rate during landing."),
    _f("MPC_ACC_HOR", 3.0, 0.5, 10.0, "m/s^2", "Horizontal acceleration for braking and for collision prevention's stopping distance."),
    _f("MPC_JERK_AUTO", 4.0, 1.0, 80.0, "m/s^3", "Jerk limit of automatic braking; collision prevention plans its stops with it."),
    _f("MPC_XY_P", 0.95, 0.0, 2.0, "1/s", "Horizontal position gain."),
    _f("MPC_XY_VEL_P_ACC", 1.8, 0.1, 5.0, "1/s", "Horizontal velocity proportional gain (to acceleration)."),
    _f("MPC_XY_VEL_I_ACC", 0.4, 0.0, 5.0, "1/s^2", "Horizontal velocity integral gain."),
    _f("MPC_XY_VEL_D_ACC", 0.2, 0.0, 2.0, "", "Horizontal velocity derivative gain."),
    _f("MPC_Z_P", 1.0, 0.1, 2.0, "1/s", "Vertical position gain."),
    _f("MPC_Z_VEL_P_ACC", 4.0, 1.0, 15.0, "1/s", "Vertical velocity proportional gain."),
    _f("MPC_Z_VEL_I_ACC", 2.0, 0.0, 3.0, "1/s^2", "Vertical velocity integral gain."),
    _f("MPC_THR_HOVER", 0.42, 0.1, 0.8, "", "Collective thrust that holds a hover."),
    _f("MPC_THR_MIN", 0.08, 0.0, 0.5, "", "Smallest collective thrust in flight."),
    _f("MPC_TILTMAX_AIR", 35.0, 10.0, 60.0, "deg", "Largest tilt in flight."),
    _f("MC_ROLL_P", 6.5, 0.0, 12.0, "1/s", "Roll attitude gain."),
    _f("MC_PITCH_P", 6.5, 0.0, 12.0, "1/s", "Pitch attitude gain."),
    _f("MC_YAW_P", 2.8, 0.0, 5.0, "1/s", "Yaw attitude gain."),
    _f("MC_YAWRATE_MAX", 60.0, 5.0, 360.0, "deg/s", "Largest yaw rate setpoint."),
    _f("MC_ROLLRATE_P", 0.08, 0.0, 0.5, "", "Roll rate proportional gain."),
    _f("MC_ROLLRATE_I", 0.1, 0.0, 1.0, "", "Roll rate integral gain."),
    _f("MC_ROLLRATE_D", 0.001, 0.0, 0.01, "", "Roll rate derivative gain."),
    _f("MC_PITCHRATE_P", 0.08, 0.0, 0.5, "", "Pitch rate proportional gain."),
    _f("MC_PITCHRATE_I", 0.1, 0.0, 1.0, "", "Pitch rate integral gain."),
    _f("MC_PITCHRATE_D", 0.001, 0.0, 0.01, "", "Pitch rate derivative gain."),
    _f("MC_YAWRATE_P", 0.3, 0.0, 1.0, "", "Yaw rate proportional gain."),
    _f("MC_YAWRATE_I", 0.1, 0.0, 1.0, "", "Yaw rate integral gain."),
    _f("NAV_ACC_RAD", 2.0, 0.05, 200.0, "m", "Mission acceptance radius when an item gives none."),
    _f("MIS_TAKEOFF_ALT", 2.5, 0.0, 80.0, "m", "Takeoff altitude when none is given."),
    _f("RTL_RETURN_ALT", 15.0, 0.0, 150.0, "m", "Lowest altitude above home on the way back in return-to-launch."),
    _f("COM_DISARM_LAND", 1.0, -1.0, 20.0, "s", "Disarm this long after landing is detected."),
    _i("COM_DL_LOSS_T", 10, 5, 300, "s", "The ground station's link counts as lost after this long (simulated time) without it, from 2.5 s after its last heartbeat, as PX4 counts it."),
    _i("NAV_DLL_ACT", 0, 0, 6, "", "What a lost ground-station link does, as in PX4: 0 nothing (PX4's default), 1 Hold, 2 Return, 3 Land (5 and 6, terminate and disarm in PX4, land here); not in Land mode."),
    _f("COM_FAIL_ACT_T", 5.0, 0.0, 25.0, "s", "Before a failsafe's Return or Land, Hold this long (PX4's delay for the user to react; 0: none)."),
    _f("EKF2_MAG_DECL", 3.0, -180.0, 180.0, "deg", "Magnetic declination at the flying site (PX4's default home, Zurich: 3 deg)."),
    _i("EKF2_NOAID_TOUT", 5000000, 500000, 10000000, "us", "Dead-reckoning time after the last GPS fix fused before the horizontal position counts as invalid; the position-loss failsafe then descends (Altitude mode in Position mode with RC), as PX4's mode fallback does."),
    _f("MPC_MAN_TILT_MAX", 35.0, 0.0, 90.0, "deg", "Altitude mode (the position-loss fallback from Position mode): tilt at full roll or pitch stick."),
    _i("EKF2_GT_MODE", 0, 0, 1, "", "1: use the simulator's ground truth (HIL_STATE_QUATERNION) instead of estimating; for debugging only."),
    _i("SYS_AUTOSTART", 4001, 0, 9999999, "", "Airframe (4001: generic quadrotor X), reported for tools that read it."),
    _i("SYS_FAILURE_EN", 0, 0, 1, "", "1: accept failure injection (MAV_CMD_INJECT_FAILURE, MAVSDK's failure plugin; what each failure does: simlink/failures.py); 0 refuses it with MAV_RESULT_DENIED, as PX4 does."),
    _i("MAV_SYS_ID", 1, 1, 250, "", "MAVLink system id."),
    _i("COM_RC_IN_MODE", 3, 0, 4, "", "Manual control source, as in PX4: 0 RC only, 1 MAVLink only, 2 or 3 RC or MAVLink, 4 none. The bundled autopilot reads RC (RC_CHANNELS on the simulator link) and has no MAVLink manual control, so 1 and 4 disable manual control."),
    _f("COM_RC_LOSS_T", 0.5, 0.0, 35.0, "s", "Manual control counts as lost this long after the last RC frame."),
    _i("NAV_RCL_ACT", 2, 1, 6, "", "What manual-control loss in Position mode does: 1 Hold, 2 Return, 3 Land (5 and 6, terminate and disarm in PX4, land here: the bundled autopilot never cuts its motors in flight)."),
    _i("RC_CHAN_CNT", 0, 0, 18, "", "RC channels calibrated; 0 (PX4's default) leaves the RC unused, as an uncalibrated RC in PX4."),
    _i("RC_MAP_ROLL", 0, 0, 18, "", "RC channel of the roll stick (0: none)."),
    _i("RC_MAP_PITCH", 0, 0, 18, "", "RC channel of the pitch stick (0: none)."),
    _i("RC_MAP_YAW", 0, 0, 18, "", "RC channel of the yaw stick (0: none)."),
    _i("RC_MAP_THROTTLE", 0, 0, 18, "", "RC channel of the throttle stick (0: none)."),
    _i("RC_MAP_FLTMODE", 0, 0, 18, "", "RC channel of the six-position flight-mode switch (0: none)."),
    *(
        spec
        for n in range(1, 9)
        for spec in (
            _f(f"RC{n}_MIN", 1000.0, 800.0, 1500.0, "us", f"RC channel {n}: lowest value."),
            _f(f"RC{n}_TRIM", 1500.0, 800.0, 2200.0, "us", f"RC channel {n}: centre value."),
            _f(f"RC{n}_MAX", 2000.0, 1500.0, 2200.0, "us", f"RC channel {n}: highest value."),
            _f(f"RC{n}_REV", 1.0, -1.0, 1.0, "", f"RC channel {n}: -1 reverses it."),
            _f(f"RC{n}_DZ", 10.0, 0.0, 100.0, "us", f"RC channel {n}: dead zone around the trim."),
        )
    ),
    *(
        _i(f"COM_FLTMODE{n}", -1, -1, 11, "", f"Flight mode of mode slot {n} (PX4's values: 2 Position, 3 Mission, 4 Hold, 5 Return, 10 Takeoff, 11 Land; -1 none)")
        for n in range(1, 7)
    ),
    _f("MPC_VEL_MANUAL", 10.0, 1.0, 20.0, "m/s", "Position mode: horizontal speed at full stick."),
    _f("MPC_JERK_MAX", 8.0, 0.5, 500.0, "m/s^3", "Position mode: jerk limit of the stick-commanded acceleration."),
    _f("MPC_HOLD_DZ", 0.1, 0.0, 1.0, "", "Position mode: stick dead zone; within it the vehicle brakes and holds position and altitude."),
    _f("MPC_XY_MAN_EXPO", 0.6, 0.0, 1.0, "", "Position mode: expo of the roll and pitch sticks (0 linear, 1 cubic)."),
    _f("MPC_Z_MAN_EXPO", 0.6, 0.0, 1.0, "", "Position mode: expo of the throttle stick."),
    _f("MPC_YAW_EXPO", 0.6, 0.0, 1.0, "", "Position mode: expo of the yaw stick."),
    _f("MPC_MAN_Y_MAX", 150.0, 0.0, 400.0, "deg/s", "Position mode: yaw rate at full yaw stick."),
)

BY_NAME = {spec.name: spec for spec in SPECS}
# PX4's parameter names (scripts/px4_parameter_names.py writes the file, with the PX4 versions it
# read): a parameter file written for PX4 sets many the bundled autopilot does not model, and
# those are accepted without effect, while a name PX4 does not have either is a typo to refuse.
PX4_NAMES = frozenset(json.loads((Path(__file__).parent / "px4_parameters.json").read_text())["names"])


class ParamError(ValueError):
    """An unknown parameter or a value outside its declared range."""


def without_effect(names: Iterable[str]) -> list[str]:
    """Those of `names` that are PX4 parameters the bundled autopilot accepts without modelling them."""
    return sorted(name for name in names if name not in BY_NAME and name in PX4_NAMES)


class Params:
    """Current values; PX4's parameter protocol encodes INT32 values bytewise in the float field.
    A PX4 parameter the autopilot does not model is kept apart (`unmodelled`): it is not listed
    on the parameter protocol, whose clients would take it for one that works."""

    def __init__(self, overrides: dict[str, float] | None = None, fault: str | None = None):
        from autopilot.faults import BY_NAME as FAULTS

        if fault is not None and fault not in FAULTS:
            raise ParamError(f"unknown fault {fault!r}; known: {', '.join(FAULTS)}")
        self.fault = fault  # the seeded fault switched on (autopilot/faults.py), or None
        self._values = {spec.name: spec.default for spec in SPECS}
        self.unmodelled = {}
        for name, value in (overrides or {}).items():
            self.set(name, value)

    def __getitem__(self, name: str) -> float:
        return self._values[name]

    def set(self, name: str, value: float) -> float:
        spec = BY_NAME.get(name)
        if spec is None and name not in PX4_NAMES:
            raise ParamError(f"unknown parameter {name!r}")
        if not (isinstance(value, (int, float)) and math.isfinite(value)):
            raise ParamError(f"{name}: {value!r} is not a number")
        if spec is None:
            self.unmodelled[name] = value
            return value
        if not spec.min <= value <= spec.max:
            raise ParamError(f"{name}: {float(value)} outside [{spec.min}, {spec.max}] {spec.unit}")
        self._values[name] = int(value) if spec.kind == "INT32" else float(value)
        return self._values[name]

    def names(self) -> list[str]:
        return [spec.name for spec in SPECS]

    def wire_value(self, name: str) -> float:
        value = self._values[name]
        if BY_NAME[name].kind == "INT32":
            return struct.unpack("<f", struct.pack("<i", int(value)))[0]
        return float(value)

    def from_wire(self, name: str, raw: float, mav_type: int) -> float:
        if BY_NAME.get(name) is not None and BY_NAME[name].kind == "INT32" and mav_type == MAV_PARAM_TYPE_INT32:
            return struct.unpack("<i", struct.pack("<f", raw))[0]
        return raw

    @classmethod
    def from_file(cls, path: Path, fault: str | None = None) -> "Params":
        """A JSON object of NAME: value overrides."""
        return cls(json.loads(Path(path).read_text()), fault)
