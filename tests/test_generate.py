"""t-wise generation covers every valid T-wise combination of the paper's value sets."""

from __future__ import annotations

from itertools import combinations, product

import pytest

from harness.scenario.documents import load_json
from harness.scenario.generate import EMPTY, MAX_OBSTACLES, covering_rows, paper_factors, scenario_to_row
from harness.scenario.logical import logical_problems
from harness.tools.cli import main


def slot_of(key: str) -> int | None:
    return int(key.split()[1]) if key.startswith("obstacle ") else None


def tuple_is_valid(assignment: dict[str, str]) -> bool:
    """Independent oracle: a partial assignment extends to a valid row iff each slot is all-empty or
    all-filled and every filled slot comes before every empty one (slot 1 is always filled)."""
    filled, empty = {1}, set()
    for key, value in assignment.items():
        slot = slot_of(key)
        if slot is not None:
            (empty if value == EMPTY else filled).add(slot)
    return not (filled & empty) and (not empty or max(filled) < min(empty))


def uncovered(rows: list[dict[str, str]], strength: int) -> list[dict[str, str]]:
    factors = paper_factors()
    seen = set()
    for row in rows:
        for keys in combinations(factors, strength):
            seen.add(tuple((k, row[k]) for k in keys))
    missing = []
    for keys in combinations(factors, strength):
        for values in product(*(factors[k] for k in keys)):
            assignment = dict(zip(keys, values))
            if tuple_is_valid(assignment) and tuple(assignment.items()) not in seen:
                missing.append(assignment)
    return missing


def rows_are_valid(rows):
    return all(tuple_is_valid(row) for row in rows)


def test_pairwise_covers_every_valid_pair():
    rows = covering_rows(2)
    assert rows_are_valid(rows)
    assert uncovered(rows, 2) == []
    # The paper's pairwise selection had 32 scenarios; a covering array needs at least 4 x 4.
    assert 16 <= len(rows) <= 40


@pytest.mark.slow
def test_threewise_covers_every_valid_triple():
    rows = covering_rows(3)
    assert rows_are_valid(rows)
    assert uncovered(rows, 3) == []


def test_oracle_rejects_invalid_tuples():
    assert not tuple_is_valid({"obstacle 2 kind": EMPTY, "obstacle 2 size": "small"})
    assert not tuple_is_valid({"obstacle 2 kind": EMPTY, "obstacle 3 form": "sphere"})
    assert tuple_is_valid({"obstacle 3 kind": EMPTY, "obstacle 2 form": "sphere"})


def test_generate_command_writes_valid_scenarios_that_round_trip(tmp_path, profile, capsys):
    assert main(["generate", "--strength", "2", "--out", str(tmp_path)]) == 0
    files = sorted(tmp_path.glob("*.json"))
    rows = covering_rows(2)
    assert len(files) == len(rows)
    for path, row in zip(files, rows):
        document = load_json(path)
        assert logical_problems(document, profile, str(path)) == []
        assert scenario_to_row(document) == row
        assert 1 <= len(document["environment"]["obstacles"]) <= MAX_OBSTACLES


@pytest.mark.parametrize("strength", [0, 9, 17])
def test_a_strength_the_value_sets_do_not_allow_is_refused_at_once_saying_why(tmp_path, capsys, strength):
    assert main(["generate", "--strength", str(strength), "--out", str(tmp_path)]) == 2
    assert "--strength" in capsys.readouterr().err and not list(tmp_path.iterdir())


def test_generate_says_how_many_scenarios_at_least_before_it_starts(tmp_path, capsys):
    assert main(["generate", "--strength", "1", "--out", str(tmp_path)]) == 0
    assert "strength 1: at least 4 logical scenarios" in capsys.readouterr().err
