"""`stella explain`: the causal timeline of a flight's closest approach and its mechanism, from the log alone."""

from __future__ import annotations

import argparse
from pathlib import Path

from harness.errors import InputError, Problem
from harness.tools.commands.common import command, emit


def _explain_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="an evaluation's .mcap file (from `stella run --out` or a campaign's logs folder)")


@command("explain", "why a flight came closest: the timeline from the log alone and the mechanism (unseen, seen_late, braked_too_little, "
                    "outrun, pushed, other)",
         _explain_options, description="The causal timeline of a flight's closest approach, read from its log alone, and the mechanism "
                                        "with the numbers behind it. docs/explain.md defines the mechanisms.")
def cmd_explain(args: argparse.Namespace) -> int:
    from harness.campaigns.explain import explain, explain_text

    path = Path(args.log)
    if not path.is_file():
        raise InputError([Problem(str(path), "", "no such file" if not path.exists() else "not a file: give an evaluation log (*.mcap)")])
    report = explain(path)
    emit(args, report, explain_text(report))
    return 0
