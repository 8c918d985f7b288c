"""The candidate steps of `stella shrink`: each a smaller or simpler concrete scenario made from the
current one, in the order that removes the most first.

A step edits the concrete scenario document and, where it removes an element or changes a
category, the logical scenario it embeds, so the candidate is a concrete scenario like any other;
it is then reloaded through the same checks a `--concrete` file passes (bounds, realism
constraints). A step that yields no valid scenario is left out, never flown.
"""

from __future__ import annotations

import copy
import json
import math
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Mapping

from harness.errors import InputError
from harness.scenario import units
from harness.scenario.space import Dimension, SearchSpace
from harness.scenario.world import space_from_concrete

Document = dict[str, Any]

# Where each searched quantity is simplest, by the last part of its dimension's name: the bound
# that means least (no wind, clear air, smallest, slowest, shortest), a number (north for a
# direction, level, straight), or absent where the value places the event itself (positions,
# onsets, an intruder's meeting time and angle): those are only rounded.
LOWER, UPPER = "lower", "upper"
NEUTRAL: Mapping[str, str | float] = {
    "wind_speed_m_s": LOWER, "wind_from_deg": 0.0, "visibility_m": UPPER,
    "temperature_c": 15.0,  # the ISA standard atmosphere at sea level
    "turbulence_m_s": LOWER, "amplitude_m_s": LOWER, "from_deg": 0.0, "duration_s": LOWER,
    "length_m": LOWER, "width_m": LOWER, "height_m": LOWER, "diameter_m": LOWER, "yaw_deg": 0.0,
    "altitude_m": LOWER, "speed_m_s": LOWER, "travel_m": LOWER, "radius_m": LOWER, "turn_deg": 0.0, "rise_m": LOWER,
    "closing_speed_m_s": LOWER, "vertical_offset_m": 0.0, "turn_rate_deg_s": 0.0,
    "max_stick": UPPER, "aim_offset_m": 0.0,  # the pilot drive's defaults: full stick, aiming along the route
    "angle_deg": 0.0, "deflection": LOWER, "yaw_stick": 0.0,  # a programme segment: straight at its reference, no stick
    "max_range_m": UPPER, "fov_deg": UPPER, "rate_hz": UPPER, "latency_s": LOWER,  # a rig sensor at its best
}
# Round numbers tried in turn: whole units, then tenths (hundredths for unitless fractions).
GRAINS = {"": (0.1, 0.01)}
DEFAULT_GRAINS = (1.0, 0.1)
# Removals change which elements interact, so a pass that kept one is followed by another.
REMOVALS = frozenset({"obstacles", "failure", "programme", "gusts", "wind", "fog"})


@dataclass(frozen=True)
class Candidate:
    kind: str  # obstacles, failure, programme, gusts, wind, fog, neutral, round
    description: str
    document: Document


def space_of(document: Mapping[str, Any]) -> SearchSpace:
    """The candidate's search space; a shrink has a few logical scenarios (one per removal) and
    many candidates of each, and checking a profile against its schema takes most of a tenth of
    a second."""
    key = json.dumps([document.get(k) for k in ("logical_scenario", "profile_document", "drive")], sort_keys=True)
    if key not in _spaces:
        _spaces[key] = space_from_concrete(document, "<shrink candidate>")
    return _spaces[key]


_spaces: dict[str, SearchSpace] = {}


def checked(document: Document) -> Document | None:
    """The candidate as a concrete scenario document, or None where it is not a valid one or breaks
    a realism constraint."""
    try:
        space = space_of(document)
        x = space.from_concrete(document, "<shrink candidate>")
    except InputError:
        return None
    if space.violations(x):
        return None
    return space.to_concrete(x)


def _variant(current: Document, edit: Callable[[Document], None]) -> Document | None:
    changed = copy.deepcopy(current)
    edit(changed)
    candidate = checked(changed)
    return None if candidate == current else candidate


def _obstacle_label(document: Mapping[str, Any], index: int) -> str:
    entry = document["obstacles"][index]
    return f"obstacle_{index + 1} ({entry['kind']} {entry['form']})"


def _drop_obstacles(keep: Callable[[int], bool]) -> Callable[[Document], None]:
    def edit(document: Document) -> None:
        logical = document["logical_scenario"]["environment"]
        logical["obstacles"] = [o for i, o in enumerate(logical["obstacles"]) if keep(i)]
        document["obstacles"] = [o for i, o in enumerate(document["obstacles"]) if keep(i)]
    return edit


