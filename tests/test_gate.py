"""`stella gate`: the verdict on each pair, the configuration file, and the whole gate against the
bundled autopilot built from this checkout (base: HEAD; head: HEAD with a real-looking fault,
collision prevention's sensor delay dropped from its stopping distance)."""

from __future__ import annotations

import contextlib
import difflib
import json
import os
import sqlite3
import time
from pathlib import Path

import pytest

from harness.campaigns.gate import CHANGE, REGRESSION, SAME, UNJUDGED, GatePlan, JudgedPair, Side, judge, judged, shrink, verify
from harness.campaigns.pairs import ReferenceCache
from harness.campaigns.shrink_steps import space_of
from harness.execution.executor import Job
from harness.execution.local import SequentialExecutor
from harness.flight.results import RunOptions
from sut_adapter import SutConfig
from harness.campaigns.gate_config import load_config
from harness.errors import InputError
from harness.flight.differential import Outcome
from harness.flight.fitness import Status
from harness.tools.cli import main

from conftest import ROOT, junit_cases, without_sensor_delay

EXAMPLES = ROOT / "scenarios" / "examples"


def flight(status: Status, clearance: float | None, time_s: float = 60.0) -> Outcome:
    return Outcome(status, 0.0 if clearance is None else clearance - 1.0, clearance, time_s, first_touchdown_s=time_s if clearance is not None else None)


OK, BLOCKED, VIOLATION, CRASHED = Status.OK, Status.MISSION_FAILED, Status.VIOLATION, Status.SUT_CRASHED


@pytest.mark.parametrize("head, base, closer_m, verdict, kind", [
    ([flight(VIOLATION, 0.3)], [flight(OK, 1.6)], 0.0, REGRESSION, "unsafe"),
    ([flight(OK, 2.0)], [flight(OK, 2.6)], 0.0, REGRESSION, "closer"),
    # closer by 0.6 m, but the team allows 1 m
    ([flight(OK, 2.0)], [flight(OK, 2.6)], 1.0, CHANGE, "closer"),
    # closer by 0.3 m, where the base's own flights spread by 0.4 m
    ([flight(OK, 2.0), flight(OK, 2.05)], [flight(OK, 2.35), flight(OK, 2.75)], 0.0, SAME, None),
    ([flight(OK, 3.0)], [flight(OK, 2.0)], 0.0, CHANGE, "farther"),
    # held back for good where the base flies its mission to the end, and the other way round
    ([flight(BLOCKED, 2.0)], [flight(OK, 2.0)], 0.0, REGRESSION, "status"),
    ([flight(OK, 2.0)], [flight(BLOCKED, 2.0)], 0.0, CHANGE, "status"),
    ([flight(OK, 2.0, 70.0)], [flight(OK, 2.0, 60.0)], 0.0, CHANGE, "longer"),
    ([flight(CRASHED, None)], [flight(OK, 2.0)], 0.0, REGRESSION, "crash"),
    ([flight(OK, 2.0)], [flight(CRASHED, None)], 0.0, UNJUDGED, None),
    ([flight(OK, 2.0)], [flight(OK, 2.02)], 0.0, SAME, None),
])
def test_a_pair_fails_the_gate_only_where_the_head_is_worse_beyond_the_bases_spread(head, base, closer_m, verdict, kind):
    judgement = judge(head, base, closer_m)
    assert (judgement.verdict, judgement.kind) == (verdict, kind), judgement.why
    assert "subject" not in judgement.why and "reference" not in judgement.why  # in the gate's words: head and base


