"""`stella shrink`: the smallest, simplest concrete scenario that still violates, from a case, a log
or a campaign's evaluation."""

from __future__ import annotations

import argparse
import shutil
import sys
from dataclasses import replace
from pathlib import Path

from harness.campaigns.regression import EXPECTATIONS
from harness.tools.commands.common import command, emit, positive_float, positive_int, seed_int
from harness.tools.commands.sut_options import add_sut_options, check_rig, check_transport, mission_plan, sut_spec
from sim_bridge.sut_link import TRANSPORTS


def evaluation_of_store(text: str) -> int | str:
    """An evaluation's id, or the file name of its log (which older stores named otherwise)."""
    if text.isdigit():
        return int(text)
    if not text.endswith(".mcap"):
        raise argparse.ArgumentTypeError(f"{text!r} is neither an evaluation's id (a whole number) nor its log's file name (*.mcap)")
    return Path(text).name


def _shrink_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", metavar="CASE|LOG|DB", help="a concrete scenario or regression case (JSON), an evaluation log (.mcap), "
                                                         "or a campaign store with --evaluation")
    p.add_argument("--evaluation", type=evaluation_of_store, metavar="ID|LOG",
                   help="with a campaign store: the evaluation to shrink, by its id (the number in its log's name, eval00025.mcap is 25) or its log's file name")
    p.add_argument("--out", default="shrunk", help="folder for the shrunk case, its regression case, its log and the journal (default: shrunk/)")
    p.add_argument("--name", help="stem of the files written (default: from the source)")
    p.add_argument("--confirm", type=positive_int, default=1,
                   help="flights that must all violate for a step to be kept (default 1: the bundled stack repeats itself bit for bit; "
                        "give 3 or more for PX4 or ArduPilot, whose timing differs run to run)")
    p.add_argument("--max-evaluations", type=positive_int, default=300, help="flights this session may make (default 300); the journal's are free")
    p.add_argument("--time-budget-s", type=positive_float, help="wall time this session may take (default: no limit)")
    p.add_argument("--seed", type=seed_int, help="sensor-noise seed of the flights (default: the source's; 0 for a concrete scenario)")
    p.add_argument("--expect", choices=[e for e in EXPECTATIONS if e != "as_reference"], default="safe",
                   help="what the regression case written expects: safe (it fails until the SUT is fixed; the default) or violation")
    add_sut_options(p)
    p.set_defaults(sut=None)  # the source's SUT where it records one, else the bundled autopilot
    p.add_argument("--rate-hz", type=positive_float, help="lockstep rate (default: the SUT's own)")
    p.add_argument("--cores", type=int, choices=(1, 2), default=1,
                   help="1 (default): the simulator and the SUT share one core, which a long series of flights leaves to other work; 2: a core each")
    p.add_argument("--transport", choices=TRANSPORTS, default="auto", help="as for `stella run`")
    p.add_argument("--property", action="append", metavar="NAME|FILE",
                   help="shrink while this safety property stays violated (instead of the safety distance); repeatable: while every one does")


def _with_recorded_sut(args: argparse.Namespace, recorded) -> argparse.Namespace:
    """The command line's SUT, or where it names none, the one the source records (its parameters
    and seeded fault too, unless the command line gives its own)."""
    if args.sut is not None:
        return args
    if not recorded:
        return argparse.Namespace(**{**vars(args), "sut": "bundled"})
    changes = {"sut": recorded["name"]}
    if not args.sut_param and not args.sut_params_file:
        changes["sut_param"] = [f"{name}={value}" for name, value in recorded.get("params", {}).items()]
    if args.sut_fault is None and recorded.get("fault"):
        changes["sut_fault"] = recorded["fault"]
    return argparse.Namespace(**{**vars(args), **changes})