def obstacle_steps(state) -> Iterator[Candidate]:
    """All but the obstacle the violation was against at once, then each obstacle one at a time
    (last first, so the indices still to try stay put)."""
    count = len(state.current["obstacles"])
    closest = state.closest_obstacle_index
    if count > 2 and closest is not None:
        candidate = _variant(state.current, _drop_obstacles(lambda i: i == closest))
        if candidate is not None:
            yield Candidate("obstacles", f"keep only {_obstacle_label(state.current, closest)}, drop the other {count - 1}", candidate)
    for index in reversed(range(len(state.current["obstacles"]))):
        if len(state.current["obstacles"]) < 2 or index >= len(state.current["obstacles"]):
            continue  # a violation needs an obstacle to violate against
        label = _obstacle_label(state.current, index)
        candidate = _variant(state.current, _drop_obstacles(lambda i, index=index: i != index))
        if candidate is not None:
            yield Candidate("obstacles", f"drop {label}", candidate)


def _drop_entry(holders, key: str, index: int) -> None:
    """The list entry at index dropped from each holder (the logical scenario's and the concrete
    values'), the list itself where it is left empty."""
    for holder in holders:
        del holder[key][index]
        if not holder[key]:
            del holder[key]


def failure_steps(state) -> Iterator[Candidate]:
    for index in reversed(range(len(state.current.get("failures", ())))):
        if index >= len(state.current.get("failures", ())):
            continue
        failure = state.current["failures"][index]

        def edit(document: Document, index: int = index) -> None:
            _drop_entry((document["logical_scenario"], document), "failures", index)

        candidate = _variant(state.current, edit)
        if candidate is not None:
            yield Candidate("failure", f"drop the {failure['unit']} {failure['type']} failure", candidate)


def programme_steps(state) -> Iterator[Candidate]:
    """Each segment of the pilot's programme dropped, the last first."""
    segments = state.current.get("pilot", {}).get("programme", ())
    for index in reversed(range(len(segments))):

        def edit(document: Document, index: int = index) -> None:
            _drop_entry((document["logical_scenario"]["mission"], document["pilot"]), "programme", index)

        candidate = _variant(state.current, edit)
        if candidate is not None:
            yield Candidate("programme", f"drop the pilot's segment {index + 1} (towards the {segments[index]['towards']})", candidate)


def gust_steps(state) -> Iterator[Candidate]:
    weather = state.current["logical_scenario"]["environment"]["weather"]
    if weather.get("gusts", "none") == "none":
        return

    def edit(document: Document) -> None:
        document["logical_scenario"]["environment"]["weather"].pop("gusts")
        for key in ("turbulence_m_s", "gust"):
            document["environment"].pop(key, None)

    candidate = _variant(state.current, edit)
    if candidate is not None:
        yield Candidate("gusts", f"drop the {weather['gusts']} gusts and turbulence", candidate)


def _category_edit(parameter: str, category: str, values: Mapping[str, float]) -> Callable[[Document], None]:
    def edit(document: Document) -> None:
        environment = document["logical_scenario"]["environment"]
        environment["weather"][parameter] = category
        ranges = environment.get("ranges", {})
        ranges.pop(parameter, None)
        if "ranges" in environment and not ranges:
            del environment["ranges"]
        document["environment"].update(values)
    return edit


def weather_steps(state) -> Iterator[Candidate]:
    """The calmest wind category (its lowest speed) and the clearest visibility category."""
    profile = space_of(state.current).profile
    wind = profile.parameters["wind force"].categories
    calm = min(wind, key=lambda name: (wind[name].max, wind[name].min))
    candidate = _variant(state.current, _category_edit("wind force", calm, {"wind_speed_m_s": wind[calm].min * _wind_scale(profile),
                                                                              "wind_from_deg": 0.0}))
    if candidate is not None:
        yield Candidate("wind", f"calm the wind: {state.current['environment']['wind_speed_m_s']:.3g} m/s -> "
                                f"{candidate['environment']['wind_speed_m_s']:.3g} m/s ({calm})", candidate)
    fog = profile.parameters["reduced visibility"].categories
    clear = max(fog, key=lambda name: (fog[name].min, fog[name].max))
    candidate = _variant(state.current, _category_edit("reduced visibility", clear, {"visibility_m": fog[clear].max}))
    if candidate is not None:
        yield Candidate("fog", f"clear the air: visibility {state.current['environment']['visibility_m']:g} m -> "
                               f"{candidate['environment']['visibility_m']:g} m ({clear})", candidate)


def _wind_scale(profile) -> float:
    return units.factor(profile.parameters["wind force"].unit, "m/s")


def neutral_value(dimension: Dimension) -> float | None:
    rule = NEUTRAL.get(dimension.name.rsplit(".", 1)[-1])
    if rule is None:
        return None
    if rule == LOWER:
        return dimension.lower
    if rule == UPPER:
        return dimension.upper
    return min(max(float(rule), dimension.lower), dimension.upper)


