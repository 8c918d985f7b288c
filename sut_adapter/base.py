"""The SUT protocol: what the harness may rely on of any system under test.

A SUT is started for one evaluation with a port block (the simulator's TCP port it connects
to, the UDP port it sends its API link to, the instance index those came from), a fresh
working directory and parameters; it answers with a handle. Its adapter declares once, in a
`Capabilities` record (`capabilities`), how the harness is to meet it without knowing which SUT
it is; the fields say what each capability means. A `start` takes, besides the port block,
`sim_socket` (and `sim_shared_memory`) where its transports include "unix" ("shm"), `world`
where it `needs_world`, `flight_params` (`Capabilities.flight_params`) where it takes
`params_at_start`; an adapter whose transports include "memory" gives `inline_arguments`.
`spin_s` (a hint to `start`): the SUT has a core of its own, the simulator another, so it may
poll for the simulator's next message this long before sleeping. The bundled autopilot does;
PX4 and command SUTs wait their own way.
* `SutHandle.mavlink_params`: parameters the harness sets over MAVLink (MAVSDK's param
  plugin) once the SUT is discovered, before it waits for health.
"""

from __future__ import annotations

import math
import signal
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Mapping, Protocol

from sut_adapter.processes import ManagedProcess, process_cpu_s

if TYPE_CHECKING:
    from sim_bridge.spec import WorldSpec

HOLD_MODES = ("frozen", "paced")
TRANSPORTS = ("tcp", "unix", "shm", "memory")
DEFAULT_RATE_HZ = 250.0
EXIT_STATUS_WAIT_S = 1.0


@dataclass(frozen=True)
class SutConfig:
    """Which SUT flies and how, as a user chose it: what a campaign records (name, params,
    fault: its identity) and a job carries to a worker (all of it)."""

    name: str = "bundled"
    params: Mapping[str, float] = field(default_factory=dict)  # set before each flight
    fault: str | None = None  # a seeded fault of the bundled autopilot
    px4_bin: str | None = None  # px4: the binary or its build folder
    command: str | None = None  # command: the command line template
    hold: str | None = None  # command: one of HOLD_MODES
    autopilot_dir: str | None = None  # bundled: a folder whose `autopilot` package flies instead (a mutant, an edit)
    ardupilot_bin: str | None = None  # ardupilot: the arducopter binary or its build folder

    def adapter_options(self) -> dict[str, str]:
        """What the named adapter is configured with (its factory's mapping)."""
        return {key: value for key, value in (("px4_bin", self.px4_bin), ("command", self.command), ("hold", self.hold),
                                              ("fault", self.fault), ("autopilot_dir", self.autopilot_dir), ("ardupilot_bin", self.ardupilot_bin))
                if value is not None}

    def identity(self) -> dict[str, object]:
        """What makes two flights' SUTs the same, wherever they run (no machine's paths)."""
        return {"name": self.name, "params": dict(self.params), **({"fault": self.fault} if self.fault else {})}


class SutError(Exception):
    """A SUT would not start or answer, or is configured wrongly; carries its name and the tail of its log."""

    def __init__(self, sut: str, message: str, log_tail: str = ""):
        self.sut = sut
        self.log_tail = log_tail
        super().__init__(f"{sut}: {message}" + (f"\n{log_tail}" if log_tail else ""))


@dataclass
class SutHandle:
    """A started SUT. `alive()` says whether it still runs; `artifacts()` lists the files worth
    keeping once it stopped (its logs, a PX4 ULog)."""

    name: str
    alive: Callable[[], bool]
    stop: Callable[[], int | None]
    artifacts: Callable[[], list[Path]] = lambda: []
    stderr_tail: Callable[[], str] = lambda: ""
    # Its process's exit status while the harness has not stopped it yet: None while it runs,
    # -N for a signal (a SUT that dies of SIGFPE or SIGSEGV in flight says so), else its code.
    exit_status: Callable[[], int | None] = lambda: None
    pids: list[int] = field(default_factory=list)
    mavlink_params: Mapping[str, int | float] = field(default_factory=dict)
    # Whether it has finished starting up: a SUT may speak MAVLink before it answers all of it
    # (PX4 drops parameter messages until the end of its start-up script).
    booted: Callable[[], bool] = lambda: True
    # A coverage build's: once it has stopped, the code it ran (sut_adapter/coverage.py); None
    # where it is no coverage build or left no counters.
    coverage: Callable[[], dict[str, Any] | None] = lambda: None

    def cpu_s(self) -> float | None:
        """The CPU time its processes and their descendants have used so far; None for a SUT
        without processes of its own (in memory) or where the system cannot say."""
        used = [process_cpu_s(pid) for pid in self.pids]
        return None if not used or None in used else sum(used)

    def settled_exit_status(self) -> int | None:
        """Its exit status, waited for a moment: a dying process closes its links before it can
        be reaped, so the bridge may see the link go, and the simulation end, before the exit
        status is there. None: it still runs."""
        deadline = time.monotonic() + EXIT_STATUS_WAIT_S
        status = self.exit_status()
        while status is None and time.monotonic() < deadline:
            time.sleep(0.02)
            status = self.exit_status()
        return status

    def how_it_ended(self) -> str:
        """Its exit (a signal by name: PX4 dying of SIGFPE in flight is a finding), then the end
        of its console, which for a crash is often start-up noise printed long before. Asked
        before the harness stops it, whose SIGTERM would be all its exit status then says."""
        status = self.settled_exit_status()
        if status is None:
            ended = f"{self.name} still ran but stopped answering" if self.alive() else f"{self.name} is gone"
        elif status < 0:
            description = signal.strsignal(-status)
            ended = f"{self.name} died of {_signal_name(-status)}" + (f" ({description})" if description else "")
        else:
            ended = f"{self.name} exited with code {status}"
        return f"{ended}; its console ends: {self.stderr_tail()[-400:]}"


