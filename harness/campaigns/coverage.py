"""The code coverage of campaigns flown with a coverage build (`stella coverage`): the stored
flights' records (sut_adapter/coverage.py) merged per source file, each line and branch with
the flight that reached it first, and the lines no flight reached; and the search it guides
(`--objective coverage`, CodeNovelty).

A line (branch) belongs to a file if some flight's record names it, hit or missed: records of
one build name the same ones. Flights of different builds of one file (a mutant and its
original) name different line numbers only where a patch moved them.
"""

from __future__ import annotations

import collections
import json
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from harness.flight.fitness import Status


@dataclass(frozen=True)
class Flight:
    """Where a stored flight is: its store and evaluation id, and when it was stored."""

    store: str
    evaluation: int
    created: float

    def as_dict(self) -> dict[str, Any]:
        return {"store": self.store, "evaluation": self.evaluation}


@dataclass
class FileCoverage:
    path: str
    lines: set[int] = field(default_factory=set)
    branches: set[str] = field(default_factory=set)
    first_line: dict[int, Flight] = field(default_factory=dict)  # each line hit, with the first flight to hit it
    first_branch: dict[str, Flight] = field(default_factory=dict)
    flights: int = 0
    # How many flights ran each line (branch): the counts of the HTML report.
    line_flights: collections.Counter = field(default_factory=collections.Counter)
    branch_flights: collections.Counter = field(default_factory=collections.Counter)

    def add(self, record: Mapping[str, Sequence], flight: Flight) -> None:
        self.flights += 1
        self.lines.update(record["lines_hit"], record["lines_missed"])
        self.branches.update(record["branches_hit"], record["branches_missed"])
        self.line_flights.update(record["lines_hit"])
        self.branch_flights.update(record["branches_hit"])
        for line in record["lines_hit"]:
            if line not in self.first_line or flight.created < self.first_line[line].created:
                self.first_line[line] = flight
        for branch in record["branches_hit"]:
            if branch not in self.first_branch or flight.created < self.first_branch[branch].created:
                self.first_branch[branch] = flight

    @property
    def uncovered_lines(self) -> list[int]:
        return sorted(self.lines - set(self.first_line))

    def as_dict(self) -> dict[str, Any]:
        return {"file": self.path, "flights": self.flights,
                "lines_hit": len(self.first_line), "lines_total": len(self.lines),
                "branches_hit": len(self.first_branch), "branches_total": len(self.branches),
                "uncovered_lines": self.uncovered_lines,
                "first_reached": {str(line): self.first_line[line].as_dict() for line in sorted(self.first_line)}}


def merged(flights: Iterable[tuple[Flight, Mapping[str, Any]]], source: str | None = None) -> list[FileCoverage]:
    """Each source file's coverage over the flights' records; `source` keeps the files whose path
    ends with it."""
    files: dict[str, FileCoverage] = {}
    for flight, record in flights:
        for path, entry in record["files"].items():
            if source is None or path == source or path.endswith("/" + source.lstrip("/")):
                files.setdefault(path, FileCoverage(path)).add(entry, flight)
    return [files[path] for path in sorted(files)]


def sources_of(flights: Iterable[tuple[Flight, Mapping[str, Any]]]) -> list[str]:
    """The source trees the flights' records name (a coverage build keeps its measured sources)."""
    return sorted({record["sources"] for _flight, record in flights if record.get("sources")})


def _branch_place(branch: str) -> tuple[int, int]:
    """A branch's line and its order there: gcovr's "line:index", coverage.py's arc "from>to"."""
    line, _, rest = branch.replace(">", ":").partition(":")
    return int(line), int(rest)


def gcovr_tracefile(files: Sequence[FileCoverage]) -> dict[str, Any]:
    """The merged coverage as a gcovr JSON tracefile, each line's and branch's count the number of
    flights that ran it, for gcovr's reports."""
    from gcovr.data_model.version import FORMAT_VERSION

    entries = []
    for f in files:
        branches_at: dict[int, list[str]] = collections.defaultdict(list)
        for branch in sorted(f.branches, key=_branch_place):
            branches_at[_branch_place(branch)[0]].append(branch)
        lines = [{"line_number": line, "count": f.line_flights[line],
                  "branches": [{"branchno": index, "count": f.branch_flights[branch], "fallthrough": False, "throw": False}
                               for index, branch in enumerate(branches_at.get(line, []))]}
                 for line in sorted(f.lines | set(branches_at))]
        entries.append({"file": f.path, "lines": lines, "functions": []})
    return {"gcovr/format_version": FORMAT_VERSION, "files": entries}


