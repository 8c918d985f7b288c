"""Regression cases: export from a campaign store, and the pytest plugin flying them for real."""

from __future__ import annotations

import json
import shutil
import sys
import xml.etree.ElementTree as ElementTree

import numpy as np
import pytest

from conftest import ROOT, stored_result
from harness.campaigns.regression import export_regressions, load_regression, verdict
from harness.campaigns.store import Store
from harness.errors import InputError
from harness.flight.results import EvaluationResult
from harness.flight.fitness import Status
from harness.scenario.logical import load_logical
from harness.scenario.space import SearchSpace
from sut_adapter import SutConfig

CASES = ROOT / "tests" / "data" / "regressions"
KNOWN_VIOLATION = json.loads((CASES / "known_violation.json").read_text())


def junit_properties(path) -> dict[str, dict[str, str]]:
    tree = ElementTree.parse(path)
    return {case.get("name"): {p.get("name"): p.get("value") for p in case.iter("property")} for case in tree.iter("testcase")}


def make_store(path, profile) -> Store:
    """A store as a campaign leaves it: three evaluations of one run, one infeasible."""
    space = SearchSpace(load_logical(ROOT / "scenarios" / "examples" / "fig4.json", profile), profile)
    store = Store(path)
    campaign = store.campaign({"scenarios": ["fig4.json"], "algorithms": ["NSGAII"], "sut": "bundled"})
    run_id, _ = store.run(campaign, "/somewhere/fig4.json", space.logical.name, "NSGAII", 0, 7)
    xs = space.sample(np.random.default_rng(0), 4)
    for ordinal, (fitness, status) in enumerate([(2.5, "ok"), (-0.4, "violation"), (1000.0, "infeasible"), (0.7, "ok")]):
        result = stored_result(fitness, status, 7, min_clearance_m=fitness + 1.0 if status != "infeasible" else None)
        store.add_evaluation(run_id, ordinal=ordinal, step=0, optimizer="NSGAII", vector=xs[ordinal], result=result,
                             concrete=space.to_concrete(xs[ordinal]))
    # The same candidate found again by a second run is exported once.
    run_2, _ = store.run(campaign, "/somewhere/fig4.json", space.logical.name, "NSGAII", 1, 8)
    store.add_evaluation(run_2, ordinal=0, step=0, optimizer="NSGAII", vector=xs[1], result=stored_result(-0.4, "violation", 7),
                         concrete=space.to_concrete(xs[1]))
    return store


def test_export_writes_each_violation_once_as_a_loadable_case(tmp_path, profile):
    make_store(tmp_path / "c.db", profile).close()
    written = export_regressions(tmp_path / "c.db", tmp_path / "out")
    assert [p.name for p in written] == ["fig4-NSGAII-run0-eval00002.regression.json"]
    case = load_regression(written[0])
    assert (case.expect, case.seed, case.sut, case.found["fitness"], case.found["status"]) == ("safe", 7, SutConfig(), -0.4, "violation")
    assert "must keep the safety distance" in json.loads(written[0].read_text())["note"]


def test_export_threshold_and_worst_choose_more_cases_and_never_infeasible_ones(tmp_path, profile):
    make_store(tmp_path / "c.db", profile).close()
    by_threshold = export_regressions(tmp_path / "c.db", tmp_path / "a", threshold=1.0, expect="violation")
    assert [load_regression(p).found["fitness"] for p in by_threshold] == [-0.4, 0.7]
    assert {load_regression(p).expect for p in by_threshold} == {"violation"}
    worst = export_regressions(tmp_path / "c.db", tmp_path / "b", worst=3)
    assert sorted(load_regression(p).found["fitness"] for p in worst) == [-0.4, 0.7, 2.5]


