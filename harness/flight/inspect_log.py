"""`stella inspect` and `stella diff`: read evaluation logs back.

summarize (and recompute the fitness from the log alone), plot, list topics, export CSV, and
compare two runs of one scenario.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

from harness.errors import InputError, Problem
from harness.flight import logs
from harness.flight.evaluation import rescore


def summarize(path: Path) -> dict[str, Any]:
    """What a log says of its flight, with the fitness recomputed from it alone; of a truncated
    log, from what precedes the damage (`partial`)."""
    scored = rescore(path)
    cut = scored["truncation"]
    clearance = scored["clearance"]
    recorded = scored["recorded"]
    summary = scored["summary"]
    return {
        "log": str(path),
        "scenario": scored["world"].scenario,
        "duration_s": summary.get("sim_time_s", cut.last_time_s if cut else None),
        "end_reason": summary.get("end_reason"),
        "status": scored["status"],
        "why": scored["why"],
        "fitness": scored["fitness"],
        "recorded_fitness": recorded.get("fitness"),
        "fitness_reproduced": None if cut else recorded.get("fitness") == scored["fitness"],
        "min_clearance_m": clearance.min_clearance_m,
        "min_clearance_at_s": clearance.at_s,
        "min_clearance_obstacle": clearance.obstacle,
        "safety_distance_m": scored["world"].safety_distance_m,
        "touchdown": summary.get("touchdown"),
        "partial": cut is not None,
        "truncation": None if cut is None else {"readable_bytes": cut.readable_bytes, "size_bytes": cut.size_bytes, "last_time_s": cut.last_time_s},
        "truncation_text": None if cut is None else cut.describe(),
    }


def plot(path: Path, out: Path) -> None:
    """Top view of the trajectory with the obstacles, and the clearance over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Polygon

    world = logs.world_of(path)
    if world is None:
        raise InputError([Problem(str(path), "", "no world metadata: not an evaluation log of this tool")])
    states = [m for _t, _ns, m in logs.messages(path, ["/uav/state"])]
    times, distances = [], []
    for _t, _ns, batch in logs.messages(path, ["/clearance"]):
        for t, d in zip(batch["t"], batch["d"]):
            if d is not None:
                times.append(t)
                distances.append(d)
    figure, (top, series) = plt.subplots(1, 2, figsize=(13, 5.5))
    top.plot([s["east_m"] for s in states], [s["north_m"] for s in states], color="tab:blue", label="UAV")
    for obstacle in world.obstacles:
        a, b = obstacle["a"], obstacle["b"]
        size = obstacle["size"]
        color = "tab:orange" if b else "tab:gray"
        if obstacle["form"] == "cuboid":
            c, s_ = math.cos(obstacle["yaw_rad"]), math.sin(obstacle["yaw_rad"])
            hl, hw = size["length_m"] / 2, size["width_m"] / 2
            corners = [(a["east_m"] + x * s_ + y * c, a["north_m"] + x * c - y * s_) for x, y in ((hl, hw), (hl, -hw), (-hl, -hw), (-hl, hw))]
            top.add_patch(Polygon(corners, closed=True, alpha=0.5, color=color))
        else:
            top.add_patch(Circle((a["east_m"], a["north_m"]), size["diameter_m"] / 2, alpha=0.5, color=color))
        if b:
            top.annotate("", xy=(b["east_m"], b["north_m"]), xytext=(a["east_m"], a["north_m"]), arrowprops={"arrowstyle": "->", "color": color})
        top.text(a["east_m"], a["north_m"], obstacle["id"], fontsize=8)
    for waypoint in world.mission.waypoints:
        top.plot(waypoint.east_m, waypoint.north_m, "k*")
    top.set_xlabel("east (m)")
    top.set_ylabel("north (m)")
    top.set_aspect("equal")
    top.set_title(world.scenario)
    series.plot(times, distances, color="tab:blue", label="clearance")
    series.axhline(world.safety_distance_m, color="tab:red", linestyle="--", label="safety distance")
    series.set_xlabel("simulation time (s)")
    series.set_ylabel("UAV to nearest obstacle (m)")
    series.legend()
    figure.tight_layout()
    figure.savefig(out, dpi=110)
    plt.close(figure)


def topics(path: Path) -> list[dict[str, Any]]:
    """Each channel: topic, schema, message count, first and last log time (simulation seconds)."""
    counts: dict[str, int] = {}
    first: dict[str, int] = {}
    last: dict[str, int] = {}
    for topic, time_ns, _message in logs.messages(path):
        counts[topic] = counts.get(topic, 0) + 1
        first.setdefault(topic, time_ns)
        last[topic] = time_ns
    return [
        {"topic": topic, "schema": schema, "encoding": encoding, "messages": counts.get(topic, 0),
         "first_s": first[topic] / 1e9 if topic in first else None, "last_s": last[topic] / 1e9 if topic in last else None}
        for _cid, topic, schema, encoding in sorted(logs.channels(path), key=lambda entry: entry[1])
    ]