def write_html(files: Sequence[FileCoverage], sources: Path, out: Path) -> Path:
    """gcovr's HTML report of the merged coverage, a page per source file read from `sources`
    (the tree the records' paths are relative to); its index page."""
    out.mkdir(parents=True, exist_ok=True)
    tracefile = out / "coverage.gcovr.json"
    tracefile.write_text(json.dumps(gcovr_tracefile(files)))
    index = out / "index.html"
    done = subprocess.run([sys.executable, "-m", "gcovr", "--json-add-tracefile", str(tracefile), "--root", str(sources),
                           "--html-details", str(index), "--html-title", "Code reached by the flights"], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"gcovr could not write the HTML report: {done.stderr.strip()[-600:]}")
    return index


@dataclass(frozen=True)
class Chosen:
    """A flight of a suite chosen by coverage, with the branches and lines it added."""

    flight: Flight
    branches_added: int
    lines_added: int

    def as_dict(self) -> dict[str, Any]:
        return {**self.flight.as_dict(), "branches_added": self.branches_added, "lines_added": self.lines_added}


def covering_suite(flights: Sequence[tuple[Flight, Mapping[str, Any]]], source: str | None = None) -> list[Chosen]:
    """A small set of the flights that reaches every branch and line any of them reached (of the
    files `source` keeps): greedy set cover, each time the flight that adds the most branches
    (then lines; then the earliest), until none adds any. Greedy is within a factor ln(n) of the
    smallest such set, and the order says what each case adds."""
    reached = []
    for flight, record in flights:
        files = merged([(flight, record)], source)
        reached.append((flight, {f"{f.path}:{b}" for f in files for b in f.first_branch}, {f"{f.path}:{n}" for f in files for n in f.first_line}))
    covered_branches: set[str] = set()
    covered_lines: set[str] = set()
    chosen: list[Chosen] = []
    while True:
        best = max(reached, key=lambda entry: (len(entry[1] - covered_branches), len(entry[2] - covered_lines), -entry[0].created), default=None)
        if best is None or not (best[1] - covered_branches or best[2] - covered_lines):
            return chosen
        chosen.append(Chosen(best[0], len(best[1] - covered_branches), len(best[2] - covered_lines)))
        covered_branches |= best[1]
        covered_lines |= best[2]
        reached.remove(best)


def stored_flights(stores: Sequence[Path]) -> list[tuple[Flight, Mapping[str, Any]]]:
    """Every flight of the stores that recorded coverage."""
    from harness.campaigns.store import Store

    flights = []
    for path in stores:
        with Store.existing(path) as store:
            flights += [(Flight(str(path), e.id, e.created), e.coverage) for e in store.all_evaluations() if e.coverage]
    return flights


def table(files: Sequence[FileCoverage]) -> str:
    rows = [f"{'file':<60} {'flights':>7} {'lines':>13} {'branches':>13}"]
    for f in files:
        rows.append(f"{f.path:<60} {f.flights:>7} {_share(len(f.first_line), len(f.lines)):>13} {_share(len(f.first_branch), len(f.branches)):>13}")
    return "\n".join(rows)


def _share(hit: int, total: int) -> str:
    return f"{hit}/{total} {100.0 * hit / total:3.0f}%" if total else "0/0"


def uncovered_text(files: Sequence[FileCoverage]) -> str:
    """The lines no flight reached, as ranges per file."""
    return "\n".join(f"{f.path}: not reached: {_ranges(f.uncovered_lines)}" for f in files if f.uncovered_lines)


def _ranges(lines: Sequence[int]) -> str:
    spans: list[list[int]] = []
    for line in lines:
        if spans and line == spans[-1][1] + 1:
            spans[-1][1] = line
        else:
            spans.append([line, line])
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in spans)


# What one line or branch that no earlier flight of the run reached is worth to the search, in
# metres of clearance.
NOVELTY_WEIGHT_M = 0.1
# What reaching a target (a mutant's mutated line) is worth: more than any difference in clearance
# between two flights, so that every flight that ran it ranks before every one that did not.
TARGET_WEIGHT_M = 1000.0


def line_name(path: str, line: int) -> str:
    """A line as code_reached names it."""
    return f"{path}:L{line}"


