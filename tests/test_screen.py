"""Screening campaigns (issue 57): each batch flown on the bundled autopilot first, the SUT only
where those cheap flights rank it worth it. In CI the subject is the bundled autopilot with a
seeded fault the cheap model knows nothing of."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT, stored_result
from harness.campaigns.residual import Pair, ResidualModel
from harness.campaigns.screen import Screen, ScreenSettings, screen_sut
from harness.campaigns.screen_sources import pairs_to_learn
from harness.campaigns.store import Store
from harness.campaigns.store.rows import vector_key
from harness.errors import InputError
from harness.execution.local import SequentialExecutor
from harness.flight.fitness import PENALTY, Status
from harness.flight.results import EvaluationResult, RunOptions
from harness.scenario.logical import load_logical
from harness.scenario.space import SearchSpace
from harness.tools.cli import main
from sut_adapter import SutConfig

WALL = str(ROOT / "scenarios" / "examples" / "wall.json")


@pytest.fixture(scope="module")
def space(profile) -> SearchSpace:
    return SearchSpace(load_logical(Path(WALL), profile), profile)


def spread_over(space: SearchSpace, count: int, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [space.lower + rng.random(len(space.lower)) * (space.upper - space.lower) for _ in range(count)]


def cheap_flight(fitness: float, blocked: bool = False) -> EvaluationResult:
    """A cheap flight with this f; blocked: its mission not performed, its fitness f + PENALTY."""
    status = Status.VIOLATION if fitness < 0 else Status.MISSION_FAILED if blocked else Status.OK
    return EvaluationResult(status=status, fitness=fitness + (PENALTY if status == Status.MISSION_FAILED else 0.0), why=None, min_clearance_m=fitness + 1.0,
                            min_clearance_at_s=1.0, min_clearance_obstacle="obstacle_1", sim_time_s=20.0, wall_time_s=1.0, real_time_factor=20.0,
                            seed=0, log_path=None, scenario="s", sut="bundled")


def screen_with(tmp_path: Path, space: SearchSpace, cheap: dict[str, float], run: int = 0, **settings) -> Screen:
    """A screen over a real store that already holds these candidates' cheap flights (as a
    resumed run's would): nothing to fly."""
    store = Store(tmp_path / "c.db")
    campaign = store.campaign({"test": True})
    run_id, _finished = store.run(campaign, "s.json", "s", "RANDOM", run, 7, scenario_key="sha256:s")
    for key, fitness in cheap.items():
        store.add_screen_flight(run_id, key, cheap_flight(fitness))
    return Screen(ScreenSettings(SutConfig(), **settings), SequentialExecutor(), store, run_id, 7, tmp_path, RunOptions(), space)


def test_the_most_promising_share_is_flown_and_the_rest_only_by_the_explore_chance_alike_every_time(tmp_path, space):
    cheap = {f"k{i}": float(i) for i in range(10)}  # k0 the most promising: the least clearance
    batch = list(zip(cheap, spread_over(space, 10)))
    screen = screen_with(tmp_path, space, cheap, share=0.3, explore=0.0)
    assert screen.choose(batch) == {"k0", "k1", "k2"}
    assert screen.screened_out == 7
    everyone = screen_with(tmp_path / "explore", space, cheap, share=0.3, explore=1.0)
    assert everyone.choose(batch) == set(cheap)
    # some: a seeded draw, the same for the same run and batch, and kept in the store for a resumed run
    some = screen_with(tmp_path / "some", space, cheap, share=0.3, explore=0.5).choose(batch)
    assert {"k0", "k1", "k2"} < some < set(cheap)
    resumed = Screen(ScreenSettings(SutConfig(), share=0.3, explore=0.5), SequentialExecutor(), Store(tmp_path / "some" / "c.db"), 1, 7,
                     tmp_path, RunOptions(), space)
    assert resumed.choose(batch) == some and resumed.screened_out == 10 - len(some)


