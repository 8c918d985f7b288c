"""Campaigns: optimizer determinism, sequences, termination, the store's resume after a full disk (after kill -9: test_cleanup.py), statistics."""

from __future__ import annotations

import json
import random
import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT, stored_result
from harness.campaigns.campaign import least_explored, run_sequence
from harness.campaigns.problem import CampaignProblem
from harness.campaigns.shrink import load_case
from harness.campaigns.statistics import a12, compare, p_value, relative_performance, spread, table
from harness.campaigns.store import Store
from harness.errors import InputError
from harness.scenario.logical import load_logical
from harness.scenario.space import SearchSpace
from harness.search.optimizers import OPTIMIZERS, _OwnStreams, nsgaii, parse_algorithm, smpso
from jmetal.util.evaluator import Evaluator
from jmetal.util.termination_criterion import StoppingByEvaluations

from harness.search.termination import AllOf, AnyOf, EvaluationBudget, FirstViolation, Progress, WallTimeBudget
from harness.tools.cli import main

SCENARIO = ROOT / "scenarios" / "table3" / "scenario_16.json"  # one dynamic obstacle: 12 dimensions


class AnalyticExecutor:
    """Stands in for the simulator in optimizer-only tests: fitness is the distance of the obstacle's
    start from a fixed point, violation below 2 m. The product never uses it."""

    name = "analytic"

    def __init__(self, draws_from_global_streams: bool = False):
        self.draws_from_global_streams = draws_from_global_streams

    def run(self, jobs):
        for job in jobs:
            if self.draws_from_global_streams:  # as a Dask client or a process pool may, between generations
                random.random()
                np.random.random(3)
            position = job.concrete["obstacles"][0]["position"]
            d = float(np.hypot(position["north_m"] - 30.0, position["east_m"] - 3.0)) - 2.0
            yield job, stored_result(d, "violation" if d < 0 else "ok", job.seed)

    def close(self):
        pass


@pytest.fixture
def space(profile):
    return SearchSpace(load_logical(SCENARIO, profile), profile)


def candidates(space, tmp_path, combination, seed, budget=20, name="store.db", executor=None, population=6):
    with Store(tmp_path / name) as store:
        campaign = store.campaign({"test": combination, "seed": seed, "name": name})
        run_id, _ = store.run(campaign, str(SCENARIO), "s", combination, 0, seed)
        problem = CampaignProblem(space, store, run_id, executor or AnalyticExecutor(), seed, EvaluationBudget(budget), tmp_path)
        run_sequence(combination, problem, budget=budget, seed=seed, population=population, batch=2)
        rows = store.db.execute("SELECT ordinal, vector, fitness FROM evaluations WHERE run_id = ? ORDER BY ordinal", (run_id,)).fetchall()
    return rows, problem


@pytest.mark.slow
# BO's suggestions cost seconds each (its acquisition is maximised from ten L-BFGS-B starts with
# numerical gradients), so its budget ends three suggestion batches after its initial set.
@pytest.mark.parametrize(("combination", "budget"), [("N", 20), ("P", 20), ("B", 12), ("R", 20), ("NPB", 20)])
def test_same_seed_same_candidates_and_the_budget_holds(space, tmp_path, combination, budget):
    first, problem = candidates(space, tmp_path, combination, seed=3, budget=budget, name="a.db")
    second, _ = candidates(space, tmp_path, combination, seed=3, budget=budget, name="b.db")
    # Another seed draws another first population already: searching on would show nothing more.
    other, _ = candidates(space, tmp_path, combination, seed=4, budget=6, name="c.db")
    assert first == second
    assert [r[1] for r in first[:6]] != [r[1] for r in other]
    assert len(first) == budget and [r[0] for r in first] == list(range(budget))
    assert problem.best.fitness == min(r[2] for r in first)


def bowl(x: np.ndarray, space) -> float:
    """A smooth stand-in fitness over the unit cube of the space."""
    return float(np.sum(((x - space.lower) / np.where(space.upper > space.lower, space.upper - space.lower, 1.0) - 0.3) ** 2))


