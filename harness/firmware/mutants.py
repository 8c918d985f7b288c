"""Mutants of one source file: generated with universalmutator's rules, kept as patches, built as
cached variants (builds.py), and sorted into what a mutation analysis may count.

Operators (universalmutator's universal, C-like and C++ or Python rules, plus ours for the
`math::min`/`math::max` family it does not know): relational and arithmetic operator
replacement, constant perturbation, condition negation, min/max swap, statement deletion, and
its other rules. Lines that only log, assert, include, or declare parameters are left alone:
a mutant there changes nothing a flight could show, or nothing at all. A mutant is one patch
(`mutants/NNNN.patch`, a unified diff against the source tree) and one entry of `mutants.json`.

Built, a mutant is *stillborn* when it does not compile, *equivalent* when its compiled code is
the original's, a *duplicate* when it is an earlier mutant's; only the rest are counted.
"""

from __future__ import annotations

import contextlib
import difflib
import hashlib
import io
import json
import re
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from harness.errors import InputError, Problem
from harness.firmware import builds
from harness.paths import write_atomically

FORMAT = "stella.mutants/1"
INDEX = "mutants.json"
BUILT = "built.json"

RULES = {".cpp": ["universal", "c_like", "cpp"], ".cc": ["universal", "c_like", "cpp"], ".hpp": ["universal", "c_like", "cpp"],
         ".h": ["universal", "c_like", "cpp"], ".c": ["universal", "c_like", "c"], ".py": ["universal", "python"]}
# Ours, in universalmutator's rule format: PX4 clamps with math::min/max and constrain, not std::.
OWN_RULES = {".cpp": [r"math::min\( ==> math::max(", r"math::max\( ==> math::min(", r"fminf\( ==> fmaxf(", r"fmaxf\( ==> fminf("]}
SKIPPED_LINES = {
    "c": [r"PX4_(INFO|WARN|ERR|DEBUG)", r"\bevents::send", r"mavlink_log_", r"\bassert\s*\(", r"DEFINE_PARAMETERS", r"\(ParamFloat<",
          r"\(ParamInt<", r"\(ParamBool<", r"^\s*#", r"^\s*//", r"perf_(alloc|free|begin|end|count)", r"^\s*[{}];?\s*$"],
    # The bundled autopilot's seeded faults (off unless a flight asks for one) are instrumentation, like logging.
    "python": [r"^\s*#", r"\blog\.(debug|info|warning|error|exception)\(", r"\blogging\.", r"^\s*assert\b", r"\bprint\(", r"^\s*(import|from)\s",
               r"\bfault\b"],
}
# universalmutator's constant rule rewrites digit runs, splitting 0.5 into 0.(5+1): replaced by
# constant_mutants, which perturbs whole literals.
DIGIT_RULE = r"(\D)(\d+)(\D)"
NUMBER = re.compile(r"(?<![\w.])(\d+\.\d*(?:[eE][-+]?\d+)?|\.\d+(?:[eE][-+]?\d+)?|\d+[eE][-+]?\d+|\d+)(f?)(?![\w.])")


@dataclass(frozen=True)
class Mutant:
    id: str
    file: str  # relative to the source tree
    line: int
    rule: str
    original: str
    mutated: str

    @property
    def patch_name(self) -> str:
        return f"{self.id}.patch"


def _language(path: Path) -> str:
    if path.suffix not in RULES:
        raise InputError([Problem(str(path), "", f"no mutation rules for {path.suffix} files; supported: {', '.join(sorted(RULES))}")])
    return "python" if path.suffix == ".py" else "c"


def function_span(lines: Sequence[str], name: str, language: str) -> tuple[int, int]:
    """First and last line (1-based) of the body of function `name`."""
    if language == "python":
        pattern = re.compile(rf"^(\s*)(async\s+)?def\s+{re.escape(name)}\s*\(")
        for index, line in enumerate(lines):
            match = pattern.match(line)
            if match:
                indent = len(match.group(1))
                end = index
                for later in range(index + 1, len(lines)):
                    text = lines[later]
                    if text.strip() and len(text) - len(text.lstrip()) <= indent:
                        break
                    end = later
                return index + 2, end + 1
    else:
        pattern = re.compile(rf"(::|^|\s){re.escape(name)}\s*\(")
        for index, line in enumerate(lines):
            if not pattern.search(line) or line.rstrip().endswith(";") or line.startswith((" ", "\t")):
                continue
            depth, body = 0, None
            for later in range(index, len(lines)):
                code = lines[later].split("//")[0]
                depth += code.count("{") - code.count("}")
                if body is None and "{" in code:
                    body = later + 2  # the line after the one that opens it
                if later > index and code.rstrip().endswith(";") and body is None:
                    break  # a declaration spread over lines
                if body is not None and depth == 0:
                    return body, later
    raise InputError([Problem("--function", "", f"no definition of {name!r} found; give a function defined in the file")])