def test_a_screen_that_stops_predicting_falls_back_to_flying_every_candidate(tmp_path, space):
    cheap = {f"k{i}": float(i) for i in range(20)}
    vectors = dict(zip(cheap, spread_over(space, 20)))
    screen = screen_with(tmp_path, space, cheap, share=0.3, explore=0.0, min_pairs=10, min_correlation=0.3, correction="none")
    for i in range(9):  # the real clearance the reverse of the cheap one
        screen.learn(f"k{i}", vectors[f"k{i}"], 10.0 - i)
    assert not screen.fell_back and screen.rank_correlation == pytest.approx(-1.0)
    screen.learn("k9", vectors["k9"], -0.5)  # a violation the cheap flight called safe
    assert screen.fell_back and screen.false_negatives == 1
    assert screen.choose([(f"k{i}", vectors[f"k{i}"]) for i in range(10, 20)]) == {f"k{i}" for i in range(10, 20)}
    assert screen.summary() == {"flights": 20, "screened_out": 0, "pairs": 10, "rank_correlation": pytest.approx(-1.0), "false_negatives": 1,
                                "fell_back": True}


def parted(space: SearchSpace, x: np.ndarray, cheap: float) -> float:
    """A subject that parts from the cheap model by where the candidate lies: 3 m closer at one end
    of the first coordinate, 3 m farther at the other (as PX4's collision prevention stops a pilot
    the bundled autopilot lets past, in one part of a scenario)."""
    return cheap + 6.0 * ((x[0] - space.lower[0]) / (space.upper[0] - space.lower[0]) - 0.5)


def test_the_residual_model_learns_where_the_subject_parts_from_the_cheap_model_whatever_the_order_it_hears_them(space):
    rng = np.random.default_rng(3)
    xs = spread_over(space, 60, seed=1)
    cheap = rng.uniform(1.0, 3.0, 60)
    pairs = [Pair(f"k{i:02d}", x, c, parted(space, x, c)) for i, (x, c) in enumerate(zip(xs[:30], cheap[:30]))]
    model = ResidualModel(space.lower, space.upper, pairs, seed=7)
    predicted = [p.objective for p in model.predict(np.array(xs[30:]), cheap[30:])]
    real = [parted(space, x, c) for x, c in zip(xs[30:], cheap[30:])]
    from scipy.stats import spearmanr

    # THEN on candidates it never heard of, the corrected objective ranks as the subject does and the cheap one does not
    assert spearmanr(predicted, real).statistic > 0.9 > spearmanr(cheap[30:], real).statistic + 0.2
    assert np.median(np.abs(np.array(predicted) - real)) < 0.5
    # AND the same pairs heard in another order give the same model to the bit (a resumed run decides alike)
    again = ResidualModel(space.lower, space.upper, list(reversed(pairs)), seed=7)
    assert [p.objective for p in again.predict(np.array(xs[30:]), cheap[30:])] == predicted


def earlier_run_parting(tmp_path: Path, space: SearchSpace, xs: list[np.ndarray]) -> Store:
    """A store whose earlier run of the scenario flew these candidates both ways, all alike on the
    cheap model (3 m), the subject parting from it by where the candidate lies."""
    earlier = screen_with(tmp_path, space, {}, run=0)
    for i, x in enumerate(xs):
        earlier.store.add_screen_flight(earlier.run_id, vector_key(x), cheap_flight(3.0))
        earlier.store.add_evaluation(earlier.run_id, ordinal=i, step=0, optimizer="RANDOM", vector=x, result=stored_result(parted(space, x, 3.0), "ok"),
                                     concrete=None)
    return earlier.store


