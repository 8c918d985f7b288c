"""Executors on this machine: in this process (`sequential`), or a pool of worker processes (`local`)."""

from __future__ import annotations

import concurrent.futures
import multiprocessing
import multiprocessing.util
import os
import signal

from harness.flight import stack
from harness.execution.executor import DEFAULT_ATTEMPTS, DEFAULT_TIMEOUT_S, Executor, Job, run_job_with_watchdog
from sut_adapter.processes import die_with_parent


class SequentialExecutor(Executor):
    name = "sequential"
    keeps_stacks = True

    def __init__(self, attempts: int = DEFAULT_ATTEMPTS, timeout_s: float = DEFAULT_TIMEOUT_S):
        super().__init__(1, attempts, timeout_s)

    def submit(self, job: Job) -> concurrent.futures.Future:
        future: concurrent.futures.Future = concurrent.futures.Future()
        future.set_result(run_job_with_watchdog(job, self.timeout_s))
        return future


class LocalExecutor(Executor):
    """A pool of worker processes on this machine. A worker that dies (killed, out of memory)
    breaks Python's pool for every try in flight: the pool is rebuilt and those tries count as
    failed ones with the cause recorded."""

    name = "local"
    keeps_stacks = True

    def __init__(self, workers: int | None = None, attempts: int = DEFAULT_ATTEMPTS, timeout_s: float = DEFAULT_TIMEOUT_S):
        super().__init__(workers or len(os.sched_getaffinity(0)), attempts, timeout_s)
        self._pool = self._new_pool()

    def _new_pool(self) -> concurrent.futures.ProcessPoolExecutor:
        # spawn, not fork: the parent may hold threads (MAVSDK, progress) that fork would copy half-way.
        # A worker is killed with the campaign, however the campaign ends (even kill -9); its
        # evaluation's processes follow it the same way (processes.die_with_parent).
        return concurrent.futures.ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"),
                                                      initializer=_start_worker, initargs=(os.getpid(),))

    def submit(self, job: Job) -> concurrent.futures.Future:
        try:
            return self._pool.submit(run_job_with_watchdog, job, self.timeout_s)
        except concurrent.futures.process.BrokenProcessPool:
            self.recover()
            return self._pool.submit(run_job_with_watchdog, job, self.timeout_s)

    def lost_worker(self, error: BaseException) -> bool:
        return isinstance(error, concurrent.futures.process.BrokenProcessPool)

    def recover(self) -> None:
        if getattr(self._pool, "_broken", False):
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = self._new_pool()

    def worker_pids(self) -> list[int]:
        """The pool's worker processes (fault tests kill one)."""
        return [process.pid for process in self._pool._processes.values()]

    def close(self) -> None:
        super().close()
        self._pool.shutdown(wait=True, cancel_futures=True)


def _start_worker(parent_pid: int) -> None:
    """A pool worker dies with the campaign; when the pool shuts it down, it first closes the
    stack its evaluations kept warm (RunOptions.warm), so that no process or port outlives it."""
    die_with_parent(signal.SIGKILL, parent_pid)
    multiprocessing.util.Finalize(None, stack.close_kept, exitpriority=0)
