"""Code coverage of the firmware under test: coverage builds, each flight's record, `stella
coverage` over stores, and the coverage-guided search; on the bundled autopilot, through
coverage.py, so that the whole path runs without PX4."""

from __future__ import annotations

import ast
import dataclasses
import json
import os
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT
from harness.campaigns.coverage import NOVELTY_WEIGHT_M, CodeNovelty, code_reached, merged
from harness.campaigns.problem import Trial
from harness.flight.fitness import Status
from harness.tools.cli import main

WALL = ROOT / "scenarios" / "examples" / "wall_concrete.json"


@pytest.fixture(scope="module")
def coverage_build(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("builds")
    assert main(["sut", "build", "bundled", "--source", str(ROOT), "--coverage", "--out", str(out)]) == 0
    [folder] = [path for path in out.iterdir() if (path / "variant.json").is_file()]
    return folder


def function_lines(module: Path, qualified: str) -> set[int]:
    """The lines of a function's body (its docstring too), found by name, not by number."""
    tree = ast.parse(module.read_text())
    scope: list = tree.body
    for name in qualified.split("."):
        node = next(n for n in scope if isinstance(n, (ast.ClassDef, ast.FunctionDef)) and n.name == name)
        scope = node.body
    return set(range(node.body[0].lineno, node.end_lineno + 1))


def test_a_coverage_build_runs_the_sources_and_is_cached_apart(coverage_build, tmp_path, capsys):
    marker = json.loads((coverage_build / "coverage.json").read_text())
    assert marker == {"tool": "coverage.py", "paths": ["autopilot/collision.py"]}
    assert not list((coverage_build / "autopilot").glob("*.so"))
    out = coverage_build.parent
    assert main(["sut", "build", "bundled", "--source", str(ROOT), "--coverage", "--out", str(out), "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["cached"] and again["fly_with"] == {"--autopilot-dir": str(coverage_build)}
    assert main(["sut", "build", "bundled", "--source", str(ROOT), "--coverage", "--coverage-path", "autopilot", "--out", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["folder"] != str(coverage_build)


@pytest.mark.parametrize("arguments, says", [
    (["--coverage", "--coverage-path", "sim_bridge/world.py"], "the bundled autopilot's flights run its autopilot/ package only"),
    (["--coverage", "--coverage-path", "autopilot/nothing.py"], "autopilot/nothing.py: not in"),
    (["--coverage-path", "autopilot/collision.py"], "add --coverage"),
])
def test_a_coverage_path_it_cannot_measure_exits_2_naming_it(tmp_path, capsys, arguments, says):
    assert main(["sut", "build", "bundled", "--source", str(ROOT), *arguments, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("--coverage-path: ") and says in err


def test_a_coverage_guided_search_needs_a_coverage_build(tmp_path, capsys):
    assert main(["campaign", str(ROOT / "scenarios" / "examples" / "wall.json"), "--algorithm", "RANDOM", "--evaluations", "2",
                 "--objective", "coverage", "--store", str(tmp_path / "c.db")]) == 2
    assert "--objective: coverage is guided by the code each flight ran" in capsys.readouterr().err
    assert not (tmp_path / "c.db").exists()


def trial(ordinal: int, fitness: float, lines: list[int]) -> Trial:
    record = {"files": {"a.py": {"lines_hit": lines, "lines_missed": [], "branches_hit": [], "branches_missed": []}}}
    return Trial(ordinal, np.zeros(1), str(ordinal), fitness, Status.OK, reached=code_reached(record))


def test_the_search_is_told_of_code_no_earlier_flight_reached_and_nothing_else():
    first, second, third = trial(0, 5.0, [1, 2, 3]), trial(1, 4.0, [2, 3, 4, 5]), trial(2, 3.0, [1, 5])
    history = [third, first, second]  # finished in any order: told by ordinal
    novelty = CodeNovelty()
    assert novelty.told(5.0, first, history) == pytest.approx(5.0 - 3 * NOVELTY_WEIGHT_M)
    assert novelty.told(4.0, second, history) == pytest.approx(4.0 - 2 * NOVELTY_WEIGHT_M)
    assert novelty.told(3.0, third, history) == 3.0
    assert novelty.told(2.0, Trial(3, np.zeros(1), "3", 2.0, Status.OK), history) == 2.0  # a flight without coverage


def test_a_flight_that_runs_the_target_line_ranks_before_every_flight_that_does_not():
    from harness.campaigns.coverage import TARGET_WEIGHT_M, line_name

    target = line_name("a.py", 9)
    novelty = CodeNovelty([target])
    far_but_on_target, close_elsewhere = trial(0, 40.0, [1, 9]), trial(1, -5.0, [1, 2, 3, 4, 5, 6])
    history = [far_but_on_target, close_elsewhere]
    on_target = novelty.told(40.0, far_but_on_target, history)
    assert on_target == pytest.approx(40.0 - 2 * NOVELTY_WEIGHT_M - TARGET_WEIGHT_M)
    assert on_target < novelty.told(-5.0, close_elsewhere, history) == pytest.approx(-5.0 - 5 * NOVELTY_WEIGHT_M)


def test_the_covering_suite_takes_the_flights_that_add_most_until_nothing_is_left():
    from harness.campaigns.coverage import Flight, covering_suite

    def flight(evaluation: int, lines: list[int], branches: list[str]):
        record = {"files": {"src/x.cpp": {"lines_hit": lines, "lines_missed": [], "branches_hit": branches, "branches_missed": []}}}
        return Flight("a.db", evaluation, float(evaluation)), record

    flights = [flight(1, [1, 2], ["1:0", "1:1"]), flight(2, [1, 2, 3], ["1:0"]), flight(3, [5], ["2:0"]), flight(4, [1], ["1:1"])]
    suite = covering_suite(flights)
    assert [(c.flight.evaluation, c.branches_added, c.lines_added) for c in suite] == [(1, 2, 2), (3, 1, 1), (2, 0, 1)]
    assert covering_suite(flights, "y.cpp") == []


def test_a_covering_suite_keeps_blocked_flights_as_cases_that_must_keep_the_distance_and_leaves_unfinished_ones_out(tmp_path, capsys, profile):
    from conftest import stored_result
    from harness.campaigns.regression import load_regression
    from harness.campaigns.store import Store
    from harness.scenario.logical import load_logical
    from harness.scenario.space import SearchSpace

    space = SearchSpace(load_logical(ROOT / "scenarios" / "examples" / "wall.json", profile), profile)
    store = Store(tmp_path / "c.db")
    run_id, _ = store.run(store.campaign({"scenarios": ["wall.json"], "algorithms": ["RANDOM"], "sut": "bundled"}), "/w/wall.json", space.logical.name, "RANDOM", 0, 1)
    xs = space.sample(np.random.default_rng(0), 3)
    for ordinal, (status, lines) in enumerate([("ok", [1, 2]), ("mission_failed", [1, 3]), ("timeout", [4])]):
        result = dataclasses.replace(stored_result(1.0, status, min_clearance_m=2.0), coverage={
            "files": {"src/cp.cpp": {"lines_hit": lines, "lines_missed": [], "branches_hit": [f"{line}:0" for line in lines], "branches_missed": []}}})
        store.add_evaluation(run_id, ordinal=ordinal, step=0, optimizer="RANDOM", vector=xs[ordinal], result=result, concrete=space.to_concrete(xs[ordinal]))
    store.close()
    assert main(["coverage", str(tmp_path / "c.db"), "--suite", str(tmp_path / "suite"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    cases = {load_regression(path).found["status"]: load_regression(path).expect for path in (tmp_path / "suite").glob("*.regression.json")}
    assert cases == {"ok": "safe", "mission_failed": "kept"}
    assert summary["suite_misses"] == {"branches": 1, "lines": 1}


def test_a_flight_ran_a_changed_line_as_far_as_its_record_tells():
    """A line without code in the record (a constant's definition, a deleted statement) or in a file
    not measured tells nothing: a flight can depend on it without running it."""
    from harness.campaigns.coverage import ran_any

    record = {"files": {"a.cpp": {"lines_hit": [3, 5], "lines_missed": [7], "branches_hit": [], "branches_missed": []}}}
    assert ran_any(record, ["a.cpp:L5"]) is True and ran_any(record, ["a.cpp:L7", "a.cpp:L3"]) is True
    assert ran_any(record, ["a.cpp:L7"]) is False and ran_any(record, ["a.cpp:L7", "a.cpp:L4"]) is False
    assert ran_any(record, ["a.cpp:L4"]) is None and ran_any(record, ["b.cpp:L5"]) is None and ran_any(None, ["a.cpp:L5"]) is None


def test_merged_coverage_names_the_first_flight_to_reach_each_line():
    from harness.campaigns.coverage import Flight

    records = [(Flight("b.db", 7, 2.0), {"files": {"src/x.cpp": {"lines_hit": [1, 2], "lines_missed": [3, 4], "branches_hit": ["1:0"], "branches_missed": ["1:1"]}}}),
               (Flight("a.db", 3, 1.0), {"files": {"src/x.cpp": {"lines_hit": [2, 3], "lines_missed": [1, 4], "branches_hit": [], "branches_missed": ["1:0", "1:1"]}}})]
    [x] = merged(records, "x.cpp")
    summary = x.as_dict()
    assert (summary["lines_hit"], summary["lines_total"], summary["branches_hit"], summary["branches_total"]) == (3, 4, 1, 2)
    assert summary["uncovered_lines"] == [4]
    assert summary["first_reached"] == {"1": {"store": "b.db", "evaluation": 7}, "2": {"store": "a.db", "evaluation": 3},
                                        "3": {"store": "a.db", "evaluation": 3}}
    assert merged(records, "y.cpp") == []


def test_the_html_report_shows_each_line_with_how_many_flights_ran_it(tmp_path):
    import re

    from harness.campaigns.coverage import Flight, write_html

    tree = tmp_path / "tree"
    (tree / "src").mkdir(parents=True)
    (tree / "src" / "x.cpp").write_text("int a;\nint b;\nint c;\nint d;\n")
    records = [(Flight("b.db", 7, 2.0), {"files": {"src/x.cpp": {"lines_hit": [1, 2], "lines_missed": [3, 4], "branches_hit": ["1:0"], "branches_missed": ["1:1"]}}}),
               (Flight("a.db", 3, 1.0), {"files": {"src/x.cpp": {"lines_hit": [2, 3], "lines_missed": [1, 4], "branches_hit": [], "branches_missed": ["1:0", "1:1"]}}})]
    index = write_html(merged(records), tree, tmp_path / "html")
    summary = re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", index.read_text()))
    assert "Lines: 3 / 4 75.0%" in summary and "Branches: 1 / 2 50.0%" in summary
    [page] = (tmp_path / "html").glob("index.x.cpp.*.html")
    text = re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", page.read_text()))
    # each line's count is the number of flights that ran it; line 4 none
    assert "1 int a ; 2 2 int b ; 3 1 int c ; 4 &cross; int d ;" in text


@pytest.mark.slow
def test_each_flight_records_the_code_it_ran_and_the_rigs_code_only_with_a_rig(coverage_build, tmp_path, capsys):
    """A coverage build flies as the compiled autopilot does (same clearance); the DISTANCE_SENSOR
    code of the collision prevention runs only in the flight with rangefinders, and `stella
    coverage` over both campaigns names that flight as the first to reach it."""
    plain, rigged = tmp_path / "plain.db", tmp_path / "rigged.db"
    for store, rig in ((plain, []), (rigged, ["--rig", "four_rangefinders"])):
        assert main(["campaign", str(ROOT / "scenarios" / "examples" / "wall.json"), "--algorithm", "RANDOM", "--evaluations", "2", "--drive", "pilot",
                     "--autopilot-dir", str(coverage_build), "--sut-param", "CP_STICK_ACCEL=1", "--store", str(store), *rig]) == 0
    capsys.readouterr()
    assert main(["coverage", str(plain), str(rigged), "--source", "collision.py", "--json"]) == 0
    [report] = json.loads(capsys.readouterr().out)["files"]
    assert report["file"] == "autopilot/collision.py" and 0 < report["lines_hit"] < report["lines_total"]
    assert report["lines_total"] - report["lines_hit"] == len(report["uncovered_lines"])
    reached_first = {int(line): where for line, where in report["first_reached"].items()}
    rangefinders = function_lines(coverage_build / "autopilot" / "collision.py", "ObstacleMap.update_distance_sensor") & set(reached_first)
    assert len(rangefinders) > 5 and {reached_first[line]["store"] for line in rangefinders} == {str(rigged)}
    # A suite of the fewest flights that reach it all, as regression cases expecting what each flight did
    from harness.campaigns.regression import load_regression

    assert main(["coverage", str(plain), str(rigged), "--source", "collision.py", "--suite", str(tmp_path / "suite"), "--json"]) == 0
    chosen = json.loads(capsys.readouterr().out)
    cases = [load_regression(path) for path in sorted((tmp_path / "suite").glob("*.regression.json"))]
    assert len(cases) == len(chosen["suite"]) >= 1 and chosen["suite"][0]["branches_added"] > 0
    assert {case.expect for case in cases} <= {"safe", "kept", "violation"}
    # The HTML report shows the sources the coverage build ran
    assert main(["coverage", str(plain), str(rigged), "--source", "collision.py", "--html", str(tmp_path / "html"), "--json"]) == 0
    html = Path(json.loads(capsys.readouterr().out)["html"])
    [page] = html.parent.glob("index.collision.py.*.html")
    assert "update_distance_sensor" in page.read_text() and f"{report['lines_hit']} / {report['lines_total']}" in html.read_text()
    # The compiled autopilot flies the same flight
    from harness.campaigns.store import Store
    from harness.flight.evaluation import evaluate
    from harness.flight.results import RunOptions
    from harness.scenario.world import space_from_concrete
    from sut_adapter import SutConfig

    with Store.existing(plain) as store:
        flown = next(e for e in store.all_evaluations() if e.coverage)
    space = space_from_concrete(flown.concrete, "stored")
    compiled = evaluate(space, space.from_concrete(flown.concrete, "stored"), seed=flown.seed, out_dir=tmp_path,
                        options=RunOptions(cores=1, sut=SutConfig("bundled", {"CP_STICK_ACCEL": 1})), name="compiled")
    assert compiled.coverage is None and compiled.min_clearance_m == flown.min_clearance_m


@pytest.mark.slow
def test_a_coverage_guided_campaign_stores_each_flights_coverage(coverage_build, tmp_path, capsys):
    store = tmp_path / "guided.db"
    assert main(["campaign", str(ROOT / "scenarios" / "examples" / "wall.json"), "--algorithm", "NSGAII", "--evaluations", "8", "--population", "4",
                 "--drive", "pilot", "--autopilot-dir", str(coverage_build), "--objective", "coverage", "--store", str(store)]) == 0
    from harness.campaigns.store import Store

    with Store.existing(store) as opened:
        flown = [e for e in opened.all_evaluations() if e.status != Status.INFEASIBLE]
    assert flown and all(e.coverage["files"]["autopilot/collision.py"]["lines_hit"] for e in flown)


def toy_firmware(tree: Path) -> None:
    """A tree shaped as PX4's: an executable `px4` of two libraries, one of them measured."""
    (tree / "src" / "lib" / "measured").mkdir(parents=True)
    (tree / "src" / "other").mkdir(parents=True)
    (tree / "CMakeLists.txt").write_text("cmake_minimum_required(VERSION 3.19)\nproject(toy C)\nadd_subdirectory(src/lib/measured)\n"
                                         "add_subdirectory(src/other)\nadd_executable(px4 main.c)\ntarget_link_libraries(px4 measured other)\n")
    (tree / "src" / "lib" / "measured" / "CMakeLists.txt").write_text("add_library(measured STATIC guard.c)\n")
    (tree / "src" / "lib" / "measured" / "guard.c").write_text(
        "int guard(int distance)\n{\n\tif (distance < 2) {\n\t\treturn 0;\n\t}\n\n\treturn distance;\n}\n")
    (tree / "src" / "other" / "CMakeLists.txt").write_text("add_library(other STATIC other.c)\n")
    (tree / "src" / "other" / "other.c").write_text("int other(int x)\n{\n\treturn x > 3 ? 1 : 2;\n}\n")
    (tree / "main.c").write_text("int guard(int);\nint other(int);\nint main(void)\n{\n\treturn guard(5) + other(1) == 7 ? 0 : 1;\n}\n")


def test_a_gcov_build_measures_its_paths_only_and_each_flight_keeps_its_own_counters(tmp_path):
    """PX4's coverage build on a tree of PX4's shape: our CMake include instruments the measured
    folder's targets only, the variant keeps their notes and sources, and a run's counters,
    written under its own working directory, are summarised by gcovr, whatever the tree holds by
    then."""
    import subprocess

    from harness.firmware.builds import COVERAGE_CMAKE, _keep_notes
    from sut_adapter.coverage import gcov_environment, gcov_record, mark_coverage_build

    tree, build_dir, folder, flight = tmp_path / "tree", tmp_path / "tree" / "build" / "sitl_coverage", tmp_path / "variant", tmp_path / "flight"
    toy_firmware(tree)
    include = tmp_path / "stella_coverage.cmake"
    include.write_text(COVERAGE_CMAKE)
    subprocess.run(["cmake", "-S", str(tree), "-B", str(build_dir), f"-DCMAKE_PROJECT_INCLUDE={include}", "-DSTELLA_COVERAGE_PATHS=src/lib/measured"],
                   check=True, capture_output=True)
    subprocess.run(["cmake", "--build", str(build_dir)], check=True, capture_output=True)
    assert [p.name for p in build_dir.glob("**/*.gcno")] == ["guard.c.gcno"]
    folder.mkdir()
    _keep_notes(tree, build_dir, folder, ["src/lib/measured"])
    mark_coverage_build(folder, "gcov", ["src/lib/measured"], build_dir=str(build_dir))
    (tree / "src" / "lib" / "measured" / "guard.c").write_text("moved on\n")  # the worktree of the next variant
    flight.mkdir()
    build = json.loads((folder / "coverage.json").read_text())
    subprocess.run([str(build_dir / "px4")], check=True, env={"PATH": "/usr/bin:/bin", **gcov_environment(build, flight)})
    assert not list(build_dir.glob("**/*.gcda"))  # the build folder is left alone
    # guard(5): the function's line and the test ran, the early return did not; the test's branch
    # to it was not taken, the other was; read against the sources the build kept
    assert gcov_record(build, folder, flight) == {"tool": "gcov", "sources": str((folder / "coverage" / "sources").resolve()), "files": {
        "src/lib/measured/guard.c": {"lines_hit": [1, 3, 7], "lines_missed": [4], "branches_hit": ["3:1"], "branches_missed": ["3:0"]}}}
    assert gcov_record(build, folder, tmp_path / "no-flight") is None


def waf_shaped_build(tree: Path, build_dir: Path, *, blocks: bool = False) -> Path:
    """A toy firmware compiled as ArduPilot's waf compiles, each object in the build folder from a
    source named relative to it (../../libraries/...), all of it with --coverage; `blocks`: its
    main then waits on a pipe nobody writes, as ArduPilot waits for its next physics frame."""
    import subprocess

    toy_firmware(tree)
    (tree / "libraries").mkdir()
    (tree / "src" / "lib" / "measured").rename(tree / "libraries" / "measured")
    (tree / "src" / "other").rename(tree / "libraries" / "other")
    main_c = (tree / "main.c").read_text()
    if blocks:
        main_c = main_c.replace("int main(void)\n{\n", "#include <unistd.h>\nint main(void)\n{\n\tint ends[2];\n\tchar byte;\n"
                                                       "\tif (pipe(ends) == 0 && read(ends[0], &byte, 1) < 0)\n\t\treturn 2;\n")
    (tree / "main.c").write_text(main_c)
    objects = []
    for source in ("libraries/measured/guard.c", "libraries/other/other.c", "main.c"):
        (build_dir / source).parent.mkdir(parents=True, exist_ok=True)
        objects.append(str(build_dir / f"{source}.0.o"))
        subprocess.run(["cc", "--coverage", "-c", f"../../{source}", "-o", objects[-1]], cwd=build_dir, check=True)
    (build_dir / "bin").mkdir()
    subprocess.run(["cc", "--coverage", *objects, "-o", str(build_dir / "bin" / "arducopter")], check=True)
    return build_dir / "bin" / "arducopter"


def test_an_ardupilot_build_measures_its_paths_from_counters_of_the_whole_program_without_its_sources(tmp_path):
    """ArduPilot's coverage build instruments every object, and its waf names each source relative
    to the worktree's build folder: a flight's record keeps the measured paths only, relative to the
    tree, read by fastcov from gcov's JSON, whatever the worktree holds by then."""
    import subprocess

    from harness.firmware.builds import _keep_notes
    from sut_adapter.coverage import fastcov_record, gcov_environment, mark_coverage_build

    tree, folder, flight = tmp_path / "tree", tmp_path / "variant", tmp_path / "flight"
    build_dir = tree / "build_coverage" / "sitl"
    binary = waf_shaped_build(tree, build_dir)
    folder.mkdir()
    _keep_notes(tree, build_dir, folder, ["libraries/measured"])
    mark_coverage_build(folder, "gcov", ["libraries/measured"], build_dir=str(build_dir), tree=str(tree))
    (tree / "libraries" / "measured" / "guard.c").unlink()  # the worktree moved on to the next variant
    flight.mkdir()
    build = json.loads((folder / "coverage.json").read_text())
    subprocess.run([str(binary)], check=True, env={"PATH": "/usr/bin:/bin", **gcov_environment(build, flight)})
    assert len(list(flight.glob("gcov/**/*.gcda"))) == 3  # every object's counters, the measured one's read
    assert fastcov_record(build, folder, flight) == {"tool": "gcov", "sources": str((folder / "coverage" / "sources").resolve()), "files": {
        "libraries/measured/guard.c": {"lines_hit": [1, 3, 7], "lines_missed": [4], "branches_hit": ["3:1"], "branches_missed": ["3:0"]}}}
    assert fastcov_record(build, folder, tmp_path / "no-flight") is None


def test_the_exit_library_makes_a_program_waiting_for_its_clock_write_its_counters_on_sigusr1(tmp_path):
    """ArduPilot's SITL acts on SIGTERM only when its simulated clock moves on; the library a
    coverage build's flights preload ends it on SIGUSR1 through exit(), which writes gcov's
    counters. Without it, the same signal kills it and leaves none."""
    import signal
    import subprocess
    import time

    from harness.firmware.ardupilot_build import compile_exit_shim

    tree, folder = tmp_path / "tree", tmp_path / "variant"
    build_dir = tree / "build_coverage" / "sitl"
    binary = waf_shaped_build(tree, build_dir, blocks=True)
    folder.mkdir()
    log_path = folder / "build.log"
    with open(log_path, "w") as log_file:
        shim = compile_exit_shim(folder, log_file, log_path)
    for preload, written in ((str(shim), True), ("", False)):
        counters = tmp_path / f"counters-{bool(preload)}"
        env = {"PATH": "/usr/bin:/bin", "GCOV_PREFIX": str(counters), "GCOV_PREFIX_STRIP": str(len(build_dir.parts) - 1), "LD_PRELOAD": preload}
        waiting = subprocess.Popen([str(binary)], env=env)
        time.sleep(0.3)
        assert waiting.poll() is None  # blocked, as ArduPilot on a finished flight
        waiting.send_signal(signal.SIGUSR1)
        assert waiting.wait(timeout=10) == (0 if written else -signal.SIGUSR1)
        assert bool(list(counters.glob("**/*.gcda"))) == written


def test_a_coverage_guided_mutation_run_needs_mutants_built_for_coverage(tmp_path, capsys):
    from harness.firmware import mutants

    folder = tmp_path / "mutation"
    mutants.generate(ROOT, "autopilot/collision.py", folder, limit=2, seed=1)
    (folder / mutants.BUILT).write_text(json.dumps({"mutants": {}, "original": {"folder": str(ROOT)}}))
    assert main(["mutants", "run", str(folder), "--suite", str(WALL), "--objective", "coverage"]) == 2
    assert "--objective: coverage is guided by the code each flight ran: build the mutants with `stella mutants build --coverage`" in capsys.readouterr().err


@pytest.mark.slow
def test_mutants_built_for_coverage_record_it_and_their_searches_are_guided_by_it(tmp_path):
    from harness.campaigns.store import Store
    from harness.firmware import mutants

    folder = tmp_path / "mutation"
    index = mutants.generate(ROOT, "autopilot/collision.py", folder)
    # range data counts as fresh for longer: the wall does not kill it, so it is searched
    quiet = next(m for m in index["mutants"] if m["original"].strip() == "STALE_AFTER_S = 0.5" and m["mutated"].strip() == "STALE_AFTER_S = 1.0")
    index["mutants"] = [quiet]
    (folder / mutants.INDEX).write_text(json.dumps(index))
    assert main(["mutants", "build", str(folder), "--coverage"]) == 0
    assert main(["mutants", "build", str(folder)]) == 2  # built with coverage: not again without
    assert main(["mutants", "run", str(folder), "--suite", str(WALL), "--scenario", str(ROOT / "scenarios" / "examples" / "wall.json"),
                 "--algorithm", "NSGAII", "--evaluations", "3", "--population", "2", "--objective", "coverage", "--workers", "1"]) == 0
    [search] = sorted((folder / "search").glob("*/*.db"))
    with Store.existing(search) as store:
        flights = [e for e in store.all_evaluations() if e.status != Status.INFEASIBLE]
        identity = store.campaign_config()
    assert flights and all(e.coverage["files"]["autopilot/collision.py"]["lines_hit"] for e in flights)
    # the search aims at the mutated line first
    assert identity["coverage_target"] == [f"autopilot/collision.py:L{quiet['line']}"]
    # an unguided search of the same budget joins it in the folder, and the report compares them
    assert main(["mutants", "run", str(folder), "--suite", str(WALL), "--scenario", str(ROOT / "scenarios" / "examples" / "wall.json"),
                 "--algorithm", "RANDOM", "--evaluations", "3", "--population", "2", "--workers", "1"]) == 0
    from harness.firmware import mutation

    assert set(mutation.report(folder)["scores"]) == {"NSGAII+coverage", "RANDOM"}
    assert sorted(path.name for path in (folder / "search").glob("*/*.db")) == ["wall-NSGAII_coverage.db", "wall-RANDOM.db"]


def body_lines(source: Path, signature: str) -> set[int]:
    """The lines of a C++ function's body: from its signature's line to the closing brace at the
    start of a line."""
    lines = source.read_text().splitlines()
    start = next(number for number, text in enumerate(lines, start=1) if signature in text)
    end = next(number for number, text in enumerate(lines[start:], start=start + 1) if text.startswith("}"))
    return set(range(start, end + 1))


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("STELLA_PX4_COVERAGE_BIN"), reason="needs a PX4 coverage build (`stella sut build px4 --coverage`: STELLA_PX4_COVERAGE_BIN)")
def test_px4s_coverage_shows_which_range_data_its_collision_prevention_used(tmp_path):
    """A flight with the profile's sensor (DISTANCE_SENSOR) runs _addDistanceSensorData and not
    _addObstacleSensorData; one with a depth camera on the companion link (OBSTACLE_DISTANCE) the
    other way round. A flight named as a mutant's suite case is (its working directory after it,
    longer than gcov's report names can hold unhashed) reports as well."""
    from harness.flight.evaluation import evaluate
    from harness.flight.results import RunOptions
    from harness.scenario.world import load_concrete, space_with_rig
    from sut_adapter import SutConfig

    build = Path(os.environ["STELLA_PX4_COVERAGE_BIN"])
    source = build / "coverage" / "sources" / "src" / "lib" / "collision_prevention" / "CollisionPrevention.cpp"
    obstacle_distance = body_lines(source, "CollisionPrevention::_addObstacleSensorData(")
    distance_sensor = body_lines(source, "CollisionPrevention::_addDistanceSensorData(")
    space, x = load_concrete(WALL, "pilot")
    options = RunOptions(sut=SutConfig("px4", {"CP_DIST": 1.5}, px4_bin=str(build)), sut_logs="failures")
    hit = {}
    long_name = "m0089-wall_local_lidar_probe-nsga-wall_local_lidar_probe-NSGAII-run0-eval00004-depth_camera"
    for name, flown in (("profile", space), (long_name, space_with_rig(space, "depth_camera"))):
        result = evaluate(flown, x, seed=0, out_dir=tmp_path, options=options, name=name)
        hit[name] = set(result.coverage["files"]["src/lib/collision_prevention/CollisionPrevention.cpp"]["lines_hit"])
    assert hit["profile"] & distance_sensor and not hit["profile"] & obstacle_distance
    assert hit[long_name] & obstacle_distance and not hit[long_name] & distance_sensor


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("STELLA_ARDUPILOT_COVERAGE_BIN"),
                    reason="needs an ArduPilot coverage build (`stella sut build ardupilot --coverage`: STELLA_ARDUPILOT_COVERAGE_BIN)")
def test_ardupilots_coverage_shows_which_proximity_backend_its_avoidance_used(tmp_path):
    """ArduCopter's avoidance reads the profile's sensor as rangefinders (AP_Proximity_RangeFinder)
    and a lidar rig's OBSTACLE_DISTANCE through its MAVLink backend (AP_Proximity_MAV): each
    flight's record runs the one and not the other, and the avoidance's own code in both."""
    from harness.flight.evaluation import evaluate
    from harness.flight.results import RunOptions
    from harness.scenario.world import load_concrete, space_with_rig
    from sut_adapter import SutConfig

    space, x = load_concrete(WALL, "pilot")
    options = RunOptions(sut=SutConfig("ardupilot", {}, ardupilot_bin=os.environ["STELLA_ARDUPILOT_COVERAGE_BIN"]), sut_logs="failures")
    reached = {}
    for name, flown in (("profile", space), ("lidar", space_with_rig(space, "lidar_360"))):
        result = evaluate(flown, x, seed=0, out_dir=tmp_path, options=options, name=name)
        files = result.coverage["files"]
        reached[name] = {path for path, lines in files.items() if lines["lines_hit"]}
        assert all(path.startswith(("libraries/AC_Avoidance/", "libraries/AP_Proximity/")) for path in files)
    backends = {"libraries/AP_Proximity/AP_Proximity_RangeFinder.cpp", "libraries/AP_Proximity/AP_Proximity_MAV.cpp"}
    assert reached["profile"] & backends == {"libraries/AP_Proximity/AP_Proximity_RangeFinder.cpp"}
    assert reached["lidar"] & backends == {"libraries/AP_Proximity/AP_Proximity_MAV.cpp"}
    assert "libraries/AC_Avoidance/AC_Avoid.cpp" in reached["profile"] & reached["lidar"]
