"""What every optimizer adapter sees of a campaign: a search space and a function from batches
of vectors to fitness values, which raises StopSearch when the budget is spent.

The campaign implements it (harness/campaigns/problem.py) with the store, the executor and the
budgets behind it; an optimizer knows none of them.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from harness.scenario.space import SearchSpace


class StopSearch(Exception):
    """Raised out of an optimizer's loop when its step budget or the run's termination is reached."""

    def __init__(self, campaign_done: bool):
        self.campaign_done = campaign_done
        super().__init__("campaign termination reached" if campaign_done else "step budget reached")


class Problem(Protocol):
    space: SearchSpace

    def evaluate(self, vectors: list[np.ndarray]) -> list[float]:
        """The fitness of each vector, in order; raises StopSearch when the search must end."""