def test_a_trained_correction_chooses_where_the_subject_comes_close_and_the_optimizer_hears_its_prediction(tmp_path, space):
    # GIVEN a store's earlier run of the scenario: 12 candidates flown both ways, the subject parting from the cheap model
    store_path = tmp_path / "c.db"
    xs = spread_over(space, 32, seed=2)
    store = earlier_run_parting(tmp_path, space, xs[:12])
    # AND this run's batch, all alike on the cheap model
    batch = {f"k{i}": x for i, x in enumerate(xs[12:])}
    campaign = store.campaign({"test": True})
    run_id, _finished = store.run(campaign, "s.json", "s", "RANDOM", 1, 8, scenario_key="sha256:s")
    # (the candidate where the subject keeps farthest blocked on the cheap model: the same 3 m of clearance)
    farthest = max(batch, key=lambda key: parted(space, batch[key], 3.0))
    for key in batch:
        store.add_screen_flight(run_id, key, cheap_flight(3.0, blocked=key == farthest))
    screen = Screen(ScreenSettings(SutConfig(), share=0.25, explore=0.0), SequentialExecutor(), store, run_id, 8, tmp_path, RunOptions(), space)
    # WHEN the screen chooses
    chosen = screen.choose(list(batch.items()))
    # THEN it chose the candidates where the subject comes closest, which the cheap flights cannot tell apart
    real = {key: parted(space, x, 3.0) for key, x in batch.items()}
    assert chosen == set(sorted(real, key=real.get)[:5])
    # AND the optimizer hears the predicted real objective of those screened out, kept in the store for a resumed run
    out = next(key for key in batch if key not in chosen)
    assert screen.told(out) == pytest.approx(real[out], abs=0.5) and screen.told(out) != 3.0
    resumed = Screen(ScreenSettings(SutConfig(), share=0.25, explore=0.0), SequentialExecutor(), Store(store_path), run_id, 8, tmp_path, RunOptions(), space)
    assert resumed.choose(list(batch.items())) == chosen and resumed.told(out) == screen.told(out)
    # and of a candidate whose cheap mission was not performed, with the penalty: no violation is predicted
    assert screen.told(farthest) == pytest.approx(parted(space, batch[farthest], 3.0) + PENALTY, abs=0.5)
    # AND the error is measured both ways on what is flown: the correction's prediction ranks, the cheap flights cannot
    for key in sorted(chosen) + [out, *[k for k in batch if k not in chosen][1:4]]:
        screen.learn(key, batch[key], real[key])
    summary = screen.summary()
    assert summary["rank_correlation"] is None and summary["corrected_rank_correlation"] > 0.9
    assert summary["training_pairs"] == 12 + 9


def test_a_correction_that_ranks_worse_than_the_cheap_flights_is_set_aside_and_the_optimizer_hears_the_cheap_ones(tmp_path, space):
    # GIVEN a correction trained on an earlier run in which the subject parted from the cheap model by where the candidate lay
    xs = spread_over(space, 36, seed=4)
    store = earlier_run_parting(tmp_path, space, xs[:12])
    # AND a run in which it flies as the cheap model does
    first = {vector_key(x): (x, 1.0 + i) for i, x in enumerate(xs[12:24])}
    second = {vector_key(x): (x, 20.0 + i) for i, x in enumerate(xs[24:])}
    run_id, _finished = store.run(store.campaign({"test": True}), "s.json", "s", "RANDOM", 1, 8, scenario_key="sha256:s")
    for key, (_x, cheap) in {**first, **second}.items():
        store.add_screen_flight(run_id, key, cheap_flight(cheap))
    settings = ScreenSettings(SutConfig(), share=0.3, explore=0.0, min_pairs=10)
    screen = Screen(settings, SequentialExecutor(), store, run_id, 8, tmp_path, RunOptions(), space)
    assert screen.correction_ranks_better  # nothing judged yet
    screen.choose([(key, x) for key, (x, _c) in first.items()])
    for key, (x, cheap) in first.items():  # WHEN its predictions meet the real flights
        screen.learn(key, x, cheap)
    # THEN the cheap flights ranked them better, and the screen ranks the next batch by them
    assert not screen.correction_ranks_better and screen.rank_correlation == pytest.approx(1.0) and screen.corrected_rank_correlation < 0.99
    chosen = screen.choose([(key, x) for key, (x, _c) in second.items()])
    assert chosen == set(list(second)[:4])
    # AND the optimizer hears the cheap objective of those screened out, in a resumed run too
    out = list(second)[-1]
    assert screen.told(out) == 31.0 and screen.summary()["ranked_by_cheap"] == 12
    resumed = Screen(settings, SequentialExecutor(), Store(tmp_path / "c.db"), run_id, 8, tmp_path, RunOptions(), space)
    assert resumed.choose([(key, x) for key, (x, _c) in second.items()]) == chosen and resumed.told(out) == 31.0


