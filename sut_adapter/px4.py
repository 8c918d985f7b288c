"""PX4 SITL as a SUT, flying against our bridge as its external simulator.

Give the `px4` binary or its build folder (`build/px4_sitl_default`) with `--px4-bin` or
STELLA_PX4_BIN. Each evaluation gets a fresh working directory (PX4 writes parameters.bson,
dataman and log/ there) and PX4 instance k = the port block's index, so PX4's own port rules
give simulator TCP 4560+k and API UDP 14540+k, the block's ports. The airframe is 10016
(`none_iris`: a quadrotor that waits for an external simulator on the simulator link).

PX4's threads follow its lockstep clock, so it cannot answer MAVLink while simulated time
stands still: it needs the "paced" hold. Its collision prevention reads the distance_sensor
topic, which the bridge feeds through DISTANCE_SENSOR messages on the simulator link, and the
obstacle_distance topic, which PX4 makes of OBSTACLE_DISTANCE from a companion computer: a rig's
OBSTACLE_DISTANCE source goes to its onboard payload link (UDP 14280+k); it acts
only in Position mode, never in missions, so in a mission PX4 flies into what is in its way
and the harness measures exactly that.
"""

from __future__ import annotations

import os
import shlex
from dataclasses import replace
from pathlib import Path
from typing import Mapping

from sut_adapter.base import Capabilities, SutError, SutHandle, start_process
from sut_adapter.coverage import coverage_build, gcov_environment, gcov_record
from sut_adapter.processes import ManagedProcess, non_empty, printed

AIRFRAME = "10016"
MODEL = "none_iris"
# PX4 maps instances above 9 onto one shared API port (ROMFS px4-rc.mavlink).
MAX_INSTANCE = 9
# Set at its start (ENV_PARAM_PREFIX), or over MAVLink before the flight by a PX4 too old for
# that. CP_DIST as the paper's setting. COM_DL_LOSS_T as PX4 documents it (10 s), not the 200 s
# its start-up script stretches it to for SPEED_FACTOR: the API tap sends the ground station's
# heartbeat once per second of PX4's own time (harness/flight/api_tap.py), so a lost data link
# is one a scenario made, and PX4 answers it after the documented time.
DEFAULT_PARAMS: dict[str, int | float] = {"CP_DIST": 1.0, "COM_DL_LOSS_T": 10}
# Every instance is system 1, as a single vehicle is, whichever port block it flies in: PX4's
# start-up makes instance k system k + 1, and code that addresses system 1 (collision
# prevention's switch to Loiter on stale range data, `_publishVehicleCmdDoLoiter`) then works
# on instance 0 only (2026-11-29: 428 of 526 flights of instance 0 switched, 0 of 536 of
# instances 1-4), so a flight's outcome depended on its slot. Set at start only: over MAVLink it
# would change the system id under the harness's connection.
ONE_SYSTEM = {"MAV_SYS_ID": 1}
# PX4 stretches its link-loss and preflight-disarm timeouts by this factor (ROMFS rcS), so its
# paced hold can run this many times faster than real time: it reaches its first heartbeat (1 s
# of its time after its MAVLink starts) and health in a twentieth of the wall time.
SPEED_FACTOR = 20
# PX4's API link (MAVLink's "onboard" mode, ROMFS px4-rc.mavlink) streams about 470 messages per
# simulated second, many times that per wall-clock second in lockstep; the harness relays and
# records each and MAVSDK parses each, which cost as much CPU as PX4's own (docs/benchmarks.md).
# The harness needs status, health and mission progress from that link, whose streams stay as
# PX4 sends them (about 1 Hz). Of the rest, PX4's view of the flight for a log viewer: its
# estimate and the ranges it relayed at 4 Hz, its setpoints, outputs and GPS at 2 Hz, and the
# other forms of its estimate at 1 Hz (its ULog has everything at full rate). About 75 messages
# per simulated second instead of 210 at 10 Hz: 13 % more PX4 evaluations per hour with two
# workers on two cores.
API_STREAM_RATES_HZ = {"DISTANCE_SENSOR": 4, "ATTITUDE": 4, "LOCAL_POSITION_NED": 4, "GLOBAL_POSITION_INT": 4,
                       "POSITION_TARGET_LOCAL_NED": 2, "POSITION_TARGET_GLOBAL_INT": 2, "ATTITUDE_TARGET": 2, "SERVO_OUTPUT_RAW_0": 2,
                       "GPS_RAW_INT": 2, "ALTITUDE": 2, "VFR_HUD": 2, "TIMESYNC": 2,
                       "ATTITUDE_QUATERNION": 1, "HIGHRES_IMU": 1, "ODOMETRY": 1}
