"""After many runs, finished, interrupted (Ctrl-C) or killed (kill -9), nothing is left behind."""

from __future__ import annotations

import json
import os
import random
import signal
import socket
import subprocess
import sys
import time

import pytest

from conftest import ROOT, children, port_bound
from harness.ports import API_BASE, CONTROL_BASE, SIM_BASE

pytestmark = pytest.mark.slow
SCENARIO = ROOT / "scenarios" / "table3" / "scenario_05.json"


def our_processes() -> list[str]:
    found = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as handle:
                argv = handle.read().split(b"\0")
        except OSError:
            continue
        if b"-m" in argv and (b"sim_bridge" in argv or b"autopilot" in argv):
            found.append(f"{pid}: {b' '.join(argv).decode(errors='replace')}")
    return found


def test_twenty_runs_including_interrupted_and_killed_ones_leave_no_process_or_port(tmp_path):
    assert our_processes() == [], "processes of an earlier test are still running"
    rng = random.Random(7)
    endings = ["finish"] * 10 + ["interrupt"] * 5 + ["kill"] * 5
    rng.shuffle(endings)
    outcomes = []
    for index, ending in enumerate(endings):
        command = [sys.executable, "-m", "harness.cli", "run", str(SCENARIO), "--seed", str(index), "--out", str(tmp_path), "--json"]
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
    deadline = time.monotonic() + 15
    while our_processes() and time.monotonic() < deadline:
        time.sleep(0.2)
    assert our_processes() == []
    for slot in range(4):
        assert not port_bound(SIM_BASE + slot, socket.SOCK_STREAM)
        assert not port_bound(CONTROL_BASE + slot, socket.SOCK_STREAM)
        assert not port_bound(API_BASE + slot, socket.SOCK_DGRAM)
    assert outcomes.count("ok") + outcomes.count("violation") == 10


def test_a_campaign_killed_with_sigkill_leaves_no_worker_and_no_flight_behind(tmp_path):
    """Issue 18, defect 3: the multiprocessing workers of a killed campaign lived on."""
    assert our_processes() == [], "processes of an earlier test are still running"
    command = [sys.executable, "-m", "harness.cli", "campaign", str(SCENARIO), "--algorithm", "RANDOM", "--evaluations", "20",
               "--workers", "2", "--store", str(tmp_path / "c.db")]
    campaign = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT)
    deadline = time.monotonic() + 60
    while not our_processes() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert our_processes(), "the campaign never started a flight"
    workers = children(campaign.pid)  # the pool's workers and multiprocessing's resource tracker
    assert len(workers) >= 2
    campaign.kill()
    campaign.wait(timeout=10)
    deadline = time.monotonic() + 15
    while (our_processes() or any(os.path.exists(f"/proc/{pid}") for pid in workers)) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert our_processes() == []
    assert [pid for pid in workers if os.path.exists(f"/proc/{pid}")] == []
