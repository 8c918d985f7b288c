"""The Docker executor: every try flies in a container of its own, through the Docker Engine API.

Each container runs `python -m harness.execution.worker` from the worker image (docker/Dockerfile) with
no network (the bridge, the SUT and MAVSDK talk over the container's own loopback), one CPU
(its own core where there are enough), a memory and a process limit, and the host's user id;
the job goes in and the result, the MCAP log and the SUT's artifacts come out through a
folder mounted at /job, and the log is moved beside the campaign's other logs. The container
is removed afterwards, also when it was killed or overran. A SUT's build (a PX4 or ArduPilot
build folder, an --autopilot-dir) is mounted read-only and the job's configuration names it
there; `check_sut` starts its programs in a container once, before a campaign flies.

`build_image` makes the worker image; `make_base` makes a Debian base image with debootstrap
where no image registry can be reached (`stella docker build --make-base`).
"""

from __future__ import annotations

import concurrent.futures
import io
import json
import logging
import os
import shutil
import subprocess
import tarfile
import tempfile
import threading
from dataclasses import replace
from pathlib import Path
from typing import Iterator

from harness.errors import InfrastructureError
from harness.execution.executor import DEFAULT_ATTEMPTS, DEFAULT_TIMEOUT_S, Executor, Job, WorkerLost, failed_try
from harness.flight import scratch
from harness.flight.results import EvaluationResult
from harness.flight.fitness import Status
from harness.paths import project_root
from sut_adapter import SutConfig, SutError, elsewhere

log = logging.getLogger(__name__)

ROOT = project_root()
IMAGE = "stella-worker:latest"
BASE_IMAGE = "stella-base:bookworm"
DEBIAN_MIRROR = "http://deb.debian.org/debian"
HOST_CA = Path("/etc/ssl/certs/ca-certificates.crt")
MEMORY_LIMIT = "2g"
PIDS_LIMIT = 512
# A start check runs the SUT's programs' help (sut_adapter.elsewhere, 30 s each at most).
START_CHECK_TIMEOUT_S = 120.0


def engine():
    """A client of the local Docker Engine; InfrastructureError when none answers."""
    import docker

    try:
        client = docker.from_env(version="auto", timeout=120)
        client.ping()
        return client
    except Exception as error:  # docker raises DockerException, requests' errors, FileNotFoundError for the socket
        raise InfrastructureError(f"no Docker Engine answers ({error}); start dockerd, or use another executor") from None


def image_exists(tag: str) -> bool:
    import docker

    try:
        engine().images.get(tag)
        return True
    except docker.errors.ImageNotFound:
        return False


def make_base(tag: str = BASE_IMAGE, mirror: str = DEBIAN_MIRROR) -> str:
    """A minimal Debian bookworm with python3, venv and what compiles the hot path, made with debootstrap and imported."""
    if shutil.which("debootstrap") is None:
        raise InfrastructureError("debootstrap is not installed (apt-get install debootstrap)")
    with tempfile.TemporaryDirectory(prefix=scratch.prefix("rootfs")) as rootfs:
        subprocess.run(["debootstrap", "--variant=minbase", "--include=python3,python3-venv,python3-dev,gcc,libc6-dev,ca-certificates", "bookworm", rootfs, mirror],
                       check=True, stdout=subprocess.DEVNULL)
        tar = subprocess.Popen(["tar", "-C", rootfs, "-c", "."], stdout=subprocess.PIPE)
        subprocess.run(["docker", "import", "-", tag], stdin=tar.stdout, check=True, stdout=subprocess.DEVNULL)
        if tar.wait() != 0:
            raise InfrastructureError("packing the debootstrapped root file system failed")
    return tag


def _context() -> io.BytesIO:
    """The build context: the project's tracked files, the Dockerfile and the host's CA bundle."""
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, check=True, capture_output=True).stdout.decode().split("\0")
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as tar:
        for name in filter(None, listed):
            if (ROOT / name).is_file():
                tar.add(ROOT / name, arcname=name)
        tar.add(ROOT / "docker" / "Dockerfile", arcname="Dockerfile")
        tar.add(HOST_CA, arcname="host-ca-certificates.crt")
    buffer.seek(0)
    return buffer


def build_image(base: str, tag: str = IMAGE) -> Iterator[str]:
    """Build the worker image from base; yields the build's output lines. The image the tag
    named before is removed once nothing refers to it, so rebuilds do not pile up."""
    import docker

    client = engine()
    previous = client.images.get(tag).id if image_exists(tag) else None
    for chunk in client.api.build(fileobj=_context(), custom_context=True, tag=tag, buildargs={"BASE": base}, network_mode="host", rm=True, decode=True):
        if "error" in chunk:
            raise InfrastructureError(f"building {tag} failed: {chunk['error']}")
        if chunk.get("stream", "").strip():
            yield chunk["stream"].rstrip()
    if previous is not None and client.images.get(tag).id != previous:
        try:
            client.images.remove(previous, noprune=False)
        except docker.errors.APIError as error:  # still used by a container or another tag
            log.info("kept the previous worker image %s: %s", previous, error)


def _build_volumes(sut: SutConfig) -> dict[str, dict[str, str]]:
    """The SUT's build folders (a PX4 or ArduPilot build, an autopilot folder), read-only where
    the job's relocated configuration names them."""
    points = elsewhere.mount_points(sut)
    return {str(build.folder): {"bind": points[build.option], "mode": "ro"} for build in elsewhere.build_folders(sut)}


