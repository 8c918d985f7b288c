"""Screening campaigns (issue 57): each batch flown on the bundled autopilot first, the SUT only
where those cheap flights rank it worth it. In CI the subject is the bundled autopilot with a
seeded fault the cheap model knows nothing of."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest

from conftest import ROOT
from harness.campaigns.screen import Screen, ScreenSettings, screen_sut
from harness.campaigns.store import Store
from harness.execution.local import SequentialExecutor
from harness.flight.fitness import Status
from harness.flight.results import EvaluationResult, RunOptions
from harness.tools.cli import main
from sut_adapter import SutConfig

WALL = str(ROOT / "scenarios" / "examples" / "wall.json")


def cheap_flight(fitness: float) -> EvaluationResult:
    return EvaluationResult(status=Status.VIOLATION if fitness < 0 else Status.OK, fitness=fitness, why=None, min_clearance_m=fitness + 1.0,
                            min_clearance_at_s=1.0, min_clearance_obstacle="obstacle_1", sim_time_s=20.0, wall_time_s=1.0, real_time_factor=20.0,
                            seed=0, log_path=None, scenario="s", sut="bundled")


def screen_with(tmp_path: Path, cheap: dict[str, float], **settings) -> Screen:
    """A screen over a real store that already holds these candidates' cheap flights (as a
    resumed run's would): nothing to fly."""
    store = Store(tmp_path / "c.db")
    campaign = store.campaign({"test": True})
    run_id, _finished = store.run(campaign, "s.json", "s", "RANDOM", 0, 7)
    for key, fitness in cheap.items():
        store.add_screen_flight(run_id, key, cheap_flight(fitness))
    return Screen(ScreenSettings(SutConfig(), **settings), SequentialExecutor(), store, run_id, 7, tmp_path, RunOptions())


def test_the_most_promising_share_is_flown_and_the_rest_only_by_the_explore_chance_alike_every_time(tmp_path):
    cheap = {f"k{i}": float(i) for i in range(10)}  # k0 the most promising: the least clearance
    screen = screen_with(tmp_path, cheap, share=0.3, explore=0.0)
    assert screen.choose(list(cheap)) == {"k0", "k1", "k2"}
    assert screen.screened_out == 7
    everyone = screen_with(tmp_path / "explore", cheap, share=0.3, explore=1.0)
    assert everyone.choose(list(cheap)) == set(cheap)
    # some: a seeded draw, the same for the same run and batch, and kept in the store for a resumed run
    some = screen_with(tmp_path / "some", cheap, share=0.3, explore=0.5).choose(list(cheap))
    assert {"k0", "k1", "k2"} < some < set(cheap)
    resumed = Screen(ScreenSettings(SutConfig(), share=0.3, explore=0.5), SequentialExecutor(), Store(tmp_path / "some" / "c.db"), 1, 7,
                     tmp_path, RunOptions())
    assert resumed.choose(list(cheap)) == some and resumed.screened_out == 10 - len(some)


def test_a_screen_that_stops_predicting_falls_back_to_flying_every_candidate(tmp_path):
    cheap = {f"k{i}": float(i) for i in range(20)}
    screen = screen_with(tmp_path, cheap, share=0.3, explore=0.0, min_pairs=10, min_correlation=0.3)
    for i in range(9):  # the real clearance the reverse of the cheap one
        screen.learn(f"k{i}", 10.0 - i)
    assert not screen.fell_back and screen.rank_correlation == pytest.approx(-1.0)
    screen.learn("k9", -0.5)  # a violation the cheap flight called safe
    assert screen.fell_back and screen.false_negatives == 1
    assert screen.choose([f"k{i}" for i in range(10, 20)]) == {f"k{i}" for i in range(10, 20)}
    assert screen.summary() == {"flights": 20, "screened_out": 0, "pairs": 10, "rank_correlation": pytest.approx(-1.0), "false_negatives": 1,
                                "fell_back": True}


def test_the_cheap_model_takes_the_subjects_px4_parameters_and_never_its_seeded_fault():
    assert screen_sut(SutConfig("px4", {"CP_DIST": 2.0, "MPC_XY_CRUISE": 4.0}, px4_bin="/x")) == SutConfig("bundled", {"CP_DIST": 2.0, "MPC_XY_CRUISE": 4.0})
    assert screen_sut(SutConfig("bundled", {"CP_DIST": 2.0}, fault="cp_ignores_delay")) == SutConfig("bundled", {"CP_DIST": 2.0})
    assert screen_sut(SutConfig("ardupilot", {"AVOID_MARGIN": 3.0})) == SutConfig("bundled", {})  # ArduPilot's names not mapped yet


def screened_campaign(tmp_path: Path, capsys, store: Path) -> dict:
    capsys.readouterr()
    assert main(["campaign", WALL, "--algorithm", "RANDOM", "--evaluations", "6", "--batch", "8", "--seed", "4", "--workers", "2",
                 "--sut-fault", "cp_ignores_delay", "--screen", "bundled", "--screen-share", "0.25", "--screen-explore", "0.1",
                 "--store", str(store), "--json"]) == 0
    return json.loads(capsys.readouterr().out)["runs"][0]


def real_flights(store: Path) -> list[tuple[str, str, float]]:
    with sqlite3.connect(store) as db:
        return db.execute("SELECT vector_key, status, fitness FROM evaluations ORDER BY ordinal").fetchall()


@pytest.mark.slow
def test_a_screened_campaign_flies_the_subject_only_where_the_cheap_model_ranks_it_and_resumes_alike(tmp_path, capsys):
    # GIVEN the bundled autopilot with collision prevention ignoring its sensor delay, screened by
    # the bundled autopilot without the fault
    run = screened_campaign(tmp_path, capsys, tmp_path / "a.db")
    real = real_flights(tmp_path / "a.db")
    flown = [row for row in real if row[1] != "infeasible"]
    assert run["evaluations"] == 6 and run["flown"] == len(flown)
    screen = run["screen"]
    # THEN more candidates were judged than the subject flew, each flown for real was chosen by the screen
    assert screen["flights"] > len(flown) and screen["screened_out"] > 0
    with sqlite3.connect(tmp_path / "a.db") as db:
        chosen = {key for key, in db.execute("SELECT vector_key FROM screen_flights WHERE chosen = 1")}
        cheap = dict(db.execute("SELECT vector_key, fitness FROM screen_flights"))
    assert {key for key, _status, _fitness in flown} <= chosen
    assert screen["pairs"] == len(flown) and screen["false_negatives"] == sum(f < 0 <= cheap[k] for k, _s, f in flown)
    # AND compare counts the SUT's flights and the cheap model's apart
    capsys.readouterr()
    assert main(["compare", str(tmp_path / "a.db"), "--json"]) == 0
    overall = json.loads(capsys.readouterr().out)["overall"][0]
    assert (overall["flown"], overall["screen_flights"]) == (len(flown), screen["flights"])
    # AND the same seed gives the same campaign, flown in full or killed half way and resumed
    assert screened_campaign(tmp_path, capsys, tmp_path / "b.db")["screen"] == screen
    assert real_flights(tmp_path / "b.db") == real
    with sqlite3.connect(tmp_path / "b.db") as db:
        db.execute("DELETE FROM evaluations WHERE ordinal >= 3")
        db.execute("UPDATE runs SET finished = NULL")
    resumed = screened_campaign(tmp_path, capsys, tmp_path / "b.db")
    assert resumed["replayed"] == 3 and real_flights(tmp_path / "b.db") == real and resumed["screen"] == screen
