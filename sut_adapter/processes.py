"""Child processes in their own process group, always killed with their whole group on exit."""

from __future__ import annotations

import concurrent.futures
import ctypes
import functools
import logging
import os
import queue
import signal
import subprocess
import threading
import time
from pathlib import Path
from typing import Callable, Sequence

log = logging.getLogger(__name__)


class ManagedProcess:
    """A context manager around Popen: stdout/stderr to files, SIGTERM then SIGKILL to the group.

    `end_signal` SIGKILL is for a program that acts on SIGTERM only on its simulated clock, which
    nothing advances once its simulator stopped (ArduPilot SITL): it would wait out the grace
    time at every stop and never go when the harness dies."""

    def __init__(self, name: str, argv: Sequence[str], *, log_dir: Path, cwd: Path | None = None, env: dict[str, str] | None = None,
                 end_signal: int = signal.SIGTERM):
        self.name = name
        self.end_signal = end_signal
        self.argv = list(argv)
        self.stdout_path = log_dir / f"{name}.stdout.log"
        self.stderr_path = log_dir / f"{name}.stderr.log"
        self._cwd = cwd
        self._env = env
        self.process: subprocess.Popen | None = None

    def __enter__(self) -> "ManagedProcess":
        log.info("starting %s: %s", self.name, " ".join(self.argv))
        with open(self.stdout_path, "wb") as out, open(self.stderr_path, "wb") as err:
            self.process = subprocess.Popen(
                self.argv, stdout=out, stderr=err, stdin=subprocess.DEVNULL, cwd=self._cwd, env=self._env, start_new_session=True,
                preexec_fn=dies_with_this_process(self.end_signal)
            )
        return self

    def __exit__(self, *exc_info) -> None:
        self.stop()

    @property
    def pid(self) -> int:
        return self.process.pid

    def poll(self) -> int | None:
        return self.process.poll()

    def wait(self, timeout_s: float) -> int | None:
        try:
            return self.process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            return None

    def stop(self, grace_s: float = 2.0) -> int | None:
        """SIGTERM (its end_signal) to the process group, then SIGKILL what is left; returns the exit code."""
        if self.process is None:
            return None
        group = self.process.pid
        if self.process.poll() is None:
            _signal_group(group, self.end_signal)
            if self.wait(grace_s) is None:
                _signal_group(group, signal.SIGKILL)
                self.wait(grace_s)
        # Children that outlived their parent still belong to the group.
        _signal_group(group, signal.SIGKILL)
        return self.process.returncode

    def stderr_tail(self, lines: int = 20) -> str:
        return _tail(self.stderr_path, lines)

    def console_tail(self, lines: int = 20) -> str:
        """The end of stderr, or of stdout for programs that report errors there (PX4)."""
        return self.stderr_tail(lines) or _tail(self.stdout_path, lines)

    def console_logs(self) -> list[Path]:
        """stdout and stderr files that have something in them."""
        return non_empty([self.stdout_path, self.stderr_path])


def printed(path: Path, text: str) -> Callable[[], bool]:
    """Whether a process has written text to its console file (path) yet; each call reads only
    what came since the last, and a text written in pieces counts once whole."""
    needle = text.encode()
    offset, tail, seen = 0, b"", False

    def check() -> bool:
        nonlocal offset, tail, seen
        if not seen:
            try:
                with open(path, "rb") as console:
                    console.seek(offset)
                    data = console.read()
            except OSError:
                return False
            offset += len(data)
            window = tail + data
            seen = needle in window
            tail = window[-(len(needle) - 1):] if len(needle) > 1 else b""
        return seen
    return check


def process_cpu_s(pid: int) -> float | None:
    """The CPU time a process and its descendants have used, with that of the children each has
    reaped (PX4's start-up script runs its commands as client processes; a command SUT may be a
    script that starts the autopilot as its child); None where /proc cannot say."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            text = stat.read()
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return None
    # Fields 14-17 (utime, stime, cutime, cstime), counted after the command name, which may hold spaces.
    fields = text[text.rindex(")") + 2:].split()
    used = sum(int(ticks) for ticks in fields[11:15]) / os.sysconf("SC_CLK_TCK")
    for task in tasks:
        try:
            with open(f"/proc/{pid}/task/{task}/children") as children:
                # A child gone meanwhile has its time in ours once we reaped it: counted as none.
                used += sum(process_cpu_s(int(child)) or 0.0 for child in children.read().split())
        except OSError:
            continue
    return used


def non_empty(paths: list[Path]) -> list[Path]:
    return [p for p in paths if p.exists() and p.stat().st_size > 0]


def _tail(path: Path, lines: int) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return ""


_PR_SET_PDEATHSIG = 1


def die_with_parent(sig: int = signal.SIGTERM, parent_pid: int | None = None) -> None:
    """In the child: get `sig` when the harness dies, even by SIGKILL, so nothing is orphaned.
    A child that sets this up after it was started (a spawned pool worker, after its imports)
    passes `parent_pid`: if the parent died before, no signal would ever come."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(_PR_SET_PDEATHSIG, sig)
    if parent_pid is not None and os.getppid() != parent_pid:
        os.kill(os.getpid(), sig)


def dies_with_this_process(sig: int = signal.SIGTERM) -> Callable[[], None]:
    """A Popen preexec_fn: the child gets `sig` when this process dies. Even a preexec_fn runs
    after the fork, so this process may die first (a campaign killed while a worker starts its
    simulator: the child, not yet in a session of its own, is stopped and continued with the
    campaign's group); the child then kills itself instead of running on as an orphan.

    Linux sends the signal when the *thread* that forked the child ends, not the process: fork
    from a thread that outlives the child (the caller's, while it waits for it), or through a
    Launcher."""
    return functools.partial(die_with_parent, sig, os.getpid())


class Launcher:
    """Starts children that die with this process but outlive the thread that asked for them
    (a web server's request thread, which its pool retires when idle): every fork happens on one
    thread of the launcher's own, which lives until `close`. Close it once its children are gone:
    they get the signal then."""

    def __init__(self, name: str = "launcher", start_timeout_s: float = 60.0):
        self._requests: queue.SimpleQueue = queue.SimpleQueue()
        self._start_timeout_s = start_timeout_s
        self._closed = False
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._serve, name=name, daemon=True)
        self._thread.start()

    def popen(self, argv: Sequence[str], sig: int = signal.SIGTERM, **popen_arguments) -> subprocess.Popen:
        """subprocess.Popen(argv, **popen_arguments) forked on the launcher's thread; the child gets `sig` when this process dies."""
        started: concurrent.futures.Future = concurrent.futures.Future()
        with self._lock:
            if self._closed:
                raise RuntimeError("the launcher is closed")
            self._requests.put((list(argv), sig, popen_arguments, started))
        return started.result(timeout=self._start_timeout_s)

    def _serve(self) -> None:
        while (request := self._requests.get()) is not None:
            argv, sig, popen_arguments, started = request
            try:
                started.set_result(subprocess.Popen(argv, preexec_fn=dies_with_this_process(sig), **popen_arguments))
            except Exception as error:  # raised in the asking thread
                started.set_exception(error)

    def close(self, timeout_s: float = 10.0) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._requests.put(None)
        self._thread.join(timeout_s)


def _signal_group(group: int, sig: int) -> None:
    try:
        os.killpg(group, sig)
    except ProcessLookupError:
        pass
    except PermissionError:
        log.warning("cannot signal process group %d", group)


def wait_until(predicate, timeout_s: float, interval_s: float = 0.02) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(interval_s)
    return predicate()
