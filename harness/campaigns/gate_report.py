"""What `stella gate` writes for a CI job and a pull request:

* `summary.md`: the verdict first, then each regression with its mechanism, both sides'
  outcomes, the commands that fly it again and its bundle; then what was and was not covered.
  Fit for a job summary ($GITHUB_STEP_SUMMARY) and a PR comment;
* `junit.xml`: one test per suite case and per scenario searched, failed by a regression (a
  search's failure lists each), skipped where the budget left it unsearched;
* `findings/NN-NAME/`: for each of the worst regressions, `case.regression.json` (the head held to
  the base's outcome: fails on the head, passes on the base), `concrete.json`, `head.mcap` and
  `base.mcap`, `flight.png` and `explanation.txt` (`stella explain` of the head's flight),
  `FINDING.md`;
* `gate.json`: all of it for scripts.
"""

from __future__ import annotations

import json
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any, Mapping

from harness.campaigns.campaign import content_key
from harness.campaigns.explain import explain, explain_text
from harness.campaigns.gate import CHANGE, REGRESSION, UNJUDGED, GateResult, JudgedPair, Shrunk, Side
from harness.campaigns.regression import EXPECTATIONS, FORMAT, SUFFIX, reference_entry
from harness.errors import InputError
from harness.flight.inspect_log import plot

SUMMARY = "summary.md"
# A regression's kind (gate.SEVERITY), as its heading says it.
KIND_WORDS = {"unsafe": "the head violates the safety distance", "crash": "the head cannot finish its flight", "status": "the head ends worse",
              "closer": "the head comes closer"}
JUNIT = "junit.xml"
RESULT = "gate.json"
FINDINGS = "findings"


def write(result: GateResult, out_dir: Path) -> dict[str, str]:
    """Every output of the gate into out_dir; their paths by name."""
    out_dir.mkdir(parents=True, exist_ok=True)
    bundles = write_findings(result, out_dir / FINDINGS)
    (out_dir / SUMMARY).write_text(summary_markdown(result, bundles, out_dir))
    ET.ElementTree(junit(result)).write(out_dir / JUNIT, encoding="utf-8", xml_declaration=True)
    (out_dir / RESULT).write_text(json.dumps(as_dict(result, bundles), indent=2, default=str) + "\n")
    return {"summary": str(out_dir / SUMMARY), "junit": str(out_dir / JUNIT), "result": str(out_dir / RESULT)}


# -- outcomes in words -------------------------------------------------------------------------


def _flights(outcomes: list[Mapping[str, Any]]) -> str:
    statuses = "/".join(sorted({o["status"] for o in outcomes}))
    clearances = [o["min_clearance_m"] for o in outcomes if o["min_clearance_m"] is not None]
    if not clearances:
        return f"{statuses}, no clearance recorded"
    low, high = min(clearances), max(clearances)
    spread = f"{low:.2f} m" if len(clearances) == 1 or high - low < 0.005 else f"{low:.2f}-{high:.2f} m over {len(clearances)} flights"
    return f"{statuses}, min clearance {spread}"


def _sut_options(side: Side, prefix: str = "") -> list[str]:
    """The options that fly this side (prefix "reference-" for the reference of `stella run`)."""
    sut = side.sut
    options = [f"--{prefix}sut {sut.name}"] if prefix or sut.name != "bundled" else []
    for option, value in (("px4-bin", sut.px4_bin), ("ardupilot-bin", sut.ardupilot_bin), ("autopilot-dir", sut.autopilot_dir)):
        if value:
            options.append(f"--{prefix}{option} {value}")
    options += [f"--{prefix}sut-param {name}={value}" for name, value in sorted(sut.params.items())]
    return options


def _pytest_command(case: Path, head: Side) -> str:
    sut = head.sut
    if sut.px4_bin:
        return f"pytest {case} --stella-px4-bin {sut.px4_bin}"
    if sut.ardupilot_bin:
        return f"STELLA_ARDUPILOT_BIN={sut.ardupilot_bin} pytest {case}"
    return f"pytest {case}" + (f" --stella-autopilot-dir {sut.autopilot_dir}" if sut.autopilot_dir else "")


def fly_again_commands(pair: JudgedPair, result: GateResult, concrete: Path, case: Path) -> list[str]:
    confirm = max(1, result.plan.confirm)
    run = ["stella run --concrete", str(concrete), f"--seed {pair.seed}", *_sut_options(result.head), *_sut_options(result.base, "reference-"),
           f"--confirm {confirm}"]
    if result.plan.drive:
        run.append(f"--drive {result.plan.drive}")
    return [" ".join(run), _pytest_command(case, result.head)]


# -- findings ----------------------------------------------------------------------------------


