"""`stella validate`: located messages for a corpus of malformed files, and the shipped scenarios pass."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from conftest import ROOT, TABLE3
from harness.tools.cli import main

MALFORMED = ROOT / "tests" / "data" / "malformed"
EXPECTED = json.loads((ROOT / "tests" / "data" / "malformed_expected.json").read_text())


def test_corpus_has_expectations_for_every_file_and_no_orphans():
    files = {p.name for p in MALFORMED.glob("*.json")}
    assert len(files) >= 30
    assert files == set(EXPECTED)


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_malformed_file_is_rejected_with_located_messages(name, capsys):
    path = MALFORMED / name
    assert main(["validate", str(path)]) == 2
    lines = capsys.readouterr().out.splitlines()
    assert lines == [f"{path}: {message}" for message in EXPECTED[name]]


def test_all_problems_of_a_file_are_reported_not_only_the_first(capsys):
    main(["validate", str(MALFORMED / "34_two_problems.json")])
    out = capsys.readouterr().out
    assert "/environment/weather/wind force" in out and "/environment/obstacles/0/size" in out


def test_table3_scenarios_and_examples_and_profile_are_valid(capsys):
    assert len(TABLE3) == 32
    paths = [str(p) for p in TABLE3] + [str(ROOT / "scenarios" / "examples"), str(ROOT / "scenarios" / "profiles")]
    assert main(["validate", *paths]) == 0
    out = capsys.readouterr().out
    assert out.count("ok: ") == 32 + 9 + 2 + 1 + 1  # Table III, fig4, wall, wall with the sensor off, the probed wall (with a lidar of searched geometry, and one from north), the plan's, the richer and the data-link scenario, the two wall concretes, the plan, the profile
    assert out.count("(concrete scenario)") == 2  # the two walls
    assert out.count("(QGroundControl plan)") == 1
    assert "lighting = normal (profile default) is not simulated" in out


def test_a_note_shared_by_many_scenarios_is_said_once_unless_verbose(capsys):
    # GIVEN Table III, whose 32 scenarios leave the same weather categories unsimulated
    paths = [str(p) for p in TABLE3]
    # WHEN validated, THEN each such note is one line that says how many files it holds for
    assert main(["validate", *paths]) == 0
    out = capsys.readouterr().out
    lighting = [line for line in out.splitlines() if "lighting = normal (profile default) is not simulated" in line]
    assert len(lighting) == 1 and "32 files" in lighting[0]
    assert len(out.splitlines()) < 32 + 10
    # AND with --verbose each file says its own notes again
    assert main(["-v", "validate", *paths]) == 0
    assert capsys.readouterr().out.count("lighting = normal (profile default) is not simulated") == 32


def test_console_script_exits_2_and_names_file_and_pointer():
    path = MALFORMED / "18_misspelt_wind.json"
    result = subprocess.run(
        [sys.executable, "-m", "harness.tools.cli", "validate", str(path)], capture_output=True, text=True, check=False
    )
    assert result.returncode == 2
    assert f"{path}: /environment/weather/wind force:" in result.stdout
    assert '"moderate"' in result.stdout


def test_validate_json_output_lists_problems(capsys):
    assert main(["validate", "--json", str(MALFORMED / "10_bad_landform.json")]) == 2
    report = json.loads(capsys.readouterr().out)
    assert report["problems"][0]["pointer"] == "/environment/flight area/landform"


def test_missing_file_is_a_located_error(capsys, tmp_path):
    assert main(["validate", str(tmp_path / "nope.json")]) == 2
    assert "no such file" in capsys.readouterr().out
