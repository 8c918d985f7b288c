"""Mutation analysis: would a campaign catch each mutant of a collision-prevention file?

Each counted mutant (built, neither equivalent nor a duplicate: mutants.py) is the *subject* of
differential flights against the unmutated build, the *reference*:

1. **screen**: a fixed suite of concrete scenarios (regression cases or concrete scenario files:
   the wall, the reference's closest approaches from one campaign per scenario) flown as pairs,
   confirmed; a revealing pair kills the mutant (*killed by the suite*); a mutant whose first
   flights crash or cannot arm where the reference flies is *killed at start*;
2. **search**: each survivor of the suite attacked by each algorithm on each logical scenario, one
   differential campaign (stored, resumable) of `evaluations` candidates; the first confirmed
   revealing candidate kills it (*killed by ALGORITHM*), at level unsafe or behaviour.

Reference flights are cached by concrete scenario in `reference_flights.db` (the same for every
mutant). Every mutant's outcome is written to `run.json` as it is known, so a stopped analysis
resumes where it was. `report` gives the mutation score per algorithm at both levels with
Wilson intervals, evaluations to kill, and Fisher's exact test, Mann-Whitney U and A12 of each
algorithm's search against the baseline's (RANDOM), as the seeded-fault benchmark does.
`rejudge` judges the searches' stored pairs again after an upgrade changed how pairs are judged.
"""

from __future__ import annotations

import fcntl
import json
import math
import statistics
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Sequence

from scipy.stats import fisher_exact

from harness.campaigns.campaign import CampaignConfig, run_campaign, run_line
from harness.campaigns.coverage import line_name
from harness.campaigns.pairs import PairedFlights, ReferenceCache
from harness.campaigns.rejudge import Rejudgement, complete_references, rejudge as rejudge_store
from harness.campaigns.screen import ScreenSettings
from harness.campaigns.regression import suite_cases
from harness.campaigns.statistics import a12, p_value
from harness.campaigns.store import Store
from harness.errors import InputError, Problem
from harness.execution.executor import Executor, Job
from harness.firmware.builds import SUT_OPTION
from harness.firmware.mutants import BUILT, load_index, write_json_atomically
from harness.flight.results import RunOptions
from harness.flight.fitness import Status
from harness.flight.logs import slug
from sut_adapter import SutConfig

RUN = "run.json"
LOCK = ".run.lock"
CACHE = "reference_flights.db"
LEVELS = ("unsafe", "any")


DEFAULT_OBJECTIVE = "difference"


@dataclass(frozen=True)
class MutationPlan:
    suite: tuple[str, ...]  # regression cases or concrete scenario files
    scenarios: tuple[str, ...] = ()  # logical scenarios the survivors are searched in
    algorithms: tuple[str, ...] = ("NSGAII", "RANDOM")
    evaluations: int = 40
    population: int = 10
    confirm: int = 0
    seed: int = 0
    drive: str | None = None
    objective: str = DEFAULT_OBJECTIVE
    sut_params: Mapping[str, float] = field(default_factory=dict)
    sut_logs: str = "all"  # RunOptions.sut_logs: which flights keep the SUT's own logs
    screen: ScreenSettings | None = None  # the searches' candidates flown on a cheap model first (harness/campaigns/screen.py)
    rig: str | None = None  # a sensor rig (preset or file) every case and search flies with instead of the profile's sensor

    def screening(self) -> dict[str, Any]:
        """What decides the suite's verdicts: a folder's mutants are screened once with these.
        Searches can be added later (other scenarios, other algorithms) to the same folder."""
        # Folders screened before rigs existed keep their identity.
        rigged = {"rig": self.rig} if self.rig is not None else {}
        return {"suite": [str(Path(s).resolve()) for s in self.suite], "confirm": self.confirm, "seed": self.seed, "drive": self.drive,
                "sut_params": dict(self.sut_params), **rigged}

    def searching(self) -> dict[str, Any]:
        """What every search of a folder shares, so that they count alike: the budget. Searches
        with another objective are told apart by their name (searcher)."""
        screened = {"screen": self.screen.identity()} if self.screen is not None else {}
        return {"evaluations": self.evaluations, "population": self.population, **screened}

    def searcher(self, algorithm: str) -> str:
        """A search's name in a folder: the algorithm, and its objective where it is not the
        default (NSGAII+coverage), so that one folder compares guided and unguided searches."""
        return algorithm if self.objective == DEFAULT_OBJECTIVE else f"{algorithm}+{self.objective}"


