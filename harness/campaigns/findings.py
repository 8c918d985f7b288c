"""A campaign's findings as bug-report bundles (`stella export-findings DB --out DIR`): one folder
per failure mode (harness/campaigns/triage.py), for its worst violation, holding what a firmware
developer needs to see, rerun and keep the failure:

* `concrete.json`: the concrete scenario; `case.regression.json`: the same as a regression case
  that pytest flies (it expects the flight to be safe, so it fails while the failure is there);
* `flight.mcap`: the harness's log (Foxglove opens it); `sut/`: the SUT's own logs and console
  (PX4's ULog, ArduPilot's dataflash .BIN, the bundled autopilot's record), as the flight kept them;
* `flight.png`: the top view of the trajectory with the obstacles and the clearance over time;
* `FINDING.md`: what happened, the command that flies it again, the command that shrinks it, and
  the SUT's identity (the build's digest and `git describe` where its tree is known, the
  parameters the campaign set);
* with `--shrink`, `shrunk/`: the smallest version that still violates (`stella shrink`).

`FINDINGS.md` in DIR lists the modes, most frequent first.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any, Mapping

from harness.campaigns.regression import SUFFIX, case_document
from harness.campaigns.store import Store, StoredEvaluation
from harness.campaigns.triage import triage
from harness.errors import InputError, Problem
from harness.flight.inspect_log import plot
from harness.flight.logs import slug


def export_findings(store_path: Path, out_dir: Path) -> list[tuple[Path, int]]:
    """One bundle per failure mode of the campaign's violations (revealing cases, for a
    differential campaign): each bundle's folder and the store's id of the evaluation in it, most
    frequent mode first."""
    report = triage(store_path)
    if not report["modes"]:
        raise InputError([Problem(str(store_path), "", "no violation with a log to export: nothing was found, or the logs were deleted "
                                                       "(`stella triage` lists what it skipped)")])
    with Store.existing(store_path) as store:
        sut = store.campaign_sut()
        sources = store.campaign_sources()
        worst = [store.evaluation(mode["worst"]["id"]) for mode in report["modes"]]
    out_dir.mkdir(parents=True, exist_ok=True)
    folders = []
    for number, (mode, case) in enumerate(zip(report["modes"], worst), start=1):
        folder = out_dir / f"{number:02d}-{slug(mode['mode'])[:80]}"
        folder.mkdir(exist_ok=True)
        _bundle(folder, mode, case, sut, sources, store_path)
        folders.append(folder)
    index = ["# Findings", "", f"From `{store_path}`: {report['violations']} violations in {len(report['modes'])} failure modes.", "",
             "| # | failure mode | violations | contacts | worst f | folder |", "| --- | --- | --- | --- | --- | --- |"]
    index += [f"| {n} | {m['mode']} | {m['count']} | {m['contacts']} | {m['worst']['fitness']:.3f} | [{f.name}]({f.name}/FINDING.md) |"
              for n, (m, f) in enumerate(zip(report["modes"], folders), start=1)]
    (out_dir / "FINDINGS.md").write_text("\n".join(index) + "\n")
    return [(folder, case.id) for folder, case in zip(folders, worst)]


def _bundle(folder: Path, mode: Mapping[str, Any], case: StoredEvaluation | None, sut: Mapping[str, Any], sources: Mapping[str, Any],
            store_path: Path) -> None:
    if case is None or case.concrete is None or not case.log_path:
        raise InputError([Problem(str(store_path), "", f"the worst violation of mode {mode['mode']!r} has no concrete scenario or log")])
    log = Path(case.log_path)
    name = slug(f"{Path(case.scenario_file).stem}-{case.algorithm}-run{case.run_index}-eval{case.ordinal}")
    regression = folder / f"case{SUFFIX}"
    regression.write_text(json.dumps(case_document(name, case, sut, store_path, "safe"), indent=2) + "\n")
    (folder / "concrete.json").write_text(json.dumps(case.concrete, indent=2) + "\n")
    shutil.copyfile(log, folder / "flight.mcap")
    artifacts = log.with_suffix(".artifacts")
    if artifacts.is_dir():
        shutil.copytree(artifacts, folder / "sut", dirs_exist_ok=True)
    plot(log, folder / "flight.png")
    sut_files = sorted(str(path.relative_to(folder)) for path in (folder / "sut").rglob("*") if path.is_file()) if (folder / "sut").is_dir() else []
    (folder / "FINDING.md").write_text(_finding_text(mode, case, sut, sources, regression.name, sut_files, str(store_path.resolve())))


def _sut_options(sut: Mapping[str, Any], build: Mapping[str, Any]) -> str:
    options = [] if sut["name"] == "bundled" else [f"--sut {sut['name']}"]
    if "px4_sha256" in build:
        options.append(f"--px4-bin {build.get('path', 'PATH')}")
    if "ardupilot_sha256" in build:
        options.append(f"--ardupilot-bin {build.get('path', 'PATH')}")
    if sut.get("fault"):
        options.append(f"--sut-fault {sut['fault']}")
    options += [f"--sut-param {name}={value}" for name, value in sorted(sut.get("params", {}).items())]
    return " ".join(options)


def _finding_text(mode: Mapping[str, Any], case: StoredEvaluation, sut: Mapping[str, Any], sources: Mapping[str, Any], regression: str,
                  sut_files: list[str], store_hint: str) -> str:
    build = sources.get("sut_build", {})
    options = _sut_options(sut, build)
    clearance = f"{case.min_clearance_m:.2f} m" if case.min_clearance_m is not None else "none recorded"
    identity = [f"* SUT: {sut['name']}" + (f", seeded fault {sut['fault']}" if sut.get("fault") else "")]
    for key, label in (("px4_sha256", "PX4 binary sha256"), ("ardupilot_sha256", "ArduCopter binary sha256"), ("path", "build"),
                       ("git_describe", "`git describe` of its tree")):
        if key in build:
            identity.append(f"* {label}: `{build[key]}`")
    params = sut.get("params", {})
    identity.append("* parameters the campaign set (the adapter's own defaults aside): "
                    + (", ".join(f"`{k}={v}`" for k, v in sorted(params.items())) if params else "none"))
    return "\n".join([
        f"# {mode['mode']}",
        "",
        f"{mode['count']} violations of this mode in the campaign ({mode['contacts']} contacts, {mode['near_misses']} near misses). "
        f"The worst: scenario {case.scenario!r}, found by {case.algorithm} (run {case.run_index}, evaluation {case.ordinal}), "
        f"fitness {case.fitness:.3f}, least clearance {clearance}" + (f": {case.why}" if case.why else "") + ".",
        "",
        "* obstacle: " + str(mode["obstacle"]) + "; approach: " + str(mode["approach"]) + "; phase: " + str(mode["phase"])
        + "; closing speed: " + str(mode["speed"]) + "; " + str(mode["wind"]) + "; " + str(mode["visibility"]),
        "* `flight.png`: the trajectory from above, with the obstacles, and the clearance over time",
        "* `flight.mcap`: the flight's log (open it in Foxglove; `stella inspect flight.mcap`)",
        ("* the SUT's own logs and console: " + ", ".join(f"`{name}`" for name in sut_files) if sut_files
         else "* the SUT's own state: the bundled autopilot's (collision prevention, setpoints) is recorded in `flight.mcap`" if sut["name"] == "bundled"
         else "* the SUT kept no logs of its own for this flight"),
        "",
        "## Fly it again",
        "",
        "```",
        f"stella run --concrete concrete.json --seed {case.seed} {options}".rstrip(),
        f"pytest {regression}    # the regression case: fails while the SUT violates the safety distance here",
        "```",
        "",
        "## Shrink it",
        "",
        "The smallest, simplest version of this scenario that still violates (docs/shrink.md; `export-findings --shrink` runs it into `shrunk/`):",
        "",
        "```",
        f"stella shrink {store_hint} --evaluation {case.id} --out shrunk {options}".rstrip(),
        "```",
        "",
        "## The SUT",
        "",
        *identity,
        "",
    ])
