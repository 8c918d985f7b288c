"""`stella inspect` and `stella diff`: read evaluation logs back.

summarize (and recompute the fitness from the log alone), plot, list topics, export CSV, and
compare two runs of one scenario.
"""

from __future__ import annotations

import bisect
import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np

from harness.errors import InputError, Problem
from harness.flight import logs
from harness.flight.evaluation import rescore
from sim_bridge.obstacles import Obstacle
from sim_bridge.recording import obstacle_kind_color

if TYPE_CHECKING:
    from matplotlib.figure import Figure


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
        "failures_refused": scored["failures_refused"],
        "partial": cut is not None,
        "truncation": None if cut is None else {"readable_bytes": cut.readable_bytes, "size_bytes": cut.size_bytes, "last_time_s": cut.last_time_s},
        "truncation_text": None if cut is None else cut.describe(),
    }


@dataclass(frozen=True)
class ClosestApproach:
    """Where a moving obstacle was when the UAV came closest to it (of the steps where it was the
    nearest obstacle): simulation and run time, the clearance, its centre north/east/up."""

    time_s: float
    run_time_s: float
    clearance_m: float
    position: tuple[float, float, float]


@dataclass(frozen=True)
class MovingPath:
    """A moving obstacle's track (N x 3 north/east/up, as `Obstacle.track`) as the plot draws it."""

    obstacle_id: str
    kind: str
    track: np.ndarray
    closest: ClosestApproach | None


def moving_paths(obstacles: Sequence[Obstacle], nearest: Mapping[str, tuple[float, float]], run_start_s: float | None,
                 changed_at_s: Mapping[str, float] | None = None) -> list[MovingPath]:
    """The track of every moving obstacle and, where `nearest` has its closest step (id -> simulation
    time, clearance), where it was then: at run time = time - run_start_s (0 before the run, as the
    simulator moves obstacles). No position for an obstacle changed by an injection (`changed_at_s`,
    id -> first change) before that time: the world spec no longer describes its motion then."""
    changed_at_s = changed_at_s or {}
    paths = []
    for obstacle in obstacles:
        track = obstacle.track
        if track is None:
            continue
        closest = None
        if obstacle.id in nearest:
            time_s, clearance_m = nearest[obstacle.id]
            if time_s < changed_at_s.get(obstacle.id, math.inf):
                run_time_s = 0.0 if run_start_s is None else max(0.0, time_s - run_start_s)
                n, e, u = obstacle.position_at(run_time_s).tolist()
                closest = ClosestApproach(time_s, run_time_s, clearance_m, (n, e, u))
        paths.append(MovingPath(obstacle.id, obstacle.kind, track, closest))
    return paths


def _run_events(path: Path) -> tuple[float | None, dict[str, float]]:
    """The simulation time of the "run" event (None if the log has none) and, per obstacle id, the
    first injection (add, move, remove) that changed it."""
    run_start_s = None
    changed_at_s: dict[str, float] = {}
    for _topic, _ns, event in logs.messages(path, ["/events"]):
        if event.get("event") == "run" and run_start_s is None:
            run_start_s = event["t"]
        elif event.get("event") == "injection" and "id" in (event.get("detail") or {}):
            changed_at_s.setdefault(event["detail"]["id"], event["t"])
    return run_start_s, changed_at_s


def _footprint(form: str, size: Mapping[str, float], yaw_rad: float, north_m: float, east_m: float, **style: Any):
    """An obstacle's outline in the plan view (x east, y north)."""
    from matplotlib.patches import Circle, Polygon

    if form == "cuboid":
        c, s_ = math.cos(yaw_rad), math.sin(yaw_rad)
        hl, hw = size["length_m"] / 2, size["width_m"] / 2
        corners = [(east_m + x * s_ + y * c, north_m + x * c - y * s_) for x, y in ((hl, hw), (hl, -hw), (-hl, -hw), (-hl, hw))]
        return Polygon(corners, closed=True, **style)
    return Circle((east_m, north_m), size["diameter_m"] / 2, **style)


def _plot_color(obstacle: Obstacle) -> tuple[float, float, float]:
    color = obstacle_kind_color(obstacle)
    return color["r"], color["g"], color["b"]


