"""`stella properties`: the named safety properties and the signals a property file may use."""

from __future__ import annotations

import argparse

from harness.tools.commands.common import command, emit


@command("properties", "the named safety properties (their STL formulas, parameters and sources) and the signals a property may use")
def cmd_properties(args: argparse.Namespace) -> int:
    from harness.properties.signals import SIGNALS
    from harness.properties.spec import LIBRARY

    lines = ["properties (--property NAME, or a JSON file; robustness >= 0: kept):"]
    for prop in LIBRARY.values():
        parameters = ", ".join(f"{name} = {value:g}" for name, value in prop.parameters.items())
        lines += [f"  {prop.name}: {prop.description}", f"      {prop.formula}" + (f"   where {parameters}" if parameters else "") + f"   [{prop.unit}]"]
        if prop.source:
            lines.append(f"      after {prop.source}")
    lines.append("signals:")
    lines += [f"  {name:<28} {signal.unit:<5} {signal.meaning}" for name, signal in SIGNALS.items()]
    emit(args, {"properties": [prop.as_dict() for prop in LIBRARY.values()],
                "signals": {name: {"unit": signal.unit, "meaning": signal.meaning} for name, signal in SIGNALS.items()}}, "\n".join(lines))
    return 0
