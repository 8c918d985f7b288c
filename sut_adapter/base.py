"""The SUT protocol: what the harness may rely on of any system under test.

A SUT is started for one evaluation with a port block (the simulator's TCP port it connects
to, the UDP port it sends its API link to, the instance index those came from), a fresh
working directory and parameters; it answers with a handle. Two properties tell the harness
how to treat it without knowing which SUT it is:

* `hold_mode`: "frozen" if it answers MAVLink while the simulation is held with simulated
  time stopped (the bundled autopilot), "paced" if its threads follow the lockstep clock and
  so need simulated time to pass while the harness sets up (PX4).
* `hold_pace` (optional, 1.0): how many times faster than real time a paced hold may run. PX4
  stretches its timeouts by the speed factor it is started with, so its hold runs that fast.
* `range_messages`: how it reads the range sensor: OBSTACLE_DISTANCE (72 sectors; the bundled
  autopilot) and/or DISTANCE_SENSOR (wedges; PX4). The simulator sends only those.
* `spin_s` (a hint to `start`): the SUT has a core of its own, the simulator another, so it
  may poll for the simulator's next message this long before sleeping. The bundled autopilot
  does; PX4 and command SUTs wait their own way.
* `inline_arguments` (optional): a SUT that can run inside the bridge's process, its simulator
  link through memory (`--transport memory`; the bundled autopilot), gives the arguments it
  takes there. PX4 and command SUTs have none: they keep TCP.
* `connects_to_unix_socket` (optional, True): the SUT's `start` also takes `sim_socket`, a
  Unix-domain socket to connect to instead of the simulator's TCP port (`--transport unix`; the
  bundled autopilot). Same bytes, half the kernel's round trip.
* `connects_to_shared_memory` (optional, True): with `sim_socket`, `start` also takes
  `sim_shared_memory`: the simulator hands shared memory over on that socket and the link's
  bytes go through it (`--transport shm`, simlink/shared_memory.py; the bundled autopilot).
* `sim_protocol` (optional, "mavlink"): what the simulator link speaks; "ardupilot-json" for
  ArduPilot's JSON physics backend (sim_bridge/ardupilot_json.py), over UDP on the simulator port.
* `needs_world` (optional, False): `start` also takes `world`, the WorldSpec it flies in
  (ArduPilot starts at its origin and sizes its rangefinders by its range sensor).
* `mission_home_item` (optional, False): the SUT takes MISSION_ITEM_INT 0 for home (ArduPilot),
  so the harness uploads the start there and the mission after it.
* `rc_port_for(instance)` (optional): the UDP port the SUT takes the pilot's sticks on, as
  ArduPilot SITL's RC input does; without it they go on the simulator link as RC_CHANNELS.
* `pilot_params` (optional, sim_bridge/pilot.py's SUT_PARAMS): the pilot drive's RC layout as
  parameters set over MAVLink; `takeoff_altitude_param` (optional, "MIS_TAKEOFF_ALT"; None:
  MAVSDK's take-off altitude); `pilot_flight_mode` (optional, "POSCTL"): MAVSDK's name of the
  mode the pilot's Position slot selects.
* `rate_hz` (optional, 250): the lockstep rate it wants unless the user chose one; ArduPilot's
  SITL samples its gyros at the physics rate and refuses to arm below 1.8 times its 400 Hz loop.
* `injects_failures` (optional, True): False for a SUT without MAV_CMD_INJECT_FAILURE
  (ArduPilot): each failure it is to be told of is answered UNSUPPORTED, `failure_refused`,
  unless its `failure_params(unit, type)` (optional) gives parameters that fail the unit (set
  over MAVLink at the onset; type "ok" gives their values without a failure); None: refused.
* `sut_failure_units` (optional, none): units whose failures the SUT makes itself although the
  simulator would fail their readings on the way for others (ArduPilot's GPS, which it makes
  from the true position): they are told to it instead.
* `SutHandle.mavlink_params`: parameters the harness sets over MAVLink (MAVSDK's param
  plugin) once the SUT is discovered, before it waits for health.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Mapping, Protocol

from sut_adapter.processes import ManagedProcess

if TYPE_CHECKING:
    from sim_bridge.spec import WorldSpec

HOLD_MODES = ("frozen", "paced")


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
    pids: list[int] = field(default_factory=list)
    mavlink_params: Mapping[str, int | float] = field(default_factory=dict)


def start_process(sut: str, process: ManagedProcess, **fields) -> SutHandle:
    """Start a SUT's process and wrap it in a handle; fields override the handle's defaults."""
    try:
        process.__enter__()
    except OSError as error:
        raise SutError(sut, f"cannot start {process.argv[0]}: {error}") from None
    defaults = {"alive": lambda: process.poll() is None, "stop": process.stop, "stderr_tail": process.console_tail, "pids": [process.pid]}
    return SutHandle(name=sut, **{**defaults, **fields})


def runs_inline(system: "SystemUnderTest") -> bool:
    """Whether the SUT can run inside the bridge's process (it gives `inline_arguments`)."""
    return callable(getattr(system, "inline_arguments", None))