def _value(document: Mapping[str, Any], dimension: Dimension) -> float:
    target: Any = document
    for key in dimension.path:
        target = target[key]
    return float(target)


def _set_values(values: Mapping[tuple[Any, ...], float]) -> Callable[[Document], None]:
    def edit(document: Document) -> None:
        for path, value in values.items():
            target = document
            for key in path[:-1]:
                target = target[key]
            target[path[-1]] = value
    return edit


def _change(dimension: Dimension, before: float, after: float, why: str) -> str:
    unit = f" {dimension.unit}" if dimension.unit else ""
    return f"{dimension.name} {before:.6g}{unit} -> {after:.6g}{unit} ({why})"


def neutral_steps(state) -> Iterator[Candidate]:
    """Every searched value to its neutral value at once; then each on its own, or halfway there."""
    dimensions = space_of(state.current).dimensions
    # Only the moves that are valid on their own: one that breaks a realism constraint (an
    # intruder slower than the profile allows) would sink the whole group.
    moves = {d.path: neutral_value(d) for d in dimensions if neutral_value(d) is not None and neutral_value(d) != _value(state.current, d)
             and _variant(state.current, _set_values({d.path: neutral_value(d)})) is not None}
    if len(moves) > 1:
        candidate = _variant(state.current, _set_values(moves))
        if candidate is not None:
            yield Candidate("neutral", f"to their neutral values: {_moves_text(state.current, dimensions, moves)}", candidate)
    for dimension in dimensions:
        target = neutral_value(dimension)
        if target is None:
            continue
        before = _value(state.current, dimension)
        for after, why in ((target, "neutral"), ((before + target) / 2.0, "halfway to neutral")):
            if after == before:
                break
            candidate = _variant(state.current, _set_values({dimension.path: after}))
            if candidate is None:
                continue
            yield Candidate("neutral", _change(dimension, before, after, why), candidate)
            if _value(state.current, dimension) == after:
                break


def _rounded(dimension: Dimension, value: float, grain: float) -> float | None:
    if value == neutral_value(dimension):
        return None  # already as simple as it gets; rounding would lead away from it, and back
    rounded = round(round(value / grain) * grain, 10)
    if not dimension.lower <= rounded <= dimension.upper:
        rounded = round((math.floor if rounded > dimension.upper else math.ceil)(value / grain) * grain, 10)
    return rounded if dimension.lower <= rounded <= dimension.upper and rounded != value else None


def round_steps(state) -> Iterator[Candidate]:
    """Every value to a round number at once, then each, whole units before tenths."""
    for level in (0, 1):
        dimensions = space_of(state.current).dimensions
        grain = {d.path: GRAINS.get(d.unit, DEFAULT_GRAINS)[level] for d in dimensions}
        moves = {d.path: r for d in dimensions if (r := _rounded(d, _value(state.current, d), grain[d.path])) is not None
                 and _variant(state.current, _set_values({d.path: r})) is not None}
        if len(moves) > 1:
            candidate = _variant(state.current, _set_values(moves))
            if candidate is not None:
                yield Candidate("round", f"rounded to {_grain_text(level)}: {_moves_text(state.current, dimensions, moves)}", candidate)
        for dimension in dimensions:
            before = _value(state.current, dimension)
            after = _rounded(dimension, before, grain[dimension.path])
            if after is None:
                continue
            candidate = _variant(state.current, _set_values({dimension.path: after}))
            if candidate is not None:
                yield Candidate("round", _change(dimension, before, after, "rounded"), candidate)


def _moves_text(document: Document, dimensions: tuple[Dimension, ...], moves: Mapping[tuple[Any, ...], float]) -> str:
    return ", ".join(f"{d.name} {_value(document, d):.6g} -> {moves[d.path]:.6g}" for d in dimensions if d.path in moves)


def _grain_text(level: int) -> str:
    return ("whole units", "tenths")[level]


STEPS = (obstacle_steps, failure_steps, programme_steps, gust_steps, weather_steps, neutral_steps, round_steps)


def elements(document: Mapping[str, Any]) -> dict[str, Any]:
    """What a concrete scenario holds, counted: for the before/after of a shrink."""
    obstacles: dict[str, int] = {}
    for entry in document["obstacles"]:
        obstacles[entry["kind"]] = obstacles.get(entry["kind"], 0) + 1
    environment = document["environment"]
    return {"obstacles": len(document["obstacles"]), "by_kind": obstacles, "failures": len(document.get("failures", ())),
            "gusts": "gust" in environment, "wind_speed_m_s": environment["wind_speed_m_s"], "visibility_m": environment["visibility_m"],
            "searched_values": len(space_of(document).dimensions)}
