"""`stella explain`: the causal timeline of a flight's closest approach and its mechanism, from the log alone."""

from __future__ import annotations

import argparse
from pathlib import Path

from harness.errors import InputError, Problem
from harness.tools.commands.common import command, emit


def _explain_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="an evaluation's .mcap file (from `stella run --out` or a campaign's logs folder)")
    p.add_argument("--property", action="append", metavar="NAME|FILE",
                   help="also say when this safety property's verdict was decided and its signals then (`stella properties` names them); repeatable")


@command("explain", "why a flight came closest: the timeline from the log alone and the mechanism (unseen, seen_late, braked_too_little, "
                    "outrun, pushed, other)",
         _explain_options, description="The causal timeline of a flight's closest approach, read from its log alone, and the mechanism "
                                        "with the numbers behind it. docs/explain.md defines the mechanisms.")
def cmd_explain(args: argparse.Namespace) -> int:
    from harness.campaigns.explain import explain, explain_text
    from harness.flight.evaluation import properties_explained
    from harness.properties.spec import load_property

    path = Path(args.log)
    if not path.is_file():
        raise InputError([Problem(str(path), "", "no such file" if not path.exists() else "not a file: give an evaluation log (*.mcap)")])
    properties = [load_property(given) for given in args.property or []]
    report = explain(path)
    text = explain_text(report)
    if properties:
        report["properties"] = properties_explained(path, properties)
        text += "\n" + properties_text(report["properties"])
    emit(args, report, text)
    return 0


def properties_text(explained: dict) -> str:
    lines = []
    for name, scored in explained.items():
        when = scored["decided"]
        robustness = "-" if scored["robustness"] is None else f"{scored['robustness']:.3f} {scored['unit']}"
        signals = ", ".join(f"{signal} {value:g}" for signal, value in when["signals"].items()) if when else ""
        lines.append(f"property {name}: {scored['verdict']}, robustness {robustness}" + (f"; decided at {when['time_s']:.2f} s: {signals}" if when else ""))
    return "\n".join(lines)
