"""Safety properties: Signal Temporal Logic formulas over the signals a flight records
(harness/properties/signals.py), named in a library or written in a property file, checked
before anything flies and monitored with rtamt (harness/properties/monitor.py).

A property file is JSON:

    {"name": "gentle",
     "formula": "always(tilt_deg <= max_tilt_deg)",
     "parameters": {"max_tilt_deg": 20},
     "unit": "deg",
     "description": "never tilts more than 20 degrees"}

The formula is rtamt's discrete-time STL: `always`, `eventually`, `historically`, `once`,
`since`, `until`, each with an optional bound in seconds (`eventually[0:5]`), `and`, `or`, `not`,
`->`, comparisons and arithmetic over signals, parameters and numbers. A property is kept where
its robustness (rtamt's quantitative semantics at the flight's first sample) is 0 or more.
"""

from __future__ import annotations

import difflib
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from harness.errors import InputError, Problem
from harness.properties.signals import SIGNALS

# rtamt's words, which are not signals.
KEYWORDS = frozenset({"always", "eventually", "historically", "once", "since", "until", "and", "or", "not", "implies", "iff", "xor",
                      "next", "prev", "rise", "fall", "abs", "sqrt", "exp", "pow", "G", "F", "H", "O", "S", "U", "X", "Y", "true", "false"})
IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


@dataclass(frozen=True)
class Property:
    name: str
    formula: str
    unit: str
    description: str
    parameters: Mapping[str, float] = field(default_factory=dict)
    source: str = ""  # the documentation the property comes from

    @property
    def stated(self) -> str:
        """The formula with its parameters' values in place, as the monitor reads it."""
        def value(match: re.Match) -> str:
            word = match.group(0)
            return repr(float(self.parameters[word])) if word in self.parameters else word

        return IDENTIFIER.sub(value, self.formula)

    @property
    def signals(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(word for word, _column in _identifiers(self.stated) if word in SIGNALS))

    def as_dict(self) -> dict[str, Any]:
        return {"name": self.name, "formula": self.formula, "parameters": dict(self.parameters), "unit": self.unit,
                "description": self.description, "source": self.source}


def _identifiers(formula: str) -> list[tuple[str, str]]:
    """(identifier, "line:column" from 1) of each name in the formula, numbers' exponents left out."""
    found = []
    for match in IDENTIFIER.finditer(formula):
        start = match.start()
        if start and (formula[start - 1].isdigit() or formula[start - 1] == "."):
            continue
        line_start = formula.rfind("\n", 0, start) + 1
        found.append((match.group(0), f"{formula.count(chr(10), 0, start) + 1}:{start - line_start + 1}"))
    return found


def check(prop: Property, where: str, at: str = "") -> None:
    """InputError naming `where` (the file), `at` (the property's JSON pointer in it) and the
    column of each name in the formula that is neither a signal, a parameter nor a word of STL,
    and the position of a syntax error."""
    from harness.properties.monitor import parse

    problems = []
    for word, column in _identifiers(prop.formula):
        if word not in SIGNALS and word not in prop.parameters and word not in KEYWORDS:
            close = difflib.get_close_matches(word, [*SIGNALS, *prop.parameters], n=3, cutoff=0.5)
            problems.append(Problem(where, f"{at}/formula", f"{column}: {word!r} is neither a signal nor a parameter"
                                                       + (f"; did you mean {', '.join(close)}?" if close else "; `stella properties` lists the signals")))
    if problems:
        raise InputError(problems)
    parse(prop, where, at=at)


