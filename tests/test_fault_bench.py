"""The seeded-fault benchmark: detection is fault-revealing, not merely unsafe; the report's
statistics; a small benchmark end to end, resumed without flying again."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import ROOT, stored_result
from harness.campaigns.store import Store
from harness.faults.bench import FAULT_FREE_CACHE, _key, detections, report, report_text
from harness.flight import logs
from harness.scenario.logical import load_logical
from harness.scenario.space import SearchSpace
from harness.tools.cli import main

WALL = ROOT / "scenarios" / "examples" / "wall.json"


def bench_folder(tmp_path, profile, runs: dict[str, list[list[tuple[str, str | None]]]], sut_params=None):
    """A benchmark folder as `faults bench` leaves it. runs: per fault store, per (algorithm) run,
    per evaluation (status, fault-free status of a violation or None when not yet re-flown)."""
    space = SearchSpace(load_logical(WALL, profile), profile)
    xs = iter(space.sample(np.random.default_rng(0), 100))
    cache = {}
    for fault, algorithm_runs in runs.items():
        store = Store(tmp_path / f"{fault}.db")
        campaign = store.campaign({"scenarios": [str(WALL)], "algorithms": ["RANDOM", "NSGAII"], "sut_fault": fault, "sut_params": sut_params or {}})
        for index, (algorithm, evaluations) in enumerate(algorithm_runs):
            run_id, _ = store.run(campaign, str(WALL), space.logical.name, algorithm, index, index)
            for ordinal, (status, fault_free) in enumerate(evaluations):
                x = next(xs)
                concrete = space.to_concrete(x)
                store.add_evaluation(run_id, ordinal=ordinal, step=0, optimizer=algorithm, vector=x,
                                     result=stored_result(-0.5 if status == "violation" else 2.0, status, 3), concrete=concrete)
                if fault_free:
                    cache[_key(json.dumps(concrete), 3, sut_params or {})] = {"status": fault_free, "fitness": 0.0, "min_clearance_m": 1.0}
            store.finish_run(run_id)
        store.close()
    (tmp_path / FAULT_FREE_CACHE).write_text(json.dumps(cache))
    return tmp_path


def test_only_a_violation_that_the_fault_free_autopilot_avoids_detects_the_fault(tmp_path, profile):
    folder = bench_folder(tmp_path, profile, {
        "cp_narrow_view": [("RANDOM", [("ok", None), ("violation", "violation"), ("violation", "ok"), ("violation", "ok")]),
                           ("NSGAII", [("violation", "violation"), ("ok", None)])],
    })
    rows = {r["algorithm"]: r for r in detections(folder)}
    # the first violation is unsafe either way: not fault-revealing; the second reveals the fault
    assert (rows["RANDOM"]["detected"], rows["RANDOM"]["evaluations_to_detection"]) == (True, 3)
    assert (rows["NSGAII"]["detected"], rows["NSGAII"]["evaluations_to_detection"]) == (False, None)


def test_a_fault_free_flight_counts_only_for_the_autopilot_parameters_the_campaign_flew(tmp_path, profile):
    runs = {"cp_ignores_delay": [("RANDOM", [("violation", "ok")])]}
    folder = bench_folder(tmp_path, profile, runs, sut_params={"CP_DIST": 1.5})
    assert [r["detected"] for r in detections(folder)] == [True]
    # the same fault-free verdicts, but the campaign flew other parameters: not yet re-flown
    with Store.existing(folder / "cp_ignores_delay.db") as store, store.db:
        store.db.execute("UPDATE campaigns SET config = json_set(config, '$.sut_params.CP_DIST', 2.5)")
    assert [(r["detected"], r["unflown_violations"]) for r in detections(folder)] == [(False, 1)]


def test_the_report_compares_detection_with_the_baseline_and_names_faults_nobody_found(tmp_path, profile):
    found = [("violation", "ok")]
    missed = [("ok", None)] * 2
    folder = bench_folder(tmp_path, profile, {
        "cp_narrow_view": [("NSGAII", found), ("NSGAII", found), ("NSGAII", found), ("RANDOM", missed), ("RANDOM", missed), ("RANDOM", found)],
        "yaw_fixed_heading": [("NSGAII", missed), ("RANDOM", missed)],
        "none": [("NSGAII", [("violation", "violation")])],
    })
    result = report(folder, "random")
    nsga, random = result["algorithms"]["NSGAII"], result["algorithms"]["RANDOM"]
    assert (nsga["detected"], nsga["runs"], random["detected"], random["runs"]) == (3, 4, 1, 4)
    assert nsga["median_evaluations_to_detection"] == 1 and random["censored"] == 3
    assert nsga["fisher_p"] == pytest.approx(0.4857, abs=1e-4)  # [[3, 1], [1, 3]], two-sided
    # evaluations to detection, a miss censored at budget + 1: NSGAII [1, 1, 1, 3] against RANDOM [3, 3, 1, 3]
    assert nsga["a12"] == pytest.approx((3 * (3 + 0.5) + 3 * 0.5) / 16)  # each 1 beats three 3s and ties the 1; the 3 ties three
    assert result["found_by_none"] == ["yaw_fixed_heading"]
    assert result["control"] == {"runs": 1, "detected": 0}


def test_a_run_still_under_way_is_left_out_of_the_report_and_counted(tmp_path, profile):
    found = [("violation", "ok")]
    folder = bench_folder(tmp_path, profile, {"cp_narrow_view": [("RANDOM", found), ("RANDOM", [("ok", None)])]})
    with Store.existing(folder / "cp_narrow_view.db") as store, store.db:
        store.db.execute("UPDATE runs SET finished = NULL WHERE run_index = 1")
    result = report(folder)
    assert result["algorithms"]["RANDOM"]["runs"] == 1 and result["algorithms"]["RANDOM"]["detected"] == 1
    assert result["unfinished_runs"] == 1
    assert "1 runs unfinished and not counted" in report_text(result)


def test_the_per_fault_table_divides_by_each_algorithms_own_finished_runs(tmp_path, profile):
    found, missed = [("violation", "ok")], [("ok", None)]
    folder = bench_folder(tmp_path, profile, {"cp_narrow_view": [("RANDOM", found), ("RANDOM", missed), ("NSGAII", found)],
                                              "cp_ignores_delay": [("NSGAII", missed)]})
    with Store.existing(folder / "cp_narrow_view.db") as store, store.db:
        store.db.execute("UPDATE runs SET finished = NULL WHERE algorithm = 'NSGAII'")
    result = report(folder)
    assert result["per_fault"]["cp_narrow_view"]["runs"] == {"NSGAII": 0, "RANDOM": 2}
    row = next(line for line in report_text(result).splitlines() if line.startswith("cp_narrow_view"))
    assert row.split()[1:] == ["-", "1/2"]  # NSGAII's run on it is still under way


def test_a_report_of_a_folder_that_is_no_benchmark_is_refused(tmp_path, capsys):
    assert main(["faults", "report", "--store", str(tmp_path)]) == 2
    assert "no fault benchmark here" in capsys.readouterr().err


@pytest.mark.slow
def test_a_small_benchmark_runs_end_to_end_and_resumes_without_flying_again(tmp_path, capsys):
    command = ["faults", "bench", "--fault", "cp_off_above_cruise", "--fault", "none", "--algorithm", "NSGAII", "--population", "10", "--scenario", str(WALL),
               "--runs", "1", "--evaluations", "6", "--store", str(tmp_path / "bench"), "--sut-param", "CP_DIST=1.5", "--json"]
    assert main(command) == 0
    first = json.loads(capsys.readouterr().out)
    assert first["control"] == {"runs": 1, "detected": 0} and first["unflown_violations"] == 0
    # the parameters reach the faulty flights and their fault-free repeats alike
    faulty = list((tmp_path / "bench" / "logs" / "cp_off_above_cruise").rglob("*.mcap"))
    fault_free = list((tmp_path / "bench" / "logs" / "fault_free").rglob("*.mcap"))
    assert faulty and fault_free
    assert logs.json_metadata(faulty[0], "sut") == {"name": "bundled", "params": {"CP_DIST": 1.5}, "fault": "cp_off_above_cruise"}
    assert logs.json_metadata(fault_free[0], "sut") == {"name": "bundled", "params": {"CP_DIST": 1.5}}
    flights = sorted(p.name for p in (tmp_path / "bench" / "logs").rglob("*.mcap"))
    assert main(command) == 0
    assert json.loads(capsys.readouterr().out) == first
    assert sorted(p.name for p in (tmp_path / "bench" / "logs").rglob("*.mcap")) == flights

    # The faulty campaign's violations, triaged: every one in a mode, one regression case per mode.
    store = tmp_path / "bench" / "cp_off_above_cruise.db"
    assert main(["triage", str(store), "--json"]) == 0
    triaged = json.loads(capsys.readouterr().out)
    assert triaged["violations"] > 0 and sum(m["count"] for m in triaged["modes"]) == triaged["violations"] and not triaged["skipped"]
    assert all(m["worst"]["fitness"] <= m["typical"]["fitness"] < 0 for m in triaged["modes"])
    assert main(["export-regressions", str(store), "--per-mode", "--out", str(tmp_path / "cases"), "--json"]) == 0
    assert len(json.loads(capsys.readouterr().out)["files"]) == len(triaged["modes"])
