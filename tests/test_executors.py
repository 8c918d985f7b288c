"""The executor contract, for real: retries of infrastructure failures with their causes, the
hard limit per try, a worker killed mid-evaluation, and the same campaign through every executor."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import sys
import threading
import time

import pytest

from conftest import FIG4, FIG4_SEED1_FITNESS, ROOT, fig4_job, port_bound, run_seeded_campaign, wait_until_flying
from harness.campaigns.campaign import CampaignConfig, run_campaign
from harness.campaigns.store import Store
from harness.execution.local import LocalExecutor, SequentialExecutor
from harness.execution.registry import make_executor
from harness.flight.results import RunOptions
from harness.flight.ports import PortLease
from harness.tools.cli import main
from sut_adapter import SutConfig

pytestmark = pytest.mark.slow
SILENT_SUT = f"{sys.executable} -c 'import time; time.sleep(600)' {{sim_port}} {{api_port}}"
# The bundled autopilot, frozen by SIGSTOP once connected to the simulator: alive but answering
# nothing (a fixed delay raced the flight, which now ends within a second).
HANGING_SUT = f"{sys.executable} {ROOT / 'tests' / 'hanging_sut.py'} {{sim_port}} {{api_port}}"


def no_leftovers() -> None:
    """Every port block free again (children of killed workers die with them)."""
    deadline = time.monotonic() + 10.0
    with PortLease() as block:
        slot = block.slot
    while time.monotonic() < deadline and any(port_bound(4560 + s) for s in range(slot + 1)):
        time.sleep(0.2)
    assert slot == 0 and not port_bound(4560)


@pytest.mark.alone  # no_leftovers: every port block of the machine free
def test_a_sut_that_never_connects_is_retried_and_each_cause_recorded(tmp_path, profile):
    executor = SequentialExecutor(attempts=2)
    [(_job, result)] = list(executor.run([fig4_job(tmp_path, profile, sut=SutConfig("command", command=SILENT_SUT), setup_timeout_s=3.0)]))
    assert result.status == "timeout"
    assert [a["status"] for a in result.attempts] == ["timeout", "timeout"]
    assert all("no autopilot heartbeat" in a["why"] for a in result.attempts)
    no_leftovers()


@pytest.mark.alone  # no_leftovers: every port block of the machine free
def test_a_sut_that_hangs_is_classified_and_retried(tmp_path, profile):
    executor = SequentialExecutor(attempts=2)
    options = {"sut": SutConfig("command", command=HANGING_SUT, hold="frozen"), "setup_timeout_s": 5.0}
    [(_job, result)] = list(executor.run([fig4_job(tmp_path, profile, **options)]))
    assert len(result.attempts) == 2
    assert {a["status"] for a in result.attempts} <= {"timeout", "sut_crashed"}
    no_leftovers()


@pytest.mark.alone  # no_leftovers: every port block of the machine free
def test_the_hard_limit_per_try_ends_a_try_and_frees_everything(tmp_path, profile):
    executor = SequentialExecutor(attempts=1, timeout_s=2.0)
    started = time.monotonic()
    [(_job, result)] = list(executor.run([fig4_job(tmp_path, profile, sut=SutConfig("command", command=SILENT_SUT))]))
    assert time.monotonic() - started < 10.0
    assert result.status == "timeout" and "the executor's limit per try" in result.why
    no_leftovers()


@pytest.mark.alone  # no_leftovers: every port block of the machine free
def test_a_worker_killed_mid_evaluation_is_replaced_and_the_evaluation_flown_again(tmp_path, profile):
    executor = LocalExecutor(workers=1, attempts=2)
    try:
        results = []
        runner = threading.Thread(target=lambda: results.extend(executor.run([fig4_job(tmp_path, profile)])))
        runner.start()
        deadline = time.monotonic() + 30.0
        while not executor.worker_pids() and time.monotonic() < deadline:
            time.sleep(0.05)
        worker = executor.worker_pids()[0]
        wait_until_flying(worker)
        os.kill(worker, signal.SIGKILL)
        runner.join(timeout=120.0)
        [(_job, result)] = results
        assert result.status == "ok" and result.fitness == FIG4_SEED1_FITNESS
        assert result.attempts[0]["status"] == "sim_crashed" and "the worker died" in result.attempts[0]["why"]
        assert result.attempts[1]["status"] == "ok"
    finally:
        executor.close()
    no_leftovers()


def test_a_campaign_with_a_broken_sut_finishes_with_every_evaluation_accounted_for(tmp_path):
    # Seed 8: its three candidates are all feasible, so each is flown.
    config = CampaignConfig((str(FIG4),), ("RANDOM",), 3, seed=8, population=3, sut=SutConfig("command", command=SILENT_SUT), batch=2)
    executor = make_executor("local", 2, attempts=2)
    options = RunOptions(setup_timeout_s=3.0)
    try:
        with Store(tmp_path / "c.db") as store:
            run_campaign(config, store, executor, tmp_path / "logs", options=options)
            rows = store.db.execute("SELECT status, attempts FROM evaluations").fetchall()
    finally:
        executor.close()
    assert len(rows) == 3
    assert all(status == "timeout" and len(json.loads(attempts)) == 2 for status, attempts in rows)


def test_the_same_seeded_campaign_flies_the_same_candidates_sequentially_locally_and_on_dask(tmp_path, sequential_candidates):
    assert {row[0] for row in sequential_candidates} == {"NSGAII", "SMPSO", "BO", "PNP"} and len(sequential_candidates) == 16
    assert run_seeded_campaign(tmp_path / "local.db", "local", "--workers", "2") == sequential_candidates
    assert run_seeded_campaign(tmp_path / "dask.db", "dask", "--workers", "2") == sequential_candidates


def test_dask_retries_the_task_of_a_lost_worker(tmp_path, profile):
    executor = make_executor("dask", 2, attempts=1)
    try:
        results = []
        jobs = [fig4_job(tmp_path, profile, key=k) for k in range(2)]
        runner = threading.Thread(target=lambda: results.extend(executor.run(jobs)))
        runner.start()
        worker_pids = list(executor.client.run(os.getpid).values())
        for worker in worker_pids:
            wait_until_flying(worker)
        os.kill(worker_pids[0], signal.SIGKILL)
        runner.join(timeout=180.0)
        assert len(results) == 2
        assert all(result.status == "ok" and result.fitness == FIG4_SEED1_FITNESS for _job, result in results)
    finally:
        executor.close()


def test_the_executor_benchmark_reports_its_figures(capsys):
    assert main(["bench", "--executor", "local", "--workers", "2", "--evaluations", "2", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert (report["executor"], report["workers"], report["evaluations"], report["statuses"]) == ("local", 2, 2, ["ok"])
    # The figures agree with each other, whatever the machine's load: each evaluation lies within
    # the bench's wall time, and the overhead is the two workers' time outside the evaluations per
    # evaluation (of two evaluations the median is the mean).
    assert report["evaluations_per_hour"] == pytest.approx(3600.0 * 2 / report["wall_time_s"])
    assert 0.0 < report["median_evaluation_wall_s"] <= report["wall_time_s"]
    assert report["overhead_per_evaluation_s"] == pytest.approx(report["wall_time_s"] * 2 / 2 - report["median_evaluation_wall_s"])
    assert report["overhead_per_evaluation_s"] >= 0.0


@pytest.mark.alone  # no_leftovers: every port block of the machine free
def test_cancel_drops_what_has_not_started_and_reports_what_ran(tmp_path, profile):
    executor = LocalExecutor(workers=1)
    jobs = [fig4_job(tmp_path, profile, key=k) for k in range(6)]
    results = []
    try:
        for _job, result in executor.run(jobs):
            results.append(result)
            executor.cancel()
    finally:
        executor.close()
    # Python's pool queues up to two tries beyond the one its worker runs: they count as started.
    assert 1 <= len(results) <= 4
    assert all(result.status == "ok" and result.fitness == FIG4_SEED1_FITNESS for result in results)
    no_leftovers()


def test_a_dask_cluster_whose_workers_lack_the_sut_refuses_it_before_the_campaign(tmp_path):
    from harness.errors import InfrastructureError
    from harness.execution.dask_executor import build_missing
    from test_sut_adapters import fake_px4_build

    build = fake_px4_build(tmp_path, "exit 0\n")
    executor = make_executor("dask", 2)
    try:
        # GIVEN a build every worker finds at its path, byte for byte: THEN it may fly
        executor.check_sut(SutConfig("px4", px4_bin=str(build)))
        # GIVEN a command SUT whose program no worker has: THEN it is refused, naming the workers
        with pytest.raises(InfrastructureError, match=r"build is missing on 2 of the cluster's workers: .*the command /nowhere/ap is not found"):
            executor.check_sut(SutConfig("command", command="/nowhere/ap --sim tcp:127.0.0.1:{sim_port} --api udp:127.0.0.1:{api_port}"))
    finally:
        executor.close()
    # AND a worker whose build at that path is another build says so (its digest differs)
    program = build / "bin" / "px4"
    digest = hashlib.sha256(program.read_bytes()).hexdigest()
    program.write_text(program.read_text() + "# rebuilt\n")
    assert "is another build than the campaign's" in build_missing([(str(program), digest)], [], None)
    assert "is not there" in build_missing([(str(tmp_path / "gone" / "px4"), digest)], [], None)


def test_a_campaign_none_of_whose_flights_flew_ends_as_an_infrastructure_failure(tmp_path, capsys):
    # GIVEN a SUT whose program is not there: every try fails before anything is recorded
    assert main(["campaign", str(ROOT / "scenarios" / "examples" / "wall.json"), "--algorithm", "RANDOM", "--evaluations", "3", "--attempts", "1",
                 "--sut", "command", "--sut-command", f"{tmp_path}/ap --sim tcp:127.0.0.1:{{sim_port}} --api udp:127.0.0.1:{{api_port}}",
                 "--store", str(tmp_path / "c.db"), "--workers", "2"]) == 3
    # THEN it says that nothing was tested and why, rather than a best fitness
    said = capsys.readouterr().err.strip().splitlines()[-1]
    assert said.startswith("error: none of the 2 flights this campaign made now flew") and "tested nothing" in said and f"cannot start {tmp_path}/ap" in said