# A screened PX4 campaign's identity as stored (CampaignConfig._identity), what --screen-learn-from compares.
PX4_SCREENED = {"profile": "sha256:profile", "drive": "pilot", "sut": "px4", "sut_params": {}, "sut_build": "sha256:build-1",
                "screen": {"sut": {"name": "bundled", "params": {"CP_STICK_ACCEL": 1}}, "share": 0.3}}


def earlier_campaign(path: Path, space: SearchSpace, xs: list[np.ndarray], identity: dict, scenario_key: str = "sha256:s") -> Path:
    """A store of a finished screened campaign that flew these candidates both ways, all alike on
    the cheap model (3 m), the subject parting from it by where the candidate lies."""
    with Store(path) as store:
        run_id, _finished = store.run(store.campaign(identity), "s.json", "s", "NSGAII", 0, 3, scenario_key=scenario_key)
        for i, x in enumerate(xs):
            store.add_screen_flight(run_id, vector_key(x), cheap_flight(3.0))
            store.add_evaluation(run_id, ordinal=i, step=0, optimizer="NSGAII", vector=x, result=stored_result(parted(space, x, 3.0), "ok"), concrete=None)
    return path


def learn_from(store: Store, ours: dict, paths: list[Path]) -> dict[str, int]:
    """As a campaign begins: the other stores' pairs checked, then kept in the store."""
    for source, pairs in pairs_to_learn(store, ours, {"sha256:s"}, [str(path) for path in paths]).items():
        store.learn_screen_pairs(source, pairs)
    return store.screen_sources()


def test_a_correction_learns_from_an_earlier_campaigns_store_of_the_same_subject_and_keeps_what_it_learned(tmp_path, space):
    # GIVEN an earlier screened campaign of the same PX4 build, drive and profile (another algorithm and seed)
    xs = spread_over(space, 52, seed=2)
    earlier = earlier_campaign(tmp_path / "earlier.db", space, xs[:12], PX4_SCREENED)
    # WHEN a new campaign begins learning from its store
    ours = {**PX4_SCREENED, "algorithms": ["RANDOM"], "seed": 9}
    store = Store(tmp_path / "new.db")
    assert learn_from(store, ours, [earlier]) == {str(earlier.resolve()): 12}
    run_id, _finished = store.run(store.campaign(ours), "s.json", "s", "RANDOM", 0, 9, scenario_key="sha256:s")
    first, second = ({f"k{i}": x for i, x in enumerate(xs[start:start + 20], start)} for start in (12, 32))
    for key in {**first, **second}:
        store.add_screen_flight(run_id, key, cheap_flight(3.0))
    settings = ScreenSettings(SutConfig(), share=0.25, explore=0.0)
    screen = Screen(settings, SequentialExecutor(), store, run_id, 9, tmp_path, RunOptions(), space)
    # THEN its first batch is already ranked by what the subject did there, which the cheap flights cannot tell apart
    real = {key: parted(space, x, 3.0) for key, x in {**first, **second}.items()}
    assert screen.choose(list(first.items())) == set(sorted(first, key=real.get)[:5])
    assert screen.summary()["training_pairs"] == screen.summary()["learned_pairs"] == 12
    # AND with the other store gone, the campaign resumed learns from what it copied: its next batch is ranked alike
    earlier.unlink()
    assert learn_from(store, ours, [earlier]) == {str(earlier.resolve()): 12}
    resumed = Screen(settings, SequentialExecutor(), Store(tmp_path / "new.db"), run_id, 9, tmp_path, RunOptions(), space)
    assert resumed.summary()["learned_pairs"] == 12
    assert resumed.choose(list(second.items())) == set(sorted(second, key=real.get)[:5])
    # AND a campaign that has begun learns from no new store
    later = earlier_campaign(tmp_path / "later.db", space, xs[:12], PX4_SCREENED)
    with pytest.raises(InputError, match="began learning from .*earlier.db, and learns from no store it did not begin with .* leave out "
                                         "--screen-learn-from to resume it, or start a new --store"):
        learn_from(store, ours, [later])


