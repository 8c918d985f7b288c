"""A campaign's findings as bug-report bundles (`stella export-findings DB --out DIR`): one folder
per failure mode (harness/campaigns/triage.py), for its worst violation, holding what a firmware
developer needs to see, rerun and keep the failure:

* `concrete.json`: the concrete scenario; `case.regression.json`: the same as a regression case
  that pytest flies (it expects the flight to be safe, so it fails while the failure is there);
* `flight.mcap`: the harness's log (Foxglove opens it); `sut/`: the SUT's own logs and console
  (PX4's ULog, ArduPilot's dataflash .BIN, the bundled autopilot's record), as the flight kept them;
* `flight.png`: the top view of the trajectory with the obstacles and the clearance over time;
* `explanation.txt` (and `.json`): `stella explain`'s timeline of the closest approach and its
  mechanism, with the numbers behind it;
* `FINDING.md`: what happened, the command that flies it again, the command that shrinks it, and
  the SUT's identity (the build's digest and `git describe` where its tree is known, the
  parameters the campaign set);
* with `--shrink`, `shrunk/`: the smallest version that still violates (`stella shrink`).

A campaign that searched safety properties gets one bundle per mode of the flights that broke
them (harness/campaigns/triage.py): its case keeps the properties, and `properties.json` (each
property's verdict and robustness) stands in for the explanation of a closest approach.

`FINDINGS.md` in DIR lists the modes, most frequent first.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any, Mapping

from harness.campaigns.explain import explain, explain_text
from harness.campaigns.regression import SUFFIX, case_document, case_name
from harness.campaigns.store import Store, StoredEvaluation
from harness.campaigns.triage import FailureMode, triage
from harness.errors import InputError, Problem
from harness.flight.inspect_log import plot
from harness.flight.logs import slug
from harness.properties.spec import LIBRARY


def export_findings(store_path: Path, out_dir: Path) -> list[tuple[Path, int]]:
    """One bundle per failure mode of the campaign's violations (revealing cases, for a
    differential campaign): each bundle's folder and the store's id of the evaluation in it, most
    frequent mode first."""
    report = triage(store_path)
    if not report.modes:
        raise InputError([Problem(str(store_path), "", "no violation with a log to export: nothing was found, or the logs were deleted "
                                                       "(`stella triage` lists what it skipped)")])
    with Store.existing(store_path) as store:
        sut = store.campaign_sut()
        sources = store.campaign_sources()
        config = store.campaign_config()
        worst = [store.evaluation(mode.worst.id) for mode in report.modes]
    out_dir.mkdir(parents=True, exist_ok=True)
    folders = []
    for number, (mode, case) in enumerate(zip(report.modes, worst), start=1):
        folder = out_dir / f"{number:02d}-{slug(mode.mode)[:80]}"
        folder.mkdir(exist_ok=True)
        _bundle(folder, mode, case, sut, sources, config, store_path)
        folders.append(folder)
    what, worst_column = ("flights breaking a property", "least robustness") if report.by_properties else ("violations", "worst f")
    index = ["# Findings", "", f"From `{store_path}`: {report.violations} {what} in {len(report.modes)} failure modes.", "",
             f"| # | failure mode | {what} | contacts | {worst_column} | folder |", "| --- | --- | --- | --- | --- | --- |"]
    index += [f"| {n} | {m.mode} | {m.count} | {m.contacts} | {m.worst.robustness if m.worst.robustness is not None else m.worst.fitness:.3f} "
              f"| [{f.name}]({f.name}/FINDING.md) |" for n, (m, f) in enumerate(zip(report.modes, folders), start=1)]
    (out_dir / "FINDINGS.md").write_text("\n".join(index) + "\n")
    return [(folder, case.id) for folder, case in zip(folders, worst)]


def _bundle(folder: Path, mode: FailureMode, case: StoredEvaluation | None, sut: Mapping[str, Any], sources: Mapping[str, Any],
            config: Mapping[str, Any], store_path: Path) -> None:
    if case is None or case.concrete is None or not case.log_path:
        raise InputError([Problem(str(store_path), "", f"the worst violation of mode {mode.mode!r} has no concrete scenario or log")])
    log = Path(case.log_path)
    name = case_name(case)
    regression = folder / f"case{SUFFIX}"
    # A differential campaign's case holds the subject to the reference's clearance instead.
    expect = "as_reference" if "reference" in config else "safe"
    document = case_document(name, case, sut, store_path, expect)
    if config.get("properties"):  # the case judges what the campaign did
        document["properties"] = config["properties"]
    regression.write_text(json.dumps(document, indent=2) + "\n")
    (folder / "concrete.json").write_text(json.dumps(case.concrete, indent=2) + "\n")
    shutil.copyfile(log, folder / "flight.mcap")
    artifacts = log.with_suffix(".artifacts")
    if artifacts.is_dir():
        shutil.copytree(artifacts, folder / "sut", dirs_exist_ok=True)
    plot(log, folder / "flight.png")
    if "broken" in mode.keys:
        (folder / "properties.json").write_text(json.dumps(case.properties, indent=2) + "\n")
    else:
        explanation = explain(log)
        (folder / "explanation.txt").write_text(explain_text(explanation) + "\n")
        (folder / "explanation.json").write_text(json.dumps(explanation, indent=2, default=str) + "\n")
    sut_files = sorted(str(path.relative_to(folder)) for path in (folder / "sut").rglob("*") if path.is_file()) if (folder / "sut").is_dir() else []
    (folder / "FINDING.md").write_text(_finding_text(mode, case, sut, sources, config, regression.name, sut_files, str(store_path.resolve()),
                                                     " ".join(f"--property {given}" for given in judged_by(config.get("properties", []), folder)),
                                                     " ".join(f"--property {given}" for given in judged_by(broken_by(case, config), folder))))


def broken_by(case: StoredEvaluation, config: Mapping[str, Any]) -> list[Mapping[str, Any]]:
    """The campaign's properties this flight broke: what a shrink of it keeps broken (a shrink
    with several properties keeps each of them broken)."""
    return [prop for prop in config.get("properties", []) if case.properties.get(prop["name"], {}).get("verdict") == "violated"]


def judged_by(properties: list[Mapping[str, Any]], folder: Path) -> list[str]:
    """What --property takes to judge a flight as the campaign did: a named property's name, or
    the path (relative to the bundle) of one of the user's, written beside it (properties/NAME.json)."""
    given = []
    for prop in properties:
        if prop["name"] in LIBRARY and LIBRARY[prop["name"]].as_dict() == prop:
            given.append(prop["name"])
            continue
        path = folder / "properties" / f"{slug(prop['name'])}.json"
        path.parent.mkdir(exist_ok=True)
        path.write_text(json.dumps(prop, indent=2) + "\n")
        given.append(str(path.relative_to(folder)))
    return given


