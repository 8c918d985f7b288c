"""t-wise generation covers every valid T-wise combination of the scenario format's category values."""

from __future__ import annotations

import json
import math
from itertools import combinations

import numpy as np
import pytest

from harness.scenario.documents import load_json
from harness.scenario.generate import EMPTY, MAX_OBSTACLES, PROGRAMME_SHAPES, FactorModel, covering_rows, row_to_scenario, scenario_to_row
from harness.scenario.logical import load_logical, logical_problems
from harness.scenario.space import SearchSpace
from harness.tools.cli import main

# What the scenario format says, written here apart from the generator: the kinds an obstacle
# slot can hold per element set, and the kinds each of its fields belongs to.
KINDS = {"paper": {"static", "dynamic"}, "all": {"static", "dynamic", "intruder"}}
BELONGS = {"size": {"static", "dynamic"}, "form": {"static", "dynamic"}, "motion": {"dynamic"}, "encounter": {"intruder"}, "path": {"intruder"}}


def tuple_is_valid(assignment: dict[str, str], elements: str) -> bool:
    """Independent oracle: a partial assignment extends to a valid row iff each obstacle slot can
    hold nothing ("-" everywhere) or one obstacle of a kind that every given field fits (a field is
    "-" exactly where it does not belong to the kind), slot 1 holds one, a filled slot never follows
    an empty one, and a failure has both its unit and its type or neither."""
    states = {slot: {None} | KINDS[elements] for slot in range(1, MAX_OBSTACLES + 1)}
    states[1].discard(None)
    failure = set()
    for key, value in assignment.items():
        words = key.split()
        if words[0] == "failure":
            failure.add(value == EMPTY)
            continue
        if words[0] != "obstacle":
            continue
        slot, field = int(words[1]), words[2]
        if field == "kind":
            states[slot] &= {None if value == EMPTY else value}
        else:
            states[slot] = {s for s in states[slot] if (value == EMPTY) == (s is None or s not in BELONGS[field])}
    if len(failure) > 1 or not all(states.values()):
        return False
    can_fill = [any(s is not None for s in states[slot]) for slot in range(1, MAX_OBSTACLES + 1)]
    can_empty = [None in states[slot] for slot in range(1, MAX_OBSTACLES + 1)]
    return any(all(can_fill[:filled]) and all(can_empty[filled:]) for filled in range(1, MAX_OBSTACLES + 1))


def uncovered(rows: list[dict[str, str]], strength: int, elements: str, rigs=(), programmes=()) -> list[dict[str, str]]:
    """Every valid t-tuple no row holds: per combination of factors, the rows' tuples are marked in
    an array indexed by the tuple's mixed-radix number; only the unmarked ones go to the oracle."""
    factors = FactorModel(elements, rigs, programmes).factors
    names = list(factors)
    matrix = np.array([[factors[name].index(row[name]) for name in names] for row in rows])
    missing = []
    for keys in combinations(range(len(names)), strength):
        sizes = [len(factors[names[k]]) for k in keys]
        held = np.zeros(math.prod(sizes), dtype=bool)
        held[np.ravel_multi_index(matrix[:, keys].T, sizes)] = True
        for number in np.flatnonzero(~held):
            values = np.unravel_index(number, sizes)
            assignment = {names[k]: factors[names[k]][v] for k, v in zip(keys, values)}
            if tuple_is_valid(assignment, elements):
                missing.append(assignment)
    return missing


def rows_are_valid(rows, elements):
    return all(tuple_is_valid(row, elements) for row in rows)


@pytest.mark.parametrize("elements", ["paper", "all"])
def test_pairwise_covers_every_valid_pair(elements):
    rows = covering_rows(2, elements)
    assert rows_are_valid(rows, elements)
    assert uncovered(rows, 2, elements) == []
    # The paper's pairwise selection had 32 scenarios; a covering array needs at least 4 x 4.
    if elements == "paper":
        assert 16 <= len(rows) <= 40


def test_threewise_covers_every_valid_triple_of_the_papers_value_sets():
    rows = covering_rows(3, "paper")
    assert rows_are_valid(rows, "paper")
    assert uncovered(rows, 3, "paper") == []


@pytest.mark.slow
def test_threewise_covers_every_valid_triple_of_all_elements(profile):
    rows = covering_rows(3, "all")
    assert rows_are_valid(rows, "all")
    assert uncovered(rows, 3, "all") == []
    assert all(logical_problems(row_to_scenario(row, "3-wise"), profile, "3-wise") == [] for row in rows)


def test_the_same_strength_gives_the_same_scenarios_every_time():
    assert covering_rows(3, "paper") == covering_rows(3, "paper")


