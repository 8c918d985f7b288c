"""`stella bench`: fly a standard scenario several times and report speed as medians and ratios.

It flies the runs once per placement (see RunOptions.cores): the simulator and the SUT on a
core each, polling for each other's messages (the fastest flight; two cores busy), and both on
one core, sleeping while the other works (the most evaluations per hour: one worker per core).
The real-time factor is simulated flight time over the wall time of the flight (after setup);
evaluations per hour assume as many workers as the placement lets the machine's cores hold.
Per-step figures come from the bridge's own timers: waiting for the SUT (from sending
HIL_SENSOR to receiving HIL_ACTUATOR_CONTROLS, less the bridge's own work in between; it holds
both socket hops and, on one core, the SUT's whole computation), building the sensor messages,
JSBSim, and the bridge's world work (obstacles, clearance, recording, done while the SUT
computes); the rest is the loop itself and its timers.

With `limit`, a SUT in a process of its own is also measured alone after each flight
(harness/tools/sut_alone.py): the first flight's simulator link replayed to it in lockstep, the
yardstick a flight through the bridge is reported against ("PX4 alone"), and the SUT's CPU time
a step in both (from /proc, its processes and their descendants, living or reaped): what it
computes in a flight beyond the replay, its flight and its API link, is the SUT's own and not
the bridge's.
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from harness.flight import scratch, stack
from harness.flight.evaluation import evaluate
from harness.flight.results import RunOptions
from harness.flight.stack import transport_problem
import sut_adapter
from sut_adapter import SutConfig
from harness.flight.fitness import Status
from harness.paths import scenarios_dir
from harness.scenario.logical import load_logical
from harness.scenario.profile import load_profile
from harness.scenario.space import SearchSpace
from sim_bridge.sut_link import TRANSPORTS

import numpy as np

DEFAULT_SCENARIO = "table3/scenario_31.json"
DEFAULT_SEED = 4
# How an evaluation runs: (cores per evaluation, transport between the simulator and the SUT,
# whether the worker keeps the simulator with the SUT inside between evaluations: RunOptions.warm).
PLACEMENTS = ((2, "tcp", False), (2, "unix", False), (2, "shm", False), (1, "tcp", False), (1, "memory", False), (1, "memory", True))
PLACEMENT_NAMES = {(2, "tcp", False): "a core each for the simulator and the SUT, polling",
                   (2, "unix", False): "the same over a Unix-domain socket instead of TCP",
                   (2, "shm", False): "the same through shared memory, polling without system calls",
                   (1, "tcp", False): "both on one core, sleeping while the other works",
                   (1, "memory", False): "the SUT inside the simulator's process, on one core",
                   (1, "memory", True): "the same, kept warm between evaluations (a worker's steady state)"}


def run_bench(runs: int, scenario: Path | None = None, seed: int = DEFAULT_SEED, rate_hz: float | None = None, pin_cpu: bool = True,
              sut: RunOptions = RunOptions(), placements: tuple[tuple[int, str, bool], ...] = PLACEMENTS, drive: str | None = None,
              mission_plan: Path | None = None, limit: bool = False, rig: str | None = None) -> dict[str, Any]:
    """`sut` names the SUT (its `sut` field, a SutConfig); the bundled autopilot by
    default. `drive` overrides the scenario's drive, `mission_plan` its route, `rig` its range
    sensors (a preset or a file, as --rig). `limit`: after
    each flight, the SUT alone on the placement's cores (harness/tools/sut_alone.py, replaying
    the first flight), and each flight's speed as a share of the replay beside it: paired, the
    ratio holds while the machine's load drifts."""
    profile = load_profile("default")
    path = scenario or scenarios_dir() / DEFAULT_SCENARIO
    space = SearchSpace(load_logical(path, profile, drive, mission_plan, rig), profile)
    x = space.sample_feasible(np.random.default_rng(seed), 1)[0]
    machine_cores = len(os.sched_getaffinity(0))
    report_placements = []
    autopilot = None
    physics_alone = None
    first_log = None
    sut_alone = None
    if limit:
        from harness.tools.sut_alone import sut_alone as replay_alone
    with tempfile.TemporaryDirectory(prefix=scratch.prefix("bench")) as out:
        # A SUT that runs in its own process only (PX4, a command) has no in-memory placement; one
        # that connects over TCP only, no Unix-domain socket or shared memory one.
        system = sut_adapter.system_for(sut.sut)
        rate_hz = rate_hz or system.capabilities.rate_hz
        can = {transport: transport_problem(transport, system) is None for transport in TRANSPORTS[1:]}
        for cores, transport, keep_warm in [(c, t, w) for c, t, w in placements if c <= machine_cores and can[t]]:
            rows = []
            options = replace(sut, rate_hz=rate_hz, pin_cpu=pin_cpu, cores=cores, transport=transport, warm=keep_warm)
            try:
                # Warm: the first run starts the stack the measured ones reuse, as a worker's first evaluation does.
                for index in range(-1 if keep_warm else 0, runs):
                    started = time.monotonic()
                    result = evaluate(space, x, seed=seed, out_dir=Path(out), options=options, name=f"bench-{cores}-{transport}-{keep_warm}-{index}")
                    # The whole call, log writing included (the result's own wall time ends before it).
                    wall = time.monotonic() - started
                    if result.real_time_factor is None:
                        which = "the warm-up run" if index < 0 else f"bench run {index}"
                        raise RuntimeError(f"{which} on {cores} core(s) ({transport}) did not fly: {result.status} {result.why}")
                    if index < 0:
                        continue
                    rows.append(_run_figures(result, rate_hz, wall))
                    first_log = first_log or Path(result.log_path)
                    if limit:
                        alone = replay_alone(first_log, sut.sut, cores, 1, pin_cpu)
                        sut_alone = {"log": str(first_log), "timed_steps": alone["timed_steps"],
                                     **{check: alone[check] and (sut_alone or alone)[check] for check in ("in_step", "started_up")}}
                        rows[-1].update(sut_alone_real_time_factor=alone["real_time_factor"], flight_speed_of_sut_alone=rows[-1]["real_time_factor"] / alone["real_time_factor"])
                        if alone["sut_cpu_us"] is not None:
                            rows[-1]["sut_alone_cpu_us"] = alone["sut_cpu_us"]
                    if autopilot is None and sut.sut.name == "bundled":
                        autopilot = autopilot_step_bench(Path(result.log_path))
                    if physics_alone is None:
                        physics_alone = jsbsim_alone(Path(result.log_path), rate_hz, repeats=runs)
            finally:
                stack.close_kept()
            # A figure some run could not read (a SUT's CPU time) has no median.
            median = {key: statistics.median(r[key] for r in rows) for key in rows[0] if all(key in r for r in rows)}
            workers = machine_cores // cores
            alone_s = median["sim_time_s"] / physics_alone["real_time_factor"]
            report_placements.append({"cores_per_evaluation": cores, "transport": transport, "warm": keep_warm, "workers": workers, "median": median,
                                      "evaluations_per_hour": workers * 3600.0 / median["wall_time_s"], "per_run": rows,
                                      # Comparable across machines: the flight's speed and an evaluation's cost against JSBSim stepped alone.
                                      "flight_speed_of_jsbsim_alone": median["real_time_factor"] / physics_alone["real_time_factor"],
                                      "evaluation_cost_in_jsbsim_alone": median["wall_time_s"] / alone_s})
    fitnesses = {r["fitness"] for p in report_placements for r in p["per_run"]}
    return {
        "scenario": str(path),
        "sut": sut.sut.name,
        "drive": space.mission.drive,
        "seed": seed,
        "rate_hz": rate_hz,
        "runs": runs,
        "cores": machine_cores,
        "placements": report_placements,
        "deterministic": len(fitnesses) == 1,
        "fitness_range": [min(fitnesses), max(fitnesses)],
        "autopilot_step": autopilot,
        "jsbsim_alone": physics_alone,
        "sut_alone": sut_alone,
    }


