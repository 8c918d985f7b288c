"""Mutants and builds from source (harness/firmware/): generation with the operators and the
lines left alone, builds cached by key, equivalent and duplicate mutants sorted out by their
compiled code, and the whole mutation analysis and differential search flown against the
bundled autopilot's collision prevention. PX4's builds run in tests/test_px4_builds.py where a
PX4 source tree is given."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import shutil
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import ROOT
from harness.campaigns.store import Store
from harness.errors import InputError
from harness.firmware import builds, mutants, mutation
from harness.tools.cli import main

COLLISION = "autopilot/collision.py"
# A small C++ file in a PX4-shaped tree: what the generator must and must not touch.
CPP = """\
#include "CollisionPrevention.hpp"
// a comment with a < and 2.0
void CollisionPrevention::modifySetpoint(float &speed, float dist)
{
\tPX4_INFO("distance %f", (double)dist);
\tif (dist < _param_cp_dist.get()) {
\t\tspeed = math::min(speed, 0.5f * dist);
\t}
}

void CollisionPrevention::other(float &x)
{
\tx = x + 1.0f;
}
"""


def px4_shaped_tree(root: Path) -> Path:
    for folder in ("boards/px4/sitl", "platforms/posix", "src/lib/collision_prevention"):
        (root / folder).mkdir(parents=True, exist_ok=True)
    (root / "src/lib/collision_prevention/CollisionPrevention.cpp").write_text(CPP)
    return root


def test_cpp_mutants_cover_the_operators_and_leave_logging_comments_and_includes_alone(tmp_path):
    tree = px4_shaped_tree(tmp_path / "px4")
    index = mutants.generate(tree, "src/lib/collision_prevention/CollisionPrevention.cpp", tmp_path / "out", function="modifySetpoint")
    by_line: dict[int, list[str]] = {}
    for m in index["mutants"]:
        by_line.setdefault(m["line"], []).append(m["mutated"].strip())
    assert set(by_line) <= {6, 7}, "only the function's code lines: not its log line, the comment, the include or the other function"
    assert "if (dist <= _param_cp_dist.get()) {" in by_line[6]  # relational operator replacement
    assert "if (!(dist < _param_cp_dist.get())) {" in by_line[6]  # condition negation
    assert "speed = math::max(speed, 0.5f * dist);" in by_line[7]  # min/max swap
    assert "speed = math::min(speed, 1.0f * dist);" in by_line[7]  # constant perturbation of a whole literal
    assert "speed = math::min(speed, 0.5f / dist);" in by_line[7]  # arithmetic operator replacement
    assert any(text.startswith("/*") for text in by_line[7])  # statement deletion
    assert not any(".(" in text for texts in by_line.values() for text in texts), "a float literal is never split into pieces"
    patch = (tmp_path / "out" / "mutants" / "m0001.patch").read_text()
    assert patch.startswith("--- a/src/lib/collision_prevention/CollisionPrevention.cpp")
    assert subprocess.run(["git", "apply", "--check", str(tmp_path / "out" / "mutants" / "m0001.patch")], cwd=tree).returncode == 0


def test_python_mutants_skip_docstrings_imports_and_seeded_fault_switches(tmp_path):
    index = mutants.generate(ROOT, COLLISION, tmp_path, limit=None)
    lines = (ROOT / COLLISION).read_text().splitlines()
    touched = {m["line"] for m in index["mutants"]}
    assert not any(lines[n - 1].lstrip().startswith(("import", "from ", "#")) or "fault" in lines[n - 1] for n in touched)
    assert 1 not in touched and 5 not in touched  # the module docstring
    assert index["generated"] == len(index["mutants"]) > 100


def test_a_sample_is_seeded_and_a_function_limits_the_lines(tmp_path):
    first = mutants.generate(ROOT, COLLISION, tmp_path / "a", limit=10, seed=3)
    again = mutants.generate(ROOT, COLLISION, tmp_path / "b", limit=10, seed=3)
    assert first["mutants"] == again["mutants"] and len(first["mutants"]) == 10
    more = mutants.generate(ROOT, COLLISION, tmp_path / "e", limit=15, seed=3)
    taken = {(m["line"], m["mutated"]) for m in more["mutants"]}
    assert {(m["line"], m["mutated"]) for m in first["mutants"]} <= taken, "a larger sample keeps the smaller one's mutants"
    span = mutants.generate(ROOT, COLLISION, tmp_path / "c", function="max_speed_from_distance")
    low, high = span["lines"]
    assert all(low <= m["line"] <= high for m in span["mutants"]) and high - low < 20
    with pytest.raises(InputError, match="no definition of 'nothing_like_this'"):
        mutants.generate(ROOT, COLLISION, tmp_path / "d", function="nothing_like_this")


def test_bad_sources_commits_and_patches_are_refused_with_exit_2(tmp_path, capsys):
    assert main(["sut", "build", "px4", "--source", str(tmp_path), "--out", str(tmp_path / "cache")]) == 2
    assert "neither a PX4-Autopilot source tree" in capsys.readouterr().err
    ardupilot = tmp_path / "ardupilot"
    for folder in ("ArduCopter", "libraries/AP_HAL_SITL"):
        (ardupilot / folder).mkdir(parents=True)
    (ardupilot / "waf").write_text("")
    assert main(["sut", "build", "px4", "--source", str(ardupilot), "--out", str(tmp_path / "cache")]) == 2
    assert "is a ardupilot tree, not px4" in capsys.readouterr().err
    assert main(["sut", "build", "bundled", "--source", str(ROOT), "--commit", "no-such-commit", "--out", str(tmp_path / "cache")]) == 2
    assert "is not a commit of" in capsys.readouterr().err
    (tmp_path / "bad.patch").write_text("--- a/autopilot/collision.py\n+++ b/autopilot/collision.py\n@@ -1,1 +1,1 @@\n-nothing like this line\n+x\n")
    assert main(["sut", "build", "bundled", "--source", str(ROOT), "--patch", str(tmp_path / "bad.patch"), "--out", str(tmp_path / "cache")]) == 2
    assert "does not apply" in capsys.readouterr().err
    assert main(["mutants", "generate", "--source", str(ROOT), "--file", "autopilot/nothing.py", "--out", str(tmp_path / "m")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_a_bundled_build_at_a_commit_is_cached_and_flies(tmp_path, capsys):
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
    argv = ["sut", "build", "bundled", "--source", str(ROOT), "--commit", head, "--out", str(tmp_path), "--json"]
    assert main(argv) == 0
    first = json.loads(capsys.readouterr().out)
    assert first["commit"] == head and Path(first["folder"], "autopilot", "collision.py").is_file()
    assert main(argv) == 0 and json.loads(capsys.readouterr().out)["cached"]
    # the build's package is what imports, as the adapter starts it (in a working directory of its own)
    started = subprocess.run([sys.executable, "-c", "import autopilot.collision as c; print(c.__file__)"], capture_output=True, text=True,
                             env={**os.environ, "PYTHONPATH": first["folder"]}, cwd=tmp_path)
    assert started.returncode == 0 and started.stdout.startswith(first["folder"]), started.stderr


def test_a_variant_built_before_without_the_mutated_file_watched_still_tells_equivalent_mutants(tmp_path, capsys):
    """`stella sut build` of the original into the cache that `mutants build --cache` then uses:
    the original's digest of the mutated file is made when first asked for, so a mutant that
    compiles to the same code is equivalent, not built."""
    assert main(["sut", "build", "bundled", "--source", str(ROOT), "--out", str(tmp_path / "cache"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["objects"] == {}
    folder = tmp_path / "m"
    index = mutants.generate(ROOT, "autopilot/collision.py", folder, limit=1, seed=1)
    [mutant] = index["mutants"]
    # a mutant that changes no computation: the line's own text again, with a comment
    patch = folder / "mutants" / f"{mutant['id']}.patch"
    lines = patch.read_text().splitlines(keepends=True)
    removed = next(line for line in lines if line.startswith("-") and not line.startswith("---"))
    patch.write_text("".join(("+" + removed[1:].rstrip("\n") + "  # the same\n") if line.startswith("+") and not line.startswith("+++") else line
                             for line in lines))
    record = mutants.build_all(folder, cache=tmp_path / "cache")
    assert record["original"]["digest"] and record["mutants"][mutant["id"]]["state"] == "equivalent"


def test_bytecode_tells_computation_from_comments():
    source = "def f(x):\n    return x < 1.0\n"
    assert builds.bytecode_digest(source) == builds.bytecode_digest("def f(x):\n    # why\n\n    return x < 1.0  # note\n")
    assert builds.bytecode_digest(source) != builds.bytecode_digest(source.replace("<", "<="))


def _mutant_with(index: dict, original: str, mutated: str) -> dict:
    return next(m for m in index["mutants"] if m["original"].strip() == original and m["mutated"].strip() == mutated)


def _add_mutant(folder: Path, index: dict, ident: str, line: int, new_text: str) -> None:
    """A hand-made mutant beside the generated ones (same patch format), to test sorting."""
    lines = (ROOT / COLLISION).read_text().splitlines(keepends=True)
    import difflib

    changed = lines[: line - 1] + [new_text] + lines[line:]
    (folder / "mutants" / f"{ident}.patch").write_text("".join(difflib.unified_diff(lines, changed, f"a/{COLLISION}", f"b/{COLLISION}")))
    index["mutants"].append({"id": ident, "file": COLLISION, "line": line, "rule": "by hand", "original": lines[line - 1].rstrip("\n"),
                             "mutated": new_text.rstrip("\n")})


@pytest.mark.parametrize(("search", "said"), [
    (None, "survived the suite"),  # screened, its searches still to come
    ({"NSGAII": {"wall": {"evaluation": None, "level": None}}}, "survived the suite; survived 1 search"),
    ({"NSGAII": {"wall": {"evaluation": None, "level": None}, "scenario_10": {"evaluation": 12, "level": "behaviour"}}},
     "survived the suite; killed by NSGAII on scenario_10 (behaviour after 12 evaluations)"),
])
def test_the_progress_line_says_what_a_survivor_has_been_through_so_far(search, said):
    outcome = {"state": "survived_suite", "suite_flights": 17, **({"search": search} if search else {})}
    assert mutation.describe(outcome) == said


def test_the_report_compares_algorithms_over_their_finished_searches_and_scores_every_kill(tmp_path):
    # GIVEN three survivors of the suite searched on two scenarios, RANDOM's searches of the third
    # still under way: m0002 not killed after one scenario, m0003 killed on its first
    folder = tmp_path / "mutation"
    index = mutants.generate(ROOT, COLLISION, folder, limit=3)
    ids = [m["id"] for m in index["mutants"]]
    nothing = {"evaluation": None, "level": None, "first_unsafe": None, "budget": 40}
    found = {**nothing, "evaluation": 3, "level": "behaviour"}
    searches = [{"NSGAII": {"s1": nothing, "s2": {**found, "evaluation": 5}}, "RANDOM": {"s1": nothing, "s2": nothing}},
                {"NSGAII": {"s1": nothing, "s2": nothing}, "RANDOM": {"s1": nothing}},
                {"NSGAII": {"s1": nothing, "s2": nothing}, "RANDOM": {"s1": found}}]
    (folder / mutation.RUN).write_text(json.dumps({"screening": {}, "searching": {"evaluations": 40}, "mutants": {
        key: {"state": "survived_suite", "suite_flights": 1, "search": search} for key, search in zip(ids, searches)}}))

    report = mutation.report(folder)

    # THEN RANDOM's unfinished searches are left out of the comparison, killed or not, and its
    # kill counts in the score
    nsga, random = report["scores"]["NSGAII"]["any"], report["scores"]["RANDOM"]["any"]
    assert (nsga["search_kills"], nsga["survivors_searched"], nsga["searches_unfinished"], nsga["median_evaluations_to_kill"]) == (1, 3, 0, 45)
    assert (random["search_kills"], random["survivors_searched"], random["searches_unfinished"], random["median_evaluations_to_kill"]) == (0, 1, 2, None)
    assert random["killed"] == 1 and nsga["killed"] == 1
    assert "not in the search kills' comparison, their searches not yet through every scenario (a kill counts in the score): RANDOM 2 survivors" \
        in mutation.report_text(report)


def test_searches_of_another_objective_share_a_folder_by_name_and_an_older_folders_one_objective_names_them(tmp_path):
    plan = mutation.MutationPlan(suite=("wall.json",), algorithms=("NSGAII", "RANDOM"))
    guided = dataclasses.replace(plan, objective="coverage")
    assert [plan.searcher(a) for a in plan.algorithms] == ["NSGAII", "RANDOM"] and guided.searcher("NSGAII") == "NSGAII+coverage"
    assert guided.searching() == plan.searching()  # guided searches count alike: one budget
    # A folder searched before searches were named by objective kept its one objective in "searching"
    folder = tmp_path / "mutation"
    index = mutants.generate(ROOT, COLLISION, folder, limit=2)
    nothing = {"evaluation": None, "level": None, "first_unsafe": None, "budget": 40}
    found = {**nothing, "evaluation": 7, "level": "behaviour"}
    (folder / mutation.RUN).write_text(json.dumps({"screening": guided.screening(), "searching": {"evaluations": 40, "population": 10, "objective": "coverage"},
                                                   "mutants": {index["mutants"][0]["id"]: {"state": "survived_suite", "suite_flights": 1,
                                                                                           "search": {"NSGAII": {"wall": found}}}}}))
    assert list(mutation.report(folder)["scores"]) == ["NSGAII+coverage"]
    with pytest.raises(InputError, match="before a search's name carried its objective"):
        mutation._load(folder / mutation.RUN, guided)


@pytest.mark.slow
def test_mutation_analysis_of_the_bundled_collision_prevention_end_to_end(tmp_path):
    folder = tmp_path / "mutation"
    # GIVEN every mutant of the CP module, of which we keep three generated ones and two made by
    # hand: one that only adds a comment (equivalent), one the same as a generated one (duplicate)
    index = mutants.generate(ROOT, COLLISION, folder)
    braking = _mutant_with(index, "vn -= (along - allowed) * bin_n", "pass")  # stops limiting the velocity north: flies into the wall
    quiet = _mutant_with(index, "STALE_AFTER_S = 0.5", "STALE_AFTER_S = 1.0")  # range data counts as fresh for longer: same flights here
    broken = next(m for m in index["mutants"] if m["mutated"].strip() == "pass" and m["original"].rstrip().endswith(":"))  # no body: stillborn
    kept = [braking, quiet, broken]
    index["mutants"] = kept
    line = braking["line"]
    source_line = (ROOT / COLLISION).read_text().splitlines()[line - 1]
    _add_mutant(folder, index, "m9001", line, source_line + "  # the same code\n")
    _add_mutant(folder, index, "m9002", quiet["line"], quiet["mutated"].replace("1.0", "1.00") + "\n")
    (folder / mutants.INDEX).write_text(json.dumps(index))

    # WHEN they are built
    assert main(["mutants", "build", str(folder)]) == 0
    built = json.loads((folder / mutants.BUILT).read_text())["mutants"]
    assert built[braking["id"]]["state"] == "built" and built[quiet["id"]]["state"] == "built"
    assert built[broken["id"]]["state"] == "stillborn" and Path(built[broken["id"]]["log"]).is_file()
    assert built["m9001"]["state"] == "equivalent"
    assert built["m9002"]["state"] == "duplicate" and built["m9002"]["same_as"] == quiet["id"]
    # built again from scratch, every variant comes from the cache, sorted the same
    (folder / mutants.BUILT).unlink()
    record = mutants.build_all(folder)
    assert all(entry["cached"] for entry in record["mutants"].values() if entry["state"] != "stillborn")
    assert {key: entry["state"] for key, entry in record["mutants"].items()} == {key: entry["state"] for key, entry in built.items()}

    # AND screened with the wall, the survivors searched with two algorithms
    wall = ROOT / "scenarios" / "examples" / "wall_concrete.json"
    argv = ["mutants", "run", str(folder), "--suite", str(wall), "--scenario", str(ROOT / "scenarios" / "examples" / "wall.json"),
            "--algorithm", "RANDOM", "--algorithm", "NSGAII", "--evaluations", "3", "--population", "2", "--workers", "2"]
    assert main(argv) == 0
    outcomes = json.loads((folder / mutation.RUN).read_text())["mutants"]
    # THEN the mutant that flies into the wall is killed by the suite, as unsafe
    assert outcomes[braking["id"]]["state"] == "killed_by_suite" and outcomes[braking["id"]]["level"] == "unsafe"
    # and the other was searched by both algorithms, its searches stored
    assert outcomes[quiet["id"]]["state"] == "survived_suite" and set(outcomes[quiet["id"]]["search"]) == {"RANDOM", "NSGAII"}
    assert len(list((folder / "search" / quiet["id"]).glob("*.db"))) == 2
    # the reference flew the wall once for both mutants
    with contextlib.closing(sqlite3.connect(folder / mutation.CACHE)) as cache:
        assert cache.execute("SELECT COUNT(*) FROM reference_flights").fetchone()[0] >= 1

    # AND a second run resumes: nothing left to fly
    assert main(argv) == 0
    report = mutation.report(folder)
    assert report["built"] == {"built": 2, "stillborn": 1, "equivalent": 1, "duplicate": 1} and report["analysed"] == 2
    assert report["killed_by_suite"]["unsafe"] == 1
    assert report["scores"]["RANDOM"]["any"]["killed"] >= 1 and report["scores"]["RANDOM"]["any"]["mutants"] == 2
    text = mutation.report_text(report)
    assert "killed by the suite: 1 unsafe" in text and "RANDOM" in text
    # beside another test method's kills (here made up: it kills only the survivor)
    other = tmp_path / "unit.json"
    other.write_text(json.dumps({"mutants": {braking["id"]: {"killed": False}, quiet["id"]: {"killed": True}}}))
    table = mutation.report(folder, other_tests=other)["other_tests"]
    survived = quiet["id"] in {m["id"] for m in report["survivors"]}
    assert table["harness_only"] == [braking["id"]] and not table["neither"]
    assert table["other_only" if survived else "both"] == [quiet["id"]]

    # AND searched with a screen, in a copy of the folder: the unmutated bundled autopilot flies
    # each of a survivor's candidates first, and a folder searched without one says so
    screened = tmp_path / "screened"
    shutil.copytree(folder, screened, ignore=shutil.ignore_patterns("search", mutation.RUN))
    assert main([*argv[:2], str(screened), *argv[3:], "--screen", "bundled"]) == 0
    for search in (screened / "search" / quiet["id"]).glob("*.db"):
        with contextlib.closing(sqlite3.connect(search)) as store:
            assert store.execute("SELECT COUNT(*) FROM screen_flights").fetchone()[0] >= 1
    assert main([*argv, "--screen", "bundled"]) == 2


@pytest.mark.slow
def test_a_kill_flown_again_stands_where_the_mutant_differs_and_is_withdrawn_where_its_flights_were_apart_by_chance(tmp_path, capsys):
    # GIVEN a built mutant of the bundled collision prevention that survived its suite: range data
    # counts as fresh for 1 s instead of 0.5 s, which shows where a probed wall's sensor goes off
    folder = tmp_path / "mutation"
    index = mutants.generate(ROOT, COLLISION, folder)
    stale = _mutant_with(index, "STALE_AFTER_S = 0.5", "STALE_AFTER_S = 1.0")
    index["mutants"] = [stale]
    (folder / mutants.INDEX).write_text(json.dumps(index))
    assert main(["mutants", "build", str(folder)]) == 0
    suite = str(ROOT / "scenarios" / "examples" / "wall_concrete.json")
    plan = mutation.MutationPlan((suite,), evaluations=3, population=2, confirm=1)
    (folder / mutation.RUN).write_text(json.dumps({"screening": plan.screening(), "searching": plan.searching(),
                                                   "mutants": {stale["id"]: {"state": "survived_suite", "suite_flights": 1}}}))
    # AND searched on the probed wall, where it revealed (confirmed with a second flight a side),
    # and on the plain wall, where it flew as the original
    examples = ROOT / "scenarios" / "examples"
    assert main(["mutants", "run", str(folder), "--suite", suite, "--scenario", str(examples / "wall_probe.json"), "--scenario", str(examples / "wall.json"),
                 "--algorithm", "RANDOM", "--evaluations", "3", "--population", "2", "--confirm", "1", "--workers", "2"]) == 0
    searches = json.loads((folder / mutation.RUN).read_text())["mutants"][stale["id"]]["search"]["RANDOM"]
    assert searches["wall_probe"]["evaluation"] is not None and searches["wall"]["evaluation"] is None
    # AND the plain wall's first two candidates stored as reveals, as two flights a side landing apart by chance would have
    plain = folder / "search" / stale["id"] / "wall-RANDOM.db"
    with Store.existing(plain) as store:
        for pair in store.pairs()[:2]:
            apart = [{**o, "min_clearance_m": o["min_clearance_m"] + 1.0} for o in pair.differential["subject"] * 2]
            store.rejudge(pair.id, {**pair.differential, "reveals": "behaviour", "why": "min clearance 1 m beyond the reference's spread",
                                    "subject": apart, "reference": pair.differential["reference"] * 2})
        searches["wall"] = store.first_reveals()
    document = json.loads((folder / mutation.RUN).read_text())
    document["mutants"][stale["id"]]["search"]["RANDOM"]["wall"] = searches["wall"]
    (folder / mutation.RUN).write_text(json.dumps(document))

    # WHEN each search's kill is flown until it has three flights a side
    capsys.readouterr()
    assert main(["mutants", "recheck", str(folder), "--flights", "3", "--workers", "2"]) == 0

    # THEN the probed wall's kill stands and the plain wall's are withdrawn, one after the other, their new flights flying as the
    # reference's do
    said = capsys.readouterr()
    probed = searches["wall_probe"]
    assert f"{stale['id']} wall_probe-RANDOM candidate {probed['evaluation']}: {probed['level']} -> {probed['level']} stands with 3 flights a side" in said.err
    for candidate in (1, 2):
        assert (f"{stale['id']} wall-RANDOM candidate {candidate}: behaviour -> withdrawn with 3 flights a side: no difference beyond the "
                "reference's spread") in said.err
    assert "3 revealing candidates flown again: 2 withdrawn, 1 stand" in said.out
    assert json.loads((folder / mutation.RUN).read_text())["mutants"][stale["id"]]["search"]["RANDOM"] == {**searches, "wall": {**searches["wall"], "evaluation": None, "level": None}}
    with Store.existing(plain) as store:
        pair = store.pairs()[0].differential
    assert len(pair["subject"]) == len(pair["reference"]) == 3 and pair["subject"][2]["min_clearance_m"] == pair["reference"][2]["min_clearance_m"]
    assert Path(pair["subject"][2]["log_path"]).is_file()
    # AND asked again, it flies nothing: every kill has its flights
    assert main(["mutants", "recheck", str(folder), "--flights", "3"]) == 0
    assert "0 revealing candidates flown again" in capsys.readouterr().out
    assert main(["mutants", "recheck", str(folder), "--only", "m9999"]) == 2
    assert "--only: m9999: no such mutant" in capsys.readouterr().err


@pytest.mark.slow
def test_a_suite_kill_flown_again_stands_where_the_mutant_differs_and_makes_a_survivor_where_it_does_not(tmp_path, capsys):
    # GIVEN two built mutants of the bundled collision prevention, both killed by the wall of the
    # suite as stored: one that stops braking north (it flies into the wall), one whose flights
    # there are the original's (its kill a by-chance spread of three flights a side, made up here)
    folder = tmp_path / "mutation"
    index = mutants.generate(ROOT, COLLISION, folder)
    braking = _mutant_with(index, "vn -= (along - allowed) * bin_n", "pass")
    stale = _mutant_with(index, "STALE_AFTER_S = 0.5", "STALE_AFTER_S = 1.0")
    index["mutants"] = [braking, stale]
    (folder / mutants.INDEX).write_text(json.dumps(index))
    assert main(["mutants", "build", str(folder)]) == 0
    plan = mutation.MutationPlan((str(ROOT / "scenarios" / "examples" / "wall_concrete.json"),), confirm=2)
    killed = {m["id"]: {"state": "killed_by_suite", "level": level, "case": f"{m['id']}-wall_concrete", "why": "as stored", "suite_flights": 1}
              for m, level in ((braking, "unsafe"), (stale, "behaviour"))}
    (folder / mutation.RUN).write_text(json.dumps({"screening": plan.screening(), "searching": plan.searching(), "mutants": killed}))
    assert mutation.report(folder)["scores"]["suite"]["any"]["killed"] == 2

    # WHEN each kill is flown again, two flights a side
    capsys.readouterr()
    assert main(["mutants", "recheck", str(folder), "--flights", "2", "--workers", "2"]) == 0

    # THEN the braking mutant's kill stands, and the other survives the suite, what was withdrawn kept
    said = capsys.readouterr()
    assert f"{braking['id']} suite case {braking['id']}-wall_concrete: unsafe -> unsafe stands with 2 flights a side" in said.err
    assert f"{stale['id']} suite case {stale['id']}-wall_concrete: behaviour -> withdrawn with 2 flights a side" in said.err
    outcomes = json.loads((folder / mutation.RUN).read_text())["mutants"]
    assert outcomes[braking["id"]]["state"] == "killed_by_suite" and outcomes[braking["id"]]["rechecked_flights"] == 2
    assert outcomes[stale["id"]] == {"state": "survived_suite", "suite_flights": 1, "withdrawn_by_recheck": {
        "level": "behaviour", "case": f"{stale['id']}-wall_concrete", "why": "as stored", "flights": 2,
        "why_after": "no difference beyond the reference's spread"}}
    assert mutation.report(folder)["scores"]["suite"]["any"]["killed"] == 1
    assert len(list((folder / "logs" / stale["id"]).glob(f"{stale['id']}-wall_concrete-recheck*.mcap"))) == 4
    # AND asked again, it flies nothing
    assert main(["mutants", "recheck", str(folder), "--flights", "2"]) == 0
    assert "0 revealing candidates flown again" in capsys.readouterr().out


@pytest.mark.slow
def test_a_revealing_case_fails_on_the_subjects_build_and_passes_on_the_references(tmp_path, pytester):
    # GIVEN a mutant that stops limiting northward velocity, and the original, both built
    index = mutants.generate(ROOT, COLLISION, tmp_path / "m")
    braking = _mutant_with(index, "vn -= (along - allowed) * bin_n", "pass")
    cache = tmp_path / "builds"
    original = builds.build(ROOT, out=cache)
    subject = builds.build(ROOT, out=cache, patches=[tmp_path / "m" / "mutants" / f"{braking['id']}.patch"])
    # WHEN a differential campaign flies the wall scenario against both
    store = tmp_path / "diff.db"
    assert main(["campaign", str(ROOT / "scenarios" / "examples" / "wall.json"), "--algorithm", "RANDOM", "--evaluations", "6", "--seed", "2",
                 "--autopilot-dir", subject.folder, "--reference-autopilot-dir", original.folder, "--objective", "difference",
                 "--store", str(store), "--workers", "2"]) == 0
    from harness.campaigns.store import Store

    with Store.existing(store) as opened:
        revealing = opened.revealing_cases()
        rows = opened.runs()
    assert revealing and rows[0].revealing == len(revealing)
    # THEN each revealing case exports as a regression case against the reference's outcome
    assert main(["export-regressions", str(store), "--revealing", "--out", str(tmp_path / "cases")]) == 0
    cases = sorted((tmp_path / "cases").glob("*.regression.json"))
    assert cases and all(json.loads(c.read_text())["expect"] == "as_reference" for c in cases)
    case = cases[0]
    # which fails against the subject's build and passes against the reference's
    bad = pytester.runpytest_subprocess(str(case), "-p", "no:cacheprovider", "--stella-autopilot-dir", subject.folder, "--stella-out", str(tmp_path / "logs"))
    bad.assert_outcomes(failed=1)
    good = pytester.runpytest_subprocess(str(case), "-p", "no:cacheprovider", "--stella-autopilot-dir", original.folder, "--stella-out", str(tmp_path / "logs"))
    good.assert_outcomes(passed=1)


# The other test method of the next test: the mutated collision.py of the tree it runs in must
# still brake for a wall 3 m ahead.
BRAKING_CHECK = """\
import importlib.util, sys
sys.path.insert(0, {root!r})
from autopilot.params import Params
spec = importlib.util.spec_from_file_location("mutated_collision", "autopilot/collision.py")
collision = importlib.util.module_from_spec(spec)
spec.loader.exec_module(collision)
with open("runs.log", "a") as log:
    log.write("run\\n")