def write_findings(result: GateResult, folder: Path) -> dict[str, Path]:
    """A bundle for each of the worst `max_findings` regressions: {the pair's name: its folder}."""
    if folder.exists():
        shutil.rmtree(folder)  # a gate run again in the same folder: only this run's findings
    bundles = {}
    for number, pair in enumerate(result.regressions[:result.plan.max_findings], start=1):
        bundle = folder / f"{number:02d}-{pair.name}"
        bundle.mkdir(parents=True)
        _bundle(pair, result, bundle)
        bundles[pair.name] = bundle
    return bundles


def case_document(pair: JudgedPair, result: GateResult) -> dict[str, Any]:
    """The pair as a regression case holding the head to the base's outcome: it fails on the head's
    build and passes on the base's (the pytest plugin flies it)."""
    head = pair.differential["subject"][0]
    return {
        "format": FORMAT, "name": pair.name, "expect": "as_reference", "seed": pair.seed, "sut": result.head.sut.identity(),
        "found": {"by": "stella gate", "origin": pair.origin, "status": head["status"], "fitness": head["fitness"], "min_clearance_m": head["min_clearance_m"],
                  "log": head.get("log_path"), "base": result.base.described, "head": result.head.described,
                  **({"store": pair.store, "evaluation": pair.evaluation.id} if pair.evaluation is not None else {})},
        "note": f"{EXPECTATIONS['as_reference']}; {pair.judgement.kind}: {pair.judgement.why}",
        "concrete_scenario": pair.concrete,
        "reference": reference_entry(pair.differential, "unsafe" if pair.judgement.kind == "unsafe" else "behaviour"),
    }


def _case_files(pair: JudgedPair, result: GateResult, folder: Path) -> tuple[Path, Path]:
    """The pair's regression case, concrete scenario and both sides' logs into folder."""
    folder.mkdir(parents=True, exist_ok=True)
    case = folder / f"case{SUFFIX}"
    case.write_text(json.dumps(case_document(pair, result), indent=2) + "\n")
    concrete = folder / "concrete.json"
    concrete.write_text(json.dumps(pair.concrete, indent=2) + "\n")
    for side, log in (("head", pair.head_log), ("base", pair.base_log)):
        if log and Path(log).is_file():
            shutil.copyfile(log, folder / f"{side}.mcap")
    return case, concrete


def _bundle(pair: JudgedPair, result: GateResult, folder: Path) -> None:
    case, concrete = _case_files(pair, result, folder)
    lines = [f"# {pair.name}: {KIND_WORDS[pair.judgement.kind]}", "", pair.judgement.why, "",
             f"* base ({result.base.described}): {_flights(pair.differential['reference'])}",
             f"* head ({result.head.described}): {_flights(pair.differential['subject'])}", ""]
    if (folder / "head.mcap").is_file():
        plot(folder / "head.mcap", folder / "flight.png")
        try:
            explanation = explain(folder / "head.mcap")
        except InputError as refused:  # a flight cut short records no closest approach to explain
            lines += [f"No explanation: {refused}", ""]
        else:
            (folder / "explanation.txt").write_text(explain_text(explanation) + "\n")
            if explanation["mechanism"] != "none":
                lines += [f"Mechanism of the head's closest approach: {explanation['mechanism']}", ""]
    lines += ["Fly it again (both sides), or as a test (fails on the head, passes on the base):", "", "```",
              *fly_again_commands(pair, result, concrete, case), "```", ""]
    shrunk = result.shrunk
    if shrunk is not None and shrunk.of == pair.name:
        lines += shrunk_lines(shrunk, result, folder, folder)
    (folder / "FINDING.md").write_text("\n".join(lines))


def shrunk_lines(shrunk: Shrunk, result: GateResult, bundle: Path, relative_to: Path) -> list[str]:
    """The shrink's outcome in words; its case written into the bundle's shrunk/ (once)."""
    if shrunk.pair is None:
        why = shrunk.stopped or "no step kept it regressing"
        return [f"Not shrunk: {why} ({shrunk.flown} pairs flown).", ""]
    folder = bundle / "shrunk"
    if not folder.is_dir():
        _case_files(shrunk.pair, result, folder)
    where = folder.relative_to(relative_to) if folder.is_relative_to(relative_to) else folder
    lines = [f"Shrunk in {len(shrunk.kept)} step{'s' * (len(shrunk.kept) != 1)} of {shrunk.tried} tried ({shrunk.flown} pairs flown"
             + (f"; stopped early: {shrunk.stopped}" if shrunk.stopped else "") + f"), still: {KIND_WORDS[shrunk.pair.judgement.kind]}: "
             f"{shrunk.pair.judgement.why}:", ""]
    lines += [f"{number}. {step}" for number, step in enumerate(shrunk.kept, start=1)]
    lines += ["", "```", *fly_again_commands(shrunk.pair, result, where / "concrete.json", where / f"case{SUFFIX}"), "```", ""]
    return lines


