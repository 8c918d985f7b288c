"""Shrinking a violating concrete scenario: the smallest, simplest one that still violates.

As Hypothesis shrinks a failing example and delta debugging minimises a failing input, each step
(harness/campaigns/shrink_steps.py) proposes a smaller or simpler scenario; it is flown, and kept
only if the flight still violates the safety distance, `confirm` times out of `confirm` for a SUT
that does not repeat itself bit for bit. Passes repeat while one removes an element.

Every candidate's flights go to a journal (JSON lines, beside the output) keyed by the candidate's
content, so a shrink that was stopped, killed or ran out of budget is run again with the same
command and replays what it flew: the steps are a function of the scenario and the flights, so
the replay walks the same path and flies only what it had not.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from harness.campaigns.regression import EXPECTATIONS, FORMAT as REGRESSION_FORMAT, SUFFIX as REGRESSION_SUFFIX
from harness.campaigns.shrink_steps import REMOVALS, STEPS, Document, elements
from harness.errors import InfrastructureError, InputError, Problem
from harness.flight.fitness import COULD_NOT_FINISH, Status
from harness.flight.logs import slug
from harness.scenario.documents import load_json
from harness.scenario.logical import with_rig_embedded
from harness.scenario.world import space_from_concrete, with_drive_recorded

JOURNAL_FORMAT = "stella.shrink-journal/1"
ATTEMPTS = 2  # flights of a candidate whose flight could not finish, as `stella campaign --attempts`
MCAP_MAGIC = b"\x89MCAP0\r\n"
SQLITE_MAGIC = b"SQLite format 3\x00"


@dataclass(frozen=True)
class Flight:
    """What the journal keeps of one flight."""

    status: str
    fitness: float
    min_clearance_m: float | None
    obstacle: str | None
    log: str | None
    why: str | None = None
    verdict: str | None = None  # a differential shrink's: the gate's judgement of the pair this flight is the head of (a regression's kind)
    properties: Mapping[str, Any] | None = None  # the safety properties scored (a shrink with --property)


def violating(flight: Flight) -> bool:
    """What a shrink keeps by default: a flight that violated the safety distance."""
    return flight.status == Status.VIOLATION


def violating_properties(names: Sequence[str]) -> Callable[[Flight], bool]:
    """What a shrink of safety properties keeps: a flight that violated every one of them."""
    return lambda flight: bool(flight.properties) and all(flight.properties[name]["verdict"] == "violated" for name in names)


@dataclass(frozen=True)
class Case:
    """A violating concrete scenario to shrink and what its source says about it."""

    document: Document
    seed: int
    sut: Mapping[str, Any] | None  # the SUT it was found with, where its source records one
    label: str  # the file (and evaluation) for messages
    name: str  # the stem of the outputs
    found: Mapping[str, Any] = field(default_factory=dict)


def load_case(path: Path, evaluation: int | str | None, seed: int | None) -> Case:
    """A concrete scenario or regression case (JSON), an evaluation log (MCAP) or a campaign store
    (SQLite, with `evaluation`: its id or its log's file name)."""
    if not path.is_file():
        raise InputError([Problem(str(path), "", "no such file: give a concrete scenario or regression case (JSON), "
                                                  "an evaluation log (.mcap) or a campaign store with --evaluation N")])
    with path.open("rb") as handle:
        magic = handle.read(16)
    if magic == SQLITE_MAGIC:
        case = _from_store(path, evaluation)
    elif evaluation is not None:
        raise InputError([Problem("--evaluation", "", f"{path} is not a campaign store: --evaluation picks an evaluation of one")])
    elif magic.startswith(MCAP_MAGIC):
        case = _from_log(path)
    else:
        case = _from_json(path)
    return case if seed is None else Case(case.document, seed, case.sut, case.label, case.name, case.found)


def _from_store(path: Path, evaluation: int | str | None) -> Case:
    from harness.campaigns.store import Store

    if evaluation is None:
        raise InputError([Problem("--evaluation", "", f"{path} is a campaign store: say which evaluation to shrink with --evaluation N "
                                                      "(its id, as `stella triage --json` and the campaign page show it)")])
    with Store.existing(path) as store:
        if isinstance(evaluation, str):
            stored = store.evaluation_logged_as(evaluation)
            if stored is None:
                raise InputError([Problem(str(path), "--evaluation", f"no evaluation of this store logged as {evaluation}: "
                                                                     "give the id, or the name of a log in its logs folder")])
            evaluation = stored.id
        stored = store.evaluation(evaluation)
        sut = store.campaign_sut()
        count = len(store.all_evaluations())
    label = f"{path} evaluation {evaluation}"
    if stored is None:
        raise InputError([Problem(str(path), "--evaluation", f"no evaluation {evaluation} in this store (it holds {count}; "
                                                             "an evaluation's id is the number in its log's name, as triage and the campaign page show it)")])
    if stored.concrete is None:
        raise InputError([Problem(str(path), "--evaluation", f"evaluation {evaluation} kept no concrete scenario to fly again")])
    found = {"store": str(path.resolve()), "evaluation": evaluation, "run": stored.run_index, "algorithm": stored.algorithm,
             "fitness": stored.fitness, "status": str(stored.status), "log": stored.log_path}
    return Case(stored.concrete, stored.seed, sut, label, slug(f"{path.stem}-evaluation{evaluation}"), found)


def _from_log(path: Path) -> Case:
    from harness.flight import logs

    concrete = logs.json_metadata(path, "concrete_scenario")
    if concrete is None:
        raise InputError([Problem(str(path), "metadata concrete_scenario", "missing: not the log of a flight of this tool (`stella run`, a campaign)")])
    result = logs.json_metadata(path, "result") or {}
    found = {"log": str(path), **{key: result[key] for key in ("fitness", "status") if key in result}}
    return Case(concrete, int(result.get("seed", 0)), logs.json_metadata(path, "sut"), str(path), slug(path.stem), found)


def _from_json(path: Path) -> Case:
    document = load_json(path)
    stem = slug(path.name.removesuffix(REGRESSION_SUFFIX).removesuffix(".json"))
    if isinstance(document, dict) and document.get("format") == REGRESSION_FORMAT:
        from harness.campaigns.regression import load_regression

        case = load_regression(path)
        return Case(dict(case.concrete), case.seed, case.sut.identity(), str(path), stem, dict(case.found))
    return Case(document, 0, None, str(path), stem)


def start_document(case: Case, drive: str | None = None, mission_plan: Path | None = None, rig: str | None = None) -> Document:
    """The case as a checked concrete scenario document, flown with `drive`, `mission_plan` and
    `rig` (a sensor rig's preset name or file) if given."""
    document = with_drive_recorded(case.document, drive)
    if rig is not None:
        document = {**document, "logical_scenario": with_rig_embedded(document["logical_scenario"], Path(case.label), rig)}
    space = space_from_concrete(document, case.label, drive, mission_plan)
    x = space.from_concrete(document, case.label)
    broken = space.violations(x)
    if broken:
        raise InputError([Problem(case.label, "", f"breaks the realism constraints {', '.join(broken)}: it is never flown, so there is nothing to shrink")])
    return space.to_concrete(x)


def key_of(document: Document) -> str:
    return hashlib.sha256(json.dumps(document, sort_keys=True).encode()).hexdigest()


class Journal:
    """The flights of every candidate tried, one JSON line each after a header naming the shrink."""

    def __init__(self, path: Path, header: Mapping[str, Any]):
        self.path = path
        self.entries: dict[str, list[Flight]] = {}
        if path.is_file() and path.stat().st_size:
            self._read(dict(header))
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._append(dict(header))

    def _read(self, header: dict[str, Any]) -> None:
        text = self.path.read_text()
        if not text.endswith("\n"):
            # The line a killed shrink was writing: dropped, so the next line starts clean.
            text = text[:text.rfind("\n") + 1]
            self.path.write_text(text)
        lines = text.splitlines()
        try:
            written = json.loads(lines[0]) if lines else None
        except json.JSONDecodeError:
            written = None
        if written != header:
            raise InputError([Problem(str(self.path), "", "the journal of another shrink (another case, SUT, seed or --confirm): "
                                                          "delete it to start afresh, or give another --out or --name")])
        for line in lines[1:]:
            entry = json.loads(line)
            self.entries[entry["key"]] = [Flight(**flight) for flight in entry["flights"]]

    def _append(self, entry: Mapping[str, Any]) -> None:
        with self.path.open("a") as handle:
            handle.write(json.dumps(entry) + "\n")
            handle.flush()
            os.fsync(handle.fileno())

    def flights(self, key: str) -> list[Flight] | None:
        return self.entries.get(key)

    def record(self, key: str, step: str, flights: list[Flight]) -> None:
        self.entries[key] = flights
        self._append({"key": key, "step": step, "flights": [asdict(f) for f in flights]})


@dataclass(frozen=True)
class Budget:
    flights: int | None = None  # flights this session may make (replays from the journal are free)
    wall_s: float | None = None


@dataclass(frozen=True)
class StepRecord:
    kind: str
    description: str
    f_before: float
    f_after: float
    kept: bool
    replayed: bool  # answered from the journal, not flown
    flights: int


@dataclass
class ShrinkReport:
    start: Document
    result: Document
    f_start: float
    f_result: float
    result_flights: list[Flight]
    steps: list[StepRecord]
    flown: int
    replayed: int
    wall_s: float
    stopped: str | None  # why the shrink ended before it was done (a budget), None if it was
    unfinished_flight: bool = False  # it stopped because a flight could not finish

    @property
    def kept(self) -> list[StepRecord]:
        return [step for step in self.steps if step.kept]


class Stopped(Exception):
    """The shrink cannot go on in this session; the journal keeps what it flew."""


class BudgetSpent(Stopped):
    pass


class FlightUnfinished(Stopped):
    """A candidate's flight could not finish, attempt after attempt: the SUT or the machine is at
    fault, not the candidate, so nothing is concluded from it (nor journaled)."""


@dataclass
class State:
    """The smallest violating scenario so far and its flights; the steps read it as they go."""

    current: Document
    flights: list[Flight]

    @property
    def closest_obstacle_index(self) -> int | None:
        obstacle = self.flights[0].obstacle
        return int(obstacle.removeprefix("obstacle_")) - 1 if obstacle and obstacle.startswith("obstacle_") else None


Fly = Callable[[Document, str], Flight]


class Shrinker:
    """`keeps` says whether a candidate's flight still fails (by default: it violates), `confirm`
    flights of it in a row must."""

    def __init__(self, fly: Fly, journal: Journal, *, confirm: int = 1, budget: Budget = Budget(),
                 on_step: Callable[[StepRecord, "Shrinker"], None] | None = None, keeps: Callable[[Flight], bool] = violating,
                 kept: str = "the safety distance"):
        self.fly, self.journal, self.confirm, self.budget, self.on_step, self.keeps = fly, journal, confirm, budget, on_step, keeps
        self.kept = kept  # what `keeps` holds violated, in words
        self.flown = self.replayed = 0
        self.started = time.monotonic()

    @property
    def elapsed_s(self) -> float:
        return time.monotonic() - self.started

    def _flights(self, document: Document, step: str) -> tuple[list[Flight], bool]:
        key = key_of(document)
        recorded = self.journal.flights(key)
        if recorded is not None:
            self.replayed += 1
            return recorded, True
        flights: list[Flight] = []
        while len(flights) < self.confirm and (not flights or self.keeps(flights[-1])):
            if self.budget.flights is not None and self.flown >= self.budget.flights:
                raise BudgetSpent(f"the evaluation budget of {self.budget.flights} flights is spent")
            if self.budget.wall_s is not None and self.elapsed_s >= self.budget.wall_s:
                raise BudgetSpent(f"the time budget of {self.budget.wall_s:g} s is spent")
            flights.append(self._finished_flight(document, f"{key[:12]}-{len(flights) + 1}"))
        self.journal.record(key, step, flights)
        return flights, False

    def _finished_flight(self, document: Document, name: str) -> Flight:
        """A flight that could not finish (the SUT crashed, time ran out on a busy machine) says
        nothing about the candidate: flown again, as an executor tries such an evaluation again."""
        for _attempt in range(ATTEMPTS):
            flight = self.fly(document, name)
            self.flown += 1
            if flight.status not in COULD_NOT_FINISH:
                return flight
        raise FlightUnfinished(f"a flight could not finish in {ATTEMPTS} attempts ({flight.status}"
                               + (f": {flight.why}" if flight.why else "") + ")")

    def fails(self, flights: list[Flight]) -> bool:
        return len(flights) == self.confirm and all(self.keeps(f) for f in flights)

    def start(self, document: Document, label: str) -> State:
        """The case flown as given: it must violate to be shrunk."""
        try:
            flights, _ = self._flights(document, "the case as given")
        except FlightUnfinished as unfinished:
            self._forget_journal()
            raise InfrastructureError(f"{label}: the case as given: {unfinished}") from None
        if self.fails(flights):
            return State(document, flights)
        self._forget_journal()
        seen = ", ".join(f"{f.status} with fitness {f.fitness:.3f}" for f in flights)
        raise InputError([Problem(label, "", f"does not violate {self.kept} as given (flown: {seen}"
                                             + (f", {len(flights)} of --confirm {self.confirm} flights" if self.confirm > 1 else "")
                                             + "): there is nothing to shrink; give a violating case, or the SUT it violated with (--sut, --sut-param)")])

    def _forget_journal(self) -> None:
        """A shrink refused at its start leaves nothing to resume, and a journal left behind would
        refuse the same case with another SUT."""
        if len(self.journal.entries) <= 1:
            self.journal.path.unlink(missing_ok=True)

    def shrink(self, document: Document, label: str) -> ShrinkReport:
        state = self.start(document, label)
        f_start = worst_case_fitness(state.flights)
        steps: list[StepRecord] = []
        stopped, unfinished = None, False
        try:
            removed = True
            while removed:
                removed = False
                for family in STEPS:
                    for candidate in family(state):
                        before = worst_case_fitness(state.flights)
                        flights, replayed = self._flights(candidate.document, candidate.description)
                        kept = self.fails(flights)
                        record = StepRecord(candidate.kind, candidate.description, before, worst_case_fitness(flights), kept, replayed, len(flights))
                        steps.append(record)
                        if kept:
                            _discard(state.flights)
                            state.current, state.flights = candidate.document, flights
                            removed |= candidate.kind in REMOVALS
                        else:
                            _discard(flights)
                        if self.on_step:
                            self.on_step(record, self)
        except Stopped as why:
            stopped, unfinished = str(why), isinstance(why, FlightUnfinished)
        return ShrinkReport(document, state.current, f_start, worst_case_fitness(state.flights), state.flights, steps, self.flown, self.replayed,
                            self.elapsed_s, stopped, unfinished)


def worst_case_fitness(flights: list[Flight]) -> float:
    """The fitness a step is judged by: its least violating flight's."""
    return max(f.fitness for f in flights)


def _discard(flights: list[Flight]) -> None:
    """A rejected or superseded candidate's logs: only the shrunk case's is kept."""
    for flight in flights:
        if flight.log:
            Path(flight.log).unlink(missing_ok=True)
            shutil.rmtree(Path(flight.log).with_suffix(".artifacts"), ignore_errors=True)


def flyer(options, seed: int, out_dir: Path) -> Fly:
    """Flights of candidates with these RunOptions and seed, their logs in out_dir."""
    from harness.flight.evaluation import evaluate
    from harness.campaigns.shrink_steps import space_of

    def fly(document: Document, name: str) -> Flight:
        space = space_of(document)
        result = evaluate(space, space.from_concrete(document), seed=seed, out_dir=out_dir, options=options, name=name)
        if options.properties and result.properties:
            # A shrink of safety properties measures its steps by the least robustness among them.
            least = min(scored["robustness"] for scored in result.properties.values())
            return Flight(str(result.status), least, result.min_clearance_m, result.min_clearance_obstacle, result.log_path, result.why,
                          properties=result.properties)
        return Flight(str(result.status), result.fitness, result.min_clearance_m, result.min_clearance_obstacle, result.log_path, result.why)

    return fly


def write_outputs(report: ShrinkReport, case: Case, out_dir: Path, name: str, sut_identity: Mapping[str, Any], expect: str,
                  properties: Sequence[Mapping[str, Any]] = ()) -> dict[str, str]:
    """The shrunk concrete scenario, its regression case and the log of its flight."""
    out_dir.mkdir(parents=True, exist_ok=True)
    concrete = out_dir / f"{name}.concrete.json"
    concrete.write_text(json.dumps(report.result, indent=2) + "\n")
    log = out_dir / f"{name}.mcap"
    flown = report.result_flights[0].log
    if flown and Path(flown).is_file():
        shutil.move(flown, log)
    final = report.result_flights[0]
    regression = out_dir / f"{name}{REGRESSION_SUFFIX}"
    regression.write_text(json.dumps({
        "format": REGRESSION_FORMAT, "name": name, "expect": expect, "seed": case.seed, "sut": dict(sut_identity),
        "found": {**case.found, "fitness": final.fitness, "status": final.status, "min_clearance_m": final.min_clearance_m,
                  "log": str(log) if log.is_file() else None, "shrunk_from": case.label, "fitness_before_shrinking": report.f_start},
        "note": f"{EXPECTATIONS[expect]}; shrunk by `stella shrink` from {case.label} in {len(report.kept)} steps, "
                f"fitness {report.f_start:.3f} -> {report.f_result:.3f}" + (f" (stopped early: {report.stopped})" if report.stopped else ""),
        "concrete_scenario": report.result,
        **({"properties": list(properties)} if properties else {}),
    }, indent=2) + "\n")
    return {"concrete": str(concrete), "regression": str(regression), **({"log": str(log)} if log.is_file() else {})}


def summary(report: ShrinkReport) -> dict[str, Any]:
    return {"before": {"fitness": report.f_start, "elements": elements(report.start)},
            "after": {"fitness": report.f_result, "elements": elements(report.result)},
            "steps": [asdict(step) for step in report.steps], "kept": [asdict(step) for step in report.kept],
            "flown": report.flown, "replayed": report.replayed, "wall_s": report.wall_s, "stopped": report.stopped,
            "unfinished_flight": report.unfinished_flight}


def elements_text(counted: Mapping[str, Any]) -> str:
    kinds = ", ".join(f"{n} {kind}" for kind, n in counted["by_kind"].items())
    return (f"{counted['obstacles']} obstacle(s)" + (f" ({kinds})" if kinds else "") + f", {counted['failures']} failure(s), "
            + ("gusts" if counted["gusts"] else "no gusts") + f", wind {counted['wind_speed_m_s']:.3g} m/s, visibility {counted['visibility_m']:g} m, "
            f"{counted['searched_values']} searched values")


def step_line(step: StepRecord) -> str:
    return (f"{'kept' if step.kept else 'no  '} {step.description}: f {step.f_before:.3f} -> {step.f_after:.3f}"
            + (" (from the journal)" if step.replayed else ""))
