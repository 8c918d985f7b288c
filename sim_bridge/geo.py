"""The local tangent-plane approximation used by the simulator and by the harness alike."""

from __future__ import annotations

import math

EARTH_RADIUS_M = 6378137.0


def geodetic_from_local(lat0_deg: float, lon0_deg: float, north_m: float, east_m: float) -> tuple[float, float]:
    """(lat, lon) of a local point, the origin at (lat0_deg, lon0_deg)."""
    return (
        lat0_deg + math.degrees(north_m / EARTH_RADIUS_M),
        lon0_deg + math.degrees(east_m / (EARTH_RADIUS_M * math.cos(math.radians(lat0_deg)))),
    )


def local_from_geodetic(lat0_deg: float, lon0_deg: float, lat_deg: float, lon_deg: float) -> tuple[float, float]:
    """(north, east) of a geodetic point, the origin at (lat0_deg, lon0_deg)."""
    return (
        math.radians(lat_deg - lat0_deg) * EARTH_RADIUS_M,
        math.radians(lon_deg - lon0_deg) * EARTH_RADIUS_M * math.cos(math.radians(lat0_deg)),
    )
