"""The seeded-fault benchmark: does a search find real faults within its budget?

Each (fault, algorithm, scenario, run) is a campaign run against the faulty bundled autopilot,
kept in `DB/FAULT.db` (so it resumes like any campaign). Every violation it found is flown again
against the fault-free autopilot with the same seed (cached in `DB/fault_free.json`, one flight
per concrete scenario and seed). The fault is *detected* in a run when some violation it found
keeps the safety distance without the fault; the evaluations to detection are the ordinal of the
first such one, plus one. `--fault none` is the control: the same SUT both ways, so it can detect
nothing.
"""

from __future__ import annotations

import hashlib
import json
import math
import statistics as stats
from pathlib import Path
from typing import Any, Iterable, Mapping

from scipy.stats import fisher_exact

from harness.campaigns.campaign import CampaignConfig, run_campaign
from harness.campaigns.statistics import a12, p_value
from harness.campaigns.store import Store, StoredEvaluation
from harness.errors import InputError, Problem
from harness.execution.executor import Executor, Job
from harness.faults.checks import checked_names, options_for
from harness.flight.results import RunOptions
from harness.flight.fitness import Status
from harness.paths import write_atomically
from harness.scenario.world import space_from_concrete
from sut_adapter import SutConfig

CONTROL = "none"
FAULT_FREE_CACHE = "fault_free.json"


def _stores(folder: Path) -> dict[str, Path]:
    return {path.stem: path for path in sorted(folder.glob("*.db"))}


def _key(concrete: str, seed: int, sut_params: Mapping[str, float]) -> str:
    """One fault-free flight per concrete scenario, seed and parameter set (parameters only when set,
    so caches made before the bench took parameters keep their keys)."""
    params = f"{json.dumps(dict(sut_params), sort_keys=True)}:" if sut_params else ""
    return hashlib.sha256(f"{seed}:{params}{concrete}".encode()).hexdigest()


def _violation_key(violation: StoredEvaluation, sut_params: Mapping[str, float]) -> str:
    # The store wrote the concrete scenario with json.dumps, and json.dumps of what json.loads
    # read from it gives the same text back: the keys of caches made from the text itself.
    return _key(json.dumps(violation.concrete), violation.seed, sut_params)


def _load_cache(folder: Path) -> dict[str, dict[str, Any]]:
    path = folder / FAULT_FREE_CACHE
    return json.loads(path.read_text()) if path.is_file() else {}


def _save_cache(folder: Path, cache: dict[str, dict[str, Any]]) -> None:
    """Written whole to a temporary file and renamed, so a kill never leaves half a cache."""
    write_atomically(folder / FAULT_FREE_CACHE, json.dumps(cache, indent=1).encode())


def run_bench(faults: Iterable[str], algorithms: tuple[str, ...], scenarios: tuple[str, ...], runs: int, evaluations: int, folder: Path,
              executor: Executor, *, seed: int = 0, population: int = 50, sut_params: Mapping[str, float] | None = None, on_result=lambda r: None,
              on_run=lambda r: None) -> None:
    """sut_params (e.g. CP_DIST) apply to the faulty and the fault-free flights alike."""
    if folder.exists() and not folder.is_dir():
        raise InputError([Problem(str(folder), "", "is not a folder: give --store a folder for the benchmark's stores, such as runs/fault-bench")])
    folder.mkdir(parents=True, exist_ok=True)
    faults = list(faults)
    checked_names([f for f in faults if f != CONTROL])
    for fault in faults:
        config = CampaignConfig(scenarios, algorithms, evaluations, runs, seed, population,
                                sut=SutConfig(params=dict(sut_params or {}), fault=None if fault == CONTROL else fault))
        with Store.for_campaign(folder / f"{fault}.db") as store:
            run_campaign(config, store, executor, folder / "logs" / fault, on_result=on_result, on_run=on_run, options=RunOptions(warm=True))
        _fly_fault_free(folder / f"{fault}.db", folder, executor)


def _fly_fault_free(store_path: Path, folder: Path, executor: Executor) -> None:
    """Each violation not yet flown without the fault, flown now; the cache saved after each."""
    cache = _load_cache(folder)
    with Store.existing(store_path) as store:
        sut_params = store.campaign_sut()["params"]
        violations = store.evaluations_with(Status.VIOLATION)
    jobs, keys = [], {}
    for violation in violations:
        key = _violation_key(violation, sut_params)
        if key in cache or key in keys.values():
            continue
        keys[len(jobs)] = key
        space = space_from_concrete(violation.concrete, str(store_path))
        jobs.append(Job.of(len(jobs), space, space.from_concrete(violation.concrete, str(store_path)), seed=violation.seed, out_dir=folder / "logs" / "fault_free",
                           name=f"fault-free-{key[:12]}", options=options_for(None, sut_params)))
    for job, result in executor.run(jobs):
        cache[keys[job.key]] = {"status": str(result.status), "fitness": result.fitness, "min_clearance_m": result.min_clearance_m}
        _save_cache(folder, cache)