def mutant_sut(kind: str, folder: str, params: Mapping[str, float]) -> SutConfig:
    return SutConfig(kind, dict(params), **{SUT_OPTION[kind]: folder})


def _suite_cases(plan: MutationPlan) -> list[tuple[str, Any, Any, int]]:
    cases = suite_cases(plan.suite, plan.drive, plan.rig)
    if not cases:
        raise InputError([Problem("--suite", "", "no suite cases: give regression cases or concrete scenarios to screen every mutant with")])
    return cases


def _load(path: Path, plan: MutationPlan) -> dict[str, Any]:
    if not path.is_file():
        return {"screening": plan.screening(), "searching": plan.searching(), "mutants": {}}
    document = json.loads(path.read_text())
    if document["screening"] != plan.screening():
        raise InputError([Problem(str(path), "/screening", "this folder's mutants were screened with another suite, confirm, seed, drive, rig or parameters; "
                                                           "run with the same ones, or generate into another folder")])
    searched = any(o.get("search") for o in document["mutants"].values())
    unnamed = document["searching"].get("objective", DEFAULT_OBJECTIVE)
    if searched and unnamed != DEFAULT_OBJECTIVE:
        raise InputError([Problem(str(path), "/searching", f"this folder's searches ran with --objective {unnamed} before a search's name "
                                                           "carried its objective (NSGAII+coverage): read it with `stella mutants report`, "
                                                           "and search again in a folder of its own")])
    if searched and _budget(document["searching"]) != plan.searching():
        raise InputError([Problem(str(path), "/searching", f"this folder's searches ran with {document['searching']}: keep --evaluations "
                                                           "and --population, so that every search counts alike")])
    document["searching"] = plan.searching()
    return document


def _budget(searching: Mapping[str, Any]) -> dict[str, Any]:
    """A folder's `searching` without the objective, which folders searched before 2026-11-29
    kept there (one for all their searches) instead of in each search's name."""
    return {key: value for key, value in searching.items() if key != "objective"}


def _named_searches(document: Mapping[str, Any]) -> Mapping[str, Any]:
    """The mutants' outcomes with each search named as MutationPlan.searcher names it, also in a
    folder whose one objective was kept in `searching`."""
    objective = document["searching"].get("objective", DEFAULT_OBJECTIVE)
    if objective == DEFAULT_OBJECTIVE:
        return document["mutants"]
    return {key: {**outcome, **({"search": {f"{a}+{objective}": s for a, s in outcome["search"].items()}} if outcome.get("search") else {})}
            for key, outcome in document["mutants"].items()}


def _started_badly(result) -> bool:
    """A subject flight that never got to fly: it crashed, or setup (arming, takeoff) failed."""
    return result.status == Status.SUT_CRASHED or (result.status in (Status.MISSION_FAILED, Status.TIMEOUT) and (result.why or "").startswith("setup"))


@contextmanager
def alone_in(mutants_dir: Path) -> Iterator[None]:
    """The folder for this process alone: `run`, `rejudge` and `recheck` each hold run.json's whole document
    while they work and write it back, so a second one at the same time would undo the first's."""
    with open(mutants_dir / LOCK, "w") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise InputError([Problem(str(mutants_dir), "", "another `stella mutants run`, `rejudge` or `recheck` is working on this folder: "
                                                            "wait for it to end, or stop it (a stopped run resumes)")]) from None
        yield


