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
        return progress.elapsed_s >= self.seconds


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
