from __future__ import annotations

import os
import socket
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from harness.flight.results import EvaluationResult
from harness.flight.fitness import Status
from harness.scenario.profile import Profile, load_profile

pytest_plugins = ["pytester"]

ROOT = Path(__file__).resolve().parent.parent
TABLE3 = sorted((ROOT / "scenarios" / "table3").glob("*.json"))


def port_bound(port: int, kind: int = socket.SOCK_STREAM) -> bool:
    """Whether a live socket holds the port; connections lingering in TIME_WAIT do not count,
    as the bridge's own SO_REUSEADDR listener binds over them."""
    with socket.socket(socket.AF_INET, kind) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(("127.0.0.1", port))
            return False
        except OSError:
            return True


@pytest.fixture(scope="session")
def profile() -> Profile:
    return load_profile("default")


# One seeded campaign of every optimizer and a sequential combination, with populations small
# enough that each run reaches its second generation (or step) within its budget.
SEEDED_CAMPAIGN = ("--algorithm", "NSGAII", "--algorithm", "SMPSO", "--algorithm", "BO", "--algorithm", "PNP",
                   "--evaluations", "4", "--population", "2", "--seed", "3")


def campaign_candidates(store_path) -> list[tuple]:
    """What a campaign flew, in the order each run asked for it: the candidate sequences."""
    import sqlite3

    with sqlite3.connect(store_path) as db:
        return db.execute("SELECT r.algorithm, e.ordinal, e.vector_key, e.status, e.fitness FROM evaluations e JOIN runs r ON r.id = e.run_id"
                          " ORDER BY r.algorithm, e.ordinal").fetchall()


def run_seeded_campaign(store_path, executor: str, *extra: str) -> list[tuple]:
    from harness.tools.cli import main

    scenario = ROOT / "scenarios" / "table3" / "scenario_02.json"
    argv = ["campaign", str(scenario), *SEEDED_CAMPAIGN, "--executor", executor, "--store", str(store_path), "--json", *extra]
    assert main(argv) == 0
    return campaign_candidates(store_path)


@pytest.fixture(scope="session")
def sequential_candidates(tmp_path_factory) -> list[tuple]:
    """The seeded campaign flown one evaluation at a time: what every executor must reproduce."""
    return run_seeded_campaign(tmp_path_factory.mktemp("sequential") / "sequential.db", "sequential")