@pytest.mark.parametrize(("letter", "make"), [("N", nsgaii), ("P", smpso)])
def test_the_ask_tell_search_asks_what_jmetalpys_own_run_loop_evaluates(space, letter, make):
    population, generations, seed = 6, 5, 11
    initial = list(space.sample(np.random.default_rng(1), 2))
    evaluated: list[np.ndarray] = []

    class Recording(Evaluator):
        def evaluate(self, solution_list, problem):
            for solution in solution_list:
                x = np.array(solution.variables, dtype=float)
                evaluated.append(x)
                solution.objectives[0] = bowl(x, space)
            return solution_list

    algorithm = make(space, population, initial)
    algorithm.termination_criterion = StoppingByEvaluations(max_evaluations=population * generations)
    algorithm.observable.register(algorithm.termination_criterion)  # it learns the evaluations as an observer
    if letter == "N":
        algorithm.population_evaluator = Recording()
    else:
        algorithm.swarm_evaluator = Recording()
    with _OwnStreams(seed).installed():
        algorithm.run()

    search = OPTIMIZERS[letter].start(space, seed=seed, population=population, batch=4, initial=initial)
    asked: list[np.ndarray] = []
    while len(asked) < len(evaluated):
        vectors = search.ask()
        asked += vectors
        search.tell(vectors, [bowl(x, space) for x in vectors])
    assert len(evaluated) == population * generations
    assert all(np.array_equal(a, b) for a, b in zip(asked, evaluated))


def test_nsga2_runs_with_an_odd_population(space, tmp_path):
    rows, _problem = candidates(space, tmp_path, "N", seed=1, budget=12, population=5)
    assert [r[0] for r in rows] == list(range(12))


@pytest.mark.slow
@pytest.mark.parametrize("combination", ["N", "P", "B", "PNP"])
def test_draws_from_the_global_random_streams_between_generations_do_not_change_the_candidates(space, tmp_path, combination):
    quiet, _ = candidates(space, tmp_path, combination, seed=3, budget=14, name="quiet.db")
    random.seed(99)
    np.random.seed(99)
    stirred, _ = candidates(space, tmp_path, combination, seed=3, budget=14, name="stirred.db", executor=AnalyticExecutor(draws_from_global_streams=True))
    assert stirred == quiet


@pytest.mark.slow
def test_a_sequence_improves_on_its_seeds_and_reports_the_lowest_fitness(space, tmp_path):
    rows, problem = candidates(space, tmp_path, "RN", seed=1, budget=40)
    first_half = min(r[2] for r in rows[:20])
    assert problem.best.fitness <= first_half
    assert problem.best.fitness == min(r[2] for r in rows)


def test_termination_objects_combine():
    progress = Progress(evaluations=10, elapsed_s=5.0, violations=0)
    assert EvaluationBudget(10).done(progress) and not EvaluationBudget(11).done(progress)
    assert WallTimeBudget(4.0).done(progress) and not FirstViolation().done(progress)
    assert AnyOf((EvaluationBudget(100), WallTimeBudget(4.0))).done(progress)
    assert not AllOf((EvaluationBudget(100), WallTimeBudget(4.0))).done(progress)
    assert FirstViolation().done(Progress(1, 0.0, 1))


def test_a_time_budget_takes_no_candidate_into_a_batch_that_it_could_not_fly_in_time():
    # 2 s a candidate so far, 5 s of 12 spent: three more fit (the third done at 11 s), a fourth does not
    assert not WallTimeBudget(12.0).done(Progress(10, 5.0, 0, pending=0, seconds_per_candidate=2.0))
    assert not WallTimeBudget(12.0).done(Progress(10, 5.0, 0, pending=2, seconds_per_candidate=2.0))
    assert WallTimeBudget(12.0).done(Progress(10, 5.0, 0, pending=3, seconds_per_candidate=2.0))
    # before any batch has flown, the time spent alone decides
    assert not WallTimeBudget(12.0).done(Progress(0, 5.0, 0, pending=40))


def test_stop_at_first_violation_ends_the_run(space, tmp_path):
    with Store(tmp_path / "v.db") as store:
        run_id, _ = store.run(store.campaign({"v": 1}), str(SCENARIO), "s", "R", 0, 0)
        problem = CampaignProblem(space, store, run_id, AnalyticExecutor(), 0, AnyOf((EvaluationBudget(5000), FirstViolation())), tmp_path)
        run_sequence("R", problem, budget=5000, seed=0, population=6, batch=1)
        assert problem.violations == 1 and problem.spent < 5000


