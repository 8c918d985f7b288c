"""Differential evaluation: one concrete scenario flown against two SUT configurations, the
*subject* (a branch, a mutant, an older build) and the *reference* (the build it is held
against), and what their outcomes say together.

A pair *reveals* a difference at one of two levels:

* `unsafe`: every subject flight violates the safety distance (f < 0) and no reference flight
  does; or the subject's SUT died in every flight (a flight controller lost in the air), where
  every reference flight flew to a recorded end;
* `behaviour`: not unsafe, but the outcomes differ beyond the reference's spread: the two sides'
  statuses never meet (the subject blocked where the reference completes its mission), or their
  minimum clearances or their flight times lie apart by more than the reference's own spread
  over its flights (and at least CLEARANCE_RESOLUTION_M / TIME_RESOLUTION_S).

A flight's time here is when it first touched down: PX4's landings on our skids hop one to five
times, 2-3 s each, before its land detector disarms, and how often is chaotic, so the time to
the end of the last hop told apart builds whose code never ran in the landing (docs/
real_faults.md). Outcomes recorded before that time was kept are compared by their whole flight.

With one flight per side the spread is zero and the resolutions alone decide: right for SUTs
that repeat bit for bit (the bundled autopilot). For PX4, whose pilot flights of one build spread
by up to 40 cm on one wall, a revealing pair is flown again (`--confirm N`) on both sides and
judged on all flights, so the spread used is the one measured.

The pair's fitness (what a search minimises) is chosen by the objective: `subject`, the
subject's own f; or `difference`, the subject's minimum clearance less the reference's (f_subject
- f_reference without the mission penalty), lowest where the subject comes closer than the
reference. A subject whose SUT died where the reference flew to its end is scored as if it had
touched the obstacle (clearance 0): among the strongest differences, without dwarfing the others.
Where either side could not finish its flight otherwise (the reference's crash, a timeout, the
simulator's crash: nothing recorded to compare) the pair gets the penalty.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from enum import StrEnum
from typing import Any, Mapping, Sequence

from harness.flight.fitness import COULD_NOT_FINISH, PENALTY, Status

# Below these, two deterministic flights are called the same: 5 cm is well under the bridge's
# range-sensor resolution and a mission's acceptance radius; 1 s of simulated time is 250
# lockstep steps, more than a waypoint's settling jitter.
CLEARANCE_RESOLUTION_M = 0.05
TIME_RESOLUTION_S = 1.0
FLOWN_TO_THE_END = frozenset({Status.OK, Status.VIOLATION})
OBJECTIVES = ("subject", "difference")


class Reveal(StrEnum):
    UNSAFE = "unsafe"
    BEHAVIOUR = "behaviour"


class Difference(StrEnum):
    """What a behaviour difference was, seen from the subject: what its regression case holds
    the subject to, and nothing else, since PX4's flights of one build vary beyond two flights'
    spread in whatever the pair did not differ by."""

    STATUS = "status"
    CLOSER = "closer"
    FARTHER = "farther"
    SHORTER = "shorter"
    LONGER = "longer"


@dataclass(frozen=True)
class Outcome:
    """What one flight of one side gave, as far as a comparison needs it."""

    status: Status
    fitness: float
    min_clearance_m: float | None
    sim_time_s: float
    why: str | None = None
    log_path: str | None = None
    first_touchdown_s: float | None = None
    violated: tuple[str, ...] = ()  # the safety properties asked that the flight violated

    @classmethod
    def of(cls, result: Any) -> "Outcome":
        return cls(Status(result.status), result.fitness, result.min_clearance_m, result.sim_time_s, result.why, result.log_path,
                   result.first_touchdown_s, tuple(name for name, scored in result.properties.items() if scored["verdict"] == "violated"))

    @classmethod
    def from_dict(cls, document: Mapping[str, Any]) -> "Outcome":
        """A stored outcome; fields a later version added are left out, so that a reference cache
        or store written by a newer version still reads (an older one stopped issue 35's searches
        when `first_touchdown_s` appeared in their cache)."""
        known = {name: value for name, value in document.items() if name in cls.__dataclass_fields__}
        return cls(**{**known, "status": Status(document["status"]), "violated": tuple(document.get("violated", ()))})

    def as_dict(self) -> dict[str, Any]:
        """Without `violated` where no property was broken (or asked), as before properties were."""
        document = {**asdict(self), "status": str(self.status)}
        if not self.violated:
            del document["violated"]
        return document


@dataclass(frozen=True)
class Verdict:
    reveals: Reveal | None
    why: str
    comparable: bool  # both sides flew to a recorded end, so there is something to compare
    difference: Difference | None = None  # with reveals BEHAVIOUR: by what


def _died_where_reference_flew(subject: Sequence[Outcome], reference: Sequence[Outcome]) -> bool:
    """Every subject flight ended with its SUT dead (a mutant's division by zero, say) and every
    reference flight flew to a recorded end."""
    return (all(o.status == Status.SUT_CRASHED for o in subject)
            and all(o.status not in COULD_NOT_FINISH and o.min_clearance_m is not None for o in reference))


def _interval(values: Sequence[float]) -> tuple[float, float]:
    return min(values), max(values)


def _apart(subject: Sequence[float], reference: Sequence[float], resolution: float) -> tuple[float, bool] | None:
    """How far the subject's values lie outside the reference's, beyond the reference's spread
    and the resolution, and whether above them (None: they do not)."""
    s_low, s_high = _interval(subject)
    r_low, r_high = _interval(reference)
    margin = max(resolution, r_high - r_low)
    below, above = r_low - s_high, s_low - r_high
    gap = max(below, above)
    return (gap, above > below) if gap > margin else None


def flight_times(subject: Sequence[Outcome], reference: Sequence[Outcome]) -> tuple[str, list[float], list[float]]:
    """What the pair's flights are timed by (module docstring), and each side's times: the first
    touchdown where every flight came down and has it, else the whole flight."""
    if all(o.first_touchdown_s is not None for o in (*subject, *reference)):
        return "touchdown", [o.first_touchdown_s for o in subject], [o.first_touchdown_s for o in reference]
    return "flight time", [o.sim_time_s for o in subject], [o.sim_time_s for o in reference]


def compare(subject: Sequence[Outcome], reference: Sequence[Outcome], names: tuple[str, str] = ("subject", "reference")) -> Verdict:
    """The verdict on all flights of a pair (each side at least one); `names` call the sides in its words."""
    mine, theirs = names
    if not subject or not reference:
        raise ValueError("a pair needs at least one flight of each side")
    if _died_where_reference_flew(subject, reference):
        return Verdict(Reveal.UNSAFE, f"the {mine}'s SUT died in flight ({subject[0].why}) where the {theirs} flew to its end "
                                      f"({'/'.join(sorted({o.status for o in reference}))})", True)
    for side, outcomes in ((mine, subject), (theirs, reference)):
        unfinished = [o for o in outcomes if o.status in COULD_NOT_FINISH or o.min_clearance_m is None]
        if unfinished:
            return Verdict(None, f"the {side} could not finish a flight ({unfinished[0].status}: {unfinished[0].why})", False)
    subject_violates = [o.status == Status.VIOLATION for o in subject]
    reference_violates = [o.status == Status.VIOLATION for o in reference]
    if all(subject_violates) and not any(reference_violates):
        worst = min(o.min_clearance_m for o in subject)
        kept = min(o.min_clearance_m for o in reference)
        return Verdict(Reveal.UNSAFE, f"the {mine} violates (min clearance {worst:.2f} m) where the {theirs} keeps {kept:.2f} m", True)
    broken = set.intersection(*(set(o.violated) for o in subject)) - set().union(*(set(o.violated) for o in reference))
    if broken:
        return Verdict(Reveal.UNSAFE, f"the {mine} violates {', '.join(sorted(broken))} where the {theirs} keeps {'it' if len(broken) == 1 else 'them'}", True)
    subject_statuses = {o.status for o in subject}
    reference_statuses = {o.status for o in reference}
    if not subject_statuses & reference_statuses:
        return Verdict(Reveal.BEHAVIOUR, f"the {mine} ends {'/'.join(sorted(subject_statuses))} where the {theirs} ends "
                                         f"{'/'.join(sorted(reference_statuses))}", True, Difference.STATUS)
    apart = _apart([o.min_clearance_m for o in subject], [o.min_clearance_m for o in reference], CLEARANCE_RESOLUTION_M)
    if apart is not None:
        gap, farther = apart
        return Verdict(Reveal.BEHAVIOUR, f"min clearance {_interval([o.min_clearance_m for o in subject])[0]:.2f} m against the {theirs}'s "
                                         f"{_interval([o.min_clearance_m for o in reference])[0]:.2f} m ({gap:.2f} m beyond its spread)", True,
                       Difference.FARTHER if farther else Difference.CLOSER)
    if subject_statuses <= FLOWN_TO_THE_END and reference_statuses <= FLOWN_TO_THE_END:
        timed_by, subject_times, reference_times = flight_times(subject, reference)
        apart = _apart(subject_times, reference_times, TIME_RESOLUTION_S)
        if apart is not None:
            gap, longer = apart
            return Verdict(Reveal.BEHAVIOUR, f"{timed_by} {subject_times[0]:.1f} s against the {theirs}'s {reference_times[0]:.1f} s "
                                             f"({gap:.1f} s beyond its spread)", True, Difference.LONGER if longer else Difference.SHORTER)
    return Verdict(None, f"no difference beyond the {theirs}'s spread", True)


def objective_value(objective: str, subject: Outcome, reference: Outcome) -> float:
    """The pair's fitness (module docstring) from each side's first flight."""
    if objective == "subject":
        return subject.fitness
    if objective != "difference":
        raise ValueError(f"objective {objective!r} is not one of {', '.join(OBJECTIVES)}")
    # Clearance against clearance: a mission the pilot could not finish because collision
    # prevention held it back (blocked) is a flight like any other here, and on either side.
    if _died_where_reference_flew([subject], [reference]):
        return -reference.min_clearance_m
    if any(side.status in COULD_NOT_FINISH or side.min_clearance_m is None for side in (subject, reference)):
        return PENALTY
    return subject.min_clearance_m - reference.min_clearance_m


def record(objective: str, subject: Sequence[Outcome], reference: Sequence[Outcome]) -> dict[str, Any]:
    """The pair as stored with the subject's result (EvaluationResult.differential)."""
    verdict = compare(subject, reference)
    return {"objective": objective, "reveals": str(verdict.reveals) if verdict.reveals else None, "why": verdict.why,
            "fitness": objective_value(objective, subject[0], reference[0]),
            "subject": [o.as_dict() for o in subject], "reference": [o.as_dict() for o in reference]}
