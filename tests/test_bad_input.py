"""Bad invocations a user will certainly make: each exits 2 with one line naming what is wrong
and how to mend it, never a traceback (issue 18). Nothing here flies."""

from __future__ import annotations

import sqlite3

import pytest

from conftest import ROOT
from harness.cli import main

FIG4 = str(ROOT / "scenarios" / "examples" / "fig4.json")


@pytest.fixture
def files(tmp_path):
    text = tmp_path / "text.db"
    text.write_text("not a database")
    other = tmp_path / "other.db"
    with sqlite3.connect(other) as db:
        db.execute("CREATE TABLE notes (x)")
    return {"TEXT": str(text), "OTHER_SQLITE": str(other), "MISSING": str(tmp_path / "missing.db"), "OUT": str(tmp_path / "out")}


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
    (["generate", "--strength", "9", "--out", "OUT"], "strength 9 gives at least 262,144 logical scenarios"),
    (["generate", "--strength", "0", "--out", "OUT"], "0 is not a strength"),
    (["run", FIG4, "--drive", "autopilot"], "--drive: invalid choice"),
    (["bench", "--campaign", "--drive", "pilot"], "leave --drive out"),
]


@pytest.mark.parametrize(("argv", "message"), CORPUS, ids=[" ".join(a[:2]) + f"-{i}" for i, (a, _m) in enumerate(CORPUS)])
def test_a_bad_invocation_exits_2_with_a_reason_and_no_traceback(files, capsys, argv, message):
    argv = [files.get(arg, arg) for arg in argv]
    try:
        code = main(argv)
    except SystemExit as exit_:  # argparse's own errors
        code = exit_.code
    err = capsys.readouterr().err
    assert code == 2, err
    assert message in err and "Traceback" not in err


def test_reading_a_file_that_is_no_store_leaves_it_as_it_was(files):
    before = open(files["OTHER_SQLITE"], "rb").read()
    assert main(["compare", files["OTHER_SQLITE"]]) == 2
    assert open(files["OTHER_SQLITE"], "rb").read() == before