def test_the_configuration_file_is_read_relative_to_itself_and_every_bad_key_is_named(tmp_path):
    config = tmp_path / "stella.toml"
    config.write_text('[gate]\nsut = "px4"\nsuite = ["cases"]\ndrive = "pilot"\nbudget_minutes = 20\n[gate.sut_params]\nCP_DIST = 1.5\n')
    read = load_config(config)
    assert read["suite"] == [str(tmp_path / "cases")] and read["sut_params"] == {"CP_DIST": 1.5} and read["budget_minutes"] == 20
    config.write_text('[gate]\nsut = "inav"\nbudget_flights = 0\nrig = "sf45"\nsuite = "cases"\n')
    with pytest.raises(InputError) as refused:
        load_config(config)
    said = str(refused.value)
    assert f"{config}: /gate/sut: 'inav' is not one of px4, ardupilot, bundled" in said
    assert f"{config}: /gate/budget_flights: 0 is not a whole number of search candidates, 1 or more" in said
    assert f"{config}: /gate/rig: unknown key; the gate reads sut, suite" in said
    assert f"{config}: /gate/suite: 'cases' is not a list" in said
    config.write_text('[gate\nsut = "px4"\n')
    with pytest.raises(InputError, match="not TOML"):
        load_config(config)


@pytest.mark.parametrize("argv, said", [
    (["--sut", "bundled", "--base-build", "."], "--head-build: give both sides' builds"),
    (["--sut", "bundled", "--source", "."], "--source: give the tree and the base commit"),
    (["--sut", "ardupilot", "--source", ".", "--base", "HEAD"], "--source: . is a bundled tree, not ardupilot"),
    (["--source", ".", "--base", "HEAD"], "--sut: say what the firmware is"),
    (["--sut", "bundled", "--source", ".", "--base", "no-such-commit"], "is not a commit of"),
])
def test_a_gate_asked_wrongly_says_what_to_give_and_exits_2(argv, said, tmp_path, capsys):
    suite = ["--suite", str(EXAMPLES / "wall_concrete.json")]
    assert main(["gate", *argv, *suite, "--out", str(tmp_path / "out"), "--cache", str(tmp_path / "cache")]) == 2
    assert said in capsys.readouterr().err


def fault_patch(folder: Path) -> Path:
    """A diff of this checkout's collision prevention that leaves the sensor delay out of its stopping distance."""
    source = (ROOT / "autopilot" / "collision.py").read_text()
    patch = folder / "ignores_delay.patch"
    patch.write_text("".join(difflib.unified_diff(source.splitlines(keepends=True), without_sensor_delay(source).splitlines(keepends=True),
                                                  "a/autopilot/collision.py", "b/autopilot/collision.py")))
    return patch


