"""The algorithm comparison of the paper's Table V, from a campaign store.

Per logical scenario and algorithm: the best (lowest) fitness of each run; their median; the
violations found (summed over runs) and the contacts among them (clearance 0 or less); performance relative to the baseline,
100 * (median_baseline - median) / |median_baseline| (positive = better, fitness is minimized);
the two-sided Mann-Whitney U p-value of the runs' best fitness against the baseline's (scipy);
and the Vargha-Delaney A12, the probability that a run of the algorithm finds a lower best
fitness than a run of the baseline, ties counting half (> 0.5 = better). "overall" averages the
relative performance over scenarios and pools the runs for the test and the A12.
"""

from __future__ import annotations

import statistics
from collections import defaultdict
from typing import Any, Sequence

from scipy.stats import mannwhitneyu

from harness.campaigns.store import Store
from harness.flight.fitness import Status
from harness.flight.results import EvaluationResult


def a12(candidate: Sequence[float], baseline: Sequence[float]) -> float:
    """Vargha-Delaney A12 for minimization: P(candidate < baseline) + 0.5 P(equal)."""
    wins = sum((c < b) + 0.5 * (c == b) for c in candidate for b in baseline)
    return wins / (len(candidate) * len(baseline))


def relative_performance(median: float, baseline_median: float) -> float | None:
    if baseline_median == 0:
        return None
    return 100.0 * (baseline_median - median) / abs(baseline_median)


def p_value(candidate: Sequence[float], baseline: Sequence[float]) -> float | None:
    if len(candidate) < 2 or len(baseline) < 2 or (len(set(candidate)) == 1 and set(candidate) == set(baseline)):
        return None
    return float(mannwhitneyu(candidate, baseline, alternative="two-sided").pvalue)


def compare(store: Store, baseline: str = "NSGAII") -> dict[str, Any]:
    best: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    violations: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    contacts: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    flaky: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    revealing: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    refused: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    flown: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    screened: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    for run in store.runs():
        if run.best_fitness is None:
            continue
        best[run.scenario][run.algorithm].append(run.best_fitness)
        violations[run.scenario][run.algorithm] += run.violations
        contacts[run.scenario][run.algorithm] += run.contacts
        flaky[run.scenario][run.algorithm] += run.flaky
        revealing[run.scenario][run.algorithm] += run.revealing
        refused[run.scenario][run.algorithm] += run.failures_refused
        flown[run.scenario][run.algorithm] += run.flown
        screened[run.scenario][run.algorithm] += run.screen_flights
    baseline = baseline.upper()
    rows = []
    pooled: dict[str, list[float]] = defaultdict(list)
    relative: dict[str, list[float]] = defaultdict(list)
    for scenario, by_algorithm in best.items():
        base = by_algorithm.get(baseline)
        for algorithm, values in sorted(by_algorithm.items()):
            median = statistics.median(values)
            row = {"scenario": scenario, "algorithm": algorithm, "runs": len(values), "median_best_fitness": median,
                   "violations": violations[scenario][algorithm], "contacts": contacts[scenario][algorithm], "flaky": flaky[scenario][algorithm], "revealing": revealing[scenario][algorithm],
                   "failures_refused": refused[scenario][algorithm], "flown": flown[scenario][algorithm], "screen_flights": screened[scenario][algorithm],
                   "relative_performance_pct": None, "p_value": None, "a12": None}
            pooled[algorithm].extend(values)
            if base and algorithm != baseline:
                row["relative_performance_pct"] = relative_performance(median, statistics.median(base))
                row["p_value"] = p_value(values, base)
                row["a12"] = a12(values, base)
                if row["relative_performance_pct"] is not None:
                    relative[algorithm].append(row["relative_performance_pct"])
            rows.append(row)
    overall = []
    for algorithm, values in sorted(pooled.items()):
        base = pooled.get(baseline)
        entry = {"algorithm": algorithm, "runs": len(values), "median_best_fitness": statistics.median(values),
                 "violations": sum(violations[s][algorithm] for s in violations), "contacts": sum(contacts[s][algorithm] for s in contacts),
                 "flaky": sum(flaky[s][algorithm] for s in flaky),
                 "revealing": sum(revealing[s][algorithm] for s in revealing), "failures_refused": sum(refused[s][algorithm] for s in refused),
                 "flown": sum(flown[s][algorithm] for s in flown), "screen_flights": sum(screened[s][algorithm] for s in screened),
                 "relative_performance_pct": None, "p_value": None, "a12": None}
        if base and algorithm != baseline:
            entry["relative_performance_pct"] = statistics.mean(relative[algorithm]) if relative[algorithm] else None
            entry["p_value"] = p_value(values, base)
            entry["a12"] = a12(values, base)
        overall.append(entry)
    return {"baseline": baseline, "scenarios": rows, "overall": overall, "differential": store.is_differential()}


