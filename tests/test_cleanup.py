"""After many runs, finished, interrupted (Ctrl-C) or killed (kill -9), nothing is left behind."""

from __future__ import annotations

import json
import os
import random
import signal
import socket
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from conftest import ROOT, alive, described, descendants, port_bound
from harness.flight import scratch
from harness.flight.ports import API_BASE, CONTROL_BASE, SIM_BASE

pytestmark = [pytest.mark.slow, pytest.mark.alone]
SCENARIO = ROOT / "scenarios" / "table3" / "scenario_05.json"


def our_processes() -> list[str]:
    """The simulator and autopilot processes this checkout's Python started: on a shared machine
    another checkout's campaign may be running its own."""
    found = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as handle:
                argv = handle.read().split(b"\0")
        except OSError:
            continue
        ours = os.path.dirname(argv[0].decode(errors="replace")) == os.path.dirname(sys.executable)
        if ours and b"-m" in argv and ({b"sim_bridge", b"autopilot", b"sut_adapter.inline"} & set(argv)):
            found.append(f"{pid}: {b' '.join(argv).decode(errors='replace')}")
    return found


def test_twenty_runs_including_interrupted_and_killed_ones_leave_no_process_port_or_folder(tmp_path):
    assert our_processes() == [], "processes of an earlier test are still running"
    rng = random.Random(7)
    endings = ["finish"] * 10 + ["interrupt"] * 5 + ["kill"] * 5
    rng.shuffle(endings)
    assert "finish" in endings[len(endings) - endings[::-1].index("kill"):]  # a run after the last kill sweeps what it left
    outcomes = []
    left_by_kills: list[Path] = []
    for index, ending in enumerate(endings):
        command = [sys.executable, "-m", "harness.tools.cli", "run", str(SCENARIO), "--seed", str(index), "--out", str(tmp_path), "--json"]
        run = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, cwd=ROOT)
        if ending == "finish":
            out, _ = run.communicate(timeout=120)
            assert run.returncode == 0
            outcomes.append(json.loads(out)["status"])
            continue
        time.sleep(rng.uniform(0.3, 3.0))
        run.send_signal(signal.SIGINT if ending == "interrupt" else signal.SIGKILL)
        run.communicate(timeout=60)
        outcomes.append(ending)
        if ending == "kill":  # its own cleanup never runs: its evaluation's folder stays until another run starts
            left_by_kills += [path for path in Path(tempfile.gettempdir()).iterdir() if (scratch.owner(path.name) or (0, ""))[0] == run.pid]
    deadline = time.monotonic() + 15
    while our_processes() and time.monotonic() < deadline:
        time.sleep(0.2)
    assert our_processes() == []
    for slot in range(4):
        assert not port_bound(SIM_BASE + slot, socket.SOCK_STREAM)
        assert not port_bound(CONTROL_BASE + slot, socket.SOCK_STREAM)
        assert not port_bound(API_BASE + slot, socket.SOCK_DGRAM)
    assert outcomes.count("ok") + outcomes.count("violation") == 10
    assert left_by_kills and [path for path in left_by_kills if path.exists()] == []


def stored(store) -> list[tuple]:
    if not store.exists():
        return []
    with sqlite3.connect(store) as db:
        try:
            return db.execute("SELECT run_id, ordinal, vector_key, fitness, created FROM evaluations ORDER BY run_id, ordinal").fetchall()
        except sqlite3.OperationalError:  # killed before it made its tables
            return []


def test_a_campaign_killed_at_ten_random_moments_loses_nothing_repeats_nothing_and_leaves_nothing(tmp_path):
    """Issue 18: kill -9 of a two-worker campaign at ten random moments (starting up, flying,
    writing), each followed by a resume; defect 3 was its workers living on."""
    assert our_processes() == [], "processes of an earlier test are still running"
    def command(store):
        return [sys.executable, "-m", "harness.tools.cli", "campaign", str(SCENARIO), "--algorithm", "NSGAII", "--evaluations", "10", "--population", "4",
                "--seed", "2", "--workers", "2", "--store", str(store), "--json"]
    store = tmp_path / "killed.db"
    rng = random.Random(18)
    seen: dict[tuple, tuple] = {}
    for _moment in range(10):
        campaign = subprocess.Popen(command(store), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT, start_new_session=True)
        time.sleep(rng.uniform(0.5, 8.0))
        # Frozen first, so that what is read and which processes exist is what the kill leaves.
        os.killpg(campaign.pid, signal.SIGSTOP)
        family = descendants(campaign.pid)
        rows = stored(store)
        # kill -9 of the campaign alone (its workers must follow by themselves). Not Popen.kill:
        # on a campaign that already finished it reaps the process first, which empties the group
        # the next line continues.
        os.kill(campaign.pid, signal.SIGKILL)
        os.killpg(campaign.pid, signal.SIGCONT)
        campaign.wait(timeout=10)
        deadline = time.monotonic() + 15
        while (our_processes() or any(alive(pid) for pid in family)) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert our_processes() == [] and [pid for pid in family if alive(pid)] == [], [described(pid) for pid in family if alive(pid)]
        keys = [(run, ordinal) for run, ordinal, *_ in rows]
        assert len(keys) == len(set(keys)), "an evaluation was stored twice"
        now = {(run, ordinal): row for run, ordinal, *row in rows}
        assert all(now.get(key) == row for key, row in seen.items()), "a stored evaluation was lost or changed"
        seen.update(now)
    before_finishing = stored(store)
    finished = subprocess.run(command(store), capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert finished.returncode == 0, finished.stderr[-2000:]
    # What was stored is replayed, not flown again; a run that finished before the last kill is not run again.
    replayed = [run["replayed"] for run in json.loads(finished.stdout)["runs"]]
    assert replayed == [len(before_finishing)] or (replayed == [] and len(before_finishing) == 10), (replayed, len(before_finishing))
    final = stored(store)
    assert [ordinal for _run, ordinal, *_ in final] == list(range(10))
    assert all({(run, ordinal): row for run, ordinal, *row in final}[key] == row for key, row in seen.items())
    subprocess.run(command(tmp_path / "clean.db"), capture_output=True, timeout=600, cwd=ROOT, check=True)
    uninterrupted = stored(tmp_path / "clean.db")
    assert [row[1:4] for row in final] == [row[1:4] for row in uninterrupted]  # the same candidates and results, in order
