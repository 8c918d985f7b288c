"""Fly one concrete scenario end to end and score it from its recording.

allocate a port block -> start the bridge and the SUT as real processes -> MAVSDK connects
through the API tap -> wait until the simulation holds and the SUT is healthy -> upload the
mission, arm, start -> release the simulation -> wait for its end -> stop everything -> merge
the log -> score from the log.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import sys
import tempfile
import time
from contextlib import ExitStack, contextmanager
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from harness.errors import InfrastructureError, InputError, Problem
from harness.flight import fitness as scoring
from harness.flight.fitness import COULD_NOT_FINISH, Status
from harness.flight import logs, warm
from harness.flight.api_tap import ApiTap
from harness.flight.bridge_control import BridgeControl
from harness.flight.mavsdk_session import ACCEPTANCE_RADIUS_M, MavsdkSession, mission_items
from harness.flight.ports import PortBlock, PortLease
from harness.scenario.space import SearchSpace
from harness.scenario.world import world_spec
from sim_bridge.spec import NORMAL_ENDS, WorldSpec
from sim_bridge.sut_link import TRANSPORTS
from simlink import shared_memory
import sut_adapter
from sut_adapter import SutConfig, SutHandle, SystemUnderTest
from sut_adapter.processes import ManagedProcess

log = logging.getLogger(__name__)

PX4_MAIN_MODE_POSCTL = 3
# ArduCopter's custom modes where the pilot's sticks steer the position and simple avoidance acts: Loiter, PosHold.
ARDUCOPTER_POSITION_MODES = (5, 16)
CLIENT_PORT_OFFSET = 1000  # MAVSDK listens here, behind the API tap
# With a core each, the simulator and the SUT poll this long for each other's next message
# before sleeping: far longer than a lockstep turn, short enough to idle during setup.
LOCKSTEP_SPIN_S = 0.002
# After its flight the simulator keeps the SUT's link open until the SUT has gone, at most this
# long: longer than stopping the SUT can take (ManagedProcess.stop's two grace periods).
LINGER_S = 5.0
# How long a SUT whose simulated time runs on while it is set up (hold "paced": PX4) may deny
# arming before the denial counts: PX4's arming checks flicker just after its start-up. Held
# frozen, a SUT cannot change its mind, so its first answer counts.
ARM_RETRY_S = 10.0


def arm_retry_for(system: SystemUnderTest) -> float:
    """How long a flight (and `stella sut check`) asks again while this SUT denies arming."""
    return ARM_RETRY_S if system.hold_mode == "paced" else 0.0


@dataclass(frozen=True)
class RunOptions:
    sut: SutConfig = field(default_factory=SutConfig)
    rate_hz: float | None = None  # the lockstep rate; None: the SUT's own (sut_adapter.physics_rate)
    hold_after_s: float = 3.0
    setup_timeout_s: float = 60.0
    min_real_time_factor: float = 1.0  # the run's wall timeout is the time limit divided by this
    keep_workdir: bool = False
    # Pin the simulator and the SUT to the evaluation's cores (see _pin).
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
    # Keep the simulator with the SUT inside (transport memory) running after the evaluation and
    # fly this process's next evaluation with the same options in it: a fresh world and a fresh
    # autopilot, without starting a process or connecting MAVSDK again. The caller closes what
    # is kept (warm.close_all); executors do when they close.
    warm: bool = False

    def __post_init__(self) -> None:
        if self.transport not in TRANSPORTS:
            raise ValueError(f"transport {self.transport!r} is not one of {', '.join(TRANSPORTS)}")


@dataclass(frozen=True)
class EvaluationResult:
    """One try's outcome, from the flight to the store, the report and a regression test; JSON
    (as_dict / from_dict) only where it crosses a process boundary or is written out."""

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

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, document: Mapping[str, Any]) -> "EvaluationResult":
        return cls(**{**document, "status": Status(document["status"])})


def _reported_position_mode(from_sut: Iterable[bytes]) -> bool:
    """Whether the SUT's heartbeats on the API link (its datagrams) ever said Position mode (PX4
    custom main mode 3; ArduCopter's Loiter or PosHold)."""
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    for datagram in from_sut:
        for message in parser.parse_buffer(datagram) or []:
            if message.get_type() != "HEARTBEAT" or message.type == mavlink.MAV_TYPE_GCS:
                continue
            if message.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA:
                if message.custom_mode in ARDUCOPTER_POSITION_MODES:
                    return True
            elif (message.custom_mode >> 16) & 0xFF == PX4_MAIN_MODE_POSCTL:
                return True
    return False


