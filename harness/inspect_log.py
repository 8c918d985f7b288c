"""`stella inspect`: summarize an evaluation log and recompute its fitness from the log alone."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from harness import logs
from harness.evaluation import rescore


def summarize(path: Path) -> dict[str, Any]:
    scored = rescore(path)
    clearance = scored["clearance"]
    recorded = scored["recorded"]
    summary = scored["summary"]
    return {
        "log": str(path),
        "scenario": scored["world"].get("scenario"),
        "duration_s": summary.get("sim_time_s"),
        "end_reason": summary.get("end_reason"),
        "status": scored["status"],
        "why": scored["why"],
        "fitness": scored["fitness"],
        "recorded_fitness": recorded.get("fitness"),
        "fitness_reproduced": recorded.get("fitness") == scored["fitness"],
        "min_clearance_m": clearance.min_clearance_m,
        "min_clearance_at_s": clearance.at_s,
        "min_clearance_obstacle": clearance.obstacle,
        "safety_distance_m": scored["world"]["safety_distance_m"],
        "touchdown": summary.get("touchdown"),
    }


def plot(path: Path, out: Path) -> None:
    """Top view of the trajectory with the obstacles, and the clearance over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Polygon

    world = logs.json_metadata(path, "world")
    states = [m for _t, _ns, m in logs.messages(path, ["/uav/state"])]
    times, distances = [], []
    for _t, _ns, batch in logs.messages(path, ["/clearance"]):
        for t, d in zip(batch["t"], batch["d"]):
            if d is not None:
                times.append(t)
                distances.append(d)
    figure, (top, series) = plt.subplots(1, 2, figsize=(13, 5.5))
    top.plot([s["east_m"] for s in states], [s["north_m"] for s in states], color="tab:blue", label="UAV")
    for obstacle in world["obstacles"]:
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
    for waypoint in world["mission"]["waypoints"]:
        top.plot(waypoint["east_m"], waypoint["north_m"], "k*")
    top.set_xlabel("east (m)")
    top.set_ylabel("north (m)")
    top.set_aspect("equal")
    top.set_title(world.get("scenario", ""))
    series.plot(times, distances, color="tab:blue", label="clearance")
    series.axhline(world["safety_distance_m"], color="tab:red", linestyle="--", label="safety distance")
    series.set_xlabel("simulation time (s)")
    series.set_ylabel("UAV to nearest obstacle (m)")
    series.legend()
    figure.tight_layout()
    figure.savefig(out, dpi=110)
    plt.close(figure)