def run(mutants_dir: Path, plan: MutationPlan, executor: Executor, *, only: Sequence[str] = (), progress: Callable[[str], None] = lambda _l: None) -> dict:
    mutants_dir = Path(mutants_dir)
    index = load_index(mutants_dir)
    with alone_in(mutants_dir):
        return _run(mutants_dir, index, plan, executor, only, progress)


def _run(mutants_dir: Path, index: Mapping[str, Any], plan: MutationPlan, executor: Executor, only: Sequence[str],
         progress: Callable[[str], None]) -> dict:
    built_path = mutants_dir / BUILT
    if not built_path.is_file():
        raise InputError([Problem(str(built_path), "", "the mutants are not built: run `stella mutants build` first")])
    built = json.loads(built_path.read_text())
    if plan.objective == "coverage" and not built.get("coverage"):
        raise InputError([Problem("--objective", "", "coverage is guided by the code each flight ran: build the mutants with "
                                                     "`stella mutants build --coverage` (into a folder of their own)")])
    cases = _suite_cases(plan)
    reference = mutant_sut(index["kind"], built["original"]["folder"], plan.sut_params)
    run_path = mutants_dir / RUN
    document = _load(run_path, plan)
    cache = ReferenceCache(mutants_dir / CACHE)
    # A worker whose process lives on keeps its simulator from mutant to mutant and for the reference.
    options = RunOptions(sut=reference, sut_logs=plan.sut_logs, warm=executor.keeps_stacks)
    try:
        for entry in sorted(built["mutants"].values(), key=lambda e: e["id"]):
            if entry["state"] != "built" or (only and entry["id"] not in only):
                continue
            subject = mutant_sut(index["kind"], entry["folder"], plan.sut_params)
            outcome = document["mutants"].get(entry["id"])
            if outcome is None:
                outcome = _screen(entry["id"], subject, reference, cases, plan, executor, cache, mutants_dir, replace(options, sut=subject),
                                  mutated_line(index, entry["id"]))
                document["mutants"][entry["id"]] = outcome
                write_json_atomically(run_path, document)
                progress(f"{entry['id']}: {describe(outcome)}")
            if outcome["state"] != "survived_suite":
                continue
            for algorithm in plan.algorithms:
                for scenario in plan.scenarios:
                    done = outcome.setdefault("search", {}).setdefault(plan.searcher(algorithm), {})
                    if Path(scenario).stem in done:
                        continue
                    done[Path(scenario).stem] = _search(entry["id"], subject, reference, plan, algorithm, scenario, executor, cache, mutants_dir,
                                                        progress, mutated_line(index, entry["id"]))
                    write_json_atomically(run_path, document)
                    progress(f"{entry['id']}: {describe(outcome)}")
    finally:
        cache.close()
    return document


def _screen(mutant: str, subject: SutConfig, reference: SutConfig, cases, plan: MutationPlan, executor: Executor, cache: ReferenceCache,
            folder: Path, options: RunOptions, changed_line: str) -> dict[str, Any]:
    pairs = PairedFlights(executor, reference, objective="subject", confirm=plan.confirm, cache=cache, changed_lines=(changed_line,))
    out_dir = folder / "logs" / mutant
    flown = 0
    for start in range(0, len(cases), max(1, executor.workers)):
        batch = cases[start:start + max(1, executor.workers)]
        jobs = [Job.of(start + i, space, x, seed=seed, out_dir=out_dir, name=f"{mutant}-{name}", options=options) for i, (name, space, x, seed) in enumerate(batch)]
        results = sorted(pairs.run(jobs), key=lambda pair: pair[0].key)
        flown += len(results)
        for job, result in results:
            reference_flights = result.differential["reference"]
            if start == 0 and _started_badly(result) and reference_flights[0]["status"] in (Status.OK, Status.VIOLATION) \
                    and _fails_to_start_again(job, plan.confirm, executor):
                return {"state": "killed_at_start", "case": job.name, "why": result.why, "suite_flights": flown}
            if result.differential["reveals"]:
                return {"state": "killed_by_suite", "level": result.differential["reveals"], "case": job.name, "why": result.differential["why"],
                        "suite_flights": flown}
    return {"state": "survived_suite", "suite_flights": flown}


