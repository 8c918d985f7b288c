"""ArduPilot's ArduCopter SITL as a SUT, its physics from our bridge through its JSON backend.

Give the `arducopter` binary or its build folder (`build/sitl`, or the source tree holding it)
with `--ardupilot-bin` or STELLA_ARDUPILOT_BIN. Each evaluation gets a fresh working directory
(ArduPilot keeps eeprom.bin, its dataflash logs/*.BIN and terrain there) and instance k = the
port block's index. Its ports are the block's: it sends its servo frames to the simulator port
(UDP, `--sim-port-out`), its MAVLink (SERIAL0) goes to the API port as a UDP client, and its
RC input listens on the RC port (UDP) where the simulated pilot's sticks arrive.

ArduPilot's scheduler and MAVLink run on the simulated clock its physics backend advances, so
it answers nothing while simulated time stands still: it needs the "paced" hold. It starts at
the world's origin (`--home`), where the bridge's positions are measured from.
"""

from __future__ import annotations

import os
import signal
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

from sim_bridge.ardupilot_json import RANGEFINDER_ORIENTATION, rangefinders_in_view
from sut_adapter.ardupilot_failures import SUT_FAILURE_UNITS, failure_params
from sut_adapter.base import Capabilities, SutError, SutHandle, start_process
from sut_adapter.coverage import coverage_build, fastcov_record, gcov_environment
from sut_adapter.processes import ManagedProcess, non_empty

if TYPE_CHECKING:
    from sim_bridge.spec import WorldSpec

PARAMS_FILE = "stella.parm"
# As many times faster than real time as its set-up may run: ArduPilot's own timeouts are in
# simulated time, MAVSDK's in wall time, and a paced hold this fast still leaves MAVSDK's
# requests their answers in time (measured: docs/suts.md).
HOLD_PACE = 20.0
# Without waiting for the wall clock: lockstep sets its pace.
SPEEDUP = 10000
# RC input (ArduPilot's AP_RCProtocol_UDP) on its own port per port block.
RC_PORT_BASE = 34560
# A rig's messages reach its MAVLink proximity backend on SERIAL1, which sends from a port of its
# own to this one per port block (harness/flight/ports.py: at most 200 blocks above RC's).
COMPANION_PORT_BASE = 34760
# Why each: docs/suts.md, "ArduPilot". Keys are ArduPilot's parameter names.
DEFAULT_PARAMS: dict[str, float] = {
    # The F450: a quad in X, motors on outputs 1-4 in ArduCopter's order (sim_bridge/ardupilot_json.py).
    "FRAME_CLASS": 1, "FRAME_TYPE": 1,
    # The transmitter's range as the simulated pilot sends it.
    **{f"RC{n}_{field}": value for n in range(1, 9) for field, value in (("MIN", 1000), ("MAX", 2000), ("TRIM", 1500))},
    # No battery is simulated through the JSON backend.
    "BATT_MONITOR": 0,
    # The mission drive arms and then switches to Auto over MAVLink: no disarm in between, and a
    # take-off in Auto without a throttle stick (bit 1; bit 0: arming in Auto).
    "DISARM_DELAY": 0, "AUTO_OPTIONS": 3,
    # The harness's API link (SERIAL0): positions and status often enough for MAVSDK's telemetry
    # and the log. ArduPilot 4.7 calls these MAV1_*, earlier releases SR0_*; a defaults file's
    # unknown names are ignored (it says so on its console).
    **{f"{prefix}_{stream}": rate for prefix in ("MAV1", "SR0")
       for stream, rate in (("POSITION", 10), ("EXT_STAT", 5), ("EXTRA1", 10), ("EXTRA2", 5), ("EXTRA3", 5), ("RAW_SENS", 2))},
    # SITL's other serial ports would listen on TCP ports no evaluation owns.
    "SERIAL1_PROTOCOL": -1, "SERIAL2_PROTOCOL": -1,
    # The range sensor as six SITL rangefinders, one orientation each, read as proximity.
    **{key: value for n, orientation in enumerate(RANGEFINDER_ORIENTATION, start=1)
       for key, value in ((f"RNGFND{n}_TYPE", 100), (f"RNGFND{n}_ORIENT", orientation), (f"RNGFND{n}_MIN", 0.1))},
    "PRX1_TYPE": 4,
    # The compass heading's noise as the EKF weighs it while it fuses heading alone: on the ground
    # and in the climb until its in-flight yaw alignment (3-axis fusion with EK3_MAG_M_NSE after
    # it). At the default 0.5 rad its yaw gyro bias takes 37 s of simulated time to learn, and it
    # uses no GPS, so it cannot arm, until then; at 0.2 rad (11 degrees, still far more than the
    # SITL compass's error, SIM_MAG_RND 0) it has learned it when its AHRS settles, 20 s after
    # its EKF started, the earliest ArduCopter arms (docs/suts.md, "Set-up time").
    "EK3_YAW_M_NSE": 0.2,
    # Simple avoidance's margin as PX4's CP_DIST: the paper's 1 m safety distance.
    "AVOID_MARGIN": 1.0,
    # The simulated pilot's mode slots (sim_bridge/pilot.py: 1 hold, 2 position, 3 land) on
    # ArduPilot's mode switch: Stabilize, its mode at boot (the take-off itself is MAVSDK's, in
    # Guided), Loiter, where simple avoidance acts on the sticks, and Land.
    "FLTMODE1": 0, "FLTMODE2": 5, "FLTMODE3": 9,
}