@pytest.mark.slow
def test_a_gate_fails_a_head_that_brakes_late_and_passes_its_base_against_itself(tmp_path, capsys, pytester):
    cache = tmp_path / "cache"
    gate = ["gate", "--sut", "bundled", "--source", str(ROOT), "--base", "HEAD", "--suite", str(EXAMPLES / "wall_concrete.json"),
            "--scenario", str(EXAMPLES / "wall.json"), "--budget-flights", "6", "--workers", "2", "--cache", str(cache)]
    # WHEN the head is the base with the fault
    out = tmp_path / "faulty"
    assert main([*gate, "--patch", str(fault_patch(tmp_path)), "--verify-flights", "2", "--out", str(out)]) == 1
    # THEN the summary leads with the verdict, and names the suite case the head violates in
    summary = (out / "summary.md").read_text()
    assert summary.startswith("## stella gate: FAILED. The head is less safe than its base")
    assert "### 1. wall_concrete (suite case): the head violates the safety distance" in summary and "the head violates" in summary
    ended = junit_cases(out / "junit.xml")
    assert ended["stella.gate.suite::wall_concrete"] == "failure" and ended["stella.gate.search::wall.json"] in ("passed", "failure")
    result = json.loads((out / "gate.json").read_text())
    assert result["passed"] is False and result["regressions"][0]["kind"] == "unsafe"
    # verified: flown once more on each side, where it held (the bundled stack repeats itself)
    assert len(result["regressions"][0]["head"]) == len(result["regressions"][0]["base"]) == 2 and not result["not_held"]
    assert result["searches"][0]["evaluated"] == 6
    # and its bundle holds the case, both flights and the explanation of the head's
    bundle = Path(result["regressions"][0]["bundle"])
    assert {"case.regression.json", "concrete.json", "head.mcap", "base.mcap", "flight.png", "explanation.txt", "FINDING.md"} <= {
        p.name for p in bundle.iterdir()}
    # and the worst regression shrunk, as unsafe as it was found
    shrunk = result["shrunk"]
    assert shrunk["of"] == "wall_concrete" and shrunk["pair"]["kind"] == "unsafe" and shrunk["tried"] >= 1
    assert {"case.regression.json", "concrete.json", "head.mcap", "base.mcap"} <= {p.name for p in (bundle / "shrunk").iterdir()}
    assert "shrunk/case.regression.json" in summary
    # whose case fails on the head's build and passes on the base's
    head_dir, base_dir = result["head"]["folder"], result["base"]["folder"]
    for folder, outcome in ((head_dir, {"failed": 1}), (base_dir, {"passed": 1})):
        flown = pytester.runpytest_subprocess(str(bundle / "case.regression.json"), "-p", "no:cacheprovider", "--stella-autopilot-dir", folder,
                                              "--stella-out", str(tmp_path / "case-logs"))
        flown.assert_outcomes(**outcome)

    # WHEN the base is gated against itself, twice, flown although it is one program
    with contextlib.closing(sqlite3.connect(cache / "base_flights.db")) as flights:
        cached = flights.execute("SELECT COUNT(*) FROM reference_flights").fetchone()[0]
    for run in ("same", "same-again"):
        capsys.readouterr()
        assert main([*gate, "--fly-identical", "--out", str(tmp_path / run)]) == 0
        assert (tmp_path / run / "summary.md").read_text().startswith("## stella gate: passed")
        assert set(junit_cases(tmp_path / run / "junit.xml").values()) == {"passed"}
    # THEN the base's flights came from the cache: the searches asked for the same candidates
    with contextlib.closing(sqlite3.connect(cache / "base_flights.db")) as flights:
        assert flights.execute("SELECT COUNT(*) FROM reference_flights").fetchone()[0] == cached
    assert "from the cache" in json.loads((tmp_path / "same-again" / "gate.json").read_text())["base"]["described"]


def test_a_head_that_changes_only_comments_builds_to_the_base_program_and_passes_unflown(tmp_path, capsys):
    source = (ROOT / "autopilot" / "faults.py").read_text()
    commented = source.replace("# collision prevention, sensing", "# one of: collision prevention, sensing", 1)
    assert commented != source
    patch = tmp_path / "comment.patch"
    patch.write_text("".join(difflib.unified_diff(source.splitlines(keepends=True), commented.splitlines(keepends=True),
                                                  "a/autopilot/faults.py", "b/autopilot/faults.py")))
    out = tmp_path / "out"
    assert main(["gate", "--sut", "bundled", "--source", str(ROOT), "--base", "HEAD", "--patch", str(patch), "--suite", str(EXAMPLES / "wall_concrete.json"),
                 "--scenario", str(EXAMPLES / "wall.json"), "--cache", str(tmp_path / "cache"), "--out", str(out)]) == 0
    assert "the head builds to the same program as the base; nothing flown" in capsys.readouterr().out
    summary = (out / "summary.md").read_text()
    assert summary.startswith("## stella gate: passed. The head builds to the same program as its base") and "nothing was flown" in summary
    assert junit_cases(out / "junit.xml") == {"stella.gate::the head builds to the same program as its base": "passed"}
    result = json.loads((out / "gate.json").read_text())
    assert result["identical"] is True and not result["suite"] and not result["searches"]
    assert not (tmp_path / "cache" / "base_flights.db").exists()