def _signal_name(number: int) -> str:
    try:
        return signal.Signals(number).name
    except ValueError:
        return f"signal {number}"


def start_process(sut: str, process: ManagedProcess, **fields) -> SutHandle:
    """Start a SUT's process and wrap it in a handle; fields override the handle's defaults."""
    try:
        process.__enter__()
    except OSError as error:
        raise SutError(sut, f"cannot start {process.argv[0]}: {error}") from None
    defaults = {"alive": lambda: process.poll() is None, "stop": process.stop, "stderr_tail": process.console_tail, "exit_status": process.poll,
                "pids": [process.pid]}
    return SutHandle(name=sut, **{**defaults, **fields})


@dataclass(frozen=True)
class Capabilities:
    """What a SUT can do and how the harness must meet it, declared on its adapter."""

    # "frozen" if it answers MAVLink while the simulation is held with simulated time stopped (the
    # bundled autopilot); "paced" if its threads follow the lockstep clock and so need simulated
    # time to pass while the harness sets up (PX4).
    hold_mode: str
    # How it reads the range sensor: OBSTACLE_DISTANCE (72 sectors; the bundled autopilot) and/or
    # DISTANCE_SENSOR (wedges; PX4). The simulator sends only those.
    range_messages: tuple[str, ...]
    # Which of a sensor rig's messages (harness/scenario/rig.py) it reads; a rig with another kind
    # of sensor is refused for it. Those of companion_messages it reads on a companion computer's
    # MAVLink link, the UDP port companion_port_for(instance), not on the simulator link.
    rig_messages: tuple[str, ...] = ()
    companion_messages: tuple[str, ...] = ()
    companion_port_for: Callable[[int], int] | None = None
    # It opens the companion link itself, sending from a port of its own to companion_port
    # (ArduPilot SITL's `udpclient:`), rather than listening there (PX4).
    companion_connects: bool = False
    # How it reads a rig's DISTANCE_SENSOR (sim_bridge/rig.py: DISTANCE_SENSOR_CONVENTIONS): "px4",
    # its direction a custom rotation's quaternion and nothing within reach read as the maximum;
    # "ardupilot", one of MAV_SENSOR_ROTATION's eight named yaws and nothing read beyond the maximum.
    distance_sensor_convention: str = "px4"
    # Why it cannot read one sensor of a rig (a rig document's sensor; None: it can), beyond the
    # sensor's message.
    rig_sensor_problem: Callable[[Mapping[str, Any]], str | None] | None = None
    # How many DISTANCE_SENSOR devices it tells apart (None: any number).
    distance_sensor_limit: int | None = None
    # How many times faster than real time a paced hold may run. PX4 stretches its timeouts by
    # the speed factor it is started with, so its hold runs that fast.
    hold_pace: float = 1.0
    # The lockstep rate it wants unless the user chose one (--rate-hz); ArduPilot's SITL samples
    # its gyros at the physics rate and refuses to arm below 1.8 times its 400 Hz loop.
    rate_hz: float = DEFAULT_RATE_HZ
    # What the simulator link speaks: "mavlink" (PX4's simulator messages), or "ardupilot-json"
    # for ArduPilot's JSON physics backend (sim_bridge/ardupilot_json.py) over UDP.
    sim_protocol: str = "mavlink"
    # What may carry the simulator link (--transport): "tcp"; "unix", a Unix-domain socket (same
    # bytes, half the kernel's round trip); "shm", shared memory handed over on that socket
    # (simlink/shared_memory.py); "memory", inside the bridge's process.
    transports: tuple[str, ...] = ("tcp",)
    # How many instances can run side by side on one host (None: as many as there are port
    # blocks); an evaluation's instance number is its port block's slot.
    instance_count: int | None = None
    # Its start takes `world`, the WorldSpec it flies in (ArduPilot starts at its origin and sizes
    # its rangefinders by its range sensor).
    needs_world: bool = False
    # It takes MISSION_ITEM_INT 0 for home (ArduPilot): the harness uploads the start there and
    # the mission after it.
    mission_home_item: bool = False
    # The UDP port it takes the pilot's sticks on for an instance, as ArduPilot SITL's RC input
    # does; None: they go on the simulator link as RC_CHANNELS.
    rc_port_for: Callable[[int], int] | None = None
    # The pilot drive's RC layout as parameters set over MAVLink (None: sim_bridge/pilot.py's
    # SUT_PARAMS, PX4's names); the parameter its take-off altitude goes in (None: MAVSDK's
    # take-off command); MAVSDK's name of the mode the pilot's Position slot selects.
    pilot_params: Mapping[str, float] | None = None
    takeoff_altitude_param: str | None = "MIS_TAKEOFF_ALT"
    pilot_flight_mode: str = "POSCTL"
    # It takes parameters with its start, set before its modules run: the flight's own (the
    # pilot drive's) go there instead of over MAVLink, where a module may apply one late. PX4's
    # navigator took off to its default MIS_TAKEOFF_ALT of 2.5 m in 40 of 217 pilot flights of a
    # mutant's wall searches (2026-11), with the parameter set and acknowledged 0.4-0.6 s of its
    # clock before the take-off command.
    params_at_start: bool = False
    # Whether it takes MAV_CMD_INJECT_FAILURE (with SYS_FAILURE_EN), as PX4 and the bundled
    # autopilot do. Without it each failure it is to be told of is answered UNSUPPORTED
    # (`failure_refused`) unless failure_params(unit, type) gives parameters that fail the unit,
    # set over MAVLink at the onset (type "ok" gives their values without a failure).
    injects_failures: bool = True
    failure_params: Callable[[str, str], Mapping[str, float] | None] | None = None
    # It answers every HIL_SENSOR, the first included: the simulation is in lockstep from its first
    # step, so a flight does not depend on how fast the SUT came up (a SUT that needs simulated
    # time to pass before it answers, as PX4 does to boot, gets real-time pace until its first).
    answers_every_step: bool = False
    # Its HIL_ACTUATOR_CONTROLS carry the time_usec of the HIL_SENSOR they answer (PX4 sends its
    # lockstep clock, which that time_usec sets): an answer that came a step late is told from the
    # step's own instead of being taken for it, which would leave the whole flight a step behind.
    echoes_step_time: bool = False
    # Units whose failures it makes itself although the simulator would fail their readings on
    # the way for others (ArduPilot's GPS, which it makes from the true position): they are told to it.
    sut_failure_units: tuple[str, ...] = ()

    def check(self, sut: str) -> None:
        """Raise SutError naming the SUT for a declaration the harness cannot act on."""
        problems = []
        if self.hold_mode not in HOLD_MODES:
            problems.append(f"its hold_mode {self.hold_mode!r} is not one of {', '.join(HOLD_MODES)}")
        for name in ("hold_pace", "rate_hz"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                problems.append(f"its {name} {value!r} is not a positive number")
        unknown = sorted(set(self.transports) - set(TRANSPORTS))
        if unknown:
            problems.append(f"its transports {', '.join(unknown)} are not among {', '.join(TRANSPORTS)}")
        if problems:
            raise SutError(sut, "; ".join(problems))

    def pilot_setup(self) -> tuple[dict[str, float], str | None, str]:
        """The pilot drive's set-up: its RC layout's parameters, the parameter its take-off
        altitude goes in (None: MAVSDK's take-off command), MAVSDK's name of its Position mode."""
        from sim_bridge.pilot import SUT_PARAMS

        return dict(SUT_PARAMS if self.pilot_params is None else self.pilot_params), self.takeoff_altitude_param, self.pilot_flight_mode

    def flight_params(self, world: "WorldSpec") -> dict[str, float]:
        """The parameters a flight in this world needs beyond the SUT's own: the pilot drive's RC
        layout and take-off altitude (none for a mission)."""
        if world.drive != "pilot":
            return {}
        params, altitude_param, _mode = self.pilot_setup()
        if altitude_param is not None:
            params[altitude_param] = float(world.mission.takeoff_altitude_m)
        return params

    def companion_port(self, instance: int) -> int | None:
        """The UDP port a companion computer's MAVLink reaches the SUT on (None: it has none)."""
        return self.companion_port_for(instance) if self.companion_port_for is not None else None

    def rc_port(self, instance: int) -> int | None:
        """The UDP port the SUT takes the pilot's sticks on (None: on the simulator link)."""
        return self.rc_port_for(instance) if self.rc_port_for is not None else None

    def with_failure_deliveries(self, world: "WorldSpec") -> "WorldSpec":
        """The world with the failures of units the SUT fails itself told to it, not made by the simulator."""
        if not any(f.unit in self.sut_failure_units and f.delivery != "sut" for f in world.failures or ()):
            return world
        return replace(world, failures=tuple(replace(f, delivery="sut") if f.unit in self.sut_failure_units else f for f in world.failures))


class SystemUnderTest(Protocol):
    name: str
    capabilities: Capabilities

    def start(self, *, sim_port: int, api_port: int, instance: int, workdir: Path, params: Mapping[str, float],
              spin_s: float = 0.0) -> SutHandle:
        """Start the SUT so that it connects to the simulator on sim_port and sends its API link to api_port."""

    def check_params(self, params: Mapping[str, float]) -> None:
        """Raise SutError for a parameter the SUT does not have or a value outside its range, before
        any flight; a SUT that only knows its parameters once running lets them all pass."""
