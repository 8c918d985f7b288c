"""Flying pairs (harness/campaigns/pairs.py) with real flights of the bundled autopilot."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest

from harness.campaigns.pairs import PairedFlights, ReferenceCache, build_identity
from harness.execution.executor import Job
from harness.execution.local import SequentialExecutor
from harness.flight.differential import Outcome
from harness.flight.evaluation import RunOptions
from harness.scenario.world import space_from_concrete
from sut_adapter import SutConfig

ROOT = Path(__file__).resolve().parents[1]
WALL = ROOT / "scenarios" / "examples" / "wall_concrete.json"


@pytest.mark.slow
def test_a_reference_cached_in_another_sitting_does_not_make_a_build_differ_from_itself(tmp_path):
    """A SUT's flights depend on the machine's load (PX4's on one wall spread by 40 cm), so a
    confirmation flies the reference again beside the subject instead of trusting a cache that
    may hold flights from a quieter sitting: a build held against itself then reveals nothing."""
    document = json.loads(WALL.read_text())
    space = space_from_concrete(document, str(WALL))
    options = RunOptions()
    job = Job.of(0, space, space.from_concrete(document, str(WALL)), seed=1, out_dir=tmp_path, name="wall", options=options)
    cache = ReferenceCache(tmp_path / "reference_flights.db")
    key = ReferenceCache.key(job, build_identity(options.sut))
    executor = SequentialExecutor()
    try:
        [(_job, alone)] = list(executor.run([job]))
        here = Outcome.of(alone)
        # The same build's two flights as another sitting gave them: 40 and 42 cm farther out.
        elsewhere = [replace(here, min_clearance_m=here.min_clearance_m + shift, fitness=here.fitness + shift) for shift in (0.40, 0.42)]
        cache.put(key, elsewhere)
        [(_job, paired)] = list(PairedFlights(executor, options.sut, confirm=1, cache=cache).run([replace(job, out_dir=str(tmp_path / "pair"))]))
    finally:
        executor.close()
        cache.close()
    differential = paired.differential
    assert differential["reveals"] is None, differential["why"]
    # Judged on the cached flights and the one flown beside the subject's two.
    assert len(differential["subject"]) == 2 and len(differential["reference"]) == 3
    assert differential["reference"][2]["min_clearance_m"] == here.min_clearance_m


def test_two_firmware_builds_are_two_references_and_one_build_in_two_folders_is_one(tmp_path):
    """The reference cache's key holds the binary's digest, so a cached flight of one build is
    never taken for another's."""
    for folder, text in (("a", "build one"), ("b", "build two"), ("c", "build one")):
        binary = tmp_path / folder / "arducopter"
        binary.parent.mkdir()
        binary.write_text(text)
        binary.chmod(0o755)
    identity = {folder: build_identity(SutConfig("ardupilot", ardupilot_bin=str(tmp_path / folder / "arducopter"))) for folder in "abc"}
    assert identity["a"] != identity["b"] and identity["a"] == identity["c"]


CP_OFF_LINE = '    if fault == "cp_off_above_cruise" and speed > OFF_ABOVE_M_S:\n'


@pytest.mark.slow
def test_a_pair_reveals_only_where_the_subject_ran_the_changed_code(tmp_path):
    """Coverage builds of the bundled autopilot, the subject's collision prevention off above 4 m/s
    (one line changed): it flies into the wall, a reveal that stands when the changed line is the
    one the flight ran, and is withdrawn, as the SUT's own spread, when the change is said to be on
    a line the flight never ran."""
    import difflib

    from harness.campaigns.coverage import line_name
    from harness.firmware import builds

    source = (ROOT / "autopilot" / "collision.py").read_text()
    assert CP_OFF_LINE in source, "autopilot/collision.py changed: choose the line again"
    patch = tmp_path / "cp_off.patch"
    patch.write_text("".join(difflib.unified_diff(source.splitlines(keepends=True),
                                                  source.replace(CP_OFF_LINE, "    if speed > OFF_ABOVE_M_S:\n").splitlines(keepends=True),
                                                  "a/autopilot/collision.py", "b/autopilot/collision.py")))
    made = {name: builds.build(ROOT, out=tmp_path / "builds", patches=patches, coverage_paths=[]) for name, patches in (("original", []), ("subject", [patch]))}
    sides = {name: SutConfig("bundled", autopilot_dir=variant.folder) for name, variant in made.items()}
    document = json.loads(WALL.read_text())
    space = space_from_concrete(document, str(WALL))
    job = Job.of(0, space, space.from_concrete(document, str(WALL)), seed=1, out_dir=tmp_path, name="wall", options=RunOptions(sut=sides["subject"]))
    changed = line_name("autopilot/collision.py", source.splitlines(keepends=True).index(CP_OFF_LINE) + 1)
    executor = SequentialExecutor()
    cache = ReferenceCache(tmp_path / "reference_flights.db")  # the reference flown once for both
    try:
        [(_job, ran)] = list(PairedFlights(executor, sides["original"], cache=cache, changed_lines=(changed,)).run([job]))
        never_run = line_name("autopilot/collision.py", ran.coverage["files"]["autopilot/collision.py"]["lines_missed"][0])
        [(_job, spread)] = list(PairedFlights(executor, sides["original"], cache=cache, changed_lines=(never_run,)).run([job]))
    finally:
        executor.close()
        cache.close()
    assert ran.differential["reveals"] is not None, ran.differential["why"]
    assert spread.differential["reveals"] is None
    assert spread.differential["why"] == f"the subject never ran {never_run}, by its coverage: what differed ({ran.differential['why']}) is the SUT's own spread"
