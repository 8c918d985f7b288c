"""Fly one concrete scenario end to end and score it from its recording.

allocate a port block -> start the bridge and the SUT as real processes -> MAVSDK connects
through the API tap -> wait until the simulation holds and the SUT is healthy -> upload the
mission, arm, start -> release the simulation -> wait for its end -> stop everything -> merge
the log -> score from the log.
"""

from __future__ import annotations

import logging
import shutil
import signal
import time
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable, Iterator, Mapping, Sequence

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from harness.errors import InfrastructureError, InputError, Problem
from harness.flight import fitness as scoring
from harness.flight import logs, scratch
from harness.flight.api_tap import ApiTap
from harness.flight.bridge_control import BridgeControl
from harness.flight.fitness import COULD_NOT_FINISH, Status
from harness.flight.mavsdk_session import ACCEPTANCE_RADIUS_M, MavsdkSession, mission_items
from harness.flight.results import NOT_FLOWN, EvaluationResult, Failure, FlightOutcome, RunOptions, Score
from harness.flight.stack import Stack, simulation_stack
from harness.properties.signals import mode_of
from harness.scenario.space import SearchSpace
from harness.scenario.logical import DATA_LINK
from harness.scenario.rig import rig_problem_for
from harness.scenario.world import world_spec
from sim_bridge.control import EXIT_CUT_SHORT, NORMAL_ENDS, STEP_TIMERS, EndReason, FailureInjected, Finished, Holding, InjectFailure, Loaded, LoadRefused, Run, Stop
from sim_bridge.spec import WorldSpec
import sut_adapter
from sut_adapter import SutHandle, SystemUnderTest
from sut_adapter.processes import ManagedProcess

if TYPE_CHECKING:
    from harness.properties.spec import Property

log = logging.getLogger(__name__)

# How long a SUT whose simulated time runs on while it is set up (hold "paced": PX4) may deny
# arming before the denial counts: PX4's arming checks flicker just after its start-up. Held
# frozen, a SUT cannot change its mind, so its first answer counts.
ARM_RETRY_S = 10.0
SETUP_POLL_S = 0.005
PARAMS_APPLIED_NS = 300_000_000  # of the SUT's clock: many cycles of PX4's slowest module loops


def arm_retry_for(system: SystemUnderTest) -> float:
    """How long a flight (and `stella sut check`) asks again while this SUT denies arming."""
    return ARM_RETRY_S if system.capabilities.hold_mode == "paced" else 0.0