def _fails_to_start_again(job: Job, times: int, executor: Executor) -> bool:
    """A start that failed once, tried `times` more (a loaded machine can fail an arming that
    the build itself would pass): killed at start only if every try failed."""
    again = [replace(job, key=i, name=f"{job.name}-start{i + 1}") for i in range(times)]
    return all(_started_badly(result) for _job, result in executor.run(again))


def mutated_line(index: Mapping[str, Any], mutant: str) -> str:
    """The mutant's mutated line as a flight's coverage names it (a mutation changes one line in place)."""
    found = next(m for m in index["mutants"] if m["id"] == mutant)
    return line_name(found["file"], found["line"])


def _search(mutant: str, subject: SutConfig, reference: SutConfig, plan: MutationPlan, algorithm: str, scenario: str, executor: Executor,
            cache: ReferenceCache, folder: Path, progress: Callable[[str], None], target: str) -> dict[str, Any]:
    """One differential campaign of the algorithm on the scenario against the mutant: when it
    first revealed a difference, and at which level. Guided by coverage, it aims at the mutated
    line (target) first."""
    config = CampaignConfig((scenario,), (algorithm,), plan.evaluations, 1, plan.seed, plan.population, sut=subject, drive=plan.drive,
                            confirm=plan.confirm, reference=reference, objective=plan.objective, screen=plan.screen, rig=plan.rig,
                            coverage_target=(target,) if plan.objective == "coverage" else (), changed_lines=(target,))
    store_path = search_store(folder, mutant, Path(scenario).stem, plan.searcher(algorithm))
    with Store.for_campaign(store_path) as store:
        run_campaign(config, store, executor, store_path.with_suffix(""), options=RunOptions(sut_logs=plan.sut_logs, warm=True), reference_cache=cache,
                     on_run=lambda run: progress(run_line(run)))
        return store.first_reveals()


def search_store(folder: Path, mutant: str, scenario: str, searcher: str) -> Path:
    return folder / "search" / mutant / f"{slug(scenario)}-{slug(searcher)}.db"


def load_run(mutants_dir: Path) -> dict[str, Any]:
    run_path = mutants_dir / RUN
    if not run_path.is_file():
        raise InputError([Problem(str(run_path), "", "no mutation run here: run `stella mutants run` first")])
    try:
        return json.loads(run_path.read_text())
    except json.JSONDecodeError as error:
        raise InputError([Problem(str(run_path), "", f"not JSON ({error}): put back the run.json `stella mutants run` wrote")]) from None


def rejudge(mutants_dir: Path) -> Rejudgement:
    """Every search's stored pairs and the cached reference flights judged again with this
    version's rule (harness/campaigns/rejudge.py), and each finished search's first kill in
    run.json with them; searches under way too, so that they resume judged alike. The suite's
    verdicts stay: its pairs are not stored."""
    mutants_dir = Path(mutants_dir)
    load_run(mutants_dir)  # a folder without a run says so before anything is locked
    index = load_index(mutants_dir)
    with alone_in(mutants_dir):
        document = load_run(mutants_dir)
        finished = {search_store(mutants_dir, mutant, scenario, algorithm): (by_scenario, scenario)
                    for mutant, outcome in sorted(document["mutants"].items())
                    for algorithm, by_scenario in (outcome.get("search") or {}).items() for scenario in by_scenario}
        gone = [path for path in finished if not path.is_file()]
        if gone:
            raise InputError([Problem(str(path), "", f"this search is in {RUN} but its store is gone: put it back, or delete its entry from "
                                                     f"{RUN} to search again") for path in gone])
        result = Rejudgement()
        cache = ReferenceCache(mutants_dir / CACHE)
        try:
            complete_references(cache, result.logs_gone)
        finally:
            cache.close()
        for store_path in sorted({*finished, *(mutants_dir / "search").glob("*/*.db")}):
            with Store.existing(store_path) as store:
                changes = rejudge_store(store, result.logs_gone, (mutated_line(index, store_path.parent.name),))
                if store_path in finished:
                    by_scenario, scenario = finished[store_path]
                    by_scenario[scenario] = store.first_reveals()
            if changes:
                result.changed.setdefault(store_path.parent.name, []).extend(changes)  # search/MUTANT/SCENARIO-ALGORITHM.db
        write_json_atomically(mutants_dir / RUN, document)
    return result