@pytest.mark.slow
def test_a_regression_judged_on_a_noisy_first_flight_does_not_fail_the_gate_unless_it_holds(tmp_path):
    # GIVEN the wall flown on the bundled autopilot, and a pair of it whose head flight (as a
    # noisy first sitting gave it) came 0.4 m closer than the base's: judged a regression
    concrete = json.loads((EXAMPLES / "wall_concrete.json").read_text())
    executor = SequentialExecutor()
    side = Side(SutConfig(), "this checkout", str(ROOT))
    space = space_of(concrete)
    try:
        [(_job, flown)] = list(executor.run([Job.of(0, space, space.from_concrete(concrete), seed=0, out_dir=tmp_path, name="wall", options=RunOptions())]))
        base = Outcome.of(flown)
        head = Outcome(base.status, base.fitness - 0.4, base.min_clearance_m - 0.4, base.sim_time_s, first_touchdown_s=base.first_touchdown_s)
        differential = {"subject": [head.as_dict()], "reference": [base.as_dict()]}
        pair = JudgedPair("wall", "suite", judged(differential, 0.0), concrete, 0, differential)
        assert pair.judgement.verdict == REGRESSION
        # WHEN it is verified over three flights a side
        held, not_held, unverified = verify([pair], GatePlan(verify_flights=3), side, side, executor, tmp_path / "verify", None, lambda _l: None)
    finally:
        executor.close()
    # THEN the two flights more of each side show the same build: it does not hold, and is not counted
    assert not held and not unverified and len(not_held) == 1
    assert not_held[0].judgement.verdict == SAME
    assert len(not_held[0].differential["subject"]) == len(not_held[0].differential["reference"]) == 3


@pytest.mark.slow
@pytest.mark.parametrize("sut, variable", [("px4", "STELLA_PX4_BIN"), ("ardupilot", "STELLA_ARDUPILOT_BIN")])
def test_a_firmware_build_gated_against_itself_passes(sut, variable, tmp_path):
    """A firmware's flights spread, so a gate of one build against itself is where a false alarm
    would show. Flown where the environment names a build, skipped, saying so, elsewhere."""
    build = os.environ.get(variable)
    if not build:
        pytest.skip(f"{variable} is not set: no {sut} SITL build to gate")
    out = tmp_path / "out"
    assert main(["gate", "--sut", sut, "--base-build", build, "--head-build", build, "--suite", str(EXAMPLES / "wall_concrete.json"),
                 "--drive", "pilot", "--fly-identical", "--workers", "2", "--cache", str(tmp_path / "cache"), "--out", str(out)]) == 0
    assert (out / "summary.md").read_text().startswith("## stella gate: passed")
    assert set(junit_cases(out / "junit.xml").values()) == {"passed"}


@pytest.mark.slow
def test_a_gate_given_minutes_stops_its_search_at_them_and_says_how_far_it_went(tmp_path):
    out = tmp_path / "out"
    assert main(["gate", "--sut", "bundled", "--base-build", str(ROOT), "--head-build", str(ROOT), "--scenario", str(EXAMPLES / "wall.json"),
                 "--budget-minutes", "0.4", "--fly-identical", "--workers", "2", "--cache", str(tmp_path / "cache"), "--out", str(out)]) == 0
    result = json.loads((out / "gate.json").read_text())
    [search] = result["searches"]
    assert search["budget"] is None and search["evaluated"] >= 1 and search["stopped"].startswith("stopped at the time budget after")
    assert "stopped at the time budget" in (out / "summary.md").read_text()


def test_a_shrink_left_no_time_says_so_and_flies_nothing(tmp_path):
    concrete = json.loads((EXAMPLES / "wall_concrete.json").read_text())
    differential = {"subject": [flight(VIOLATION, 0.3).as_dict()], "reference": [flight(OK, 1.6).as_dict()]}
    pair = JudgedPair("wall", "suite", judged(differential, 0.0), concrete, 0, differential)
    side = Side(SutConfig(), "this checkout", str(ROOT))
    executor = SequentialExecutor()
    try:
        shrunk = shrink(pair, GatePlan(), side, side, executor, ReferenceCache(tmp_path / "base_flights.db"), tmp_path / "shrink",
                        time.monotonic() - 1.0, lambda _line: None)
    finally:
        executor.close()
    assert shrunk.pair is None and shrunk.flown == 0 and shrunk.stopped == "the time budget was spent before it"