# The script PX4's rcS sources to start its MAVLink instances, found first on PATH.
MAVLINK_SCRIPT = "px4-rc.mavlink"
# What PX4 prints once its rcS has returned, whatever it returned (INFO or ERROR). PX4's MAVLink drops parameter
# messages unanswered until `mavlink boot_complete`, near the end of rcS; its API link sends
# heartbeats from the start of px4-rc.mavlink, and the simulated clock runs ahead of rcS, so the
# harness can find PX4 and reach its hold in between: its first PARAM_SET went unanswered and
# MAVSDK sent it again only after its 0.5 s timeout.
STARTED_UP = "[px4] Startup script returned"
# PX4's rcS (since 2023-09) sets PX4_PARAM_{name}={value} from its environment before it starts
# its modules, so each reads the value from its start, without a MAVLink round trip.
ENV_PARAM_PREFIX = "PX4_PARAM_"


def companion_port_for(instance: int) -> int:
    """The UDP port of instance k's onboard payload link (px4-rc.mavlink: udp_onboard_payload_port_local),
    a MAVLink instance in onboard mode that takes a companion computer's messages."""
    return 14280 + instance


def resolve_binary(given: str | None) -> tuple[Path, Path]:
    """(px4 binary, its etc/ folder with the init scripts) from a binary or build folder path,
    or STELLA_PX4_BIN's where none is given."""
    given = given or os.environ.get("STELLA_PX4_BIN")
    if not given:
        raise SutError("px4", "no PX4 build given; pass --px4-bin PATH (the px4 binary or its build folder, e.g. PX4-Autopilot/build/px4_sitl_default) or set STELLA_PX4_BIN")
    path = Path(given).expanduser().resolve()
    binary = path / "bin" / "px4" if path.is_dir() else path
    if not binary.is_file() or not os.access(binary, os.X_OK):
        raise SutError("px4", f"{binary} is not an executable px4 binary; pass the build folder (with bin/px4) or the binary itself")
    etc = binary.parent.parent / "etc"
    if not (etc / "init.d-posix" / "rcS").is_file():
        raise SutError("px4", f"{etc}/init.d-posix/rcS not found: the binary must sit in a PX4 SITL build folder (bin/px4 beside etc/)")
    return binary, etc


def api_stream_script(etc: Path, instance: int) -> str:
    """PX4's own MAVLink start-up, then its API link's high-rate streams at API_STREAM_RATES_HZ:
    PX4's rcS sources this instead of its own px4-rc.mavlink (PX4 puts its bin/ first on PATH,
    its init.d-posix/ last, so a folder between them comes first), and this sources PX4's."""
    own = etc / "init.d-posix" / MAVLINK_SCRIPT
    api_port_local = 14580 + instance  # its API link's own UDP port (px4-rc.mavlink: udp_offboard_port_local)
    return "\n".join(["# Written by stella (sut_adapter/px4.py) for PX4's rcS.", f". {shlex.quote(str(own))}",
                      *(f"mavlink stream -u {api_port_local} -s {name} -r {rate}" for name, rate in API_STREAM_RATES_HZ.items()), ""])


def takes_params_from_environment(etc: Path) -> bool:
    """Whether this build's start-up script sets parameters from ENV_PARAM_PREFIX variables."""
    return ENV_PARAM_PREFIX in (etc / "init.d-posix" / "rcS").read_text(errors="replace")