def describe(outcome: Mapping[str, Any]) -> str:
    if outcome["state"] != "survived_suite":
        return f"{outcome['state']}" + (f" ({outcome['level']})" if outcome.get("level") else "") + f" by {outcome.get('case')}: {outcome.get('why')}"
    searches = [(algorithm, scenario, first) for algorithm, by_scenario in (outcome.get("search") or {}).items() for scenario, first in by_scenario.items()]
    kills = [f"{algorithm} on {scenario} ({first['level']} after {first['evaluation']} evaluations)" for algorithm, scenario, first in searches if first["evaluation"]]
    if kills:
        return "survived the suite; killed by " + ", ".join(kills)
    return "survived the suite" + (f"; survived {len(searches)} search{'es' if len(searches) > 1 else ''}" if searches else "")


# -- the report --------------------------------------------------------------------------------


def wilson(killed: int, total: int, z: float = 1.96) -> tuple[float, float] | None:
    """The Wilson score interval of a proportion (95 % by default)."""
    if total == 0:
        return None
    p = killed / total
    centre = (p + z * z / (2 * total)) / (1 + z * z / total)
    half = z * math.sqrt(p * (1 - p) / total + z * z / (4 * total * total)) / (1 + z * z / total)
    return max(0.0, centre - half), min(1.0, centre + half)


def _first_kill(outcome: Mapping[str, Any], algorithm: str, level: str) -> int | None:
    """Evaluations the algorithm's search took to kill the mutant (its first revealing candidate
    at the level, over the scenarios searched one after another), None if it did not."""
    spent = 0
    for first in (outcome.get("search") or {}).get(algorithm, {}).values():
        evaluation = first["evaluation"] if level == "any" else first["first_unsafe"]
        if evaluation is not None:
            return spent + evaluation
        spent += first["budget"]
    return None


def against_other_tests(outcomes: Mapping[str, Any], algorithms: Sequence[str], other: Mapping[str, Any]) -> dict[str, Any]:
    """Kills of the harness (suite or any search, either level) against another test method's
    (`other`: {"mutants": {ID: {"killed": bool}}}, e.g. PX4's own unit tests run against each
    mutant), over the mutants both judged."""
    table = {"harness_only": [], "other_only": [], "both": [], "neither": []}
    for key, outcome in sorted(outcomes.items()):
        theirs = (other.get("mutants") or {}).get(key)
        if theirs is None:
            continue
        ours = outcome["state"] != "survived_suite" or any(_first_kill(outcome, a, "any") is not None for a in algorithms)
        table[{(True, True): "both", (True, False): "harness_only", (False, True): "other_only", (False, False): "neither"}[(ours, bool(theirs["killed"]))]].append(key)
    return table