def _wait_until(done: Callable[[], bool], timeout_s: float, alive: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not done():
        if time.monotonic() > deadline or not alive():
            raise InfrastructureError(f"{what} within {timeout_s:.0f} s")
        time.sleep(SETUP_POLL_S)


def wait_for_sut_clock(tap: ApiTap, until_ns: int, timeout_s: float, alive: Callable[[], bool]) -> None:
    """Until the SUT's own clock (its time_boot_ms on the API link) reaches until_ns, or raise InfrastructureError."""
    _wait_until(lambda: tap.sut_time_ns >= until_ns, timeout_s, alive, f"the SUT's clock did not reach {until_ns / 1e9:.2f} s")


def wait_booted(sut: SutHandle, timeout_s: float, alive: Callable[[], bool]) -> None:
    """Until the SUT has finished starting up (SutHandle.booted), or raise InfrastructureError."""
    _wait_until(sut.booted, timeout_s, alive, "the SUT did not finish starting up")


def _reported_position_mode(from_sut: Iterable[bytes]) -> bool:
    """Whether the SUT's heartbeats on the API link (its datagrams) ever said Position mode (PX4
    custom main mode 3; ArduCopter's Loiter or PosHold, where its sticks steer the position and
    simple avoidance acts)."""
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    for datagram in from_sut:
        for message in parser.parse_buffer(datagram) or []:
            if message.get_type() != "HEARTBEAT" or message.type == mavlink.MAV_TYPE_GCS:
                continue
            if mode_of(message) == "position":
                return True
    return False


def _logged_api_traffic(log_path: Path) -> Iterator[tuple[int, str, bytes]]:
    """What the SUT sent on the API link, as recorded in an evaluation's log: (SUT time ns,
    "from_sut", datagram), as the API tap records it in flight."""
    for _t, ns, record in logs.messages(log_path, ["/mavlink/api"]):
        if record["direction"] == "from_sut":
            yield ns, "from_sut", bytes.fromhex(record["hex"])


def refused_failures(events: Iterable[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The failure injections the SUT refused, from the simulator's /events."""
    return [{"t": event["t"], "unit": event["detail"]["unit"], "type": event["detail"]["type"], "result": event["detail"]["result"]}
            for event in events if event.get("event") == "failure_refused"]


def _score(recorded: Callable[[Sequence[str]], Iterable[tuple[str, int, Any]]], world: WorldSpec, summary: Mapping[str, Any],
           failure: Failure | None, api_from_sut: Iterable[bytes], partial: bool = False) -> Score:
    """Status and fitness of a flight from the simulator's recording (recorded(topics): the
    bridge's or the merged log's messages) and what the SUT sent on the API link; of a partial
    (truncated) log, the clearance of what was recorded, as whether the mission was flown cannot
    be told from part of it."""
    if failure is None and not partial and summary.get("end_reason") == EndReason.BLOCKED and not _reported_position_mode(api_from_sut):
        # Not collision prevention holding the pilot back: the SUT ignored the mode switch.
        failure = Failure(Status.MISSION_FAILED, "the SUT never reported Position mode after the pilot's mode switch (does it read RC_CHANNELS?)")
    clearance = scoring.min_clearance(message for _t, _ns, message in recorded(["/clearance"]))
    if failure is None and clearance.samples and not partial:
        states = [message for _t, _ns, message in recorded(["/uav/state"])]
        why = scoring.mission_check(states, world.mission, ACCEPTANCE_RADIUS_M, summary, world.drive)
        failure = Failure(Status.MISSION_FAILED, why) if why else None
    status, value, why = scoring.judge(clearance, world.safety_distance_m, failure)
    return Score(status, value, why, clearance)


def scored_properties(properties: Sequence["Property"], recorded, api_records: Sequence[tuple[int, str, bytes]], world: WorldSpec) -> dict[str, dict[str, Any]]:
    """Each property's verdict and robustness over the flight's recording (as `stella inspect
    --property` scores its log)."""
    if not properties:
        return {}
    from harness.properties.monitor import verdicts
    from harness.properties.signals import extract

    return verdicts(properties, extract(recorded, ((ns, datagram) for ns, direction, datagram in api_records if direction == "from_sut"), world))


def properties_of_log(log_path: Path, properties: Sequence["Property"]) -> dict[str, dict[str, Any]]:
    """Each property's verdict and robustness from an evaluation's log alone, as its flight scored them."""
    world = logs.world_of(log_path)
    return scored_properties(properties, lambda topics: logs.messages(log_path, topics), list(_logged_api_traffic(log_path)), world)


def properties_explained(log_path: Path, properties: Sequence["Property"]) -> dict[str, dict[str, Any]]:
    """Each property's verdict and robustness from the log alone, with when it was decided and
    its signals then (harness/properties/monitor.py: decided)."""
    from harness.properties.monitor import decided, verdicts
    from harness.properties.signals import extract

    world = logs.world_of(log_path)
    api = list(_logged_api_traffic(log_path))
    series = extract(lambda topics: logs.messages(log_path, topics), ((ns, datagram) for ns, _direction, datagram in api), world)
    return {name: {**scored, "decided": decided(prop, series)} for prop, (name, scored) in zip(properties, verdicts(properties, series).items())}


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
        failure = Failure(Status(recorded["status"]), recorded.get("why") or "")
    score = _score(lambda topics: logs.messages(log_path, topics), world, summary, failure, (datagram for _ns, _direction, datagram in _logged_api_traffic(log_path)), partial=cut is not None)
    return {"status": score.status, "fitness": score.fitness, "why": score.why, "clearance": score.clearance, "world": world, "summary": summary,
            "recorded": recorded,
            "truncation": cut, "failures_refused": refused_failures(m for _t, _ns, m in logs.messages(log_path, ["/events"]))}


def infeasible(space: SearchSpace, x: np.ndarray, *, seed: int, sut: str) -> EvaluationResult | None:
    """The result of a point that breaks a realism constraint (never flown), or None if it breaks none."""
    violations = space.violations(x)
    if not violations:
        return None
    total = -sum(min(0.0, float(m[0])) for m in space.constraint_margins(np.asarray(x)[None, :]).values())
    return EvaluationResult(status=Status.INFEASIBLE, fitness=scoring.infeasible_fitness(total), why="; ".join(violations), min_clearance_m=None,
                            min_clearance_at_s=None, min_clearance_obstacle=None, sim_time_s=0.0, wall_time_s=0.0, real_time_factor=None, seed=seed,
                            log_path=None, scenario=space.logical.name, sut=sut, violations=violations)


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
    workdir = scratch.folder(stem)
    log_path = out_dir / f"{stem}.mcap"
    kept_dir = out_dir / f"{stem}.artifacts"
    timings: dict[str, float] = {}
    outcome = NOT_FLOWN
    artifacts: list[str] = []
    flight_logs: list[Path] = []

    def finish(score: Score, log_path: Path | None, failures_refused: list[dict[str, Any]] | None = None,
               properties: dict[str, dict[str, Any]] | None = None, coverage: dict[str, Any] | None = None) -> EvaluationResult:
        summary = outcome.summary
        in_run = summary.get("wall_in_run_s") or 0.0
        run_time = summary.get("run_time_s") or 0.0
        clearance = score.clearance
        return EvaluationResult(
            status=score.status,
            fitness=score.fitness,
            why=score.why,
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
            timings={**timings, **{k: summary[k] for k in (*STEP_TIMERS, "wall_in_run_s") if k in summary}},
            mavsdk=dict(outcome.mavsdk),
            failures_refused=failures_refused or [],
            first_touchdown_s=summary.get("first_touchdown_s"),
            properties=properties or {},
            coverage=coverage,
        )

    try:
        system = sut_adapter.system_for(options.sut)
        world = system.capabilities.with_failure_deliveries(world)
        if world.rig:
            problem = rig_problem_for({"name": "flown", "sensors": [asdict(sensor) for sensor in world.rig]}, system.name, system.capabilities)
            if problem is not None:
                raise sut_adapter.SutError(system.name, f"cannot read the {problem}")
        started = time.monotonic()
        with simulation_stack(world, options, system, workdir) as stack:
            timings["start_s"] = time.monotonic() - started
            outcome = _fly(world, options, stack, timings, system)
            # Inside the stack: once it stops the SUT, the exit status is the harness's own SIGTERM.
            lost = _sut_lost(stack.sut, outcome.summary, stack.session.last_request) if outcome.end_reason is not None and outcome.end_reason.sut_lost else ""
            stack.clean = outcome.failure is None and outcome.end_reason in NORMAL_ENDS
            stopping = time.monotonic()
        timings["stop_s"] = time.monotonic() - stopping
        failure = outcome.failure
        if failure is None and lost:
            failure = Failure(Status.SUT_CRASHED, lost)
        # The SUT's consoles (*.log) are always kept; its own flight log (a PX4 ULog, about 19 MB)
        # as --sut-logs chooses, once the flight's status is known.
        sut_files = stack.sut.artifacts()
        consoles = [path for path in sut_files if path.suffix == ".log"]
        flight_logs = [path for path in sut_files if path.suffix != ".log"]
        artifacts = _keep_artifacts(consoles, kept_dir)
        api_records = list(stack.tap.records)
        if not stack.bridge_log.exists() or stack.bridge_log.stat().st_size == 0:
            raise InfrastructureError(f"the simulator wrote no log: {stack.bridge.stderr_tail()}")
        t0 = time.monotonic()
        # Scored from the simulator's own recording, read once; the log is then written once, result included.
        recording = logs.Recording(stack.bridge_log)
        api_from_sut = (datagram for _ns, direction, datagram in api_records if direction == "from_sut")
        score = _score(recording.messages, world, outcome.summary, failure, api_from_sut)
        properties = scored_properties(options.properties, recording.messages, api_records, world)
        timings["score_s"] = time.monotonic() - t0
        if options.keeps_sut_log(score.status, outcome.end_reason):
            artifacts = _keep_artifacts(flight_logs, kept_dir) + artifacts
        result = finish(score, log_path, refused_failures(m for _t, _ns, m in recording.messages(["/events"])), properties, stack.sut.coverage())
        logs.merge(recording, log_path, api_records=api_records, extra_metadata={
            "concrete_scenario": concrete, "result": result.as_dict(),
            "sut": options.sut.identity(), "placement": stack.placement,
        })
        return result
    except sut_adapter.SutError as error:
        log.warning("evaluation %s: the SUT failed to start: %s", stem, error)
        return finish(Score(Status.SUT_CRASHED, scoring.PENALTY, str(error), None), None)
    except InfrastructureError as error:
        log.warning("evaluation %s failed: %s", stem, error)
        if options.keeps_sut_log(Status.SIM_CRASHED, outcome.end_reason):
            artifacts = _keep_artifacts(flight_logs, kept_dir) + artifacts
        return finish(Score(Status.SIM_CRASHED, scoring.PENALTY, str(error), None), None)
    finally:
        if not options.keep_workdir:
            shutil.rmtree(workdir, ignore_errors=True)


def _keep_artifacts(files: list[Path], target: Path) -> list[str]:
    """Copy the SUT's artifacts out of the evaluation's temporary directory, beside its log."""
    kept = []
    for source in files:
        target.mkdir(parents=True, exist_ok=True)
        destination = target / source.name
        shutil.copy2(source, destination)
        kept.append(str(destination))
    return kept


def _fly(world: WorldSpec, options: RunOptions, stack: Stack, timings: dict[str, float], system: SystemUnderTest) -> FlightOutcome:
    """Set the SUT up while the simulation holds, release it and see the flight to its end."""
    arm_retry_s = arm_retry_for(system)
    takeoff_altitude_param = system.capabilities.takeoff_altitude_param
    bridge, sut, session = stack.bridge, stack.sut, stack.session
    t0 = time.monotonic()
    control = BridgeControl(stack.ports.control)
    try:
        alive = lambda: bridge.poll() is None and sut.alive()  # noqa: E731
        if stack.load is not None:
            control.send(stack.load)
            # Until the simulator has begun the flight, stopping it (as after a SUT that died at
            # once) would leave the flight without a log.
            loaded = control.wait_for((Loaded, LoadRefused), options.setup_timeout_s, lambda: bridge.poll() is None)
            if isinstance(loaded, LoadRefused):
                return FlightOutcome(Failure(Status.SIM_CRASHED, f"the simulator refused the world: {loaded.why}"), control_summary(control), {})
            if loaded is None:
                return FlightOutcome(_setup_failure(stack, control, "the simulator did not begin the flight"), control_summary(control), {})

        def discovered() -> Failure | None:
            try:
                session.discover(options.setup_timeout_s, alive)
            except InfrastructureError as error:
                return _setup_failure(stack, control, str(error))
            timings["discover_s"] = time.monotonic() - t0
            return None

        def held() -> Failure | None:
            if control.wait_for(Holding, options.setup_timeout_s, alive) is None:
                return _setup_failure(stack, control, "the simulation never reached its hold point")
            timings["hold_s"] = time.monotonic() - t0
            return None

        # From a cold start MAVSDK finds the SUT while the simulation runs up to its hold; a warm
        # simulator starts that run on the load request, by when MAVSDK has found the fresh SUT too
        # (a session kept with a SUT in memory reconnects to it once that has spoken).
        for stage in (discovered, held) if stack.load is None else (held, discovered):
            failure = stage()
            if failure is not None:
                return FlightOutcome(failure, control_summary(control), {})
        try:
            wait_booted(sut, options.setup_timeout_s, alive)
            session.set_params(sut.mavlink_params)
            if not system.capabilities.injects_failures:
                session.answer_without_injection = "UNSUPPORTED"  # each failure it is to be told of: failure_refused in /events
                session.failure_params = system.capabilities.failure_params  # unless it fails the unit through its parameters
            injecting = system.capabilities.injects_failures and any(f.delivery == "sut" for f in world.failures or ())
            if injecting:
                session.enable_failure_injection()  # as PX4, the bundled autopilot refuses injections without it
            # A SUT that took them with its start (params_at_start) has them already.
            flight_params = {} if system.capabilities.params_at_start else system.capabilities.flight_params(world)
            # A parameter the user set (--sut-param) is the user's to decide.
            session.set_params({name: value for name, value in flight_params.items() if name not in options.sut.params})
            params_acknowledged_ns = stack.tap.sut_time_ns
            set_over_mavlink = bool(sut.mavlink_params or flight_params or injecting)
            timings["healthy_after_s"] = session.wait_healthy(options.setup_timeout_s)
            if set_over_mavlink and system.capabilities.hold_mode == "paced" and params_acknowledged_ns > 0:  # 0: no clock on its API link
                # PX4's modules apply a parameter some steps after MAVLink acknowledged it: with
                # MIS_TAKEOFF_ALT set 3-10 ms before the take-off command, PX4 took off to its
                # default 2.5 m in 495 of 720 pilot flights (the CP mutants' screening, 2026-11),
                # and still in 2 of 12 with it set before a health wait that found PX4 healthy at
                # once. Its clock runs during a paced hold, so this wait costs milliseconds. Even
                # so its navigator missed MIS_TAKEOFF_ALT set 0.4 s of its clock before: a SUT
                # that can takes the flight's parameters with its start (params_at_start).
                wait_for_sut_clock(stack.tap, params_acknowledged_ns + PARAMS_APPLIED_NS, options.setup_timeout_s, alive)
            if world.drive == "pilot":
                session.arm_and_take_off(arm_retry_s, None if takeoff_altitude_param else world.mission.takeoff_altitude_m)
            else:
                session.upload_and_start(mission_items(world, system.capabilities.mission_home_item), arm_retry_s)
        except InfrastructureError as error:  # not healthy in time, a parameter refused
            return FlightOutcome(_setup_failure(stack, control, f"setup: {error}"), control_summary(control), {})
        except Exception as error:  # MAVSDK raises its own error type per plugin, each with a result
            if _unanswered(error):
                return FlightOutcome(_setup_failure(stack, control, f"setup: the SUT stopped answering: {error}"), control_summary(control), {})
            refused = (Failure(Status.SUT_CRASHED, f"setup: {sut.how_it_ended()} ({error})") if not sut.alive()
                       else Failure(Status.MISSION_FAILED, f"setup: the SUT refused: {error}"))
            return FlightOutcome(refused, control_summary(control), {})
        timings["setup_s"] = time.monotonic() - t0
        sut_cpu_at_run = sut.cpu_s()
        control.send(Run())
        deadline = world.time_limit_s / options.min_real_time_factor + 30.0
        finished = _fly_until_finished(control, session, stack.tap, deadline, lambda: bridge.poll() is None)
        timings["flight_wall_s"] = time.monotonic() - t0 - timings["setup_s"]
        sut_cpu_at_end = sut.cpu_s()
        if sut_cpu_at_run is not None and sut_cpu_at_end is not None:
            # What the SUT computed over the steps the real-time factor counts (`stella bench` per step).
            timings["sut_cpu_in_run_s"] = sut_cpu_at_end - sut_cpu_at_run
        info = {"status_texts": list(session.status_texts), "mission_progress": list(session.mission_progress)}
        if finished is None:
            if control.closed:
                bridge.wait(5.0)  # a simulator that died closed its control channel first: give it time to be seen exiting
            crashed = _crash(bridge, sut, "in flight", control, last_request=session.last_request)
            if crashed is not None:
                return FlightOutcome(crashed, control_summary(control), info)
            control.send(Stop())
            finished = control.wait_for(Finished, 10.0, lambda: bridge.poll() is None)
            return FlightOutcome(Failure(Status.TIMEOUT, f"no end within {deadline:.0f} s wall time"), finished.summary if finished else {}, info)
        return FlightOutcome(None, finished.summary, info)
    finally:
        control.close()


def _fly_until_finished(control: BridgeControl, session: MavsdkSession, tap: ApiTap, timeout_s: float, alive) -> Finished | None:
    """The bridge's Finished event, injecting each failure it asks for on the way: the data link's
    by silencing the API tap, every other through the SUT's own means."""
    deadline = time.monotonic() + timeout_s
    events = list(control.events)
    while True:
        for event in events:
            if isinstance(event, Finished):
                return event
            if isinstance(event, InjectFailure) and event.unit == DATA_LINK:
                tap.blackout = event.type != "ok"
                control.send(FailureInjected("SUCCESS"))
            elif isinstance(event, InjectFailure):
                control.send(FailureInjected(session.inject_failure(event.unit, event.type)))
        if time.monotonic() > deadline or control.closed or not alive():
            return None
        events = control.poll(0.05)


def control_summary(control: BridgeControl) -> Mapping[str, Any]:
    finished = control.seen(Finished)
    return finished.summary if finished is not None else {}


def _unanswered(error: Exception) -> bool:
    """Whether a MAVSDK error means no answer came (rather than an answer that said no)."""
    result = getattr(getattr(error, "result", None), "name", "")
    return result in ("TIMEOUT", "NO_SYSTEM", "CONNECTION_ERROR")


SIMULATOR_VERDICT_WAIT_S = 5.0


def _setup_failure(stack: Stack, control: BridgeControl, what: str) -> Failure:
    return _crash(stack.bridge, stack.sut, what, control, last_request=stack.session.last_request) or Failure(Status.TIMEOUT, what)


def _crash(bridge: ManagedProcess, sut: SutHandle, what: str, control: BridgeControl | None = None, *, last_request: str | None = None) -> Failure | None:
    """Which of the two died or stopped, if one did. A SUT that dies closes its simulator link,
    and the simulator then ends its flight and exits (EXIT_CUT_SHORT): by the time the harness
    looks, both may be gone. So a SUT that died of a signal crashed the flight whatever the
    simulator did afterwards (but SIGPIPE, which a simulator that went first sends), as does one
    that exited where the simulator cut the flight short, or one the simulator saw stop
    answering (`finished`, its summary); otherwise a simulator that exited crashed it. A
    simulator still running is given a moment to say why it ends: it gives up on a SUT that never
    connected after as long as the harness waits for the SUT's heartbeat, and exits just after.
    (Without a control channel the simulator said nothing.)"""
    sut_status = sut.settled_exit_status()
    if control is not None:
        control.wait_for(Finished, SIMULATOR_VERDICT_WAIT_S, lambda: bridge.poll() is None)
    simulator_status = bridge.poll()
    finished = control.heard(Finished) if control is not None else None
    died_of_its_own = sut_status is not None and sut_status < 0 and -sut_status != signal.SIGPIPE
    if sut_status is not None and (died_of_its_own or simulator_status in (None, EXIT_CUT_SHORT)):
        return Failure(Status.SUT_CRASHED, f"{what}: {sut.how_it_ended()}")
    if finished is not None and (finished.summary["end_reason"].sut_lost or finished.summary["end_reason"] == EndReason.SUT_NEVER_CONNECTED):
        return Failure(Status.SUT_CRASHED, _sut_lost(sut, finished.summary, last_request))
    if simulator_status is not None:
        return Failure(Status.SIM_CRASHED, f"{what}: simulator exited with {simulator_status}: {bridge.stderr_tail()}")
    if not sut.alive():
        return Failure(Status.SUT_CRASHED, f"{what}: {sut.how_it_ended()}")
    return None


def _sut_lost(sut: SutHandle, summary: Mapping[str, Any], last_request: str | None) -> str:
    """What the simulator saw of a SUT it lost, when, and what the harness had last asked of it,
    before the end of its console: a stalled PX4's last line is often start-up noise printed
    long before ("uxrce_dds_client: not found")."""
    what = {EndReason.SUT_STALLED: "stopped answering its simulator link", EndReason.SUT_DISCONNECTED: "closed its simulator link",
            EndReason.SUT_NEVER_CONNECTED: "never connected to its simulator link"}[summary["end_reason"]]
    run_time_s = summary.get("run_time_s") or 0.0
    when = (f" {run_time_s:.1f} s into the flight" if run_time_s > 0.0
            else "" if summary["end_reason"] == EndReason.SUT_NEVER_CONNECTED
            else f" in set-up, {summary.get('sim_time_s', 0.0):.1f} s of simulated time after it started")
    return f"{sut.name} {what}{when}" + (f", after {last_request}" if last_request else "") + f"; {sut.how_it_ended()}"