def ran_any(coverage: Mapping[str, Any] | None, lines: Iterable[str]) -> bool | None:
    """Whether a flight ran any of these lines (line_name), as far as its record tells: None
    without a record, or where none of them holds code in it (a constant's definition, a deleted
    statement), which a flight can depend on without running it."""
    if not coverage:
        return None
    holds_code = False
    for name in lines:
        path, _, number = name.rpartition(":L")
        entry = coverage["files"].get(path)
        if entry is None:
            continue
        if int(number) in entry["lines_hit"]:
            return True
        holds_code = holds_code or int(number) in entry["lines_missed"]
    return False if holds_code else None


def never_ran(coverage: Mapping[str, Any] | None, changed_lines: Sequence[str]) -> bool:
    """A flight whose program differs from another's only on changed_lines, and which ran none of
    them: it computed what the other would have (in the same timing), so a difference between
    them is the SUT's own spread, not the change."""
    return bool(changed_lines) and ran_any(coverage, changed_lines) is False


def withdrawn_reveal(why: str, changed_lines: Sequence[str]) -> str:
    return f"the subject never ran {', '.join(changed_lines)}, by its coverage: what differed ({why}) is the SUT's own spread"


def missed(status: str, coverage: Mapping[str, Any] | None, changed_lines: Sequence[str]) -> bool:
    """Whether a flight ran none of the changed lines, by its coverage; never said of a flight
    whose SUT died. gcov counts a block's lines as the block is left, so the line a process dies
    in (a division by zero) counts as never run, and PX4 writes its counters on its way out of
    its fault handler: the record of a crash would say the crash's own line never ran."""
    return status != Status.SUT_CRASHED and never_ran(coverage, changed_lines)


def withdrawn(differential: Mapping[str, Any], changed_lines: Sequence[str], flights: Sequence[int]) -> dict[str, Any]:
    """A pair's record with its reveal withdrawn, as these subject flights (indices) never ran the
    changed lines; marked with them, since only the first flight's coverage is stored and judging
    the pair again from it alone would restore the reveal."""
    return {**differential, "reveals": None, "why": withdrawn_reveal(differential["why"], changed_lines), "missed_changed_lines": list(flights)}


def marked_missed(differential: Mapping[str, Any]) -> bool:
    """Whether a stored pair was withdrawn as a subject flight of its that did not die never ran
    the changed lines. (Marked before the indices were kept: unless every subject flight died,
    which no longer counts.)"""
    mark = differential.get("missed_changed_lines")
    statuses = [flight["status"] for flight in differential["subject"]]
    if mark is True:
        return any(status != Status.SUT_CRASHED for status in statuses)
    return any(statuses[index] != Status.SUT_CRASHED for index in mark or ())


def code_reached(coverage: Mapping[str, Any] | None) -> frozenset[str]:
    """The lines and branches a flight ran, one name each."""
    if not coverage:
        return frozenset()
    return frozenset(f"{path}:{kind}{item}" for path, entry in coverage["files"].items()
                     for kind, items in (("L", entry["lines_hit"]), ("B", entry["branches_hit"])) for item in items)


class CodeNovelty:
    """A coverage-guided search (`--objective coverage`), as coverage-guided fuzzers reward inputs
    that reach new code: the optimizer is told the objective less NOVELTY_WEIGHT_M for each line
    and branch that the flight reached and no flight of the run before it (by ordinal, so that a
    resumed run tells the same values). A flight that reaches nothing new is told its objective as
    it is, so among those the search still goes for the closest; the stored fitness is never
    changed. Applied to what any optimizer is told, as the failure-mode sharing is
    (harness/campaigns/diversity.py).

    A target (line_name of a mutant's mutated line: a flight that does not run it cannot tell
    the mutant from its original) is worth TARGET_WEIGHT_M to every flight that ran it, so the
    search goes for it first and, once there, for the difference among the flights that run it."""

    def __init__(self, target: Iterable[str] = ()):
        self.target = frozenset(target)

    def told(self, objective: float, trial, history: Iterable) -> float:
        if not trial.reached:
            return objective
        earlier = set().union(*(other.reached for other in history if other.ordinal < trial.ordinal))
        on_target = TARGET_WEIGHT_M if trial.reached & self.target else 0.0
        return objective - NOVELTY_WEIGHT_M * len(trial.reached - earlier) - on_target
