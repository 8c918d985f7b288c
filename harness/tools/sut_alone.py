"""`stella bench --limit`: a SUT alone, the yardstick for flights through the bridge.

A minimal stand-in for the simulator replays the simulator-link bytes of a recorded flight,
cut into its steps and held in memory before timing, to a fresh SUT process, and only reads its
answers. PX4's protocol (over TCP): one step's HIL_SENSOR, HIL_GPS, ... frames per
HIL_ACTUATOR_CONTROLS once the SUT answers in lockstep, as the bridge paces them. ArduPilot's
JSON protocol (over UDP): one recorded state line per servo frame, from the frame that opened
the link, as the bridge answers them. No physics, sensors, scoring or recording, so its
real-time factor is what the SUT's own computation per step allows on this machine ("PX4
alone", "ArduPilot alone"); a flight through the bridge is reported as a share of it.

The flight's hold is replayed at the pace the bridge held it, and more slowly while the SUT
has not finished starting up (SutHandle.booted), since a flight's set-up waits for that before
its run. PX4's start-up script, one client process per command, runs on the wall clock while
some of its commands wait on PX4's lockstep clock: replayed at full speed, PX4 was still
starting modules (its MAVLink instances among them) through the timed steps, and took 77 us a
step where a started one takes 88 (scenario 31, 2026-11-27); with its clock held still at the
run, its start-up never finished. `started_up` says whether it had before the timed steps.

What the replay does not give the SUT: its API link. Nobody uploads a mission or arms it, so it
computes every step on the recorded flight's sensors but stays disarmed (for PX4: the same
estimator and controllers run, its logger does not write, as it logs from arming; a replay that
force-armed it ran no slower: docs/benchmarks.md).
"""

from __future__ import annotations

import json
import os
import shutil
import statistics
import time
from pathlib import Path
from typing import Any, Callable

from pymavlink.dialects.v20 import common as mavlink

from harness.flight import logs, scratch
from harness.flight.ports import PortLease
from sim_bridge.__main__ import listen
from sim_bridge.ardupilot_json import FrameError, decode_servo_frame
from sim_bridge.ardupilot_link import UdpLink, accept, listen_udp
from sim_bridge.sut_link import SocketLink
from simlink import codec
import sut_adapter
from sut_adapter import SutConfig

_CRC_EXTRAS = {msgid: cls.crc_extra for msgid, cls in mavlink.mavlink_map.items()}
# With a core of its own the stand-in polls for the answer this long before sleeping, as the bridge does (evaluation.LOCKSTEP_SPIN_S).
SPIN_S = 0.002
CONNECT_TIMEOUT_S = 60.0
STALL_TIMEOUT_S = 10.0
# While the SUT is starting up, a hold step takes at least this long (PX4's start-up script has
# about 0.2-0.5 s of wall time left at the hold: a few hundred steps of the hold give it that,
# its clock moving on), and at the run it gets this much more with its clock held.
STARTING_UP_STEP_S = 0.002
STARTING_UP_AT_RUN_S = 1.0


def link_steps(stream: bytes) -> tuple[list[bytes], list[int]]:
    """A recorded simulator-to-SUT stream cut into the bridge's steps: each step's frames, its
    HIL_SENSOR last (the bridge sends it last, so the SUT has seen the rest when it steps on
    it), and each step's time (its HIL_SENSOR's, in us), which the SUT's answer carries back."""
    splitter = codec.FrameSplitter(_CRC_EXTRAS)
    steps: list[bytes] = []
    times: list[int] = []
    pending: list[bytes] = []
    for msgid, payload, frame in splitter.feed(stream):
        pending.append(frame)
        if msgid == codec.HIL_SENSOR_ID:
            steps.append(b"".join(pending))
            times.append(codec.decode_hil_sensor(payload)[0])
            pending = []
    if splitter.bad_frames or splitter.skipped_bytes:
        raise ValueError(f"the recorded simulator link has {splitter.bad_frames} bad frames and {splitter.skipped_bytes} stray bytes: not a bridge's recording")
    return steps, times


