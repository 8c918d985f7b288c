"""The Docker executor on a real engine: one container per try, limits, logs brought back,
containers removed, a killed container retried, and the same campaign as everywhere else.
`make test` installs and starts the engine and builds the worker image first."""

from __future__ import annotations

import os
import sys
import threading
import time

import pytest

from conftest import FIG4_SEED1_FITNESS, ROOT, SEEDED_CAMPAIGN, campaign_candidates, fig4_job, run_seeded_campaign
from harness.errors import InfrastructureError
from harness.execution.executor import run_job
from harness.flight import logs
from sut_adapter import SutConfig
from test_executors import SILENT_SUT
from test_transport import SIMULATED

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def engine():
    from harness.execution.docker_executor import IMAGE, engine, image_exists

    try:
        client = engine()
    except InfrastructureError as error:
        pytest.skip(f"no Docker Engine can be reached here: {error}")
    if not image_exists(IMAGE):
        pytest.skip(f"no worker image {IMAGE}: `make docker` (part of `make test`) builds it")
    return client


def stella_containers(client) -> list:
    return client.containers.list(all=True, filters={"label": "stella.job"})


@pytest.fixture
def executor(engine):
    from harness.execution.registry import make_executor

    made = []

    def make(workers=2, **kwargs):
        made.append(make_executor("docker", workers, **kwargs))
        return made[-1]

    yield make
    for each in made:
        each.close()
    assert stella_containers(engine) == []


def test_a_container_flies_a_scenario_with_limits_and_its_log_comes_back(engine, executor, tmp_path, profile):
    docker = executor()
    seen = {}

    def watch():
        deadline = time.monotonic() + 60.0
        while not seen and time.monotonic() < deadline:
            for container_id in list(docker.running.values()):
                seen.update(engine.api.inspect_container(container_id)["HostConfig"])
            time.sleep(0.05)

    watcher = threading.Thread(target=watch)
    watcher.start()
    [(_job, result)] = list(docker.run([fig4_job(tmp_path, profile)]))
    watcher.join()
    assert result.status == "ok" and result.fitness == FIG4_SEED1_FITNESS
    assert result.log_path == str(tmp_path / "job0.mcap")
    assert sum(len(m["d"]) for _t, _ns, m in logs.messages(result.log_path, ["/clearance"])) > 1000
    assert (seen["NetworkMode"], seen["NanoCpus"], seen["Memory"], seen["PidsLimit"]) == ("none", 1_000_000_000, 2 * 1024**3, 512)
    # The image's flight is the flight a local worker flies, to the last bit.
    local = run_job(fig4_job(tmp_path / "local", profile))
    assert list(logs.messages(result.log_path, SIMULATED)) == list(logs.messages(local.log_path, SIMULATED))


def test_the_image_flies_the_compiled_hot_path(engine):
    """As local workers do (make setup compiles it): the pure-Python sources fly at about half the speed."""
    from harness.execution.docker_executor import IMAGE

    modules = "autopilot.app", "autopilot.control", "simlink.codec", "sim_bridge.bridge", "sim_bridge.physics"
    program = f"import importlib; print(' '.join(importlib.import_module(m).__file__ for m in {modules!r}))"
    files = engine.containers.run(IMAGE, ["python", "-c", program], remove=True, network_mode="none").decode().split()
    assert len(files) == len(modules) and all(f.endswith(".so") for f in files), files


def test_a_killed_container_is_retried(engine, executor, tmp_path, profile):
    docker = executor(attempts=2)
    results = []
    runner = threading.Thread(target=lambda: results.extend(docker.run([fig4_job(tmp_path, profile)])))
    runner.start()
    deadline = time.monotonic() + 60.0
    while not docker.running and time.monotonic() < deadline:
        time.sleep(0.02)
    time.sleep(0.5)
    engine.containers.get(next(iter(docker.running.values()))).kill()
    runner.join(timeout=180.0)
    [(_job, result)] = results
    assert result.attempts[0]["status"] == "sim_crashed" and "exited with 137 (killed)" in result.attempts[0]["why"]
    assert result.status == "ok" and result.fitness == FIG4_SEED1_FITNESS


def test_a_container_that_overruns_is_ended_as_a_timeout(executor, tmp_path, profile):
    docker = executor(attempts=1, timeout_s=8.0)
    silent = SILENT_SUT.replace(sys.executable, "python")  # the image's python
    [(_job, result)] = list(docker.run([fig4_job(tmp_path, profile, sut=SutConfig("command", command=silent))]))
    assert result.status == "timeout" and "the executor's limit per try" in result.why


def test_the_same_seeded_campaign_flies_the_same_candidates_in_containers(engine, tmp_path, sequential_candidates):
    assert run_seeded_campaign(tmp_path / "docker.db", "docker", "--workers", "2") == sequential_candidates
    assert stella_containers(engine) == []


def test_the_compose_file_runs_a_campaign_on_a_dask_cluster_of_worker_containers(engine, tmp_path, sequential_candidates):
    import shutil
    import subprocess

    if shutil.which("docker-compose") is None:
        pytest.skip("docker-compose is not installed (make docker installs it)")
    compose = ["docker-compose", "-f", str(ROOT / "docker" / "compose.yaml"), "-p", f"stella-test-{os.getpid()}"]
    env = {**os.environ, "STELLA_RUNS": str(tmp_path)}
    try:
        subprocess.run([*compose, "up", "-d", "--scale", "worker=2", "scheduler", "worker"], env=env, check=True, capture_output=True, timeout=120)
        subprocess.run([*compose, "run", "--rm", "campaign", "stella", "campaign", "/src/scenarios/table3/scenario_02.json", *SEEDED_CAMPAIGN,
                        "--executor", "dask", "--dask-scheduler", "tcp://scheduler:8786", "--store", "/runs/compose.db", "--json"],
                       env=env, check=True, capture_output=True, timeout=600)
    finally:
        subprocess.run([*compose, "down"], env=env, capture_output=True, timeout=120)
    assert campaign_candidates(tmp_path / "compose.db") == sequential_candidates
