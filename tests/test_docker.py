"""The Docker executor on a real engine: one container per try, limits, logs brought back,
containers removed, a killed container retried, and the same campaign as everywhere else.
`make test` installs and starts the engine and builds the worker image first."""

from __future__ import annotations

import os
import sys
import threading
import time
from pathlib import Path

import pytest

from conftest import FIG4_SEED1_FITNESS, ROOT, SEEDED_CAMPAIGN, campaign_candidates, fig4_job, run_seeded_campaign
from harness.campaigns.store import Store
from harness.errors import InfrastructureError
from harness.execution.executor import run_job
from harness.flight import logs
from harness.tools.cli import main
from sut_adapter import SutConfig
from test_executors import SILENT_SUT
from test_sut_adapters import fake_px4_build
from test_transport import SIMULATED

pytestmark = pytest.mark.slow

# How far apart pilot flights of one concrete scenario stop before the wall on this machine
# (docs/suts.md): PX4 2.50-2.76 m over 8 repeats, its threads' timing differing from run to run;
# ArduPilot 0.69-0.71 m over 6.
SPREAD_M = {"px4": 0.3, "ardupilot": 0.1}


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


def test_a_sut_that_cannot_start_in_the_image_is_refused_before_anything_flies(engine, tmp_path, capsys):
    # GIVEN a PX4 build whose px4 needs an interpreter the worker image does not have
    build = fake_px4_build(tmp_path, "")
    (build / "bin" / "px4").write_text("#!/usr/bin/env stella-no-such-interpreter\n")
    store = tmp_path / "c.db"
    # WHEN a campaign would fly it in containers, THEN it is refused once, as infrastructure, and nothing flies
    assert main(["campaign", str(ROOT / "scenarios" / "examples" / "wall.json"), "--algorithm", "RANDOM", "--evaluations", "2",
                 "--sut", "px4", "--px4-bin", str(build), "--executor", "docker", "--store", str(store)]) == 3
    said = capsys.readouterr().err
    assert "the px4 SUT cannot start in the worker image" in said and "bin/px4 cannot start" in said and "stella-no-such-interpreter" in said
    with Store.existing(store) as opened:
        assert opened.all_evaluations() == []
    assert stella_containers(engine) == []


def test_a_command_sut_whose_program_is_not_in_the_image_is_refused(engine, tmp_path, capsys):
    assert main(["campaign", str(ROOT / "scenarios" / "examples" / "wall.json"), "--algorithm", "RANDOM", "--evaluations", "2",
                 "--sut", "command", "--sut-command", f"{tmp_path}/my-autopilot --sim tcp:127.0.0.1:{{sim_port}} --api udp:127.0.0.1:{{api_port}}",
                 "--executor", "docker", "--store", str(tmp_path / "c.db")]) == 3
    assert f"the command {tmp_path}/my-autopilot is not found" in capsys.readouterr().err


@pytest.mark.parametrize("sut, build", [
    pytest.param("px4", "STELLA_PX4_BIN", marks=pytest.mark.skipif(not os.environ.get("STELLA_PX4_BIN"), reason="STELLA_PX4_BIN is not set: no PX4 SITL build")),
    pytest.param("ardupilot", "STELLA_ARDUPILOT_BIN",
                 marks=pytest.mark.skipif(not os.environ.get("STELLA_ARDUPILOT_BIN"), reason="STELLA_ARDUPILOT_BIN is not set: no ArduCopter SITL build")),
])
def test_real_firmware_flies_in_containers_as_on_this_machine(engine, tmp_path, sut, build):
    # GIVEN a pilot-drive campaign on the wall (PX4 in Position mode, ArduPilot in Loiter), flown
    # on this machine and in containers, the build named by the environment
    argv = ["campaign", str(ROOT / "scenarios" / "examples" / "wall.json"), "--algorithm", "RANDOM", "--evaluations", "4", "--seed", "1",
            "--sut", sut, "--drive", "pilot", "--workers", "2", "--json"]
    flown = {}
    for executor in ("local", "docker"):
        assert main([*argv, "--executor", executor, "--store", str(tmp_path / f"{executor}.db")]) == 0
        with Store.existing(tmp_path / f"{executor}.db") as opened:
            flown[executor] = opened.all_evaluations()
    # THEN they fly the same candidates, every one in containers flown to its end (not a SUT that
    # could not start), and where both flew to the same outcome their clearances lie within the
    # firmware's own spread from one flight to the next (SPREAD_M; PX4 itself ended a flight of
    # the same scenario now ok, now blocked, on a loaded machine)
    assert [e.vector_key for e in flown["docker"]] == [e.vector_key for e in flown["local"]]
    assert not {e.status for e in flown["docker"]} & {"sut_crashed", "sim_crashed", "timeout"}
    assert any(e.status != "infeasible" for e in flown["docker"]) and all(Path(e.log_path).is_file() for e in flown["docker"] if e.status != "infeasible")
    same = [(local, docker) for local, docker in zip(flown["local"], flown["docker"]) if local.status == docker.status and local.min_clearance_m is not None]
    assert same
    for local, docker in same:
        assert docker.min_clearance_m == pytest.approx(local.min_clearance_m, abs=SPREAD_M[sut])