def test_export_refuses_a_missing_store_and_an_unknown_expectation(tmp_path, profile):
    with pytest.raises(InputError, match="no such campaign store"):
        export_regressions(tmp_path / "none.db", tmp_path / "out")
    make_store(tmp_path / "c.db", profile).close()
    with pytest.raises(InputError, match="allowed values: safe, kept, violation"):
        export_regressions(tmp_path / "c.db", tmp_path / "out", expect="fixed")


def test_a_malformed_case_names_the_file_the_field_and_the_fix(tmp_path):
    document = dict(KNOWN_VIOLATION, expect="fixed", seed=-1)
    document["concrete_scenario"] = dict(document["concrete_scenario"], environment={"wind_speed_m_s": 99.0})
    path = tmp_path / "bad.regression.json"
    path.write_text(json.dumps(document))
    with pytest.raises(InputError) as error:
        load_regression(path)
    assert str(error.value).splitlines() == [
        f'{path}: /expect: "fixed" is not allowed; allowed values: "safe", "kept", "violation", "as_reference"',
        f"{path}: /seed: must be at least 0, got -1",
    ]
    path.write_text(json.dumps(dict(KNOWN_VIOLATION, expect="as_reference")))
    with pytest.raises(InputError, match="reference"):  # what the reference did is what such a case is judged by
        load_regression(path)
    path.write_text(json.dumps(dict(KNOWN_VIOLATION, concrete_scenario=document["concrete_scenario"])))
    with pytest.raises(InputError) as error:
        load_regression(path)
    assert f"{path}: /concrete_scenario/environment/wind_speed_m_s: 99.0 lies outside [2.2222222222222223, 5.555555555555555] m/s for `wind_speed_m_s`" in str(error.value)
    assert f"{path}: /concrete_scenario/environment/wind_from_deg: missing value for `wind_from_deg` (deg)" in str(error.value)


@pytest.mark.parametrize(
    ("expect", "status", "failure"),
    [
        ("safe", "ok", None),
        ("safe", "violation", "safety distance violated: status violation"),
        ("safe", "mission_failed", "the mission was not flown safely to its end: status mission_failed"),
        ("kept", "ok", None),
        ("kept", "mission_failed", None),
        ("kept", "violation", "safety distance violated: status violation"),
        ("kept", "timeout", "the flight did not end: status timeout"),
        ("violation", "violation", None),
        ("violation", "ok", "the known violation no longer reproduces: status ok"),
    ],
)
def test_verdicts(expect, status, failure):
    result = EvaluationResult(status=Status(status), fitness=0.25, why=None, min_clearance_m=1.25, min_clearance_at_s=3.0, min_clearance_obstacle="obstacle_1",
                              sim_time_s=30.0, wall_time_s=1.0, real_time_factor=30.0, seed=0, log_path="x.mcap", scenario="s", sut="bundled")
    message = verdict(expect, result, 1.0)
    assert message == failure if failure is None else message.startswith(failure)
    if message:
        assert message.endswith("min clearance 1.250 m >= safety distance 1.000 m at t=3.00 s to obstacle_1; log: x.mcap" + (". If the fault was fixed, set \"expect\": \"safe\"." if expect == "violation" else ""))


# -- the plugin, in a pytest of its own (pytester), flying real cases ---------------------------


def copy_case(pytester, source: str, target: str, **changes) -> None:
    document = json.loads((CASES / source).read_text())
    document.update(changes)
    (pytester.path / f"{target}.regression.json").write_text(json.dumps(document))


@pytest.mark.slow
def test_a_known_violation_fails_with_the_documented_message_and_the_log_goes_to_junit(pytester):
    copy_case(pytester, "known_violation.json", "known")
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider", "--junitxml=junit.xml")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines([
        "*_ scenario_01-known-violation (expect safe) _*",
        "scenario_01-known-violation: must keep the safety distance and complete the mission",
        "safety distance violated: status violation, fitness -2.322; min clearance -1.322 m (inside the obstacle) < safety distance 1.000 m"
        " at t=14.49 s to obstacle_4; log: */stella-logs/scenario_01-known-violation.mcap",
        "FAILED known.regression.json::scenario_01-known-violation - *",
    ])
    properties = junit_properties(pytester.path / "junit.xml")["scenario_01-known-violation"]
    assert float(properties["stella_fitness"]) == KNOWN_VIOLATION["found"]["fitness"]
    with open(properties["stella_log"], "rb") as log:
        assert log.read(8) == b"\x89MCAP0\r\n"