def _sut_options(sut: Mapping[str, Any], build: Mapping[str, Any], prefix: str = "") -> str:
    """The command-line options that name this SUT (prefix "reference-" for a reference); a
    build whose path the store does not hold (made before it kept one) is left to fill in."""
    options = [] if sut["name"] == "bundled" and not prefix else [f"--{prefix}sut {sut['name']}"]
    placeholder = "REFERENCE_BUILD" if prefix else "SUBJECT_BUILD"
    if "px4_sha256" in build:
        options.append(f"--{prefix}px4-bin {build.get('path', placeholder)}")
    if "ardupilot_sha256" in build:
        options.append(f"--{prefix}ardupilot-bin {build.get('path', placeholder)}")
    if sut.get("fault"):
        options.append(f"--{prefix}sut-fault {sut['fault']}")
    options += [f"--{prefix}sut-param {name}={value}" for name, value in sorted(sut.get("params", {}).items())]
    return " ".join(options)


def _identity(title: str, sut: Mapping[str, Any], build: Mapping[str, Any]) -> list[str]:
    lines = [f"* {title}: {sut['name']}" + (f", seeded fault {sut['fault']}" if sut.get("fault") else "")]
    for key, label in (("px4_sha256", "PX4 binary sha256"), ("ardupilot_sha256", "ArduCopter binary sha256"), ("path", "build"),
                       ("git_describe", "`git describe` of its tree")):
        if key in build:
            lines.append(f"  * {label}: `{build[key]}`")
    params = sut.get("params", {})
    lines.append("  * parameters the campaign set (the adapter's own defaults aside): "
                 + (", ".join(f"`{k}={v}`" for k, v in sorted(params.items())) if params else "none"))
    return lines


