"""A differential campaign's stored pairs judged again, without flying.

A stored verdict is the one of the version that flew the pair. When an upgrade changes how pairs
are judged (harness/flight/differential.py; e.g. flights timed by their first touchdown instead
of the end of the landing's last hop), the stored flights are compared again with today's rule.
What today's rule needs and an older record lacks is read from the flight's log while the log is
still there (the first touchdown: the log's first `touchdown` event), and stored with the flight,
in the pairs and in the cached reference flights that later pairs are judged with.

Of a mutant (changed_lines), a reveal whose first subject flight never ran the mutated line by its
stored coverage record is withdrawn, as PairedFlights would withdraw it now, and one withdrawn
when flown (any of its subject flights never ran it: marked so) stays withdrawn.

Re-judging can withdraw a reveal, restate it, or add one, but only on a pair flown as often as
the campaign confirms (`--confirm N`: 1 + N flights a side): a pair that did not reveal when
flown was flown once a side, fewer flights than a reveal needs.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Sequence

from harness.campaigns.coverage import marked_missed, missed, withdrawn_reveal
from harness.campaigns.pairs import ReferenceCache
from harness.campaigns.store import Store
from harness.errors import InputError, Problem
from harness.flight import logs
from harness.flight.differential import Outcome, compare


@dataclass(frozen=True)
class Rejudged:
    """One stored pair whose verdict changed (level or reason)."""

    evaluation_id: int
    scenario: str
    algorithm: str
    run_index: int
    before: str | None
    why_before: str
    after: str | None
    why_after: str

    def text(self) -> str:
        return (f"evaluation {self.evaluation_id} ({self.scenario} {self.algorithm} run {self.run_index}): {self.before or 'no reveal'} "
                f"({self.why_before}) -> {self.after or 'no reveal'} ({self.why_after})")


@dataclass
class Rejudgement:
    """What judging again changed, by store or mutant, and the flights whose logs were gone."""

    changed: dict[str, list[Rejudged]] = field(default_factory=dict)
    logs_gone: set[str] = field(default_factory=set)

    def text(self) -> str:
        lines = [f"{where} {change.text()}" for where, changes in self.changed.items() for change in changes]
        lines.append(f"{len(lines)} stored verdict{'s' if len(lines) != 1 else ''} changed")
        if self.logs_gone:
            count = len(self.logs_gone)
            lines.append(f"the logs of {count} flight{'s' if count != 1 else ''} are gone (e.g. {min(self.logs_gone)}): lacking their first "
                         "touchdown, their pairs are still timed by the whole flight")
        return "\n".join(lines)

    def as_dict(self) -> dict[str, object]:
        return {"changed": {where: [vars(change) for change in changes] for where, changes in self.changed.items()},
                "logs_gone": sorted(self.logs_gone)}


def _completed(outcome: Outcome, logs_gone: set[str]) -> Outcome:
    """The outcome with what older records did not keep, from its flight's log if it is there."""
    if outcome.first_touchdown_s is not None or not outcome.log_path:
        return outcome
    if not Path(outcome.log_path).is_file():
        logs_gone.add(outcome.log_path)
        return outcome
    return replace(outcome, first_touchdown_s=logs.first_event_s(Path(outcome.log_path), "touchdown"))


def complete_references(cache: ReferenceCache, logs_gone: set[str]) -> None:
    """The cached reference flights with what their records lack, so that pairs flown from now on
    are judged with today's rule too."""
    for key, outcomes in cache.items():
        completed = [_completed(o, logs_gone) for o in outcomes]
        if completed != outcomes:
            cache.put(key, completed)


def rejudge(store: Store, logs_gone: set[str], changed_lines: Sequence[str] = ()) -> list[Rejudged]:
    """Judge the store's pairs again; store every pair a log completed and return those whose
    verdict changed. changed_lines: as PairedFlights', read against the coverage the store kept
    of each pair's first subject flight."""
    confirm = int(store.campaign_config().get("confirm", 0))
    changed = []
    for evaluation in store.pairs():
        pair = evaluation.differential
        if len(pair["subject"]) <= confirm:  # flown once, not revealing: too few flights to judge again
            continue
        subject = [_completed(Outcome.from_dict(o), logs_gone) for o in pair["subject"]]
        reference = [_completed(Outcome.from_dict(o), logs_gone) for o in pair["reference"]]
        verdict = compare(subject, reference)
        if verdict.reveals and (marked_missed(pair) or missed(evaluation.status, evaluation.coverage, changed_lines)):
            verdict = replace(verdict, reveals=None, why=withdrawn_reveal(verdict.why, changed_lines))
        after = str(verdict.reveals) if verdict.reveals else None
        sides = {"subject": [o.as_dict() for o in subject], "reference": [o.as_dict() for o in reference]}
        if after == pair["reveals"] and verdict.why == pair["why"]:
            if sides != {"subject": pair["subject"], "reference": pair["reference"]}:
                store.rejudge(evaluation.id, {**pair, **sides})
            continue
        store.rejudge(evaluation.id, {**pair, "reveals": after, "why": verdict.why, **sides})
        changed.append(Rejudged(evaluation.id, evaluation.scenario, evaluation.algorithm, evaluation.run_index, pair["reveals"], pair["why"],
                                after, verdict.why))
    return changed


def rejudge_campaigns(paths: list[Path]) -> Rejudgement:
    """`stella rejudge`: each differential campaign store's pairs and cached reference flights;
    every store is checked before any is changed."""
    for path in paths:
        with Store.existing(path) as store:
            if not store.is_differential():
                raise InputError([Problem(str(path), "", "not a differential campaign (flown without --reference-...): it has no pairs to judge")])
    result = Rejudgement()
    for path in paths:
        cache = ReferenceCache(path)
        try:
            complete_references(cache, result.logs_gone)
        finally:
            cache.close()
        with Store.existing(path) as store:
            changes = rejudge(store, result.logs_gone)
        if changes:
            result.changed[str(path)] = changes
    return result
