"""Robustness of properties over a flight's signals, with rtamt's offline discrete-time monitor:
how far the flight is from violating each (above 0: kept by that much; below: violated)."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, Sequence

import rtamt

from harness.errors import InputError, Problem
from harness.properties.signals import Series
from harness.properties.spec import Property

# rtamt's time unit for the bounds of temporal operators: a formula's [0:5] is 5 seconds.
TIME_UNIT = "s"
# How far a sample may lie off the regular period before rtamt warns (the recording's samples are regular).
PERIOD_TOLERANCE = 0.1


def parse(prop: Property, where: str, period_s: float | None = None, at: str = "") -> Any:
    """rtamt's specification of the property; InputError with the formula's line and column where
    rtamt cannot parse it."""
    spec = rtamt.StlDiscreteTimeSpecification()
    spec.name = prop.name
    for signal in prop.signals:
        spec.declare_var(signal, "float")
    if period_s:
        spec.set_sampling_period(period_s, TIME_UNIT, PERIOD_TOLERANCE)
    spec.spec = prop.stated
    try:
        spec.parse()
    except rtamt.RTAMTException as error:
        message = str(error).replace("RTAMT Exception: ", "").strip()
        raise InputError([Problem(where, f"{at}/formula", f"{message} (in {prop.stated!r})")]) from None
    return spec


def _evaluated(prop: Property, series: Series) -> list[tuple[float, float]]:
    """The property's robustness from each sample on: (time, robustness)."""
    spec = parse(prop, prop.name, round(series.period_s, 6) or None)
    trace = {"time": [float(t) for t in series.time_s], **{s: [float(v) for v in series.values[s]] for s in prop.signals}}
    return [(float(t), float(r)) for t, r in spec.evaluate(trace)]


def robustness(prop: Property, series: Series) -> float:
    """The property's robustness over the whole flight (its value at the first sample)."""
    if len(series.time_s) == 0:
        return math.nan
    return _evaluated(prop, series)[0][1]


def decided(prop: Property, series: Series) -> dict[str, Any] | None:
    """When the flight's verdict on the property was decided, and its signals then. For
    `always(X)`: the first moment X is at its worst (it came closest to breaking, or broke most).
    Otherwise: the last sample from which the rest of the flight still has the whole flight's
    robustness. None: no samples."""
    if len(series.time_s) == 0:
        return None
    inner = _always_of(prop.formula)
    if inner is not None:
        evaluated = _evaluated(replace(prop, formula=inner), series)
        worst = min(r for _t, r in evaluated)
        index = min(i for i, (_t, r) in enumerate(evaluated) if r == worst)
    else:
        evaluated = _evaluated(prop, series)
        index = max(i for i, (_t, r) in enumerate(evaluated) if r == evaluated[0][1])
    return {"time_s": evaluated[index][0], "signals": {s: float(series.values[s][index]) for s in prop.signals}}


def _always_of(formula: str) -> str | None:
    """X of a formula that is `always(X)` as a whole, else None."""
    text = formula.strip()
    if not (text.startswith("always(") and text.endswith(")")):
        return None
    depth = 0
    for position, character in enumerate(text[len("always"):], start=len("always")):
        depth += {"(": 1, ")": -1}.get(character, 0)
        if depth == 0:
            return text[len("always("):-1] if position == len(text) - 1 else None
    return None


def verdicts(properties: Sequence[Property], series: Series) -> dict[str, dict[str, Any]]:
    """{name: {"verdict": "kept"|"violated", "robustness": r, "unit": u}} for each property."""
    out = {}
    for prop in properties:
        value = robustness(prop, series)
        out[prop.name] = {"verdict": "kept" if value >= 0 else "violated" if value < 0 else "unknown",
                          "robustness": None if math.isnan(value) else (value if math.isfinite(value) else None), "unit": prop.unit}
    return out
