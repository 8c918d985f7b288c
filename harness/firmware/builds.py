"""Firmware variants built from source and cached: a variant is (source tree, commit, patches,
build configuration); its build is kept under a key made of those, so asking again is instant,
and it is just another SUT configuration (`px4_bin` of the variant, or the bundled autopilot's
`autopilot_dir`).

PX4: one git worktree per commit under the cache (`worktrees/COMMIT`), its submodules those the
source tree has initialised, at the commit's pins; a variant's patches applied there, the build
incremental (after the first, a patch of one file recompiles that object and links), then the
patched files put back. The variant keeps `bin/` and `etc/` (what a flight needs), its build log,
and a digest of each patched file's object code with the debug information stripped: two
variants whose objects are byte for byte the same are the same program (trivial compiler
equivalence, used to drop equivalent and duplicate mutants).

ArduPilot (ArduCopter SITL): the same worktree per commit and patches, built by its waf
(`configure --board sitl`, then `copter`); the variant keeps `bin/arducopter`.

The bundled autopilot: its package copied, the patches applied, and the patched modules that the
project compiles (setup.py) compiled again the way `make setup` does; the digest is the Python
bytecode's (line numbers left out), which is what a compiled module computes too.

A coverage build (`coverage_paths`) is another build configuration: its flights record which of
those paths' lines and branches ran (sut_adapter/coverage.py). The bundled autopilot then runs as
its Python sources, under coverage.py. PX4's measured paths only are compiled with gcov (a CMake
file of ours); ArduPilot has no such switch, so its whole build is, with its own `--coverage`.
"""

from __future__ import annotations

import dis
import hashlib
import json
import logging
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Iterable, Sequence

from harness.errors import InputError, Problem, StellaError
from harness.paths import write_atomically
from sut_adapter.coverage import GCOV_TOOL, NOTES_DIR, PYTHON_TOOL, mark_coverage_build

log = logging.getLogger(__name__)

PX4_CONFIG = "px4_sitl_default"
ARDUPILOT_CONFIG = "sitl-copter"
BUNDLED_CONFIG = "bundled"
SUT_OPTION = {"px4": "px4_bin", "ardupilot": "ardupilot_bin", "bundled": "autopilot_dir"}  # the SutConfig field that flies a kind's build
VARIANT_FILE = "variant.json"
BUILD_LOG = "build.log"
DIGEST_LOG = "digest.log"  # a compile again for the digests of files a cached variant did not watch
# What a coverage build measures unless told: the collision prevention.
DEFAULT_COVERAGE_PATHS = {"bundled": ("autopilot/collision.py",), "px4": ("src/lib/collision_prevention",),
                          "ardupilot": ("libraries/AC_Avoidance", "libraries/AP_Proximity")}


class BuildFailed(StellaError):
    """A variant's sources do not compile (a mutant that does not is *stillborn*); the log is kept."""

    exit_code = 2

    def __init__(self, what: str, log_path: Path, tail: str):
        self.log_path = log_path
        super().__init__(f"{what} failed to build; log: {log_path}\n{tail}")


@dataclass(frozen=True)
class Variant:
    """A built variant as the cache keeps it (VARIANT_FILE in its folder)."""

    key: str
    kind: str  # "px4", "ardupilot" or "bundled"
    source: str
    commit: str | None
    patches: tuple[str, ...]  # the patches' digests, in the order applied
    folder: str
    build_s: float
    objects: dict[str, str] = field(default_factory=dict)  # patched file -> digest of its compiled code
    cached: bool = False  # found in the cache rather than built by this request

    def sut_options(self) -> dict[str, str]:
        """The SUT configuration that flies this build."""
        return {SUT_OPTION[self.kind]: self.folder}

    @property
    def program_digest(self) -> str:
        """One digest of every patched file's compiled code: equal digests, equal programs."""
        return hashlib.sha256(json.dumps(self.objects, sort_keys=True).encode()).hexdigest()