def _run_figures(result, rate_hz: float, wall_time_s: float) -> dict[str, Any]:
    timings = result.timings
    in_run = timings["wall_in_run_s"]
    run_steps = result.real_time_factor * in_run * rate_hz  # the bridge times the run's steps only
    figures = {
        "real_time_factor": result.real_time_factor,
        "wall_time_s": wall_time_s,
        "start_s": timings.get("start_s", 0.0),
        "setup_s": timings.get("setup_s", 0.0),
        "stop_s": timings.get("stop_s", 0.0),
        "score_s": timings.get("score_s", 0.0),
        "sut_wait_us": 1e6 * (timings["wait_s"] + timings["send_s"]) / run_steps,
        "send_us": 1e6 * timings["send_s"] / run_steps,
        "sensors_us": 1e6 * timings["sensors_s"] / run_steps,
        "physics_us": 1e6 * timings["physics_s"] / run_steps,
        "observe_us": 1e6 * timings["observe_s"] / run_steps,
        "world_us": 1e6 * timings["world_s"] / run_steps,
        "step_us": 1e6 * in_run / run_steps,
        "sim_time_s": result.sim_time_s,
        "run_steps": round(run_steps),
        "fitness": result.fitness,
    }
    if "sut_cpu_in_run_s" in timings:
        figures["sut_cpu_us"] = 1e6 * timings["sut_cpu_in_run_s"] / run_steps
        # The step's wall time the SUT spent computing: a harness that cost nothing would be at 1.
        figures["sut_cpu_share_of_step"] = figures["sut_cpu_us"] / figures["step_us"]
    figures["other_us"] = figures["step_us"] - sum(figures[k] for k in ("sut_wait_us", "sensors_us", "physics_us", "observe_us", "world_us"))
    return figures


