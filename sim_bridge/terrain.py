"""Terrain height by landform, shared by the world builder and the simulator.

Heights are metres above the start point's datum (up positive) at local north/east metres.
"""

from __future__ import annotations

import math
from typing import Any, Mapping


def terrain_height_m(terrain: Mapping[str, Any], north_m: float, east_m: float) -> float:
    kind = terrain["kind"]
    if kind == "flat":
        return 0.0
    if kind == "gaussian":
        dn = north_m - terrain["center_north_m"]
        de = east_m - terrain["center_east_m"]
        sigma = terrain["sigma_m"]
        return terrain["height_m"] * math.exp(-(dn * dn + de * de) / (2.0 * sigma * sigma))
    if kind == "step":
        return 0.5 * terrain["height_m"] * (1.0 + math.tanh((north_m - terrain["edge_north_m"]) / terrain["width_m"]))
    raise ValueError(f"unknown terrain kind {kind!r}")


def max_height_on_segment_m(
    terrain: Mapping[str, Any], start: tuple[float, float], end: tuple[float, float], samples: int = 200
) -> float:
    """Highest terrain along a straight line, sampled finely enough for these smooth landforms."""
    return max(
        terrain_height_m(
            terrain,
            start[0] + (end[0] - start[0]) * i / samples,
            start[1] + (end[1] - start[1]) * i / samples,
        )
        for i in range(samples + 1)
    )


def is_water(water: list[Mapping[str, float]], north_m: float, east_m: float) -> bool:
    return any(
        r["north_min_m"] <= north_m <= r["north_max_m"] and r["east_min_m"] <= east_m <= r["east_max_m"] for r in water
    )