def _finding_text(mode: FailureMode, case: StoredEvaluation, sut: Mapping[str, Any], sources: Mapping[str, Any], config: Mapping[str, Any],
                  regression: str, sut_files: list[str], store_hint: str, judged: str = "", shrunk_by: str = "") -> str:
    # Stores made before the sources kept the builds still have their digests in the identity.
    build = sources.get("sut_build") or config.get("subject", {})
    options = subject_options = _sut_options(sut, build)
    clearance = f"{case.min_clearance_m:.2f} m" if case.min_clearance_m is not None else "none recorded"
    identity = _identity("SUT" if "reference" not in config else "subject", sut, build)
    outcome = f"fitness {case.fitness:.3f}, least clearance {clearance}" + (f": {case.why}" if case.why else "")
    expectation = "fails while the SUT violates the safety distance here"
    by_properties = "broken" in mode.keys
    if by_properties:
        outcome = f"least robustness {mode.worst.robustness:.3f}, breaking {mode.keys['broken']}; {case.status}" + (f": {case.why}" if case.why else "")
        expectation = "fails while the SUT breaks one of the properties here"
    detail = ([f"* broken: {mode.keys['broken']}; injected: {mode.keys['failures']}; {mode.keys['wind']}; {mode.keys['visibility']}",
               "* `properties.json`: each property's verdict and robustness (`stella inspect flight.mcap " + judged + "` gives them again from the log)"]
              if by_properties else
              ["* obstacle: " + str(mode.keys["obstacle"]) + "; approach: " + str(mode.keys["approach"]) + "; phase: " + str(mode.keys["phase"])
               + "; closing speed: " + str(mode.keys["speed"]) + "; " + str(mode.keys["wind"]) + "; " + str(mode.keys["visibility"]),
               "* `explanation.txt`: why it failed (`stella explain`): the timeline of the closest approach and the mechanism, with its evidence"])
    flights = "flights breaking a property" if by_properties else "violations"
    if "reference" in config:
        reference = config["reference"]
        reference_build = sources.get("reference_build") or reference
        options += " " + _sut_options(reference, reference_build, prefix="reference-") + f" --confirm {max(1, config.get('confirm', 0))}"
        identity += _identity("reference", reference, reference_build)
        outcome = f"least clearance {clearance}" + (f" ({case.why})" if case.why else "") + f"; against the reference: {case.differential['why']}"
        expectation = "fails unless the SUT keeps the reference's clearance here (run it with either build)"
    return "\n".join([
        f"# {mode.mode}",
        "",
        f"{mode.count} {flights} of this mode in the campaign ({mode.contacts} contacts, {mode.near_misses} near misses). "
        f"The worst: scenario {case.scenario!r}, evaluation {case.id}, found by {case.algorithm} (run {case.run_index}), "
        f"{outcome}.",
        "",
        *detail,
        "* `flight.png`: the trajectory from above, with the obstacles, and the clearance over time",
        "* `flight.mcap`: the flight's log (open it in Foxglove; `stella inspect flight.mcap`)",
        ("* the SUT's own logs and console: " + ", ".join(f"`{name}`" for name in sut_files) if sut_files
         else "* the SUT's own state: the bundled autopilot's (collision prevention, setpoints) is recorded in `flight.mcap`" if sut["name"] == "bundled"
         else "* the SUT kept no logs of its own for this flight"),
        "",
        "## Fly it again",
        "",
        "```",
        f"stella run --concrete concrete.json --seed {case.seed} {options} {judged}".rstrip(),
        f"pytest {regression}    # the regression case: {expectation}",
        "```",
        "",
        "## Shrink it",
        "",
        "The smallest, simplest version of this scenario that still violates (docs/shrink.md; `export-findings --shrink` runs it into `shrunk/`):",
        "",
        "```",
        f"stella shrink {store_hint} --evaluation {case.id} --out shrunk {subject_options} {shrunk_by}".rstrip(),
        "```",
        "",
        "## The SUT" + ("s" if "reference" in config else ""),
        "",
        *identity,
        "",
    ])