# -- summary -----------------------------------------------------------------------------------


def _verdict_line(result: GateResult) -> str:
    regressions = result.regressions
    if regressions:
        return f"## stella gate: FAILED. The head is less safe than its base: {len(regressions)} confirmed regression{'s' * (len(regressions) > 1)}"
    if result.identical:
        return "## stella gate: passed. The head builds to the same program as its base"
    return "## stella gate: passed. No regression found in what was covered (below)"


IDENTICAL = ("The two builds load the same machine code and data, and read the same start-up scripts and modules (debug information, "
             "build IDs, time stamps and line numbers aside), so no flight can tell them apart: nothing was flown. "
             "`--fly-identical` flies them all the same.")


def summary_markdown(result: GateResult, bundles: Mapping[str, Path], out_dir: Path) -> str:
    lines = [_verdict_line(result), "",
             "| | build |", "| --- | --- |", f"| base | {result.base.described} |", f"| head | {result.head.described} |", ""]
    if result.base.built_by and result.head.built_by:
        lines += ["The commands below fly the builds in this gate's cache; elsewhere, build each side first (each prints the folder to "
                  "give in their place):", "", "```", f"{result.base.built_by}   # base", f"{result.head.built_by}   # head", "```", ""]
    for number, pair in enumerate(result.regressions, start=1):
        lines.append(f"### {number}. {pair.name} ({'suite case' if pair.origin == 'suite' else 'found searching ' + pair.origin}): "
                     f"{KIND_WORDS[pair.judgement.kind]}")
        lines += ["", pair.judgement.why, "", "| side | outcome |", "| --- | --- |",
                  f"| base | {_flights(pair.differential['reference'])} |", f"| head | {_flights(pair.differential['subject'])} |", ""]
        bundle = bundles.get(pair.name)
        if bundle is None:
            lines += [f"(no bundle: the gate writes the worst {result.plan.max_findings}; the case is in `{pair.store or 'the suite'}`)", ""]
            continue
        explained = bundle / "explanation.txt"
        if explained.is_file():
            mechanism = next((line for line in explained.read_text().splitlines() if line.startswith("mechanism: ")), None)
            if mechanism and mechanism != "mechanism: none":
                lines += [f"Mechanism (head): {mechanism.removeprefix('mechanism: ')}", ""]
        relative = bundle.relative_to(out_dir)
        lines += ["```", *fly_again_commands(pair, result, relative / "concrete.json", relative / f"case{SUFFIX}"), "```", "",
                  f"Bundle: [{relative}/]({relative}/FINDING.md) in the gate's output (the CI job's artifact): case, both logs, plot, explanation", ""]
        if result.shrunk is not None and result.shrunk.of == pair.name:
            lines += shrunk_lines(result.shrunk, result, bundle, out_dir)
    if result.identical:
        lines += [IDENTICAL, ""]
    else:
        lines += ["### Covered", ""] + coverage_lines(result)
    return "\n".join(lines) + "\n"


def coverage_lines(result: GateResult) -> list[str]:
    lines = []
    if result.plan.suite:
        counts = _counts(result.suite)
        lines.append(f"* suite: {len(result.suite)} case{'s' * (len(result.suite) != 1)} flown on both sides ({counts})")
        lines += [f"  * {pair.name}: {pair.judgement.verdict}" + (f" ({pair.judgement.kind})" if pair.judgement.kind else "") + f": {pair.judgement.why}"
                  for pair in result.suite if pair.judgement.verdict in (CHANGE, UNJUDGED)]
    for covered in result.searches:
        name = Path(covered.scenario).name
        if covered.store is None:
            lines.append(f"* search {name}: {covered.stopped}")
            continue
        found = [p for p in result.searched if p.store == covered.store]
        lines.append(f"* search {name}: {covered.evaluated}" + (f" of {covered.budget}" if covered.budget else "") + f" candidates, {len(found)} flown on both sides "
                     f"({_counts(found)}), {covered.wall_s:.0f} s" + (f"; {covered.stopped}" if covered.stopped else ""))
    plan = result.plan
    budget = [f"{plan.budget_flights} search candidates"] if plan.budget_flights is not None else []
    budget += [f"{plan.budget_minutes:g} minutes"] if plan.budget_minutes is not None else []
    lines.append(f"* took {result.wall_s / 60:.1f} minutes" + (f" of a budget of {' and '.join(budget)}" if budget else "")
                 + (f"; pairs that differed flown {plan.confirm} more times on each side" if plan.confirm else "; pairs that differed not flown again (confirm 0)")
                 + (f", regressions verified over {plan.verify_flights} flights a side" if plan.verify_flights > 1 else "")
                 + f"; drive {plan.drive or 'as each scenario says'}")
    for pair in result.not_held:
        lines.append(f"* did not hold over {plan.verify_flights} flights a side, so not counted: {pair.name} ({pair.judgement.why})")
    if result.unverified:
        lines.append(f"* judged regressions on their first flights but not verified (the budget, or {plan.max_findings} held already): "
                     + ", ".join(pair.name for pair in result.unverified))
    lines.append("* a regression: the head violates where the base keeps the safety distance, comes closer than the base beyond the base's "
                 f"spread{f' and {plan.closer_m:g} m' if plan.closer_m else ''}, ends worse (e.g. blocked where the base completes), "
                 "or cannot finish its flight where the base can")
    return lines


