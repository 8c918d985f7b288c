"""`stella report DB --out report.html`: one self-contained page (plots embedded as PNG data).

Best fitness vs evaluations per algorithm (median and range over runs, per scenario), each safety
property's violations and least robustness per run, the comparison table, the violations, and the worst concrete scenarios with their top-view plots
and MCAP paths.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
import tempfile
from collections import defaultdict
from pathlib import Path
from typing import Any

from harness.campaigns.statistics import compare, refused_text
from harness.campaigns.store import Store
from harness.flight.fitness import Status

PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<style>
body {{ font-family: sans-serif; margin: 2em; color: #222; }}
table {{ border-collapse: collapse; margin: 1em 0; }}
td, th {{ border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: right; }}
th {{ background: #f2f2f2; }} td.text {{ text-align: left; }}
img {{ max-width: 100%; border: 1px solid #eee; }}
p.warning {{ color: #a40; }}
code {{ font-size: 0.9em; }}
</style></head>
<body>
<h1>{title}</h1>
{body}
<script>
  // Marks how many plots decoded, for a reader (or a test) that cannot look at the pictures.
  window.addEventListener("load", function () {{
    var images = Array.prototype.slice.call(document.querySelectorAll("img.plot"));
    var shown = images.filter(function (img) {{ return img.complete && img.naturalWidth > 0; }}).length;
    document.body.setAttribute("data-plots-shown", String(shown));
    document.body.setAttribute("data-plots", String(images.length));
  }});
</script>
</body></html>
"""


def _png(figure) -> str:
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=90)
    return base64.b64encode(buffer.getvalue()).decode()


def _img(data: str, alt: str) -> str:
    return f'<img class="plot" alt="{html.escape(alt)}" src="data:image/png;base64,{data}">'


def _convergence(store: Store) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    curves: dict[str, dict[str, list[list[float]]]] = defaultdict(lambda: defaultdict(list))
    for run in store.runs():
        curve = [best for _ordinal, best in store.best_so_far(run.id)]
        if curve:
            curves[run.scenario][run.algorithm].append(curve)
    images = []
    for scenario, by_algorithm in sorted(curves.items()):
        figure, axes = plt.subplots(figsize=(8, 4))
        for algorithm, runs in sorted(by_algorithm.items()):
            length = min(len(c) for c in runs)
            values = np.array([c[:length] for c in runs])
            x = np.arange(1, length + 1)
            line, = axes.plot(x, np.median(values, axis=0), label=f"{algorithm} (median of {len(runs)})")
            axes.fill_between(x, values.min(axis=0), values.max(axis=0), alpha=0.2, color=line.get_color())
        axes.axhline(0.0, color="tab:red", linestyle="--", linewidth=1)
        axes.set_xlabel("evaluations")
        axes.set_ylabel("best fitness so far")
        axes.set_yscale("symlog")
        axes.set_title(scenario)
        axes.legend()
        figure.tight_layout()
        images.append(f"<h3>{html.escape(scenario)}</h3>" + _img(_png(figure), f"best fitness vs evaluations, {scenario}"))
        plt.close(figure)
    return images


def _comparison_table(report: dict[str, Any]) -> str:
    def cell(value, fmt):
        return "-" if value is None else format(value, fmt)

    rows = ["<tr><th>scenario</th><th>algorithm</th><th>runs</th><th>median best fitness</th><th>violations</th><th>contacts</th><th>relative %</th><th>p</th><th>A12</th></tr>"]
    for row in report["scenarios"] + [dict(r, scenario="overall") for r in report["overall"]]:
        rows.append(
            f"<tr><td class='text'>{html.escape(row['scenario'])}</td><td class='text'>{row['algorithm']}</td><td>{row['runs']}</td>"
            f"<td>{row['median_best_fitness']:.3f}</td><td>{row['violations']}</td><td>{row['contacts']}</td><td>{cell(row['relative_performance_pct'], '+.0f')}</td>"
            f"<td>{cell(row['p_value'], '.3f')}</td><td>{cell(row['a12'], '.2f')}</td></tr>"
        )
    refused = any(row["failures_refused"] for row in report["overall"])
    return (f"<p>Baseline: {report['baseline']}.</p><table>{''.join(rows)}</table>"
            + (f"<p class='warning'>{html.escape(refused_text(report))}.</p>" if refused else ""))


def _worst(store: Store, count: int) -> list[str]:
    from harness.flight.inspect_log import plot

    sections = []
    with tempfile.TemporaryDirectory() as folder:
        for index, worst in enumerate(store.lowest(count, logged=True)):
            picture = Path(folder) / f"{index}.png"
            try:
                plot(Path(worst.log_path), picture)
                image = _img(base64.b64encode(picture.read_bytes()).decode(), f"top view of {worst.log_path}")
            except OSError:
                image = "<p>(log no longer on disk)</p>"
            environment = worst.concrete["environment"] if worst.concrete else {}
            clearance = worst.min_clearance_m
            sections.append(
                f"<h3>{index + 1}. {html.escape(worst.scenario)}: fitness {worst.fitness:.3f} ({worst.status})</h3>"
                f"<p>evaluation {worst.id} ({worst.algorithm} run {worst.run_index}); min clearance {clearance if clearance is None else round(clearance, 3)} m; "
                f"log <code>{html.escape(worst.log_path)}</code></p><p><code>{html.escape(json.dumps(environment))}</code></p>{image}"
            )
    return sections