class DockerExecutor(Executor):
    name = "docker"

    def __init__(self, workers: int | None = None, attempts: int = DEFAULT_ATTEMPTS, timeout_s: float = DEFAULT_TIMEOUT_S, image: str | None = None):
        super().__init__(workers or len(os.sched_getaffinity(0)), attempts, timeout_s)
        self.image = image or IMAGE
        if not image_exists(self.image):
            raise InfrastructureError(f"no image {self.image}; build it with `stella docker build` (add --make-base where no registry is reachable)")
        self.client = engine()
        self._threads = concurrent.futures.ThreadPoolExecutor(self.workers, thread_name_prefix="docker-try")
        self._cores = sorted(os.sched_getaffinity(0))
        self._free_cores = list(self._cores)
        self._lock = threading.Lock()
        self.running: dict[str, str] = {}  # job name -> container id, for fault tests and cancel
        # The start checks passed so far (a mutation run checks its SUT before each of its campaigns).
        self._started_once: set[tuple[str, tuple[str, ...]]] = set()

    def cores_per_evaluation(self) -> int:
        return 1  # a container gets one CPU (see _try)

    def submit(self, job: Job) -> concurrent.futures.Future:
        return self._threads.submit(self._try, job)

    def check_sut(self, sut: SutConfig) -> None:
        """Start the SUT's programs in a container as evaluations will have them (its build
        mounted read-only), or look its command up there."""
        try:
            volumes = _build_volumes(sut)
            check = elsewhere.start_check(sut, elsewhere.mount_points(sut))
        except SutError as error:
            raise InfrastructureError(str(error)) from None
        checked = (check, tuple(sorted(volumes)))
        if check == elsewhere.NOTHING_TO_CHECK or checked in self._started_once:  # the bundled autopilot is the image's own
            return
        import docker
        import requests

        try:
            container = self.client.containers.run(self.image, ["sh", "-c", check], detach=True, network_mode="none", mem_limit=MEMORY_LIMIT,
                                                   user=f"{os.getuid()}:{os.getgid()}", volumes=volumes, labels={"stella.job": "start-check"})
            try:
                code = container.wait(timeout=START_CHECK_TIMEOUT_S)["StatusCode"]
                said = container.logs().decode(errors="replace").strip()
            finally:
                container.remove(force=True)
        except (docker.errors.DockerException, requests.exceptions.RequestException) as error:
            raise InfrastructureError(f"could not check that the {sut.name} SUT starts in {self.image}: {error}") from None
        if code != 0:
            raise InfrastructureError(f"the {sut.name} SUT cannot start in the worker image {self.image}: {said or f'its check exited with {code}'}; "
                                      "fly it with --executor local, or build an image that has what it needs")
        self._started_once.add(checked)

    def _try(self, job: Job) -> EvaluationResult:
        with self._lock:
            core = self._free_cores.pop(0) if self._free_cores else None
        folder = scratch.folder(job.name)
        try:
            (folder / "out").mkdir()
            sut = job.options.sut
            inside = replace(job, out_dir="/job/out", options=replace(job.options, sut=elsewhere.relocated(sut, elsewhere.mount_points(sut))))
            (folder / "job.json").write_text(json.dumps(inside.to_json()))
            return self._fly(job, folder, core)
        finally:
            shutil.rmtree(folder, ignore_errors=True)
            if core is not None:
                with self._lock:
                    self._free_cores.append(core)

    def _fly(self, job: Job, folder: Path, core: int | None) -> EvaluationResult:
        import requests

        container = self.client.containers.run(
            self.image, ["python", "-m", "harness.execution.worker", "--job", "/job/job.json", "--result", "/job/result.json"],
            detach=True, network_mode="none", nano_cpus=1_000_000_000, mem_limit=MEMORY_LIMIT, pids_limit=PIDS_LIMIT,
            cpuset_cpus=str(core) if core is not None else None, user=f"{os.getuid()}:{os.getgid()}",
            volumes={str(folder): {"bind": "/job", "mode": "rw"}, **_build_volumes(job.options.sut)}, labels={"stella.job": job.name},
        )
        self.running[job.name] = container.id
        try:
            try:
                exit_code = container.wait(timeout=self.timeout_s)["StatusCode"]
            except (requests.exceptions.ReadTimeout, requests.exceptions.ConnectionError):
                container.kill()
                return failed_try(job, Status.TIMEOUT, f"no result within {self.timeout_s:.0f} s wall time (the executor's limit per try)")
            result_file = folder / "result.json"
            if exit_code != 0 or not result_file.exists():
                tail = container.logs(tail=5).decode(errors="replace").strip().replace("\n", " | ")
                raise WorkerLost(f"container {container.short_id} exited with {exit_code}" + (" (killed)" if exit_code == 137 else "") + (f": {tail}" if tail else ""))
            return self._bring_back(EvaluationResult.from_dict(json.loads(result_file.read_text())), folder / "out", Path(job.out_dir))
        finally:
            self.running.pop(job.name, None)
            container.remove(force=True)

    @staticmethod
    def _bring_back(result: EvaluationResult, inside: Path, outside: Path) -> EvaluationResult:
        """Move the log and artifacts out of the container's folder; point the result at them."""
        outside.mkdir(parents=True, exist_ok=True)
        for entry in inside.iterdir():
            target = outside / entry.name
            if target.is_dir():
                shutil.rmtree(target)
            shutil.move(str(entry), target)

        def moved(path: str | None) -> str | None:
            return str(outside / Path(path).relative_to("/job/out")) if path else None

        return replace(result, log_path=moved(result.log_path), artifacts=[moved(a) for a in result.artifacts])

    def cancel(self) -> None:
        super().cancel()
        for container_id in list(self.running.values()):
            try:
                self.client.containers.get(container_id).kill()
            except Exception as error:  # already gone
                log.debug("cannot kill %s: %s", container_id, error)

    def close(self) -> None:
        self.cancel()
        self._threads.shutdown(wait=True, cancel_futures=True)
        self.client.close()
