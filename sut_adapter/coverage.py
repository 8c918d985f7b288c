"""Code coverage of the firmware under test, per flight.

A coverage build (`stella sut build KIND --coverage`) carries COVERAGE_FILE in its folder: which
tool measures it and which source paths. Its flights record coverage without another option:
the adapter starts the SUT so that the tool measures it, and once the SUT has stopped, the
counters it left in the flight's working directory are summarised into the evaluation's record
(`coverage`): what `stella coverage` merges, and a coverage-guided search reads.

The bundled autopilot is measured by coverage.py: the build removes its compiled modules, so that
it runs as the Python sources they are compiled from (which compute the same), and the adapter
starts it under `coverage run --branch`. A branch is an arc of coverage.py ("from>to" line
numbers; a negative "to" leaves the function).

PX4 is measured by gcov: the build compiles the measured paths only with `--coverage` (a CMake
file of ours that PX4's configuration includes), in a build folder of its own, and keeps their
notes files (.gcno) and sources. Each flight's PX4 writes its counters (.gcda) at its orderly
exit under the flight's working directory (GCOV_PREFIX), not into the build folder, so that
parallel flights keep theirs apart; gcovr summarises them. A branch is gcovr's: "line:index"
of the line's branches in gcov's order.

ArduPilot is measured by gcov too, but its waf names each source relative to the build folder of
the worktree it compiled in, where gcov looks for it (and finds the next variant's file, or
nothing). So its counters are read by fastcov, from gcov's JSON, which needs no sources; the
branches are the same "line:index".

A record: {"tool": ..., "sources": the source tree, "files": {path: {"lines_hit": [...],
"lines_missed": [...], "branches_hit": [...], "branches_missed": [...]}}}, each path relative
to the source tree (for PX4 the copy of the measured sources its build kept), each list sorted. Hit and missed together are all of a file's lines (branches), so records of
several flights merge by union of what was hit.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable, Mapping, Sequence

if TYPE_CHECKING:
    from sut_adapter.base import SutConfig

COVERAGE_FILE = "coverage.json"
PYTHON_TOOL = "coverage.py"
PYTHON_DATA = "flight.coverage"  # coverage.py's data file in the flight's working directory


def coverage_build(folder: Path | str | None) -> dict[str, Any] | None:
    """The coverage settings of a build folder (None: not a coverage build)."""
    if folder is None:
        return None
    marker = Path(folder) / COVERAGE_FILE
    return json.loads(marker.read_text()) if marker.is_file() else None


def build_folder_of(sut: "SutConfig") -> Path | None:
    """The build folder of a SUT configuration: the bundled autopilot's folder, or PX4's (its
    binary lies in bin/ under it)."""
    if sut.autopilot_dir:
        return Path(sut.autopilot_dir)
    if sut.px4_bin:
        given = Path(sut.px4_bin)
        return given.parent.parent if given.is_file() else given
    return None


def mark_coverage_build(folder: Path, tool: str, paths: Sequence[str], **settings: Any) -> None:
    (folder / COVERAGE_FILE).write_text(json.dumps({"tool": tool, "paths": list(paths), **settings}, indent=1) + "\n")


# -- the bundled autopilot: coverage.py -----------------------------------------------------------


def python_command(build: Mapping[str, Any], root: Path, workdir: Path) -> list[str]:
    """The interpreter's arguments that run a module under coverage.py, measuring the build's
    paths (files or folders, relative to `root`) into the working directory."""
    rcfile = workdir / "coveragerc"
    include = [str(root / path) + ("/*" if (root / path).is_dir() else "") for path in build["paths"]]
    rcfile.write_text("[run]\nbranch = True\ndata_file = {}\ninclude =\n{}\n".format(workdir / PYTHON_DATA, "".join(f"    {p}\n" for p in include)))
    return [sys.executable, "-m", "coverage", "run", f"--rcfile={rcfile}"]


def python_record(root: Path, workdir: Path) -> dict[str, Any] | None:
    """The flight's coverage of the measured paths (None: the SUT left no data, as a SUT killed
    before its orderly exit does)."""
    import coverage

    data_file = workdir / PYTHON_DATA
    if not data_file.is_file():
        return None
    measured = coverage.Coverage(data_file=str(data_file), config_file=str(workdir / "coveragerc"))
    measured.load()
    report = workdir / "coverage-report.json"
    measured.json_report(outfile=str(report), show_contexts=False, ignore_errors=True)
    files = {}
    for name, entry in json.loads(report.read_text())["files"].items():
        relative = Path(name).resolve().relative_to(root.resolve()).as_posix() if Path(name).is_absolute() else name
        files[relative] = {"lines_hit": sorted(entry["executed_lines"]), "lines_missed": sorted(entry["missing_lines"]),
                           "branches_hit": sorted(_arcs(entry.get("executed_branches", []))),
                           "branches_missed": sorted(_arcs(entry.get("missing_branches", [])))}
    return {"tool": PYTHON_TOOL, "sources": str(root.resolve()), "files": files}


def _arcs(pairs: Iterable[Sequence[int]]) -> list[str]:
    return [f"{start}>{end}" for start, end in pairs]



# -- PX4: gcov through gcovr ----------------------------------------------------------------------

GCOV_TOOL = "gcov"
GCOV_DIR = "gcov"  # where a flight's PX4 writes its counters, under its working directory
NOTES_DIR = "coverage"  # in a PX4 coverage build's folder: the measured objects' .gcno and sources


def gcov_environment(build: Mapping[str, Any], workdir: Path) -> dict[str, str]:
    """The environment that makes a gcov-instrumented process write its counters under workdir:
    the build folder's absolute path, where the objects were compiled, is stripped."""
    return {"GCOV_PREFIX": str(workdir / GCOV_DIR), "GCOV_PREFIX_STRIP": str(len(Path(build["build_dir"]).parts) - 1)}


