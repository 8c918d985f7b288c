"""`stella validate`, `space`, `sample`, `generate` and `import`: logical scenarios and profiles
checked, their search spaces, concrete scenarios sampled from them, and other tools' tests
turned into concrete scenarios."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Sequence

import numpy as np

from harness.errors import InputError, Problem
from harness.scenario.documents import load_json
from harness.scenario.generate import ELEMENTS, PROGRAMME_SHAPES
from harness.scenario.logical import DRIVES, load_logical, logical_problems, with_plan_embedded, with_rig_embedded
from harness.scenario.plan import plan_problems
from harness.scenario.profile import is_profile_document, load_profile, profile_problems
from harness.scenario.rig import is_rig_document, rig_problems
from harness.scenario.space import CONCRETE_FORMAT
from harness.scenario.world import space_from_concrete
from harness.tools.commands.common import command, emit, non_negative_float, positive_int, seed_int
from harness.tools.commands.sut_options import space_of


def _validate_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("paths", nargs="+", help="JSON files or folders of them")
    p.add_argument("--profile", default="default", help="profile name or path used to check units (default: default)")
    p.add_argument("--rig", metavar="NAME|FILE", help="check logical scenarios against this sensor rig (their \"sensors\" and failures of one sensor)")


@command("validate", "check logical scenarios, profiles and sensor rigs; each error as `file: /json/pointer: message`", _validate_options)
def cmd_validate(args: argparse.Namespace) -> int:
    profile = load_profile(args.profile)
    problems: list[Problem] = []
    report = []
    for path in _expand(args.paths):
        try:
            document = load_json(path)
        except InputError as error:
            problems.extend(error.problems)
            report.append({"file": str(path), "ok": False})
            continue
        if path.suffix == ".plan":
            found, kind, notes = plan_problems(document, str(path)), "QGroundControl plan", []
        elif is_rig_document(document):
            found, kind, notes = rig_problems(document, str(path)), "sensor rig", []
        elif is_profile_document(document):
            found = profile_problems(document, str(path))
            kind = "profile"
            notes: list[str] = []
            if not found:
                notes = [f"{name} not simulated" for name, p in document["parameters"].items() if not p["simulated"]]
        elif isinstance(document, dict) and document.get("format") == CONCRETE_FORMAT:
            kind, notes = "concrete scenario", []
            try:
                space = space_from_concrete(document, str(path))
                space.from_concrete(document, str(path))
                found = []
            except InputError as error:
                found = list(error.problems)
        else:
            try:
                found = logical_problems(with_rig_embedded(with_plan_embedded(document, path.parent), path, args.rig), profile, str(path))
            except InputError as error:  # its plan or rig file
                found = list(error.problems)
            kind = "logical scenario"
            notes = []
            if not found:
                logical = load_logical(path, profile, rig=args.rig)
                notes = [f"{w.parameter} = {w.category} ({w.source}) is not simulated" for w in logical.not_simulated]
        problems.extend(found)
        report.append({"file": str(path), "kind": kind, "ok": not found, "notes": notes})
    if args.json:
        print(json.dumps({"files": report, "problems": [p.__dict__ for p in problems]}, indent=2))
    else:
        for problem in problems:
            print(problem)
        for entry in report:
            if entry["ok"]:
                notes = "; ".join(entry["notes"]) if args.verbose else ""
                print(f"ok: {entry['file']} ({entry['kind']})" + (f"; note: {notes}" if notes else ""))
        if not args.verbose:
            _print_each_note_once(report)
    return 2 if problems else 0


@command("rigs", "list the sensor rigs (--rig NAME): each one's messages and sensors")
def cmd_rigs(args: argparse.Namespace) -> int:
    from harness.scenario.rig import presets, summary_line

    listed = presets()
    lines = []
    for rig in listed:
        lines.append(f"{rig['name']} ({', '.join(rig['messages'])}): {rig['description']}")
        lines += [f"  {summary_line(sensor)}" for sensor in rig["sensors"]]
    emit(args, {"rigs": listed}, "\n".join(lines))
    return 0


def _print_each_note_once(report: list[dict]) -> None:
    """Most scenarios share the profile's unsimulated defaults (lighting, lightning, ...): one
    line per note with how many files it holds for, rather than the same four notes per file."""
    files_of: dict[str, list[str]] = {}
    for entry in report:
        for note in entry.get("notes", []):
            files_of.setdefault(note, []).append(entry["file"])
    for note, files in files_of.items():
        where = files[0] if len(files) == 1 else f"{len(files)} files"
        print(f"note: {note} ({where}; each file's notes with --verbose)")


def _expand(paths: Sequence[str]) -> list[Path]:
    files: list[Path] = []
    for raw in paths:
        path = Path(raw)
        found = sorted([*path.glob("*.json"), *path.glob("*.plan")]) if path.is_dir() else [path]
        if not found:
            raise InputError([Problem(str(path), "", "a folder without *.json or *.plan files: give scenario, profile or plan files, or a folder of them")])
        files.extend(found)
    return files


def _scenario_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="logical scenario JSON")
    p.add_argument("--profile", default="default")
    p.add_argument("--drive", choices=DRIVES, help="override the scenario's mission.drive (pilot adds the pilot's dimensions)")
    p.add_argument("--mission-plan", metavar="PLAN", help="fly this QGroundControl .plan instead of the scenario's route (its home is the origin)")
    p.add_argument("--rig", metavar="NAME|FILE", help="the vehicle's range sensors: a preset (`stella rigs`) or a rig file, instead of the profile's")


@command("space", "print the derived search space", _scenario_options)
def cmd_space(args: argparse.Namespace) -> int:
    space = space_of(args)
    description = space.describe()
    lines = [f"{space.logical.name} ({space.n_dimensions} dimensions, profile {space.profile.name})"]
    lines += [f"  {d['name']:<28} {d['lower']:>10.3f} {d['upper']:>10.3f}  {d['unit']}" for d in description["dimensions"]]
    lines += [f"  fixed: {f['name']} = {f['value']} {f['unit']}" for f in description["fixed"]]
    lines += [
        f"  not simulated: {n['parameter']} = {n['category']} ({n['min']}-{n['max']} {n['unit']})"
        for n in description["not_simulated"]
    ]
    lines += [f"  constraint: {c}" for c in description["constraints"]]
    emit(args, description, "\n".join(lines))
    return 0


def _sample_options(p: argparse.ArgumentParser) -> None:
    _scenario_options(p)
    p.add_argument("--seed", type=seed_int, default=0)
    p.add_argument("--out", help="also write the concrete scenario to this file")


@command("sample", "sample one feasible concrete scenario and its world spec", _sample_options)
def cmd_sample(args: argparse.Namespace) -> int:
    from harness.scenario.world import world_spec

    space = space_of(args)
    x = space.sample_feasible(np.random.default_rng(args.seed), 1)[0]
    result = {"vector": x.tolist(), "concrete": space.to_concrete(x), "world": world_spec(space, x, args.seed).as_dict()}
    if args.out:
        Path(args.out).write_text(json.dumps(result["concrete"], indent=2) + "\n")
    text = json.dumps({k: v for k, v in result["concrete"].items() if k not in ("logical_scenario", "profile_document")}, indent=2)
    emit(args, result, text)
    return 0


def _generate_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--strength", type=int, default=2, help="T: every valid combination of T category values is in some scenario (default 2, pairwise)")
    p.add_argument("--elements", choices=ELEMENTS, default="all",
                   help="all (default): the paper's value sets plus gusts, intruders, dynamic obstacles' motions and one injected failure; "
                        "paper: the paper's value sets only (landform, surface, wind, visibility, up to four static or dynamic obstacles)")
    p.add_argument("--rigs", type=_listed, default=[], metavar="RIG,...",
                   help="add the vehicle's sensor rig as a factor over these presets or rig files; presets: every preset; profile: the profile's own sensors")
    p.add_argument("--programmes", type=_listed, default=[], metavar="SHAPE,...",
                   help="add the shape of the pilot's stick programme as a factor, flying every scenario in the pilot drive: "
                        f"{', '.join(PROGRAMME_SHAPES)}, or all (docs/scenarios.md)")
    p.add_argument("--max-scenarios", type=positive_int, default=10_000, help="refuse a strength that gives more logical scenarios than this (default 10,000)")
    p.add_argument("--out", required=True)


def _listed(text: str) -> list[str]:
    return [item.strip() for item in text.split(",") if item.strip()]


@command("generate", "write logical scenarios covering every T-wise combination of the scenario format's category values", _generate_options)
def cmd_generate(args: argparse.Namespace) -> int:
    from harness.scenario.generate import MAX_TUPLES, FactorModel, generate

    model = FactorModel(args.elements, args.rigs, args.programmes)
    factors = len(model.names)
    if not 1 <= args.strength <= factors:
        raise InputError([Problem("--strength", "", f"{args.strength} is not a strength for the {factors} value sets of --elements {args.elements}: "
                                                    f"choose 1 to {factors} (2, pairwise, is usual)")])
    bound = model.fewest_rows(args.strength)
    if bound > args.max_scenarios:
        raise InputError([Problem("--strength", "", f"strength {args.strength} gives at least {bound:,} logical scenarios, more than --max-scenarios "
                                                    f"{args.max_scenarios:,}: choose a lower strength, or raise --max-scenarios")])
    tuples = model.tuples(args.strength)
    if tuples > MAX_TUPLES:
        raise InputError([Problem("--strength", "", f"strength {args.strength} over --elements {args.elements} has {tuples:,} combinations of values to cover, "
                                                    f"more than the {MAX_TUPLES:,} that generation holds in memory: choose a lower strength"
                                                    + (", or --elements paper" if args.elements != "paper" else ""))])
    print(f"strength {args.strength}: at least {bound:,} logical scenarios (the valid combinations of the {args.strength} value sets with the most) "
          f"over the {args.elements} elements' {factors} value sets; strength 3 of all elements takes about 10 s, strength 4 minutes",
          file=sys.stderr)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for stem, document in generate(args.strength, args.elements, args.rigs, args.programmes):
        path = out / f"{stem}.json"
        path.write_text(json.dumps(document, indent=2) + "\n")
        written.append(str(path))
    emit(args, {"strength": args.strength, "elements": args.elements, "count": len(written), "files": written},
         f"wrote {len(written)} logical scenarios covering every {args.strength}-wise combination of the {args.elements} elements' values to {out}")
    return 0


def _import_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("kind", choices=["aerialist"])
    p.add_argument("test", help="the test's YAML (its mission_file and params_file are found beside it or in the working directory)")
    p.add_argument("--out", required=True, help="the concrete scenario JSON to write (its SUT parameters go beside it as NAME.params.csv)")
    p.add_argument("--safety-distance", type=non_negative_float, default=1.5, help="metres (default 1.5: the competition's soft-fail distance)")


@command("import", "turn a UAV Testing Competition test (Aerialist YAML) into a concrete scenario", _import_options)
def cmd_import(args: argparse.Namespace) -> int:
    from harness.interop.aerialist import import_aerialist

    concrete, params = import_aerialist(Path(args.test), args.safety_distance)
    out = Path(args.out)
    out.write_text(json.dumps(concrete, indent=2) + "\n")
    files = [str(out)]
    fly = f"stella run --concrete {out}"
    if params:
        params_path = out.with_name(out.stem + ".params.csv")
        params_path.write_text("".join(f"{name},{value}\n" for name, value in params.items()))
        files.append(str(params_path))
        fly += f" --sut-params-file {params_path}"
    boxes = len(concrete["obstacles"])
    emit(args, {"files": files, "obstacles": boxes, "sut_params": params, "fly": fly},
         "\n".join(files) + f"\nimported {boxes} box(es) and the plan; fly it with: {fly}  (add --sut px4 for PX4 SITL)")
    return 0
