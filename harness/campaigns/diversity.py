"""Search for diverse failures (`stella campaign --objective diverse`): fitness sharing over
failure modes.

A campaign that minimises the clearance alone lets the easiest failure take over: once one
obstacle is hit, every generation breeds more of the same hit (234 of 234 violations with one
intruder, measured). Evolutionary search has two classic answers. *Fitness sharing* (Goldberg and
Richardson, 1987) divides a solution's fitness by the crowd in its niche, so that selection keeps
sub-populations in several niches; *quality diversity* (MAP-Elites, novelty search with local
competition) keeps the best solution per niche of a behaviour descriptor. Both need a niche; here
it is the failure mode that triage reads from the log at the moment of least clearance (obstacle,
approach, phase, closing speed, weather: harness/campaigns/triage.py), the same mode by which a
campaign's diversity is counted afterwards.

Sharing is applied to what the optimizer is told, never to what is stored: a violation's f (< 0)
is divided by one plus the number of violations of its mode found before it (by ordinal, so the
values do not depend on which flight finished first, and a resumed run tells the same), and a
flight that does not violate is told its f as it is. So any violation still beats any flight that
keeps its distance (diversity never costs finding a violation at all), a violation of a new mode
beats a repeat of a crowded one of the same depth, and the pull deeper into one mode fades as that
mode fills. This works for every optimizer and sequence (each sees one scalar), unlike a
per-obstacle multi-objective front, which BO and the sequences could not use.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterable

from harness.errors import InputError
from harness.flight.fitness import Status

UNKNOWN_MODE = "unknown (no log to read the mode from)"


def mode_from_log(log_path: str | None) -> str:
    """A violation's failure mode as triage names it; violations without a readable log share one mode."""
    from harness.campaigns.triage import features, mode_name

    if not log_path or not Path(log_path).is_file():
        return UNKNOWN_MODE
    try:
        return mode_name(features(Path(log_path)))
    except InputError:
        return UNKNOWN_MODE


class FailureModes:
    """The modes of a run's violations, read once each, and the shared fitness they give."""

    def __init__(self, mode_of: Callable[[str | None], str] = mode_from_log):
        self._mode_of = mode_of
        self._modes: dict[int, str] = {}  # by ordinal

    def mode(self, ordinal: int, log_path: str | None) -> str:
        if ordinal not in self._modes:
            self._modes[ordinal] = self._mode_of(log_path)
        return self._modes[ordinal]

    def shared(self, trial, history: Iterable) -> float:
        """What the optimizer is told for trial, given the run's trials so far (module docstring)."""
        if trial.status != Status.VIOLATION:
            return trial.fitness
        mode = self.mode(trial.ordinal, trial.log_path)
        crowd = sum(1 for other in history
                    if other.status == Status.VIOLATION and other.ordinal < trial.ordinal and self.mode(other.ordinal, other.log_path) == mode)
        return trial.fitness / (1 + crowd)