def _counters_beside_notes(folder: Path, workdir: Path) -> list[Path]:
    """The counters (.gcda) a flight's SUT left of the measured objects, each with its notes (.gcno)
    copied beside it from the build; none where it left none, as a SUT killed before its orderly
    exit does. (A build instrumented whole, as ArduPilot's, leaves counters of every object.)"""
    counters, notes = workdir / GCOV_DIR, folder / NOTES_DIR / "notes"
    found = [gcda for gcda in sorted(counters.glob("**/*.gcda")) if (notes / gcda.relative_to(counters).with_suffix(".gcno")).is_file()] \
        if counters.is_dir() else []
    for gcda in found:
        shutil.copy2(notes / gcda.relative_to(counters).with_suffix(".gcno"), gcda.with_suffix(".gcno"))
    return found


def gcov_record(build: Mapping[str, Any], folder: Path, workdir: Path) -> dict[str, Any] | None:
    """The flight's coverage of the measured paths from the counters its PX4 left (None: none,
    as a PX4 killed before its orderly exit leaves none)."""
    found = _counters_beside_notes(folder, workdir)
    if not found:
        return None
    notes = folder / NOTES_DIR
    # gcov, run beside a copy of the kept sources (the build names them relative to the tree's
    # root: -fprofile-prefix-map), writes its reports there; gcovr reads those of the measured paths.
    # (gcovr running gcov itself would want every file the objects inline, other libraries'
    # headers and generated ones, which a build keeps no sources of.)
    text = workdir / "gcov-text"
    shutil.copytree(notes / "sources", text, dirs_exist_ok=True)
    for folder_of_counters in sorted({gcda.parent for gcda in found}):
        # --long-file-names: a header's report named after the object that inlined it too, so
        # that each object's report of it is kept (and gcovr merges them), not overwritten.
        # --hash-filenames: those names hashed, as the paths they join (the flight's working
        # directory, named after its job, among them) outgrow a file name's 255 bytes.
        ran = subprocess.run(["gcov", "--branch-probabilities", "--branch-counts", "--preserve-paths", "--long-file-names", "--hash-filenames",
                              "--object-directory", str(folder_of_counters),
                              *[str(g) for g in found if g.parent == folder_of_counters]], cwd=text, capture_output=True, text=True)
        if ran.returncode != 0:
            raise RuntimeError(f"gcov failed on the flight's counters: {ran.stderr.strip()[-600:]}")
    report = workdir / "gcovr.json"
    filters = [argument for path in build["paths"] for argument in ("--filter", re.escape(path) + ("/" if (notes / "sources" / path).is_dir() else "$"))]
    done = subprocess.run([sys.executable, "-m", "gcovr", "--root", str(text), "--use-gcov-files", *filters, "--json", str(report), str(text)],
                          cwd=text, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"gcovr failed on the flight's gcov reports: {done.stderr.strip()[-600:]}")
    files = {}
    for entry in json.loads(report.read_text())["files"]:
        lines = entry["lines"]
        hit = sorted({line["line_number"] for line in lines if line["count"] > 0})
        branches = [(f"{line['line_number']}:{branch['branchno']}", branch["count"] > 0) for line in lines for branch in line["branches"]]
        files[entry["file"]] = {"lines_hit": hit, "lines_missed": sorted({line["line_number"] for line in lines} - set(hit)),
                                "branches_hit": sorted(key for key, taken in branches if taken),
                                "branches_missed": sorted(key for key, taken in branches if not taken)}
    return {"tool": GCOV_TOOL, "sources": str((notes / "sources").resolve()), "files": files}


def fastcov_record(build: Mapping[str, Any], folder: Path, workdir: Path) -> dict[str, Any] | None:
    """The flight's coverage of the measured paths from the counters its ArduPilot left (None:
    none), read by fastcov; the paths are relative to the worktree the build compiled in."""
    found = _counters_beside_notes(folder, workdir)
    if not found:
        return None
    report = workdir / "fastcov.json"
    # --exceptional-branch-coverage: every branch gcov counts, as gcovr reads PX4's.
    done = subprocess.run([sys.executable, "-m", "fastcov", "--exceptional-branch-coverage", "--skip-exclusion-markers", "--jobs", "1", "--quiet",
                           "--gcda-files", *map(str, found), "--output", str(report)], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"fastcov failed on the flight's counters: {(done.stderr or done.stdout).strip()[-600:]}")
    tree = Path(build["tree"])
    files = {}
    for name, tests in json.loads(report.read_text())["sources"].items():
        path = Path(name)
        if not path.is_relative_to(tree):
            continue
        relative = path.relative_to(tree).as_posix()
        if not any(relative == measured or relative.startswith(measured.rstrip("/") + "/") for measured in build["paths"]):
            continue
        counts = tests[""]
        branches = [(f"{line}:{index}", count > 0) for line, taken in counts["branches"].items() for index, count in enumerate(taken)]
        hit = {int(line) for line, count in counts["lines"].items() if count > 0}
        files[relative] = {"lines_hit": sorted(hit), "lines_missed": sorted({int(line) for line in counts["lines"]} - hit),
                           "branches_hit": sorted(key for key, taken in branches if taken),
                           "branches_missed": sorted(key for key, taken in branches if not taken)}
    return {"tool": GCOV_TOOL, "sources": str((folder / NOTES_DIR / "sources").resolve()), "files": files}
