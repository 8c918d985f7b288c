"""Whether two builds are one program: what a SUT loads when it runs, compared without what does
not change its behaviour.

A change that only renames, reformats, comments or refactors (PX4's 399a8ad5b7 replaced a
constant by the same value computed) builds to other files, but not to other machine code: the
debug information, the build ID and the time stamps differ, the instructions and data do not. No
flight can tell two such builds apart, so a gate on them has nothing to fly.

A build's fingerprint covers every file its SUT reads (PX4: `bin/` and `etc/`; ArduPilot: the
arducopter binary; the bundled autopilot: its package), each as
* an ELF file (an executable, a compiled module): the contents and addresses of its sections that
  are loaded into memory (code, read-only and initialised data, dynamic linking), with notes such
  as the build ID left out;
* a Python module: its bytecode without line numbers (harness/firmware/builds.bytecode_digest);
* any other file (start-up scripts, parameter files): its bytes; a symbolic link: its target.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from elftools.common.exceptions import ELFError
from elftools.elf.constants import SH_FLAGS
from elftools.elf.elffile import ELFFile

from harness.firmware.builds import bytecode_digest
from sut_adapter import SutConfig

ELF_MAGIC = b"\x7fELF"
# Loaded, but they describe the build rather than the program: the build ID hashes the whole
# file, debug information included.
SKIPPED_SECTION_TYPES = ("SHT_NOBITS", "SHT_NOTE")
# Not read by the SUT: Python's caches, and Cython's generated C (compiled into the modules beside it).
SKIPPED_PARTS = ("__pycache__",)
SKIPPED_SUFFIXES = (".c", ".pyc")


def program_roots(config: SutConfig) -> list[Path]:
    """The files and folders of the build a SUT configuration flies that make up its program."""
    from sut_adapter.ardupilot import resolve_binary as resolve_arducopter
    from sut_adapter.px4 import resolve_binary as resolve_px4

    if config.name == "px4":
        binary, etc = resolve_px4(config.px4_bin)
        return [binary.parent, etc]
    if config.name == "ardupilot":
        return [resolve_arducopter(config.ardupilot_bin)]
    if config.autopilot_dir:
        return [Path(config.autopilot_dir).expanduser().resolve() / "autopilot"]
    import autopilot

    return [Path(autopilot.__file__).resolve().parent]


def fingerprint(config: SutConfig) -> str:
    """One digest of the program the configuration flies: equal fingerprints, one program."""
    digest = hashlib.sha256()
    for root in program_roots(config):
        files = [root] if not root.is_dir() else sorted(p for p in root.rglob("*") if _read_by_the_sut(p))
        for path in files:
            name = path.name if path == root else path.relative_to(root).as_posix()
            digest.update(f"{root.name}/{name}\0{file_digest(path)}\n".encode())
    return digest.hexdigest()


def _read_by_the_sut(path: Path) -> bool:
    return not path.is_dir() and path.suffix not in SKIPPED_SUFFIXES and not set(SKIPPED_PARTS) & set(path.parts)


def file_digest(path: Path) -> str:
    if path.is_symlink():
        return "link " + str(path.readlink())
    with open(path, "rb") as handle:
        if handle.read(4) == ELF_MAGIC:
            handle.seek(0)
            try:
                return "elf " + _loaded_sections_digest(handle)
            except ELFError:  # not an ELF file after all: compared as bytes
                pass
    if path.suffix == ".py":
        try:
            return "bytecode " + bytecode_digest(path.read_text(), path.name)
        except (SyntaxError, UnicodeDecodeError, ValueError):
            pass
    return "bytes " + hashlib.sha256(path.read_bytes()).hexdigest()


def _loaded_sections_digest(handle) -> str:
    digest = hashlib.sha256()
    for section in ELFFile(handle).iter_sections():
        if section["sh_flags"] & SH_FLAGS.SHF_ALLOC and section["sh_type"] not in SKIPPED_SECTION_TYPES:
            digest.update(f"{section.name} {section['sh_addr']:x}\0".encode())
            digest.update(section.data())
    return digest.hexdigest()