def json_link_steps(stream: bytes) -> tuple[list[bytes], list[int]]:
    """A recorded ArduPilot JSON stream cut into the bridge's steps: each state line as sent
    (newline before and after), a line sent again for a frame that came again (its answer was
    lost) counted once, and each step's time (its timestamp, in us)."""
    steps: list[bytes] = []
    times: list[int] = []
    for line in stream.split(b"\n"):
        if not line:
            continue
        try:
            time_us = round(json.loads(line)["timestamp"] * 1e6)
        except (ValueError, KeyError, TypeError):
            raise ValueError(f"the recorded simulator link holds {line[:60]!r}: not a bridge's recording of ArduPilot's JSON link") from None
        if times and time_us == times[-1]:
            continue
        steps.append(b"\n" + line + b"\n")
        times.append(time_us)
    return steps, times


def recorded_link(log_path: Path, protocol: str = "mavlink") -> dict[str, Any]:
    """What a replay needs of a flight's log: its steps in the SUT's simulator protocol, their
    period, and the step its run began at (the flight's real-time factor counts from there)."""
    stream = b"".join(bytes.fromhex(m["hex"]) for _t, _ns, m in logs.messages(log_path, ["/mavlink/sim"]) if m["direction"] == "to_sut")
    steps, times = link_steps(stream) if protocol == "mavlink" else json_link_steps(stream)
    summary = logs.json_metadata(log_path, "bridge_summary")
    dt_s = summary["sim_time_s"] / summary["steps"]
    run_at_s = logs.first_event_s(log_path, "run") or 0.0
    hold_at_s = logs.first_event_s(log_path, "holding")
    run_step = min(len(steps) - 1, round(run_at_s / dt_s))
    return {"steps": steps, "times_us": times, "dt_s": dt_s, "run_step": run_step, "hold_step": run_step if hold_at_s is None else round(hold_at_s / dt_s)}


def replay(link: SocketLink, steps: list[bytes], times_us: list[int], dt_s: float, timed_from: int, spin_s: float, hold: tuple[int, float] = (0, 0.0),
           ready: Callable[[], bool] = lambda: True, cpu_s: Callable[[], float | None] = lambda: None) -> dict[str, Any]:
    """Send the steps as the bridge does: at real-time pace until the SUT's first answer, then
    each step once the last one is answered, the hold's (from step hold[0] to the run) no faster
    than hold[1] times real time (0: as fast), and the run's once ready() (the SUT has started
    up). Times the steps from `timed_from` on, and says
    whether each timed step's answer carried that step's time (`in_step`: the replay and the SUT
    kept in lockstep), and the SUT's CPU time a timed step (`sut_cpu_us`, as cpu_s() reads it)."""
    splitter = codec.FrameSplitter(_CRC_EXTRAS)
    answer_times: list[int] = []
    lockstep_from = None
    started = None
    perf = time.perf_counter
    for index, frames in enumerate(steps):
        if index == timed_from:
            started_up = _wait_until_ready(ready)
            cpu_at_start = cpu_s()
            started = perf()
        sent = perf()
        link.send(frames)
        if lockstep_from is None:
            # Before lockstep the SUT may or may not answer a step: wait out the step's period.
            if link.readable(dt_s) and _answers(splitter, link.receive(0.0), answer_times):
                lockstep_from = index
            time.sleep(max(0.0, dt_s - (perf() - sent)))
            continue
        while not _answers(splitter, link.receive(spin_s), answer_times):
            pass
        _hold_pace(index, hold, timed_from, dt_s, sent, ready)
    if started is None or lockstep_from is None or lockstep_from > timed_from:
        raise RuntimeError(f"the SUT answered in lockstep from step {lockstep_from}, not by step {timed_from} where timing starts")
    wall_s = perf() - started
    timed = len(steps) - timed_from
    sut_cpu_us = _cpu_per_step_us(cpu_at_start, cpu_s(), timed)
    return {"steps": len(steps), "timed_steps": timed, "lockstep_from": lockstep_from, "wall_s": wall_s, "step_us": 1e6 * wall_s / timed,
            "real_time_factor": timed * dt_s / wall_s, "in_step": answer_times[-timed:] == times_us[timed_from:], "started_up": started_up,
            "sut_cpu_us": sut_cpu_us}


