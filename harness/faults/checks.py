"""Seeded faults from the harness's side: their list, a witness per fault (a concrete scenario in
scenarios/faults/ that reveals it), flying the witnesses both ways, and finding a witness.

A scenario *reveals* a fault when the faulty autopilot violates the safety distance or fails the
mission in it and the fault-free one flies it `ok`: unsafe because of the fault, not merely unsafe.
A fault judged by safety properties (a failsafe's: Fault.properties) is revealed where the faulty
autopilot violates one of them and the fault-free one keeps them all, whatever the mission's
outcome (a failsafe that lands short of the goal does what it should).
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

import numpy as np

from harness.errors import InputError, Problem
from harness.flight.evaluation import evaluate, infeasible
from harness.flight.results import EvaluationResult, RunOptions
from harness.flight.fitness import Status
from harness.paths import scenarios_dir
from harness.properties.spec import LIBRARY, Property
from harness.scenario.logical import load_logical
from harness.scenario.profile import load_profile
from harness.scenario.space import SearchSpace
from harness.scenario.world import load_concrete
from sut_adapter import SutConfig
from sut_adapter.bundled import seeded_faults

WITNESS_SEED = 0  # the sensor-noise seed every witness is flown with
REVEALING = (Status.VIOLATION, Status.MISSION_FAILED)


def witness_path(fault: str) -> Path:
    return scenarios_dir() / "faults" / f"{fault}.json"


def checked_names(names: Iterable[str] | None) -> list[str]:
    known = seeded_faults()
    names = list(names or known)
    unknown = [n for n in names if n not in known]
    if unknown:
        raise InputError([Problem("--fault", "", f"no seeded fault {unknown[0]!r}; known: {', '.join(known)}")])
    return names


def fault_list() -> list[dict[str, Any]]:
    return [{**asdict(fault), "witness": str(witness_path(fault.name)) if witness_path(fault.name).is_file() else None} for fault in seeded_faults().values()]


def unsafe(result: EvaluationResult) -> bool:
    """Violates a property it was judged by, or (judged by none) the safety distance or the mission."""
    if result.properties:
        return any(scored["verdict"] == "violated" for scored in result.properties.values())
    return result.status in REVEALING


def reveals(faulty: EvaluationResult, clean: EvaluationResult | None) -> bool:
    if clean is None or not unsafe(faulty):
        return False
    if clean.properties:
        return all(scored["verdict"] == "kept" for scored in clean.properties.values())
    return clean.status == Status.OK


def judged_by(fault: str) -> tuple[Property, ...]:
    """The properties a fault's witness is judged by (none: the clearance and the mission)."""
    return tuple(LIBRARY[name] for name in seeded_faults()[fault].properties)


def options_for(fault: str | None, sut_params: Mapping[str, float] | None = None, properties: tuple[Property, ...] = ()) -> RunOptions:
    """The bundled autopilot with the fault switched on, or fault-free for None."""
    return RunOptions(sut=SutConfig(params=dict(sut_params or {}), fault=fault), properties=properties)


def _fly(space: SearchSpace, x: np.ndarray, fault: str | None, out_dir: Path, name: str, properties: tuple[Property, ...]) -> EvaluationResult:
    return evaluate(space, x, seed=WITNESS_SEED, out_dir=out_dir, options=options_for(fault, properties=properties), name=name)


def _outcome(result: EvaluationResult) -> dict[str, Any]:
    return {"status": str(result.status), "fitness": result.fitness, "why": result.why, "min_clearance_m": result.min_clearance_m, "log_path": result.log_path,
            **({"properties": result.properties} if result.properties else {})}


def check(names: Iterable[str] | None, out_dir: Path, workers: int | None = None,
          progress: Callable[[str], None] = lambda _line: None) -> list[dict[str, Any]]:
    """Each fault's witness flown with the fault and without (through the local executor, both
    flights of every witness at once); `revealed` when it tells them apart."""
    from harness.execution.executor import Job
    from harness.execution.registry import make_executor

    names = checked_names(names)
    jobs, unflown, witness_of = [], {}, {}
    for name in names:
        path = witness_path(name)
        if not path.is_file():
            unflown[name] = {"fault": name, "witness": None, "revealed": False, "why": f"no witness: {path} is missing"}
            continue
        space, x = load_concrete(path)
        refused = infeasible(space, x, seed=WITNESS_SEED, sut="bundled")
        if refused is not None:
            unflown[name] = {"fault": name, "witness": str(path), "revealed": False, "why": f"the witness is infeasible: {refused.why}"}
            continue
        for fault, suffix in ((name, "with-fault"), (None, "without")):
            witness_of[len(jobs)] = name
            jobs.append(Job.of(len(jobs), space, x, seed=WITNESS_SEED, out_dir=out_dir, name=f"{name}-{suffix}",
                               options=options_for(fault, properties=judged_by(name))))
    flown: dict[str, EvaluationResult] = {}
    executor = make_executor("local", workers)
    try:
        for job, result in executor.run(jobs):
            flown[job.name] = result
            name = witness_of[job.key]
            if f"{name}-with-fault" in flown and f"{name}-without" in flown:
                progress(_line(_entry(name, flown)))
    finally:
        executor.close()
    return [unflown[name] if name in unflown else _entry(name, flown) for name in names]


def _entry(name: str, flown: dict[str, EvaluationResult]) -> dict[str, Any]:
    faulty, clean = flown[f"{name}-with-fault"], flown[f"{name}-without"]
    return {"fault": name, "witness": str(witness_path(name)), "with_fault": _outcome(faulty), "without": _outcome(clean), "revealed": reveals(faulty, clean)}


def _line(entry: dict[str, Any]) -> str:
    if "with_fault" not in entry:  # no witness, or one that cannot be flown
        return f"{entry['fault']:<28} {entry['why']}"
    a, b = entry["with_fault"], entry["without"]
    return (f"{entry['fault']:<28} {'revealed' if entry['revealed'] else 'NOT REVEALED':<13} with it: {_judged(a)}; without: {_judged(b)}")


def _judged(outcome: dict[str, Any]) -> str:
    if "properties" in outcome:
        return ", ".join(f"{name} {scored['verdict']}" for name, scored in outcome["properties"].items())
    return f"{outcome['status']} (fitness {outcome['fitness']:.3f})"


def check_text(report: list[dict[str, Any]]) -> str:
    revealed = sum(entry["revealed"] for entry in report)
    return "\n".join([_line(entry) for entry in report] + [f"{revealed} of {len(report)} witnesses reveal their fault"])


def find_witness(fault: str, scenario: Path, tries: int, seed: int, out_dir: Path) -> tuple[dict[str, Any] | None, int]:
    """The first of `tries` feasible samples of a logical scenario that reveals the fault, as a
    concrete scenario, and how many samples it took (flown with the fault first: most do not
    fail with it, and those need no second flight)."""
    checked_names([fault])
    profile = load_profile("default")
    space = SearchSpace(load_logical(scenario, profile), profile)
    properties = judged_by(fault)
    for index, x in enumerate(space.sample_feasible(np.random.default_rng(seed), tries), 1):
        faulty = _fly(space, x, fault, out_dir, f"{fault}-try{index}-with-fault", properties)
        if not unsafe(faulty):
            continue
        if reveals(faulty, _fly(space, x, None, out_dir, f"{fault}-try{index}-without", properties)):
            return space.to_concrete(x), index
    return None, tries


def write_witness(fault: str, concrete: dict[str, Any]) -> Path:
    path = witness_path(fault)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(concrete, indent=2) + "\n")
    return path
