"""What the campaign store hands its readers: typed, frozen rows, their JSON columns parsed, their
status a Status. SQL and column names stay in the store; readers see fields."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from harness.flight.differential import Reveal
from harness.flight.fitness import Status


def vector_key(x: np.ndarray) -> str:
    """Exact identity of a candidate in the store: the bytes of its float64 values."""
    return np.ascontiguousarray(np.asarray(x, dtype=np.float64)).tobytes().hex()


def evaluation_name(evaluation_id: int) -> str:
    """The name of an evaluation's log (and of its folder of SUT logs): its id in the store, the
    number every command shows and takes (`stella shrink DB --evaluation 25` for eval00025.mcap)."""
    return f"eval{evaluation_id:05d}"


@dataclass(frozen=True)
class StoredEvaluation:
    """One stored evaluation, with the run it belongs to (scenario, algorithm, run index)."""

    id: int
    run_id: int
    ordinal: int
    vector: np.ndarray = field(compare=False)
    vector_key: str
    fitness: float
    status: Status
    log_path: str | None
    seed: int
    why: str | None = None
    min_clearance_m: float | None = None
    sim_time_s: float | None = None
    wall_time_s: float | None = None
    created: float = 0.0
    concrete: Mapping[str, Any] | None = None  # the concrete scenario flown; None for stores of analytic tests
    confirmations: Mapping[str, Any] | None = None  # a violation flown again (--confirm): how often it came back
    reveals: Reveal | None = None  # a differential campaign's verdict on the pair
    differential: Mapping[str, Any] | None = None  # both sides' flights
    scenario: str = ""
    scenario_file: str = ""
    algorithm: str = ""
    run_index: int = 0
    properties: Mapping[str, Any] = field(default_factory=dict)  # each safety property scored: verdict, robustness, unit
    coverage: Mapping[str, Any] | None = None  # a coverage build's flight: the code it ran (sut_adapter/coverage.py)

    @property
    def flaky(self) -> bool:
        """A violation re-flown with --confirm that did not violate in every re-flight."""
        return self.confirmations is not None and self.confirmations["violations"] < self.confirmations["repeats"]


@dataclass(frozen=True)
class StoredRun:
    """One run of a campaign (scenario x algorithm x run index) with what its evaluations add up to."""

    id: int
    scenario_file: str
    scenario: str
    algorithm: str
    run_index: int
    seed: int
    finished: float | None  # when it finished; None while under way or stopped
    best_fitness: float | None  # what its search minimised (f, or the least robustness of its properties); None before its first evaluation
    evaluations: int
    violations: int
    contacts: int  # violations that touched an obstacle (clearance 0 or less)
    flaky: int  # violations that did not come back in every re-flight (--confirm)
    failures_refused: int  # flights in which the SUT refused a failure injection
    revealing: int  # a differential campaign's candidates that reveal a difference ...
    revealing_unsafe: int  # ... and those of them that reveal an unsafe one
    first_revealing: int | None  # the ordinal of the first revealing candidate
    first_created: float | None  # when its first and last evaluations were stored
    last_created: float | None
    flown: int = 0  # its evaluations the SUT flew (not refused as infeasible)
    screen_flights: int = 0  # a screened run's flights on the cheap model (harness/campaigns/screen.py)