@pytest.mark.slow
def test_repeats_in_parallel_pass_and_report_a_zero_spread(pytester):
    copy_case(pytester, "safe_fig4.json", "safe")
    copy_case(pytester, "known_violation.json", "known", expect="violation")
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider", "-v", "--stella-repeat", "3", "--stella-workers", "2", "--junitxml=junit.xml")
    result.assert_outcomes(passed=2)
    result.stdout.fnmatch_lines([
        "*stella: fitness spread over repeats*",
        "known.regression.json::scenario_01-known-violation: spread 0.000000 over 3 repeats (mean fitness -2.321973)",
        "safe.regression.json::fig4-safe: spread 0.000000 over 3 repeats (mean fitness 9.88*)",
    ])
    properties = junit_properties(pytester.path / "junit.xml")
    assert float(properties["fig4-safe"]["stella_fitness_spread"]) == 0.0
    assert len({properties["fig4-safe"][f"stella_log_{i}"] for i in (1, 2, 3)}) == 3


@pytest.mark.slow
def test_a_malformed_case_is_a_collection_error_with_the_located_message(pytester):
    copy_case(pytester, "safe_fig4.json", "broken", expect="fixed")
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    assert result.ret == pytest.ExitCode.INTERRUPTED
    result.stdout.fnmatch_lines(['*broken.regression.json: /expect: "fixed" is not allowed; allowed values: "safe", "kept", "violation", "as_reference"'])


@pytest.mark.slow
def test_the_documented_example_suite_passes(pytester):
    shutil.copy(ROOT / "docs" / "examples" / "test_example_suite.py", pytester.path)
    (pytester.path / "scenarios" / "examples").mkdir(parents=True)
    shutil.copy(ROOT / "scenarios" / "examples" / "fig4.json", pytester.path / "scenarios" / "examples")
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider", "--junitxml=junit.xml")
    result.assert_outcomes(passed=2)
    properties = junit_properties(pytester.path / "junit.xml")
    assert properties["test_moving_the_building_onto_the_route_costs_clearance"]["stella_log_2"].endswith("costs_clearance-2.mcap")


@pytest.mark.slow
def test_campaign_then_export_then_pytest_reproduces_the_fitness_the_campaign_found(pytester):
    # Each command in a process of its own, as a user runs them: pytester removes from
    # sys.modules what a test imported, and numpy's extension modules (numpy.fft, which the
    # campaign imports through scipy) cannot be imported again in this process by later tests.
    store = pytester.path / "c.db"
    stella = (sys.executable, "-m", "harness.tools.cli")
    assert pytester.run(*stella, "campaign", str(ROOT / "scenarios" / "table3" / "scenario_02.json"), "--algorithm", "RANDOM", "--evaluations", "4",
                        "--executor", "sequential", "--store", str(store), "--json").ret == 0
    assert pytester.run(*stella, "export-regressions", str(store), "--out", str(pytester.path / "cases"), "--worst", "1", "--json").ret == 0
    [case] = (pytester.path / "cases").glob("*.regression.json")
    found = json.loads(case.read_text())["found"]
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider", "cases", "--junitxml=junit.xml")
    assert result.ret in (pytest.ExitCode.OK, pytest.ExitCode.TESTS_FAILED)
    [properties] = junit_properties(pytester.path / "junit.xml").values()
    assert float(properties["stella_fitness"]) == found["fitness"]
    assert (result.ret == pytest.ExitCode.OK) == (found["status"] == "ok")