# ArduCopter's own defaults (4.7, read from its source) of the parameters that have a counterpart
# in the bundled autopilot: what the subject flies with where neither the adapter nor the user
# sets them. Speeds and accelerations in cm/s and cm/s^2, angles in centidegrees, as ArduPilot has them.
ARDUCOPTER_DEFAULTS: dict[str, float] = {
    "AVOID_ENABLE": 3, "AVOID_MARGIN": 2.0, "AVOID_BEHAVE": 0, "OA_TYPE": 0, "OA_MARGIN_MAX": 5.0,
    "LOIT_SPEED": 1250, "LOIT_ACC_MAX": 500, "WPNAV_SPEED": 1000, "WPNAV_ACCEL": 250, "WPNAV_SPEED_UP": 250, "WPNAV_SPEED_DN": 150,
    "WPNAV_RADIUS": 200, "ANGLE_MAX": 3000, "LAND_SPEED": 50, "RTL_ALT": 1500, "FS_GCS_ENABLE": 0, "FS_GCS_TIMEOUT": 5,
}
AVOID_USE_PROXIMITY = 2  # AVOID_ENABLE's bit for proximity sensors
# FS_GCS_ENABLE's actions as PX4's NAV_DLL_ACT: RTL (and SmartRTL, Auto-RTL) as Return, Land as Land, Brake as Hold.
GCS_FAILSAFE_AS_NAV_DLL_ACT = {0: 0, 1: 2, 2: 2, 3: 2, 4: 3, 5: 3, 6: 2, 7: 1}


def bundled_equivalent(params: Mapping[str, float], drive: str) -> dict[str, float]:
    """The PX4 parameters that make the bundled autopilot fly as ArduCopter would with `params`
    (over the adapter's defaults and ArduCopter's), where it has a counterpart: the screen's cheap
    model of an ArduPilot subject (harness/campaigns/screen.py).

    Simple avoidance acts on the pilot's sticks in Loiter and not in Auto, where only the path
    planner (OA_TYPE) steers round obstacles: in the mission drive the cheap model has collision
    prevention only with a path planner, keeping its largest margin. Avoidance that stops
    (AVOID_BEHAVE 1) rather than slides has no guidance towards free space. The GCS failsafe's
    timeout counts from the last heartbeat, the bundled autopilot's (as PX4's) from 2.5 s after
    it, and acts at once."""
    given = {**ARDUCOPTER_DEFAULTS, **DEFAULT_PARAMS, **params}
    proximity = int(given["AVOID_ENABLE"]) & AVOID_USE_PROXIMITY
    if drive == "pilot":
        keeps = given["AVOID_MARGIN"] if proximity else -1.0
    else:
        keeps = given["OA_MARGIN_MAX"] if int(given["OA_TYPE"]) else -1.0
    loss_action = GCS_FAILSAFE_AS_NAV_DLL_ACT.get(int(given["FS_GCS_ENABLE"]), 2)
    return {
        "CP_DIST": keeps,
        **({"CP_GUIDE_ANG": 0.0} if drive == "pilot" and int(given["AVOID_BEHAVE"]) == 1 else {}),
        "MPC_VEL_MANUAL": given["LOIT_SPEED"] / 100.0,
        "MPC_ACC_HOR": (given["LOIT_ACC_MAX"] if drive == "pilot" else given["WPNAV_ACCEL"]) / 100.0,
        "MPC_XY_CRUISE": given["WPNAV_SPEED"] / 100.0,
        "MPC_Z_VEL_MAX_UP": given["WPNAV_SPEED_UP"] / 100.0,
        "MPC_Z_VEL_MAX_DN": given["WPNAV_SPEED_DN"] / 100.0,
        "NAV_ACC_RAD": given["WPNAV_RADIUS"] / 100.0,
        "MPC_TILTMAX_AIR": given["ANGLE_MAX"] / 100.0,
        "MPC_LAND_SPEED": given["LAND_SPEED"] / 100.0,
        "RTL_RETURN_ALT": given["RTL_ALT"] / 100.0,
        "NAV_DLL_ACT": loss_action,
        **({"COM_DL_LOSS_T": max(5, round(given["FS_GCS_TIMEOUT"] - 2.5)), "COM_FAIL_ACT_T": 0.0} if loss_action else {}),
    }


