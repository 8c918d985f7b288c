"""Flying pairs: each job against the subject SUT and the reference SUT, through one executor,
judged by harness/flight/differential.py.

Both sides of a batch go to the executor together, so they fly in parallel where it has
workers. A pair that reveals a difference is flown `confirm` more times on both sides and judged
again on all flights: with SUTs that do not repeat bit for bit, only a difference that survives
the measured spread counts. Reference flights are kept in a ReferenceCache by concrete scenario,
seed and reference build, so a case flown against many subjects (mutants) costs its first
reference flight once. The confirming reference flights are always flown afresh, beside the
subject's: a SUT's timing depends on the machine's load (PX4 lands up to 40 cm apart on one wall),
and a reference cached in a quieter sitting must not make a loaded subject look different.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
from dataclasses import replace
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping, Sequence

from harness.campaigns.coverage import missed, withdrawn
from harness.campaigns.store import ReferenceFlightTable
from harness.execution.executor import Executor, Job
from harness.flight.differential import Outcome, compare, record
from harness.flight.results import EvaluationResult
from sut_adapter import SutConfig


def firmware_digest(config: SutConfig, *, from_environment: bool = True) -> dict[str, str]:
    """The digest of the firmware binary the SUT flies, by its bytes (the same build from another
    folder is the same build): given on the command line, or named by the environment as its
    adapter reads it (STELLA_PX4_BIN); empty for a SUT without one. from_environment=False: as
    identities were before builds named by the environment counted (stores made then)."""
    from sut_adapter.ardupilot import resolve_binary as resolve_arducopter
    from sut_adapter.px4 import resolve_binary as resolve_px4

    if config.px4_bin or (from_environment and config.name == "px4"):
        return {"px4_sha256": _file_digest(resolve_px4(config.px4_bin)[0])}
    if config.ardupilot_bin or (from_environment and config.name == "ardupilot"):
        return {"ardupilot_sha256": _file_digest(resolve_arducopter(config.ardupilot_bin))}
    return {}


def build_identity(config: SutConfig, *, from_environment: bool = True) -> dict[str, object]:
    """What tells two SUT configurations apart, builds included: the SUT's identity plus its
    firmware's digest or the bundled autopilot's source folder."""
    identity: dict[str, object] = {**config.identity(), **firmware_digest(config, from_environment=from_environment)}
    for name in ("autopilot_dir", "command", "hold"):
        if getattr(config, name):
            identity[name] = str(getattr(config, name))
    return identity


def build_record(config: SutConfig) -> dict[str, object]:
    """Where the SUT's build lay and what it was, for a person reading a finding later: its
    identity, the binary's or source folder's path, and `git describe` of the tree it lies in."""
    from sut_adapter.ardupilot import resolve_binary as resolve_arducopter
    from sut_adapter.px4 import resolve_binary as resolve_px4

    record = build_identity(config)
    where: Path | None = None
    if "px4_sha256" in record:
        where = resolve_px4(config.px4_bin)[0]
    elif "ardupilot_sha256" in record:
        where = resolve_arducopter(config.ardupilot_bin)
    elif config.name == "bundled":
        where = Path(config.autopilot_dir) if config.autopilot_dir else Path(__file__).resolve().parents[2]
    if where is not None:
        record["path"] = str(where)
        described = _git_describe(where if where.is_dir() else where.parent)
        if described:
            record["git_describe"] = described
    return record


def _git_describe(folder: Path) -> str | None:
    try:
        found = subprocess.run(["git", "-C", str(folder), "describe", "--always", "--dirty", "--tags"], capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return found.stdout.strip() if found.returncode == 0 and found.stdout.strip() else None


_DIGESTS: dict[tuple[str, float, int], str] = {}


def _file_digest(path: Path) -> str:
    stat = path.stat()
    key = (str(path), stat.st_mtime, stat.st_size)
    if key not in _DIGESTS:
        digest = hashlib.sha256()
        with open(path, "rb") as file:
            for block in iter(lambda: file.read(1 << 20), b""):
                digest.update(block)
        _DIGESTS[key] = digest.hexdigest()
    return _DIGESTS[key]


class ReferenceCache:
    """Reference flights by (concrete scenario, seed, reference build, properties), kept in the store's
    table of them (a campaign's store, or one file shared by a mutation run's campaigns)."""

    def __init__(self, path: Path):
        self._table = ReferenceFlightTable(path)

    @staticmethod
    def key(job: Job, reference: Mapping[str, object]) -> str:
        key = {"concrete": job.concrete, "seed": job.seed, "drive": job.world.drive, "reference": reference}
        if job.options.properties:  # what was scored belongs to the flight: not one flown without them
            key["properties"] = [prop.as_dict() for prop in job.options.properties]
        text = json.dumps(key, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()

    def get(self, key: str) -> list[Outcome]:
        return [Outcome.from_dict(o) for o in self._table.get(key)]

    def items(self) -> list[tuple[str, list[Outcome]]]:
        return [(key, [Outcome.from_dict(o) for o in outcomes]) for key, outcomes in self._table.items()]

    def put(self, key: str, outcomes: list[Outcome]) -> None:
        self._table.put(key, [o.as_dict() for o in outcomes])

    def close(self) -> None:
        self._table.close()


class PairedFlights:
    """Flies jobs as pairs; `run` yields each subject job with its result, whose `fitness` is the
    objective's and whose `differential` holds both sides' flights and the verdict."""

    def __init__(self, executor: Executor, reference: SutConfig, *, objective: str = "subject", confirm: int = 0, cache: ReferenceCache | None = None,
                 changed_lines: Sequence[str] = ()):
        """changed_lines: where the subject's program differs from the reference's (a mutant's
        mutated line, harness/campaigns/coverage.line_name); a coverage build's flight that ran
        none of them reveals nothing."""
        self.changed_lines = tuple(changed_lines)
        self.executor = executor
        self.reference = reference
        self.objective = objective
        self.confirm = confirm
        self.cache = cache
        self._reference_identity = build_identity(reference)

    def _reference_job(self, job: Job, flight: int) -> Job:
        return replace(job, name=f"{job.name}-reference" + (f"-confirm{flight}" if flight else ""), options=replace(job.options, sut=self.reference))

    def _fly(self, jobs: list[Job]) -> dict[str, EvaluationResult]:
        """Each job flown once, by name (the executor's keys renumbered and given back)."""
        numbered = [replace(job, key=number) for number, job in enumerate(jobs)]
        return {job.name: result for job, result in self.executor.run(numbered)}

    def run(self, jobs: Iterable[Job]) -> Iterator[tuple[Job, EvaluationResult]]:
        jobs = list(jobs)
        keys = {job.name: ReferenceCache.key(job, self._reference_identity) for job in jobs}
        references = {job.name: self.cache.get(keys[job.name]) if self.cache else [] for job in jobs}
        first = self._fly(jobs + [self._reference_job(job, 0) for job in jobs if not references[job.name]])
        subjects = {job.name: [first[job.name]] for job in jobs}
        for job in jobs:
            if not references[job.name]:
                references[job.name] = [Outcome.of(first[f"{job.name}-reference"])]
                self._remember(keys[job.name], references[job.name])
        revealing = [job for job in jobs if compare([Outcome.of(subjects[job.name][0])], references[job.name]).reveals is not None
                     and not missed(subjects[job.name][0].status, subjects[job.name][0].coverage, self.changed_lines)]
        if self.confirm and revealing:
            again = [replace(job, name=f"{job.name}-confirm{i}") for job in revealing for i in range(1, self.confirm + 1)]
            again += [self._reference_job(job, i) for job in revealing for i in range(1, self.confirm + 1)]
            flown = self._fly(again)
            for job in revealing:
                subjects[job.name] += [flown[f"{job.name}-confirm{i}"] for i in range(1, self.confirm + 1)]
                references[job.name] = references[job.name] + [Outcome.of(flown[f"{job.name}-reference-confirm{i}"])
                                                                for i in range(1, self.confirm + 1)]
                self._remember(keys[job.name], references[job.name])
        for job in jobs:
            flights = subjects[job.name]
            differential = record(self.objective, [Outcome.of(r) for r in flights], references[job.name])
            missing = [index for index, flight in enumerate(flights) if missed(flight.status, flight.coverage, self.changed_lines)]
            if differential["reveals"] and missing:
                differential = withdrawn(differential, self.changed_lines, missing)
            yield job, replace(flights[0], fitness=differential["fitness"], differential=differential)

    def again(self, job: Job, subject: Sequence[Outcome], reference: Sequence[Outcome], more: int) -> dict[str, Any]:
        """A pair flown before, with its flights so far, flown `more` times again on both sides in
        one sitting (as confirmations are), and its record judged on all of its flights."""
        subject_jobs = [replace(job, name=f"{job.name}-confirm{i}") for i in range(len(subject), len(subject) + more)]
        reference_jobs = [self._reference_job(job, i) for i in range(len(reference), len(reference) + more)]
        flown = self._fly(subject_jobs + reference_jobs)
        new_subject = [flown[j.name] for j in subject_jobs]
        differential = record(self.objective, [*subject, *map(Outcome.of, new_subject)], [*reference, *(Outcome.of(flown[j.name]) for j in reference_jobs)])
        missing = [len(subject) + index for index, flight in enumerate(new_subject) if missed(flight.status, flight.coverage, self.changed_lines)]
        if differential["reveals"] and missing:
            differential = withdrawn(differential, self.changed_lines, missing)
        return differential

    def _remember(self, key: str, outcomes: list[Outcome]) -> None:
        if self.cache is not None:
            self.cache.put(key, outcomes)


def outcome_lines(differential: Mapping[str, object]) -> list[str]:
    """A pair in words, for the CLI."""
    lines = []
    for side in ("subject", "reference"):
        for index, outcome in enumerate(differential[side]):  # type: ignore[index]
            clearance = "-" if outcome["min_clearance_m"] is None else f"{outcome['min_clearance_m']:.3f} m"
            lines.append(f"{side}{'' if index == 0 else f' (flight {index + 1})'}: {outcome['status']}, min clearance {clearance}, "
                         f"{outcome['sim_time_s']:.1f} s" + (f" ({outcome['why']})" if outcome.get("why") else ""))
    reveals = differential["reveals"]
    lines.append(f"reveals: {reveals or 'nothing'}: {differential['why']}")
    return lines

