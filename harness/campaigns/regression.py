"""Regression cases: concrete scenarios a campaign found, kept as files and flown again as tests.

A case file (`NAME.regression.json`, schema `regression.schema.json`) holds the concrete
scenario (which embeds its logical scenario and profile), the flight seed, the SUT and what is
expected: `safe` (the SUT keeps the safety distance and completes the mission: a fixed fault
stays fixed), `kept` (it keeps the safety distance, whether or not it completes the mission: a
flight collision prevention rightly blocks) or `violation` (a known violation still reproduces). The pytest plugin collects
these files; `verdict` is the judgement both it and `stella` use.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from harness.campaigns.problem import least_robustness
from harness.campaigns.store import Store, StoredEvaluation, evaluation_name
from harness.errors import InputError, Problem
from harness.flight.differential import CLEARANCE_RESOLUTION_M, TIME_RESOLUTION_S, Difference, Outcome, compare, flight_times
from harness.flight.evaluation import infeasible
from harness.flight.results import EvaluationResult
from harness.flight.fitness import Status
from harness.flight.logs import slug
from harness.properties.spec import Property, property_from
from harness.scenario.documents import load_json, schema_problems
from harness.scenario.space import SearchSpace
from harness.scenario.world import load_concrete, space_from_concrete, space_with_rig, with_drive_recorded
from sut_adapter import SutConfig

FORMAT = "stella.regression/1"
SUFFIX = ".regression.json"
EXPECTATIONS = {
    "safe": "must keep the safety distance and complete the mission",
    "kept": "must keep the safety distance, whether or not it completes the mission",
    "violation": "the known violation must still reproduce",
    "as_reference": "must do at least as well as the reference build did",
}


@dataclass(frozen=True)
class Regression:
    path: Path
    name: str
    expect: str
    seed: int
    sut: SutConfig  # as the case names it: its name, parameters and seeded fault
    concrete: Mapping[str, Any]
    found: Mapping[str, Any]
    space: SearchSpace
    x: np.ndarray
    reference: Mapping[str, Any] | None = None  # expect as_reference: what the reference did
    properties: tuple[Property, ...] = ()  # safety properties judged besides the safety distance

    @property
    def safety_distance_m(self) -> float:
        return self.space.profile.safety_distance_m


def load_regression(path: Path, drive: str | None = None) -> Regression:
    """A regression case; `drive` flies it with another drive than it was found with."""
    document = load_json(path)
    problems = schema_problems(document, "regression", str(path))
    if problems:
        raise InputError(problems)
    concrete = with_drive_recorded(document["concrete_scenario"], drive)
    try:
        space = space_from_concrete(concrete, str(path), drive)
        x = space.from_concrete(concrete, str(path))
        if drive is not None:
            concrete = space.to_concrete(x)
    except InputError as error:
        raise InputError([Problem(p.file, "/concrete_scenario" + p.pointer, p.message) for p in error.problems]) from None
    properties = tuple(property_from(prop, str(path), f"/properties/{index}") for index, prop in enumerate(document.get("properties", [])))
    return Regression(path, document["name"], document["expect"], document["seed"],
                      SutConfig(document["sut"]["name"], dict(document["sut"].get("params", {})), document["sut"].get("fault")), concrete, document.get("found", {}), space, x,
                      document.get("reference"), properties)


def suite_cases(paths: Sequence[str], drive: str | None, rig: str | None = None) -> list[tuple[str, Any, Any, int]]:
    """(name, space, vector, seed) of each case: regression cases (their seed) and concrete
    scenarios (seed 0), a folder standing for the cases in it; each flown with `rig`'s range
    sensors (a preset or file, `--rig`) if given."""
    files: list[Path] = []
    for given in map(Path, paths):
        if given.is_dir():
            inside = sorted([*given.glob(f"*{SUFFIX}"), *(p for p in given.glob("*.json") if not p.name.endswith(SUFFIX))])
            if not inside:
                raise InputError([Problem(str(given), "", f"no regression cases (*{SUFFIX}) or concrete scenarios (*.json) in this folder")])
            files += inside
        else:
            files.append(given)
    cases = []
    for path in files:
        if path.name.endswith(SUFFIX):
            regression = load_regression(path, drive)
            space, x, seed = regression.space, regression.x, regression.seed
        else:
            space, x = load_concrete(path, drive)
            seed = 0
        if rig is not None:
            space = space_with_rig(space, rig)
        refused = infeasible(space, x, seed=seed, sut="suite")
        if refused is not None:
            raise InputError([Problem(str(path), "", f"the case is infeasible ({refused.why}): it can tell no two builds apart; drop it")])
        cases.append((slug(path.name.removesuffix(SUFFIX).removesuffix(".json")), space, x, seed))
    names = [name for name, *_ in cases]
    doubled = sorted({name for name in names if names.count(name) > 1})
    if doubled:
        raise InputError([Problem("--suite", "", f"two cases are named {doubled[0]}: rename one, a case's name is its test's")])
    return cases


def describe(result: EvaluationResult, safety_distance_m: float) -> str:
    """What happened in one flight, in the words the failure messages use."""
    text = f"status {result.status}, fitness {result.fitness:.3f}"
    if result.min_clearance_m is not None:
        relation = "<" if result.min_clearance_m < safety_distance_m else ">="
        inside = " (inside the obstacle)" if result.min_clearance_m < 0 else ""
        text += (f"; min clearance {result.min_clearance_m:.3f} m{inside} {relation} safety distance {safety_distance_m:.3f} m"
                 f" at t={result.min_clearance_at_s:.2f} s to {result.min_clearance_obstacle}")
    if result.why:
        text += f" ({result.why})"
    if result.log_path:
        text += f"; log: {result.log_path}"
    return text


def verdict(expect: str, result: EvaluationResult, safety_distance_m: float, reference: Mapping[str, Any] | None = None) -> str | None:
    """None when the flight meets the expectation, else the failure message. The safety
    properties the flight was scored on count as the safety distance does: `safe` keeps every
    one, `violation` still breaks the distance or one of them."""
    what = describe(result, safety_distance_m)
    broken = [f"property {name} violated: robustness {scored['robustness']:.3f} {scored['unit']}"
              for name, scored in result.properties.items() if scored["verdict"] == "violated"]
    if expect == "as_reference":
        return _as_reference(result, reference or {}, what)
    if expect in ("safe", "kept"):
        if (result.status == Status.OK or expect == "kept" and result.status == Status.MISSION_FAILED) and not broken:
            return None
        if result.status == Status.VIOLATION:
            return f"safety distance violated: {what}"
        if broken:
            return f"{'; '.join(broken)}: {what}"
        if expect == "kept":
            return f"the flight did not end: {what}"
        return f"the mission was not flown safely to its end: {what}"
    if result.status == Status.VIOLATION or broken:
        return None
    kept = "".join(f"; property {name} kept by {scored['robustness']:.3f} {scored['unit']}" for name, scored in result.properties.items())
    return f"the known violation no longer reproduces: {what}{kept}. If the fault was fixed, set \"expect\": \"safe\"."


def _as_reference(result: EvaluationResult, reference: Mapping[str, Any], what: str) -> str | None:
    """The flight against what the reference build did: its safety distance and mission kept where
    the reference kept them, its minimum clearance kept within the reference's tolerance; for a
    behaviour difference also not that difference again (`difference`: the same end as the
    reference's, or clearance or flight time on the subject's side of the reference's no farther
    than its spread). Cases written before `difference` hold the flight to all of these."""
    statuses = set(reference["statuses"])
    if result.status == Status.VIOLATION and Status.VIOLATION not in statuses:
        return f"safety distance violated where the reference build kept it: {what}"
    if statuses == {Status.OK} and result.status != Status.OK:
        return f"the mission was not flown to its end where the reference build flew it: {what}"
    floor = reference["min_clearance_m"] - reference["tolerance_m"]
    if result.min_clearance_m is None or result.min_clearance_m < floor:
        return (f"came closer than the reference build: min clearance below its {reference['min_clearance_m']:.3f} m "
                f"- {reference['tolerance_m']:.3f} m tolerance: {what}")
    if reference.get("level") != "behaviour":
        return None
    held_to = {Difference(reference["difference"])} if "difference" in reference else set(Difference)
    if Difference.STATUS in held_to and result.status not in statuses:
        return f"ended {result.status} where the reference build ended {'/'.join(sorted(statuses))}: {what}"
    ceiling = reference["max_clearance_m"] + reference["tolerance_m"]
    if Difference.FARTHER in held_to and result.min_clearance_m > ceiling:
        return f"kept farther away than the reference build: min clearance above its {reference['max_clearance_m']:.3f} m + {reference['tolerance_m']:.3f} m: {what}"
    if not held_to & {Difference.SHORTER, Difference.LONGER}:
        return None
    # Timed as the pair was (harness/flight/differential.py): by the first touchdown, or in cases
    # written before it was kept, by the whole flight.
    if "first_touchdown_s" in reference:
        shortest, longest = reference["first_touchdown_s"]
        flown, did = result.first_touchdown_s, "touched down at"
        if flown is None:
            return f"never touched down where the reference build did at {shortest:.1f}-{longest:.1f} s: {what}"
    else:
        shortest, longest = reference["sim_time_s"]
        flown, did = result.sim_time_s, "flew"
    if (Difference.SHORTER in held_to and flown < shortest - reference["time_tolerance_s"]
            or Difference.LONGER in held_to and flown > longest + reference["time_tolerance_s"]):
        return f"{did} {flown:.1f} s where the reference build {did} {shortest:.1f}-{longest:.1f} s: {what}"
    return None


def reference_entry(differential: Mapping[str, Any], level: str) -> dict[str, Any]:
    """The `reference` entry of a revealing case (expect as_reference) from its pair's flights
    (pairs.record), revealing at `level`."""
    flights = differential["reference"]
    subject, reference = [Outcome.from_dict(f) for f in differential["subject"]], [Outcome.from_dict(f) for f in flights]
    clearances = [f["min_clearance_m"] for f in flights]
    timed_by, _, times = flight_times(subject, reference)
    entry = {"level": level, "min_clearance_m": min(clearances), "max_clearance_m": max(clearances),
             "tolerance_m": max(CLEARANCE_RESOLUTION_M, max(clearances) - min(clearances)), "statuses": sorted({f["status"] for f in flights}),
             "first_touchdown_s" if timed_by == "touchdown" else "sim_time_s": [min(times), max(times)],
             "time_tolerance_s": max(TIME_RESOLUTION_S, max(times) - min(times))}
    difference = compare(subject, reference).difference
    if difference is not None:
        entry["difference"] = str(difference)
    return entry


def case_name(case: StoredEvaluation) -> str:
    """A case's file or folder name: where it was found, and the evaluation's id as its log has it."""
    return slug(f"{Path(case.scenario_file).stem}-{case.algorithm}-run{case.run_index}-{evaluation_name(case.id)}")


def chosen_cases(store_path: Path, threshold: float, worst: int, per_mode: bool = False) -> tuple[dict[str, Any], list[tuple[str, StoredEvaluation]]]:
    """The campaign's SUT and (name, case) for each distinct concrete scenario with fitness below
    `threshold`, plus the `worst` lowest-fitness ones of each run; a scenario found twice comes
    once. `per_mode`: only the worst violation of each failure mode (harness/campaigns/triage.py)."""
    with Store.existing(store_path) as store:
        sut = store.campaign_sut()
        searched_properties = bool(store.campaign_config().get("properties"))
        cases = _least_robust(store, threshold, worst) if searched_properties else store.worst_cases(threshold, worst)
    if per_mode:
        from harness.campaigns.triage import triage

        wanted = {m.worst.id for m in triage(store_path).modes}
        cases = [c for c in cases if c.id in wanted]
    chosen, seen = [], set()
    for case in cases:
        if case.concrete is None or case.vector_key in seen:
            continue
        seen.add(case.vector_key)
        chosen.append((case_name(case), case))
    return sut, chosen


def _least_robust(store: Store, threshold: float, worst_per_run: int) -> list[StoredEvaluation]:
    """A property campaign's worst cases as its search ranked them: by the least robustness of
    their properties, below threshold, plus each run's worst_per_run lowest."""
    scored = [(least_robustness(e.properties), e) for e in store.all_evaluations() if e.properties]
    by_run: dict[int, list[tuple[float, StoredEvaluation]]] = {}
    for robustness, evaluation in sorted(scored, key=lambda pair: (pair[0], pair[1].ordinal)):
        by_run.setdefault(evaluation.run_id, []).append((robustness, evaluation))
    chosen = {e.id: (r, e) for ranked in by_run.values() for rank, (r, e) in enumerate(ranked) if r < threshold or rank < worst_per_run}
    return [e for _r, e in sorted(chosen.values(), key=lambda pair: (pair[0], pair[1].id))]