def detections(folder: Path) -> list[dict[str, Any]]:
    """Per (fault, scenario, algorithm, run): detected, and the evaluations to the first detection."""
    if not folder.is_dir() or not _stores(folder):
        raise InputError([Problem(str(folder), "", "no fault benchmark here: give the folder `stella faults bench --store` wrote")])
    cache = _load_cache(folder)
    rows = []
    for fault, store_path in _stores(folder).items():
        found: dict[int, int | None] = {}
        unflown = 0
        with Store.existing(store_path) as store:
            sut_params = store.campaign_sut()["params"]
            violations = store.evaluations_with(Status.VIOLATION)
            runs = store.runs()
        for violation in violations:
            clean = cache.get(_violation_key(violation, sut_params))
            if clean is None:
                unflown += 1
            elif Status(clean["status"]) != Status.VIOLATION and violation.run_id not in found:
                found[violation.run_id] = violation.ordinal + 1
        for run in runs:
            rows.append({"fault": fault, "scenario": run.scenario, "algorithm": run.algorithm, "run": run.run_index,
                         "evaluations": run.evaluations, "finished": run.finished is not None, "violations": run.violations,
                         "detected": run.id in found, "evaluations_to_detection": found.get(run.id), "unflown_violations": unflown})
    return rows


def report(folder: Path, baseline: str = "RANDOM") -> dict[str, Any]:
    every = detections(folder)
    # A run still under way (or stopped) says nothing yet of its detection: left out, and counted.
    finished = [r for r in every if r["finished"]]
    rows = [r for r in finished if r["fault"] != CONTROL]
    control = [r for r in finished if r["fault"] == CONTROL]
    algorithms = sorted({r["algorithm"] for r in rows})
    baseline = baseline.upper()
    by_algorithm = {}
    for algorithm in algorithms:
        mine = [r for r in rows if r["algorithm"] == algorithm]
        # A run that never detected is censored at its budget: ranked after every detection.
        to_detection = [r["evaluations_to_detection"] if r["detected"] else r["evaluations"] + 1 for r in mine]
        detected = [r["evaluations_to_detection"] for r in mine if r["detected"]]
        entry = {"runs": len(mine), "detected": len(detected), "detection_rate": len(detected) / len(mine) if mine else math.nan,
                 "median_evaluations_to_detection": stats.median(detected) if detected else None, "censored": len(mine) - len(detected),
                 "_censored_ranks": to_detection}
        by_algorithm[algorithm] = entry
    base = by_algorithm.get(baseline)
    for algorithm, entry in by_algorithm.items():
        if base is None or algorithm == baseline:
            entry.update(fisher_p=None, mann_whitney_p=None, a12=None)
            continue
        table = [[entry["detected"], entry["runs"] - entry["detected"]], [base["detected"], base["runs"] - base["detected"]]]
        entry["fisher_p"] = float(fisher_exact(table)[1])
        entry["mann_whitney_p"] = p_value(entry["_censored_ranks"], base["_censored_ranks"])
        entry["a12"] = a12(entry["_censored_ranks"], base["_censored_ranks"])
    for entry in by_algorithm.values():
        entry.pop("_censored_ranks")
    per_fault = {}
    for fault in sorted({r["fault"] for r in rows}):
        per_fault[fault] = {algorithm: sum(r["detected"] for r in rows if r["fault"] == fault and r["algorithm"] == algorithm) for algorithm in algorithms}
        per_fault[fault]["runs"] = {a: sum(1 for r in rows if r["fault"] == fault and r["algorithm"] == a) for a in algorithms}
    return {"baseline": baseline, "algorithms": by_algorithm, "per_fault": per_fault,
            "found_by_none": [f for f, counts in per_fault.items() if not any(counts[a] for a in algorithms)],
            "control": {"runs": len(control), "detected": sum(r["detected"] for r in control)},
            "unflown_violations": sum({r["fault"]: r["unflown_violations"] for r in every}.values()),
            "unfinished_runs": sum(not r["finished"] for r in every)}


def report_text(result: dict[str, Any]) -> str:
    lines = [f"{'algorithm':<10} {'detected':>9} {'rate':>6} {'median evals':>13} {'censored':>9} {'Fisher p':>9} {'MWU p':>7} {'A12':>5}   (baseline {result['baseline']})"]
    fmt = lambda v, spec: "-" if v is None else format(v, spec)
    for algorithm, e in result["algorithms"].items():
        lines.append(f"{algorithm:<10} {e['detected']:>4}/{e['runs']:<4} {e['detection_rate']:>6.2f} {fmt(e['median_evaluations_to_detection'], '.1f'):>13} "
                     f"{e['censored']:>9} {fmt(e['fisher_p'], '.3f'):>9} {fmt(e['mann_whitney_p'], '.3f'):>7} {fmt(e['a12'], '.2f'):>5}")
    lines.append("")
    algorithms = list(result["algorithms"])
    lines.append(f"{'fault':<28} " + " ".join(f"{a:>8}" for a in algorithms) + "   (runs detecting it, of runs per algorithm)")
    for fault, counts in result["per_fault"].items():
        lines.append(f"{fault:<28} " + " ".join(f"{counts[a]:>5}/{counts['runs'][a]:<2}" if counts["runs"][a] else f"{'-':>8}" for a in algorithms))
    lines.append(f"found by no algorithm: {', '.join(result['found_by_none']) or 'none'}")
    lines.append(f"control (--fault none): {result['control']['detected']} detections in {result['control']['runs']} runs")
    if result["unfinished_runs"]:
        lines.append(f"{result['unfinished_runs']} runs unfinished and not counted: run the bench command again to finish them")
    if result["unflown_violations"]:
        lines.append(f"{result['unflown_violations']} violations not yet flown without their fault: run the bench command again to finish")
    return "\n".join(lines)
