"""Robustness of properties over a flight's signals, with rtamt's offline discrete-time monitor:
how far the flight is from violating each (above 0: kept by that much; below: violated)."""

from __future__ import annotations

import math
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


def robustness(prop: Property, series: Series) -> float:
    """The property's robustness over the whole flight (its value at the first sample)."""
    if len(series.time_s) == 0:
        return math.nan
    spec = parse(prop, prop.name, round(series.period_s, 6) or None)
    trace = {"time": [float(t) for t in series.time_s], **{s: [float(v) for v in series.values[s]] for s in prop.signals}}
    return float(spec.evaluate(trace)[0][1])


def verdicts(properties: Sequence[Property], series: Series) -> dict[str, dict[str, Any]]:
    """{name: {"verdict": "kept"|"violated", "robustness": r, "unit": u}} for each property."""
    out = {}
    for prop in properties:
        value = robustness(prop, series)
        out[prop.name] = {"verdict": "kept" if value >= 0 else "violated" if value < 0 else "unknown",
                          "robustness": None if math.isnan(value) else (value if math.isfinite(value) else None), "unit": prop.unit}
    return out
