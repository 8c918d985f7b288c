"""`stella mutants recheck`: each search's kill flown again, more often, before it counts.

A pair reveals where the subject's flights lie outside the spread of the reference's. PX4's
flights of one candidate spread, and sometimes in two modes (a pilot held 29.2 m or 29.9 m from
a wall, from run to run): with `--confirm 2`, three flights a side, both sides land in one mode
each by chance now and then, and over a folder's thousands of candidates such false kills come
(docs/real_faults.md: m0089, three times in one folder). A coverage build withdraws those whose
subject never ran the mutated line, but not those of a line every flight runs.

So each finished search's first revealing candidate, and its first unsafe one (the two levels
`report` counts), is flown again on both sides, in one sitting, until it has `flights` flights a
side, and judged on all of them (of a coverage build, each new subject flight must run the
mutated line too). A reveal that no longer stands is withdrawn, and the search's next revealing
candidate is rechecked, until one stands or none is left. Each verdict is kept with the pair in
the search's store, and run.json's kills follow it at once, so a recheck asked again flies only
what a pair lacks. Where a new flight could not finish (a simulator that would not start), the
pair is left as it was, to be asked again.

A kill by the suite is rechecked the same way, but its pair was not stored: its case is flown
afresh, `flights` times a side in one sitting, and judged on those alone. A suite kill that does
not stand makes the mutant a survivor of the suite (run.json keeps what was withdrawn), which
the folder's searches then take on (`stella mutants run`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from harness.campaigns.campaign import PAIR_OBJECTIVES
from harness.campaigns.pairs import PairedFlights, build_identity
from harness.campaigns.regression import suite_cases
from harness.campaigns.store import Store, StoredEvaluation, evaluation_name
from harness.errors import InputError, Problem
from harness.execution.executor import Executor, Job
from harness.firmware.mutants import BUILT, load_index, write_json_atomically
from harness.firmware.mutation import RUN, alone_in, load_run, mutant_sut, mutated_line, search_store
from harness.flight.differential import Outcome, Reveal
from harness.flight.fitness import COULD_NOT_FINISH
from harness.flight.results import RunOptions
from harness.scenario.world import space_from_concrete, world_spec
from sut_adapter import SutConfig


@dataclass(frozen=True)
class Rechecked:
    """One revealing candidate of a search flown again: its verdict before and after (None:
    withdrawn), or that its new flights could not finish (left as it was)."""

    mutant: str
    search: str  # SCENARIO-SEARCHER, as its store is named
    evaluation: int | None  # 1-based, as run.json counts; None: a suite case
    flights: int  # a side, now
    before: str
    after: str | None
    why: str
    finished: bool = True

    def text(self) -> str:
        verdict = "could not be flown again, left as it was" if not self.finished else f"{self.after} stands" if self.after else "withdrawn"
        candidate = f" candidate {self.evaluation}" if self.evaluation is not None else ""
        return f"{self.mutant} {self.search}{candidate}: {self.before} -> {verdict} with {self.flights} flights a side: {self.why}"


def _job(evaluation: StoredEvaluation, store_path: Path, options: RunOptions) -> Job:
    """The pair's subject flight as it was flown: its concrete scenario and seed, its logs beside
    the search's other flights."""
    name = evaluation_name(evaluation.id)
    space = space_from_concrete(evaluation.concrete, f"{store_path} evaluation {evaluation.id}")
    x = space.from_concrete(evaluation.concrete, name)
    out_dir = store_path.with_suffix("") / f"run{evaluation.run_id}"
    return Job(0, world_spec(space, x, evaluation.seed), evaluation.concrete, evaluation.seed, str(out_dir), name, options)


def _unfinished(before: Mapping[str, Any], after: Mapping[str, Any]) -> str | None:
    """Why one of the flights `after` added could not finish, unless the subject's SUT died where
    the reference flew, which is the verdict."""
    if after["reveals"] == Reveal.UNSAFE:
        return None
    for side in ("subject", "reference"):
        for outcome in after[side][len(before[side]):]:
            if outcome["status"] in COULD_NOT_FINISH:
                return f"the {side} could not finish a flight ({outcome['status']}: {outcome['why']})"
    return None