def _universal_mutants(lines: list[str], suffix: str, skipped: list[str]) -> list[tuple[int, str, str]]:
    from universalmutator import mutator

    rules = list(RULES[suffix])
    own = OWN_RULES.get(suffix)
    with contextlib.ExitStack() as stack:
        if own:
            rule_file = stack.enter_context(_rules_file(own))
            rules.append(rule_file)
        # universalmutator reports on stdout; a library keeps quiet (our own stdout carries --json).
        stack.enter_context(contextlib.redirect_stdout(io.StringIO()))
        found = mutator.mutants_regexp(lines, ruleFiles=rules, ignorePatterns=skipped, ignoreStringOnly=True)
    return [(lineno, mutated, rule[0]) for lineno, mutated, rule, _pattern in found if rule[0].split(" ==> ")[0] != DIGIT_RULE]


def _literal(value: float, is_float: bool) -> str:
    text = repr(float(value)) if is_float else str(int(value))
    return f"({text})" if value < 0 else text


def constant_mutants(lines: Sequence[str], skipped: Sequence[str], excluded: set[int]) -> list[tuple[int, str, str]]:
    """Each numeric literal replaced by 0, 1, -1, half and twice its value, and (integers) one
    more and one less; not in comments, strings or skipped lines."""
    patterns = [re.compile(p) for p in skipped]
    found = []
    for lineno, line in enumerate(lines, 1):
        if lineno in excluded or any(p.search(line) for p in patterns):
            continue
        code = re.split(r"//|#", line, maxsplit=1)[0]
        for match in NUMBER.finditer(code):
            if code[: match.start()].count('"') % 2 or code[: match.start()].count("'") % 2:
                continue
            text, suffix = match.group(1), match.group(2)
            is_float = any(c in text for c in ".eE")
            value = float(text)
            options = {0.0, 1.0, -1.0, value / 2, value * 2} | ({value + 1, value - 1} if not is_float else set())
            for option in sorted(options - {value}):
                literal = _literal(option, is_float) + suffix
                found.append((lineno, line[: match.start()] + literal + line[match.end():], f"constant {text} ==> {literal}"))
    return found


def _docstring_lines(lines: Sequence[str]) -> set[int]:
    """Lines of Python string statements (docstrings): text, not code."""
    import ast

    try:
        tree = ast.parse("".join(lines))
    except SyntaxError:
        return set()
    return {n for node in ast.walk(tree) if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str)
            for n in range(node.lineno, node.end_lineno + 1)}


@contextlib.contextmanager
def _rules_file(rules: list[str]):
    import tempfile

    with tempfile.NamedTemporaryFile("w", suffix=".rules", delete=True) as file:
        file.write("\n".join(rules) + "\n")
        file.flush()
        yield file.name


def generate(source: Path, file: str, out: Path, *, function: str | None = None, limit: int | None = None, seed: int = 0) -> dict:
    """Write the mutants of `file` (relative to the source tree) to out/mutants/ and out/mutants.json."""
    source = Path(source).expanduser().resolve()
    builds.tree_kind(source)
    path = source / file
    if not path.is_file():
        raise InputError([Problem("--file", "", f"{path} does not exist: give a path relative to --source")])
    language = _language(path)
    lines = path.read_text().splitlines(keepends=True)
    first, last = function_span(lines, function, language) if function else (1, len(lines))
    excluded = _docstring_lines(lines) if language == "python" else set()
    found = [m for m in _universal_mutants(lines, path.suffix, SKIPPED_LINES[language]) + constant_mutants(lines, SKIPPED_LINES[language], excluded)
             if first <= m[0] <= last and m[0] not in excluded]
    # A mutant that compiles the same source twice (two rules, one text) is written once.
    unique = list({(lineno, mutated): (lineno, mutated, rule) for lineno, mutated, rule in found}.values())
    chosen = unique
    if limit is not None and limit < len(unique):
        # A prefix of one seeded permutation: a larger --limit keeps every mutant a smaller one took.
        picked = np.random.default_rng(seed).permutation(len(unique))[:limit]
        chosen = [unique[i] for i in sorted(picked)]
    folder = Path(out) / "mutants"
    folder.mkdir(parents=True, exist_ok=True)
    mutants = []
    for number, (lineno, mutated, rule) in enumerate(chosen, 1):
        mutant = Mutant(f"m{number:04d}", file, lineno, rule, lines[lineno - 1].rstrip("\n"), mutated.rstrip("\n"))
        changed = lines[: lineno - 1] + mutated.splitlines(keepends=True) + lines[lineno:]
        diff = difflib.unified_diff(lines, changed, f"a/{file}", f"b/{file}", n=3)
        (folder / mutant.patch_name).write_text("".join(diff))
        mutants.append(mutant)
    commit = builds.git(source, "rev-parse", "HEAD", check=False).stdout.strip() if (source / ".git").exists() else None
    index = {"format": FORMAT, "source": str(source), "commit": commit or None, "kind": builds.tree_kind(source), "file": file,
             "file_sha256": hashlib.sha256(path.read_bytes()).hexdigest(), "function": function,
             "lines": [first, last], "generated": len(unique), "limit": limit, "seed": seed, "mutants": [asdict(m) for m in mutants]}
    (Path(out) / INDEX).write_text(json.dumps(index, indent=1) + "\n")
    return index