def _flatten(value: Any, prefix: str, row: dict[str, Any]) -> None:
    if isinstance(value, dict):
        for key, item in value.items():
            _flatten(item, f"{prefix}.{key}" if prefix else key, row)
    elif isinstance(value, list):
        for index, item in enumerate(value):
            _flatten(item, f"{prefix}.{index}", row)
    else:
        row[prefix] = value


def _rows(message: dict[str, Any]) -> list[dict[str, Any]]:
    """A columnar batch (every field a list of one length, as /clearance) becomes one row per
    entry; any other message one row, nested fields named by their dotted path."""
    columns = list(message.values())
    if len(columns) > 1 and all(isinstance(c, list) for c in columns) and len({len(c) for c in columns}) == 1:
        return [dict(zip(message, entry)) for entry in zip(*columns)]
    row: dict[str, Any] = {}
    _flatten(message, "", row)
    return [row]


def export_csv(path: Path, out_dir: Path, selected: list[str] | None = None) -> list[Path]:
    """One CSV per topic (`/uav/state` -> `uav_state.csv`), first column the log time in seconds."""
    available = [row["topic"] for row in topics(path)]
    unknown = sorted(set(selected or []) - set(available))
    if unknown:
        raise InputError([Problem("--topic", "", f"{', '.join(unknown)} not in {path}; its topics: {', '.join(available)}")])
    wanted = selected or available
    tables: dict[str, list[dict[str, Any]]] = {topic: [] for topic in wanted}
    for topic, time_ns, message in logs.messages(path, wanted):
        for row in _rows(message):
            tables[topic].append({"log_time_s": time_ns / 1e9, **row})
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for topic, rows in tables.items():
        header: dict[str, None] = {}
        for row in rows:
            header.update(dict.fromkeys(row))
        target = out_dir / (topic.strip("/").replace("/", "_") + ".csv")
        with open(target, "w", newline="") as stream:
            writer = csv.DictWriter(stream, fieldnames=list(header))
            writer.writeheader()
            writer.writerows(rows)
        written.append(target)
    return written


def _trace(path: Path) -> dict[float, float | None]:
    trace: dict[float, float | None] = {}
    for _topic, _ns, batch in logs.messages(path, ["/clearance"]):
        trace.update(zip(batch["t"], batch["d"]))
    return trace


def _positions(path: Path) -> dict[float, tuple[float, float, float]]:
    return {s["t"]: (s["north_m"], s["east_m"], s["up_m"]) for _topic, _ns, s in logs.messages(path, ["/uav/state"])}


def diff(a: Path, b: Path, tolerance: float = 0.0) -> dict[str, Any]:
    """Compare two runs of one scenario: same inputs?, both results, and where the clearance
    traces and the trajectories first differ by more than `tolerance` metres."""
    first, second = summarize(a), summarize(b)
    inputs = {name: logs.json_metadata(a, name) == logs.json_metadata(b, name) for name in ("concrete_scenario", "world", "sut")}
    trace_a, trace_b = _trace(a), _trace(b)
    common = sorted(set(trace_a) & set(trace_b))
    clearance_divergence = None
    largest = 0.0
    for t in common:
        da, db = trace_a[t], trace_b[t]
        gap = math.inf if (da is None) != (db is None) else abs(da - db) if da is not None else 0.0
        largest = max(largest, gap)
        if gap > tolerance and clearance_divergence is None:
            clearance_divergence = {"t_s": t, "a_m": da, "b_m": db}
    positions_a, positions_b = _positions(a), _positions(b)
    path_divergence = None
    for t in sorted(set(positions_a) & set(positions_b)):
        gap = math.dist(positions_a[t], positions_b[t])
        if gap > tolerance:
            path_divergence = {"t_s": t, "distance_m": gap, "a": positions_a[t], "b": positions_b[t]}
            break
    lengths_differ = set(trace_a) != set(trace_b)
    identical = (clearance_divergence is None and path_divergence is None and not lengths_differ and first["fitness"] == second["fitness"]
                 and not first["partial"] and not second["partial"])
    return {
        "a": {key: first[key] for key in ("log", "status", "fitness", "min_clearance_m", "min_clearance_at_s", "min_clearance_obstacle", "duration_s")},
        "b": {key: second[key] for key in ("log", "status", "fitness", "min_clearance_m", "min_clearance_at_s", "min_clearance_obstacle", "duration_s")},
        "truncated": {side: report["truncation_text"] for side, report in (("a", first), ("b", second)) if report["partial"]},
        "same_inputs": inputs,
        "tolerance_m": tolerance,
        "common_steps": len(common),
        "steps_only_in_a": len(set(trace_a) - set(trace_b)),
        "steps_only_in_b": len(set(trace_b) - set(trace_a)),
        "max_clearance_difference_m": largest,
        "clearance_divergence": clearance_divergence,
        "path_divergence": path_divergence,
        "identical": identical,
    }
