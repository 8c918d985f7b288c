"""The options that choose what flies (the SUT, its parameters, the reference of a differential
run, the drive and the route) and their checks, shared by every command that flies."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

from harness.errors import InputError, Problem
from harness.flight.results import SUT_LOGS
from harness.scenario.logical import DRIVES, load_logical
from harness.scenario.profile import load_profile

if TYPE_CHECKING:
    from harness.scenario.space import SearchSpace
    from sut_adapter import SutConfig


def add_sut_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sut", default="bundled", help="bundled (default), px4, ardupilot or command")
    p.add_argument("--px4-bin", help="with --sut px4: the px4 binary or its build folder (default: $STELLA_PX4_BIN)")
    p.add_argument("--ardupilot-bin", help="with --sut ardupilot: the arducopter binary or its build folder, build/sitl (default: $STELLA_ARDUPILOT_BIN)")
    p.add_argument("--sut-command", help="with --sut command: the SUT's command line with {sim_port}, {api_port}, {instance}, {workdir}")
    p.add_argument("--sut-hold", choices=["paced", "frozen"], help="with --sut command: how the SUT waits during setup (default paced; see README)")
    p.add_argument("--sut-param", action="append", metavar="NAME=VALUE", help="a SUT parameter, e.g. CP_DIST=2.0; repeatable; wins over --sut-params-file")
    p.add_argument("--sut-fault", metavar="NAME", help="switch on one of the bundled autopilot's seeded faults (`stella faults list`)")
    p.add_argument("--autopilot-dir", metavar="DIR", help="with --sut bundled: fly the `autopilot` package in DIR instead (a mutant's folder from "
                                                          "`stella mutants build`, or a build of `stella sut build --source .`)")
    p.add_argument("--sut-params-file", metavar="FILE", help="SUT parameters from QGroundControl's .params export, a NAME,VALUE CSV (the UAV Testing Competition's) "
                                                            "or ArduPilot's .parm/.param (NAME VALUE)")
    p.add_argument("--mission-plan", metavar="PLAN", help="fly this QGroundControl .plan instead of the scenario's route (its home becomes the origin; "
                                                      "takeoff, waypoint, land, return, change speed, delay)")
    p.add_argument("--drive", choices=DRIVES, help="how the route is flown, overriding the scenario's mission.drive: mission (an uploaded mission) "
                                                   "or pilot (a simulated pilot in Position mode with stick input, relying on collision prevention)")
    p.add_argument("--rig", metavar="NAME|FILE", help="the vehicle's range sensors: a preset (`stella rigs`) or a rig file, instead of the profile's")


def add_sut_logs_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sut-logs", choices=SUT_LOGS, default="all",
                   help="which flights keep the SUT's own log beside their MCAP (PX4's ULog, about 19 MB a flight; ArduPilot's .BIN): all "
                        "(default); failures: those that did not end ok; violations: those that violated, crashed into the ground or could not "
                        "finish, not the other mission failures (blocked, time limit); consoles are kept either way")


def add_reference_options(p: argparse.ArgumentParser, *, campaign: bool = False) -> None:
    group = p.add_argument_group("differential", "fly every scenario against a reference SUT too, and say where the subject (the --sut) differs")
    group.add_argument("--reference-sut", metavar="NAME", help="the reference SUT (default: the subject's, with the changes below)")
    group.add_argument("--reference-px4-bin", metavar="PATH", help="the reference's px4 binary or build folder (e.g. main's, against your branch's --px4-bin)")
    group.add_argument("--reference-ardupilot-bin", metavar="PATH", help="the reference's arducopter binary or build folder")
    group.add_argument("--reference-autopilot-dir", metavar="DIR", help="the reference's bundled autopilot folder")
    group.add_argument("--reference-sut-param", action="append", metavar="NAME=VALUE", help="a reference parameter (over the subject's); repeatable")
    group.add_argument("--reference-sut-fault", metavar="NAME", help="a seeded fault of the reference's bundled autopilot")
    if campaign:
        p.add_argument("--objective", choices=["subject", "difference", "diverse", "properties", "coverage"], default="subject",
                       help="what the search minimises: the fitness (default; with --property, the least robustness of the properties); with a "
                            "reference, f_subject - f_reference (difference: where the subject is worse); without one, the fitness shared over "
                            "failure modes (diverse: new failures before repeats; docs/diversity.md); with --property, each property's robustness "
                            "as an objective of its own (properties: NSGA-II and SMPSO keep a Pareto front over them; docs/properties.md); "
                            "with a coverage build, the fitness (with a reference, the difference) less a reward for code no earlier flight "
                            "reached (coverage; docs/coverage.md)")
    else:
        group.add_argument("--objective", choices=["subject", "difference"], default="subject",
                           help="the pair's fitness: the subject's (default), or f_subject - f_reference (where the subject is worse)")


def mission_plan(args: argparse.Namespace) -> Path | None:
    plan = getattr(args, "mission_plan", None)
    return Path(plan) if plan else None


def space_of(args: argparse.Namespace) -> SearchSpace:
    """The search space of the command's logical scenario, with its profile, drive and plan."""
    from harness.scenario.space import SearchSpace

    profile = load_profile(args.profile)
    return SearchSpace(load_logical(Path(args.scenario), profile, getattr(args, "drive", None), mission_plan(args), getattr(args, "rig", None)), profile)


def rigged(space: SearchSpace, args: argparse.Namespace) -> SearchSpace:
    """The space with --rig's sensors, if given (a concrete scenario's own profile otherwise)."""
    from harness.scenario.world import space_with_rig

    if not getattr(args, "rig", None):
        return space
    return space_with_rig(space, args.rig)