def jsbsim_alone(log_path: Path, rate_hz: float, repeats: int = 3) -> dict[str, Any]:
    """JSBSim's F450 alone: the recorded flight's motor commands (zero before the SUT's first
    answer) stepped through the flight model at the bench's rate, over the terrain and in the wind
    it flew in, with nothing else: no SUT, sockets, sensors, obstacles or recording. The median
    of `repeats` replays, each on a fresh model."""
    from pymavlink.dialects.v20 import common as mavlink

    from harness.flight import logs
    from sim_bridge.terrain import terrain_height_m
    from sim_bridge.world import vehicle_for
    from simlink import codec

    world = logs.world_of(log_path)
    steps = logs.json_metadata(log_path, "bridge_summary")["steps"]
    splitter = codec.FrameSplitter({m: c.crc_extra for m, c in mavlink.mavlink_map.items()})
    answers = [codec.decode_hil_actuator_controls(payload)[2][:4]
               for _t, _ns, m in logs.messages(log_path, ["/mavlink/sim"]) if m["direction"] == "from_sut"
               for msgid, payload, _frame in splitter.feed(bytes.fromhex(m["hex"])) if msgid == codec.HIL_ACTUATOR_CONTROLS_ID]
    if not answers:  # ArduPilot's JSON link: servo frames, the first sent before any step
        from sim_bridge.ardupilot_json import motor_commands, servo_frames_in

        stream = b"".join(bytes.fromhex(m["hex"]) for _t, _ns, m in logs.messages(log_path, ["/mavlink/sim"]) if m["direction"] == "from_sut")
        answers = [motor_commands(frame.pwm_us) for frame in servo_frames_in(stream)[1:]]
    commands = [(0.0, 0.0, 0.0, 0.0)] * max(0, steps - len(answers)) + answers[:steps]
    terrain = world.terrain
    wind = (world.atmosphere.wind_north_m_s, world.atmosphere.wind_east_m_s)
    durations = []
    for _ in range(max(1, repeats)):
        vehicle = vehicle_for(world, rate_hz)
        started = time.perf_counter()
        for motors in commands:
            s = vehicle.state
            vehicle.step(motors, terrain_height_m(terrain, s.north_m, s.east_m), *wind)
        durations.append(time.perf_counter() - started)
    wall = statistics.median(durations)
    sim_time = len(commands) / rate_hz
    return {"steps": len(commands), "sim_time_s": sim_time, "wall_time_s": wall, "step_us": 1e6 * wall / max(1, len(commands)),
            "real_time_factor": sim_time / wall}