class _Search:
    """One finished search's store, its kills rechecked in the order they were flown."""

    def __init__(self, store: Store, store_path: Path, pairs: PairedFlights, options: RunOptions, mutant: str):
        self.store, self.store_path, self.pairs, self.options, self.mutant = store, store_path, pairs, options, mutant

    def recheck(self, flights: int, on_verdict: Callable[[Rechecked], None]) -> None:
        """Until the first reveal and the first unsafe one stand (or none is left): each flown up
        to `flights` a side and judged again. on_verdict hears each, after it is stored."""
        any_stands = unsafe_stands = False
        for evaluation in self.store.pairs():
            pair = evaluation.differential
            if not pair["reveals"] or (any_stands and (pair["reveals"] != Reveal.UNSAFE or unsafe_stands)):
                continue
            more = flights - min(len(pair["subject"]), len(pair["reference"]))
            if more > 0:
                after = self.pairs.again(_job(evaluation, self.store_path, self.options), [Outcome.from_dict(o) for o in pair["subject"]],
                                         [Outcome.from_dict(o) for o in pair["reference"]], more)
                unfinished = _unfinished(pair, after)
                verdict = Rechecked(self.mutant, self.store_path.stem, evaluation.ordinal + 1, flights, pair["reveals"], after["reveals"],
                                    unfinished or after["why"], finished=unfinished is None)
                if unfinished:
                    on_verdict(verdict)
                    return
                pair = {**pair, **after}
                self.store.rejudge(evaluation.id, pair)
                on_verdict(verdict)
            any_stands = any_stands or bool(pair["reveals"])
            unsafe_stands = unsafe_stands or pair["reveals"] == Reveal.UNSAFE
            if any_stands and unsafe_stands:
                return


def _recheck_suite_kill(mutant: str, outcome: dict[str, Any], screening: Mapping[str, Any], mutants_dir: Path, pairs: PairedFlights,
                        options: RunOptions, flights: int) -> Rechecked | None:
    """The suite case that killed the mutant, flown `flights` times a side; the outcome changed in
    place (a survivor of the suite where the kill does not stand). None where it was rechecked
    with as many flights before."""
    if outcome.get("rechecked_flights", 0) >= flights:
        return None
    cases = {f"{mutant}-{name}": (space, x, seed) for name, space, x, seed in suite_cases(screening["suite"], screening.get("drive"), screening.get("rig"))}
    if outcome["case"] not in cases:
        raise InputError([Problem(str(mutants_dir / RUN), f"/mutants/{mutant}/case", f"{outcome['case']}: no such case in the folder's suite "
                                                                                     f"({', '.join(screening['suite'])}): put its file back")])
    space, x, seed = cases[outcome["case"]]
    job = Job.of(0, space, x, seed=seed, out_dir=mutants_dir / "logs" / mutant, name=f"{outcome['case']}-recheck", options=options)
    after = pairs.again(job, [], [], flights)
    unfinished = _unfinished({"subject": [], "reference": []}, after)
    verdict = Rechecked(mutant, f"suite case {outcome['case']}", None, flights, outcome["level"], after["reveals"], unfinished or after["why"],
                        finished=unfinished is None)
    if unfinished:
        return verdict
    if after["reveals"]:
        outcome.update(level=after["reveals"], why=after["why"], rechecked_flights=flights)
    else:
        withdrawn = {key: outcome[key] for key in ("level", "case", "why")}
        suite_flights = outcome["suite_flights"]
        outcome.clear()
        outcome.update(state="survived_suite", suite_flights=suite_flights, withdrawn_by_recheck={**withdrawn, "flights": flights, "why_after": after["why"]})
    return verdict


def _check_builds(store: Store, store_path: Path, builds: Mapping[str, tuple[SutConfig, str]]) -> None:
    """The builds to fly ({"subject": (SUT, its folder), "reference": ...}) are those the search
    flew: built.json names folders, and a folder can be built again."""
    flown = store.campaign_config()
    for side, (sut, folder) in builds.items():
        if side in flown and build_identity(sut) != flown[side]:
            raise InputError([Problem(str(store_path), "", f"this search flew another {side} build than {folder} holds now: a recheck flies "
                                                           "the builds the search flew; put them back, or search again")])


