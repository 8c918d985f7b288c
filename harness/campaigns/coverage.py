"""The code coverage of campaigns flown with a coverage build (`stella coverage`): the stored
flights' records (sut_adapter/coverage.py) merged per source file, each line and branch with
the flight that reached it first, and the lines no flight reached; and the search it guides
(`--objective coverage`, CodeNovelty).

A line (branch) belongs to a file if some flight's record names it, hit or missed: records of
one build name the same ones. Flights of different builds of one file (a mutant and its
original) name different line numbers only where a patch moved them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence


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

    def add(self, record: Mapping[str, Sequence], flight: Flight) -> None:
        self.flights += 1
        self.lines.update(record["lines_hit"], record["lines_missed"])
        self.branches.update(record["branches_hit"], record["branches_missed"])
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
    (harness/campaigns/diversity.py)."""

    def told(self, objective: float, trial, history: Iterable) -> float:
        if not trial.reached:
            return objective
        earlier = set().union(*(other.reached for other in history if other.ordinal < trial.ordinal))
        return objective - NOVELTY_WEIGHT_M * len(trial.reached - earlier)