class Px4Sitl:
    name = "px4"
    capabilities = Capabilities(hold_mode="paced", hold_pace=float(SPEED_FACTOR), range_messages=("DISTANCE_SENSOR",), rig_messages=("DISTANCE_SENSOR", "OBSTACLE_DISTANCE"),
                                companion_messages=("OBSTACLE_DISTANCE",), companion_port_for=companion_port_for,
                                # SimulatorMavlink publishes distance_sensor instances for the first ORB_MULTI_MAX_INSTANCES ids
                                distance_sensor_limit=10, instance_count=MAX_INSTANCE + 1,
                                echoes_step_time=True)

    def __init__(self, config: Mapping[str, str]):
        unknown = sorted(set(config) - {"px4_bin"})
        if unknown:
            raise SutError(self.name, f"unknown configuration {unknown}; it takes px4_bin (--px4-bin)")
        self.binary, self.etc = resolve_binary(config.get("px4_bin"))
        self.capabilities = replace(Px4Sitl.capabilities, params_at_start=takes_params_from_environment(self.etc))

    def command(self, *, instance: int, workdir: Path, params: Mapping[str, float] | None = None) -> tuple[list[str], dict[str, str]]:
        """PX4's command line and environment for an instance in workdir (where it writes a script
        of its own for PX4's rcS, found on PATH before PX4's: api_stream_script), with params
        set by its start-up (ENV_PARAM_PREFIX)."""
        if not 0 <= instance <= MAX_INSTANCE:
            raise SutError(self.name, f"instance {instance} is out of range: PX4 gives instances above {MAX_INSTANCE} one shared API port; run at most {MAX_INSTANCE + 1} PX4 evaluations at once")
        scripts = workdir / "stella-rc"
        scripts.mkdir(parents=True, exist_ok=True)
        (scripts / MAVLINK_SCRIPT).write_text(api_stream_script(self.etc, instance))
        env = {**os.environ, "PX4_SYS_AUTOSTART": AIRFRAME, "PX4_SIM_MODEL": MODEL, "PX4_SIM_SPEED_FACTOR": str(SPEED_FACTOR),
               "PATH": os.pathsep.join([str(scripts), os.environ.get("PATH", os.defpath)]),
               **{f"{ENV_PARAM_PREFIX}{name}": str(value) for name, value in (params or {}).items()}}
        return [str(self.binary), "-i", str(instance), "-d", "-w", str(workdir), str(self.etc)], env

    def check_params(self, params: Mapping[str, float]) -> None:
        """Its parameters are known only to the running SUT, which reports a bad one when set."""

    def start(self, *, sim_port: int, api_port: int, instance: int, workdir: Path, params: Mapping[str, float],
              spin_s: float = 0.0, flight_params: Mapping[str, float] | None = None) -> SutHandle:
        """PX4 with its DEFAULT_PARAMS, the flight's and the user's params set by its start-up
        where it can; the user's go over MAVLink as well, where PX4 refuses a name it does not
        have (its rcS passes over one)."""
        if (sim_port, api_port) != (4560 + instance, 14540 + instance):
            raise SutError(self.name, f"PX4 instance {instance} uses simulator port {4560 + instance} and API port {14540 + instance}, not {sim_port} and {api_port}")
        px4_dir = workdir / "px4"
        px4_dir.mkdir()
        at_start = {**DEFAULT_PARAMS, **ONE_SYSTEM, **(flight_params or {}), **params} if self.capabilities.params_at_start else {}
        argv, env = self.command(instance=instance, workdir=px4_dir, params=at_start)
        folder = self.binary.parent.parent
        measured = coverage_build(folder)
        if measured is not None:
            env.update(gcov_environment(measured, workdir))
        process = ManagedProcess("px4", argv, log_dir=workdir, cwd=px4_dir, env=env)
        return start_process(self.name, process, artifacts=lambda: collect_artifacts(px4_dir, [process.stdout_path, process.stderr_path]),
                             mavlink_params=dict(params) if at_start else {**DEFAULT_PARAMS, **params}, booted=printed(process.stdout_path, STARTED_UP),
                             **({} if measured is None else {"coverage": lambda: gcov_record(measured, folder, workdir)}))


def collect_artifacts(px4_dir: Path, console_logs: list[Path]) -> list[Path]:
    """PX4's ULog files (log/DATE/TIME.ulg) and its non-empty console output."""
    return sorted(px4_dir.glob("log/**/*.ulg")) + non_empty(console_logs)