def table(report: dict[str, Any]) -> str:
    def number(value, fmt):
        return "-" if value is None else format(value, fmt)

    # A differential campaign's candidates that reveal a difference from the reference come first.
    revealing = report.get("differential", False)
    lines = [f"baseline: {report['baseline']}", f"{'scenario':<28} {'algorithm':<10} {'runs':>4} " + (f"{'revealing':>9} " if revealing else "")
             + f"{'median best f':>14} {'violations':>10} {'contacts':>8} {'rel. %':>8} {'p':>6} {'A12':>5}"]
    for row in report["scenarios"] + [dict(r, scenario="overall") for r in report["overall"]]:
        lines.append(
            f"{row['scenario'][:28]:<28} {row['algorithm']:<10} {row['runs']:>4} " + (f"{row['revealing']:>9} " if revealing else "")
            + f"{row['median_best_fitness']:>14.3f} {row['violations']:>10} {row['contacts']:>8} "
            f"{number(row['relative_performance_pct'], '+.0f'):>8} {number(row['p_value'], '.2f'):>6} {number(row['a12'], '.2f'):>5}"
        )
    if any(row["flaky"] for row in report["overall"]):
        lines.append("flaky: " + ", ".join(f"{row['algorithm']} {row['flaky']} of its {row['violations']} violations did not come back in "
                                            "every --confirm re-flight" for row in report["overall"] if row["flaky"]))
    if any(row["failures_refused"] for row in report["overall"]):
        lines.append(refused_text(report))
    if any(row["screen_flights"] for row in report["overall"]):
        lines.append("screened: " + ", ".join(f"{row['algorithm']} {row['flown']} flights of the SUT, {row['screen_flights']} of the cheap model"
                                              for row in report["overall"] if row["screen_flights"]))
    return "\n".join(lines)


def refused_text(report: dict[str, Any]) -> str:
    return ("the SUT refused a failure injection: " + ", ".join(f"{row['algorithm']} in {row['failures_refused']} flights" for row in report["overall"]
                                                                  if row["failures_refused"])
            + "; they flew without the failure their scenario asks for")


def spread(results: Sequence[EvaluationResult]) -> dict[str, Any]:
    """How repeated flights of one concrete scenario differ: the range and median of fitness and
    clearance, and how many violated. A violation in some repeats but not all is flaky: a real
    SUT's timing differs run to run, and a violation by millimetres may not come back."""
    flown = [r for r in results if r.min_clearance_m is not None]

    def summary(values: list[float]) -> dict[str, float] | None:
        return {"min": min(values), "median": statistics.median(values), "max": max(values)} if values else None

    violations = sum(r.status == Status.VIOLATION for r in results)
    return {
        "repeats": len(results),
        "statuses": {str(status): sum(r.status == status for r in results) for status in sorted({r.status for r in results})},
        "violations": violations,
        "flaky": 0 < violations < len(flown),  # of the repeats that flew: a crash says nothing of the violation
        "fitness": summary([r.fitness for r in flown]),
        "min_clearance_m": summary([r.min_clearance_m for r in flown]),
    }