def instance_count(system: "SystemUnderTest") -> int | None:
    """How many instances of the SUT can run side by side on one host (None: as many as there
    are port blocks); an evaluation's instance number is its port block's slot."""
    return getattr(system, "instance_count", None)


def hold_pace(system: "SystemUnderTest") -> float:
    """Simulated seconds per wall-clock second in the SUT's paced hold (real time unless it says)."""
    pace = getattr(system, "hold_pace", 1.0)
    if not (isinstance(pace, (int, float)) and math.isfinite(pace) and pace > 0):
        raise SutError(system.name, f"its hold_pace {pace!r} is not a positive number of simulated seconds per wall-clock second")
    return float(pace)


def sim_protocol(system: "SystemUnderTest") -> str:
    """What the SUT's simulator link speaks: "mavlink" unless it says otherwise."""
    return getattr(system, "sim_protocol", "mavlink")


def needs_world(system: "SystemUnderTest") -> bool:
    """Whether the SUT's start takes `world`, the WorldSpec it flies in."""
    return getattr(system, "needs_world", False) is True


def mission_home_item(system: "SystemUnderTest") -> bool:
    """Whether the SUT takes mission item 0 for home."""
    return getattr(system, "mission_home_item", False) is True


def pilot_setup(system: "SystemUnderTest") -> tuple[dict[str, float], str | None, str]:
    """The pilot drive's set-up for this SUT: its RC layout's parameters, the parameter its
    take-off altitude goes in (None: MAVSDK's take-off command), MAVSDK's name of its Position mode."""
    from sim_bridge.pilot import SUT_PARAMS

    return (dict(getattr(system, "pilot_params", SUT_PARAMS)), getattr(system, "takeoff_altitude_param", "MIS_TAKEOFF_ALT"),
            getattr(system, "pilot_flight_mode", "POSCTL"))


DEFAULT_RATE_HZ = 250.0


def physics_rate(system: "SystemUnderTest") -> float:
    """The lockstep rate the SUT wants unless the user chose one (--rate-hz): 250 Hz, PX4's."""
    return float(getattr(system, "rate_hz", DEFAULT_RATE_HZ))


def injects_failures(system: "SystemUnderTest") -> bool:
    """Whether the SUT takes MAV_CMD_INJECT_FAILURE (with SYS_FAILURE_EN), as PX4 and the bundled autopilot do."""
    return getattr(system, "injects_failures", True) is not False


def failure_params(system: "SystemUnderTest") -> Callable[[str, str], Mapping[str, float] | None] | None:
    """How a SUT without MAV_CMD_INJECT_FAILURE fails a unit through its parameters (None: it cannot)."""
    means = getattr(system, "failure_params", None)
    return means if callable(means) else None


def with_failure_deliveries(system: "SystemUnderTest", world: "WorldSpec") -> "WorldSpec":
    """The world with the failures of units the SUT fails itself told to it, not made by the simulator."""
    units = tuple(getattr(system, "sut_failure_units", ()))
    if not any(f.unit in units and f.delivery != "sut" for f in world.failures or ()):
        return world
    return replace(world, failures=tuple(replace(f, delivery="sut") if f.unit in units else f for f in world.failures))


def rc_port(system: "SystemUnderTest", instance: int) -> int | None:
    """The UDP port the SUT takes the pilot's sticks on (None: on the simulator link)."""
    port_for = getattr(system, "rc_port_for", None)
    return port_for(instance) if callable(port_for) else None


def connects_to_unix_socket(system: "SystemUnderTest") -> bool:
    """Whether the SUT's start takes `sim_socket`, a Unix-domain socket to connect to."""
    return getattr(system, "connects_to_unix_socket", False) is True


def connects_to_shared_memory(system: "SystemUnderTest") -> bool:
    """Whether the SUT's start takes `sim_shared_memory` beside `sim_socket`."""
    return connects_to_unix_socket(system) and getattr(system, "connects_to_shared_memory", False) is True


class SystemUnderTest(Protocol):
    name: str
    hold_mode: str
    range_messages: tuple[str, ...]

    def start(self, *, sim_port: int, api_port: int, instance: int, workdir: Path, params: Mapping[str, float],
              spin_s: float = 0.0) -> SutHandle:
        """Start the SUT so that it connects to the simulator on sim_port and sends its API link to api_port."""

    def check_params(self, params: Mapping[str, float]) -> None:
        """Raise SutError for a parameter the SUT does not have or a value outside its range, before
        any flight; a SUT that only knows its parameters once running lets them all pass."""
