"""One evaluation's running parts and where they run: the simulator, the API tap, the SUT and
MAVSDK on a free port block, placed on the evaluation's cores with the transport that carries
the simulator link (RunOptions.transport, .cores), and a warm stack kept for the next flight.

Warm stacks: starting an evaluation's simulator process costs 0.3-0.4 s of one core in Python
imports before the flight begins, and MAVSDK a connection; a campaign pays that on every
evaluation. A process that flies evaluation after evaluation with the same options (but for
which SUT, where the SUT runs in a process of its own) keeps one stack (the simulator serving
flight after flight, with the SUT inside it or a fresh SUT process connecting to it for each)
and hands it to the next evaluation if the last flight ended cleanly. Up to two stacks per
process (KEPT_STACKS), for the two kinds of flight a screened campaign alternates; a third
closes the least recently used. The owner of the process closes what is kept (`close_kept`)
before it exits or when its campaign ends.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import sys
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Iterator

from harness.flight import scratch
from harness.flight.api_tap import ApiTap
from harness.flight.mavsdk_session import MavsdkSession
from harness.flight.ports import PortBlock, PortLease
from harness.flight.results import RunOptions
from sim_bridge.control import Load
from sim_bridge.spec import WorldSpec
from simlink import shared_memory
import sut_adapter
from sut_adapter import SutConfig, SutHandle, SystemUnderTest
from sut_adapter.processes import ManagedProcess

log = logging.getLogger(__name__)

CLIENT_PORT_OFFSET = 1000  # MAVSDK listens here, behind the API tap
# With a core each, the simulator and the SUT poll this long for each other's next message
# before sleeping: far longer than a lockstep turn, short enough to idle during setup.
LOCKSTEP_SPIN_S = 0.002
# After its flight the simulator keeps the SUT's link open until the SUT has gone, at most this
# long: longer than stopping the SUT can take (ManagedProcess.stop's two grace periods).
LINGER_S = 5.0

@dataclass
class Stack:
    """One evaluation's running parts: its port block, the simulator, the API tap, the SUT and MAVSDK."""

    ports: PortBlock
    bridge: ManagedProcess
    bridge_log: Path
    tap: ApiTap
    sut: SutHandle
    session: MavsdkSession
    # Where it runs: {"cores": N, "transport": "memory" | "unix" | "shm" | "tcp"}, as the log records it.
    placement: dict[str, Any]
    # A warm stack's simulator serves flight after flight: this one starts when it gets this request.
    load: Load | None = None
    # Set once the flight ended normally: a warm stack may then fly the next evaluation.
    clean: bool = False


def cores_for(options: RunOptions) -> int:
    """The cores an evaluation gets: those it may use, as far as this machine has them."""
    return min(options.cores, len(os.sched_getaffinity(0)))


def transport_problem(transport: str, system: SystemUnderTest) -> str | None:
    """Why this SUT cannot fly over this transport (None: it can)."""
    if transport in ("memory", "unix", "shm") and transport not in system.capabilities.transports:
        how = "runs in a process of its own" if transport == "memory" else "connects to the simulator over TCP"
        return f"{transport} carries the bundled autopilot only; {system.name} {how}: use --transport tcp"
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


def serves_warm(options: RunOptions, system: SystemUnderTest) -> bool:
    """Whether a warm evaluation (RunOptions.warm) can keep its simulator for the next one: a
    SUT in memory is served with it, one in a process of its own connects to it anew for each
    flight over a connection (not ArduPilot's JSON link, whose UDP port would still hold the
    last SUT's datagrams)."""
    return in_memory(options, system) or system.capabilities.sim_protocol == "mavlink"


def _kept_for(options: RunOptions, system: SystemUnderTest) -> str:
    """What a kept stack serves: the options it was started with; for a SUT started with each
    flight, not which SUT (mutation analysis and differential search alternate builds of PX4
    in a worker), only what the simulator was started for."""
    if in_memory(options, system):
        return repr(options)
    return repr((replace(options, sut=SutConfig()), system.capabilities))


@contextmanager
def simulation_stack(world: WorldSpec, options: RunOptions, system: SystemUnderTest, workdir: Path) -> Iterator[Stack]:
    """Start the bridge, the API tap and the SUT on a free port block, with MAVSDK listening;
    on exit close MAVSDK and stop the SUT and the bridge (the bridge finishes its log first).
    With options.warm, a simulator kept from this process's last evaluation flies it instead
    (serves_warm), and is kept for the next if the flight ended cleanly."""
    world_path = workdir / "world.json"
    world_path.write_text(json.dumps(world.as_dict()))
    bridge_log = workdir / "bridge.mcap"
    if options.warm and serves_warm(options, system):
        with _reuse(_kept_for(options, system), lambda: _ServingStack.start(options, system)) as serving:
            with serving.flight(bridge_log, Load(world=str(world_path), mcap=str(bridge_log)), world, workdir, options, system) as stack:
                yield stack
        return
    with ExitStack() as contexts:
        ports = _lease(contexts, options, system)
        session = _listening_session(contexts, ports)
        simulator = _Simulator.start(contexts, ports, options, system, workdir, (world_path, bridge_log))
        sut = simulator.start_sut(contexts, options, system, workdir, world, session)
        yield Stack(ports, simulator.bridge, bridge_log, simulator.tap, sut, session, simulator.placement)


