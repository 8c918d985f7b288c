"""Whether two builds are one program (harness/firmware/programs.py): real binaries compiled here
and the bundled autopilot's package, each changed the ways a refactoring does and the ways a
bug fix does."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from harness.firmware.programs import file_digest, fingerprint
from sut_adapter import SutConfig

from conftest import ROOT

LIMIT = """/* How many bins the obstacle map has. */
static const int bins = {value};
int bin_count(void) {{ return bins; }}
int main(void) {{ return bin_count() - {value}; }}
"""


def compiled(folder: Path, name: str, source: str, *flags: str) -> Path:
    (folder / f"{name}.c").write_text(source)
    subprocess.run(["cc", "-O2", *flags, "-o", str(folder / name), str(folder / f"{name}.c")], check=True, cwd=folder)
    return folder / name


def test_binaries_that_differ_in_comments_and_debug_information_only_are_one_program(tmp_path):
    if shutil.which("cc") is None:
        pytest.fail("no C compiler: the project's set-up installs one (it compiles the bundled autopilot)")
    base = compiled(tmp_path, "base", LIMIT.format(value=72), "-g")
    # a comment longer and a line further down: other debug information, other bytes
    refactored = compiled(tmp_path, "refactored", "\n// The number of bins, unified with obstacle_distance's array.\n" + LIMIT.format(value=72), "-g")
    fixed = compiled(tmp_path, "fixed", LIMIT.format(value=71), "-g")
    assert base.read_bytes() != refactored.read_bytes()
    assert file_digest(base) == file_digest(refactored)
    assert file_digest(base) != file_digest(fixed)


def package_copy(folder: Path) -> Path:
    shutil.copytree(ROOT / "autopilot", folder / "autopilot", ignore=shutil.ignore_patterns("__pycache__", "*.c"))
    return folder


def edited(folder: Path, module: str, old: str, new: str) -> None:
    path = folder / "autopilot" / module
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


def test_the_bundled_autopilot_changed_in_a_comment_is_the_same_program_and_changed_in_a_value_is_not(tmp_path):
    base = package_copy(tmp_path / "base")
    commented = package_copy(tmp_path / "commented")
    edited(commented, "faults.py", "# collision prevention, sensing", "# one of: collision prevention, sensing")
    # a line more shifts every line number after it, which no computation reads
    edited(commented, "faults.py", "from dataclasses import dataclass\n", "from dataclasses import dataclass\n\n")
    changed = package_copy(tmp_path / "changed")
    edited(changed, "telemetry.py", "MIN_STREAM_PERIOD_S = 0.02", "MIN_STREAM_PERIOD_S = 0.05")

    def of(folder: Path) -> str:
        return fingerprint(SutConfig("bundled", autopilot_dir=str(folder)))

    assert of(base) == of(commented) == fingerprint(SutConfig("bundled"))
    assert of(changed) != of(base)