def report(mutants_dir: Path, baseline: str = "RANDOM", other_tests: Path | None = None, other_name: str = "unit tests") -> dict[str, Any]:
    mutants_dir = Path(mutants_dir)
    index = load_index(mutants_dir)
    built = json.loads((mutants_dir / BUILT).read_text()) if (mutants_dir / BUILT).is_file() else {"mutants": {}}
    document = load_run(mutants_dir)
    states = [e["state"] for e in built["mutants"].values()]
    outcomes = _named_searches(document)
    searched: dict[str, set[str]] = {}
    for outcome in outcomes.values():
        for algorithm, by_scenario in (outcome.get("search") or {}).items():
            searched.setdefault(algorithm, set()).update(by_scenario)
    algorithms = sorted(searched) or ["suite"]  # screened only: the suite's score
    scores: dict[str, dict[str, Any]] = {}
    budget = document["searching"]["evaluations"] * max([len(s) for s in searched.values()] or [1])
    for algorithm in algorithms:
        entry: dict[str, Any] = {}
        for level in LEVELS:
            killed = unfinished = 0
            to_kill, kills = [], []
            for outcome in outcomes.values():
                by_suite = outcome["state"] in ("killed_at_start", "killed_by_suite") and (level == "any" or outcome.get("level") == "unsafe"
                                                                                            or outcome["state"] == "killed_at_start")
                by_search = _first_kill(outcome, algorithm, level) if outcome["state"] == "survived_suite" else None
                killed += by_suite or by_search is not None
                mine = (outcome.get("search") or {}).get(algorithm) if outcome["state"] == "survived_suite" else None
                if mine is None:
                    continue
                # A search not yet through every scenario is no survivor of it yet, and counted only
                # when it killed it would make the algorithm look better than its finished searches:
                # its kill counts in the score, not in the comparison.
                if not set(mine) >= searched[algorithm]:
                    unfinished += 1
                    continue
                to_kill.append(by_search if by_search is not None else budget + 1)
                if by_search is not None:
                    kills.append(by_search)
            total = len(outcomes)
            entry[level] = {"killed": killed, "mutants": total, "score": killed / total if total else None, "ci95": wilson(killed, total),
                            "search_kills": len(kills), "survivors_searched": len(to_kill), "searches_unfinished": unfinished,
                            "median_evaluations_to_kill": statistics.median(kills) if kills else None, "_ranks": to_kill}
        scores[algorithm] = entry
    base = scores.get(baseline.upper())
    for algorithm, entry in scores.items():
        for level in LEVELS:
            mine = entry[level]
            if base is None or algorithm == baseline.upper() or not mine["survivors_searched"]:
                mine.update(fisher_p=None, mann_whitney_p=None, a12=None)
                continue
            theirs = base[level]
            table = [[mine["search_kills"], mine["survivors_searched"] - mine["search_kills"]],
                     [theirs["search_kills"], theirs["survivors_searched"] - theirs["search_kills"]]]
            mine["fisher_p"] = float(fisher_exact(table)[1])
            mine["mann_whitney_p"] = p_value(mine["_ranks"], theirs["_ranks"])
            mine["a12"] = a12(mine["_ranks"], theirs["_ranks"])
    for entry in scores.values():
        for level in LEVELS:
            entry[level].pop("_ranks")
    mutants = {m["id"]: m for m in index["mutants"]}
    survivors = [{"id": key, "line": mutants[key]["line"], "original": mutants[key]["original"], "mutated": mutants[key]["mutated"], "rule": mutants[key]["rule"]}
                 for key, outcome in sorted(outcomes.items()) if outcome["state"] == "survived_suite" and not any(
                     _first_kill(outcome, a, "any") is not None for a in algorithms)]
    return {"file": index["file"], "kind": index["kind"], "generated": index["generated"], "sampled": len(index["mutants"]),
            "built": {state: states.count(state) for state in ("built", "stillborn", "equivalent", "duplicate")},
            "analysed": len(outcomes), "killed_at_start": sum(o["state"] == "killed_at_start" for o in outcomes.values()),
            "killed_by_suite": {level: sum(o["state"] == "killed_by_suite" and (level == "any" or o.get("level") == "unsafe") for o in outcomes.values())
                                for level in LEVELS},
            "baseline": baseline.upper(), "scores": scores, "survivors": survivors, "screening": document["screening"],
            "searching": document["searching"], "searched": {a: sorted(s) for a, s in searched.items()},
            **({"other_tests": {"name": other_name, "file": str(other_tests), **against_other_tests(outcomes, algorithms, load_other_tests(other_tests))}}
               if other_tests else {})}


