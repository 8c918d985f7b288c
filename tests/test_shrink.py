"""`stella shrink`: a violating case made as small and simple as it can be while it still violates,
flown for real against the bundled stack."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT, stored_result
from harness.campaigns.regression import load_regression
from harness.campaigns.shrink import Flight, Journal, State, key_of
from harness.campaigns.shrink_steps import STEPS, checked, elements, neutral_value, round_steps, space_of
from harness.campaigns.store import Store
from harness.errors import InputError
from harness.scenario.logical import load_logical
from harness.scenario.space import SearchSpace
from harness.tools.cli import main

DATA = ROOT / "tests" / "data" / "scenarios"
# A head-on intruder that meets the UAV (tests/test_richer_flights.py), two small buildings well
# off the route and a light wind: only the intruder makes the violation.
AMONG_BUILDINGS = {
    "wind_speed_m_s": 0.83, "wind_from_deg": 123.4, "temperature_c": 21.7,
    "obstacle_1.length_m": 3.2, "obstacle_1.width_m": 2.1, "obstacle_1.height_m": 4.4, "obstacle_1.north_m": 70.5, "obstacle_1.east_m": 22.3,
    "obstacle_1.yaw_deg": 33.0,
    "obstacle_2.closest_approach_s": 8.0, "obstacle_2.crossing_deg": 180.0, "obstacle_2.closing_speed_m_s": 10.0, "obstacle_2.vertical_offset_m": 0.0,
    "obstacle_3.diameter_m": 2.5, "obstacle_3.height_m": 3.0, "obstacle_3.north_m": -12.0, "obstacle_3.east_m": -24.0,
}


def concrete_file(tmp_path, profile, scenario: str = "intruder_among_buildings.json", values=AMONG_BUILDINGS):
    space = SearchSpace(load_logical(DATA / scenario, profile), profile)
    x = space.vector_from(values)
    assert space.violations(x) == []
    path = tmp_path / "among_buildings.json"
    path.write_text(json.dumps(space.to_concrete(x), indent=2))
    return path


def shrink_command(case, out) -> list[str]:
    return ["shrink", str(case), "--out", str(out), "--json"]


def shrink(case, out, capsys) -> dict:
    assert main(shrink_command(case, out)) == 0
    return json.loads(capsys.readouterr().out)


@pytest.fixture(scope="module")
def among_buildings(tmp_path_factory, profile):
    """The case and its shrink, flown once for the tests below."""
    folder = tmp_path_factory.mktemp("among")
    case = concrete_file(folder, profile)
    completed = subprocess.run([sys.executable, "-m", "harness.tools.cli", *shrink_command(case, folder / "out")], cwd=ROOT,
                               capture_output=True, text=True, timeout=600)
    assert completed.returncode == 0, completed.stderr[-2000:]
    return case, json.loads(completed.stdout)


@pytest.mark.slow
def test_bystander_obstacles_and_wind_are_shrunk_away_and_the_intruder_still_violates(among_buildings, tmp_path, capsys):
    _case, report = among_buildings
    assert report["before"]["elements"]["obstacles"] == 3
    after = report["after"]["elements"]
    assert (after["obstacles"], after["by_kind"], after["wind_speed_m_s"]) == (1, {"intruder": 1}, 0.0)
    assert report["after"]["fitness"] < 0.0
    assert report["kept"][0]["description"].startswith("keep only obstacle_2 (intruder cuboid)")
    shrunk = json.loads(open(report["concrete"]).read())
    # GIVEN the shrunk case WHEN it is flown again THEN it violates, as its regression case says it did
    assert main(["run", "--concrete", report["concrete"], "--cores", "1", "--out", str(tmp_path), "--json"]) == 0
    flown = json.loads(capsys.readouterr().out)
    assert flown["status"] == "violation" and flown["fitness"] == report["after"]["fitness"]
    case = load_regression(Path(report["regression"]))
    assert (case.expect, case.seed, case.sut.name, dict(case.concrete)) == ("safe", 0, "bundled", shrunk)
    assert case.found["fitness_before_shrinking"] == report["before"]["fitness"]
    assert os.path.isfile(report["log"]) and not os.path.exists(os.path.join(os.path.dirname(report["concrete"]), "among_buildings-shrunk-flights"))


@pytest.mark.slow
def test_the_bundled_stack_shrinks_the_same_case_to_the_same_result_twice(among_buildings, tmp_path, capsys):
    case, first = among_buildings
    second = shrink(case, tmp_path / "again", capsys)
    assert open(second["concrete"]).read() == open(first["concrete"]).read()
    assert second["steps"] == first["steps"]


@pytest.mark.slow
def test_a_killed_shrink_resumes_from_its_journal_and_ends_where_an_uninterrupted_one_does(among_buildings, tmp_path, capsys):
    case, uninterrupted = among_buildings
    out = tmp_path / "killed"
    journal = out / "among_buildings-shrunk.journal.jsonl"
    command = [sys.executable, "-m", "harness.tools.cli", *shrink_command(case, out)]
    killed = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and killed.poll() is None:
        if journal.is_file() and len(journal.read_text().splitlines()) >= 3:  # the header, the case as given, one step
            break
        time.sleep(0.1)
    os.killpg(killed.pid, signal.SIGKILL)
    killed.wait()
    flown_before = journal.read_text().count("\n") - 1  # whole lines after the header
    assert 2 <= flown_before < len(uninterrupted["steps"]) + 1
    resumed = shrink(case, out, capsys)
    assert resumed["replayed"] == flown_before
    assert resumed["flown"] == len(uninterrupted["steps"]) + 1 - flown_before
    assert open(resumed["concrete"]).read() == open(uninterrupted["concrete"]).read()


@pytest.mark.slow
def test_a_case_that_does_not_violate_is_refused_naming_the_file(tmp_path, capsys):
    wall = ROOT / "scenarios" / "examples" / "wall_concrete.json"  # collision prevention stops the UAV 2 m before the wall
    assert main(["shrink", str(wall), "--out", str(tmp_path)]) == 2
    error = capsys.readouterr().err
    assert f"{wall}: does not violate the safety distance as given (flown: ok with fitness" in error
    assert not list(tmp_path.glob("*.journal.jsonl"))  # so the same case can be tried with another SUT


@pytest.mark.slow
def test_a_sut_that_cannot_fly_the_case_ends_the_shrink_as_an_infrastructure_failure(tmp_path, capsys):
    case = ROOT / "scenarios" / "examples" / "wall_concrete.json"
    assert main(["shrink", str(case), "--out", str(tmp_path), "--sut", "command", "--sut-command", "sh -c 'exit 1' {sim_port} {api_port}"]) == 3
    assert f"{case}: the case as given: a flight could not finish in 2 attempts (sut_crashed" in capsys.readouterr().err
    assert not list(tmp_path.glob("*.journal.jsonl"))  # nothing was learnt, so nothing to replay


def test_an_evaluation_not_in_the_store_or_none_given_is_refused_naming_the_store_and_option(tmp_path, capsys, profile):
    space = SearchSpace(load_logical(ROOT / "scenarios" / "examples" / "fig4.json", profile), profile)
    x = space.sample_feasible(np.random.default_rng(0), 1)[0]
    with Store(tmp_path / "c.db") as store:
        run_id, _ = store.run(store.campaign({"scenarios": ["fig4.json"], "sut": "bundled"}), "fig4.json", space.logical.name, "NSGAII", 0, 7)
        store.add_evaluation(run_id, ordinal=0, step=0, optimizer="NSGAII", vector=x, result=stored_result(-0.4, "violation", 7),
                             concrete=space.to_concrete(x))
    assert main(["shrink", str(tmp_path / "c.db"), "--evaluation", "9"]) == 2
    assert f"{tmp_path / 'c.db'}: --evaluation: no evaluation 9 in this store (it holds 1" in capsys.readouterr().err
    assert main(["shrink", str(tmp_path / "c.db")]) == 2
    assert "--evaluation: " in capsys.readouterr().err
    assert main(["shrink", str(ROOT / "scenarios" / "examples" / "wall_concrete.json"), "--evaluation", "1"]) == 2
    assert "is not a campaign store" in capsys.readouterr().err
    assert main(["shrink", str(ROOT / "scenarios" / "examples" / "wall.json")]) == 2
    assert "wall.json: /format: not a concrete scenario" in capsys.readouterr().err


def test_the_steps_remove_the_most_first_and_each_is_a_valid_smaller_scenario(tmp_path, profile):
    document = checked(json.loads(concrete_file(tmp_path, profile).read_text()))
    state = State(document, [Flight("violation", -1.1, -0.1, "obstacle_2", None)])  # the violation was against the intruder
    candidates = [candidate for family in STEPS for candidate in family(state)]
    assert [c.description for c in candidates[:4]] == [
        "keep only obstacle_2 (intruder cuboid), drop the other 2", "drop obstacle_3 (static cylinder)", "drop obstacle_2 (intruder cuboid)",
        "drop obstacle_1 (static cuboid)"]
    assert candidates[4].description.startswith("calm the wind: 0.83 m/s -> 0 m/s (none)")
    for candidate in candidates:
        assert checked(candidate.document) == candidate.document  # a concrete scenario as `stella run --concrete` takes it
        assert elements(candidate.document)["searched_values"] <= elements(document)["searched_values"]
    neutral = {d.name: neutral_value(d) for d in space_of(document).dimensions}
    assert neutral["wind_speed_m_s"] == pytest.approx(1.0 / 3.6) and neutral["temperature_c"] == 15.0 and neutral["obstacle_1.north_m"] is None
    # A value at its neutral value is left there: rounding 0.2778 m/s (1 km/h) would lead away from it.
    state.current = checked({**document, "environment": {**document["environment"], "wind_speed_m_s": neutral["wind_speed_m_s"]}})
    rounding = [c.description for c in round_steps(state)]
    assert rounding and not any("wind_speed_m_s" in text for text in rounding)


def test_a_journal_cut_mid_line_keeps_its_whole_lines_and_a_foreign_one_is_refused(tmp_path):
    header = {"format": "stella.shrink-journal/1", "start": "abc", "seed": 0, "sut": {"name": "bundled", "params": {}}, "confirm": 1}
    journal = Journal(tmp_path / "j.jsonl", header)
    journal.record("k1", "drop obstacle_1", [])
    with open(tmp_path / "j.jsonl", "a") as handle:
        handle.write('{"key": "k2", "step": "drop obst')  # killed while writing
    reopened = Journal(tmp_path / "j.jsonl", header)
    assert reopened.flights("k1") == [] and reopened.flights("k2") is None
    reopened.record("k2", "drop obstacle_2", [])
    assert Journal(tmp_path / "j.jsonl", header).flights("k2") == []
    with pytest.raises(InputError, match="j.jsonl: the journal of another shrink"):
        Journal(tmp_path / "j.jsonl", {**header, "confirm": 3})
    assert key_of({"a": 1, "b": 2}) == key_of({"b": 2, "a": 1})