def _lease(contexts: ExitStack, options: RunOptions, system: SystemUnderTest) -> PortBlock:
    """A free port block, released when contexts close; for a SUT that can run only so many
    instances at once, one of its slots."""
    limited = system.capabilities.instance_count
    return contexts.enter_context(PortLease(slots=limited, wait_s=options.setup_timeout_s) if limited else PortLease())


def _listening_session(contexts: ExitStack, ports: PortBlock) -> MavsdkSession:
    """MAVSDK behind the tap, listening before any SUT can speak, closed when contexts close."""
    session = MavsdkSession(ports.api + CLIENT_PORT_OFFSET)
    contexts.callback(session.close)
    return session


@dataclass
class _Simulator:
    """The bridge on its port block with the API tap before it, placed for the SUT that flies with
    it: what a warm stack keeps between flights."""

    ports: PortBlock
    bridge: ManagedProcess
    tap: ApiTap
    transport: str
    cores: int
    spin_s: float
    sim_socket: str | None  # the Unix-domain socket that carries the simulator link, if one does
    serving: bool  # flying world after world (--serve): it goes on after a flight, and the SUT stops without it
    flown: bool = False  # a SUT was started to fly with it

    @classmethod
    def start(cls, contexts: ExitStack, ports: PortBlock, options: RunOptions, system: SystemUnderTest, workdir: Path,
              flying: tuple[Path, Path] | None) -> "_Simulator":
        """Started on the port block, stopped when contexts close: python -m sim_bridge flying
        one world and recording it (flying: the world's file and the log's), or serving world
        after world (None)."""
        capabilities = system.capabilities
        serving = flying is None
        run_arguments = ["--serve", "--harness-pid", str(os.getpid())] if serving else ["--world", str(flying[0]), "--mcap", str(flying[1])]
        transport = placed_transport(options, system)
        inline = transport == "memory"
        # In memory the SUT steps inside the bridge: one process, one core, nobody to poll for.
        cores = 1 if inline else cores_for(options)
        spin_s = LOCKSTEP_SPIN_S if cores >= 2 else 0.0
        rc_port = capabilities.rc_port(ports.slot)
        companion_port = capabilities.companion_port(ports.slot)
        bridge_argv = [sys.executable, "-m", "sim_bridge", *run_arguments, "--sim-port", str(ports.sim), "--control-port", str(ports.control),
                       "--rate-hz", str(options.rate_hz or capabilities.rate_hz), "--hold-after-s", str(options.hold_after_s), "--hold-mode", capabilities.hold_mode,
                       "--hold-pace", str(capabilities.hold_pace),
                       "--range-messages", ",".join(capabilities.range_messages), "--spin-us", str(spin_s * 1e6),
                       "--sim-protocol", capabilities.sim_protocol,
                       *(["--rc-port", str(rc_port)] if rc_port is not None else []),
                       *(["--companion-port", str(companion_port), "--companion-messages", ",".join(capabilities.companion_messages)]
                         if companion_port is not None else []),
                       *(["--companion-connects"] if companion_port is not None and capabilities.companion_connects else []),
                       "--distance-sensor-convention", capabilities.distance_sensor_convention,
                       *(["--lockstep-from-start"] if capabilities.answers_every_step else []),
                       *(["--answer-times-echoed"] if capabilities.echoes_step_time else []),
                       # Read once and rewritten compressed into the evaluation's log (logs.merge): compressing it here too would be wasted.
                       "--mcap-compression", "none",
                       # The SUT is stopped before the simulator's flight is over, with the simulator link still open.
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
        bridge = contexts.enter_context(ManagedProcess("bridge", bridge_argv, log_dir=workdir))
        simulator = cls(ports, bridge, contexts.enter_context(ApiTap(ports.api, ports.api + CLIENT_PORT_OFFSET)), transport, cores, spin_s,
                        sim_socket, serving)
        if options.pin_cpu:
            pin_process(bridge.pid, placed_cores(ports.slot, cores)[0])
        contexts.callback(simulator._stop)
        return simulator

    def _stop(self) -> None:
        """After its SUT has stopped and before the tap closes: a simulator that flew one world
        ends by itself once its log is written (one whose SUT never started waits for none)."""
        if self.flown and not self.serving:
            self.bridge.wait(5.0)
        self.bridge.stop()
        log.info("bridge exited with %s", self.bridge.process.returncode)

    @property
    def placement(self) -> dict[str, Any]:
        return {"cores": self.cores, "transport": self.transport}

    def start_sut(self, contexts: ExitStack, options: RunOptions, system: SystemUnderTest, workdir: Path, world: WorldSpec | None,
                  session: MavsdkSession) -> SutHandle:
        """The SUT that flies with this simulator (world: the one it flies, for a SUT that takes
        it with its start), stopped when contexts close, after session (MAVSDK is not to hear it
        go); a SUT in memory runs inside the bridge's process, which started it."""
        bridge = self.bridge
        self.flown = True
        if self.transport == "memory":
            contexts.callback(session.close)
            return SutHandle(name=system.name, alive=lambda: bridge.poll() is None, stop=lambda: bridge.poll(), stderr_tail=bridge.stderr_tail, pids=[])
        capabilities = system.capabilities
        extra: dict[str, Any] = {"sim_socket": self.sim_socket} if self.sim_socket is not None else {}
        if capabilities.needs_world:
            extra["world"] = world
        if capabilities.params_at_start and world is not None:
            extra["flight_params"] = capabilities.flight_params(world)
        if self.transport == "shm":
            extra["sim_shared_memory"] = True
        started: list[SutHandle] = []

        def stop() -> None:
            session.close()
            for sut in started:
                log.info("sut exited with %s", sut.stop())

        # Registered first: a time limit may land between the SUT's start and the next line.
        contexts.callback(stop)
        sut = system.start(sim_port=self.ports.sim, api_port=self.ports.api, instance=self.ports.slot, workdir=workdir, params=options.sut.params,
                           spin_s=self.spin_s, **extra)
        started.append(sut)
        if options.pin_cpu:
            for pid in sut.pids:
                pin_process(pid, placed_cores(self.ports.slot, self.cores)[1])
        return sut


class _ServingStack:
    """A warm stack: the bridge serving flight after flight (its --serve), with the SUT inside
    it or a fresh SUT process for each flight, and with its own directory for its logs (and the
    SUT's files when it is inside)."""

    def __init__(self, contexts: ExitStack, simulator: _Simulator, inline: tuple[SutHandle, MavsdkSession] | None):
        self._contexts = contexts
        self._simulator = simulator
        self._inline = inline
        self._flights = 0
        self._flight: Stack | None = None  # the last flight's once it began, whose `clean` says if it may fly again

    @classmethod
    def start(cls, options: RunOptions, system: SystemUnderTest) -> "_ServingStack":
        home = scratch.folder("warm")
        contexts = ExitStack()
        contexts.callback(shutil.rmtree, home, ignore_errors=True)
        try:
            ports = _lease(contexts, options, system)
            # In memory each flight's autopilot is fresh but the API link's port is the same:
            # MAVSDK stays, its system found once. A SUT process of its own gets one of its own.
            session = _listening_session(contexts, ports) if in_memory(options, system) else None
            simulator = _Simulator.start(contexts, ports, options, system, home, None)
            inline = (simulator.start_sut(contexts, options, system, home, None, session), session) if session is not None else None
            return cls(contexts, simulator, inline)
        except BaseException:
            contexts.close()
            raise

    @contextmanager
    def flight(self, bridge_log: Path, load: Load, world: WorldSpec, workdir: Path, options: RunOptions, system: SystemUnderTest) -> Iterator[Stack]:
        """The stack for one evaluation, the tap's records of the last one dropped. With the SUT
        inside the simulator, the simulator gives the flight a fresh autopilot and MAVSDK stays,
        its records dropped. Otherwise a SUT process of its own (options.sut's, which may differ
        from the last flight's) is started for it in workdir, as from a cold start, and stopped
        after it, with a MAVSDK of its own, which has heard no other."""
        simulator = self._simulator
        self._flights += 1
        self._flight = None  # unfit until this flight has ended cleanly
        simulator.tap.restart()
        with ExitStack() as contexts:
            if self._inline is not None:
                sut, session = self._inline
                session.restart()
            else:
                session = _listening_session(contexts, simulator.ports)
                sut = simulator.start_sut(contexts, options, system, workdir, world, session)
            self._flight = Stack(simulator.ports, simulator.bridge, bridge_log, simulator.tap, sut, session, simulator.placement, load)
            yield self._flight

    def _fit(self) -> bool:
        """Whether it may fly the next evaluation as far as its flights tell: none yet, or the
        last ended cleanly."""
        return self._flights == 0 or (self._flight is not None and self._flight.clean)

    def reusable(self) -> bool:
        return self._fit() and self._simulator.bridge.poll() is None

    def close(self) -> None:
        bridge = self._simulator.bridge
        if self._fit() and bridge.poll() is not None:  # died between flights; its stderr goes with its folder
            log.warning("a kept simulator exited with %s after a clean flight: %s", bridge.poll(), bridge.stderr_tail())
        self._contexts.close()


# Stacks kept warm in this process, the most recently used last: two, as a screened campaign's
# worker alternates the subject and the cheap model batch by batch (harness/campaigns/screen.py),
# and a differential one's may alternate a bundled reference and a PX4 subject.
KEPT_STACKS = 2
_kept: list[tuple[str, "_ServingStack"]] = []  # (the options it was started for, the stack)


@contextmanager
def _reuse(key: str, start: Callable[[], "_ServingStack"]) -> Iterator["_ServingStack"]:
    """The stack kept for key if it is still fit, else a new one from start(); kept again
    afterwards if it is still fit then, closing the least recently used beyond KEPT_STACKS.
    Whatever is not kept is closed, however the body ends (an executor's time limit arrives as
    an exception at any point)."""
    stack = None
    try:
        for index, (kept_key, kept) in enumerate(_kept):
            if kept_key == key:
                del _kept[index]
                if kept.reusable():
                    stack = kept
                else:
                    _close(kept)
                break
        if stack is None:
            stack = start()
        yield stack
        if stack.reusable():
            _kept.append((key, stack))
            stack = None
            while len(_kept) > KEPT_STACKS:
                _close(_kept.pop(0)[1])
    finally:
        if stack is not None:
            _close(stack)


def start_kept(options: RunOptions) -> None:
    """Start now the stack that warm evaluations with these options keep, unless one is kept
    for them: the first of them then flies as the rest do (`stella run --repeat`, whose repeats
    are compared; PX4's flights follow the wall clock, which a simulator's start would share)."""
    try:
        system = sut_adapter.system_for(options.sut)
    except sut_adapter.SutError:
        return  # the evaluation says so
    if serves_warm(options, system):
        with _reuse(_kept_for(options, system), lambda: _ServingStack.start(options, system)):
            pass  # a stack that has flown nothing yet is fit to be kept


def close_kept() -> None:
    """Close the stacks this process kept warm, if any."""
    while _kept:
        _close(_kept.pop()[1])


def _close(stack: "_ServingStack") -> None:
    try:
        stack.close()
    except Exception as error:  # closing is best effort: its processes die with this one anyway
        log.warning("closing a kept stack failed: %s", error)


def placed_cores(slot: int, cores: int) -> tuple[int, int]:
    """(the bridge's core, the SUT's core). One core: both on core slot (modulo the cores there
    are). Two: the bridge on core 2*slot, the SUT on the next one."""
    available = sorted(os.sched_getaffinity(0))
    first = slot * cores
    return available[first % len(available)], available[(first + cores - 1) % len(available)]


def pin_process(pid: int, core: int) -> None:
    """Every thread of pid on core: a SUT's threads started before it was pinned keep the
    affinity they were born with (16 of PX4's 28 were, now and then, free to run on the bridge's
    core, and such flights ran at half speed)."""
    try:
        _pin_threads(pid, core)
    except OSError as error:  # a process that already exited, or a restricted container
        log.debug("cannot pin %d to core %d: %s", pid, core, error)


PINNING_PASSES = 5


def _pin_threads(pid: int, core: int) -> None:
    """Pin every thread of pid to core; again while a pass finds one that was not yet, as an
    unpinned thread may start another meanwhile (one started by a pinned thread inherits)."""
    try:
        tasks = [int(task) for task in os.listdir(f"/proc/{pid}/task")]
    except FileNotFoundError:  # no /proc: its first thread, as the system call alone can
        os.sched_setaffinity(pid, {core})
        return
    for _ in range(PINNING_PASSES):
        unpinned = [tid for tid in tasks if _affinity(tid) != {core}]
        if not unpinned:
            return
        for tid in unpinned:
            try:
                os.sched_setaffinity(tid, {core})
            except ProcessLookupError:  # a thread that ended meanwhile
                pass
            except OSError as error:  # one thread we may not move: the others still go
                log.debug("cannot pin thread %d of %d to core %d: %s", tid, pid, core, error)
        tasks = [int(task) for task in os.listdir(f"/proc/{pid}/task")]
    log.debug("threads of %d still not on core %d after %d passes: %s", pid, core, PINNING_PASSES,
              [tid for tid in tasks if _affinity(tid) != {core}])


def _affinity(tid: int) -> set[int] | None:
    try:
        return os.sched_getaffinity(tid)
    except ProcessLookupError:
        return None
