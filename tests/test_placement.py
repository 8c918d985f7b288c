"""Where an evaluation's simulator and SUT run, and how they wait for each other (RunOptions.cores)."""

from __future__ import annotations

import concurrent.futures
import os
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from conftest import FIG4, fig4_job, stored_result
from harness.execution.executor import Executor
from harness.execution.local import LocalExecutor
from harness.flight.results import RunOptions
from harness.flight.stack import pin_process, placed_cores, simulation_stack
from harness.scenario.logical import load_logical
from harness.scenario.space import SearchSpace
from harness.scenario.world import world_spec
from simlink import codec
import sut_adapter

MACHINE_CORES = len(os.sched_getaffinity(0))


def test_a_polling_receive_returns_what_the_peer_sends_later():
    a, b = socket.socketpair()
    with a, b:
        threading.Timer(0.001, lambda: b.sendall(b"answer")).start()
        assert codec.receive(a, spin_s=0.5) == b"answer"


def test_a_polling_receive_falls_back_to_the_sockets_own_timeout():
    a, b = socket.socketpair()
    with a, b:
        codec.set_receive_timeout(a, 0.05)
        started = time.perf_counter()
        with pytest.raises(BlockingIOError):
            codec.receive(a, spin_s=0.02)
        assert 0.06 <= time.perf_counter() - started < 1.0  # polled 20 ms, then slept 50 ms


class RecordingExecutor(Executor):
    def __init__(self, workers: int):
        super().__init__(workers)
        self.submitted = []

    def submit(self, job):
        self.submitted.append(job)
        future = concurrent.futures.Future()
        future.set_result(stored_result(1.0, "ok"))
        return future


@pytest.mark.parametrize("workers", [1, 2, 4])
def test_executors_give_an_evaluation_two_cores_only_when_every_worker_can_have_two(tmp_path, profile, workers):
    executor = RecordingExecutor(workers)
    list(executor.run([fig4_job(tmp_path, profile, key) for key in range(3)]))
    expected = 2 if MACHINE_CORES >= 2 * workers else 1
    assert {job.options.cores for job in executor.submitted} == {expected}


def test_the_local_executor_with_one_worker_per_core_shares_a_core_per_evaluation():
    executor = LocalExecutor()
    try:
        assert executor.cores_per_evaluation() == 1
    finally:
        executor.close()


def _placement(tmp_path, profile, cores: int) -> tuple[set[int], set[int], list[str], list[str]]:
    space = SearchSpace(load_logical(FIG4, profile), profile)
    x = space.sample_feasible(np.random.default_rng(1), 1)[0]
    system = sut_adapter.get("bundled", {})
    with simulation_stack(world_spec(space, x, 1), RunOptions(cores=cores, transport="tcp"), system, tmp_path) as stack:
        sut_pid = stack.sut.pids[0]
        with open(f"/proc/{sut_pid}/cmdline", "rb") as cmdline:
            sut_argv = cmdline.read().decode().split("\0")
        return os.sched_getaffinity(stack.bridge.pid), os.sched_getaffinity(sut_pid), list(stack.bridge.argv), sut_argv


@pytest.mark.slow
@pytest.mark.skipif(MACHINE_CORES < 2, reason="needs two cores to place the simulator and the SUT apart")
def test_two_cores_put_the_simulator_and_the_sut_apart_and_both_poll(tmp_path, profile):
    bridge_cores, sut_cores, bridge_argv, sut_argv = _placement(tmp_path, profile, cores=2)
    assert len(bridge_cores) == len(sut_cores) == 1 and bridge_cores != sut_cores
    assert float(bridge_argv[bridge_argv.index("--spin-us") + 1]) > 0 and float(sut_argv[sut_argv.index("--spin-us") + 1]) > 0
    # The harness rewrites the simulator's recording compressed, and stops the SUT before it.
    assert bridge_argv[bridge_argv.index("--mcap-compression") + 1] == "none"
    assert float(bridge_argv[bridge_argv.index("--linger-s") + 1]) > 0
    # The bundled autopilot answers every step from the first, with the step's time.
    assert "--lockstep-from-start" in bridge_argv and "--answer-times-echoed" in bridge_argv