def _violations(store: Store) -> str:
    violations = sorted(store.evaluations_with(Status.VIOLATION), key=lambda e: (e.scenario, e.algorithm, e.run_index, e.ordinal))
    runs: dict[int, list] = {}
    for violation in violations:
        entry = runs.setdefault(violation.run_id, [violation.scenario, violation.algorithm, violation.run_index, 0, math.inf, 0])
        entry[3] += 1
        entry[4] = min(entry[4], violation.fitness)
        entry[5] += violation.flaky
    rows = ["<tr><th>scenario</th><th>algorithm</th><th>run</th><th>violations</th><th>flaky (--confirm)</th><th>lowest fitness</th></tr>"]
    for scenario, algorithm, run, count, lowest, flaky in runs.values():
        rows.append(f"<tr><td class='text'>{html.escape(scenario)}</td><td class='text'>{algorithm}</td><td>{run}</td><td>{count}</td><td>{flaky}</td><td>{lowest:.3f}</td></tr>")
    return f"<table>{''.join(rows)}</table>" if len(rows) > 1 else "<p>No violation found.</p>"


def _failure_modes(store: Store) -> str:
    """The violations grouped by what happened (harness/campaigns/triage.py)."""
    from harness.campaigns.triage import triage

    report = triage(store.path)
    if not report.modes:
        return "<p>No violation to triage.</p>"
    spread = report.mean_pairwise_trajectory_distance_m
    rows = ["<tr><th>violations</th><th>mode</th><th>contact</th><th>near miss</th><th>worst (evaluation, fitness, log)</th><th>typical (evaluation, fitness, log)</th></tr>"]
    for mode in report.modes:
        worst, typical = mode.worst, mode.typical
        rows.append(f"<tr><td>{mode.count}</td><td class='text'>{html.escape(mode.mode)}</td><td>{mode.contacts}</td><td>{mode.near_misses}</td>"
                    f"<td class='text'>{worst.id}, {worst.fitness:.3f} <code>{html.escape(worst.log)}</code></td>"
                    f"<td class='text'>{typical.id}, {typical.fitness:.3f} <code>{html.escape(typical.log)}</code></td></tr>")
    summary = (f"<p>{report.violations} distinct violations in {len(report.modes)} failure modes; mean pairwise trajectory distance "
               f"{'-' if spread is None else f'{spread:.1f} m'}.</p>")
    return summary + f"<table>{''.join(rows)}</table>"


def _properties(store: Store) -> list[str]:
    """Each safety property a run scored: its flights, the violations, the least robustness and
    the flight that came closest to (or furthest into) violating it."""
    rows = ["<tr><th>scenario</th><th>algorithm</th><th>run</th><th>property</th><th>flights scored</th><th>violated</th><th>least robustness</th><th>evaluation, log</th></tr>"]
    for run in store.runs():
        scored: dict[str, list] = {}
        for evaluation in store.evaluations(run.id).values():
            for name, verdict in evaluation.properties.items():
                scored.setdefault(name, []).append((evaluation, verdict))
        for name, flights in sorted(scored.items()):
            judged = [(e, v) for e, v in flights if v.get("robustness") is not None]
            closest = min(judged, key=lambda ev: ev[1]["robustness"], default=None)
            least = f"{closest[1]['robustness']:.3f} {html.escape(closest[1]['unit'])}" if closest else "-"
            where = f"{closest[0].id} <code>{html.escape(str(closest[0].log_path))}</code>" if closest else "-"
            rows.append(f"<tr><td class='text'>{html.escape(run.scenario)}</td><td class='text'>{run.algorithm}</td><td>{run.run_index}</td>"
                        f"<td class='text'>{html.escape(name)}</td><td>{len(flights)}</td><td>{sum(v['verdict'] == 'violated' for _e, v in flights)}</td>"
                        f"<td>{least}</td><td class='text'>{where}</td></tr>")
    if len(rows) == 1:
        return []
    return ["<h2>Safety properties</h2>", f"<table>{''.join(rows)}</table>"]


def _revealing(store: Store) -> list[str]:
    """A differential campaign's revealing candidates, unsafe ones first: both sides' outcomes."""
    if not store.is_differential():
        return []
    cases = store.revealing_cases()
    rows = ["<tr><th>reveals</th><th>scenario</th><th>algorithm</th><th>run</th><th>evaluation</th><th>subject</th><th>reference</th><th>why</th><th>log</th></tr>"]
    for case in cases:
        sides = [" / ".join(f"{f['status']} {f['min_clearance_m'] if f['min_clearance_m'] is None else round(f['min_clearance_m'], 3)} m"
                            for f in case.differential[side]) for side in ("subject", "reference")]
        rows.append(f"<tr><td class='text'>{case.reveals}</td><td class='text'>{html.escape(Path(case.scenario_file).stem)}</td>"
                    f"<td class='text'>{case.algorithm}</td><td>{case.run_index}</td><td>{case.id}</td>"
                    f"<td class='text'>{html.escape(sides[0])}</td><td class='text'>{html.escape(sides[1])}</td>"
                    f"<td class='text'>{html.escape(case.differential['why'])}</td><td class='text'><code>{html.escape(str(case.log_path))}</code></td></tr>")
    table = f"<table>{''.join(rows)}</table>" if cases else "<p>No candidate revealed a difference from the reference.</p>"
    return ["<h2>Revealing cases (subject against reference)</h2>", table]


def write_report(store: Store, out: Path, worst: int = 5, baseline: str = "NSGAII") -> None:
    report = compare(store, baseline)
    body = [*_revealing(store), *_properties(store), "<h2>Best fitness vs evaluations</h2>", *_convergence(store), "<h2>Comparison</h2>", _comparison_table(report),
            "<h2>Violations</h2>", _violations(store), "<h2>Failure modes</h2>", _failure_modes(store),
            f"<h2>The {worst} worst concrete scenarios</h2>", *_worst(store, worst)]
    out.write_text(PAGE.format(title=f"Campaign report: {html.escape(str(store.path))}", body="\n".join(body)), encoding="utf-8")
