"""A SUT flown on another machine or in a container: the folders of this machine its build needs,
where they appear there, and a command that says whether it can start there.

Executors that fly elsewhere (docker, dask) use these so that a SUT which cannot start where
they fly is refused once, before the campaign, rather than crashing every evaluation.
"""

from __future__ import annotations

import shlex
from dataclasses import dataclass, replace
from pathlib import Path

from sut_adapter.base import SutConfig, SutError


# The start check of a SUT with nothing of this machine's to start (the bundled autopilot).
NOTHING_TO_CHECK = "true"
# How long a program's help may take in a start check before it counts as started.
HELP_TIMEOUT_S = 30


@dataclass(frozen=True)
class BuildFolder:
    """A folder of this machine a SUT's configuration names (its build), the option that names
    it, and the path of what the option names inside it."""

    option: str  # the SutConfig field: px4_bin, ardupilot_bin, autopilot_dir
    folder: Path
    inside: str  # relative to folder; "." for the folder itself
    program: str | None  # relative to folder: an executable that must start where it is flown


def build_folders(config: SutConfig) -> list[BuildFolder]:
    """The folders of this machine the SUT needs, resolved as its adapter resolves them (a build
    named by STELLA_PX4_BIN included); SutError where the build is not there."""
    from sut_adapter.ardupilot import resolve_binary as resolve_arducopter
    from sut_adapter.px4 import resolve_binary as resolve_px4

    folders = []
    if config.px4_bin or config.name == "px4":
        binary, _etc = resolve_px4(config.px4_bin)
        build = binary.parent.parent
        folders.append(BuildFolder("px4_bin", build, ".", str(binary.relative_to(build))))
    if config.ardupilot_bin or config.name == "ardupilot":
        binary = resolve_arducopter(config.ardupilot_bin)
        folders.append(BuildFolder("ardupilot_bin", binary.parent, binary.name, binary.name))
    if config.autopilot_dir:
        folder = Path(config.autopilot_dir).expanduser().resolve()
        if not (folder / "autopilot").is_dir():
            raise SutError(config.name, f"--autopilot-dir {folder} has no autopilot package")
        folders.append(BuildFolder("autopilot_dir", folder, ".", None))
    return folders


def relocated(config: SutConfig, mount_points: dict[str, str]) -> SutConfig:
    """The configuration as it reads where each option's folder is mounted at mount_points[option]."""
    changes = {}
    for build in build_folders(config):
        changes[build.option] = str(Path(mount_points[build.option]) / build.inside) if build.inside != "." else mount_points[build.option]
    return replace(config, **changes)


def start_check(config: SutConfig, mount_points: dict[str, str]) -> str:
    """A shell command that fails, saying why on its output, where the SUT cannot start: its
    programs missing, not executable or lacking a shared library, or a command SUT's program
    not found."""
    checks = []
    for build in build_folders(config):
        if build.program is None:
            continue
        program = shlex.quote(str(Path(mount_points[build.option]) / build.program))
        # A program that cannot be loaded exits 126 or 127 with the loader's complaint; any other
        # end of its help (or timeout's 124 for one that ignores -h) means it started.
        checks.append(f"test -x {program} || {{ echo '{build.program} is not there or not executable'; exit 1; }}; "
                      f"out=$(timeout {HELP_TIMEOUT_S} {program} -h 2>&1 </dev/null); code=$?; "
                      f"if [ $code -eq 126 ] || [ $code -eq 127 ]; then echo \"{build.program} cannot start: $out\" | head -c 600; exit 1; fi")
    if config.command:
        program = shlex.split(config.command)[0]
        checks.append(f"command -v {shlex.quote(program)} >/dev/null || {{ echo 'the command {program} is not found'; exit 1; }}")
    return "; ".join(checks) or NOTHING_TO_CHECK


def mount_points(config: SutConfig, root: str = "/sut") -> dict[str, str]:
    """Where each of the SUT's build folders is mounted, under root."""
    return {build.option: f"{root}/{build.option}" for build in build_folders(config)}
