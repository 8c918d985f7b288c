"""The units a profile may declare, and their conversion into the units the simulation works
in: the one place where a number changes unit. The schema lists the same closed set."""

from __future__ import annotations

# unit -> (the simulation's unit of that quantity, factor)
TO_SIMULATION = {
    "m/s": ("m/s", 1.0),
    "km/h": ("m/s", 1.0 / 3.6),
    "kn": ("m/s", 1852.0 / 3600.0),
    "m": ("m", 1.0),
    "km": ("m", 1000.0),
    "degC": ("degC", 1.0),
    "lx": ("lx", 1.0),
    "cm/h": ("cm/h", 1.0),
    "mm/h": ("cm/h", 0.1),
    "strikes/min": ("strikes/min", 1.0),
    "%": ("%", 1.0),
}
UNITS = tuple(TO_SIMULATION)


def factor(unit: str, simulation_unit: str) -> float:
    """What a value in `unit` is multiplied by to be in `simulation_unit`; ValueError if the two
    do not measure the same quantity."""
    target, scale = TO_SIMULATION[unit]
    if target != simulation_unit:
        convertible = ", ".join(u for u, (t, _f) in TO_SIMULATION.items() if t == simulation_unit)
        raise ValueError(f'"{unit}" is not a unit of this quantity; use one of {convertible}')
    return scale
