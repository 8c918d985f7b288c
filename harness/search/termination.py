"""Termination objects: an evaluation budget, a wall-time budget, stop at the first violation;
combine them with AnyOf / AllOf. Pure: they look at a progress snapshot the caller passes in."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol


@dataclass(frozen=True)
class Progress:
    evaluations: int
    elapsed_s: float
    violations: int
    revealing: int = 0  # differential campaigns: candidates that reveal a difference, confirmed
    pending: int = 0  # candidates taken into the batch under way, not yet flown
    seconds_per_candidate: float = 0.0  # the wall time a batch has cost per candidate flown so far (0 before the first)


class Termination(Protocol):
    def done(self, progress: Progress) -> bool: ...


@dataclass(frozen=True)
class EvaluationBudget:
    evaluations: int

    def done(self, progress: Progress) -> bool:
        return progress.evaluations >= self.evaluations


@dataclass(frozen=True)
class WallTimeBudget:
    seconds: float

    def done(self, progress: Progress) -> bool:
        """Done once one more candidate in the batch under way would not fly before the time is up,
        as long as candidates have cost so far: a batch flies all its candidates, so a budget
        checked only by the time already spent would run over by a whole batch."""
        return progress.elapsed_s + (progress.pending + 1) * progress.seconds_per_candidate >= self.seconds


@dataclass(frozen=True)
class FirstViolation:
    def done(self, progress: Progress) -> bool:
        return progress.violations > 0


@dataclass(frozen=True)
class FirstReveal:
    def done(self, progress: Progress) -> bool:
        return progress.revealing > 0


@dataclass(frozen=True)
class AnyOf:
    parts: tuple[Termination, ...]

    def done(self, progress: Progress) -> bool:
        return any(part.done(progress) for part in self.parts)


@dataclass(frozen=True)
class AllOf:
    parts: tuple[Termination, ...]

    def done(self, progress: Progress) -> bool:
        return all(part.done(progress) for part in self.parts)
