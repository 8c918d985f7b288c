"""`stella faults ACTION`: the bundled autopilot's seeded faults listed, each witness flown with
and without its fault, a witness found for a fault, and the detection benchmark and its report.
Each action declares its own options."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from harness.errors import InputError, Problem
from harness.execution import registry as executors
from harness.scenario.logical import load_logical
from harness.scenario.profile import load_profile
from harness.tools.commands.campaigns import print_run_line
from harness.tools.commands.common import command, command_with_actions, emit, positive_int, seed_int
from harness.tools.commands.sut_options import sut_param_values

command_with_actions("faults", "the bundled autopilot's seeded faults: list them, fly each witness with and without its fault, find a witness, "
                               "benchmark searches on them")


@command("faults list", "the faults, documented, with their witnesses")
def faults_list(args: argparse.Namespace) -> int:
    from harness.faults import checks as faults

    listed = faults.fault_list()
    lines = []
    for fault in listed:
        lines += [f"{fault['name']} ({fault['area']}): {fault['breaks']}",
                  f"    like: {fault['kin']}; revealed by: {fault['revealed_by']}; witness: {fault['witness'] or 'none'}"]
    emit(args, {"faults": listed}, "\n".join(lines))
    return 0


def _out_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="runs/faults", help="folder for the flights' logs (default runs/faults)")


def _check_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--fault", action="append", metavar="NAME", help="only these (repeatable; default all)")
    _out_option(p)
    p.add_argument("--workers", type=positive_int, help="flights at once (default: cores)")


@command("faults check", "fly each fault's witness with and without the fault; exit 1 unless every one reveals its fault", _check_options)
def faults_check(args: argparse.Namespace) -> int:
    from harness.faults import checks as faults

    report = faults.check(args.fault, Path(args.out), args.workers, progress=lambda line: None if args.json else print(line, file=sys.stderr))
    emit(args, {"witnesses": report, "all_revealed": all(e["revealed"] for e in report)}, faults.check_text(report).splitlines()[-1])
    return 0 if all(e["revealed"] for e in report) else 1


def _witness_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--fault", action="append", metavar="NAME", help="the fault to find a witness for")
    p.add_argument("--scenario", action="append", help="the logical scenario to sample candidates from")
    p.add_argument("--tries", type=positive_int, default=20, help="samples to try (default 20)")
    p.add_argument("--seed", type=seed_int, default=0, help="the sampling seed")
    _out_option(p)


@command("faults witness", "sample a logical scenario until a concrete scenario reveals the fault, and write it as the fault's witness",
         _witness_options)
def faults_witness(args: argparse.Namespace) -> int:
    from harness.faults import checks as faults

    if not args.fault or len(args.fault) != 1 or not args.scenario or len(args.scenario) != 1:
        raise InputError([Problem("stella faults witness", "", "give one --fault NAME and one --scenario to sample witnesses from")])
    [fault] = args.fault
    concrete, tried = faults.find_witness(fault, Path(args.scenario[0]), args.tries, args.seed, Path(args.out))
    if concrete is None:
        emit(args, {"fault": fault, "witness": None, "tried": tried}, f"none of {tried} samples of {args.scenario} reveals {fault}")
        return 1
    path = faults.write_witness(fault, concrete)
    emit(args, {"fault": fault, "witness": str(path), "tried": tried}, f"sample {tried} reveals {fault}: written to {path}")
    return 0


def _baseline_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--baseline", default="RANDOM", help="the algorithm the others are tested against (default RANDOM)")


def _bench_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--fault", action="append", metavar="NAME", help="a fault to campaign against (repeatable; none: the fault-free control)")
    p.add_argument("--scenario", action="append", help="a logical scenario to search (repeatable)")
    p.add_argument("--algorithm", action="append", help="as for campaign; repeatable")
    p.add_argument("--runs", type=positive_int, default=3, help="runs per fault, algorithm and scenario (default 3)")
    p.add_argument("--evaluations", type=positive_int, help="budget per run")
    p.add_argument("--population", type=positive_int, default=50, help="as for campaign")
    p.add_argument("--store", help="the benchmark's folder (one campaign store per fault and the fault-free re-flights)")
    p.add_argument("--executor", choices=executors.names(), default="local", help="as for campaign")
    _baseline_option(p)
    p.add_argument("--seed", type=seed_int, default=0, help="run r uses seed + r")
    p.add_argument("--workers", type=positive_int, help="flights at once (default: cores)")
    p.add_argument("--sut-param", action="append", metavar="NAME=VALUE",
                   help="an autopilot parameter for the faulty and the fault-free flights alike, e.g. CP_DIST=1.5; repeatable")


@command("faults bench", "the seeded-fault benchmark: campaigns against each fault, every violation flown again without it (resumable); "
                         "then its report", _bench_options)
def faults_bench(args: argparse.Namespace) -> int:
    from harness.execution.registry import make_executor
    from harness.faults.bench import report, report_text, run_bench
    from harness.search.optimizers import parse_algorithm
    import sut_adapter

    missing = [flag for flag, value in (("--fault", args.fault), ("--algorithm", args.algorithm), ("--scenario", args.scenario),
                                        ("--evaluations", args.evaluations), ("--store", args.store)) if not value]
    if missing:
        raise InputError([Problem("stella faults bench", "", f"give {', '.join(missing)}")])
    for algorithm in args.algorithm:
        try:
            parse_algorithm(algorithm)
        except ValueError as error:
            raise InputError([Problem("--algorithm", "", str(error))]) from None
    profile = load_profile("default")
    for scenario in args.scenario:
        load_logical(Path(scenario), profile)
    sut_params = sut_param_values(args.sut_param)
    try:
        sut_adapter.system_for(sut_adapter.SutConfig(params=sut_params)).check_params(sut_params)
    except sut_adapter.SutError as error:
        raise InputError([Problem("--sut-param", "", str(error))]) from None
    try:
        executor = make_executor(args.executor, args.workers)
    except ValueError as error:
        raise InputError([Problem("--executor", "", str(error))]) from None
    try:
        run_bench(args.fault, tuple(a.upper() for a in args.algorithm), tuple(args.scenario), args.runs, args.evaluations, Path(args.store), executor,
                  seed=args.seed, population=args.population, sut_params=sut_params, on_run=print_run_line)
    finally:
        executor.close()
    result = report(Path(args.store), args.baseline)
    emit(args, result, report_text(result))
    return 0


def _report_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--store", help="the benchmark's folder (the one `stella faults bench --store` wrote)")
    _baseline_option(p)


@command("faults report", "over a benchmark's finished runs: detection rate, evaluations to detection, Fisher exact, Mann-Whitney U and A12 "
                          "against the baseline, per-fault table", _report_options)
def faults_report(args: argparse.Namespace) -> int:
    from harness.faults.bench import report, report_text

    if not args.store:
        raise InputError([Problem("stella faults report", "", "give --store FOLDER (the one `stella faults bench` wrote)")])
    result = report(Path(args.store), args.baseline)
    emit(args, result, report_text(result))
    return 0