def tree_kind(source: Path) -> str:
    """"px4" for a PX4-Autopilot tree, "ardupilot" for an ArduPilot one, "bundled" for a checkout of
    this project (its autopilot)."""
    if (source / "boards" / "px4" / "sitl").is_dir() and (source / "platforms" / "posix").is_dir():
        return "px4"
    if (source / "ArduCopter").is_dir() and (source / "libraries" / "AP_HAL_SITL").is_dir() and (source / "waf").is_file():
        return "ardupilot"
    if (source / "autopilot" / "__main__.py").is_file() and (source / "autopilot" / "collision.py").is_file():
        return "bundled"
    raise InputError([Problem(str(source), "", "neither a PX4-Autopilot source tree (boards/px4/sitl, platforms/posix), an ArduPilot one "
                                               "(ArduCopter, libraries/AP_HAL_SITL, waf) nor a checkout of this project (autopilot/): "
                                               "give --source the root of one")])


def git(source: Path, *args: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(["git", "-C", str(source), *args], capture_output=True, text=True, check=check)


def resolve_commit(source: Path, commit: str | None) -> str:
    """The full hash of `commit` in the source tree (HEAD when None)."""
    if not (source / ".git").exists():
        raise InputError([Problem(str(source), "", "not a git work tree: builds of a commit need the tree's history (give a clone)")])
    found = git(source, "rev-parse", "--verify", "--quiet", f"{commit or 'HEAD'}^{{commit}}", check=False)
    if found.returncode != 0:
        raise InputError([Problem("--commit", "", f"{commit!r} is not a commit of {source}: give a hash, branch or tag that `git log` shows there")])
    return found.stdout.strip()


def patch_digest(patch: Path) -> str:
    if not patch.is_file():
        raise InputError([Problem(str(patch), "", "no such patch file: give a unified diff made with `git diff` in the source tree")])
    return hashlib.sha256(patch.read_bytes()).hexdigest()


def variant_key(kind: str, commit: str | None, patches: Sequence[str], config: str) -> str:
    return hashlib.sha256(json.dumps([kind, commit, list(patches), config]).encode()).hexdigest()[:20]


def _patched_files(patch: Path) -> list[str]:
    files = []
    for line in patch.read_text(errors="replace").splitlines():
        if line.startswith("+++ ") and not line.startswith("+++ /dev/null"):
            name = line[4:].split("\t")[0]
            files.append(name[2:] if name.startswith("b/") else name)
    return files


def apply_patches(folder: Path, patches: Sequence[Path]) -> list[str]:
    """Apply the patches in order; the files they touch. A patch that does not apply is the user's."""
    touched: list[str] = []
    for patch in patches:
        check = subprocess.run(["git", "apply", "--check", str(patch.resolve())], cwd=folder, capture_output=True, text=True)
        if check.returncode != 0:
            raise InputError([Problem(str(patch), "", f"does not apply to {folder}: {check.stderr.strip()[:400]}")])
        subprocess.run(["git", "apply", str(patch.resolve())], cwd=folder, capture_output=True, text=True, check=True)
        touched += [f for f in _patched_files(patch) if f not in touched]
    return touched


def _cached(folder: Path) -> Variant | None:
    record = folder / VARIANT_FILE
    if not record.is_file():
        return None
    document = json.loads(record.read_text())
    return Variant(**{**document, "patches": tuple(document["patches"]), "cached": True})


def _save(variant: Variant) -> Variant:
    write_atomically(Path(variant.folder) / VARIANT_FILE, json.dumps({k: v for k, v in asdict(variant).items() if k != "cached"}, indent=1).encode())
    return variant


def build(source: Path, *, out: Path, commit: str | None = None, patches: Sequence[Path] = (), jobs: int | None = None,
          watch: Sequence[str] = (), worktree_command: str | None = None, coverage_paths: Sequence[str] | None = None) -> Variant:
    """The variant of the source tree at commit with the patches applied, from the cache or built;
    its `objects` digest the compiled code of the patched files and of those in `watch`.
    `coverage_paths` (files or folders of the tree) make it a coverage build measuring them."""
    source = Path(source).expanduser().resolve()
    if not source.is_dir():
        raise InputError([Problem(str(source), "", "no such folder: give --source the root of a PX4-Autopilot or ArduPilot tree, or of this project")])
    kind = tree_kind(source)
    digests = tuple(patch_digest(Path(p)) for p in patches)
    resolved = resolve_commit(source, commit) if kind != "bundled" or commit else None
    config = {"px4": PX4_CONFIG, "ardupilot": ARDUPILOT_CONFIG}.get(kind, BUNDLED_CONFIG)
    if coverage_paths is not None:
        coverage_paths = coverage_paths_of(source, kind, coverage_paths)
        config += "+coverage:" + ",".join(coverage_paths)
    key = variant_key(kind, resolved, digests, config)
    folder = Path(out).expanduser().resolve() / key
    found = _cached(folder)
    if found is not None:
        unwatched = [name for name in watch if name not in found.objects]
        if not unwatched:
            return found
        # Built before without these files watched (`stella sut build`): the digests a mutant's
        # build is compared with are missing, and equivalent mutants would pass for built ones.
        if kind != "bundled":
            objects = _firmware_builder(kind)(source, resolved, [Path(p) for p in patches], folder, Path(out).expanduser().resolve(), jobs, unwatched,
                                              worktree_command, coverage_paths, keep=False)
        else:
            objects = {name: bytecode_digest((folder / name).read_text(), name) for name in unwatched}
        return _save(replace(found, objects={**found.objects, **objects}))
    if folder.exists():  # a build that was interrupted: start it again
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    started = time.monotonic()
    # A failed build keeps its folder for the log, but has no VARIANT_FILE: never taken for a build.
    if kind != "bundled":
        objects = _firmware_builder(kind)(source, resolved, [Path(p) for p in patches], folder, Path(out).expanduser().resolve(), jobs, watch,
                                          worktree_command, coverage_paths)
    else:
        objects = _build_bundled(source, resolved, [Path(p) for p in patches], folder, watch)
        if coverage_paths is not None:
            # coverage.py traces Python sources, which compute what the compiled modules do; the
            # compiled ones reach each other's C functions (cimport), so none of them can stay.
            for compiled in (folder / "autopilot").glob("*.so"):
                compiled.unlink()
            mark_coverage_build(folder, PYTHON_TOOL, coverage_paths)
    return _save(Variant(key, kind, str(source), resolved, digests, str(folder), time.monotonic() - started, objects))


# -- PX4 ---------------------------------------------------------------------------------------


def _initialised_submodules(source: Path) -> list[str]:
    status = git(source, "submodule", "status", check=False)
    return [line[1:].split()[1] for line in status.stdout.splitlines() if line and line[0] != "-"]


def _worktree(source: Path, commit: str, cache: Path, log_file, command: str | None) -> Path:
    """The cache's worktree of the commit, made once; its submodules those the source tree uses.
    `command` (a template with {source}, {commit}, {dir}) makes it instead, for trees that need
    more than `git worktree add` and `git submodule update` (sparse checkouts, local mirrors,
    board edits); it runs once per commit."""
    tree = cache / "worktrees" / commit[:12]
    if (tree / ".git").exists():
        return tree
    tree.parent.mkdir(parents=True, exist_ok=True)
    if command:
        argv = ["sh", "-c", command.format(source=source, commit=commit, dir=tree)]
        log_file.write(f"$ {argv[2]}\n")
        log_file.flush()
        made = subprocess.run(argv, stdout=log_file, stderr=subprocess.STDOUT)
        if made.returncode != 0 or not (tree / ".git").exists():
            raise InputError([Problem("--worktree-command", "", f"exited {made.returncode} without making a worktree at {tree}; see {log_file.name}")])
        return tree
    made = git(source, "worktree", "add", "--detach", str(tree), commit, check=False)
    log_file.write(made.stdout + made.stderr)
    if made.returncode != 0:
        raise InputError([Problem(str(source), "", f"cannot make a worktree of {commit[:12]}: {made.stderr.strip()[:400]}")])
    modules = _initialised_submodules(source)
    if modules:
        updated = git(tree, "submodule", "update", "--init", "--recursive", "--", *modules, check=False)
        log_file.write(updated.stdout + updated.stderr)
        if updated.returncode != 0:
            raise InputError([Problem(str(tree), "", f"its submodules ({', '.join(modules)}) cannot be checked out at {commit[:12]}'s pins: "
                                                     f"{updated.stderr.strip()[-400:]}; make them reachable (git's url.<mirror>.insteadOf) and build again")])
    return tree


def _outputs_of(build_dir: Path, source_file: str, suffix: str) -> list[Path]:
    """The build's outputs of one source file with that suffix: CMake's NAME.o, waf's NAME.N.o."""
    name = Path(source_file).name
    return sorted({*build_dir.glob(f"**/{name}{suffix}"), *build_dir.glob(f"**/{name}.[0-9]{suffix}")})


def _object_digest(build_dir: Path, source_file: str) -> str | None:
    """The stripped object code of one source file of the build (None: it compiles into none)."""
    candidates = _outputs_of(build_dir, source_file, ".o")
    candidates = [c for c in candidates if Path(source_file).parent.name in c.as_posix()] or candidates
    if not candidates:
        return None
    with tempfile.NamedTemporaryFile(suffix=".o") as stripped:
        subprocess.run(["objcopy", "--strip-debug", str(candidates[0]), stripped.name], check=True, capture_output=True)
        return hashlib.sha256(Path(stripped.name).read_bytes()).hexdigest()


# A coverage build's CMake, included by PX4's configuration (CMAKE_PROJECT_INCLUDE): once every
# directory is configured, the targets of the measured folders (and the measured files) compile
# with gcov's instrumentation, their notes naming sources relative to the tree, and px4 links
# gcov's runtime. Atomic counters, as PX4's own Coverage build type: PX4 runs many threads.
COVERAGE_CMAKE = """# Written by stella (harness/firmware/builds.py): gcov on STELLA_COVERAGE_PATHS only.
if(NOT STELLA_COVERAGE_DEFERRED)
  set(STELLA_COVERAGE_DEFERRED TRUE)
  cmake_language(DEFER DIRECTORY ${CMAKE_SOURCE_DIR} CALL stella_coverage_flags)
endif()
function(stella_coverage_flags)
  set(flags --coverage -fprofile-update=atomic -fprofile-prefix-map=${CMAKE_SOURCE_DIR}=.)
  string(REPLACE "," ";" paths "${STELLA_COVERAGE_PATHS}")
  foreach(path IN LISTS paths)
    set(measured ${CMAKE_SOURCE_DIR}/${path})
    if(IS_DIRECTORY ${measured})
      get_property(targets DIRECTORY ${measured} PROPERTY BUILDSYSTEM_TARGETS)
      foreach(target IN LISTS targets)
        target_compile_options(${target} PRIVATE ${flags})
      endforeach()
    else()
      get_filename_component(folder ${measured} DIRECTORY)
      set_property(SOURCE ${measured} DIRECTORY ${folder} APPEND PROPERTY COMPILE_OPTIONS ${flags})
    endif()
  endforeach()
  target_link_options(px4 PRIVATE --coverage)
endfunction()
"""
COVERAGE_SUFFIX = "_coverage"  # its build folder beside px4_sitl_default: switching between them recompiles nothing


def _build_px4(source: Path, commit: str, patches: list[Path], folder: Path, cache: Path, jobs: int | None, watch: Sequence[str],
               worktree_command: str | None, coverage_paths: Sequence[str] | None = None, keep: bool = True) -> dict[str, str]:
    """Compile the commit with the patches in its worktree; the digests of the patched and watched
    files' objects. keep: the variant's folder takes what a flight needs (else only the digests
    are wanted, and the folder and its build log stay as they are)."""
    log_path = folder / (BUILD_LOG if keep else DIGEST_LOG)
    with open(log_path, "w") as log_file:
        tree = _worktree(source, commit, cache, log_file, worktree_command)
        touched = apply_patches(tree, patches)
        try:
            # The cache's worktree keeps the submodules at the pins checked out above; PX4's own
            # submodule update would reach for the network.
            env = {**os.environ, "GIT_SUBMODULES_ARE_EVIL": "1"}
            argv = ["make", PX4_CONFIG, f"-j{jobs or len(os.sched_getaffinity(0))}"]
            build_dir = tree / "build" / PX4_CONFIG
            if coverage_paths is not None:
                include = cache / "stella_coverage.cmake"
                include.write_text(COVERAGE_CMAKE)
                argv += [f"BUILD_DIR_SUFFIX={COVERAGE_SUFFIX}",
                         f"CMAKE_ARGS=-DCMAKE_PROJECT_INCLUDE={include} -DSTELLA_COVERAGE_PATHS={','.join(coverage_paths)}"]
                build_dir = tree / "build" / (PX4_CONFIG + COVERAGE_SUFFIX)
            log_file.write(f"$ {' '.join(argv)}  (in {tree})\n")
            log_file.flush()
            built = subprocess.run(argv, cwd=tree, stdout=log_file, stderr=subprocess.STDOUT, env=env)
            if built.returncode != 0:
                raise BuildFailed(f"PX4 {commit[:12]} with {len(patches)} patch(es)", log_path, _tail(log_path))
            objects = {name: digest for name in dict.fromkeys([*touched, *watch]) if (digest := _object_digest(build_dir, name))}
            if not keep:
                return objects
            for part in ("bin", "etc"):
                shutil.copytree(build_dir / part, folder / part, symlinks=True)
            if coverage_paths is not None:
                _keep_notes(tree, build_dir, folder, coverage_paths)
                mark_coverage_build(folder, GCOV_TOOL, coverage_paths, build_dir=str(build_dir))
        finally:
            if touched:  # the next variant starts from the commit's own files
                git(tree, "checkout", "--", *touched, check=False)
    return objects


def _keep_notes(tree: Path, build_dir: Path, folder: Path, paths: Sequence[str]) -> None:
    """A PX4 coverage build's notes (.gcno) of the measured objects and the sources they were
    compiled from (patches applied), kept in the variant: a flight's counters are read against
    them, whatever the worktree holds by then."""
    notes = folder / NOTES_DIR
    for path in paths:
        objects = build_dir / path
        for gcno in sorted(objects.glob("**/*.gcno")) if objects.is_dir() else _outputs_of(objects.parent, objects.name, ".gcno"):
            target = notes / "notes" / gcno.relative_to(build_dir)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(gcno, target)
        measured = tree / path
        target = notes / "sources" / path
        target.parent.mkdir(parents=True, exist_ok=True)
        if measured.is_dir():
            shutil.copytree(measured, target, dirs_exist_ok=True)
        else:
            shutil.copy2(measured, target)
    if not any(notes.glob("**/*.gcno")):
        raise BuildFailed(f"the coverage build of {', '.join(paths)}", folder / BUILD_LOG,
                          f"no object of {', '.join(paths)} was compiled with gcov: do they hold sources that the build compiles?")


def _firmware_builder(kind: str):
    """The function that builds a firmware kind's variant (ArduPilot's in harness/firmware/ardupilot_build.py)."""
    if kind == "ardupilot":
        from harness.firmware.ardupilot_build import build_ardupilot

        return build_ardupilot
    return _build_px4


def _tail(path: Path, lines: int = 25) -> str:
    return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])


