"""SUT parameter files: QGroundControl's `.params` export and the UAV Testing Competition's
`NAME,VALUE` CSV, read into the same name -> number mapping as `--sut-param`.

QGroundControl writes one parameter per line, tab-separated, after `#` comment lines:
`vehicle-id  component-id  NAME  VALUE  MAV_PARAM_TYPE` (type 9 is a float, 1-8 integers).
"""

from __future__ import annotations

import math
import re
from pathlib import Path

from harness.errors import InputError, Problem
from harness.scenario.documents import read_text

FLOAT_TYPES = (9, 10)  # MAV_PARAM_TYPE_REAL32, REAL64
INTEGER_TYPES = range(1, 9)
NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,15}$")  # PX4's names: at most 16 characters


def _number(text: str, as_int: bool | None) -> int | float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(text)
    if as_int or (as_int is None and re.fullmatch(r"[-+]?\d+", text.strip())):
        if not value.is_integer():
            raise ValueError(text)
        return int(value)
    return value


def _qgc_line(fields: list[str]) -> tuple[str, int | float]:
    _vehicle, _component, name, value, kind = fields
    if int(kind) not in (*FLOAT_TYPES, *INTEGER_TYPES):
        raise ValueError(f"unknown MAV_PARAM_TYPE {kind}")
    return name, _number(value, int(kind) in INTEGER_TYPES)


def load_params_file(path: Path) -> dict[str, int | float]:
    """The parameters of a .params or NAME,VALUE file, in file order; each bad line located."""
    lines = read_text(path).splitlines()
    values: dict[str, int | float] = {}
    problems = []
    for number, line in enumerate(lines, 1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        tabbed = [field.strip() for field in line.split("\t")]
        csv = [field.strip() for field in text.split(",")]
        try:
            if len(tabbed) == 5:
                name, value = _qgc_line(tabbed)
            elif len(csv) == 2:
                if number == 1 and csv[0].lower() in ("name", "param", "parameter"):
                    continue  # a header row
                name, value = csv[0], _number(csv[1], None)
            else:
                raise ValueError("layout")
        except ValueError as error:
            what = ("expected NAME,VALUE or QGroundControl's tab-separated `vehicle component NAME VALUE TYPE`"
                    if str(error) == "layout" else f"not a finite number of the right type ({error})")
            problems.append(Problem(str(path), f"line {number}", what))
            continue
        if not NAME.match(name):
            problems.append(Problem(str(path), f"line {number}", f"{name!r} is not a parameter name (letters, digits, _; at most 16)"))
            continue
        if name in values:
            problems.append(Problem(str(path), f"line {number}", f"{name} is set twice: keep one"))
            continue
        values[name] = value
    if problems:
        raise InputError(problems)
    if not values:
        raise InputError([Problem(str(path), "", "no parameters in this file")])
    return values
