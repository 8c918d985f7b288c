"""The screen's learned correction: a Gaussian process trained on the candidates flown both ways,
predicting the real SUT's objective from the cheap flight's and the candidate itself.

The real objective is modelled as the cheap one plus a residual, real = cheap + r(x, cheap), on
a squashed scale, sign(y) log(1 + |y|): a flight that could not do its mission carries a penalty
of 1000 m (harness/flight/fitness.py), which on a linear scale would swamp clearances of a few
metres, and the squash keeps every order and the sign, so a violation stays below 0. The cheap
objective is an input beside the candidate's coordinates: how the two SUTs part often depends on
how close the cheap flight came (PX4's collision prevention stops a pilot that the bundled
autopilot lets past), not only on where the candidate lies.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Sequence

import numpy as np

OPTIMISM = 2.0  # standard deviations below the predicted mean that the screen ranks by
# The kernel's hyperparameters fitted from their initial values only, no random restarts: the
# fit is about a third of a screened campaign's own CPU on PX4 (3-20 CPU-s a batch, measured with
# two restarts), and each restart costs another fit.
RESTARTS = 0


def squash(y: np.ndarray | float) -> np.ndarray:
    return np.sign(y) * np.log1p(np.abs(y))


def unsquash(z: np.ndarray | float) -> np.ndarray:
    return np.sign(z) * np.expm1(np.abs(z))


@dataclass(frozen=True)
class Pair:
    """A candidate flown both ways: its coordinates, and the cheap and the real objective."""

    key: str
    x: np.ndarray
    cheap: float
    real: float


@dataclass(frozen=True)
class Prediction:
    """The real objective expected of a candidate, and its standard deviation, both on the
    squashed scale; `objective` is the mean back in metres."""

    mean: float
    sd: float

    @property
    def objective(self) -> float:
        return float(unsquash(self.mean))

    @property
    def optimistic(self) -> float:
        """The objective the real flight gets below with a chance of about 2 %, on the squashed
        scale: what the screen ranks by, so that a candidate the model knows little of comes
        forward. (The chance of a violation itself ranks badly: where no candidate is near one,
        it prefers the most uncertain to the closest.)"""
        return self.mean - OPTIMISM * self.sd


class ResidualModel:
    """Fitted on pairs in the order of their keys, with the run's seed for the optimiser's restarts,
    so the same pairs give the same model in a resumed run."""

    def __init__(self, lower: np.ndarray, upper: np.ndarray, pairs: Sequence[Pair], seed: int):
        from sklearn.exceptions import ConvergenceWarning
        from sklearn.gaussian_process import GaussianProcessRegressor
        from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

        self.lower = np.asarray(lower, dtype=float)
        self.width = np.where(np.asarray(upper, dtype=float) > self.lower, np.asarray(upper, dtype=float) - self.lower, 1.0)
        ordered = sorted(pairs, key=lambda pair: pair.key)
        features = self._features(np.array([pair.x for pair in ordered]), np.array([pair.cheap for pair in ordered]))
        residuals = squash(np.array([pair.real for pair in ordered])) - squash(np.array([pair.cheap for pair in ordered]))
        kernel = (ConstantKernel(1.0, (1e-3, 1e3)) * Matern(np.ones(features.shape[1]), (1e-2, 1e3), nu=2.5)
                  + WhiteKernel(1e-2, (1e-6, 1e1)))
        self.gp = GaussianProcessRegressor(kernel, normalize_y=True, n_restarts_optimizer=RESTARTS, random_state=seed)
        with warnings.catch_warnings():
            # A length scale at its bound says a coordinate does not matter: the fit is still sound.
            warnings.simplefilter("ignore", ConvergenceWarning)
            self.gp.fit(features, residuals)

    def _features(self, xs: np.ndarray, cheap: np.ndarray) -> np.ndarray:
        return np.column_stack([(xs - self.lower) / self.width, squash(cheap)])

    def predict(self, xs: np.ndarray, cheap: np.ndarray) -> list[Prediction]:
        residual, sd = self.gp.predict(self._features(np.atleast_2d(xs), np.asarray(cheap, dtype=float)), return_std=True)
        return [Prediction(float(mean), float(spread)) for mean, spread in zip(squash(np.asarray(cheap, dtype=float)) + residual, sd)]
