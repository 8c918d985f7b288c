"""t-wise generation of logical scenarios: covering arrays over the scenario format's category values.

Two element sets (`stella generate --elements`):
* `paper`: the paper's value sets: landform, surface nature, wind force, reduced visibility, and
  up to four obstacle slots of kind (static, dynamic), size and form.
* `all` (the default): also gusts, intruders (an obstacle slot of kind intruder, with its
  encounter and path), each dynamic obstacle's motion, and one injected failure (unit and type).
Either may add two factors of the vehicle: its sensor rig (`--rigs`: presets or files, or the
profile's own sensors) and the shape of the pilot's stick programme (`--programmes`, PROGRAMME_SHAPES),
which flies the scenario in the pilot drive.

The values are the schema's enums. Each list element (obstacle, failure) is a group of slots,
each slot a few factors that hold one element or nothing: a factor that does not apply (an empty
slot, an intruder's size, a static obstacle's motion, no failure) holds "-", and slots fill from
the first. The constraints keep every row valid; the covering array covers every t-tuple that a
valid row can hold (`harness/scenario/covering.py`). One failure slot, not one per unit: a
covering array fills most slots, and a scenario failing several sensors at once would hide
which of them the violation is down to.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from harness.errors import InputError, Problem
from harness.scenario.covering import covering_array, tuple_count, valid_tuples
from harness.scenario.documents import schema
from harness.scenario.logical import DATA_LINK
from harness.scenario.rig import load_rig, preset_names

EMPTY = "-"
MAX_OBSTACLES = 4
ELEMENTS = ("all", "paper")
# The builder keeps five bytes per t-tuple (covered?, its factor combination): 200 MB at this many.
MAX_TUPLES = 40_000_000
_ENUMERATED_AT_MOST = 1_000_000
PROFILE_RIG = "profile"  # the --rigs value that keeps the profile's own range sensors

# The pilot's stick programmes by shape (docs/pilot_drive.md): what each probes of collision
# prevention; the ranges are the searched dimensions of a generated scenario's programme.
_PROBE = {"towards": "obstacle", "deflection": {"min": 0.5, "max": 1}, "duration_s": {"min": 1, "max": 8}}
PROGRAMME_SHAPES: dict[str, tuple[str, list[dict[str, Any]]]] = {
    "push": ("no programme: the pilot pushes along the route", []),
    "probe": ("push towards the nearest obstacle first", [_PROBE]),
    # PX4's stick dead zone (MAN_DEADZONE) and the bundled autopilot's (MPC_HOLD_DZ) are 0.1: just
    # inside it the vehicle holds, just past it collision prevention gets its smallest set-points.
    "tiny": ("a deflection at the edge of the sticks' dead zone (0.1), any direction",
             [{"towards": "obstacle", "angle_deg": {"min": -180, "max": 180}, "deflection": {"min": 0.09, "max": 0.13}, "duration_s": {"min": 1, "max": 10}}]),
    "slide": ("push at an angle to the nearest obstacle: along it once stopped",
              [{"towards": "obstacle", "angle_deg": {"min": 20, "max": 80}, "deflection": {"min": 0.5, "max": 1}, "duration_s": {"min": 2, "max": 10}}]),
    "release": ("push at the obstacle, release the stick, push again",
                [_PROBE, {"towards": "obstacle", "deflection": 0, "duration_s": {"min": 0.2, "max": 3}}, _PROBE]),
    "back_away": ("push at the obstacle, then back away from it",
                  [_PROBE, {"towards": "obstacle", "angle_deg": 180, "deflection": {"min": 0.1, "max": 1}, "duration_s": {"min": 0.5, "max": 3}}]),
    "yaw": ("push along the route while turning",
            [{"towards": "route", "deflection": {"min": 0.5, "max": 1}, "duration_s": {"min": 2, "max": 8}, "yaw_stick": {"min": -1, "max": 1}}]),
}


def vehicle_factors(rigs: Sequence[str] = (), programmes: Sequence[str] = ()) -> dict[str, list[str]]:
    """The vehicle's factors `--rigs` and `--programmes` add, their names checked: "presets" and
    "all" stand for every preset rig and every programme shape."""
    factors: dict[str, list[str]] = {}
    if rigs:
        names = [name for given in rigs for name in (preset_names() if given == "presets" else [given])]
        for name in names:
            if name != PROFILE_RIG:
                load_rig(name, named_at=("--rigs", ""))
        factors["rig"] = list(dict.fromkeys(names))
    if programmes:
        shapes = [shape for given in programmes for shape in (PROGRAMME_SHAPES if given == "all" else [given])]
        unknown = [shape for shape in shapes if shape not in PROGRAMME_SHAPES]
        if unknown:
            raise InputError([Problem("--programmes", "", f"{', '.join(unknown)}: no programme shape: choose among {', '.join(PROGRAMME_SHAPES)}, or all")])
        factors["programme"] = list(dict.fromkeys(shapes))
    return factors


def _enums() -> dict[str, list[str]]:
    document = schema("logical_scenario")
    environment = document["properties"]["environment"]["properties"]
    obstacle = document["$defs"]["obstacle"]["properties"]
    failure = document["properties"]["failures"]["items"]["properties"]
    enums = {name: spec["enum"] for name, spec in environment["flight area"]["properties"].items() if "enum" in spec}
    enums.update({name: environment["weather"]["properties"][name]["enum"] for name in ("wind force", "reduced visibility", "gusts")})
    enums.update({f"obstacle {name}": obstacle[name]["enum"] for name in ("kind", "size", "form", "motion", "encounter", "path")})
    enums.update({f"failure {name}": failure[name]["enum"] for name in ("unit", "type")})
    # The data link fails one way only (off), which a failure slot's factors cannot say: the
    # generated scenarios fail sensors, and a data-link loss is written by hand.
    enums["failure unit"] = [unit for unit in enums["failure unit"] if unit != DATA_LINK]
    return enums


@dataclass(frozen=True)
class Slots:
    """`count` slots of one list element; a slot holds one element of one of `kinds`, or nothing.
    `fields` name, for each factor of a slot, the kinds it belongs to; "kind", if present, says
    which kind the slot holds. The first `required` slots are never empty."""

    label: str
    count: int
    required: int
    kinds: tuple[str, ...]
    fields: tuple[tuple[str, tuple[str, ...]], ...]

    def factor(self, slot: int, field: str) -> str:
        return f"{self.label} {slot} {field}" if self.count > 1 else f"{self.label} {field}"

    def values(self, enums: Mapping[str, list[str]], slot: int, field: str) -> list[str]:
        if field == "kind":
            real = list(self.kinds)
            empty_possible = slot > self.required
        else:
            real = enums[f"{self.label} {field}"]
            empty_possible = slot > self.required or set(self.kinds) - set(dict(self.fields)[field])
        return real + ([EMPTY] if empty_possible else [])

    def states(self, field: str, value: str) -> int:
        """The slot's states (bit 0: empty, bit i: kinds[i - 1]) a field's value allows."""
        bit = {kind: 1 << (index + 1) for index, kind in enumerate(self.kinds)}
        if field == "kind":
            return 1 if value == EMPTY else bit[value]
        belongs = dict(self.fields)[field]
        if value == EMPTY:
            return 1 | sum(bit[kind] for kind in self.kinds if kind not in belongs)
        return sum(bit[kind] for kind in belongs)


_SIZED = ("static", "dynamic")
PAPER_OBSTACLES = Slots("obstacle", MAX_OBSTACLES, 1, ("static", "dynamic"), (("kind", ()), ("size", _SIZED), ("form", _SIZED)))
ALL_OBSTACLES = Slots("obstacle", MAX_OBSTACLES, 1, ("static", "dynamic", "intruder"),
                      (("kind", ()), ("size", _SIZED), ("form", _SIZED), ("motion", ("dynamic",)), ("encounter", ("intruder",)), ("path", ("intruder",))))
FAILURE = Slots("failure", 1, 0, ("failing",), (("unit", ("failing",)), ("type", ("failing",))))


class FactorModel:
    """The factors of one element set, and which partial rows extend to a valid one."""

    def __init__(self, elements: str, rigs: Sequence[str] = (), programmes: Sequence[str] = ()):
        if elements not in ELEMENTS:
            raise ValueError(f"unknown elements {elements!r}: choose {' or '.join(ELEMENTS)}")
        enums = {**_enums(), **vehicle_factors(rigs, programmes)}
        free = ["landform", "surface nature", "wind force", "reduced visibility"] + (["gusts"] if elements == "all" else [])
        free += [name for name in ("rig", "programme") if name in enums]
        self.slot_groups = (PAPER_OBSTACLES,) if elements == "paper" else (ALL_OBSTACLES, FAILURE)
        self.free = free  # the factors no constraint touches
        self.factors: dict[str, list[str]] = {name: list(enums[name]) for name in free}
        self._slots: list[tuple[Slots, list[int]]] = []  # per slot: its group and its factors' columns
        states: dict[int, list[int]] = {}  # per slot factor: the slot's states each value allows
        for group in self.slot_groups:
            for slot in range(1, group.count + 1):
                columns = []
                for field, _kinds in group.fields:
                    values = group.values(enums, slot, field)
                    columns.append(len(self.factors))
                    states[len(self.factors)] = [group.states(field, value) for value in values]
                    self.factors[group.factor(slot, field)] = values
                self._slots.append((group, columns))
        self.names = list(self.factors)
        self.sizes = [len(values) for values in self.factors.values()]
        # The factors whose values constrain each other: a free factor alone, a group's slots together.
        self.coupled = [[self.names.index(name)] for name in free]
        for group in self.slot_groups:
            self.coupled.append([c for g, columns in self._slots if g is group for c in columns])
        # One table for all factors, -1 (every state) where a factor constrains nothing: a free
        # factor, and the last column, which an open factor (UNSET, -1) picks.
        self._states = np.full((len(self.names), max(self.sizes) + 1), -1, dtype=np.int64)
        for column, allowed in states.items():
            self._states[column, : len(allowed)] = allowed
        self._slot_starts = [columns[0] for _g, columns in self._slots]
        self._group_slots = [[index for index, (g, _c) in enumerate(self._slots) if g is group] for group in self.slot_groups]

    def extendable(self, partial: np.ndarray) -> np.ndarray:
        """Whether each partial row (UNSET where open) extends to a valid row: every slot can hold
        something its fields allow, and some number of filled slots, at least the required ones,
        can be filled while the rest stay empty."""
        allowed = self._states[np.arange(len(self.names)), partial]
        # A slot's factors are adjacent columns: AND them per slot.
        slots = np.bitwise_and.reduceat(allowed[:, self._slot_starts[0]:], np.subtract(self._slot_starts, self._slot_starts[0]), axis=1)
        possible = (slots != 0).all(axis=1)
        for group, members in zip(self.slot_groups, self._group_slots):
            # Slots fill from the first: the first m can hold something and the rest nothing, for some m >= required.
            leading_fillable = np.logical_and.accumulate((slots[:, members] & ~1) != 0, axis=1).sum(axis=1)
            trailing_emptiable = np.logical_and.accumulate((slots[:, members[::-1]] & 1) != 0, axis=1).sum(axis=1)
            possible &= np.maximum(group.required, len(members) - trailing_emptiable) <= leading_fillable
        return possible

    def fewest_rows(self, strength: int) -> int:
        """A lower bound on the rows of any covering array of this strength: the valid tuples of
        `strength` factors, one from as many coupled groups (free factors, slots) as can be, the
        largest first; each needs a row of its own."""
        by_slot = [[self.names.index(name)] for name in self.free]
        by_slot += [sorted(columns, key=lambda c: -self.sizes[c]) for _g, columns in self._slots]
        chosen: list[int] = []
        for depth in range(max(len(columns) for columns in by_slot)):
            layer = sorted((columns[depth] for columns in by_slot if depth < len(columns)), key=lambda c: -self.sizes[c])
            chosen += layer[: strength - len(chosen)]
        bound = 1
        for group in self.coupled:
            members = [c for c in chosen if c in group]
            # Fewer factors of a group give fewer tuples (each extends), so dropping keeps a bound.
            while members and math.prod(self.sizes[c] for c in members) > _ENUMERATED_AT_MOST:
                members.remove(min(members, key=lambda c: self.sizes[c]))
            if members:
                bound *= valid_tuples(self.sizes, members, self.extendable)
        return bound

    def tuples(self, strength: int) -> int:
        return tuple_count(self.sizes, strength)

    def row_values(self, indices: np.ndarray) -> dict[str, str]:
        return {name: self.factors[name][int(index)] for name, index in zip(self.names, indices)}


def covering_rows(strength: int, elements: str = "all", rigs: Sequence[str] = (), programmes: Sequence[str] = ()) -> list[dict[str, str]]:
    model = FactorModel(elements, rigs, programmes)
    if strength < 1:
        raise ValueError("strength must be at least 1")
    array = covering_array(model.sizes, strength, model.extendable)
    array = array[np.lexsort(array.T[::-1])]
    return [model.row_values(indices) for indices in array]


def _element(row: Mapping[str, str], group: Slots, slot: int) -> dict[str, str] | None:
    fields = {field: row[group.factor(slot, field)] for field, _kinds in group.fields}
    if all(value == EMPTY for value in fields.values()):
        return None
    return {field: value for field, value in fields.items() if value != EMPTY}


def row_to_scenario(row: Mapping[str, str], name: str) -> dict[str, Any]:
    obstacles_group = ALL_OBSTACLES if "obstacle 1 motion" in row else PAPER_OBSTACLES
    obstacles = [o for o in (_element(row, obstacles_group, slot) for slot in range(1, MAX_OBSTACLES + 1)) if o is not None]
    weather = {"wind force": row["wind force"], "reduced visibility": row["reduced visibility"]}
    if "gusts" in row:
        weather["gusts"] = row["gusts"]
    document: dict[str, Any] = {
        "name": name,
        "system": {"UAVs": [{"maneuvers": ["take off", "move to waypoint", "land"]}]},
        "environment": {
            "flight area": {"landform": row["landform"], "surface nature": row["surface nature"]},
            "obstacles": obstacles,
            "weather": weather,
        },
    }
    if "failure unit" in row:
        failure = _element(row, FAILURE, 1)
        if failure is not None:
            document["failures"] = [failure]
    if row.get("rig", PROFILE_RIG) != PROFILE_RIG:
        # A preset by name; a file read in, as the generated scenario lies elsewhere.
        document["rig"] = row["rig"] if row["rig"] in preset_names() else load_rig(row["rig"])
    if "programme" in row:
        programme = PROGRAMME_SHAPES[row["programme"]][1]
        document["mission"] = {"drive": "pilot", **({"programme": programme} if programme else {})}
    return document


# What the loader assumes when a scenario leaves these out (harness/scenario/logical.py).
_DEFAULTS = {("dynamic", "motion"): "straight", ("intruder", "path"): "straight"}


def scenario_to_row(document: Mapping[str, Any], elements: str = "all", rigs: Sequence[str] = (), programmes: Sequence[str] = ()) -> dict[str, str]:
    """The row of a logical scenario in the factors of `elements` and the vehicle's (its inverse of row_to_scenario)."""
    model = FactorModel(elements, rigs, programmes)
    environment = document["environment"]
    row = {"landform": environment["flight area"]["landform"], "surface nature": environment["flight area"]["surface nature"]}
    row.update({name: environment["weather"].get(name, "none") for name in ("wind force", "reduced visibility", "gusts") if name in model.factors})
    lists = {"obstacle": environment["obstacles"], "failure": document.get("failures", [])}
    for group in model.slot_groups:
        for slot in range(1, group.count + 1):
            element = lists[group.label][slot - 1] if slot <= len(lists[group.label]) else {}
            for field, _kinds in group.fields:
                row[group.factor(slot, field)] = element.get(field, _DEFAULTS.get((element.get("kind"), field), EMPTY))
    if "rig" in model.factors:
        rig = document.get("rig")
        row["rig"] = rig if isinstance(rig, str) else next((name for name in model.factors["rig"] if name != PROFILE_RIG and load_rig(name) == rig), PROFILE_RIG)
    if "programme" in model.factors:
        programme = document.get("mission", {}).get("programme", [])
        row["programme"] = next(shape for shape, (_about, segments) in PROGRAMME_SHAPES.items() if segments == programme)
    return row


def generate(strength: int, elements: str = "all", rigs: Sequence[str] = (), programmes: Sequence[str] = ()) -> Iterable[tuple[str, dict[str, Any]]]:
    """(file stem, logical scenario) for every row of a t-wise covering array."""
    rows = covering_rows(strength, elements, rigs, programmes)
    width = len(str(len(rows)))
    for index, row in enumerate(rows, start=1):
        stem = f"t{strength}_{index:0{width}d}"
        yield stem, row_to_scenario(row, f"{strength}-wise scenario {index} of {len(rows)}")