def resolve_binary(given: str | None) -> Path:
    """The arducopter binary from a binary, a build folder (build/sitl) or a source tree, or
    STELLA_ARDUPILOT_BIN's where none is given."""
    given = given or os.environ.get("STELLA_ARDUPILOT_BIN")
    if not given:
        raise SutError("ardupilot", "no ArduCopter SITL build given; pass --ardupilot-bin PATH (the arducopter binary or its build folder, "
                                    "e.g. ardupilot/build/sitl) or set STELLA_ARDUPILOT_BIN")
    path = Path(given).expanduser().resolve()
    candidates = [path] if not path.is_dir() else [path / "bin" / "arducopter", path / "build" / "sitl" / "bin" / "arducopter"]
    for binary in candidates:
        if binary.is_file() and os.access(binary, os.X_OK):
            return binary
    raise SutError("ardupilot", f"no executable arducopter at {' or '.join(map(str, candidates))}; build it with `./waf configure --board sitl && "
                                "./waf copter` and pass build/sitl (docs/suts.md)")


def rc_port_for(instance: int) -> int:
    """The UDP port ArduPilot takes RC input on in this port block."""
    return RC_PORT_BASE + instance


def companion_port_for(instance: int) -> int:
    """The UDP port its SERIAL1 sends to in this port block: the companion computer's."""
    return COMPANION_PORT_BASE + instance


def rig_sensor_problem(sensor: Mapping[str, Any]) -> str | None:
    """What ArduPilot's MAVLink proximity backend (AP_Proximity_MAV) cannot read of a rig's sensor."""
    if sensor["message"] == "DISTANCE_SENSOR" and not (float(sensor.get("yaw_deg", 0.0)) / 45.0).is_integer():
        return ("ArduPilot reads a rangefinder's direction only as one of eight yaws 45 degrees apart (MAV_SENSOR_ROTATION_NONE to "
                "YAW_315) and drops its readings otherwise; give yaw_deg a multiple of 45")
    if sensor["message"] == "OBSTACLE_DISTANCE" and sensor.get("frame", "body") != "body":
        return "ArduPilot reads OBSTACLE_DISTANCE's sectors from the nose whatever its frame says; give it frame body"
    return None


def format_params(params: Mapping[str, float]) -> str:
    """A .parm file ArduPilot reads with --defaults: NAME VALUE per line."""
    return "".join(f"{name} {float(value):.9g}\n" for name, value in params.items())