def load_other_tests(path: Path) -> Mapping[str, Any]:
    if not Path(path).is_file():
        raise InputError([Problem(str(path), "", "no such file: give a JSON file {\"mutants\": {ID: {\"killed\": true|false}}}")])
    document = json.loads(Path(path).read_text())
    if not isinstance(document.get("mutants"), dict) or not all(isinstance(v, dict) and "killed" in v for v in document["mutants"].values()):
        raise InputError([Problem(str(path), "/mutants", "expected {ID: {\"killed\": true|false}} for each mutant the other tests judged")])
    return document


def report_text(result: Mapping[str, Any]) -> str:
    built = result["built"]
    lines = [f"{result['file']} ({result['kind']}): {result['generated']} mutants generated, {result['sampled']} taken; built {built['built']}, "
             f"stillborn {built['stillborn']}, equivalent {built['equivalent']}, duplicate {built['duplicate']}; analysed {result['analysed']}",
             f"killed at start: {result['killed_at_start']}; killed by the suite: {result['killed_by_suite']['unsafe']} unsafe, "
             f"{result['killed_by_suite']['any']} unsafe or behaviour", ""]
    fmt = lambda v, spec: "-" if v is None else format(v, spec)  # noqa: E731
    lines.append(f"{'algorithm':<15} {'level':<7} {'killed':>9} {'score':>6} {'95% CI':>13} {'search kills':>13} {'median evals':>13} "
                 f"{'Fisher p':>9} {'MWU p':>7} {'A12':>5}   (baseline {result['baseline']})")
    for algorithm, entry in result["scores"].items():
        for level in LEVELS:
            e = entry[level]
            ci = f"{e['ci95'][0]:.2f}-{e['ci95'][1]:.2f}" if e["ci95"] else "-"
            lines.append(f"{algorithm:<15} {level:<7} {e['killed']:>4}/{e['mutants']:<4} {fmt(e['score'], '.2f'):>6} {ci:>13} "
                         f"{e['search_kills']:>6}/{e['survivors_searched']:<6} {fmt(e['median_evaluations_to_kill'], '.1f'):>13} "
                         f"{fmt(e['fisher_p'], '.3f'):>9} {fmt(e['mann_whitney_p'], '.3f'):>7} {fmt(e['a12'], '.2f'):>5}")
    unfinished = {algorithm: entry["any"]["searches_unfinished"] for algorithm, entry in result["scores"].items() if entry["any"]["searches_unfinished"]}
    if unfinished:
        lines.append("not in the search kills' comparison, their searches not yet through every scenario (a kill counts in the score): "
                     + ", ".join(f"{algorithm} {n} survivor{'s' if n > 1 else ''}" for algorithm, n in unfinished.items()))
    if "other_tests" in result:
        other = result["other_tests"]
        lines += ["", f"against {other['name']} ({other['file']}), over the mutants both judged:"]
        for key, label in (("harness_only", "killed by the harness only"), ("other_only", f"killed by {other['name']} only"),
                           ("both", "killed by both"), ("neither", "killed by neither")):
            lines.append(f"  {label:<40} {len(other[key]):>3}  {' '.join(other[key])}")
    lines.append("")
    lines.append(f"surviving mutants ({len(result['survivors'])}):")
    for survivor in result["survivors"]:
        lines.append(f"  {survivor['id']} line {survivor['line']}: - {survivor['original'].strip()}")
        lines.append(f"  {' ' * len(survivor['id'])} line {survivor['line']}: + {survivor['mutated'].strip()}")
    return "\n".join(lines)
