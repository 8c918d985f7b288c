"""What a flight is asked and what it answers: the run's options, the evaluation's result (the
one currency of executors, the campaign, its store and its reports) and the flight's own parts
of it. Light to import: no MAVSDK, no processes.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any, Mapping, NamedTuple

from harness.flight.fitness import COULD_NOT_FINISH, Clearance, Status
from sim_bridge.control import EndReason
from sim_bridge.sut_link import TRANSPORTS
from sut_adapter import SutConfig

if TYPE_CHECKING:
    from harness.properties.spec import Property

SUT_LOGS = ("all", "failures", "violations")


@dataclass(frozen=True)
class RunOptions:
    sut: SutConfig = field(default_factory=SutConfig)
    rate_hz: float | None = None  # the lockstep rate; None: the SUT's own (sut_adapter.physics_rate)
    hold_after_s: float = 3.0
    setup_timeout_s: float = 60.0
    min_real_time_factor: float = 1.0  # the run's wall timeout is the time limit divided by this
    keep_workdir: bool = False
    # Pin the simulator and the SUT to the evaluation's cores (harness/flight/stack.py: placed_cores).
    pin_cpu: bool = True
    # Cores one evaluation may keep busy. 1: the simulator and the SUT share a core and sleep
    # while the other works (a lockstep round trip costs about 20 us there; waking a process on
    # the other core about 80). 2: each has a core and polls for the other's messages, so a
    # flight runs about 1.5x faster but keeps two cores busy. Executors choose 2 only when every
    # concurrent evaluation can have two cores.
    cores: int = 1
    # How the simulator's bytes reach the SUT: "tcp" (any SUT, its own process); "unix": the
    # same over a Unix-domain socket, for a SUT that can connect to one (the bundled autopilot;
    # half TCP's round trip); "shm": the same bytes through shared memory handed over on that
    # socket (the same SUTs, Linux on x86-64; no system call per step); or "memory": a SUT that
    # can (the bundled autopilot) runs inside the bridge's process, the same bytes handed over by
    # a call. The flight is the same to the last bit whichever carries it. On one core memory is
    # the fastest, about 1.8x faster than both processes sharing it; on two the polling pair
    # through shared memory is. "auto": memory where an evaluation has one core, shm (else unix)
    # where it has two, whichever the SUT can, else tcp.
    transport: str = "auto"
    # Keep the simulator running after the evaluation and fly this process's next evaluation
    # with the same options in it (harness/flight/stack.py), without starting its process again:
    # a fresh world, and a fresh autopilot inside it (transport memory, MAVSDK staying connected)
    # or a fresh SUT process that connects to it (with a MAVSDK of its own). ArduPilot's JSON
    # link always starts cold. The caller closes what is kept (stack.close_kept); executors do
    # when they close.
    warm: bool = False
    # The SUT's own flight logs beside each MCAP (PX4's ULog, about 19 MB for a 50 s flight;
    # ArduPilot's dataflash .BIN): which flights keep them (keeps_sut_log), so that a campaign of
    # thousands of real-firmware flights fits on a disk. Consoles are kept either way.
    sut_logs: str = "all"
    # Safety properties (harness/properties) scored on each flight beside its fitness.
    properties: tuple["Property", ...] = ()

    def __post_init__(self) -> None:
        if self.transport not in TRANSPORTS:
            raise ValueError(f"transport {self.transport!r} is not one of {', '.join(TRANSPORTS)}")
        if self.sut_logs not in SUT_LOGS:
            raise ValueError(f"sut_logs {self.sut_logs!r} is not one of {', '.join(SUT_LOGS)}")

    def keeps_sut_log(self, status: Status, end_reason: EndReason | None) -> bool:
        """Whether a flight that ended so keeps the SUT's own flight log: with "failures" every
        flight that did not end ok; with "violations" those that violated, crashed into the
        ground or could not finish, not the other mission failures (blocked by the pilot drive's
        rule, the time limit, a landing off the goal): collision prevention holding a vehicle
        back is one, and every pilot flight of a foggy scenario."""
        if self.sut_logs == "failures":
            return status != Status.OK
        if self.sut_logs == "violations":
            return status == Status.VIOLATION or status in COULD_NOT_FINISH or end_reason == EndReason.CRASHED
        return True


@dataclass(frozen=True, kw_only=True)
class EvaluationResult:
    """One try's outcome, from the flight to the store, the report and a regression test; JSON
    (as_dict / from_dict) only where it crosses a process boundary or is written out. Built by
    keyword: thirteen fields of a few types, in an order nobody should have to remember."""

    status: Status
    fitness: float
    why: str | None
    min_clearance_m: float | None
    min_clearance_at_s: float | None
    min_clearance_obstacle: str | None
    sim_time_s: float
    wall_time_s: float
    real_time_factor: float | None
    seed: int
    log_path: str | None
    scenario: str
    sut: str
    sut_fault: str | None = None  # a seeded fault of the bundled autopilot, switched on
    violations: list[str] = field(default_factory=list)
    artifacts: list[str] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    mavsdk: dict[str, Any] = field(default_factory=dict)
    attempts: list[dict[str, str]] = field(default_factory=list)  # every try's status and why, when an executor retried
    confirmations: dict[str, Any] | None = None  # a violation flown again: how often it came back
    # Flown against a reference SUT too (harness/flight/differential.py): both sides' flights,
    # whether they reveal a difference, and the objective that made `fitness`.
    differential: dict[str, Any] | None = None
    # Failure injections the SUT refused (t, unit, type, its answer): it flew on without them, so
    # the flight did not test what the scenario says.
    failures_refused: list[dict[str, Any]] = field(default_factory=list)
    # Simulated time of the first touchdown once airborne (None: it never came down): where a
    # landing hops, sim_time_s ends at the last hop.
    first_touchdown_s: float | None = None
    # Each property asked for (RunOptions.properties): {name: {"verdict", "robustness", "unit"}}.
    properties: dict[str, dict[str, Any]] = field(default_factory=dict)
    # A coverage build's: the lines and branches of its measured sources the flight ran
    # (sut_adapter/coverage.py); None for any other build.
    coverage: dict[str, Any] | None = None

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, document: Mapping[str, Any]) -> "EvaluationResult":
        return cls(**{**document, "status": Status(document["status"])})


class Failure(NamedTuple):
    """Why a flight's outcome is not what its recording alone would say: the SUT or the simulator
    failed, the run timed out, or the mission was not performed."""

    status: Status
    why: str


@dataclass(frozen=True)
class FlightOutcome:
    """What a flight leaves besides its recording: the failure that ended it early (None: it
    flew to its end), the simulator's summary (its Finished event; empty when none came) and
    what MAVSDK observed."""

    failure: Failure | None
    summary: Mapping[str, Any]
    mavsdk: Mapping[str, Any]

    @property
    def end_reason(self) -> EndReason | None:
        return self.summary.get("end_reason")


NOT_FLOWN = FlightOutcome(None, {}, {})


@dataclass(frozen=True)
class Score:
    """A flight's status and fitness (harness/flight/fitness.py's policy) and the clearance they
    come from (None: nothing was recorded)."""

    status: Status
    fitness: float
    why: str | None
    clearance: Clearance | None
