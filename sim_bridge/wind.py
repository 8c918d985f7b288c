"""The air's motion over the ground: the steady wind, Dryden turbulence and a discrete 1-cosine gust.

Turbulence follows the Dryden model's first-order form, each axis a Gauss-Markov process with
time constant L / V (MIL-F-8785C): the vehicle flying at V through frozen turbulence of scale
length L meets changes every L / V seconds. North and east share the horizontal intensity and
length, down has the vertical ones. It draws its own seeded generator (the sensors' noise stays
what it was without turbulence) in blocks, and runs from the start of the run, so setup time
changes nothing.
"""

from __future__ import annotations

import math

import numpy as np

from sim_bridge.spec import Atmosphere

# Below this airspeed the turbulence is taken as met at it: a hovering vehicle still feels the
# air move past (the Dryden model is undefined at V = 0).
MIN_AIRSPEED_M_S = 1.0
_BLOCK = 1024


class WindField:
    def __init__(self, atmosphere: Atmosphere, seed: int, dt_s: float):
        self.steady = (atmosphere.wind_north_m_s, atmosphere.wind_east_m_s, 0.0)
        self.turbulence = atmosphere.turbulence
        self.gust = atmosphere.gust
        self.varies = atmosphere.varies
        self.dt_s = dt_s
        self._rng = np.random.default_rng([seed, 0x6775])  # 'gu': a stream of its own
        self._draws: list[list[float]] = []
        self._state = [0.0, 0.0, 0.0]
        if self.turbulence is not None:
            # Start in the stationary distribution rather than in still air.
            first = self._next_draw()
            sigma = (self.turbulence.sigma_horizontal_m_s,) * 2 + (self.turbulence.sigma_vertical_m_s,)
            self._state = [s * n for s, n in zip(sigma, first)]
        if self.gust is not None:
            toward = math.radians(self.gust.from_deg + 180.0)
            self._gust_direction = (math.cos(toward), math.sin(toward))

    def _next_draw(self) -> list[float]:
        if not self._draws:
            self._draws = self._rng.standard_normal((_BLOCK, 3)).tolist()[::-1]
        return self._draws.pop()

    def gust_at(self, run_time_s: float) -> float:
        """The 1-cosine gust's speed at a run time (0 outside it)."""
        gust = self.gust
        if gust is None or not gust.onset_s <= run_time_s <= gust.onset_s + gust.duration_s:
            return 0.0
        return gust.amplitude_m_s / 2.0 * (1.0 - math.cos(2.0 * math.pi * (run_time_s - gust.onset_s) / gust.duration_s))

    def advance(self, run_time_s: float | None, airspeed_m_s: float) -> tuple[float, float, float]:
        """The wind (north, east, down m/s) for the next step; the turbulence moves on by one step
        once the run has begun (run_time_s not None)."""
        north, east, down = self.steady
        if run_time_s is None:
            return north, east, down
        turbulence = self.turbulence
        if turbulence is not None:
            travelled_m = max(airspeed_m_s, MIN_AIRSPEED_M_S) * self.dt_s
            draw = self._next_draw()
            state = self._state
            decay = math.exp(-travelled_m / turbulence.length_horizontal_m)
            kick = turbulence.sigma_horizontal_m_s * math.sqrt(1.0 - decay * decay)
            state[0] = decay * state[0] + kick * draw[0]
            state[1] = decay * state[1] + kick * draw[1]
            decay = math.exp(-travelled_m / turbulence.length_vertical_m)
            state[2] = decay * state[2] + turbulence.sigma_vertical_m_s * math.sqrt(1.0 - decay * decay) * draw[2]
            north += state[0]
            east += state[1]
            down += state[2]
        gust = self.gust_at(run_time_s)
        if gust:
            north += gust * self._gust_direction[0]
            east += gust * self._gust_direction[1]
        return north, east, down
