"""The Dask executor: every try is a task on a dask.distributed cluster.

Connects to a scheduler (`--dask-scheduler tcp://HOST:8786`) or starts a LocalCluster of
`--workers` processes with one thread each. A task runs the evaluation as a process of its own
(`python -m harness.execution.worker`), which dies with the task's worker and is killed whole when it
overruns the executor's limit. Dask reschedules the task of a worker that is lost; a task that
keeps losing its workers ends as KilledWorker and counts as a failed try here.

Every worker needs stella installed (the worker image does) and the campaign's log folder at
the same path (a shared file system on a multi-machine cluster), since that is where each
evaluation writes its MCAP; and the SUT's build at the same path, the same build by its
digest, which `check_sut` asks every worker before a campaign flies.
"""

from __future__ import annotations

import concurrent.futures
import hashlib
import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import uuid
from dataclasses import replace
from pathlib import Path
from typing import Any, Mapping

from harness.flight import scratch
from harness.execution.executor import DEFAULT_ATTEMPTS, DEFAULT_TIMEOUT_S, Executor, Job, WorkerLost, failed_try
from harness.flight.results import EvaluationResult
from harness.errors import InfrastructureError
from harness.flight.fitness import Status
from sut_adapter import SutConfig, SutError, elsewhere
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


def build_missing(programs: list[tuple[str, str]], folders: list[str], command: str | None) -> str | None:
    """On a worker: why the SUT's build is not there ((program, sha256) pairs, folders, a command
    SUT's program), or None."""
    for path, digest in programs:
        if not Path(path).is_file():
            return f"{path} is not there"
        if _sha256(Path(path)) != digest:
            return f"{path} is another build than the campaign's (its sha256 differs)"
    for folder in folders:
        if not Path(folder).is_dir():
            return f"{folder} is not there"
    if command is not None and shutil.which(command) is None:
        return f"the command {command} is not found"
    return None


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


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

    def check_sut(self, sut: SutConfig) -> None:
        """Every worker must have the SUT's build at the path the campaign names, the same by its digest."""
        try:
            builds = elsewhere.build_folders(sut)
        except SutError as error:
            raise InfrastructureError(str(error)) from None
        programs = [(str(build.folder / build.program), _sha256(build.folder / build.program)) for build in builds if build.program]
        folders = [str(build.folder) for build in builds if not build.program]
        command = shlex.split(sut.command)[0] if sut.command else None
        missing = {worker: why for worker, why in self._client.run(build_missing, programs, folders, command).items() if why}
        if missing:
            raise InfrastructureError(f"the {sut.name} SUT's build is missing on {len(missing)} of the cluster's workers: "
                                      + "; ".join(f"{worker}: {why}" for worker, why in sorted(missing.items()))
                                      + "; put the same build at the same path on every worker")

    def cores_per_evaluation(self) -> int:
        # A scheduler's workers run on machines whose cores this process cannot see.
        return 1 if self._cluster is None else super().cores_per_evaluation()

    def submit(self, job: Job) -> concurrent.futures.Future:
        from distributed import KilledWorker

        outer: concurrent.futures.Future = concurrent.futures.Future()
        # The build as check_sut found it here, by its absolute path: not what a worker's own
        # environment (STELLA_PX4_BIN) or working directory would make of the job's.
        sut = job.options.sut
        job = replace(job, options=replace(job.options, sut=elsewhere.relocated(sut, {b.option: str(b.folder) for b in elsewhere.build_folders(sut)})))
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