# -- the bundled autopilot ---------------------------------------------------------------------


def bytecode_digest(source_text: str, filename: str = "<mutant>") -> str:
    """The module's bytecode with line numbers left out: what it computes, not where it says so."""
    digest = hashlib.sha256()

    def walk(code) -> None:
        for instruction in dis.get_instructions(code):
            digest.update(f"{instruction.opname} {instruction.argrepr if not hasattr(instruction.argval, 'co_code') else ''}\n".encode())
        for constant in code.co_consts:
            if hasattr(constant, "co_code"):
                digest.update(f"code {constant.co_name}\n".encode())
                walk(constant)

    walk(compile(source_text, filename, "exec"))
    return digest.hexdigest()


def project_root() -> Path:
    return Path(__file__).resolve().parents[2]


def _build_bundled(source: Path, commit: str | None, patches: list[Path], folder: Path, watch: Sequence[str]) -> dict[str, str]:
    log_path = folder / BUILD_LOG
    package = folder / "autopilot"
    # The package as the source tree has it, its compiled modules included (copy2 keeps their
    # times, so the unpatched ones stay newer than their sources: simlink.check_compiled).
    shutil.copytree(source / "autopilot", package, ignore=shutil.ignore_patterns("*.c", "__pycache__"))
    changed = []
    if commit is not None:
        for module in [*package.glob("*.py"), *package.glob("*.pxd")]:
            shown = git(source, "show", f"{commit}:autopilot/{module.name}", check=False)
            if shown.returncode == 0 and shown.stdout != module.read_text():
                module.write_text(shown.stdout)
                changed.append(f"autopilot/{module.name}")
    if any(name.endswith(".pxd") for name in changed):
        # Another commit's static types: every compiled module is compiled again, as a .pxd
        # changed under one changes what the modules that cimport it compile to. Another
        # commit's sources alone change only their own modules.
        changed = [f"autopilot/{so.name.split('.', 1)[0]}.py" for so in package.glob("*.so")]
    touched = apply_patches(folder, patches)
    objects = {}
    with open(log_path, "w") as log_file:
        for name in dict.fromkeys([*touched, *watch]):
            path = folder / name
            try:
                objects[name] = bytecode_digest(path.read_text(), name)
            except SyntaxError as error:
                log_file.write(f"{name}: {error}\n")
                raise BuildFailed(f"the bundled autopilot with {len(patches)} patch(es)", log_path, str(error)) from None
        _compile_again(folder, [name for name in dict.fromkeys([*changed, *touched]) if name.endswith(".py")], log_file, log_path)
    return objects