def revealing_cases(store_path: Path) -> tuple[dict[str, Any], list[tuple[str, StoredEvaluation]]]:
    """The campaign's SUT and (name, case) for each distinct revealing concrete scenario of a
    differential campaign, unsafe ones first."""
    with Store.existing(store_path) as store:
        sut = store.campaign_sut()
        cases = store.revealing_cases()
    chosen, seen = [], set()
    for case in cases:
        if case.concrete is None or case.vector_key in seen:
            continue
        seen.add(case.vector_key)
        chosen.append((f"{case_name(case)}-{case.reveals}", case))
    return sut, chosen


def export_regressions(store_path: Path, out_dir: Path, *, threshold: float = 0.0, worst: int = 0, expect: str = "safe", per_mode: bool = False,
                       revealing: bool = False, properties: list[dict[str, Any]] | None = None) -> list[Path]:
    """One case file per distinct concrete scenario with fitness below `threshold`, plus the
    `worst` lowest-fitness ones of each run; identical scenarios found twice are written once.
    `revealing`: instead, each revealing scenario of a differential campaign, expecting the SUT
    to do as well as the reference did (fails on the subject's build, passes on the reference's).
    `properties`: what the cases judge besides the safety distance (default: the campaign's)."""
    if expect not in EXPECTATIONS:
        raise InputError([Problem("--expect", "", f"{expect!r} is not allowed; allowed values: {', '.join(EXPECTATIONS)}")])
    if revealing:
        sut, chosen = revealing_cases(store_path)
        expect = "as_reference"
    elif expect == "as_reference":
        raise InputError([Problem("--expect", "", "as_reference needs the revealing cases of a differential campaign: add --revealing")])
    else:
        sut, chosen = chosen_cases(store_path, threshold, worst, per_mode)
    if properties is None:
        with Store.existing(store_path) as store:
            properties = store.campaign_config().get("properties", [])
    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    for name, case in chosen:
        path = out_dir / f"{name}{SUFFIX}"
        document = case_document(name, case, sut, store_path, expect)
        if properties:
            document["properties"] = properties
        path.write_text(json.dumps(document, indent=2) + "\n")
        written.append(path)
    return written


def case_document(name: str, case: StoredEvaluation, sut: Mapping[str, Any], store_path: Path, expect: str) -> dict[str, Any]:
    """A stored evaluation as a regression case that pytest flies (expect: what must hold)."""
    revealing = expect == "as_reference"
    document = {
        "format": FORMAT,
        "name": name,
        "expect": expect,
        "seed": case.seed,
        "sut": dict(sut),
        "found": {
            "fitness": case.fitness, "status": str(case.status), "min_clearance_m": case.min_clearance_m, "store": str(store_path.resolve()),
            "run": case.run_index, "algorithm": case.algorithm, "evaluation": case.id, "log": case.log_path,
            **({"confirmations": case.confirmations, "flaky": case.flaky} if case.confirmations else {}),
        },
        "note": f"{EXPECTATIONS[expect]}; found by {case.algorithm} with fitness {case.fitness:.3f} ({case.status})"
                + ("; FLAKY: it did not violate in every re-flight" if case.flaky else "")
                + (f"; reveals {case.reveals}: {case.differential['why']}" if revealing else ""),
        "concrete_scenario": case.concrete,
    }
    if revealing:
        document["reference"] = reference_entry(case.differential, str(case.reveals))
    return document