class ArduPilotSitl:
    name = "ardupilot"
    capabilities = Capabilities(
        hold_mode="paced",
        hold_pace=HOLD_PACE,
        # The range sensor reaches it as rangefinders in the JSON state, not as MAVLink.
        range_messages=(),
        sim_protocol="ardupilot-json",
        # ArduPilot's SITL IMU samples at the physics rate, and its pre-arm check wants the gyro at
        # 1.8 times ArduCopter's 400 Hz loop at least ("Gyro 0 rate 253Hz < loop ratex1.8 720Hz",
        # "Main loop slow (250Hz < 400Hz)" at our 250 Hz).
        rate_hz=800.0,
        # start() takes the world it flies in: ArduPilot starts at its origin, with rangefinders of its sensor's reach.
        needs_world=True,
        # MISSION_ITEM_INT 0 is home to ArduPilot: the harness puts the start there.
        mission_home_item=True,
        rc_port_for=rc_port_for,
        # The pilot drive: its RC layout is in the defaults above; its take-off altitude goes with
        # MAVSDK's take-off command, as ArduPilot has no parameter for it; MAVSDK calls ArduCopter's
        # Loiter "Hold".
        pilot_params={},
        takeoff_altitude_param=None,
        pilot_flight_mode="HOLD",
        # ArduPilot has no MAV_CMD_INJECT_FAILURE: its SITL fails its sensors through SIM_* parameters,
        # set at the failure's onset (sut_adapter/ardupilot_failures.py); a failure without one is
        # refused. Its GPS is its own (the JSON backend carries none), so GPS failures go to it too.
        injects_failures=False,
        failure_params=failure_params,
        sut_failure_units=SUT_FAILURE_UNITS,
        # A rig reaches its MAVLink proximity backend (PRX1_TYPE 2) on SERIAL1 as a companion
        # computer's messages; its JSON rangefinders are then off (world_params).
        rig_messages=("DISTANCE_SENSOR", "OBSTACLE_DISTANCE"),
        companion_messages=("DISTANCE_SENSOR", "OBSTACLE_DISTANCE"),
        companion_port_for=companion_port_for,
        companion_connects=True,
        distance_sensor_convention="ardupilot",
        rig_sensor_problem=rig_sensor_problem,
    )

    def __init__(self, config: Mapping[str, str]):
        unknown = sorted(set(config) - {"ardupilot_bin"})
        if unknown:
            raise SutError(self.name, f"unknown configuration {unknown}; it takes ardupilot_bin (--ardupilot-bin)")
        self.binary = resolve_binary(config.get("ardupilot_bin"))

    def check_params(self, params: Mapping[str, float]) -> None:
        """Its parameters are known only to the running SUT, which reports a bad one when set."""

    def command(self, *, sim_port: int, api_port: int, instance: int, workdir: Path, origin: tuple[float, float, float],
                rigged: bool = False) -> list[str]:
        lat_deg, lon_deg, ground_msl_m = origin
        rc_port = rc_port_for(instance)
        return [str(self.binary), "--model", "JSON:127.0.0.1", "--instance", str(instance), "--sim-port-out", str(sim_port),
                "--rc-in-port", str(rc_port), "--serial0", f"udpclient:127.0.0.1:{api_port}",
                *(["--serial1", f"udpclient:127.0.0.1:{companion_port_for(instance)}"] if rigged else []),
                "--home", f"{lat_deg:.8f},{lon_deg:.8f},{ground_msl_m:.2f},0", "--speedup", str(SPEEDUP), "--defaults", str(workdir / PARAMS_FILE)]

    def start(self, *, sim_port: int, api_port: int, instance: int, workdir: Path, params: Mapping[str, float], spin_s: float = 0.0,
              world: "WorldSpec") -> SutHandle:
        ardupilot_dir = workdir / "ardupilot"
        ardupilot_dir.mkdir()
        # The user's parameters go in at boot too: some take effect only then (RNGFNDn_TYPE, OA_TYPE).
        (ardupilot_dir / PARAMS_FILE).write_text(format_params({**DEFAULT_PARAMS, **world_params(world), **params}))
        origin = (world.origin.lat_deg, world.origin.lon_deg, world.start_msl_m)
        argv = self.command(sim_port=sim_port, api_port=api_port, instance=instance, workdir=ardupilot_dir, origin=origin, rigged=bool(world.rig))
        # Its SIGTERM handler only sets a flag its scheduler reads, on the clock our steps advance:
        # once the flight or the harness is gone nothing reads it (2 s lost at each stop, an
        # arducopter left after kill -9 of a campaign). Its dataflash log is written as it goes.
        # A coverage build's counters are written only by exit(): the library it preloads exits
        # on SIGUSR1 (sut_adapter/gcov_exit.c).
        folder = self.binary.parent.parent
        measured = coverage_build(folder)
        env = None if measured is None else {**os.environ, **gcov_environment(measured, workdir), "LD_PRELOAD": measured["preload"]}
        process = ManagedProcess("arducopter", argv, log_dir=workdir, cwd=ardupilot_dir, env=env,
                                 end_signal=signal.SIGKILL if measured is None else signal.SIGUSR1)
        return start_process(self.name, process, artifacts=lambda: collect_artifacts(ardupilot_dir, [process.stdout_path, process.stderr_path]),
                             mavlink_params=dict(params), **({} if measured is None else {"coverage": lambda: fastcov_record(measured, folder, workdir)}))


def world_params(world: "WorldSpec") -> dict[str, float]:
    """What ArduPilot must know of the world: its rangefinders reach as far as the range sensor
    (our reading beyond it is "out of range high"), and there are none where the sensor sees
    nothing (one without data fails ArduPilot's pre-arm check). With a rig there are none at all:
    the rig's messages reach the MAVLink proximity backend on SERIAL1."""
    if world.rig:
        return {**{f"RNGFND{n}_TYPE": 0 for n in range(1, len(RANGEFINDER_ORIENTATION) + 1)}, "PRX1_TYPE": 2, "SERIAL1_PROTOCOL": 2}
    params: dict[str, float] = {}
    for n, in_view in enumerate(rangefinders_in_view(world.sensor.fov_deg), start=1):
        params[f"RNGFND{n}_MAX"] = float(world.sensor.range_m)
        if not in_view:
            params[f"RNGFND{n}_TYPE"] = 0
    return params


def collect_artifacts(ardupilot_dir: Path, console_logs: list[Path]) -> list[Path]:
    """ArduPilot's dataflash logs (logs/*.BIN) and its non-empty console output."""
    return sorted(ardupilot_dir.glob("logs/*.BIN")) + non_empty(console_logs)