def check_coverage_build(sut: SutConfig) -> None:
    """Exit 2 where the SUT is no coverage build: a coverage-guided search has nothing to go by."""
    from sut_adapter.coverage import build_folder_of, coverage_build

    if coverage_build(build_folder_of(sut)) is None:
        raise InputError([Problem("--objective", "", "coverage is guided by the code each flight ran, which only a coverage build records: fly the "
                                                     "--px4-bin or --autopilot-dir that `stella sut build px4|bundled --coverage` prints")])


def check_rig(rig: Mapping[str, Any] | None, *suts: SutConfig | None) -> None:
    """Exit 2 where a SUT cannot read a sensor of the rig."""
    import sut_adapter
    from harness.scenario.rig import rig_problem_for

    for sut in suts:
        if sut is None:
            continue
        capabilities = sut_adapter.system_for(sut).capabilities
        problem = rig_problem_for(rig, sut.name, capabilities)
        if problem is not None:
            raise InputError([Problem("--rig", "", problem)])


def sut_param_values(items: list[str] | None) -> dict[str, float]:
    """--sut-param NAME=VALUE items as numbers."""
    params: dict[str, float] = {}
    for item in items or []:
        name, _, value = item.partition("=")
        try:
            params[name] = int(value) if value.lstrip("-").isdigit() else float(value)
        except ValueError:
            raise InputError([Problem("--sut-param", "", f"{item!r} is not NAME=NUMBER (e.g. CP_DIST=2.5)")]) from None
        if not math.isfinite(params[name]):
            raise InputError([Problem("--sut-param", "", f"{item!r}: a parameter's value must be a finite number")])
    return params


def sut_spec(args: argparse.Namespace) -> SutConfig:
    """The SUT the command line chose, checked by its adapter."""
    import sut_adapter

    if args.sut_fault is not None and args.sut != "bundled":
        raise InputError([Problem("--sut-fault", "", f"seeded faults live in the bundled autopilot, not in --sut {args.sut}")])
    from_file: dict[str, float] = {}
    if args.sut_params_file:
        from harness.interop.param_files import load_params_file

        from_file = load_params_file(Path(args.sut_params_file))
    params = {**from_file, **sut_param_values(args.sut_param)}
    config = sut_adapter.SutConfig(args.sut, params, args.sut_fault, args.px4_bin, args.sut_command, args.sut_hold, args.autopilot_dir,
                                   getattr(args, "ardupilot_bin", None))
    return checked_sut(config, "--sut", "--sut-param", from_file)


def checked_sut(config: SutConfig, option: str, params_option: str, from_file: dict[str, float] | None = None) -> SutConfig:
    """The configuration, if its SUT takes it; else InputError naming the option at fault (the
    parameter file's where the file's own parameters are refused)."""
    import sut_adapter

    try:
        system = sut_adapter.system_for(config)
    except sut_adapter.SutError as error:
        raise InputError([Problem(option, "", str(error))]) from None
    try:
        system.check_params(config.params)
    except sut_adapter.SutError as error:
        raise InputError([Problem(_refused_params_option(system, params_option, from_file), "", str(error))]) from None
    return config


def _refused_params_option(system, params_option: str, from_file: dict[str, float] | None) -> str:
    """The option refused parameters came from: the parameter file where its own are refused."""
    import sut_adapter

    if not from_file:
        return params_option
    try:
        system.check_params(from_file)
    except sut_adapter.SutError:
        return "--sut-params-file"
    return params_option


def reference_spec(args: argparse.Namespace, subject: SutConfig) -> SutConfig | None:
    """The reference SUT of a differential run: the subject's configuration with what the
    --reference-* options change (another build, another SUT, other parameters); None without them."""
    import sut_adapter

    given = {name: getattr(args, f"reference_{name}") for name in ("sut", "px4_bin", "ardupilot_bin", "autopilot_dir", "sut_param", "sut_fault")}
    if args.objective == "diverse":
        if any(value is not None for value in given.values()):
            raise InputError([Problem("--objective", "", "diverse searches one SUT's failures: drop the --reference-* options, or use "
                                                         "--objective difference to search where the subject is worse than the reference")])
        return None
    if not any(value is not None for value in given.values()):
        if args.objective == "difference":
            raise InputError([Problem("--objective", "", "difference needs a reference SUT: add --reference-px4-bin, --reference-ardupilot-bin, --reference-sut or --reference-sut-param")])
        return None
    name = given["sut"] or subject.name
    same = name == subject.name
    reference = sut_adapter.SutConfig(
        name, {**(subject.params if same else {}), **sut_param_values(given["sut_param"])},
        given["sut_fault"], given["px4_bin"] or (subject.px4_bin if same else None),
        subject.command if same else None, subject.hold if same else None,
        given["autopilot_dir"] or (subject.autopilot_dir if same and given["sut_fault"] is None else None),
        given["ardupilot_bin"] or (subject.ardupilot_bin if same else None))
    if reference == subject:
        raise InputError([Problem("--reference-sut", "", "the reference is the subject itself: give another build (--reference-px4-bin, "
                                                         "--reference-ardupilot-bin, --reference-autopilot-dir), SUT or parameters")])
    return checked_sut(reference, "--reference-sut", "--reference-sut-param")


def check_transport(transport: str, sut: SutConfig) -> None:
    import sut_adapter
    from harness.flight.stack import transport_problem

    problem = transport_problem(transport, sut_adapter.system_for(sut))
    if problem is not None:
        raise InputError([Problem("--transport", "", problem)])