def bench_text(report: dict[str, Any]) -> str:
    lines = [f"{report['runs']} runs of {report['scenario']} (seed {report['seed']}, {report['drive']} drive) against {report['sut']} "
             f"at {report['rate_hz']:.0f} Hz lockstep, medians:"]
    alone = report["jsbsim_alone"]
    lines.append(f"  JSBSim's F450 alone           {alone['real_time_factor']:.0f}x real time ({alone['step_us']:.0f} us per step; the flight's "
                 f"motor commands replayed, nothing else)")
    alone = report.get("sut_alone")
    if alone:
        lines.append(f"  {report['sut'] + ' alone':<30}the first flight's simulator link replayed to it after each flight ({alone['timed_steps']} steps timed, "
                     f"{'every answer in step' if alone['in_step'] else 'ANSWERS OUT OF STEP: not a lockstep figure'}"
                     f"{'' if alone['started_up'] else '; TIMED BEFORE THE SUT HAD STARTED UP: it computed less than in a flight'})")
    for placement in report["placements"]:
        m = placement["median"]
        workers = placement["workers"]
        lines += [
            f"  {PLACEMENT_NAMES[(placement['cores_per_evaluation'], placement['transport'], placement['warm'])]}:",
            f"    real-time factor (flight)   {m['real_time_factor']:.1f}x, {placement['flight_speed_of_jsbsim_alone']:.3f} of JSBSim alone's",
            f"    wall time per evaluation    {m['wall_time_s']:.2f} s (start {m['start_s']:.2f} s, setup {m['setup_s']:.2f} s, stop {m['stop_s']:.2f} s, "
            f"scoring {m['score_s']:.2f} s), "
            f"{placement['evaluation_cost_in_jsbsim_alone']:.1f}x JSBSim alone's time for its {m['sim_time_s']:.1f} s",
            *([f"    {report['sut']} alone{' ' * (22 - len(report['sut']))}{m['sut_alone_real_time_factor']:.1f}x; the flight at "
               f"{m['flight_speed_of_sut_alone']:.3f} of it (median of the paired ratios)"] if "flight_speed_of_sut_alone" in m else []),
            *([f"    {report['sut']}'s CPU a step{' ' * (16 - len(report['sut']))}{m['sut_cpu_us']:.0f} us in the flight ({m['sut_cpu_share_of_step']:.2f} of its step), "
               f"{m['sut_alone_cpu_us']:.0f} us alone (in the flight it also flies and talks to MAVSDK)"] if "sut_alone_cpu_us" in m and "sut_cpu_us" in m else []),
            f"    evaluations per hour        {placement['evaluations_per_hour']:.0f} with {workers} worker{'s' if workers != 1 else ''}",
            f"    one lockstep step           {m['step_us']:.0f} us:",
            f"      sensor messages           {m['sensors_us']:.0f} us",
            f"      sending them              {m['send_us']:.0f} us",
            f"      scoring, recording        {m['observe_us']:.0f} us (while the SUT computes)",
            f"      waiting for the answer    {m['sut_wait_us'] - m['send_us']:.0f} us",
            f"      JSBSim                    {m['physics_us']:.0f} us",
            f"      control ops, end checks   {m['world_us']:.0f} us",
            f"      loop and timers           {m['other_us']:.0f} us",
        ]
    if report["autopilot_step"]:
        lines.append(f"  the autopilot's computation   {report['autopilot_step']['median_step_us']:.0f} us per step (median, replayed without sockets)")
    low, high = report["fitness_range"]
    lines.append(f"  fitness over the runs         {low:.6g} every run" if report["deterministic"] else
                 f"  fitness over the runs         {low:.6g} to {high:.6g} (the SUT does not repeat bit for bit: its outcomes spread by {high - low:.3g})")
    return "\n".join(lines)


def run_campaign_bench(evaluations: int, workers: int | None, scenario: Path | None = None, seed: int = 0, population: int = 50,
                       transport: str = "auto", warm: bool = True, on_run=lambda run: None, sut: SutConfig = SutConfig()) -> dict[str, Any]:
    """A one-run NSGA-II campaign against `sut`: wall time, evaluations per hour, and where the time went."""

    from harness.campaigns.campaign import CampaignConfig, run_campaign
    from harness.execution.local import LocalExecutor
    from harness.campaigns.store import Store

    path = scenario or scenarios_dir() / "table3" / "scenario_09.json"
    executor = LocalExecutor(workers)
    config = CampaignConfig((str(path),), ("NSGAII",), evaluations, 1, seed, population, batch=executor.workers, sut=sut)
    with tempfile.TemporaryDirectory(prefix=scratch.prefix("bench-campaign")) as folder:
        started = time.monotonic()
        with Store(Path(folder) / "campaign.db") as store:
            try:
                run_campaign(config, store, executor, Path(folder) / "logs", on_run=on_run, options=RunOptions(transport=transport, warm=warm))
            finally:
                executor.close()
            wall = time.monotonic() - started
            rows = store.all_evaluations()
    flown = [r for r in rows if r.status != Status.INFEASIBLE]
    busy = sum(r.wall_time_s or 0.0 for r in flown)
    return {
        "scenario": str(path),
        "sut": sut.name,
        "evaluations": len(rows),
        "flown": len(flown),
        "workers": executor.workers,
        "transport": transport,
        "warm": warm,
        "wall_time_s": wall,
        "evaluations_per_hour": 3600.0 * len(rows) / wall,
        "mean_evaluation_wall_s": busy / len(flown) if flown else None,
        "simulated_s": sum(r.sim_time_s or 0.0 for r in flown),
        "outside_evaluations_share": 1.0 - busy / (wall * executor.workers),
        "violations": sum(1 for r in rows if r.status == Status.VIOLATION),
    }


