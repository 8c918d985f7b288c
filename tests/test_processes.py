"""Child processes die with the harness, even when the harness dies while one is being started."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time

from conftest import ROOT, alive

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
