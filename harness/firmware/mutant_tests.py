"""Another test method run against each mutant: PX4's own unit tests, a project's test suite.

Each counted mutant's patch is applied in a source tree the user prepared (configured and built
once, so that the command only rebuilds what the patch touches), the command runs there, and
the mutated file is put back byte for byte before the next mutant, also when the run is stopped.
A mutant is killed when the command fails (non-zero exit) or does not end within the timeout
(a mutated loop bound can hang a test). The unmutated tree must pass first: a command that
fails on it can judge no mutant. Results go to a JSON file that `stella mutants report
--other-tests` reads, written after each mutant, so a stopped run resumes where it was.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

from harness.errors import InputError, Problem
from harness.firmware import builds
from harness.firmware.mutants import BUILT, load_index

OUT = "other_tests.json"
OUTPUT_TAIL_LINES = 12


@dataclass(frozen=True)
class Verdict:
    killed: bool
    exit: int | None  # None: timed out
    seconds: float
    why: str

    def as_json(self) -> dict:
        return {"killed": self.killed, "exit": self.exit, "seconds": round(self.seconds, 2), "why": self.why}


def run_command(command: str, tree: Path, timeout_s: float) -> Verdict:
    """The command in the tree, its whole process group ended on a timeout or an interrupt (a
    build tool's compilers must not outlive it)."""
    started = time.monotonic()
    process = subprocess.Popen(command, shell=True, cwd=tree, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, errors="replace",
                               start_new_session=True)
    try:
        output, _ = process.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        _end_group(process)
        return Verdict(True, None, time.monotonic() - started, f"timed out after {timeout_s:g} s")
    except BaseException:
        _end_group(process)
        raise
    seconds = time.monotonic() - started
    if process.returncode == 0:
        return Verdict(False, 0, seconds, "passed")
    tail = "\n".join(output.rstrip().splitlines()[-OUTPUT_TAIL_LINES:])
    return Verdict(True, process.returncode, seconds, f"exit {process.returncode}: {tail}")


def _end_group(process: subprocess.Popen) -> None:
    try:
        os.killpg(process.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    process.wait()


def _counted_mutants(folder: Path, index: dict) -> list[dict]:
    """The mutants the flights judge: built, neither equivalent nor duplicate. A stillborn one
    would fail any command that compiles it and count as killed."""
    built_path = folder / BUILT
    if not built_path.is_file():
        raise InputError([Problem(str(built_path), "", "the mutants are not built: run `stella mutants build` first, so that stillborn, "
                                                       "equivalent and duplicate mutants are left out")])
    states = {key: entry["state"] for key, entry in json.loads(built_path.read_text())["mutants"].items()}
    return [m for m in index["mutants"] if states.get(m["id"]) == "built"]


def _load(out: Path, identity: dict) -> dict:
    if not out.is_file():
        return {**identity, "mutants": {}}
    document = json.loads(out.read_text())
    differing = [key for key in identity if document.get(key) != identity[key]]
    if differing:
        raise InputError([Problem(str(out), f"/{differing[0]}", f"these results were made with another {differing[0]} ({document.get(differing[0])!r}): "
                                                                 "run with the same one, or give another --out")])
    return document


def _save(out: Path, document: dict) -> None:
    temporary = out.with_suffix(".tmp")
    temporary.write_text(json.dumps(document, indent=1) + "\n")
    temporary.replace(out)


def run(folder: Path, tree: Path, command: str, *, timeout_s: float, only: Sequence[str] = (), out: Path | None = None,
        progress: Callable[[str], None] = lambda _line: None) -> dict:
    folder, tree = Path(folder), Path(tree).expanduser().resolve()
    index = load_index(folder)
    target = tree / index["file"]
    if not target.is_file():
        raise InputError([Problem("--tree", "", f"{target} does not exist: give the source tree the mutants of {index['file']} were generated from "
                                                f"(or a worktree of it)")])
    unknown = sorted(set(only) - {m["id"] for m in index["mutants"]})
    if unknown:
        raise InputError([Problem("--only", "", f"no mutant {', '.join(unknown)} in {folder}")])
    mutants = [m for m in _counted_mutants(folder, index) if not only or m["id"] in only]
    out = Path(out) if out else folder / OUT
    document = _load(out, {"command": command, "tree": str(tree), "file": index["file"]})
    original_bytes = target.read_bytes()
    for mutant in mutants:
        check = subprocess.run(["git", "apply", "--check", str((folder / "mutants" / f"{mutant['id']}.patch").resolve())], cwd=tree,
                               capture_output=True, text=True)
        if check.returncode != 0:
            raise InputError([Problem("--tree", "", f"{mutant['id']}'s patch does not apply to {target} ({check.stderr.strip()[:300]}): "
                                                    "give a tree with the unmutated file the mutants were generated from")])
    if "original" not in document:
        verdict = run_command(command, tree, timeout_s)
        if verdict.killed:
            raise InputError([Problem("--command", "", f"it fails on the unmutated tree {tree}, so it can judge no mutant: {verdict.why}")])
        document["original"] = verdict.as_json()
        _save(out, document)
        progress(f"original: passed ({verdict.seconds:.1f} s)")
    for mutant in mutants:
        if mutant["id"] in document["mutants"]:
            continue
        try:
            builds.apply_patches(tree, [folder / "mutants" / f"{mutant['id']}.patch"])
            verdict = run_command(command, tree, timeout_s)
        finally:
            target.write_bytes(original_bytes)
        document["mutants"][mutant["id"]] = verdict.as_json()
        _save(out, document)
        progress(f"{mutant['id']}: {'killed' if verdict.killed else 'survived'} ({verdict.seconds:.1f} s)"
                 + (f": {verdict.why.splitlines()[0]}" if verdict.killed else ""))
    document["out"] = str(out)
    return document
