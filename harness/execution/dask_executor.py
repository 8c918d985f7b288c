"""The Dask executor: every try is a task on a dask.distributed cluster.

Connects to a scheduler (`--dask-scheduler tcp://HOST:8786`) or starts a LocalCluster of
`--workers` processes with one thread each. A task runs the evaluation as a process of its own
(`python -m harness.execution.worker`), which dies with the task's worker and is killed whole when it
overruns the executor's limit. Dask reschedules the task of a worker that is lost; a task that
keeps losing its workers ends as KilledWorker and counts as a failed try here.

Every worker needs stella installed (the worker image does) and the campaign's log folder at
the same path (a shared file system on a multi-machine cluster), since that is where each
evaluation writes its MCAP.
"""

from __future__ import annotations

import concurrent.futures
import json
import os
import signal
import subprocess
import sys
import tempfile
import uuid
from pathlib import Path
from typing import Any, Mapping

from harness.flight import scratch
from harness.execution.executor import DEFAULT_ATTEMPTS, DEFAULT_TIMEOUT_S, Executor, Job, WorkerLost, failed_try
from harness.flight.results import EvaluationResult
from harness.flight.fitness import Status
from sut_adapter.processes import dies_with_this_process


def fly_in_subprocess(document: Mapping[str, Any], timeout_s: float) -> dict[str, Any]:
    """The task: one try in its own process group, ended after timeout_s; its result as JSON data
    (the cluster's workers may run another build of this package than the client)."""
    job = Job.from_json(document)
    with tempfile.TemporaryDirectory(prefix=scratch.prefix("task")) as folder:
        job_file, result_file = Path(folder) / "job.json", Path(folder) / "result.json"
        job_file.write_text(json.dumps(document))
        process = subprocess.Popen([sys.executable, "-m", "harness.execution.worker", "--job", str(job_file), "--result", str(result_file)],
                                   stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                   start_new_session=True, preexec_fn=dies_with_this_process())
        try:
            _out, err = process.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
            return failed_try(job, Status.TIMEOUT, f"no result within {timeout_s:.0f} s wall time (the executor's limit per try)").as_dict()
        if process.returncode != 0 or not result_file.exists():
            tail = err.decode(errors="replace").strip().splitlines()[-5:]
            return failed_try(job, Status.SIM_CRASHED, f"the evaluation process exited with {process.returncode}: {' | '.join(tail)}").as_dict()
        return json.loads(result_file.read_text())


class DaskExecutor(Executor):
    name = "dask"

    def __init__(self, workers: int | None = None, attempts: int = DEFAULT_ATTEMPTS, timeout_s: float = DEFAULT_TIMEOUT_S, scheduler: str | None = None):
        from dask.distributed import Client, LocalCluster

        self._cluster = None
        if scheduler:
            self._client = Client(scheduler)
            workers = workers or sum(w["nthreads"] for w in self._client.scheduler_info()["workers"].values())
        else:
            workers = workers or len(os.sched_getaffinity(0))
            self._cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
            self._client = Client(self._cluster)
        super().__init__(workers, attempts, timeout_s)

    @property
    def client(self):
        return self._client

    def cores_per_evaluation(self) -> int:
        # A scheduler's workers run on machines whose cores this process cannot see.
        return 1 if self._cluster is None else super().cores_per_evaluation()

    def submit(self, job: Job) -> concurrent.futures.Future:
        from distributed import KilledWorker

        outer: concurrent.futures.Future = concurrent.futures.Future()
        task = self._client.submit(fly_in_subprocess, job.to_json(), self.timeout_s, key=f"{job.name}-{uuid.uuid4().hex[:8]}", pure=False)

        def relay(done) -> None:
            if outer.done():  # cancelled from this side
                return
            if done.status == "finished":
                outer.set_result(EvaluationResult.from_dict(done.result()))
            elif done.status == "cancelled":
                outer.cancel() or outer.set_exception(WorkerLost("the task was cancelled"))
            else:
                error = done.exception()
                outer.set_exception(WorkerLost(f"Dask lost the task's workers: {error}") if isinstance(error, KilledWorker) else error)

        task.add_done_callback(relay)
        outer.add_done_callback(lambda done: task.cancel() if done.cancelled() else None)
        return outer

    def close(self) -> None:
        super().close()
        self._client.close()
        if self._cluster is not None:
            self._cluster.close()