@pytest.mark.parametrize("identity, scenario_key, why", [
    ({**PX4_SCREENED, "sut_build": "sha256:build-2"}, "sha256:s", "its campaign flew other flights .sut_build 'sha256:build-2' where this campaign has 'sha256:build-1'."),
    ({**PX4_SCREENED, "drive": "mission"}, "sha256:s", "drive 'mission' where this campaign has 'pilot'"),
    ({**PX4_SCREENED, "screen": {"sut": {"name": "bundled", "params": {}}}}, "sha256:s", "another cheap model"),
    ({k: v for k, v in PX4_SCREENED.items() if k != "screen"}, "sha256:s", "its campaign was not screened"),
    (PX4_SCREENED, "sha256:another-scenario", "has no candidate flown both ways of this campaign's scenarios"),
])
def test_a_store_of_other_flights_is_refused_naming_it_and_why_and_read_only(tmp_path, space, identity, scenario_key, why):
    other = earlier_campaign(tmp_path / "other.db", space, spread_over(space, 6), identity, scenario_key)
    before = other.read_bytes()
    with Store(tmp_path / "new.db") as store:
        with pytest.raises(InputError, match=f"--screen-learn-from: {other}: .*{why}"):
            learn_from(store, PX4_SCREENED, [other])
        with pytest.raises(InputError, match="is this campaign's own store"):
            learn_from(store, PX4_SCREENED, [tmp_path / "new.db"])
        with pytest.raises(InputError, match=f"--screen-learn-from: {tmp_path / 'gone.db'}: no such campaign store"):
            learn_from(store, PX4_SCREENED, [tmp_path / "gone.db"])
        assert store.screen_sources() == {} and not store.runs()
    assert other.read_bytes() == before


def test_the_cheap_model_takes_the_subjects_px4_parameters_calibrated_by_drive_and_never_its_seeded_fault():
    # PX4's collision prevention as it acts: on the pilot's sticks' acceleration, and not in missions
    assert screen_sut(SutConfig("px4", {"CP_DIST": 2.0, "MPC_XY_CRUISE": 4.0}, px4_bin="/x"), "pilot") == SutConfig(
        "bundled", {"CP_DIST": 2.0, "MPC_XY_CRUISE": 4.0, "CP_STICK_ACCEL": 1})
    assert screen_sut(SutConfig("px4", {"CP_DIST": 2.0}, px4_bin="/x"), "mission") == SutConfig("bundled", {"CP_DIST": -1.0})
    assert screen_sut(SutConfig("bundled", {"CP_DIST": 2.0}, fault="cp_ignores_delay"), "mission") == SutConfig("bundled", {"CP_DIST": 2.0})


def test_an_ardupilot_subject_is_screened_by_the_bundled_autopilot_with_its_counterparts_of_arducopters_parameters():
    loiter = screen_sut(SutConfig("ardupilot", {"AVOID_MARGIN": 3.0, "LOIT_SPEED": 500, "FS_GCS_ENABLE": 1}), "pilot").params
    # simple avoidance's margin in Loiter, its speed and acceleration in m/s, the GCS failsafe's RTL acting at once
    assert (loiter["CP_DIST"], loiter["MPC_VEL_MANUAL"], loiter["MPC_ACC_HOR"]) == (3.0, 5.0, 5.0)
    assert (loiter["NAV_DLL_ACT"], loiter["COM_FAIL_ACT_T"], loiter["MPC_TILTMAX_AIR"]) == (2, 0.0, 30.0)
    # the adapter's margin (1 m) over ArduCopter's (2 m); avoidance that stops has no guidance; no proximity, no avoidance
    assert screen_sut(SutConfig("ardupilot", {"AVOID_BEHAVE": 1}), "pilot").params["CP_DIST"] == 1.0
    assert screen_sut(SutConfig("ardupilot", {"AVOID_BEHAVE": 1}), "pilot").params["CP_GUIDE_ANG"] == 0.0
    assert screen_sut(SutConfig("ardupilot", {"AVOID_ENABLE": 1}), "pilot").params["CP_DIST"] == -1.0
    # Auto avoids nothing without a path planner, and keeps the planner's margin with one
    assert screen_sut(SutConfig("ardupilot", {}), "mission").params["CP_DIST"] == -1.0
    assert screen_sut(SutConfig("ardupilot", {"OA_TYPE": 1, "OA_MARGIN_MAX": 3.0}), "mission").params["CP_DIST"] == 3.0
    # every counterpart is a parameter the bundled autopilot models, within its range
    from autopilot.params import BY_NAME

    for drive in ("pilot", "mission"):
        for name, value in screen_sut(SutConfig("ardupilot", {"FS_GCS_ENABLE": 5}), drive).params.items():
            assert BY_NAME[name].min <= value <= BY_NAME[name].max, name