def plot(path: Path, out: Path) -> "Figure":
    """Top view of the trajectory with the obstacles at their start, the path of each moving one
    (intruders in their own colour) and where it was at the UAV's closest approach to it; and the
    clearance over time. Returns the figure it saved (closed: inspect it, don't show it)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    world = logs.world_of(path)
    if world is None:
        raise InputError([Problem(str(path), "", "no world metadata: not an evaluation log of this tool")])
    obstacles = [Obstacle.from_spec(spec) for spec in world.obstacles]
    states = [m for _t, _ns, m in logs.messages(path, ["/uav/state"])]
    times, distances = [], []
    nearest: dict[str, tuple[float, float]] = {}
    for _t, _ns, batch in logs.messages(path, ["/clearance"]):
        for t, d, o in zip(batch["t"], batch["d"], batch["o"]):
            if d is not None:
                times.append(t)
                distances.append(d)
                if o is not None and (o not in nearest or d < nearest[o][1]):
                    nearest[o] = (t, d)
    paths = {entry.obstacle_id: entry for entry in moving_paths(obstacles, nearest, *_run_events(path))}
    state_times = [s["t"] for s in states]

    figure, (top, series) = plt.subplots(1, 2, figsize=(13, 5.5))
    top.plot([s["east_m"] for s in states], [s["north_m"] for s in states], color="tab:blue", label="UAV")
    labelled: set[str] = set()

    def label(text: str) -> str:
        """A legend entry once per kind of artist."""
        if text in labelled:
            return "_nolegend_"
        labelled.add(text)
        return text

    for obstacle in obstacles:
        color = _plot_color(obstacle)
        north, east, _up = obstacle.a.tolist()
        top.add_patch(_footprint(obstacle.form, obstacle.size, obstacle.yaw_rad, north, east, alpha=0.5, color=color))
        top.text(east, north, obstacle.id, fontsize=8)
        moving = paths.get(obstacle.id)
        if moving is None:
            continue
        track = moving.track
        kind = "intruder" if obstacle.kind == "intruder" else "moving obstacle"
        top.plot(track[:, 1], track[:, 0], color=color, linewidth=1.2, marker=".", markevery=[0, len(track) - 1],
                 gid=f"{obstacle.id}/path", label=label(f"{kind} path"))
        (n0, e0, _), (n1, e1, _) = track[-2], track[-1]
        if math.hypot(n1 - n0, e1 - e0) > 0.0:  # which way it goes (a vertical mover's plan view is a point)
            top.annotate("", xy=(e1, n1), xytext=(e0, n0), arrowprops={"arrowstyle": "->", "color": color})
        closest = moving.closest
        if closest is not None:
            n, e, _u = closest.position
            top.add_patch(_footprint(obstacle.form, obstacle.size, obstacle.yaw_rad, n, e, fill=False, linestyle="--", color=color))
            top.plot(e, n, "x", color=color, gid=f"{obstacle.id}/closest", label=label("at closest approach"))
            if states:
                uav = states[min(bisect.bisect_left(state_times, closest.time_s), len(states) - 1)]
                top.plot([uav["east_m"], e], [uav["north_m"], n], ":", color=color, linewidth=0.8)
            top.annotate(f"t={closest.time_s:.1f} s, {closest.clearance_m:.1f} m", (e, n), fontsize=7, color=color,
                         xytext=(4, -10), textcoords="offset points")
    for waypoint in world.mission.waypoints:
        top.plot(waypoint.east_m, waypoint.north_m, "k*")
    top.set_xlabel("east (m)")
    top.set_ylabel("north (m)")
    top.set_aspect("equal")
    top.set_title(world.scenario)
    if paths:
        top.legend(fontsize=8, loc="best")
    series.plot(times, distances, color="tab:blue", label="clearance")
    series.axhline(world.safety_distance_m, color="tab:red", linestyle="--", label="safety distance")
    series.set_xlabel("simulation time (s)")
    series.set_ylabel("UAV to nearest obstacle (m)")
    series.legend()
    figure.tight_layout()
    figure.savefig(out, dpi=110)
    plt.close(figure)
    return figure


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
