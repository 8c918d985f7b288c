"""`stella mutants recheck`: each search's kill flown again, more often, before it counts.

A pair reveals where the subject's flights lie outside the spread of the reference's. PX4's
flights of one candidate spread, and sometimes in two modes (a pilot held 29.2 m or 29.9 m from
a wall, from run to run): with `--confirm 2`, three flights a side, both sides land in one mode
each by chance now and then, and over a folder's thousands of candidates such false kills come
(docs/real_faults.md: m0089, twice in one folder). A coverage build withdraws those whose subject
never ran the mutated line, but not those of a line every flight runs.

So each finished search's first revealing candidate is flown `more` times again on both sides,
in one sitting, and judged on all of its flights (of a coverage build, each new subject flight
must run the mutated line too). A reveal that no longer stands is withdrawn, and the search's
next revealing candidate is rechecked, until one stands or none is left. The flights are kept
with the pair in the search's store, so a recheck asked again flies only what a pair lacks, and
run.json's first kill of each search follows.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

from harness.campaigns.pairs import PairedFlights
from harness.campaigns.store import Store, StoredEvaluation, evaluation_name
from harness.errors import InputError, Problem
from harness.execution.executor import Executor, Job
from harness.firmware.mutants import BUILT, load_index, write_json_atomically
from harness.firmware.mutation import RUN, alone_in, load_run, mutant_sut, mutated_line, search_store
from harness.flight.differential import Outcome
from harness.flight.results import RunOptions
from harness.scenario.world import space_from_concrete, world_spec


@dataclass(frozen=True)
class Rechecked:
    """One revealing candidate of a search flown again: its verdict before and after."""

    mutant: str
    search: str  # SCENARIO-SEARCHER, as its store is named
    evaluation: int  # 1-based, as run.json counts
    flights: int  # a side, now
    before: str
    after: str | None
    why: str

    def text(self) -> str:
        verdict = f"{self.after} stands" if self.after else "withdrawn"
        return f"{self.mutant} {self.search} candidate {self.evaluation}: {self.before} -> {verdict} with {self.flights} flights a side: {self.why}"


def _job(evaluation: StoredEvaluation, store_path: Path, options: RunOptions) -> Job:
    """The pair's subject flight as it was flown: its concrete scenario, seed and log folder."""
    name = evaluation_name(evaluation.id)
    space = space_from_concrete(evaluation.concrete, f"{store_path} evaluation {evaluation.id}")
    x = space.from_concrete(evaluation.concrete, name)
    out_dir = Path(evaluation.log_path).parent if evaluation.log_path else store_path.with_suffix("") / f"run{evaluation.run_id}"
    return Job(0, world_spec(space, x, evaluation.seed), evaluation.concrete, evaluation.seed, str(out_dir), name, options)


def _recheck_search(store: Store, store_path: Path, pairs: PairedFlights, options: RunOptions, flights: int, mutant: str,
                    progress: Callable[[str], None]) -> list[Rechecked]:
    """The search's revealing candidates in the order they were flown, each flown up to `flights`
    a side, until one stands."""
    done = []
    for evaluation in store.pairs():
        pair = evaluation.differential
        if not pair["reveals"]:
            continue
        subject = [Outcome.from_dict(o) for o in pair["subject"]]
        reference = [Outcome.from_dict(o) for o in pair["reference"]]
        more = flights - min(len(subject), len(reference))
        if more > 0:
            after = pairs.again(_job(evaluation, store_path, options), subject, reference, more)
            store.rejudge(evaluation.id, {**pair, **after})
            change = Rechecked(mutant, store_path.stem, evaluation.ordinal + 1, flights, pair["reveals"], after["reveals"], after["why"])
            progress(change.text())
            done.append(change)
            pair = after
        if pair["reveals"]:
            break
    return done


def recheck(mutants_dir: Path, flights: int, executor: Executor, *, only: Sequence[str] = (), sut_logs: str = "all",
            progress: Callable[[str], None] = lambda _line: None) -> list[Rechecked]:
    """Every finished search's kill (of the mutants `only`, else all) rechecked with `flights`
    flights a side; run.json's first kills updated as each search is done."""
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
    rechecked: list[Rechecked] = []
    with alone_in(mutants_dir):
        document = load_run(mutants_dir)
        sut_params = document["screening"].get("sut_params", {})
        reference = mutant_sut(index["kind"], built["original"]["folder"], sut_params)
        for mutant, outcome in sorted(document["mutants"].items()):
            if only and mutant not in only:
                continue
            subject = mutant_sut(index["kind"], built["mutants"][mutant]["folder"], sut_params)
            options = RunOptions(sut=subject, sut_logs=sut_logs, warm=executor.keeps_stacks)
            for searcher, by_scenario in (outcome.get("search") or {}).items():
                for scenario, first in by_scenario.items():
                    if first["evaluation"] is None:
                        continue
                    store_path = search_store(mutants_dir, mutant, scenario, searcher)
                    with Store.existing(store_path) as store:
                        pairs = PairedFlights(executor, reference, objective=store.campaign_config().get("objective", "subject"),
                                              changed_lines=(mutated_line(index, mutant),))
                        rechecked += _recheck_search(store, store_path, pairs, options, flights, mutant, progress)
                        by_scenario[scenario] = store.first_reveals()
                    write_json_atomically(mutants_dir / RUN, document)
    return rechecked
