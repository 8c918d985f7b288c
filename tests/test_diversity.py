"""Search for diverse failures (--objective diverse): fitness sharing over failure modes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conftest import stored_result
from harness.campaigns.campaign import run_sequence
from harness.campaigns.diversity import FailureModes
from harness.campaigns.problem import CampaignProblem, Trial
from harness.campaigns.store import Store
from harness.flight.fitness import Status
from harness.scenario.logical import load_logical
from harness.scenario.profile import load_profile
from harness.scenario.space import SearchSpace
from harness.search.termination import EvaluationBudget
from harness.tools.cli import main

ROOT = Path(__file__).resolve().parents[1]


def trial(ordinal: int, fitness: float, mode: str) -> Trial:
    status = Status.VIOLATION if fitness < 0 else Status.OK
    return Trial(ordinal, np.zeros(1), f"k{ordinal}", fitness, status, log_path=mode)


def test_a_violation_of_a_crowded_mode_is_told_less_than_a_new_modes_and_more_than_any_safe_flight():
    modes = FailureModes(mode_of=lambda log_path: log_path)  # the mode is named where the log would be
    history = [trial(0, -2.0, "intruder ahead"), trial(1, -1.0, "intruder ahead"), trial(2, 0.5, "wall ahead"),
               trial(3, -1.5, "intruder ahead"), trial(4, -0.6, "wall beside")]
    told = {t.ordinal: modes.shared(t, history) for t in history}
    assert told[0] == -2.0 and told[4] == -0.6  # first of their modes: as flown
    assert told[1] == -0.5 and told[3] == -0.5  # the second and third of one mode: shared by 2 and 3
    assert told[2] == 0.5  # no violation: nothing to share
    assert max(v for v in told.values() if v < 0) < 0 < told[2]
    # By ordinal, not by the order the flights came back in.
    assert [modes.shared(t, list(reversed(history))) for t in history] == list(told.values())


class SidedExecutor:
    """Stands in for the simulator in this optimizer-only test: a violation wherever the obstacle
    starts within 25 m of the route's far point, deeper the closer; its failure mode is the side of
    the route it starts on (named in place of a log). The product never uses it."""

    name = "sided"

    def run(self, jobs):
        for job in jobs:
            position = job.concrete["obstacles"][0]["position"]
            d = float(np.hypot(position["north_m"] - 30.0, position["east_m"] - 3.0)) - 25.0
            side = "left" if position["east_m"] < 0 else "right"
            yield job, stored_result(d, "violation" if d < 0 else "ok", job.seed, log_path=side)

    def close(self):
        pass


def searched(tmp_path, name: str, diversity: FailureModes | None) -> list[tuple]:
    profile = load_profile("default")
    space = SearchSpace(load_logical(ROOT / "scenarios/table3/scenario_16.json", profile), profile)
    with Store(tmp_path / name) as store:
        run_id, _ = store.run(store.campaign({"test": name}), "s", "s", "NSGAII", 0, 3)
        problem = CampaignProblem(space, store, run_id, SidedExecutor(), 3, EvaluationBudget(40), tmp_path, diversity=diversity)
        run_sequence("N", problem, budget=40, seed=3, population=8, batch=2)
        return [(e.ordinal, e.vector_key, e.fitness, e.log_path) for e in store.evaluations(run_id).values()]


def test_the_optimizer_hears_the_shared_fitness_the_store_keeps_each_flights_own_and_new_modes_are_searched_for(tmp_path):
    plain = sorted(searched(tmp_path, "plain.db", None))
    diverse = sorted(searched(tmp_path, "diverse.db", FailureModes(mode_of=lambda log_path: log_path)))
    # The first generation is asked before anything is told: the same flights, stored as flown.
    assert plain[:8] == diverse[:8]
    violations = [row for row in plain[:8] if row[2] < 0]
    assert len(violations) >= 2
    # Told that repeats of a mode are worth less, NSGA-II breeds other generations.
    assert [row[1] for row in plain[8:]] != [row[1] for row in diverse[8:]]


def test_diverse_is_a_campaigns_objective_without_a_reference(tmp_path, capsys):
    assert main(["campaign", "scenarios/examples/wall.json", "--algorithm", "RANDOM", "--evaluations", "2", "--store", str(tmp_path / "c.db"),
                 "--objective", "diverse", "--reference-sut-param", "CP_DIST=1.0"]) == 2
    assert "--objective: diverse searches one SUT's failures" in capsys.readouterr().err
    assert not (tmp_path / "c.db").exists()
    with pytest.raises(SystemExit):
        main(["run", "scenarios/examples/wall.json", "--objective", "diverse"])
    assert "invalid choice: 'diverse'" in capsys.readouterr().err