@command("shrink", "the smallest, simplest version of a violating case that still violates (a regression case of it too)", _shrink_options,
         description="Shrink a violating concrete scenario: drop obstacles, failures and gusts, calm the wind, clear the air, move each searched "
                     "value to its neutral value and round it, keeping a step only if the re-flown case still violates. Resumable: run the "
                     "same command again after a stop and it replays its journal. See docs/shrink.md.")
def cmd_shrink(args: argparse.Namespace) -> int:
    from harness.campaigns import shrink
    from harness.flight import stack
    from harness.flight.evaluation import RunOptions
    from harness.properties.spec import load_property

    case = shrink.load_case(Path(args.source), args.evaluation, args.seed)
    args = _with_recorded_sut(args, case.sut)
    sut = sut_spec(args)
    check_transport(args.transport, sut)
    start = shrink.start_document(case, args.drive, mission_plan(args), args.rig)
    check_rig(start["profile_document"].get("rig"), sut)
    name = args.name or f"{case.name}-shrunk"
    out = Path(args.out)
    properties = tuple(load_property(given) for given in args.property or [])
    header = {"format": shrink.JOURNAL_FORMAT, "start": shrink.key_of(start), "seed": case.seed, "sut": sut.identity(), "confirm": args.confirm,
              **({"properties": [prop.as_dict() for prop in properties]} if properties else {})}
    journal = shrink.Journal(out / f"{name}.journal.jsonl", header)
    options = replace(RunOptions(sut=sut, rate_hz=args.rate_hz, cores=args.cores, transport=args.transport, properties=properties), warm=True)
    keeps = {"keeps": shrink.violating_properties([prop.name for prop in properties]),
             "kept": "the propert" + ("y " if len(properties) == 1 else "ies ") + ", ".join(prop.name for prop in properties)} if properties else {}

    def progress(step: shrink.StepRecord, shrinker: shrink.Shrinker) -> None:
        if not args.json:
            print(f"[{shrinker.flown} flown, {shrinker.replayed} from the journal, {shrinker.elapsed_s:.0f} s] {shrink.step_line(step)}", file=sys.stderr)

    shrinker = shrink.Shrinker(shrink.flyer(options, case.seed, out / f"{name}-flights"), journal, confirm=args.confirm,
                               budget=shrink.Budget(args.max_evaluations, args.time_budget_s), on_step=progress, **keeps)
    try:
        report = shrinker.shrink(start, case.label)
    finally:
        stack.close_kept()
    written = shrink.write_outputs(report, case, out, name, sut.identity(), args.expect, [prop.as_dict() for prop in properties])
    if not report.stopped:
        shutil.rmtree(out / f"{name}-flights", ignore_errors=True)
    result = {"source": case.label, "sut": sut.identity(), "seed": case.seed, **shrink.summary(report), **written, "journal": str(journal.path)}
    emit(args, result, _text(report, written, case.label, journal.path, "least robustness" if properties else "fitness"))
    return 3 if report.unfinished_flight else 0


def _text(report, written: dict[str, str], label: str, journal: Path, measure: str = "fitness") -> str:
    from harness.campaigns.shrink import elements_text, summary

    counted = summary(report)
    lines = [f"shrunk {label}: {measure} {report.f_start:.3f} -> {report.f_result:.3f} in {len(report.kept)} kept steps of {len(report.steps)} tried "
             f"({report.flown} flown, {report.replayed} from the journal, {report.wall_s:.0f} s)"]
    lines += [f"  {index}. {step.description}: f {step.f_before:.3f} -> {step.f_after:.3f}" for index, step in enumerate(report.kept, 1)]
    lines.append(f"before: {elements_text(counted['before']['elements'])}")
    lines.append(f"after:  {elements_text(counted['after']['elements'])}")
    if report.stopped:
        lines.append(f"stopped early: {report.stopped}; run the same command again to go on (the journal {journal} keeps every flight)")
    lines.append("wrote " + ", ".join(written.values()))
    return "\n".join(lines)
