"""The local tangent-plane approximation used by the simulator and by the harness alike."""

from __future__ import annotations

import math
from typing import Mapping

EARTH_RADIUS_M = 6378137.0


def geodetic_from_local(origin: Mapping[str, float], north_m: float, east_m: float) -> tuple[float, float]:
    lat0 = origin["lat_deg"]
    return (
        lat0 + math.degrees(north_m / EARTH_RADIUS_M),
        origin["lon_deg"] + math.degrees(east_m / (EARTH_RADIUS_M * math.cos(math.radians(lat0)))),
    )


def local_from_geodetic(origin: Mapping[str, float], lat_deg: float, lon_deg: float) -> tuple[float, float]:
    lat0 = origin["lat_deg"]
    return (
        math.radians(lat_deg - lat0) * EARTH_RADIUS_M,
        math.radians(lon_deg - origin["lon_deg"]) * EARTH_RADIUS_M * math.cos(math.radians(lat0)),
    )
