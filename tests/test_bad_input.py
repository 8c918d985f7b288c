"""Bad invocations a user will certainly make: each exits 2 with one line naming what is wrong
and how to mend it, never a traceback (issue 18). Nothing here flies."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from conftest import ROOT
from harness.tools.cli import main

FIG4 = str(ROOT / "scenarios" / "examples" / "fig4.json")
WALL = str(ROOT / "scenarios" / "examples" / "wall_concrete.json")


@pytest.fixture
def files(tmp_path):
    text = tmp_path / "text.db"
    text.write_text("not a database")
    other = tmp_path / "other.db"
    with sqlite3.connect(other) as db:
        db.execute("CREATE TABLE notes (x)")
    (tmp_path / "broken.json").write_text('{"name": "half')
    (tmp_path / "array.json").write_text("[1, 2]")
    (tmp_path / "text.mcap").write_text("a text file named like a log")
    (tmp_path / "magic_only.mcap").write_bytes(b"\x89MCAP0\r\n")  # a log cut before the simulator wrote anything
    (tmp_path / "empty_folder").mkdir()
    return {"TEXT": str(text), "OTHER_SQLITE": str(other), "MISSING": str(tmp_path / "missing.db"), "OUT": str(tmp_path / "out"),
            "BROKEN_JSON": str(tmp_path / "broken.json"), "ARRAY_JSON": str(tmp_path / "array.json"), "TEXT_MCAP": str(tmp_path / "text.mcap"),
            "MAGIC_ONLY_MCAP": str(tmp_path / "magic_only.mcap"), "EMPTY_FOLDER": str(tmp_path / "empty_folder"),
            "UNDER_A_FILE": str(text / "out"), "UNDER_A_FILE_DB": str(text / "campaign.db"), "UNDER_A_FILE_JSON": str(text / "concrete.json")}


CORPUS = [
    (["compare", "TEXT"], "not a campaign store"),
    (["compare", "OTHER_SQLITE"], "not a campaign store"),
    (["compare", "MISSING"], "no such campaign store"),
    (["report", "TEXT", "--out", "OUT"], "not a campaign store"),
    (["report", "OTHER_SQLITE", "--out", "OUT"], "not a campaign store"),
    (["export-regressions", "TEXT", "--out", "OUT"], "not a campaign store"),
    (["export-regressions", "MISSING", "--out", "OUT"], "no such campaign store"),
    (["run", FIG4, "--rate-hz", "-5"], "--rate-hz: -5 is not a positive number"),
    (["run", FIG4, "--rate-hz", "0"], "--rate-hz: 0 is not a positive number"),
    (["campaign", FIG4, "--algorithm", "NSGAII", "--evaluations", "0", "--store", "OUT"], "--evaluations: 0 is not a positive whole number"),
    (["campaign", FIG4, "--algorithm", "NSGAII", "--evaluations", "5", "--runs", "-1", "--store", "OUT"], "--runs: -1 is not a positive whole number"),
    (["campaign", FIG4, "--algorithm", "NSGAII", "--evaluations", "5", "--workers", "0", "--store", "OUT"], "--workers: 0 is not a positive whole number"),
    (["campaign", FIG4, "--algorithm", "NSGAII", "--evaluations", "5", "--population", "0", "--store", "OUT"], "--population: 0 is not a positive"),
    (["campaign", FIG4, "--algorithm", "NSGAII", "--evaluations", "5", "--wall-time-s", "-3", "--store", "OUT"], "--wall-time-s: -3 is not a positive number"),
    (["campaign", FIG4, "--algorithm", "NSGAII", "--evaluations", "5", "--screen", "bundled", "--screen-share", "1.5", "--store", "OUT"],
     "--screen-share: 1.5 is not a share: give a number from 0 to 1"),
    (["campaign", FIG4, "--algorithm", "NSGAII", "--evaluations", "5", "--screen", "bundled", "--screen-correction", "none", "--reference-sut-param",
      "CP_DIST=2", "--objective", "difference", "--store", "OUT"], "--screen-correction: none ranks by the cheap flights' clearance"),
    (["generate", "--strength", "9", "--out", "OUT"], "strength 9 gives at least 1,120,000 logical scenarios"),
    (["generate", "--strength", "0", "--out", "OUT"], "0 is not a strength"),
    (["run", FIG4, "--drive", "autopilot"], "--drive: invalid choice"),
    (["bench", "--campaign", "--drive", "pilot"], "leave --drive out"),
    (["run", FIG4, "--transport", "pigeon"], "--transport: invalid choice"),
    (["campaign", FIG4, "--algorithm", "RANDOM", "--evaluations", "2", "--store", "OUT", "--sut", "command",
      "--sut-command", "x {sim_port} {api_port}", "--transport", "memory"], "memory carries the bundled autopilot only"),
    (["bench", "--transport", "memory", "--sut", "command", "--sut-command", "x {sim_port} {api_port}"], "memory carries the bundled autopilot only"),
    (["bench", "--transport", "memory", "--cores", "2"], "no placement has --cores 2 with --transport memory"),
    (["bench", "--cold-start"], "--cold-start: only the campaign benchmark takes it (--campaign)"),
    (["bench", "--limit", "--campaign"], "--limit: the SUT-alone replay goes with the flight benchmark; leave out --campaign and --executor"),
    (["validate", "BROKEN_JSON"], "invalid JSON at line 1"),
    (["validate", "ARRAY_JSON"], "expected object, got array"),
    (["validate", "EMPTY_FOLDER"], "a folder without *.json or *.plan files"),
    (["validate", "MISSING"], "no such file"),
    (["validate", FIG4, "--profile", "BROKEN_JSON"], "invalid JSON"),
    (["space", FIG4, "--profile", "no_such_profile"], "no_such_profile.json: no such file"),
    (["space", FIG4, "--drive", "autopilot"], "--drive: invalid choice"),
    (["sample", FIG4, "--seed", "-1"], "-1 is not a seed"),
    (["sample", FIG4, "--seed", "4294967296"], "is not a seed"),
    (["sample", FIG4, "--out", "UNDER_A_FILE_JSON"], "Not a directory: give a path in a writable folder"),
    (["run", "BROKEN_JSON"], "invalid JSON"),
    (["run", FIG4, "--sut", "no_such_sut"], "unknown SUT; available: ardupilot, bundled, command, px4"),
    (["run", FIG4, "--sut-param", "CP_DIST"], "is not NAME=NUMBER"),
    (["run", FIG4, "--sut-param", "CP_DIST=nan"], "must be a finite number"),
    (["run", FIG4, "--sut-param", "CP_DISTANCE=2"], "unknown parameter 'CP_DISTANCE' (`python -m autopilot.params` lists its parameters)"),
    (["run", FIG4, "--sut-param", "CP_DIST=500"], "CP_DIST: 500.0 outside [-1.0, 15.0] m"),
    (["faults", "bench", "--fault", "none", "--algorithm", "RANDOM", "--scenario", FIG4, "--evaluations", "2", "--store", "OUT", "--sut-param", "CP_DISTANCE=2"],
     "--sut-param: bundled: unknown parameter 'CP_DISTANCE'"),
    (["run", FIG4, "--out", "UNDER_A_FILE"], "Not a directory: give a path in a writable folder"),
    (["inspect", "TEXT_MCAP"], "not an MCAP file"),
    (["inspect", "MAGIC_ONLY_MCAP"], "no world metadata"),
    (["inspect", "EMPTY_FOLDER"], "not a file: give an evaluation log"),
    (["inspect", "MISSING"], "no such file"),
    (["diff", "TEXT_MCAP", "TEXT_MCAP"], "not an MCAP file"),
    (["diff", "MAGIC_ONLY_MCAP", "MISSING"], "no such file"),
    (["diff", "TEXT_MCAP", "TEXT_MCAP", "--tolerance", "-1"], "is not a number of zero or more"),
    (["campaign", FIG4, "--algorithm", "XYZ", "--evaluations", "3", "--store", "OUT"], "unknown algorithm 'XYZ'"),
    (["campaign", FIG4, "--algorithm", "NSGAII", "--evaluations", "3", "--batch", "0", "--store", "OUT"], "--batch: 0 is not a positive whole number"),
    (["campaign", FIG4, "--algorithm", "NSGAII", "--evaluations", "3", "--workers", "1", "--store", "UNDER_A_FILE_DB"], "cannot create a campaign store here"),
    (["campaign", FIG4, "--algorithm", "NSGAII", "--evaluations", "3", "--workers", "1", "--store", "EMPTY_FOLDER"], "is not a file"),
    (["campaign", FIG4, "--algorithm", "NSGAII", "--evaluations", "3", "--workers", "1", "--store", "TEXT"], "not a campaign store"),
    (["campaign", FIG4, "--algorithm", "NSGAII", "--evaluations", "3", "--workers", "1", "--store", "OTHER_SQLITE"], "not a campaign store"),
    (["campaign", "BROKEN_JSON", "--algorithm", "NSGAII", "--evaluations", "3", "--store", "OUT"], "invalid JSON"),
    (["campaign", FIG4, "--algorithm", "NSGAII", "--evaluations", "3", "--store", "OUT", "--sut-logs", "some"], "--sut-logs: invalid choice: 'some'"),
    (["report", "MISSING", "--out", "OUT"], "no such campaign store"),
    (["export-regressions", "OTHER_SQLITE", "--out", "OUT"], "not a campaign store"),
    (["export-regressions", "TEXT", "--out", "OUT", "--threshold", "abc"], "--threshold: invalid float value"),
    (["generate", "--strength", "2", "--out", "UNDER_A_FILE"], "Not a directory: give a path in a writable folder"),
    (["ui", "--port", "99999"], "99999 is not a TCP port"),
    (["sut", "check", "--sut", "px4", "--px4-bin", "TEXT"], "is not an executable px4 binary"),
    (["sut", "check", "--sut", "command", "--sut-command", "true"], "must use {sim_port}, {api_port}"),
    (["bench", "--runs", "0"], "--runs: 0 is not a positive whole number"),
    (["gate", "--sut", "bundled", "--source", ".", "--base", "HEAD", "--config", "MISSING", "--out", "OUT"], "no such configuration file"),
    (["gate", "--sut", "bundled", "--source", ".", "--base", "HEAD", "--config", "BROKEN_JSON", "--out", "OUT"], "not TOML"),
    (["gate", "--sut", "bundled", "--source", ".", "--base", "HEAD", "--suite", "MISSING", "--out", "OUT"], "no such file"),
    (["gate", "--sut", "bundled", "--source", ".", "--base", "HEAD", "--scenario", "BROKEN_JSON", "--out", "OUT"], "invalid JSON"),
    (["gate", "--sut", "bundled", "--source", ".", "--base", "HEAD", "--out", "OUT"], "nothing to fly"),
    (["gate", "--sut", "px4", "--base-build", "TEXT", "--head-build", "TEXT", "--suite", WALL, "--out", "OUT"], "is not an executable px4 binary"),
    (["gate", "--sut", "bundled", "--base-build", "EMPTY_FOLDER", "--head-build", "EMPTY_FOLDER", "--suite", WALL, "--out", "OUT"], "holds no autopilot package"),
    (["gate", "--sut", "bundled", "--source", ".", "--base", "HEAD", "--suite", WALL, "--budget-flights", "0", "--out", "OUT"],
     "--budget-flights: 0 is not a positive whole number"),
]


@pytest.mark.parametrize(("argv", "message"), CORPUS, ids=[" ".join(a[:2]) + f"-{i}" for i, (a, _m) in enumerate(CORPUS)])
def test_a_bad_invocation_exits_2_with_a_reason_and_no_traceback(files, capsys, argv, message):
    argv = [files.get(arg, arg) for arg in argv]
    try:
        code = main(argv)
    except SystemExit as exit_:  # argparse's own errors
        code = exit_.code
    captured = capsys.readouterr()
    said = captured.err + captured.out  # validate reports problems as its output, as linters do
    assert code == 2, said
    assert message in said and "Traceback" not in said


def test_a_file_that_is_no_store_is_left_as_it_was(files):
    before = open(files["OTHER_SQLITE"], "rb").read()
    assert main(["compare", files["OTHER_SQLITE"]]) == 2
    assert main(["campaign", FIG4, "--algorithm", "NSGAII", "--evaluations", "3", "--workers", "1", "--store", files["OTHER_SQLITE"]]) == 2
    assert open(files["OTHER_SQLITE"], "rb").read() == before


def test_a_reader_that_goes_away_ends_the_command_without_a_traceback():
    import subprocess
    import sys

    command = subprocess.Popen([sys.executable, "-m", "harness.tools.cli", "faults", "list"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT)
    command.stdout.close()  # before the command has written anything: its first write fails
    stderr = command.communicate(timeout=60)[1].decode()
    assert command.returncode == 141
    assert stderr == ""


def test_a_defect_of_stella_exits_3_with_its_traceback_not_1(monkeypatch, capsys):
    """Exit 1 means a violation (or, for `stella gate`, a regression) to a script: a defect of the
    harness must not read as one."""
    from harness.tools.commands.common import COMMANDS

    def broken(_args):
        raise RuntimeError("a defect")

    monkeypatch.setattr(COMMANDS["space"], "run", broken)
    assert main(["space", FIG4]) == 3
    said = capsys.readouterr().err
    assert "RuntimeError: a defect" in said and "a defect of stella" in said


@pytest.mark.parametrize("section, entry, said", [
    ("failures", {"unit": "distance sensor", "type": "off", "onset_s": 6.0, "duration_s": 60.0},
     "/failures: 1 failures (distance sensor off) but its logical scenario declares 0 (none)"),
    ("obstacles", {"kind": "static", "form": "sphere", "size": {"radius_m": 2.0}, "position": {"north_m": 40.0, "east_m": 5.0}},
     "/obstacles: 2 obstacles (static, static) but its logical scenario declares 1 (static)"),
])
def test_a_concrete_scenario_with_more_than_its_logical_scenario_declares_is_refused_rather_than_flown_without_it(tmp_path, capsys, section, entry, said):
    import json

    document = json.loads(Path(WALL).read_text())
    document.setdefault(section, []).append(entry)
    concrete = tmp_path / "concrete.json"
    concrete.write_text(json.dumps(document))
    assert main(["run", "--concrete", str(concrete), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"{concrete}: {said}: declare them in /logical_scenario, which is what is flown" in err
    assert not list(tmp_path.glob("*.mcap"))