obstacles = collision.ObstacleMap()
distances = [collision.UINT16_MAX] * collision.BINS
for sector in range(-10, 11):
    distances[sector % collision.BINS] = 300
obstacles.update(0.0, 0.0, distances, 5.0, 0.0, 20, 2000)
north, _east = collision.constrain_velocity(Params(), obstacles, 0.0, (5.0, 0.0), (0.0, 0.0))
sys.exit(0 if north < 4.0 else 1)
"""


def test_another_test_method_judges_each_mutant_in_its_tree_and_leaves_the_tree_as_it_was(tmp_path, capsys):
    # GIVEN three built mutants of the CP module: one stops braking, one changes nothing a short
    # test sees, one hangs at import (and a stillborn one); and a tree with the module and a
    # test that checks braking
    folder = tmp_path / "mutation"
    index = mutants.generate(ROOT, COLLISION, folder)
    braking = _mutant_with(index, "vn -= (along - allowed) * bin_n", "pass")
    quiet = _mutant_with(index, "STALE_AFTER_S = 0.5", "STALE_AFTER_S = 1.0")
    broken = next(m for m in index["mutants"] if m["mutated"].strip() == "pass" and m["original"].rstrip().endswith(":"))
    index["mutants"] = [braking, quiet, broken]
    _add_mutant(folder, index, "m9003", quiet["line"], "import time; time.sleep(60); STALE_AFTER_S = 0.5\n")
    (folder / mutants.INDEX).write_text(json.dumps(index))
    tree = tmp_path / "tree"
    (tree / "autopilot").mkdir(parents=True)
    unmutated = (ROOT / COLLISION).read_bytes()
    (tree / COLLISION).write_bytes(unmutated)
    (tree / "check.py").write_text(BRAKING_CHECK.format(root=str(ROOT)))
    command = f"{sys.executable} check.py"
    argv = ["mutants", "test", str(folder), "--tree", str(tree), "--command", command, "--timeout-s", "10"]

    # WHEN the test runs before the mutants are built, THEN it is refused: stillborn ones would count as killed
    assert main(argv) == 2
    assert "run `stella mutants build` first" in capsys.readouterr().err

    # WHEN they are built (their builds are tested above: here only their states) and the test runs against each
    states = {braking["id"]: "built", quiet["id"]: "built", "m9003": "built", broken["id"]: "stillborn"}
    (folder / mutants.BUILT).write_text(json.dumps({"mutants": {key: {"id": key, "state": state} for key, state in states.items()}}))
    assert main(argv) == 0
    results = json.loads((folder / "other_tests.json").read_text())
    # THEN it kills the one that stops braking and the one that hangs (on the timeout), not the quiet one
    assert results["mutants"][braking["id"]]["killed"] and results["mutants"][braking["id"]]["exit_code"] == 1
    assert not results["mutants"][quiet["id"]]["killed"]
    assert results["mutants"]["m9003"]["killed"] and results["mutants"]["m9003"]["why"] == "timed out after 10 s"
    assert results["original"]["why"] == "passed"
    assert broken["id"] not in results["mutants"]  # a stillborn mutant fails any build: not judged
    # and the tree is as it was
    assert (tree / COLLISION).read_bytes() == unmutated
    # AND a second run resumes: nothing runs again
    runs = (tree / "runs.log").read_text().count("run")
    assert main(argv) == 0
    assert (tree / "runs.log").read_text().count("run") == runs
    # AND the report takes the results beside the flights' kills (its table is tested above)
    assert mutation.against_other_tests({braking["id"]: {"state": "killed_by_suite"}}, ["RANDOM"], mutation.load_other_tests(folder / "other_tests.json"))["both"] == [braking["id"]]

    # WHEN the command fails on the unmutated tree, THEN it judges nothing and says so
    capsys.readouterr()
    assert main(["mutants", "test", str(folder), "--tree", str(tree), "--command", "false", "--out", str(tmp_path / "x.json")]) == 2
    assert "fails on the unmutated tree" in capsys.readouterr().err and not (tmp_path / "x.json").exists()
    # nor does a tree without the file
    assert main(["mutants", "test", str(folder), "--tree", str(tmp_path), "--command", command, "--out", str(tmp_path / "x.json")]) == 2
    assert "does not exist" in capsys.readouterr().err
    # nor a tree whose file a run stopped with kill -9 left mutated
    (tree / COLLISION).write_text((ROOT / COLLISION).read_text().replace("STALE_AFTER_S = 0.5", "STALE_AFTER_S = 1.0"))
    assert main(["mutants", "test", str(folder), "--tree", str(tree), "--command", command, "--out", str(tmp_path / "x.json")]) == 2
    assert "differs from the file the mutants were generated from" in capsys.readouterr().err


def test_a_stopped_test_run_puts_the_file_back_and_leaves_no_process(tmp_path):
    # GIVEN a built mutant and a command that passes at once on the unmutated file and, on a
    # mutated one, records its process group and then hangs
    folder = tmp_path / "mutation"
    index = mutants.generate(ROOT, COLLISION, folder)
    quiet = _mutant_with(index, "STALE_AFTER_S = 0.5", "STALE_AFTER_S = 1.0")
    index["mutants"] = [quiet]
    (folder / mutants.INDEX).write_text(json.dumps(index))
    (folder / mutants.BUILT).write_text(json.dumps({"mutants": {quiet["id"]: {"id": quiet["id"], "state": "built"}}}))
    tree = tmp_path / "tree"
    (tree / "autopilot").mkdir(parents=True)
    (tree / COLLISION).write_bytes((ROOT / COLLISION).read_bytes())
    command = "grep -q 'STALE_AFTER_S = 0.5' autopilot/collision.py || { sleep 300 & echo $$ > group; wait; }"
    run = subprocess.Popen([sys.executable, "-m", "harness.tools.cli", "mutants", "test", str(folder), "--tree", str(tree), "--command", command],
                           cwd=ROOT, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not (tree / "group").exists() and time.monotonic() < deadline and run.poll() is None:
            time.sleep(0.1)
        assert (tree / "group").exists(), run.stderr.read() if run.poll() is not None else "the mutant's command never started"
        group = int((tree / "group").read_text())
        # WHEN the run is stopped with SIGTERM while the mutant's command runs
        run.terminate()
        run.wait(timeout=30)
    finally:
        run.kill()
    # THEN the file is as it was and nothing of the command's process group runs on
    assert (tree / COLLISION).read_bytes() == (ROOT / COLLISION).read_bytes()
    assert _running_in_group(group) == []
    assert run.returncode != 0


def _running_in_group(group: int) -> list[int]:
    """The group's processes that are not zombies (an orphan waits for init to reap it)."""
    running = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError):
            fields = stat.read_text().rsplit(")", 1)[1].split()
            if int(fields[2]) == group and fields[0] != "Z":
                running.append(int(stat.parent.name))
    return running