def load_index(out: Path) -> dict:
    path = Path(out) / INDEX
    if not path.is_file():
        raise InputError([Problem(str(path), "", "no mutants here: give the --out folder of `stella mutants generate`")])
    document = json.loads(path.read_text())
    if document.get("format") != FORMAT:
        raise InputError([Problem(str(path), "/format", f"expected {FORMAT!r}: not a mutants index of this tool")])
    return document


def build_all(out: Path, *, cache: Path | None = None, jobs: int | None = None, only: Sequence[str] = (), worktree_command: str | None = None,
              progress: Callable[[str], None] = lambda _line: None, coverage_paths: Sequence[str] | None = None) -> dict:
    """Build the original and each mutant (cached); sort them into built, stillborn, equivalent
    and duplicate; write out/built.json after each, so an interrupted build resumes.
    `coverage_paths`: coverage builds (builds.build), whose flights record the code they ran."""
    out = Path(out)
    index = load_index(out)
    cache = Path(cache) if cache else out / "builds"
    source = Path(index["source"])
    commit = index["commit"] if index["kind"] != "bundled" else None
    built_path = out / BUILT
    record = json.loads(built_path.read_text()) if built_path.is_file() else {"mutants": {}}
    coverage = None if coverage_paths is None else builds.coverage_paths_of(source, index["kind"], coverage_paths)
    if record["mutants"] and record.get("coverage") != coverage:
        raise InputError([Problem(str(built_path), "/coverage", f"this folder's mutants were built {'with coverage of ' + ', '.join(record['coverage']) if record.get('coverage') else 'without coverage'}: "
                                                                 "build them alike, or generate the mutants again into another folder (the same --seed gives the same ones)")])
    record["coverage"] = coverage
    original = builds.build(source, out=cache, commit=commit, jobs=jobs, watch=[index["file"]], worktree_command=worktree_command, coverage_paths=coverage)
    baseline = original.objects.get(index["file"])
    record["original"] = {"folder": original.folder, "build_s": original.build_s, "key": original.key, "digest": baseline}
    by_digest: dict[str, str] = {}
    for entry in sorted(record["mutants"].values(), key=lambda e: e["id"]):
        if entry.get("digest") and entry["state"] == "built":
            by_digest.setdefault(entry["digest"], entry["id"])
    for mutant in index["mutants"]:
        if only and mutant["id"] not in only:
            continue
        if mutant["id"] in record["mutants"]:
            continue
        patch = out / "mutants" / f"{mutant['id']}.patch"
        try:
            variant = builds.build(source, out=cache, commit=commit, patches=[patch], jobs=jobs, watch=[index["file"]], worktree_command=worktree_command,
                                   coverage_paths=coverage)
        except builds.BuildFailed as failed:
            entry = {"id": mutant["id"], "state": "stillborn", "log": str(failed.log_path)}
        else:
            digest = variant.objects.get(index["file"])
            state = "built"
            if digest == baseline:
                state = "equivalent"
            elif digest in by_digest:
                state = "duplicate"
            else:
                by_digest[digest] = mutant["id"]
            entry = {"id": mutant["id"], "state": state, "folder": variant.folder, "digest": digest, "build_s": variant.build_s,
                     "cached": variant.cached, **({"same_as": by_digest[digest]} if state == "duplicate" else {})}
        record["mutants"][mutant["id"]] = entry
        write_json_atomically(built_path, record)
        progress(f"{mutant['id']} {entry['state']}" + (f" ({entry['build_s']:.1f} s)" if "build_s" in entry and not entry.get("cached") else ""))
    write_json_atomically(built_path, record)
    return record


def write_json_atomically(path: Path, document: dict) -> None:
    write_atomically(path, (json.dumps(document, indent=1) + "\n").encode())


def counts(record: dict) -> dict[str, int]:
    states = [entry["state"] for entry in record["mutants"].values()]
    return {state: states.count(state) for state in ("built", "stillborn", "equivalent", "duplicate")}