LIBRARY: dict[str, Property] = {p.name: p for p in (
    Property("clearance", "always(margin_m >= 0)", "m",
             "keeps the safety distance from every obstacle; its robustness is the fitness f"),
    Property("geofence", "always(distance_from_home_m <= max_distance_m and altitude_m <= max_altitude_m)", "m",
             "stays inside a cylinder around the take-off point", {"max_distance_m": 150.0, "max_altitude_m": 120.0},
             "PX4's GF_MAX_HOR_DIST and GF_MAX_VER_DIST (0 in PX4, no fence, until a team sets them)"),
    Property("max_tilt", "always(tilt_deg <= max_tilt_deg)", "deg",
             "never tilts beyond the multicopter's tilt limit", {"max_tilt_deg": 45.0},
             "PX4 MPC_TILTMAX_AIR (default 45 degrees)"),
    Property("max_speed", "always(horizontal_speed_m_s <= max_speed_m_s)", "m/s",
             "never flies faster horizontally than the speed limit", {"max_speed_m_s": 12.0},
             "PX4 MPC_XY_VEL_MAX (default 12 m/s)"),
    Property("lands_in_area", "eventually(always(agl_m <= landed_agl_m and distance_to_goal_m <= radius_m))", "m",
             "ends the flight on the ground within the landing area around the goal", {"landed_agl_m": 0.3, "radius_m": 3.0}),
    Property("no_flyaway", "always(distance_from_route_m <= corridor_m)", "m",
             "stays within a corridor around its route, failures or not", {"corridor_m": 20.0}),
    Property("altitude_band", "always(agl_m <= ceiling_m and ((distance_from_home_m >= clear_m and distance_to_goal_m >= clear_m) -> agl_m >= floor_m))", "m",
             "between take-off and landing (farther than clear_m from either) flies no lower than floor_m above the ground, and never above ceiling_m",
             {"floor_m": 1.0, "ceiling_m": 120.0, "clear_m": 5.0},
             "the 120 m ceiling of EU and US drone rules; PX4's GF_MAX_VER_DIST when a team sets it"),
    Property("gps_loss_lands",
             "always(historically[0:loss_s](lost_gps >= 0.5) -> eventually[0:react_s]((mode_land >= 0.5) or (mode_altitude >= 0.5) or (armed <= 0.5) or (lost_gps <= 0.5)))", "1/0",
             "once the GPS has been off for loss_s, within react_s the vehicle descends or lands (or, flown by hand, is in Altitude mode), or is disarmed, "
             "or has its GPS back",
             {"loss_s": 5.0, "react_s": 3.0},
             "PX4: the EKF reports no horizontal position after EKF2_NOAID_TOUT (5 s) without aiding; a mode that needs one falls back "
             "(failsafe.cpp checkModeFallback): Position to Altitude mode, the others to Land, else Descend, both reported as AUTO/LAND. "
             "ArduCopter: the EKF failsafe, FS_EKF_ACTION (1: Land, 2: AltHold), after the EKF's variance passes FS_EKF_THRESH for a second"),
    Property("datalink_loss_acts",
             "always(historically[0:loss_s](lost_data_link >= 0.5) -> eventually[0:react_s]((mode_hold >= 0.5) or (mode_rtl >= 0.5) or (mode_land >= 0.5) or (armed <= 0.5) or (lost_data_link <= 0.5)))", "1/0",
             "once the ground station's link has been lost for loss_s, within react_s the vehicle holds, returns or lands (or is disarmed, or has its link back); "
             "for a SUT set to act on it (PX4's NAV_DLL_ACT 0, its default, does nothing)",
             {"loss_s": 10.0, "react_s": 5.0},
             "PX4: the GCS connection loss failsafe after COM_DL_LOSS_T (10 s) without a heartbeat, NAV_DLL_ACT 1 Hold, 2 Return, 3 Land "
             "(failsafe.cpp fromNavDllOrRclActParam; Return and Land after Hold for COM_FAIL_ACT_T), not while landing. "
             "react_s allows PX4's own link timeout: its MAVLink link keeps a ground station for 2.5 s after its last heartbeat "
             "(HEARTBEAT_TIMEOUT_US) and reports it at 1 Hz, so PX4 holds about 12 s after the last heartbeat"),
    Property("range_loss_stops",
             "always((historically[0:stop_s](lost_distance_sensor * mode_position)) * (horizontal_speed_m_s - creep_m_s) <= 0)", "m/s",
             "in Position mode, stop_s after the range sensor goes silent the vehicle is no faster than creep_m_s: it moves nowhere it cannot see "
             "(robustness: 0 when kept, less by the excess speed when not)",
             {"stop_s": 3.0, "creep_m_s": 0.5},
             "PX4 CollisionPrevention.cpp: bins without data for 0.5 s (RANGE_STREAM_TIMEOUT_US) are reset, and with no obstacle data at all "
             "'allow no movement' (even with CP_GO_NO_DATA=1, CollisionPreventionTest.cpp)"),
    Property("range_loss_holds",
             "always(not historically[0:hold_s]((lost_distance_sensor >= 0.5) and (mode_position >= 0.5)))", "1/0",
             "in Position mode with the range sensor silent, the vehicle switches to Hold within hold_s",
             {"hold_s": 6.0},
             "PX4 CollisionPrevention.cpp: 'if distance data is stale, switch to Loiter' after TIMEOUT_HOLD_US (5 s)"),
)}


def property_from(document: Mapping[str, Any], where: str, at: str = "") -> Property:
    """A property as Property.as_dict wrote it (a regression case's, a campaign's), checked."""
    prop = Property(document["name"], document["formula"], document["unit"], document.get("description", ""),
                    {k: float(v) for k, v in document.get("parameters", {}).items()}, document.get("source", ""))
    check(prop, where, at)
    return prop


def load_property(given: str) -> Property:
    """A named property, or the property in a JSON file, checked."""
    if given in LIBRARY:
        return LIBRARY[given]
    path = Path(given)
    if not path.is_file():
        raise InputError([Problem(given, "", f"neither a property's name ({', '.join(LIBRARY)}) nor a property file")])
    try:
        document = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise InputError([Problem(str(path), "", f"invalid JSON: {error}")]) from None
    if not isinstance(document, dict):
        raise InputError([Problem(str(path), "", "a property file is a JSON object with name, formula, unit and description")])
    problems = []
    for key in ("name", "formula", "unit"):
        if not isinstance(document.get(key), str) or not document[key].strip():
            problems.append(Problem(str(path), f"/{key}", "missing or not a non-empty string"))
    parameters = document.get("parameters", {})
    if not isinstance(parameters, dict) or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in parameters.values()):
        problems.append(Problem(str(path), "/parameters", "an object of names and numbers, e.g. {\"max_tilt_deg\": 20}"))
    clashing = [name for name in parameters if name in SIGNALS or name in KEYWORDS] if isinstance(parameters, dict) else []
    problems += [Problem(str(path), f"/parameters/{name}", "is a signal's or STL's own name: name the parameter otherwise") for name in clashing]
    unknown = sorted(set(document) - {"name", "formula", "unit", "description", "parameters", "source"})
    problems += [Problem(str(path), f"/{key}", "unknown key; a property has name, formula, unit, description, parameters, source") for key in unknown]
    if problems:
        raise InputError(problems)
    return property_from(document, str(path))
