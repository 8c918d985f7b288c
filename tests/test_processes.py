"""Child processes die with the harness, even when the harness dies while one is being started,
and say how much CPU they used."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from conftest import ROOT, alive
from sut_adapter.base import SutHandle
from sut_adapter.processes import process_cpu_s

# The parent makes the hook, forks, and exits at once; its child sets the hook up only after
# that, as a Popen child does when the parent is killed between fork and preexec_fn.
LATE_CHILD = textwrap.dedent("""
    import os, time
    from sut_adapter.processes import dies_with_this_process
    hook = dies_with_this_process()
    child = os.fork()
    if child == 0:
        time.sleep(0.5)
        hook()
        time.sleep(30)
        os._exit(0)
    print(child, flush=True)
""")


def test_a_child_whose_parent_died_before_it_set_up_its_death_signal_ends_itself():
    parent = subprocess.run([sys.executable, "-c", LATE_CHILD], capture_output=True, text=True, cwd=ROOT, timeout=30, check=True)
    child = int(parent.stdout)
    deadline = time.monotonic() + 10.0
    while alive(child) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not alive(child)


# A child computes for a while; a start-up script's shell has reaped it, a wrapper script's still waits on it.
BUSY = f"""{sys.executable} -c 'import time
end = time.process_time() + 0.4
while time.process_time() < end: pass
time.sleep({{after}})'"""
REAPED_THEN_WAIT = BUSY.format(after=0) + "; sleep 30"
STILL_RUNNING = BUSY.format(after=30) + " & wait"


@pytest.mark.parametrize("script", [REAPED_THEN_WAIT, STILL_RUNNING], ids=["reaped", "running"])
def test_a_sut_processes_cpu_time_counts_its_childrens_and_none_is_said_when_it_is_gone(script):
    """GIVEN a SUT process whose child computed 0.4 s of CPU, reaped (as PX4's start-up script's
    client processes are) or still running (a wrapper script's autopilot) WHEN its CPU time is
    read THEN the child's is in it (to the clock ticks /proc counts in); a handle of no processes
    (a SUT in memory) or of one that is gone says None rather than a number."""
    shell = subprocess.Popen(["sh", "-c", script], start_new_session=True)
    try:
        handle = SutHandle(name="busy", alive=lambda: shell.poll() is None, stop=shell.kill, pids=[shell.pid])
        deadline = time.monotonic() + 10.0
        while (handle.cpu_s() or 0.0) < 0.35 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert 0.35 <= handle.cpu_s() < 1.0
    finally:
        os.killpg(shell.pid, signal.SIGKILL)
        shell.wait()
    assert process_cpu_s(shell.pid) is None
    assert SutHandle(name="inline", alive=lambda: True, stop=lambda: None).cpu_s() is None
