"""Scratch folders left by killed processes are swept by the next process that makes one."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

from harness.flight import scratch


def a_gone_pid() -> int:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def test_a_folder_names_the_process_and_host_that_made_it_whatever_dashes_its_kind_holds():
    made = scratch.folder("Table_III-scenario-5-seed1")
    try:
        assert scratch.owner(made.name) == (os.getpid(), socket.gethostname())
    finally:
        made.rmdir()
    assert scratch.owner(f"stella-job0-123@build-host-7.example-{'x' * 8}") == (123, "build-host-7.example")
    assert scratch.owner("stella-slots") is None and scratch.owner("stella-warm-abcd1234") is None


def test_only_the_folders_of_gone_owners_on_this_host_are_swept(tmp_path):
    host = "this-host"
    gone = a_gone_pid()
    names = {
        "gone": f"stella-run1-eval00001-{gone}@{host}-abc_1234",
        "alive": f"stella-warm-{os.getpid()}@{host}-abc_1234",
        "elsewhere": f"stella-warm-{gone}@other-host-abc_1234",  # another pid namespace's: not ours to judge
        "lock": "stella-slots",
        "older": "stella-warm-abc_1234",  # named before owners were: its owner is unknown
    }
    for name in names.values():
        (tmp_path / name).mkdir()
        (tmp_path / name / "px4.log").write_text("kept until swept")
    (tmp_path / f"stella-file-{gone}@{host}-abc_1234").write_text("a file, not a folder")
    removed = scratch.sweep(tmp_path, host)
    assert removed == [tmp_path / names["gone"]]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([*(n for k, n in names.items() if k != "gone"), f"stella-file-{gone}@{host}-abc_1234"])


def test_the_first_folder_a_process_makes_sweeps_what_a_killed_one_left(tmp_path):
    leftover = Path(tempfile.mkdtemp(prefix=f"stella-warm-{a_gone_pid()}@{socket.gethostname()}-", dir=tmp_path))
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    made = subprocess.run([sys.executable, "-c", "from harness.flight import scratch; print(scratch.folder('eval'))"], env=env, capture_output=True, text=True,
                          check=True).stdout.strip()
    assert not leftover.exists() and Path(made).is_dir() and Path(made).parent == tmp_path
