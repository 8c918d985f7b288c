"""A differential campaign's stored pairs judged again, without flying.

A stored verdict is the one of the version that flew the pair. When an upgrade changes how pairs
are judged (harness/flight/differential.py; e.g. flights timed by their first touchdown instead
of the end of the landing's last hop), the stored flights are compared again with today's rule.
What today's rule needs and an older record lacks is read from the flight's log while the log is
still there (the first touchdown: the log's first `touchdown` event).

Re-judging can withdraw a reveal or restate it, but adds one only where the campaign confirmed
nothing (`--confirm 0`): with confirmation, a pair that did not reveal was flown once per side,
fewer flights than a reveal needs.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Mapping, Sequence

from harness.campaigns.store import Store
from harness.flight import logs
from harness.flight.differential import Outcome, compare


@dataclass(frozen=True)
class Rejudged:
    """One stored pair whose verdict changed (level or reason)."""

    scenario: str
    algorithm: str
    ordinal: int  # 0-based, as stored
    before: str | None
    why_before: str
    after: str | None
    why_after: str

    def text(self) -> str:
        return (f"{self.scenario} {self.algorithm} candidate {self.ordinal + 1}: {self.before or 'no reveal'} ({self.why_before}) "
                f"-> {self.after or 'no reveal'} ({self.why_after})")


def completed(outcome: Outcome) -> Outcome:
    """The outcome with what older records did not keep, from its flight's log if it is there."""
    if outcome.first_touchdown_s is None and outcome.log_path and Path(outcome.log_path).is_file():
        return replace(outcome, first_touchdown_s=logs.first_event_s(Path(outcome.log_path), "touchdown"))
    return outcome


def rejudge(store: Store) -> list[Rejudged]:
    """Judge every stored pair again; store and return those whose verdict changed."""
    confirmed = bool(store.campaign_config().get("confirm"))
    changed = []
    for evaluation in store.pairs():
        pair = evaluation.differential
        if pair["reveals"] is None and confirmed:
            continue
        subject = [completed(Outcome.from_dict(o)) for o in pair["subject"]]
        reference = [completed(Outcome.from_dict(o)) for o in pair["reference"]]
        verdict = compare(subject, reference)
        after = str(verdict.reveals) if verdict.reveals else None
        if after == pair["reveals"] and verdict.why == pair["why"]:
            continue
        store.rejudge(evaluation.id, {**pair, "reveals": after, "why": verdict.why, "subject": [o.as_dict() for o in subject],
                                      "reference": [o.as_dict() for o in reference]})
        changed.append(Rejudged(evaluation.scenario, evaluation.algorithm, evaluation.ordinal, pair["reveals"], pair["why"], after, verdict.why))
    return changed


def changes_text(changed: Mapping[str, Sequence[Rejudged]]) -> str:
    """Each changed verdict under its store's or mutant's name, and how many changed."""
    lines = [f"{where} {change.text()}" for where, changes in changed.items() for change in changes]
    return "\n".join(lines + [f"{len(lines)} stored verdict{'s' if len(lines) != 1 else ''} changed"])
