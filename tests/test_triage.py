"""Triage: what happened at the moment of least clearance, read from the trajectory; the modes a
store's violations fall into; per-mode export."""

from __future__ import annotations

import numpy as np
import pytest

from harness.campaigns.triage import SPEED_BANDS, _approach, _band, _phase, trajectory, trajectory_distance


def state(t: float, vn: float = 0.0, ve: float = 0.0, vd: float = 0.0, north: float = 0.0, east: float = 0.0, up: float = 8.0) -> dict:
    return {"t": t, "north_m": north, "east_m": east, "up_m": up, "v_ned_m_s": [vn, ve, vd]}


@pytest.mark.parametrize("before, at, phase", [
    (state(0.0, vd=-1.0), state(0.1, vd=-1.0), "climb"),
    (state(0.0, vd=0.7), state(0.1, vd=0.7), "descent"),
    (state(0.0), state(0.1, vn=0.2), "hover"),
    (state(0.0, vn=3.0), state(0.1, vn=2.5), "braking"),  # -5 m/s^2 along the velocity
    (state(0.0, vn=5.0), state(0.1, vn=5.0, ve=0.1), "cruise"),
    (state(0.0, ve=-4.0), state(0.1, ve=-4.02), "cruise"),  # speeding up a little is not braking
])
def test_the_flight_phase_at_the_closest_moment(before, at, phase):
    assert _phase(before, at) == phase


@pytest.mark.parametrize("obstacle, where", [((10.0, 1.0), "ahead"), ((0.0, 8.0), "beside"), ((-6.0, -1.0), "behind")])
def test_where_the_obstacle_was_relative_to_the_direction_of_flight(obstacle, where):
    assert _approach(state(0.0, vn=4.0), np.array([*obstacle, 8.0])) == where
    assert _approach(state(0.0, vn=0.1), np.array([*obstacle, 8.0])) == "while hovering"


def test_speed_bands_and_trajectory_distance():
    assert [_band(v, SPEED_BANDS) for v in (0.2, 1.0, 2.9, 3.0, 12.0)] == ["slow (< 1 m/s)", "medium (1-3 m/s)", "medium (1-3 m/s)", "fast (> 3 m/s)", "fast (> 3 m/s)"]
    straight = [state(t, north=5.0 * t) for t in np.linspace(0.0, 10.0, 101)]
    beside = [state(t, north=5.0 * t, east=2.0) for t in np.linspace(0.0, 10.0, 37)]  # sampled differently, 2 m east
    assert trajectory(straight).shape == (50, 3)
    assert trajectory_distance(trajectory(straight), trajectory(beside)) == pytest.approx(2.0)
