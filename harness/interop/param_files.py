"""SUT parameter files: QGroundControl's `.params` export, the UAV Testing Competition's
`NAME,VALUE` CSV and ArduPilot's `.parm`/`.param` files, read into the same name -> number
mapping as `--sut-param`.

QGroundControl writes one parameter per line, tab-separated, after `#` comment lines:
`vehicle-id  component-id  NAME  VALUE  MAV_PARAM_TYPE` (type 9 is a float, 1-8 integers).
ArduPilot reads `NAME VALUE` with any of space, tab, `,` or `=` between them (its
AP_Param::parse_param_line), `#` comment lines, and ignores what follows the value: a `# comment`
in its own default files, the `@READONLY` flag (which stella does not carry: logged). MAVProxy's
`param save` and Mission Planner's `.param` (`NAME,VALUE`) are of that kind.
"""

from __future__ import annotations

import logging
import math
import re
from pathlib import Path

from harness.errors import InputError, Problem
from harness.scenario.documents import read_text

FLOAT_TYPES = (9, 10)  # MAV_PARAM_TYPE_REAL32, REAL64
INTEGER_TYPES = range(1, 9)
NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,15}$")  # PX4's and ArduPilot's names: at most 16 characters
# ArduPilot's separators between name and value (AP_Param::parse_param_line's strtok set).
SEPARATORS = re.compile(r"[\s,=]+")
READONLY = "@READONLY"

log = logging.getLogger(__name__)


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
        # NAME,VALUE (the competition's, Mission Planner's) or NAME VALUE (ArduPilot's), a comment after it
        fields = SEPARATORS.split(text.split("#", 1)[0].strip())
        try:
            if len(tabbed) == 5:
                name, value = _qgc_line(tabbed)
            elif len(fields) == 2 or (len(fields) == 3 and fields[2] == READONLY):
                if number == 1 and fields[0].lower() in ("name", "param", "parameter"):
                    continue  # a header row
                name, value = fields[0], _number(fields[1], None)
                if fields[2:]:
                    log.warning("%s: line %d: %s is set to %s; stella does not make it read-only (%s ignored)", path, number, name, fields[1], READONLY)
            else:
                raise ValueError("layout")
        except ValueError as error:
            what = ("expected NAME,VALUE, ArduPilot's NAME VALUE or QGroundControl's tab-separated `vehicle component NAME VALUE TYPE`"
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