def _logged_api_traffic(log_path: Path) -> Iterator[bytes]:
    """What the SUT sent on the API link, as recorded in an evaluation's log."""
    for _t, _ns, record in logs.messages(log_path, ["/mavlink/api"]):
        if record["direction"] == "from_sut":
            yield bytes.fromhex(record["hex"])


def refused_failures(events: Iterable[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The failure injections the SUT refused, from the simulator's /events."""
    return [{"t": event["t"], "unit": event["detail"]["unit"], "type": event["detail"]["type"], "result": event["detail"]["result"]}
            for event in events if event.get("event") == "failure_refused"]


def _score(recorded: Callable[[Sequence[str]], Iterable[tuple[str, int, Any]]], world: WorldSpec, summary: Mapping[str, Any],
           failure: tuple[str, str] | None, api_from_sut: Iterable[bytes], partial: bool = False) -> tuple[str, float, str | None, scoring.Clearance]:
    """Status and fitness of a flight from the simulator's recording (recorded(topics): the
    bridge's or the merged log's messages) and what the SUT sent on the API link; of a partial
    (truncated) log, the clearance of what was recorded, as whether the mission was flown cannot
    be told from part of it."""
    if failure is None and not partial and summary.get("end_reason") == "blocked" and not _reported_position_mode(api_from_sut):
        # Not collision prevention holding the pilot back: the SUT ignored the mode switch.
        failure = (Status.MISSION_FAILED, "the SUT never reported Position mode after the pilot's mode switch (does it read RC_CHANNELS?)")
    clearance = scoring.min_clearance(message for _t, _ns, message in recorded(["/clearance"]))
    if failure is None and clearance.samples and not partial:
        states = [message for _t, _ns, message in recorded(["/uav/state"])]
        why = scoring.mission_check(states, world.mission, ACCEPTANCE_RADIUS_M, summary, world.drive)
        failure = (Status.MISSION_FAILED, why) if why else None
    status, value, why = scoring.judge(clearance, world.safety_distance_m, failure)
    return status, value, why, clearance


def rescore(log_path: Path) -> dict[str, Any]:
    """Recompute status and fitness from a log alone (what `stella inspect` does); a truncated log
    is scored on what precedes the damage, and says where that is."""
    cut = logs.truncation(log_path)
    world = logs.world_of(log_path)
    if world is None:
        where = f"; the file is {cut.describe()}" if cut else ""
        raise InputError([Problem(str(log_path), "", f"no world metadata: not an evaluation log of this tool, or cut before the simulator wrote it{where}")])
    summary = logs.json_metadata(log_path, "bridge_summary") or {}
    recorded = logs.json_metadata(log_path, "result") or {}
    failure = None
    if recorded.get("status") in COULD_NOT_FINISH:
        failure = (recorded["status"], recorded.get("why") or "")
    status, value, why, clearance = _score(lambda topics: logs.messages(log_path, topics), world, summary, failure, _logged_api_traffic(log_path),
                                           partial=cut is not None)
    return {"status": status, "fitness": value, "why": why, "clearance": clearance, "world": world, "summary": summary, "recorded": recorded,
            "truncation": cut, "failures_refused": refused_failures(m for _t, _ns, m in logs.messages(log_path, ["/events"]))}


def infeasible(space: SearchSpace, x: np.ndarray, *, seed: int, sut: str) -> EvaluationResult | None:
    """The result of a point that breaks a realism constraint (never flown), or None if it breaks none."""
    violations = space.violations(x)
    if not violations:
        return None
    total = -sum(min(0.0, float(m[0])) for m in space.constraint_margins(np.asarray(x)[None, :]).values())
    return EvaluationResult(Status.INFEASIBLE, scoring.infeasible_fitness(total), "; ".join(violations), None, None, None, 0.0, 0.0, None, seed, None,
                            space.logical.name, sut, violations)


def evaluate(space: SearchSpace, x: np.ndarray, *, seed: int, out_dir: Path, options: RunOptions = RunOptions(), name: str | None = None) -> EvaluationResult:
    """Fly the concrete scenario x of space (unless it is infeasible); never raises for a failed
    run, only reports it."""
    refused = infeasible(space, x, seed=seed, sut=options.sut.name)
    if refused is not None:
        return refused
    return fly(world_spec(space, x, seed), space.to_concrete(x), seed=seed, out_dir=out_dir, options=options, name=name)


def fly(world: WorldSpec, concrete: Mapping[str, Any], *, seed: int, out_dir: Path, options: RunOptions = RunOptions(),
        name: str | None = None) -> EvaluationResult:
    """Fly a feasible concrete scenario from the world spec the simulator loads (world.world_spec);
    the concrete scenario is recorded with the log. Needs no search space, so a worker flies a
    job as the campaign made it."""
    wall_start = time.monotonic()
    stem = logs.slug(name or f"{world.scenario}-seed{seed}")
    out_dir.mkdir(parents=True, exist_ok=True)
    workdir = Path(tempfile.mkdtemp(prefix=f"stella-{stem}-"))
    log_path = out_dir / f"{stem}.mcap"
    timings: dict[str, float] = {}
    failure: tuple[str, str] | None = None
    summary: dict[str, Any] = {}
    mavsdk_info: dict[str, Any] = {}
    artifacts: list[str] = []

    def finish(status: Status, value: float, why: str | None, clearance: scoring.Clearance | None, log_path: Path | None,
               failures_refused: list[dict[str, Any]] | None = None) -> EvaluationResult:
        in_run = summary.get("wall_in_run_s") or 0.0
        run_time = summary.get("run_time_s") or 0.0
        return EvaluationResult(
            status=status,
            fitness=value,
            why=why,
            min_clearance_m=clearance.min_clearance_m if clearance else None,
            min_clearance_at_s=clearance.at_s if clearance else None,
            min_clearance_obstacle=clearance.obstacle if clearance else None,
            sim_time_s=summary.get("sim_time_s", 0.0),
            wall_time_s=time.monotonic() - wall_start,
            real_time_factor=(run_time / in_run) if in_run > 0 else None,
            seed=seed,
            log_path=str(log_path) if log_path else None,
            scenario=world.scenario,
            sut=options.sut.name,
            sut_fault=options.sut.fault,
            artifacts=artifacts,
            timings={**timings, **{k: summary[k] for k in ("wait_s", "send_s", "sensors_s", "physics_s", "world_s", "wall_in_run_s") if k in summary}},
            mavsdk=mavsdk_info,
            failures_refused=failures_refused or [],
        )

    try:
        system = sut_adapter.system_for(options.sut)
        world = sut_adapter.with_failure_deliveries(system, world)
        started = time.monotonic()
        with simulation_stack(world, options, system, workdir) as stack:
            timings["start_s"] = time.monotonic() - started
            failure, summary, mavsdk_info = _fly(world, options, stack, timings, system)
            stack.clean = failure is None and summary.get("end_reason") in NORMAL_ENDS
            stopping = time.monotonic()
        timings["stop_s"] = time.monotonic() - stopping
        if failure is None and summary.get("end_reason") in ("sut_disconnected", "sut_stalled"):
            failure = (Status.SUT_CRASHED, f"{summary['end_reason']}: {stack.sut.stderr_tail()[-500:]}")
        artifacts = _keep_artifacts(stack.sut.artifacts(), out_dir / f"{stem}.artifacts")
        api_records = list(stack.tap.records)
        if not stack.bridge_log.exists() or stack.bridge_log.stat().st_size == 0:
            raise InfrastructureError(f"the simulator wrote no log: {stack.bridge.stderr_tail()}")
        t0 = time.monotonic()
        # Scored from the simulator's own recording, read once; the log is then written once, result included.
        recording = logs.Recording(stack.bridge_log)
        api_from_sut = (datagram for _ns, direction, datagram in api_records if direction == "from_sut")
        status, value, why, clearance = _score(recording.messages, world, summary, failure, api_from_sut)
        timings["score_s"] = time.monotonic() - t0
        result = finish(status, value, why, clearance, log_path, refused_failures(m for _t, _ns, m in recording.messages(["/events"])))
        logs.merge(recording, log_path, api_records=api_records, extra_metadata={
            "concrete_scenario": concrete, "result": result.as_dict(),
            "sut": options.sut.identity(), "placement": stack.placement,
        })
        return result
    except sut_adapter.SutError as error:
        log.warning("evaluation %s: the SUT failed to start: %s", stem, error)
        return finish(Status.SUT_CRASHED, scoring.PENALTY, str(error), None, None)
    except InfrastructureError as error:
        log.warning("evaluation %s failed: %s", stem, error)
        return finish(Status.SIM_CRASHED, scoring.PENALTY, str(error), None, None)
    finally:
        if not options.keep_workdir:
            shutil.rmtree(workdir, ignore_errors=True)


@dataclass
class Stack:
    """One evaluation's running parts: its port block, the simulator, the API tap, the SUT and MAVSDK."""

    ports: PortBlock
    bridge: ManagedProcess
    bridge_log: Path | None  # None: a warm stack between its evaluations
    tap: ApiTap
    sut: SutHandle
    session: MavsdkSession
    # Where it runs: {"cores": N, "transport": "memory" | "unix" | "shm" | "tcp"}, as the log records it.
    placement: dict[str, Any]
    # A warm stack's simulator serves flight after flight: this one starts when it gets this request.
    load: dict[str, str] | None = None
    # Set once the flight ended normally: a warm stack may then fly the next evaluation.
    clean: bool = False


def cores_for(options: RunOptions) -> int:
    """The cores an evaluation gets: those it may use, as far as this machine has them."""
    return min(options.cores, len(os.sched_getaffinity(0)))


def transport_problem(transport: str, system: SystemUnderTest) -> str | None:
    """Why this SUT cannot fly over this transport (None: it can)."""
    if transport == "memory" and not sut_adapter.runs_inline(system):
        return f"memory carries the bundled autopilot only; {system.name} runs in a process of its own: use --transport tcp"
    if transport == "unix" and not sut_adapter.connects_to_unix_socket(system):
        return f"unix carries the bundled autopilot only; {system.name} connects to the simulator over TCP: use --transport tcp"
    if transport == "shm" and not sut_adapter.connects_to_shared_memory(system):
        return f"shm carries the bundled autopilot only; {system.name} connects to the simulator over TCP: use --transport tcp"
    if transport == "shm" and not shared_memory.AVAILABLE:
        return "shm needs Linux on x86-64, which this machine is not: use --transport unix"
    return None


def _check_transport(options: RunOptions, system: SystemUnderTest) -> None:
    problem = transport_problem(options.transport, system)
    if problem is not None:
        raise sut_adapter.SutError(system.name, problem)


def placed_transport(options: RunOptions, system: SystemUnderTest) -> str:
    """What carries the simulator link (RunOptions.transport): auto puts a SUT that can run
    inside the bridge's process there when the evaluation has one core; with two, it takes
    shared memory, else a Unix-domain socket, where the SUT can; TCP otherwise."""
    _check_transport(options, system)
    if options.transport != "auto":
        return options.transport
    preferred = ("memory",) if cores_for(options) == 1 else ("shm", "unix")
    return next((transport for transport in preferred if transport_problem(transport, system) is None), "tcp")


def in_memory(options: RunOptions, system: SystemUnderTest) -> bool:
    """Whether the SUT runs inside the bridge's process."""
    return placed_transport(options, system) == "memory"


@contextmanager
def simulation_stack(world: WorldSpec, options: RunOptions, system: SystemUnderTest, workdir: Path) -> Iterator[Stack]:
    """Start the bridge, the API tap and the SUT on a free port block, with MAVSDK listening;
    on exit close MAVSDK and stop the SUT and the bridge (the bridge finishes its log first).
    With options.warm and the SUT in memory, a stack kept from this process's last evaluation
    flies it instead (harness/flight/warm.py), and is kept for the next if the flight ended cleanly."""
    world_path = workdir / "world.json"
    world_path.write_text(json.dumps(world.as_dict()))
    bridge_log = workdir / "bridge.mcap"
    if options.warm and in_memory(options, system):
        with warm.reuse(repr(options), lambda: _ServingStack.start(options, system)) as serving:
            yield serving.begin(bridge_log, {"op": "load", "world": str(world_path), "mcap": str(bridge_log)})
        return
    with ExitStack() as contexts:
        yield _start(contexts, options, system, workdir, ["--world", str(world_path), "--mcap", str(bridge_log)], bridge_log, world)


def _start(contexts: ExitStack, options: RunOptions, system: SystemUnderTest, workdir: Path, run_arguments: list[str], bridge_log: Path | None,
           world: WorldSpec | None = None) -> Stack:
    """A stack whose parts stop when contexts close: the bridge runs python -m sim_bridge
    run_arguments (a world and its log, or --serve; a SUT that needs_world gets the one flown)."""
    limited = sut_adapter.instance_count(system)
    ports = contexts.enter_context(PortLease(slots=limited, wait_s=options.setup_timeout_s) if limited else PortLease())
    transport = placed_transport(options, system)
    inline = transport == "memory"
    # In memory the SUT steps inside the bridge: one process, one core, nobody to poll for.
    cores = 1 if inline else cores_for(options)
    spin_s = LOCKSTEP_SPIN_S if cores >= 2 else 0.0
    bridge_argv = [sys.executable, "-m", "sim_bridge", *run_arguments, "--sim-port", str(ports.sim), "--control-port", str(ports.control),
                   "--rate-hz", str(options.rate_hz or sut_adapter.physics_rate(system)), "--hold-after-s", str(options.hold_after_s), "--hold-mode", system.hold_mode,
                   "--hold-pace", str(sut_adapter.hold_pace(system)),
                   "--range-messages", ",".join(system.range_messages), "--spin-us", str(spin_s * 1e6),
                   "--sim-protocol", sut_adapter.sim_protocol(system),
                   *(["--rc-port", str(sut_adapter.rc_port(system, ports.slot))] if sut_adapter.rc_port(system, ports.slot) is not None else []),
                   # Read once and rewritten compressed into the evaluation's log (logs.merge): compressing it here too would be wasted.
                   "--mcap-compression", "none",
                   # stop() stops the SUT before the simulator, with the simulator link still open.
                   "--linger-s", str(LINGER_S)]
    # Named after the leased simulator port, so unique on this machine while the lease lasts; in
    # the abstract namespace, so nothing is left behind however the processes end.
    sim_socket = f"@stella-sim-{ports.sim}" if transport in ("unix", "shm") else None
    if sim_socket is not None:
        bridge_argv += ["--sim-socket", sim_socket]
    if transport == "shm":
        bridge_argv.append("--sim-shared-memory")
    if inline:
        bridge_argv = [sys.executable, "-m", "sut_adapter.inline", *bridge_argv[3:], "--",
                       *system.inline_arguments(api_port=ports.api, workdir=workdir, params=options.sut.params)]
    session = MavsdkSession(ports.api + CLIENT_PORT_OFFSET)
    contexts.callback(session.close)
    bridge = contexts.enter_context(ManagedProcess("bridge", bridge_argv, log_dir=workdir))
    tap = contexts.enter_context(ApiTap(ports.api, ports.api + CLIENT_PORT_OFFSET))
    if inline:
        sut = SutHandle(name=system.name, alive=lambda: bridge.poll() is None, stop=lambda: bridge.poll(), stderr_tail=bridge.stderr_tail, pids=[])
    else:
        extra: dict[str, Any] = {"sim_socket": sim_socket} if sim_socket is not None else {}
        if sut_adapter.needs_world(system):
            extra["world"] = world
        if transport == "shm":
            extra["sim_shared_memory"] = True
        sut = system.start(sim_port=ports.sim, api_port=ports.api, instance=ports.slot, workdir=workdir, params=options.sut.params, spin_s=spin_s, **extra)

    def stop() -> None:
        session.close()
        sut_exit = sut.stop()
        if bridge_log is not None:  # a bridge flying one world ends by itself once its log is written
            bridge.wait(5.0)
        bridge.stop()
        log.info("sut exited with %s, bridge with %s", sut_exit, bridge.process.returncode)

    contexts.callback(stop)
    if options.pin_cpu:
        _pin(bridge.pid, sut.pids, ports.slot, cores)
    placement = {"cores": cores, "transport": transport}
    return Stack(ports, bridge, bridge_log, tap, sut, session, placement)


class _ServingStack:
    """A warm stack: the bridge with the SUT inside, serving flight after flight (its --serve),
    with its own directory for its logs and the SUT's files."""

    def __init__(self, contexts: ExitStack, stack: Stack):
        self._contexts = contexts
        self._stack = stack
        self._flight: Stack | None = None  # the last evaluation's, whose `clean` says if it may fly again

    @classmethod
    def start(cls, options: RunOptions, system: SystemUnderTest) -> "_ServingStack":
        home = Path(tempfile.mkdtemp(prefix="stella-warm-"))
        contexts = ExitStack()
        contexts.callback(shutil.rmtree, home, ignore_errors=True)
        try:
            return cls(contexts, _start(contexts, options, system, home, ["--serve", "--harness-pid", str(os.getpid())], None))
        except BaseException:
            contexts.close()
            raise

    def begin(self, bridge_log: Path, load: dict[str, str]) -> Stack:
        """The stack for one evaluation: MAVSDK's and the tap's records of the last one dropped."""
        self._stack.tap.restart()
        self._stack.session.restart()
        self._flight = replace(self._stack, bridge_log=bridge_log, load=load, clean=False)
        return self._flight

    def _flew_cleanly(self) -> bool:
        return self._flight is not None and self._flight.clean

    def reusable(self) -> bool:
        return self._flew_cleanly() and self._stack.bridge.poll() is None

    def close(self) -> None:
        bridge = self._stack.bridge
        if self._flew_cleanly() and bridge.poll() is not None:  # died between flights; its stderr goes with its folder
            log.warning("a kept simulator exited with %s after a clean flight: %s", bridge.poll(), bridge.stderr_tail())
        self._contexts.close()


def _keep_artifacts(files: list[Path], target: Path) -> list[str]:
    """Copy the SUT's artifacts out of the evaluation's temporary directory, beside its log."""
    kept = []
    for source in files:
        target.mkdir(parents=True, exist_ok=True)
        destination = target / source.name
        shutil.copy2(source, destination)
        kept.append(str(destination))
    return kept


def _pin(bridge_pid: int, sut_pids: list[int], slot: int, cores: int) -> None:
    """One core: both on core slot (modulo the cores there are). Two: the bridge on core 2*slot,
    the SUT on the next one."""
    available = sorted(os.sched_getaffinity(0))
    first = slot * cores
    placement = {bridge_pid: available[first % len(available)]}
    placement.update({pid: available[(first + cores - 1) % len(available)] for pid in sut_pids})
    for pid, core in placement.items():
        try:
            os.sched_setaffinity(pid, {core})
        except OSError as error:  # a process that already exited, or a restricted container
            log.debug("cannot pin %d to core %d: %s", pid, core, error)


def _fly(world: WorldSpec, options: RunOptions, stack: Stack, timings: dict[str, float], system: SystemUnderTest):
    """Returns (failure or None, bridge summary, MAVSDK observations)."""
    arm_retry_s = arm_retry_for(system)
    pilot_params, takeoff_altitude_param, _mode = sut_adapter.pilot_setup(system)
    bridge, sut, session = stack.bridge, stack.sut, stack.session
    t0 = time.monotonic()
    control = BridgeControl(stack.ports.control)
    try:
        if stack.load is not None:
            control.send(stack.load)
        alive = lambda: bridge.poll() is None and sut.alive()  # noqa: E731

        def discovered() -> tuple[str, str] | None:
            try:
                session.discover(options.setup_timeout_s, alive)
            except InfrastructureError as error:
                return _setup_failure(bridge, sut, control, str(error))
            timings["discover_s"] = time.monotonic() - t0
            return None

        def held() -> tuple[str, str] | None:
            if control.wait_for("holding", options.setup_timeout_s, alive) is None:
                refused = next((e["why"] for e in control.events if e.get("event") == "load_refused"), None)
                if refused is not None:  # as a cold-started simulator exits on a world it cannot load
                    return Status.SIM_CRASHED, f"the simulator refused the world: {refused}"
                return _setup_failure(bridge, sut, control, "the simulation never reached its hold point")
            timings["hold_s"] = time.monotonic() - t0
            return None

        # From a cold start MAVSDK finds the SUT while the simulation runs up to its hold; a warm
        # stack's session is connected already, to the fresh SUT once that has spoken, by the hold.
        for stage in (discovered, held) if stack.load is None else (held, discovered):
            failure = stage()
            if failure is not None:
                return failure, control_summary(control), {}
        try:
            session.set_params(sut.mavlink_params)
            if not sut_adapter.injects_failures(system):
                session.answer_without_injection = "UNSUPPORTED"  # each failure it is to be told of: failure_refused in /events
                session.failure_params = sut_adapter.failure_params(system)  # unless it fails the unit through its parameters
            elif any(f.delivery == "sut" for f in world.failures or ()):
                session.enable_failure_injection()  # as PX4, the bundled autopilot refuses injections without it
            if world.drive == "pilot":
                # A parameter the user set (--sut-param) is the user's to decide.
                session.set_params({name: value for name, value in pilot_params.items() if name not in options.sut.params})
            timings["healthy_after_s"] = session.wait_healthy(options.setup_timeout_s)
            if world.drive == "pilot":
                session.arm_and_take_off(world.mission.takeoff_altitude_m, arm_retry_s, takeoff_altitude_param)
            else:
                session.upload_and_start(mission_items(world, sut_adapter.mission_home_item(system)), arm_retry_s)
        except InfrastructureError as error:  # not healthy in time, a parameter refused
            return _setup_failure(bridge, sut, control, f"setup: {error}"), control_summary(control), {}
        except Exception as error:  # MAVSDK raises its own error type per plugin, each with a result
            if _unanswered(error):
                return _setup_failure(bridge, sut, control, f"setup: the SUT stopped answering: {error}"), control_summary(control), {}
            return (Status.SUT_CRASHED if not sut.alive() else Status.MISSION_FAILED, f"setup: the SUT refused: {error}"), control_summary(control), {}
        timings["setup_s"] = time.monotonic() - t0
        control.send({"op": "run"})
        deadline = world.time_limit_s / options.min_real_time_factor + 30.0
        finished = _fly_until_finished(control, session, deadline, lambda: bridge.poll() is None)
        timings["flight_wall_s"] = time.monotonic() - t0 - timings["setup_s"]
        info = {"status_texts": list(session.status_texts), "mission_progress": list(session.mission_progress)}
        if finished is None:
            if control.closed:
                bridge.wait(5.0)  # a simulator that died closed its control channel first: give it time to be seen exiting
            if bridge.poll() is not None:
                return (Status.SIM_CRASHED, f"simulator exited with {bridge.poll()}: {bridge.stderr_tail()}"), control_summary(control), info
            control.send({"op": "stop"})
            finished = control.wait_for("finished", 10.0, lambda: bridge.poll() is None)
            return (Status.TIMEOUT, f"no end within {deadline:.0f} s wall time"), finished or {}, info
        return None, finished, info
    finally:
        control.close()


def _fly_until_finished(control: BridgeControl, session: MavsdkSession, timeout_s: float, alive) -> dict[str, Any] | None:
    """The bridge's "finished" event, injecting each failure it asks for on the way."""
    deadline = time.monotonic() + timeout_s
    events = list(control.events)
    while True:
        for event in events:
            if event.get("event") == "finished":
                return event
            if event.get("event") == "inject_failure":
                control.send({"op": "failure_injected", "result": session.inject_failure(event["unit"], event["type"])})
        if time.monotonic() > deadline or control.closed or not alive():
            return None
        events = control.poll(0.05)


def control_summary(control: BridgeControl) -> dict[str, Any]:
    return next((e for e in control.events if e.get("event") == "finished"), {})


def _unanswered(error: Exception) -> bool:
    """Whether a MAVSDK error means no answer came (rather than an answer that said no)."""
    result = getattr(getattr(error, "result", None), "name", "")
    return result in ("TIMEOUT", "NO_SYSTEM", "CONNECTION_ERROR")


def _setup_failure(bridge: ManagedProcess, sut, control: BridgeControl, what: str) -> tuple[str, str]:
    if bridge.poll() is not None:
        return Status.SIM_CRASHED, f"{what}: simulator exited with {bridge.poll()}: {bridge.stderr_tail()}"
    if not sut.alive():
        return Status.SUT_CRASHED, f"{what}: SUT exited: {sut.stderr_tail()}"
    return Status.TIMEOUT, what