def test_an_ardupilot_campaign_of_both_drives_is_not_screened_with_one_mapping(tmp_path, capsys):
    pilot = tmp_path / "pilot.json"
    document = json.loads(Path(WALL).read_text())
    pilot.write_text(json.dumps({**document, "mission": {**document.get("mission", {}), "drive": "pilot"}}))
    # an executable where the build should be: the options are refused before anything would run it
    (tmp_path / "bin").mkdir()
    (tmp_path / "bin" / "arducopter").write_text("#!/bin/sh\nexit 1\n")
    (tmp_path / "bin" / "arducopter").chmod(0o755)
    assert main(["campaign", WALL, str(pilot), "--algorithm", "RANDOM", "--evaluations", "2", "--sut", "ardupilot", "--ardupilot-bin", str(tmp_path),
                 "--screen", "bundled", "--store", str(tmp_path / "c.db")]) == 2
    assert "--screen: configures the cheap model by drive, as ardupilot's collision avoidance acts on the pilot's sticks" in capsys.readouterr().err


def screened_campaign(tmp_path: Path, capsys, store: Path) -> dict:
    capsys.readouterr()
    assert main(["campaign", WALL, "--algorithm", "RANDOM", "--evaluations", "8", "--batch", "8", "--seed", "4", "--workers", "2",
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
    # (an infeasible candidate flies nothing: it is no flight of the subject's, and not stored)
    assert run["evaluations"] == run["flown"] == len(flown) == len(real) == 8
    screen = run["screen"]
    # THEN more candidates were judged than the subject flew, each flown for real was chosen by the screen
    assert screen["flights"] > len(flown) and screen["screened_out"] > 0
    with sqlite3.connect(tmp_path / "a.db") as db:
        chosen = {key for key, in db.execute("SELECT vector_key FROM screen_flights WHERE chosen = 1")}
        cheap = dict(db.execute("SELECT vector_key, fitness FROM screen_flights"))
    assert {key for key, _status, _fitness in flown} <= chosen
    assert screen["pairs"] == len(flown) and screen["false_negatives"] == sum(f < 0 <= cheap[k] for k, _s, f in flown)
    # AND once five were flown both ways, the correction trained on them predicted the rest
    with sqlite3.connect(tmp_path / "a.db") as db:
        predicted = db.execute("SELECT COUNT(*) FROM screen_flights WHERE predicted_mean IS NOT NULL").fetchone()[0]
    assert screen["training_pairs"] == len(flown) >= 5 and predicted > 0
    # AND compare counts the SUT's flights and the cheap model's apart
    capsys.readouterr()
    assert main(["compare", str(tmp_path / "a.db"), "--json"]) == 0
    overall = json.loads(capsys.readouterr().out)["overall"][0]
    assert (overall["flown"], overall["screen_flights"]) == (len(flown), screen["flights"])
    # AND the same seed gives the same campaign, flown in full or killed half way and resumed
    assert screened_campaign(tmp_path, capsys, tmp_path / "b.db")["screen"] == screen
    assert real_flights(tmp_path / "b.db") == real
    with sqlite3.connect(tmp_path / "b.db") as db:
        db.execute("DELETE FROM evaluations WHERE ordinal >= 4")
        db.execute("UPDATE runs SET finished = NULL")
    resumed = screened_campaign(tmp_path, capsys, tmp_path / "b.db")
    assert resumed["replayed"] == 4 and real_flights(tmp_path / "b.db") == real and resumed["screen"] == screen


@pytest.mark.slow
def test_a_differential_campaign_is_screened_once_the_correction_has_learned_what_the_cheap_clearance_means_for_the_difference(tmp_path, capsys):
    # GIVEN a subject with the seeded fault against the bundled autopilot without it, searched for
    # the difference of their clearances, which one cheap flight's clearance does not measure
    store = tmp_path / "d.db"
    assert main(["campaign", WALL, "--algorithm", "RANDOM", "--evaluations", "12", "--batch", "6", "--seed", "5", "--workers", "2",
                 "--sut-fault", "cp_ignores_delay", "--reference-sut", "bundled", "--objective", "difference",
                 "--screen", "bundled", "--store", str(store), "--json"]) == 0
    screen = json.loads(capsys.readouterr().out)["runs"][0]["screen"]
    with sqlite3.connect(store) as db:
        decided = db.execute("SELECT chosen, predicted_mean IS NOT NULL FROM screen_flights WHERE chosen IS NOT NULL ORDER BY created").fetchall()
        pairs = db.execute("SELECT COUNT(*) FROM evaluations WHERE differential IS NOT NULL").fetchone()[0]
        flown = db.execute("SELECT COUNT(*) FROM evaluations WHERE status != 'infeasible'").fetchone()[0]
    # THEN every candidate was flown as a pair until the correction was trained, and only then screened
    untrained = [chosen for chosen, predicted in decided if not predicted]
    assert untrained and all(untrained)
    assert any(predicted and not chosen for chosen, predicted in decided)
    assert pairs == flown and screen["pairs"] == flown and screen["corrected_rank_correlation"] is not None


@pytest.mark.slow
def test_a_campaign_that_learns_from_an_earlier_campaigns_store_ranks_its_first_batch_by_the_correction_and_resumes_alike(tmp_path, capsys):
    # GIVEN an earlier screened campaign of the faulted subject
    screened_campaign(tmp_path, capsys, tmp_path / "a.db")
    with Store.existing(tmp_path / "a.db") as earlier:
        taught = len(earlier.flown_both_ways())

    def learning(store: Path) -> dict:
        capsys.readouterr()
        assert main(["campaign", WALL, "--algorithm", "NSGAII", "--evaluations", "8", "--population", "8", "--batch", "8", "--seed", "6",
                     "--workers", "2", "--sut-fault", "cp_ignores_delay", "--screen", "bundled", "--screen-share", "0.25",
                     "--screen-learn-from", str(tmp_path / "a.db"), "--store", str(store), "--json"]) == 0
        return json.loads(capsys.readouterr().out)["runs"][0]

    # WHEN another campaign of the same subject (another algorithm and seed) learns from its store
    run = learning(tmp_path / "c.db")
    # THEN its correction was trained on the earlier flights before its own first batch was decided
    assert run["screen"]["learned_pairs"] == taught >= 5 and run["screen"]["training_pairs"] >= taught
    with sqlite3.connect(tmp_path / "c.db") as db:
        first_batch = db.execute("SELECT predicted_mean IS NOT NULL FROM screen_flights WHERE chosen IS NOT NULL ORDER BY created LIMIT 8").fetchall()
    assert first_batch and all(predicted for predicted, in first_batch)
    real = real_flights(tmp_path / "c.db")
    # AND killed half way and resumed with the earlier store gone, it flies the same flights
    (tmp_path / "a.db").rename(tmp_path / "moved.db")
    with sqlite3.connect(tmp_path / "c.db") as db:
        db.execute("DELETE FROM evaluations WHERE ordinal >= 4")
        db.execute("UPDATE runs SET finished = NULL")
    capsys.readouterr()
    assert main(["campaign", WALL, "--algorithm", "NSGAII", "--evaluations", "8", "--population", "8", "--batch", "8", "--seed", "6",
                 "--workers", "2", "--sut-fault", "cp_ignores_delay", "--screen", "bundled", "--screen-share", "0.25",
                 "--store", str(tmp_path / "c.db"), "--json"]) == 0
    resumed = json.loads(capsys.readouterr().out)["runs"][0]
    assert real_flights(tmp_path / "c.db") == real and resumed["screen"] == run["screen"]
    # AND without a screen to teach, the option is refused
    assert main(["campaign", WALL, "--algorithm", "RANDOM", "--evaluations", "2", "--screen-learn-from", str(tmp_path / "moved.db"),
                 "--store", str(tmp_path / "d.db")]) == 2
    assert "--screen-learn-from: teaches the screen's learned correction: give --screen bundled" in capsys.readouterr().err
