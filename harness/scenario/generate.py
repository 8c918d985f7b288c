"""t-wise generation of logical scenarios with covertable (a maintained covering-array library).

The factors are the paper's value sets: landform, surface nature, wind force, reduced
visibility, and up to four obstacle slots of kind, size and form. Slots 2-4 may be empty
("-"); an empty slot is empty in all three of its factors, and slots fill from the first.
"""

from __future__ import annotations

import math

from itertools import combinations
from typing import Any, Iterable, Mapping

import covertable

EMPTY = "-"
MAX_OBSTACLES = 4
KINDS = ("static", "dynamic")
SIZES = ("small", "medium", "large")
FORMS = ("cuboid", "sphere", "cylinder")
SLOT_FIELDS = ("kind", "size", "form")


def paper_factors() -> dict[str, list[str]]:
    factors: dict[str, list[str]] = {
        "landform": ["flat", "depression", "elevation", "steep transition"],
        "surface nature": ["land", "water", "mixture"],
        "wind force": ["none", "light", "moderate", "strong"],
        "reduced visibility": ["none", "fog", "heavy fog", "thick fog"],
    }
    for slot in range(1, MAX_OBSTACLES + 1):
        optional = [] if slot == 1 else [EMPTY]
        for field, values in zip(SLOT_FIELDS, (KINDS, SIZES, FORMS)):
            factors[f"obstacle {slot} {field}"] = list(values) + optional
    return factors


def _is_empty(key: str) -> dict:
    return {"operator": "eq", "left": key, "value": EMPTY}


def _not_empty(key: str) -> dict:
    return {"operator": "ne", "left": key, "value": EMPTY}


def slot_constraints() -> list[dict]:
    """covertable constraints: a slot is empty in all fields or none; slot k needs slot k-1."""
    constraints = []
    for slot in range(2, MAX_OBSTACLES + 1):
        keys = [f"obstacle {slot} {field}" for field in SLOT_FIELDS]
        for a, b in combinations(keys, 2):
            constraints.append(
                {
                    "operator": "or",
                    "conditions": [
                        {"operator": "and", "conditions": [_is_empty(a), _is_empty(b)]},
                        {"operator": "and", "conditions": [_not_empty(a), _not_empty(b)]},
                    ],
                }
            )
        if slot > 2:
            constraints.append(
                {"operator": "or", "conditions": [_is_empty(f"obstacle {slot} kind"), _not_empty(f"obstacle {slot - 1} kind")]}
            )
    return constraints


def fewest_rows(strength: int) -> int:
    """A lower bound on the scenarios a strength gives: every combination of the `strength`
    largest value sets must appear in some row (the slot constraints only add rows)."""
    sizes = sorted((len(values) for values in paper_factors().values()), reverse=True)
    return math.prod(sizes[:strength])


def covering_rows(strength: int) -> list[dict[str, str]]:
    if strength < 1:
        raise ValueError("strength must be at least 1")
    rows = covertable.make(paper_factors(), strength=strength, constraints=slot_constraints())
    return sorted(rows, key=lambda r: tuple(r[k] for k in paper_factors()))


def row_to_scenario(row: Mapping[str, str], name: str) -> dict[str, Any]:
    obstacles = []
    for slot in range(1, MAX_OBSTACLES + 1):
        kind = row[f"obstacle {slot} kind"]
        if kind == EMPTY:
            break
        obstacles.append({"kind": kind, "size": row[f"obstacle {slot} size"], "form": row[f"obstacle {slot} form"]})
    return {
        "name": name,
        "system": {"UAVs": [{"maneuvers": ["take off", "move to waypoint", "land"]}]},
        "environment": {
            "flight area": {"landform": row["landform"], "surface nature": row["surface nature"]},
            "obstacles": obstacles,
            "weather": {"wind force": row["wind force"], "reduced visibility": row["reduced visibility"]},
        },
    }


def scenario_to_row(document: Mapping[str, Any]) -> dict[str, str]:
    environment = document["environment"]
    row = {
        "landform": environment["flight area"]["landform"],
        "surface nature": environment["flight area"]["surface nature"],
        "wind force": environment["weather"]["wind force"],
        "reduced visibility": environment["weather"]["reduced visibility"],
    }
    obstacles = environment["obstacles"]
    for slot in range(1, MAX_OBSTACLES + 1):
        for field in SLOT_FIELDS:
            row[f"obstacle {slot} {field}"] = obstacles[slot - 1][field] if slot <= len(obstacles) else EMPTY
    return row


def generate(strength: int) -> Iterable[tuple[str, dict[str, Any]]]:
    """(file stem, logical scenario) for every row of a t-wise covering array."""
    rows = covering_rows(strength)
    width = len(str(len(rows)))
    for index, row in enumerate(rows, start=1):
        stem = f"t{strength}_{index:0{width}d}"
        yield stem, row_to_scenario(row, f"{strength}-wise scenario {index} of {len(rows)}")