def test_the_coverage_check_finds_a_triple_that_is_missing():
    rows = covering_rows(3, "paper")
    left_out = rows[len(rows) // 2]
    missing = uncovered([row for row in rows if row is not left_out], 3, "paper")
    assert missing and all(all(left_out[key] == value for key, value in tuple_.items()) for tuple_ in missing)


def test_all_elements_take_every_value_of_the_richer_elements():
    factors = FactorModel("all").factors
    assert factors["gusts"] == ["none", "light", "moderate", "severe"]
    assert factors["obstacle 1 kind"] == ["static", "dynamic", "intruder"]
    assert factors["obstacle 2 motion"] == ["straight", "arc", "waypoints", "vertical", EMPTY]
    assert factors["obstacle 3 encounter"] == ["crossing", "head-on", "overtaking", "any", EMPTY]
    assert factors["obstacle 4 path"] == ["straight", "arc", EMPTY]
    assert factors["failure unit"] == ["distance sensor", "gps", "magnetometer", "barometer", "accelerometer", "gyro", EMPTY]
    assert factors["failure type"] == ["off", "stuck", "wrong", "intermittent", "slow", EMPTY]
    assert FactorModel("paper").factors["obstacle 1 size"] == ["small", "medium", "large"]


def test_oracle_rejects_invalid_tuples():
    assert not tuple_is_valid({"obstacle 2 kind": EMPTY, "obstacle 2 size": "small"}, "paper")
    assert not tuple_is_valid({"obstacle 2 kind": EMPTY, "obstacle 3 form": "sphere"}, "paper")
    assert tuple_is_valid({"obstacle 3 kind": EMPTY, "obstacle 2 form": "sphere"}, "paper")
    # In the paper's value sets no kind goes without a size; an intruder does.
    assert not tuple_is_valid({"obstacle 2 size": EMPTY, "obstacle 3 kind": "static"}, "paper")
    assert tuple_is_valid({"obstacle 2 size": EMPTY, "obstacle 3 kind": "static"}, "all")
    assert not tuple_is_valid({"obstacle 1 kind": "static", "obstacle 1 motion": "arc"}, "all")
    assert not tuple_is_valid({"obstacle 1 motion": "arc", "obstacle 1 encounter": "crossing"}, "all")
    assert not tuple_is_valid({"obstacle 1 kind": "dynamic", "obstacle 1 motion": EMPTY}, "all")
    assert not tuple_is_valid({"obstacle 2 encounter": "any", "obstacle 2 size": "small"}, "all")
    assert not tuple_is_valid({"failure unit": "gps", "failure type": EMPTY}, "all")
    assert tuple_is_valid({"obstacle 2 path": "arc", "obstacle 1 motion": "vertical", "failure unit": "gyro"}, "all")


@pytest.mark.parametrize("elements", ["paper", "all"])
def test_generate_command_writes_valid_scenarios_that_round_trip(tmp_path, profile, capsys, elements):
    assert main(["generate", "--strength", "2", "--elements", elements, "--out", str(tmp_path)]) == 0
    files = sorted(tmp_path.glob("*.json"))
    rows = covering_rows(2, elements)
    assert len(files) == len(rows)
    kinds, failures = set(), 0
    for path, row in zip(files, rows):
        document = load_json(path)
        assert logical_problems(document, profile, str(path)) == []
        assert scenario_to_row(document, elements) == row
        assert 1 <= len(document["environment"]["obstacles"]) <= MAX_OBSTACLES
        kinds |= {obstacle["kind"] for obstacle in document["environment"]["obstacles"]}
        failures += len(document.get("failures", []))
    assert kinds == KINDS[elements]
    assert (failures > 0) == (elements == "all")
    # Every 10th flies: it loads and becomes a search space with a feasible point.
    for path in files[::10]:
        space = SearchSpace(load_logical(path, profile), profile)
        point = space.sample_feasible(np.random.default_rng(1), 1)[0]
        assert space.to_concrete(point)["logical_scenario"]["name"] == load_json(path)["name"]


@pytest.mark.parametrize("strength", [0, 9, 17, 32])
def test_a_strength_the_value_sets_do_not_allow_is_refused_at_once_saying_why(tmp_path, capsys, strength):
    assert main(["generate", "--strength", str(strength), "--out", str(tmp_path)]) == 2
    assert "--strength" in capsys.readouterr().err and not list(tmp_path.iterdir())


def test_a_strength_with_too_many_combinations_to_hold_is_refused_naming_the_smaller_element_set(tmp_path, capsys):
    assert main(["generate", "--strength", "5", "--max-scenarios", "100000", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "225,511,095 combinations" in err and "--elements paper" in err and not list(tmp_path.iterdir())


@pytest.mark.parametrize("elements, fewest", [("paper", 4), ("all", 7)])
def test_generate_says_how_many_scenarios_at_least_before_it_starts(tmp_path, capsys, elements, fewest):
    assert main(["generate", "--strength", "1", "--elements", elements, "--out", str(tmp_path)]) == 0
    assert f"strength 1: at least {fewest} logical scenarios" in capsys.readouterr().err
    assert len(list(tmp_path.glob("*.json"))) >= fewest


def test_rigs_and_programme_shapes_are_factors_every_pair_of_which_a_scenario_flies(tmp_path, profile, capsys):
    from harness.scenario.rig import load_rig, preset_names
    from harness.scenario.world import world_spec

    rigs, programmes = ["presets", "profile"], ["all"]
    assert main(["generate", "--strength", "2", "--rigs", ",".join(rigs), "--programmes", ",".join(programmes), "--out", str(tmp_path)]) == 0
    rows = covering_rows(2, "all", rigs, programmes)
    assert uncovered(rows, 2, "all", rigs, programmes) == []
    files = sorted(tmp_path.glob("*.json"))
    assert len(files) == len(rows)
    assert {row["rig"] for row in rows} == {*preset_names(), "profile"} and {row["programme"] for row in rows} == set(PROGRAMME_SHAPES)
    for path, row in zip(files, rows):
        document = load_json(path)
        assert scenario_to_row(document, "all", rigs, programmes) == row
        space = SearchSpace(load_logical(path, profile), profile)
        assert space.mission.drive == "pilot"
        world = world_spec(space, space.sample_feasible(np.random.default_rng(1), 1)[0], 1)
        expected = [] if row["rig"] == "profile" else [sensor["name"] for sensor in load_rig(row["rig"])["sensors"]]
        assert [sensor.name for sensor in world.rig or ()] == expected
        segments = len(PROGRAMME_SHAPES[row["programme"]][1])
        assert sum(name.startswith("pilot.segment_") and name.endswith(".duration_s") for name in (d.name for d in space.dimensions)) == segments


def test_a_rig_file_is_read_into_the_generated_scenarios(tmp_path, profile):
    from harness.scenario.rig import load_rig

    mine = tmp_path / "mine.json"
    mine.write_text(json.dumps({**load_rig("four_rangefinders"), "name": "mine"}))
    assert main(["generate", "--strength", "1", "--elements", "paper", "--rigs", str(mine), "--out", str(tmp_path / "out")]) == 0
    assert {load_json(path)["rig"]["name"] for path in (tmp_path / "out").glob("*.json")} == {"mine"}


@pytest.mark.parametrize("option, value, says", [
    ("--rigs", "lidar_360,sf45", "--rigs: sf45: no such rig file or preset"),
    ("--programmes", "push,zigzag", "--programmes: zigzag: no programme shape: choose among push, probe"),
])
def test_an_unknown_rig_or_programme_shape_exits_2_naming_it(tmp_path, capsys, option, value, says):
    assert main(["generate", "--strength", "2", option, value, "--out", str(tmp_path)]) == 2
    assert says in capsys.readouterr().err and not list(tmp_path.iterdir())


@pytest.mark.slow
def test_a_generated_scenario_flies_its_rig_and_its_programme(tmp_path, profile):
    from pathlib import Path

    from harness.flight import logs
    from harness.flight.evaluation import evaluate
    from harness.flight.results import RunOptions

    assert main(["generate", "--strength", "1", "--elements", "paper", "--rigs", "lidar_and_rangefinders", "--programmes", "release",
                 "--out", str(tmp_path / "out")]) == 0
    path = sorted((tmp_path / "out").glob("*.json"))[0]
    space = SearchSpace(load_logical(path, profile), profile)
    result = evaluate(space, space.sample_feasible(np.random.default_rng(2), 1)[0], seed=2, out_dir=tmp_path, options=RunOptions(cores=1), name="generated")
    log = Path(result.log_path)
    assert {topic for topic, _ns, _m in logs.messages(log, ["/sensor/rig/lidar", "/sensor/rig/front", "/sensor/rig/back"])} == {
        "/sensor/rig/lidar", "/sensor/rig/front", "/sensor/rig/back"}
    assert {record.get("segment") for _t, _ns, record in logs.messages(log, ["/pilot"]) if record["phase"] == "programme"} == {1, 2, 3}


def test_the_tiny_programme_reaches_both_sides_of_the_sticks_dead_zone():
    # The bundled autopilot maps sticks as PX4 does (dead zone MPC_HOLD_DZ, as PX4's MAN_DEADZONE, then expo):
    # a deflection inside it commands nothing, one past it collision prevention's smallest set-points.
    from autopilot.manual import expo_deadzone
    from autopilot.params import Params

    dead_zone = Params()["MPC_HOLD_DZ"]
    deflection = PROGRAMME_SHAPES["tiny"][1][0]["deflection"]
    low, high = expo_deadzone(deflection["min"], 0.6, dead_zone), expo_deadzone(deflection["max"], 0.6, dead_zone)
    assert low == 0.0 and 0.0 < high < 0.05
