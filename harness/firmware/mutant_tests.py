"""Another test method run against each mutant: PX4's own unit tests, a project's test suite.

Each counted mutant's patch is applied in a source tree the user prepared (configured and built
once, so that the command only rebuilds what the patch touches), the command runs there, and
the mutated file is put back byte for byte before the next mutant, also when the run is stopped
(Ctrl-C, SIGTERM, SIGHUP; after a kill -9 the next run finds the tree's file mutated and says
so, as the file must be the one the mutants were generated from).
A mutant is killed when the command fails (non-zero exit) or does not end within the timeout
(a mutated loop bound can hang a test); a timeout is a verdict, kept like any other. The unmutated tree must pass first: a command that
fails on it can judge no mutant. Results go to a JSON file that `stella mutants report
--other-tests` reads, written after each mutant, so a stopped run resumes where it was.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import signal
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator, Sequence

from harness.errors import InputError, Problem
from harness.firmware import builds
from harness.firmware.mutants import BUILT, load_index, write_json_atomically
from harness.paths import write_atomically
from sut_adapter.processes import ManagedProcess

OUT = "other_tests.json"
OUTPUT_TAIL_LINES = 12


@dataclass(frozen=True)
class Verdict:
    killed: bool
    exit_code: int | None  # None: timed out
    seconds: float
    why: str

    def as_json(self) -> dict:
        return {"killed": self.killed, "exit_code": self.exit_code, "seconds": round(self.seconds, 2), "why": self.why}


def run_command(command: str, tree: Path, timeout_s: float, log_dir: Path, name: str) -> Verdict:
    """The command in the tree, its output in log_dir/NAME.stdout.log; its whole process group
    ended when it returns or times out (a build tool's compilers and servers must not outlive it)."""
    log_dir.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    with ManagedProcess(name, ["sh", "-c", command], log_dir=log_dir, cwd=tree) as process:
        code = process.wait(timeout_s)
    seconds = time.monotonic() - started
    if code is None:
        return Verdict(True, None, seconds, f"timed out after {timeout_s:g} s")
    if code == 0:
        return Verdict(False, 0, seconds, "passed")
    output = process.stdout_path.read_text(errors="replace") + process.stderr_path.read_text(errors="replace")
    tail = "\n".join(output.rstrip().splitlines()[-OUTPUT_TAIL_LINES:])
    return Verdict(True, code, seconds, f"exit {code}: {tail}")


@contextlib.contextmanager
def _stopped_by_signals_as_by_ctrl_c() -> Iterator[None]:
    """SIGTERM and SIGHUP raise KeyboardInterrupt, so that a stopped run puts the file back."""
    def interrupt(_signum, _frame):
        raise KeyboardInterrupt

    try:
        previous = {sig: signal.signal(sig, interrupt) for sig in (signal.SIGTERM, signal.SIGHUP)}
    except ValueError:  # not the main thread: nothing to install, nothing to restore
        yield
        return
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


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
    try:
        document = json.loads(out.read_text())
    except json.JSONDecodeError as error:
        raise InputError([Problem(str(out), "", f"not a results file of `stella mutants test` ({error}): give another --out")]) from None
    differing = [key for key in identity if document.get(key) != identity[key]]
    if differing:
        raise InputError([Problem(str(out), f"/{differing[0]}", f"these results were made with another {differing[0]} "
                                                                 f"({document.get(differing[0])!r}, now {identity[differing[0]]!r}): "
                                                                 "run with the same one, or give another --out")])
    return document


def run(folder: Path, *, tree: Path, command: str, timeout_s: float, only: Sequence[str] = (), out: Path | None = None,
        progress: Callable[[str], None] = lambda _line: None) -> dict:
    folder, tree = Path(folder), Path(tree).expanduser().resolve()
    index = load_index(folder)
    target = tree / index["file"]
    if not target.is_file():
        raise InputError([Problem("--tree", "", f"{target} does not exist: give the source tree the mutants of {index['file']} were generated from "
                                                f"(or a worktree of it)")])
    unmutated = target.read_bytes()
    if index.get("file_sha256") not in (None, hashlib.sha256(unmutated).hexdigest()):
        raise InputError([Problem("--tree", "", f"{target} differs from the file the mutants were generated from (a run stopped with kill -9 "
                                                f"may have left a mutant in it: `git checkout -- {index['file']}` in the tree)")])
    unknown = sorted(set(only) - {m["id"] for m in index["mutants"]})
    if unknown:
        raise InputError([Problem("--only", "", f"no mutant {', '.join(unknown)} in {folder}")])
    mutants = [m for m in _counted_mutants(folder, index) if not only or m["id"] in only]
    out = Path(out) if out else folder / OUT
    log_dir = out.with_name(out.stem + "-logs")
    identity = {"command": command, "tree": str(tree), "file": index["file"], "file_sha256": hashlib.sha256(unmutated).hexdigest(),
                "timeout_s": timeout_s}
    document = _load(out, identity)
    for mutant in mutants:
        check = builds.git(tree, "apply", "--check", str((folder / "mutants" / f"{mutant['id']}.patch").resolve()), check=False)
        if check.returncode != 0:
            raise InputError([Problem("--tree", "", f"{mutant['id']}'s patch does not apply to {target} ({check.stderr.strip()[:300]}): "
                                                    "give a tree with the unmutated file the mutants were generated from")])
    with _stopped_by_signals_as_by_ctrl_c():
        if "original" not in document:
            verdict = run_command(command, tree, timeout_s, log_dir, "original")
            if verdict.killed:
                raise InputError([Problem("--command", "", f"it fails on the unmutated tree {tree}, so it can judge no mutant: {verdict.why}")])
            document["original"] = verdict.as_json()
            write_json_atomically(out, document)
            progress(f"original: passed ({verdict.seconds:.1f} s)")
        for mutant in mutants:
            if mutant["id"] in document["mutants"]:
                continue
            try:
                builds.apply_patches(tree, [folder / "mutants" / f"{mutant['id']}.patch"])
                verdict = run_command(command, tree, timeout_s, log_dir, mutant["id"])
            finally:
                write_atomically(target, unmutated)
            document["mutants"][mutant["id"]] = verdict.as_json()
            write_json_atomically(out, document)
            progress(f"{mutant['id']}: {'killed' if verdict.killed else 'survived'} ({verdict.seconds:.1f} s)"
                     + (f": {verdict.why.splitlines()[0]}" if verdict.killed else ""))
    return {**document, "out": str(out), "logs": str(log_dir)}