def recheck(mutants_dir: Path, flights: int, executor: Executor, *, only: Sequence[str] = (), sut_logs: str = "all",
            progress: Callable[[str], None] = lambda _line: None) -> list[Rechecked]:
    """Every kill by the suite and every finished search's kills (of the mutants `only`, else all)
    rechecked with `flights` flights a side; run.json's kills updated with each verdict."""
    mutants_dir = Path(mutants_dir)
    load_run(mutants_dir)  # a folder without a run says so before anything is locked
    index = load_index(mutants_dir)
    built_path = mutants_dir / BUILT
    if not built_path.is_file():
        raise InputError([Problem(str(built_path), "", "the mutants are not built: nothing was flown to recheck")])
    built = json.loads(built_path.read_text())
    unknown = sorted(set(only) - {m["id"] for m in index["mutants"]})
    if unknown:
        raise InputError([Problem("--only", "", f"{', '.join(unknown)}: no such mutant in {mutants_dir / 'mutants.json'}")])
    verdicts: list[Rechecked] = []
    with alone_in(mutants_dir):
        document = load_run(mutants_dir)
        outcomes = {mutant: outcome for mutant, outcome in sorted(document["mutants"].items()) if not only or mutant in only}
        killed_by_suite = [mutant for mutant, outcome in outcomes.items() if outcome["state"] == "killed_by_suite"]
        searches = [(mutant, by_scenario, scenario, search_store(mutants_dir, mutant, scenario, searcher))
                    for mutant, outcome in outcomes.items()
                    for searcher, by_scenario in (outcome.get("search") or {}).items() for scenario, first in by_scenario.items()
                    if first["evaluation"] is not None]
        problems = [Problem(str(path), "", f"this search is in {RUN} but its store is gone: put it back, or delete its entry from {RUN} to search again")
                    for _m, _b, _s, path in searches if not path.is_file()]
        problems += [Problem(str(built_path), f"/mutants/{mutant}", "not built: the folder lists no build of this mutant to fly")
                     for mutant in sorted({*killed_by_suite, *(m for m, _b, _s, _p in searches)}) if built["mutants"].get(mutant, {}).get("state") != "built"]
        if problems:
            raise InputError(problems)
        screening = document["screening"]
        sut_params = screening.get("sut_params", {})
        reference = mutant_sut(index["kind"], built["original"]["folder"], sut_params)
        executor.check_sut(reference)
        for mutant in killed_by_suite:
            subject = mutant_sut(index["kind"], built["mutants"][mutant]["folder"], sut_params)
            executor.check_sut(subject)
            pairs = PairedFlights(executor, reference, objective="subject", changed_lines=(mutated_line(index, mutant),))
            verdict = _recheck_suite_kill(mutant, outcomes[mutant], screening, mutants_dir, pairs,
                                          RunOptions(sut=subject, sut_logs=sut_logs, warm=executor.keeps_stacks), flights)
            if verdict is not None:
                verdicts.append(verdict)
                progress(verdict.text())
                write_json_atomically(mutants_dir / RUN, document)
        for mutant, by_scenario, scenario, store_path in searches:
            subject = mutant_sut(index["kind"], built["mutants"][mutant]["folder"], sut_params)
            executor.check_sut(subject)
            with Store.existing(store_path) as store:
                _check_builds(store, store_path, {"subject": (subject, built["mutants"][mutant]["folder"]),
                                                  "reference": (reference, built["original"]["folder"])})
                objective = store.campaign_config().get("objective", "subject")
                pairs = PairedFlights(executor, reference, objective=PAIR_OBJECTIVES.get(objective, objective), changed_lines=(mutated_line(index, mutant),))

                def kept(verdict: Rechecked) -> None:
                    verdicts.append(verdict)
                    progress(verdict.text())
                    by_scenario[scenario] = store.first_reveals()
                    write_json_atomically(mutants_dir / RUN, document)

                _Search(store, store_path, pairs, RunOptions(sut=subject, sut_logs=sut_logs, warm=executor.keeps_stacks), mutant).recheck(flights, kept)
    return verdicts