def children(parent_pid: int) -> list[int]:
    """The live processes whose parent is parent_pid."""
    found = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            with open(f"/proc/{pid}/stat") as handle:
                parent = int(handle.read().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
        if parent == parent_pid:
            found.append(int(pid))
    return found


def alive(pid: int) -> bool:
    """Running, not a zombie: a container whose init does not reap keeps dead orphans listed."""
    try:
        with open(f"/proc/{pid}/stat") as handle:
            return handle.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def descendants(pid: int) -> list[int]:
    family, found = [pid], []
    while family:
        kids = children(family.pop())
        found += kids
        family += kids
    return found


def described(pid: int) -> str:
    """pid, state and command line, for a failure message."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as handle:
            argv = b" ".join(handle.read().split(b"\0")).decode(errors="replace")
        with open(f"/proc/{pid}/stat") as handle:
            return f"{pid} ({handle.read().rsplit(')', 1)[1].split()[0]}): {argv[:200]}"
    except OSError:
        return f"{pid}: gone"


def flying(pid: int) -> bool:
    """Whether process pid, or a process it started, runs an evaluation: has the bridge and the
    SUT as its children, or the bridge with the SUT inside (--transport memory)."""
    family = [pid]
    while family:
        kids = children(family.pop())
        if len(kids) >= 2 or any(_runs_module(kid, b"sut_adapter.inline") for kid in kids):
            return True
        family += kids
    return False


def _runs_module(pid: int, module: bytes) -> bool:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as handle:
            return module in handle.read().split(b"\0")
    except OSError:
        return False


def wait_until_flying(pid: int, timeout_s: float = 60.0) -> None:
    """Block until process pid runs an evaluation: a state to wait for, where a sleep would race
    the machine's speed."""
    deadline = time.monotonic() + timeout_s
    while not flying(pid):
        assert time.monotonic() < deadline, f"process {pid} started no flight within {timeout_s} s"
        time.sleep(0.02)


FIG4 = ROOT / "scenarios" / "examples" / "fig4.json"
FIG4_SEED1_FITNESS = 9.882575416238263  # the bundled autopilot's fitness on Fig. 4 sampled with seed 1


def stored_result(fitness: float, status: str, seed: int = 0, *, min_clearance_m: float | None = None, log_path: str | None = None,
                  confirmations: dict | None = None) -> EvaluationResult:
    """An evaluation's result as a campaign stores it, for tests that fill a store by hand."""
    return EvaluationResult(status=Status(status), fitness=fitness, why=None, min_clearance_m=min_clearance_m, min_clearance_at_s=None,
                            min_clearance_obstacle=None, sim_time_s=0.0, wall_time_s=0.0, real_time_factor=None, seed=seed, log_path=log_path,
                            scenario="test", sut="bundled", confirmations=confirmations)


def fig4_job(out_dir, profile: Profile, key: int = 0, **options):
    """An executor job: Fig. 4 sampled with seed 1, flown with seed 1."""
    import numpy as np

    from harness.flight.results import RunOptions
    from harness.execution.executor import Job
    from harness.scenario.logical import load_logical
    from harness.scenario.space import SearchSpace

    space = SearchSpace(load_logical(FIG4, profile), profile)
    x = space.sample_feasible(np.random.default_rng(1), 1)[0]
    return Job.of(key, space, x, seed=1, out_dir=out_dir, name=f"job{key}", options=RunOptions(**options))


PLAN_SCENARIO = ROOT / "scenarios" / "examples" / "plan_mission.json"
PLAN_SPEED_M_S = 4.0  # two_altitudes.plan's change-speed item


def plan_flight(log_path: Path) -> dict:
    """What a flight of two_altitudes.plan did at each waypoint, as a user would check it: the
    best moment within the acceptance radius (horizontal miss, altitude error there), the fastest
    horizontal speed after the speed change, and how long it stayed at the held waypoint."""
    import math

    from harness.flight import logs

    world = logs.world_of(log_path)
    states = [m for _t, _ns, m in logs.messages(log_path, ["/uav/state"])]
    up0 = world.uav.start.up_m
    waypoints = []
    for waypoint in world.mission.waypoints:
        def miss(s, w=waypoint):
            return math.hypot(s["north_m"] - w.north_m, s["east_m"] - w.east_m)
        inside = [s for s in states if miss(s) <= 2.0] or [min(states, key=miss)]
        best = min(inside, key=lambda s, w=waypoint: abs(s["up_m"] - up0 - w.altitude_m))
        at_it = [s for s in states if miss(s) <= 1.0 and abs(s["up_m"] - up0 - waypoint.altitude_m) <= 0.5]
        waypoints.append({"miss_m": miss(best), "altitude_error_m": best["up_m"] - up0 - waypoint.altitude_m,
                          "at_it_s": len(at_it) * (states[1]["t"] - states[0]["t"])})
    speeds = [math.hypot(*s["v_ned_m_s"][:2]) for s in states]
    return {"waypoints": waypoints, "max_speed_m_s": max(speeds), "states": states}


def chunk_compressions(stream) -> set[str]:
    """The compressions of an MCAP file's chunks (read from a binary stream)."""
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    return {record.compression for record in StreamReader(stream, emit_chunks=True).records if isinstance(record, Chunk)}


# A realistic fault for the gate's tests: collision prevention's stopping distance without the
# distance flown during the sensor's delay (the seeded fault cp_ignores_delay, written as a change).
DELAY_LINE = '    delay = 0.0 if fault == "cp_ignores_delay" else params["CP_DELAY"]\n'


def without_sensor_delay(collision_source: str) -> str:
    assert DELAY_LINE in collision_source, "autopilot/collision.py changed: make the gate's fault again"
    return collision_source.replace(DELAY_LINE, "    delay = 0.0  # the estimator compensates the sensor delay already\n")


def junit_cases(path: Path) -> dict[str, str]:
    """Each test case of a JUnit file, CLASS::NAME, and how it ended."""
    ended = {}
    for case in ET.parse(path).getroot().iter("testcase"):
        kinds = [child.tag for child in case if child.tag in ("failure", "error", "skipped")]
        ended[f"{case.get('classname')}::{case.get('name')}"] = kinds[0] if kinds else "passed"
    return ended
