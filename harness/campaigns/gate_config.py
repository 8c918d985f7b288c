"""The gate's configuration file (`stella.toml` at the root of the firmware tree, or `--config`):
the `[gate]` table names the suite, the scenarios, the drive, the SUT's parameters, the budget and
the thresholds, so that a CI job's command line stays short. Paths in it are relative to the
file's folder. Every key is checked, and a wrong one named with its file and key and the fix.

    [gate]
    sut = "px4"
    suite = ["test/stella/cases"]            # regression cases and concrete scenarios, or folders of them
    scenarios = ["test/stella/wall.json"]    # logical scenarios searched
    drive = "pilot"
    budget_flights = 60                      # search candidates, split across the scenarios
    budget_minutes = 20                      # the whole gate, builds included
    confirm = 2                              # flights more of each side for a pair that differs
    verify_flights = 7                       # flights a side a regression must hold over before it fails the gate
    closer_m = 0.0                           # a head closer by less than this (beyond the base's spread) passes

    [gate.sut_params]
    CP_DIST = 1.5
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

from harness.errors import InputError, Problem
from harness.scenario.logical import DRIVES

FILE_NAME = "stella.toml"
SUTS = ("px4", "ardupilot", "bundled")


@dataclass(frozen=True)
class Key:
    check: Callable[[Any], bool]
    expected: str
    path: bool = False  # a path (or a list of them) relative to the file


def _whole(low: int) -> Callable[[Any], bool]:
    return lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= low


def _number(low: float, *, above: bool = False) -> Callable[[Any], bool]:
    return lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and (v > low if above else v >= low)


def _strings(v: Any) -> bool:
    return isinstance(v, list) and all(isinstance(item, str) and item for item in v)


def _algorithm(v: Any) -> bool:
    from harness.search.optimizers import parse_algorithm

    try:
        parse_algorithm(v)
    except (ValueError, AttributeError):
        return False
    return True


def _params(v: Any) -> bool:
    return isinstance(v, dict) and all(_number(-math.inf)(value) for value in v.values())


KEYS: dict[str, Key] = {
    "sut": Key(lambda v: v in SUTS, f"one of {', '.join(SUTS)}"),
    "suite": Key(_strings, "a list of regression cases, concrete scenarios or folders of them", path=True),
    "scenarios": Key(_strings, "a list of logical scenario files", path=True),
    "drive": Key(lambda v: v in DRIVES, f"one of {', '.join(DRIVES)}"),
    "budget_flights": Key(_whole(1), "a whole number of search candidates, 1 or more"),
    "budget_minutes": Key(_number(0, above=True), "a number of minutes above 0"),
    "algorithm": Key(_algorithm, "NSGAII, SMPSO, BO, RANDOM or a combination such as NPB"),
    "population": Key(_whole(2), "a whole number, 2 or more"),
    "confirm": Key(_whole(0), "a whole number of flights, 0 or more"),
    "verify_flights": Key(_whole(1), "a whole number of flights a side, 1 or more"),
    "seed": Key(lambda v: _whole(0)(v) and v < 2**32, "a whole number from 0 to 4294967295"),
    "closer_m": Key(_number(0), "a distance in metres, 0 or more"),
    "max_findings": Key(_whole(1), "a whole number, 1 or more"),
    "shrink_candidates": Key(_whole(0), "a whole number of candidates, 0 or more (0: the worst regression is not shrunk)"),
    "workers": Key(_whole(1), "a whole number, 1 or more"),
    "fly_identical": Key(lambda v: isinstance(v, bool), "true or false"),
    "profile": Key(lambda v: isinstance(v, str) and bool(v), "a vehicle profile's name or file"),
    "sut_params": Key(_params, "a table of parameter names and numbers, e.g. CP_DIST = 1.5"),
    "sut_params_file": Key(lambda v: isinstance(v, str) and bool(v), "a parameter file (.params, .parm or NAME,VALUE CSV)", path=True),
    "worktree_command": Key(lambda v: isinstance(v, str) and bool(v), "a shell command template with {source}, {commit} and {dir}"),
    "cache": Key(lambda v: isinstance(v, str) and bool(v), "a folder for the builds and the base's flights", path=True),
}


def load_config(path: Path) -> dict[str, Any]:
    """The `[gate]` table, checked, with its paths made absolute."""
    if not path.is_file():
        raise InputError([Problem(str(path), "", "no such configuration file: give --config the path of a stella.toml, or leave it out")])
    try:
        document = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as error:
        raise InputError([Problem(str(path), "", f"not TOML: {error}")]) from None
    except UnicodeDecodeError:
        raise InputError([Problem(str(path), "", "not a text file: give a TOML file")]) from None
    gate = document.get("gate")
    if not isinstance(gate, dict):
        raise InputError([Problem(str(path), "/gate", "no [gate] table: put the gate's settings under [gate] (docs/ci.md shows one)")])
    problems = [Problem(str(path), f"/{table}", "unknown table: the gate reads [gate] only") for table in document if table != "gate"]
    for key, value in gate.items():
        known = KEYS.get(key)
        if known is None:
            problems.append(Problem(str(path), f"/gate/{key}", f"unknown key; the gate reads {', '.join(KEYS)}"))
        elif not known.check(value):
            problems.append(Problem(str(path), f"/gate/{key}", f"{value!r} is not {known.expected}"))
    if problems:
        raise InputError(problems)
    return {key: _relative_to(path.parent, value) if KEYS[key].path else value for key, value in gate.items()}


def _relative_to(folder: Path, value: str | list[str]) -> str | list[str]:
    if isinstance(value, list):
        return [str((folder / item).resolve()) for item in value]
    return str((folder / Path(value).expanduser()).resolve())


def merged(config: Mapping[str, Any], given: Mapping[str, Any]) -> dict[str, Any]:
    """The configuration file's settings with the command line's (those not None) over them."""
    return {**config, **{key: value for key, value in given.items() if value is not None}}