def replay_json(link: UdpLink, steps: list[bytes], dt_s: float, timed_from: int, spin_s: float, hold: tuple[int, float] = (0, 0.0),
                ready: Callable[[], bool] = lambda: True, cpu_s: Callable[[], float | None] = lambda: None) -> dict[str, Any]:
    """Answer each of ArduPilot's servo frames with the next recorded line, from the frame that
    opened the link (ArduPilot waits for each answer: lockstep from the start), the hold's as
    replay() paces them, and time the
    steps from `timed_from` on. `in_step`: every timed frame counted one up from the one before
    (none sent again, none skipped); `sut_cpu_us` as replay() says it."""
    counts = [decode_servo_frame(link.first).frame_count]
    started = None
    perf = time.perf_counter
    for index, line in enumerate(steps):
        if index == timed_from:
            started_up = _wait_until_ready(ready)
            cpu_at_start = cpu_s()
            started = perf()
        sent = perf()
        link.send(line)
        if index + 1 < len(steps):
            counts.append(_next_servo_frame(link, spin_s))
        _hold_pace(index, hold, timed_from, dt_s, sent, ready)
    if started is None:
        raise RuntimeError(f"the recording has {len(steps)} steps, fewer than the {timed_from} before its run")
    wall_s = perf() - started
    timed = len(steps) - timed_from
    sut_cpu_us = _cpu_per_step_us(cpu_at_start, cpu_s(), timed)
    in_step = all(later == earlier + 1 for earlier, later in zip(counts[timed_from:], counts[timed_from + 1:]))
    return {"steps": len(steps), "timed_steps": timed, "lockstep_from": 0, "wall_s": wall_s, "step_us": 1e6 * wall_s / timed,
            "real_time_factor": timed * dt_s / wall_s, "in_step": in_step, "started_up": started_up, "sut_cpu_us": sut_cpu_us}


def _cpu_per_step_us(at_start: float | None, at_end: float | None, steps: int) -> float | None:
    """The SUT's CPU time a timed step (None where its CPU time cannot be read)."""
    return None if at_start is None or at_end is None else 1e6 * (at_end - at_start) / steps


def _wait_until_ready(ready: Callable[[], bool]) -> bool:
    """Whether the SUT has started up, waiting for it a moment at the run with its clock held."""
    deadline = time.monotonic() + STARTING_UP_AT_RUN_S
    while not ready():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.002)
    return True


def _hold_pace(index: int, hold: tuple[int, float], timed_from: int, dt_s: float, sent: float, ready: Callable[[], bool]) -> None:
    """In the hold (step hold[0] up to the run), a step takes at least dt_s / hold[1] of wall
    time, as in the bridge's paced hold, and STARTING_UP_STEP_S while the SUT is starting up."""
    hold_from, pace = hold
    if hold_from <= index < timed_from:
        period = dt_s / pace if pace else 0.0
        if not ready():
            period = max(period, STARTING_UP_STEP_S)
        time.sleep(max(0.0, period - (time.perf_counter() - sent)))


def _next_servo_frame(link: UdpLink, spin_s: float) -> int:
    """The next servo frame's count; what is no servo frame is skipped."""
    while True:
        try:
            return decode_servo_frame(link.receive(spin_s)).frame_count
        except FrameError:
            continue


def _answers(splitter: codec.FrameSplitter, data: bytes, answer_times: list[int]) -> bool:
    """Whether `data` completes an actuator answer (recording each one's time)."""
    if not data:
        raise ConnectionResetError("the SUT closed its simulator link")
    answered = False
    for msgid, payload, _frame in splitter.feed(data):
        if msgid == codec.HIL_ACTUATOR_CONTROLS_ID:
            answer_times.append(codec.decode_hil_actuator_controls(payload)[0])
            answered = True
    return answered