def test_least_explored_points_keep_away_from_what_was_evaluated(space):
    rng = np.random.default_rng(0)
    evaluated = list(space.sample(rng, 50))
    chosen = least_explored(space, evaluated, 5, rng)
    span = space.upper - space.lower
    def gap(x):
        return min(np.linalg.norm((x - e) / span) for e in evaluated)
    random_gaps = sorted(gap(x) for x in space.sample(rng, 200))
    assert min(gap(x) for x in chosen) > random_gaps[len(random_gaps) // 2]


def test_algorithm_names_and_combinations_parse():
    assert parse_algorithm("nsgaii") == "N" and parse_algorithm("BO") == "B" and parse_algorithm("pnb") == "PNB"
    with pytest.raises(ValueError, match="unknown algorithm"):
        parse_algorithm("NXP")


def test_statistics_match_hand_computed_values():
    assert a12([1, 2, 3], [4, 5, 6]) == 1.0
    assert a12([1, 5], [2, 5]) == pytest.approx(2.5 / 4)  # 1<2 and 1<5 win, 5>2 loses, 5=5 counts half
    assert relative_performance(-2.0, -1.0) == pytest.approx(100.0)  # twice as deep a violation
    assert relative_performance(1.5, 1.0) == pytest.approx(-50.0)
    assert p_value([1, 2, 3], [4, 5, 6]) == pytest.approx(0.1)  # exact two-sided Mann-Whitney U, n = 3 + 3


def test_the_spread_of_repeats_says_how_many_violated_and_whether_that_is_flaky():
    def flight(status, fitness):
        return stored_result(fitness, status, min_clearance_m=fitness + 1.0)

    flaky = spread([flight("violation", -0.001), flight("ok", 0.002), flight("violation", -0.003)])
    assert (flaky["repeats"], flaky["violations"], flaky["flaky"]) == (3, 2, True)
    assert flaky["fitness"] == {"min": -0.003, "median": -0.001, "max": 0.002} and flaky["statuses"] == {"ok": 1, "violation": 2}
    steady = spread([flight("violation", -0.5)] * 2 + [stored_result(1e6, "sut_crashed")])
    assert not steady["flaky"] and steady["fitness"] == {"min": -0.5, "median": -0.5, "max": -0.5}  # a crash is no flight to spread


def test_compare_lays_out_median_best_fitness_per_scenario_and_overall(tmp_path):
    with Store(tmp_path / "c.db") as store:
        campaign = store.campaign({"c": 1})
        for algorithm, bests in (("NSGAII", [1.0, 2.0, 3.0]), ("BO", [4.0, 5.0, 6.0])):
            for index, best in enumerate(bests):
                run_id, _ = store.run(campaign, "s.json", "s", algorithm, index, index)
                store.add_evaluation(run_id, ordinal=0, step=0, optimizer=algorithm, vector=np.array([best]), result=stored_result(best, "ok"), concrete=None)
        report = compare(store, "NSGAII")
    bo = next(r for r in report["scenarios"] if r["algorithm"] == "BO")
    assert bo["median_best_fitness"] == 5.0 and bo["relative_performance_pct"] == pytest.approx(-150.0)
    assert bo["a12"] == 0.0 and bo["p_value"] == pytest.approx(0.1)


def test_compare_counts_the_violations_that_did_not_come_back_in_every_re_flight(tmp_path):
    with Store(tmp_path / "c.db") as store:
        run_id, _ = store.run(store.campaign({"c": 1}), "s.json", "s", "NSGAII", 0, 0)
        for ordinal, reproduced in enumerate((2, 1, None)):
            confirmations = {"repeats": 2, "violations": reproduced} if reproduced is not None else None
            store.add_evaluation(run_id, ordinal=ordinal, step=0, optimizer="NSGAII", vector=np.array([float(ordinal)]),
                                 result=stored_result(-0.1 * (ordinal + 1), "violation", confirmations=confirmations), concrete=None)
        report = compare(store, "NSGAII")
    assert (report["overall"][0]["violations"], report["overall"][0]["flaky"]) == (3, 1)
    assert "NSGAII 1 of its 3 violations did not come back" in table(report)


def test_compare_counts_the_violations_that_touched_an_obstacle_as_contacts(tmp_path):
    # GIVEN violations that passed 0.5 m from an obstacle, touched it, and went into it
    with Store(tmp_path / "c.db") as store:
        run_id, _ = store.run(store.campaign({"c": 1}), "s.json", "s", "NSGAII", 0, 0)
        for ordinal, clearance in enumerate((0.5, 0.0, -0.3, 2.0)):
            status = "violation" if clearance < 1.0 else "ok"
            store.add_evaluation(run_id, ordinal=ordinal, step=0, optimizer="NSGAII", vector=np.array([float(ordinal)]),
                                 result=stored_result(clearance - 1.0, status, min_clearance_m=clearance), concrete=None)
        report = compare(store, "NSGAII")
    # THEN three violations, two of them contacts, per scenario and overall
    assert (report["scenarios"][0]["violations"], report["scenarios"][0]["contacts"]) == (3, 2)
    assert (report["overall"][0]["violations"], report["overall"][0]["contacts"]) == (3, 2)
    header, row = table(report).splitlines()[1:3]
    assert "violations contacts" in header and row.split()[3:6] == ["-1.300", "3", "2"]  # median best f, violations, contacts


@pytest.mark.slow
def test_a_full_disk_stops_the_campaign_with_one_message_and_a_resume_loses_nothing(tmp_path, capsys, monkeypatch):
    import errno

    from harness.flight import logs

    scenario = ROOT / "tests" / "data" / "scenarios" / "one_dynamic_sphere.json"

    def command(store):
        return ["campaign", str(scenario), "--algorithm", "NSGAII", "--evaluations", "6", "--population", "2", "--executor", "sequential",
                "--store", str(store), "--json"]

    real_merge = logs.merge

    def merge_until_the_disk_is_full(recording, out, **kwargs):
        if "eval00004" in str(out):  # the disk fills up while the fourth evaluation's log is written (ids count from 1)
            raise OSError(errno.ENOSPC, "No space left on device", str(out))
        return real_merge(recording, out, **kwargs)

    store = tmp_path / "full.db"
    monkeypatch.setattr(logs, "merge", merge_until_the_disk_is_full)
    assert main(command(store)) == 2
    said = capsys.readouterr().err
    assert said.count("\n") == 1 and "No space left on device" in said and "run the same command again to resume" in said
    with sqlite3.connect(store) as db:
        before = db.execute("SELECT ordinal, vector_key, fitness, created FROM evaluations ORDER BY ordinal").fetchall()
    assert [row[0] for row in before] == [0, 1, 2]  # the fourth flight's log could not be written: it is not stored
    monkeypatch.setattr(logs, "merge", real_merge)
    assert main(command(store)) == 0
    capsys.readouterr()
    with sqlite3.connect(store) as db:
        after = db.execute("SELECT ordinal, vector_key, fitness, created FROM evaluations ORDER BY ordinal").fetchall()
    assert after[:3] == before and [row[0] for row in after] == list(range(6))
    assert main(command(tmp_path / "room.db")) == 0
    with sqlite3.connect(tmp_path / "room.db") as db:
        assert db.execute("SELECT ordinal, vector_key, fitness FROM evaluations ORDER BY ordinal").fetchall() == [row[:3] for row in after]


SPHERE = ROOT / "tests" / "data" / "scenarios" / "one_dynamic_sphere.json"


def campaign_command(scenario, store) -> list[str]:
    return ["campaign", str(scenario), "--algorithm", "RANDOM", "--evaluations", "3", "--population", "3", "--executor", "sequential",
            "--store", str(store), "--json"]


def evaluations(store) -> list[tuple]:
    with sqlite3.connect(store) as db:
        return db.execute("SELECT ordinal, vector_key, fitness FROM evaluations ORDER BY ordinal").fetchall()


def killed_before_its_last_evaluation(store) -> None:
    """What kill -9 leaves when it strikes before the last evaluation is committed."""
    with sqlite3.connect(store) as db:
        db.execute("DELETE FROM evaluations WHERE ordinal = (SELECT MAX(ordinal) FROM evaluations)")
        db.execute("DELETE FROM checkpoints")
        db.execute("UPDATE runs SET finished = NULL")


@pytest.mark.slow
def test_a_store_copied_to_another_clone_at_another_path_resumes_there(tmp_path, capsys):

    # GIVEN two clones with the same scenario at different paths, and a campaign made in the first
    here, there = tmp_path / "clone" / "scenarios", tmp_path / "elsewhere" / "other-clone" / "s"
    for folder in (here, there):
        folder.mkdir(parents=True)
        shutil.copy(SPHERE, folder / "sphere.json")
    store = tmp_path / "clone" / "c.db"
    assert main(campaign_command(here / "sphere.json", store)) == 0
    uninterrupted = evaluations(store)
    # WHEN its store, killed before its last evaluation, is copied to the other clone
    copy = tmp_path / "elsewhere" / "other-clone" / "c.db"
    shutil.copy(store, copy)
    killed_before_its_last_evaluation(copy)
    capsys.readouterr()
    # THEN the same command there resumes it: the missing evaluation flown, the others from the store
    assert main(campaign_command(there / "sphere.json", copy)) == 0
    (run,) = json.loads(capsys.readouterr().out)["runs"]
    assert (run["replayed"], run["flown"]) == (len(uninterrupted) - 1, 1)
    assert evaluations(copy) == uninterrupted
    with sqlite3.connect(copy) as db:  # where it was made is kept, as information
        assert db.execute("SELECT scenario_file FROM runs").fetchall() == [(str(here / "sphere.json"),)]
        assert json.loads(db.execute("SELECT sources FROM campaigns").fetchone()[0])["scenario_files"] == [str(here / "sphere.json")]


def test_a_resumed_run_answers_from_its_outcomes_without_holding_every_concrete_scenario(tmp_path):
    """A campaign resumed after 3,135 evaluations grew by 93 MB when the run held each stored
    evaluation's concrete scenario (30 KB), which it never reads."""
    store = tmp_path / "c.db"
    assert main(campaign_command(SPHERE, store)) == 0
    with Store.existing(store) as opened:
        [run] = opened.runs()
        resumed = opened.evaluations(run.id)
        full = {e.vector_key: e for e in opened.all_evaluations()}
    assert resumed.keys() == full.keys() and all(e.concrete is not None for e in full.values())
    assert all(e.concrete is None and e.differential is None for e in resumed.values())
    assert {k: (e.fitness, e.status, e.reveals, e.log_path) for k, e in resumed.items()} == {k: (e.fitness, e.status, e.reveals, e.log_path)
                                                                                              for k, e in full.items()}


def test_a_rebuilt_firmware_is_another_campaign_also_where_the_environment_names_it(tmp_path, monkeypatch):
    """A developer rebuilds PX4 with a fix and runs the same command on the same store: the store
    must not replay the old build's flights as the new one's. Stores made before builds named by
    STELLA_PX4_BIN counted resume once more, and are known with their build from then on."""
    from harness.campaigns.campaign import CampaignConfig
    from sut_adapter import SutConfig
    from test_sut_adapters import fake_px4_build

    build = fake_px4_build(tmp_path, "exit 0\n")
    monkeypatch.setenv("STELLA_PX4_BIN", str(build))
    config = CampaignConfig(scenarios=(str(SPHERE),), algorithms=("RANDOM",), evaluations=3, sut=SutConfig("px4"))
    before_builds_counted = config.legacy_identities()[1]
    assert "sut_build" not in before_builds_counted and config.identity()["sut_build"]["px4_sha256"]
    with Store(tmp_path / "c.db") as store:
        made = store.campaign(before_builds_counted)
        assert store.campaign(config.identity(), legacy=config.legacy_identities()) == made  # re-keyed with the build flown
        assert store.campaign(config.identity(), legacy=config.legacy_identities()) == made
        (build / "bin" / "px4").write_text("#!/bin/sh\n# rebuilt with the fix\nexit 0\n")
        with pytest.raises(InputError, match="SUT build"):
            store.campaign(config.identity(), legacy=config.legacy_identities())
    # The same bytes from another folder are the same build.
    moved = shutil.copytree(build, tmp_path / "moved")
    assert CampaignConfig(scenarios=(str(SPHERE),), algorithms=("RANDOM",), evaluations=3, sut=SutConfig("px4", px4_bin=str(moved))).identity() == config.identity()


@pytest.mark.slow
def test_a_store_made_when_campaigns_were_known_by_path_keeps_resuming(tmp_path, capsys):

    scenario = tmp_path / "sphere.json"
    shutil.copy(SPHERE, scenario)
    store = tmp_path / "old.db"
    assert main(campaign_command(scenario, store)) == 0
    uninterrupted = evaluations(store)
    # Made the old way: the campaign known by the scenario's absolute path and the profile's name,
    # its runs by the scenario's path, no record of where its files lay.
    old_identity = {"scenarios": [str(scenario.resolve())], "algorithms": ["RANDOM"], "evaluations": 3, "runs": 1, "seed": 0, "population": 3,
                    "profile": "default", "stop_at_violation": False, "sut": "bundled", "sut_params": {}}
    with sqlite3.connect(store) as db:
        db.execute("UPDATE campaigns SET config = ?", (json.dumps(old_identity, sort_keys=True),))
        db.execute("ALTER TABLE campaigns DROP COLUMN sources")
        db.execute("ALTER TABLE runs DROP COLUMN scenario_key")
    killed_before_its_last_evaluation(store)
    capsys.readouterr()
    assert main(campaign_command(scenario, store)) == 0
    (run,) = json.loads(capsys.readouterr().out)["runs"]
    assert (run["replayed"], run["flown"]) == (len(uninterrupted) - 1, 1)
    assert evaluations(store) == uninterrupted
    # Resumed once where it was made, it is known by content: a copy elsewhere resumes too.
    moved = tmp_path / "moved"
    moved.mkdir()
    shutil.copy(scenario, moved / "sphere.json")
    shutil.copy(store, moved / "old.db")
    killed_before_its_last_evaluation(moved / "old.db")
    assert main(campaign_command(moved / "sphere.json", moved / "old.db")) == 0
    assert evaluations(moved / "old.db") == uninterrupted


def test_an_executor_registered_by_name_is_made_by_that_name_and_listed_when_a_name_is_unknown():
    from harness.execution import registry

    registry.register("analytic", lambda workers, attempts, timeout_s, settings: AnalyticExecutor())
    try:
        assert isinstance(registry.make_executor("analytic", 1), AnalyticExecutor)
        with pytest.raises(ValueError, match="available: sequential, local, dask, docker, analytic"):
            registry.make_executor("pigeon", 1)
    finally:
        registry._REGISTRY.pop("analytic")



def test_an_evaluation_id_is_given_once_per_store_also_to_two_writers_and_after_a_kill(tmp_path):
    # GIVEN two writers of one store, and a campaign killed after it reserved ids it never stored
    first, second = Store(tmp_path / "c.db"), Store(tmp_path / "c.db")
    given = [first.new_evaluation_id(), second.new_evaluation_id(), first.new_evaluation_id()]
    first.close()
    second.close()
    # THEN no id is given twice: a log named by one always belongs to that evaluation
    with Store(tmp_path / "c.db") as resumed:
        assert given == [1, 2, 3] and resumed.new_evaluation_id() == 4


@pytest.mark.slow
def test_an_evaluation_is_one_number_in_its_log_name_its_regression_case_and_shrink(tmp_path):
    # GIVEN a campaign of two runs, so that a run's third candidate is not the store's third
    store = tmp_path / "c.db"
    assert main(["campaign", str(ROOT / "scenarios" / "examples" / "wall.json"), "--algorithm", "RANDOM", "--evaluations", "3", "--runs", "2",
                 "--store", str(store), "--workers", "2"]) == 0
    with Store.existing(store) as opened:
        stored = opened.all_evaluations()
    assert len(stored) == 6 and {e.ordinal for e in stored} == {0, 1, 2}
    # THEN each log is named by the evaluation's id in the store
    flown = [e for e in stored if e.log_path is not None]  # an infeasible candidate is not flown
    assert len(flown) >= 2 and all(Path(e.log_path).name == f"eval{e.id:05d}.mcap" for e in flown)
    # AND shrink takes that number, or the log's name, for the same evaluation
    last = max(flown, key=lambda e: e.id)
    assert load_case(store, last.id, None).found["log"] == last.log_path
    assert load_case(store, Path(last.log_path).name, None).found["evaluation"] == last.id
    # AND a regression case says the same number, in its name and in what it found
    assert main(["export-regressions", str(store), "--threshold=inf", "--out", str(tmp_path / "cases")]) == 0
    cases = list((tmp_path / "cases").glob("*.regression.json"))
    assert len(cases) == len({e.vector_key for e in stored if e.concrete is not None})
    for case in cases:
        found = json.loads(case.read_text())["found"]
        assert case.name.endswith(f"-eval{found['evaluation']:05d}.regression.json") and Path(found["log"]).name == f"eval{found['evaluation']:05d}.mcap"
