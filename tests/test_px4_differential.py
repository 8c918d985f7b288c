"""Differential flights and builds from source against real PX4. Flights run where STELLA_PX4_BIN
names a PX4 SITL build; builds where STELLA_PX4_SOURCE names a PX4-Autopilot clone with its
submodules (STELLA_PX4_WORKTREE_COMMAND, if set, is passed as --worktree-command: see
docs/real_faults.md). Skipped, saying so, elsewhere."""

from __future__ import annotations

import difflib
import json
import os
from pathlib import Path

import pytest

from conftest import ROOT
from harness.tools.cli import main

WALL = ROOT / "scenarios" / "examples" / "wall_concrete.json"
CP_FILE = "src/lib/collision_prevention/CollisionPrevention.cpp"
needs_px4 = pytest.mark.skipif(not os.environ.get("STELLA_PX4_BIN"), reason="STELLA_PX4_BIN is not set: no PX4 SITL build to fly against")
needs_source = pytest.mark.skipif(not os.environ.get("STELLA_PX4_SOURCE"), reason="STELLA_PX4_SOURCE is not set: no PX4 source tree to build")


@pytest.mark.slow
@needs_px4
def test_px4_with_a_larger_cp_distance_reveals_a_behaviour_difference_on_the_wall(capsys, tmp_path):
    # GIVEN the same build twice, the subject keeping 3 m from obstacles, the reference 1 m
    argv = ["run", "--concrete", str(WALL), "--sut", "px4", "--drive", "pilot", "--sut-param", "CP_DIST=3.0",
            "--reference-sut-param", "CP_DIST=1.0", "--confirm", "1", "--out", str(tmp_path), "--json"]
    assert main(argv) == 0
    result = json.loads(capsys.readouterr().out)
    differential = result["differential"]
    # THEN both flew twice (the pair was confirmed), the subject stopped farther from the wall
    assert len(differential["subject"]) == 2 and len(differential["reference"]) == 2
    assert differential["reveals"] == "behaviour"
    # by more than PX4's spread between pilot flights on a wall (up to 0.4 m, docs/real_faults.md);
    # not by the whole 2 m: PX4 main 02e73e3b6f stops 2.7 m from it keeping 1 m and 3.7 m keeping 3 m.
    assert min(f["min_clearance_m"] for f in differential["subject"]) > max(f["min_clearance_m"] for f in differential["reference"]) + 0.4


def _worktree_options() -> list[str]:
    command = os.environ.get("STELLA_PX4_WORKTREE_COMMAND")
    return ["--worktree-command", command] if command else []


@pytest.mark.slow
@needs_source
def test_a_px4_variant_with_a_patch_builds_once_and_then_comes_from_the_cache(capsys, tmp_path_factory):
    source = Path(os.environ["STELLA_PX4_SOURCE"])
    cache = Path(os.environ.get("STELLA_PX4_BUILD_CACHE") or tmp_path_factory.mktemp("px4-builds"))
    text = (source / CP_FILE).read_text()
    assert "_min_dist_to_keep" in text
    patched = text.replace("_min_dist_to_keep = math::max(", "_min_dist_to_keep = 2.f * math::max(", 1)
    assert patched != text, "CollisionPrevention.cpp no longer sets _min_dist_to_keep as this test expects"
    patch = cache / "cp-dist-doubled.patch"
    patch.write_text("".join(difflib.unified_diff(text.splitlines(keepends=True), patched.splitlines(keepends=True), f"a/{CP_FILE}", f"b/{CP_FILE}")))
    argv = ["sut", "build", "px4", "--source", str(source), "--patch", str(patch), "--out", str(cache), "--json", *_worktree_options()]
    assert main(argv) == 0
    first = json.loads(capsys.readouterr().out)
    assert Path(first["folder"], "bin", "px4").is_file() and CP_FILE in first["objects"]
    assert main(argv) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["cached"] and again["folder"] == first["folder"]