def sut_alone(log_path: Path, sut: SutConfig, cores: int, repeats: int, pin_cpu: bool = True) -> dict[str, Any]:
    """The SUT alone on `cores` cores (2: the stand-in and the SUT a core each, the stand-in
    polling; 1: both on one core, sleeping while the other works), replaying the flight in
    `log_path` `repeats` times, each into a fresh SUT process: the median and each run."""
    from harness.flight.stack import pin_process, placed_cores

    system = sut_adapter.system_for(sut)
    protocol = system.capabilities.sim_protocol
    if protocol not in ("mavlink", "ardupilot-json"):
        raise ValueError(f"{system.name}'s simulator link speaks {protocol}; the replay speaks PX4's MAVLink protocol and ArduPilot's JSON one")
    recorded = recorded_link(log_path, protocol)
    # Started as in the flight: ArduPilot at the world's origin with rangefinders of its sensor's
    # reach; the user's parameters and, for a SUT that takes them with its start, the flight's.
    world = logs.world_of(log_path)
    extra: dict[str, Any] = {"world": world} if system.capabilities.needs_world else {}
    if system.capabilities.params_at_start and world is not None:
        extra["flight_params"] = system.capabilities.flight_params(world)
    spin_s = SPIN_S if cores >= 2 else 0.0
    hold = (recorded["hold_step"], system.capabilities.hold_pace if system.capabilities.hold_mode == "paced" else 0.0)
    runs = []
    own_cores = os.sched_getaffinity(0)
    for _ in range(max(1, repeats)):
        workdir = scratch.folder("alone")
        try:
            # A SUT that numbers its instances within a range (PX4: 0-9) needs a slot in it, as a flight does.
            limited = system.capabilities.instance_count
            with (PortLease(slots=limited, wait_s=CONNECT_TIMEOUT_S) if limited else PortLease()) as ports:
                listener = listen(ports.sim) if protocol == "mavlink" else listen_udp(ports.sim)
                handle = None
                try:
                    handle = system.start(sim_port=ports.sim, api_port=ports.api, instance=ports.slot, workdir=workdir, params=sut.params, spin_s=spin_s, **extra)
                    if pin_cpu:
                        # The stand-in is this thread alone: the process's others (MAVSDK's, an executor's) outlive the replay.
                        stand_in_core, sut_core = placed_cores(ports.slot, cores)
                        os.sched_setaffinity(0, {stand_in_core})
                        for pid in handle.pids:
                            pin_process(pid, sut_core)
                    try:
                        if protocol == "mavlink":
                            listener.settimeout(CONNECT_TIMEOUT_S)
                            link = SocketLink(listener.accept()[0], STALL_TIMEOUT_S)
                        else:
                            link = accept(listener, CONNECT_TIMEOUT_S, STALL_TIMEOUT_S)
                    except TimeoutError:
                        raise RuntimeError(f"{system.name} did not connect to the stand-in within {CONNECT_TIMEOUT_S:.0f} s: {handle.stderr_tail()}") from None
                    try:
                        if protocol == "mavlink":
                            runs.append(replay(link, recorded["steps"], recorded["times_us"], recorded["dt_s"], recorded["run_step"], spin_s, hold, handle.booted, handle.cpu_s))
                        else:
                            runs.append(replay_json(link, recorded["steps"], recorded["dt_s"], recorded["run_step"], spin_s, hold, handle.booted, handle.cpu_s))
                    except (BlockingIOError, OSError) as error:
                        raise RuntimeError(f"{system.name} stopped answering the replay ({error}): {handle.stderr_tail()}") from None
                    finally:
                        handle.stop()  # before its link closes: PX4 spins on a closed simulator link and heeds SIGTERM late
                        link.close()
                finally:
                    os.sched_setaffinity(0, own_cores)
                    listener.close()
                    if handle is not None:
                        handle.stop()
        finally:
            shutil.rmtree(workdir, ignore_errors=True)
    rtf = statistics.median(r["real_time_factor"] for r in runs)
    return {"log": str(log_path), "cores": cores, "timed_steps": runs[0]["timed_steps"], "real_time_factor": rtf,
            "step_us": statistics.median(r["step_us"] for r in runs), "per_run": [r["real_time_factor"] for r in runs],
            "in_step": all(r["in_step"] for r in runs), "started_up": all(r["started_up"] for r in runs),
            "sut_cpu_us": None if None in (cpu := [r["sut_cpu_us"] for r in runs]) else statistics.median(cpu)}