def campaign_bench_text(report: dict[str, Any]) -> str:
    return "\n".join(
        [
            f"NSGA-II campaign on {report['scenario']} against {report['sut']}: {report['evaluations']} evaluations ({report['flown']} flown) with {report['workers']} workers, "
            f"transport {report['transport']}, {'warm workers' if report['warm'] else 'cold starts'}",
            f"  wall time                   {report['wall_time_s']:.0f} s",
            f"  evaluations per hour        {report['evaluations_per_hour']:.0f}",
            f"  mean wall per evaluation    {report['mean_evaluation_wall_s']:.2f} s (in a worker)",
            f"  time outside evaluations    {100 * report['outside_evaluations_share']:.1f} % of worker time",
            f"  violations found            {report['violations']}",
        ]
    )


def run_executor_bench(executor_name: str, workers: int, evaluations: int, scenario: Path | None = None, seed: int = DEFAULT_SEED) -> dict[str, Any]:
    """The standard scenario flown `evaluations` times through an executor: evaluations per hour,
    and, as the executor's overhead per evaluation, the workers' time spent outside evaluations
    (process or container start, teardown, bringing the log back) per evaluation."""
    from harness.execution.executor import Job
    from harness.execution.registry import make_executor

    profile = load_profile("default")
    path = scenario or scenarios_dir() / DEFAULT_SCENARIO
    space = SearchSpace(load_logical(path, profile), profile)
    x = space.sample_feasible(np.random.default_rng(seed), 1)[0]
    executor = make_executor(executor_name, workers)
    with tempfile.TemporaryDirectory(prefix=scratch.prefix("bench-executor")) as out:
        jobs = [Job.of(index, space, x, seed=seed, out_dir=out, name=f"bench-{index}", options=RunOptions()) for index in range(evaluations)]
        started = time.monotonic()
        try:
            results = [result for _job, result in executor.run(jobs)]
        finally:
            executor.close()
        wall = time.monotonic() - started
    inside = [r.wall_time_s for r in results]
    return {
        "executor": executor_name,
        "workers": executor.workers,
        "scenario": str(path),
        "evaluations": evaluations,
        "statuses": sorted({str(r.status) for r in results}),
        "wall_time_s": wall,
        "evaluations_per_hour": 3600.0 * evaluations / wall,
        "median_evaluation_wall_s": statistics.median(inside),
        # the mean, not the median: worker time not spent inside evaluations, shared out
        "overhead_per_evaluation_s": (wall * executor.workers - sum(inside)) / evaluations,
    }


def executor_bench_text(report: dict[str, Any]) -> str:
    return "\n".join(
        [
            f"{report['evaluations']} evaluations of {report['scenario']} through {report['executor']} with {report['workers']} workers ({', '.join(report['statuses'])}):",
            f"  wall time                   {report['wall_time_s']:.1f} s",
            f"  evaluations per hour        {report['evaluations_per_hour']:.0f}",
            f"  evaluation's own wall time  {report['median_evaluation_wall_s']:.2f} s (median)",
            f"  executor overhead           {report['overhead_per_evaluation_s']:.2f} s per evaluation (worker time outside evaluations / evaluations)",
        ]
    )


def autopilot_step_bench(log_path: Path) -> dict[str, Any]:
    """The bundled autopilot's cost per lockstep step, replaying a recorded flight's
    simulator-to-SUT stream into it in this process (sut_adapter.bundled.step_bench)."""
    from harness.flight import logs
    from sut_adapter.bundled import step_bench

    mission = logs.json_metadata(log_path, "world")["mission"]  # as JSON: the autopilot knows no simulator types
    stream = b"".join(bytes.fromhex(m["hex"]) for _t, _ns, m in logs.messages(log_path, ["/mavlink/sim"]) if m["direction"] == "to_sut")
    return {"log": str(log_path), **step_bench(stream, mission)}