def coverage_paths_of(source: Path, kind: str, paths: Sequence[str]) -> list[str]:
    """The paths a coverage build measures (the default where none are given), each checked to be
    in the tree."""
    chosen = list(paths) or list(DEFAULT_COVERAGE_PATHS[kind])
    missing = [path for path in chosen if not (source / path).exists()]
    if missing:
        raise InputError([Problem("--coverage-path", "", f"{', '.join(missing)}: not in {source}: give files or folders relative to the tree's root")])
    if kind == "bundled":
        outside = [path for path in chosen if Path(path).parts[0] != "autopilot"]
        if outside:
            raise InputError([Problem("--coverage-path", "", f"{', '.join(outside)}: the bundled autopilot's flights run its autopilot/ package only: "
                                                             "measure paths in it")])
    return chosen


def _compile_again(folder: Path, modules: Iterable[str], log_file, log_path: Path) -> None:
    """The patched modules that the project compiles, compiled again by its setup.py in the
    variant's folder; without setup.py (an installed, not checked-out, harness) the variant's
    compiled modules are removed and it runs as the Python sources, which compute the same."""
    compiled = [m for m in modules if any((folder / m).parent.glob(f"{Path(m).stem}.*.so"))]
    if not compiled:
        return
    setup = project_root() / "setup.py"
    if not setup.is_file():
        for so in (folder / "autopilot").glob("*.so"):
            so.unlink()
        log_file.write(f"{setup} not found: the variant runs as Python sources\n")
        return
    for module in compiled:
        for so in (folder / module).parent.glob(f"{Path(module).stem}.*.so"):
            so.unlink()
    env = {**os.environ, "STELLA_COMPILE_ONLY": ",".join(compiled)}
    argv = [sys.executable, str(setup), "build_ext", "--inplace"]
    log_file.write(f"$ STELLA_COMPILE_ONLY={env['STELLA_COMPILE_ONLY']} {' '.join(argv)}  (in {folder})\n")
    log_file.flush()
    done = subprocess.run(argv, cwd=folder, stdout=log_file, stderr=subprocess.STDOUT, env=env)
    if done.returncode != 0 or not all(any((folder / m).parent.glob(f"{Path(m).stem}.*.so")) for m in compiled):
        raise BuildFailed(f"compiling {', '.join(compiled)}", log_path, _tail(log_path))
    shutil.rmtree(folder / "build", ignore_errors=True)