@pytest.mark.skipif(MACHINE_CORES < 2, reason="needs two cores to place the simulator and the SUT apart")
def test_pinning_a_sut_pins_the_threads_it_started_before():
    """GIVEN a SUT process that started threads before the harness pinned it (PX4 starts 28)
    WHEN it is placed on its core THEN every one of its threads is held to that core, not only
    its first: a thread left free runs on the simulator's core now and then and halves the flight's speed."""
    threads = 6
    bridge = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    sut = subprocess.Popen([sys.executable, "-c", f"import threading, time\n"
                            f"for _ in range({threads}): threading.Thread(target=time.sleep, args=(60,), daemon=True).start()\n"
                            "print('started', flush=True)\ntime.sleep(60)"], stdout=subprocess.PIPE)
    try:
        assert sut.stdout.readline() == b"started\n"
        bridge_core, sut_core = placed_cores(slot=0, cores=2)
        pin_process(bridge.pid, bridge_core)
        pin_process(sut.pid, sut_core)
        assert (bridge_core, sut_core) == tuple(sorted(os.sched_getaffinity(0))[:2])
        affinities = [os.sched_getaffinity(int(tid)) for tid in os.listdir(f"/proc/{sut.pid}/task")]
        assert len(affinities) == threads + 1 and all(cores == {sut_core} for cores in affinities)
        assert os.sched_getaffinity(bridge.pid) == {bridge_core}
    finally:
        for process in (bridge, sut):
            process.kill()
            process.wait()


@pytest.mark.slow
def test_one_core_puts_both_on_it_and_neither_polls(tmp_path, profile):
    bridge_cores, sut_cores, bridge_argv, sut_argv = _placement(tmp_path, profile, cores=1)
    assert len(bridge_cores) == 1 and bridge_cores == sut_cores
    assert float(bridge_argv[bridge_argv.index("--spin-us") + 1]) == 0 and "--spin-us" not in sut_argv


@pytest.mark.slow
def test_the_benchmark_flies_both_placements_and_finds_the_same_fitness(capsys):
    import json

    from harness.tools.bench import bench_text
    from harness.tools.cli import main

    assert main(["bench", "--runs", "1", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    placements = {p["cores_per_evaluation"]: p for p in report["placements"]}
    assert set(placements) == ({1, 2} if MACHINE_CORES >= 2 else {1})
    assert report["deterministic"] and report["autopilot_step"]["flew_mission"]
    low, high = report["fitness_range"]
    assert low == high and f"fitness over the runs         {low:.6g} every run" in bench_text(report)
    for placement in placements.values():
        median = placement["median"]
        assert median["real_time_factor"] > 1.0 and median["step_us"] > 0
        assert placement["workers"] == MACHINE_CORES // placement["cores_per_evaluation"]
        # The ratios to JSBSim stepped alone: a lockstep flight is slower than its physics alone,
        # an evaluation (with setup) slower still, and the two follow from the absolute figures.
        alone = report["jsbsim_alone"]
        assert 0.0 < placement["flight_speed_of_jsbsim_alone"] < 1.0
        assert placement["flight_speed_of_jsbsim_alone"] == pytest.approx(median["real_time_factor"] / alone["real_time_factor"])
        assert placement["evaluation_cost_in_jsbsim_alone"] == pytest.approx(median["wall_time_s"] * alone["real_time_factor"] / median["sim_time_s"])
        assert placement["evaluation_cost_in_jsbsim_alone"] > 1.0 / placement["flight_speed_of_jsbsim_alone"]
    # Every step of the flight is replayed, with the SUT's own motor commands.
    assert report["jsbsim_alone"]["steps"] == round(report["placements"][0]["median"]["sim_time_s"] * report["rate_hz"])


@pytest.mark.slow
def test_by_default_one_core_runs_the_bundled_autopilot_inside_the_simulators_process(tmp_path, profile):
    space = SearchSpace(load_logical(FIG4, profile), profile)
    x = space.sample_feasible(np.random.default_rng(1), 1)[0]
    with simulation_stack(world_spec(space, x, 1), RunOptions(cores=1), sut_adapter.get("bundled", {}), tmp_path) as stack:
        assert stack.bridge.argv[1:3] == ["-m", "sut_adapter.inline"] and "--api" in stack.bridge.argv
        assert stack.sut.pids == [] and stack.sut.alive() and len(os.sched_getaffinity(stack.bridge.pid)) == 1
    with simulation_stack(world_spec(space, x, 1), RunOptions(cores=1), sut_adapter.get("command", {"command": "sleep 30 --sim {sim_port} --api {api_port}"}), tmp_path) as stack:
        assert stack.bridge.argv[1:3] == ["-m", "sim_bridge"]  # a SUT in a process of its own keeps TCP
