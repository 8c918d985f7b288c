"""The files the campaign page offers: logical scenarios, QGroundControl plans and SUT parameter
files, each either under scenarios/ or uploaded into the store directory's uploads/.

An upload is kept only once it passed the check the command line gives such a file (a scenario
as `stella validate` checks it, a plan as `--mission-plan` reads it, a parameter file as
`--sut-params-file` reads it), under a name of letters, digits, _ and - that the page offers as
`uploads/NAME.SUFFIX`. A choice the browser sends is found only inside those two folders.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from harness.errors import InputError, Problem
from harness.interop.param_files import load_params_file
from harness.paths import scenarios_dir
from harness.scenario.documents import load_json
from harness.scenario.logical import logical_problems
from harness.scenario.plan import plan_problems
from harness.scenario.profile import load_profile

UPLOADS = "uploads"
MAX_UPLOAD_BYTES = 256 * 1024


def inside(base: Path, relative: str) -> Path | None:
    """base/relative if it stays inside base (no `..`, no absolute path, no symlink out), else None."""
    if not relative or relative.startswith("/") or "\\" in relative:
        return None
    candidate = (base / relative).resolve()
    return candidate if candidate.is_relative_to(base.resolve()) else None


def _scenario_problems(path: Path, filename: str, profile: str) -> list[Problem]:
    return logical_problems(load_json(path), load_profile(profile), filename)


def _plan_problems(path: Path, filename: str, _profile: str) -> list[Problem]:
    return plan_problems(load_json(path), filename)


def _params_problems(path: Path, _filename: str, _profile: str) -> list[Problem]:
    load_params_file(path)
    return []


@dataclass(frozen=True)
class Kind:
    """One kind of file the page offers."""

    what: str  # as a message names it: "a logical scenario"
    suffixes: tuple[str, ...]  # an upload with another suffix gets the first
    problems: Callable[[Path, str, str], list[Problem]]  # (the file, its name as uploaded, profile): what is wrong with it
    bundled: bool  # whether scenarios/ holds some


KINDS = {
    "scenario": Kind("a logical scenario", (".json",), _scenario_problems, bundled=True),
    "plan": Kind("a QGroundControl plan", (".plan",), _plan_problems, bundled=True),
    "params": Kind("a parameter file", (".params", ".csv", ".txt"), _params_problems, bundled=False),
}


def _bundled(path: Path) -> bool:
    return "schema" not in path.parts and "profiles" not in path.parts


class Uploads:
    def __init__(self, store_dir: Path):
        self.folder = store_dir / UPLOADS
        self.folder.mkdir(parents=True, exist_ok=True)

    def choices(self, kind: str) -> list[str]:
        """What the page offers of a kind: `scenarios/...` files, then `uploads/...` files."""
        suffixes = KINDS[kind].suffixes
        bundled = sorted(f"scenarios/{p.relative_to(scenarios_dir()).as_posix()}" for p in scenarios_dir().rglob("*")
                         if p.suffix in suffixes and _bundled(p.relative_to(scenarios_dir()))) if KINDS[kind].bundled else []
        return bundled + sorted(f"{UPLOADS}/{p.name}" for p in self.folder.iterdir() if p.suffix in suffixes)

    def resolve(self, kind: str, choice: object) -> Path | None:
        """The file a choice names, if it is one the page offers of that kind."""
        if not isinstance(choice, str):
            return None
        prefix, _, rest = choice.partition("/")
        base = {"scenarios": scenarios_dir() if KINDS[kind].bundled else None, UPLOADS: self.folder}.get(prefix)
        path = inside(base, rest) if base is not None else None
        return path if path is not None and path.suffix in KINDS[kind].suffixes and path.is_file() else None

    def add(self, kind: str, filename: str, data: bytes, profile: str = "default") -> tuple[str | None, list[Problem]]:
        """Check an uploaded file and keep it if it is sound: (its choice, problems)."""
        suffixes = KINDS[kind].suffixes
        stem = re.sub(r"[^A-Za-z0-9_-]+", "_", Path(filename).stem).strip("_")[:60] or kind
        suffix = Path(filename).suffix.lower()
        target = self.folder / f"{stem}{suffix if suffix in suffixes else suffixes[0]}"
        pending = target.with_name(target.name + ".pending")
        pending.write_bytes(data)
        try:
            try:
                problems = KINDS[kind].problems(pending, filename, profile)
            except InputError as error:  # the file as a whole: its syntax, its lines
                problems = [Problem(filename, p.pointer, p.message) for p in error.problems]
            if problems:
                return None, problems
            pending.replace(target)
            return f"{UPLOADS}/{target.name}", []
        finally:
            pending.unlink(missing_ok=True)