def _counts(pairs: list[JudgedPair]) -> str:
    tally: dict[str, int] = {}
    for pair in pairs:
        tally[pair.judgement.verdict] = tally.get(pair.judgement.verdict, 0) + 1
    return ", ".join(f"{count} {verdict}" for verdict, count in sorted(tally.items())) or "none"


# -- JUnit -------------------------------------------------------------------------------------


def junit(result: GateResult) -> ET.Element:
    suites = ET.Element("testsuites", name="stella gate")
    suite = ET.SubElement(suites, "testsuite", name="stella gate", time=f"{result.wall_s:.1f}")
    properties = ET.SubElement(suite, "properties")
    for name, side in (("base", result.base), ("head", result.head)):
        ET.SubElement(properties, "property", name=f"stella_{name}", value=side.described)
    counted = {"tests": 0, "failures": 0, "errors": 0, "skipped": 0}
    regressions = {content_key(p.concrete) for p in result.regressions}

    def case(classname: str, name: str) -> ET.Element:
        counted["tests"] += 1
        return ET.SubElement(suite, "testcase", classname=classname, name=name)

    if result.identical:
        case("stella.gate", "the head builds to the same program as its base")
    for pair in result.suite:
        test = case("stella.gate.suite", pair.name)
        if pair.judgement.verdict == REGRESSION and content_key(pair.concrete) in regressions:
            counted["failures"] += 1
            failure = ET.SubElement(test, "failure", message=f"{pair.judgement.kind}: {pair.judgement.why}")
            failure.text = f"base: {_flights(pair.differential['reference'])}\nhead: {_flights(pair.differential['subject'])}"
        elif pair.judgement.verdict == UNJUDGED:
            counted["errors"] += 1
            ET.SubElement(test, "error", message=pair.judgement.why)
    for covered in result.searches:
        test = case("stella.gate.search", Path(covered.scenario).name)
        if covered.store is None:
            counted["skipped"] += 1
            ET.SubElement(test, "skipped", message=covered.stopped or "")
            continue
        found = [p for p in result.regressions if p.store == covered.store]
        if found:
            counted["failures"] += 1
            failure = ET.SubElement(test, "failure", message=f"{len(found)} regression{'s' * (len(found) > 1)} found; the worst, "
                                                             f"{found[0].judgement.kind}: {found[0].judgement.why}")
            failure.text = "\n".join(f"{p.name}: {p.judgement.kind}: {p.judgement.why}" for p in found)
    for element in (suites, suite):
        element.attrib.update({key: str(value) for key, value in counted.items()})
    return suites


def as_dict(result: GateResult, bundles: Mapping[str, Path]) -> dict[str, Any]:
    def pair_dict(pair: JudgedPair) -> dict[str, Any]:
        return {"name": pair.name, "origin": pair.origin, "verdict": pair.judgement.verdict, "kind": pair.judgement.kind, "why": pair.judgement.why,
                "base": pair.differential["reference"], "head": pair.differential["subject"],
                **({"bundle": str(bundles[pair.name])} if pair.name in bundles else {}),
                **({"store": pair.store, "evaluation": pair.evaluation.id} if pair.evaluation is not None else {})}

    return {"passed": result.passed, "identical": result.identical, "base": result.base.__dict__ | {"sut": result.base.sut.identity()},
            "head": result.head.__dict__ | {"sut": result.head.sut.identity()}, "wall_s": result.wall_s,
            "regressions": [pair_dict(p) for p in result.regressions], "not_held": [pair_dict(p) for p in result.not_held],
            "unverified": [pair_dict(p) for p in result.unverified], "suite": [pair_dict(p) for p in result.suite],
            "searches": [c.__dict__ for c in result.searches],
            "search_pairs": {"flown": len(result.searched), "by_verdict": _counts(result.searched)},
            "shrunk": None if result.shrunk is None else {"of": result.shrunk.of, "kept": list(result.shrunk.kept), "tried": result.shrunk.tried,
                                                          "flown": result.shrunk.flown, "stopped": result.shrunk.stopped,
                                                          "pair": pair_dict(result.shrunk.pair) if result.shrunk.pair else None}}
