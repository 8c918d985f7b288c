"""The bundled autopilot's modules compiled by setup.py: in use, and computing what their sources do."""

from __future__ import annotations

import ast
import importlib
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from simlink import check_compiled
from conftest import FIG4, ROOT
from harness.flight.evaluation import evaluate
from harness.scenario.logical import load_logical
from harness.scenario.space import SearchSpace


def compiled_sources() -> list[str]:
    tree = ast.parse((ROOT / "setup.py").read_text())
    assignment = next(node for node in tree.body if isinstance(node, ast.Assign) and node.targets[0].id == "COMPILED")
    return ast.literal_eval(assignment.value)


def test_setup_compiled_every_listed_module_and_python_loads_the_compiled_one():
    for source in compiled_sources():
        module = importlib.import_module(source.removesuffix(".py").replace("/", "."))
        assert module.__file__.endswith(".so"), f"{source} runs as Python: is a C compiler there? see the log of `make setup`"


def test_a_compiled_module_older_than_its_source_is_refused(tmp_path):
    package = tmp_path / "package"
    package.mkdir()
    (package / "control.cpython-311-x86_64-linux-gnu.so").write_bytes(b"")
    source = package / "control.py"
    source.write_text("")
    later = source.stat().st_mtime + 10
    os.utime(source, (later, later))
    with pytest.raises(ImportError, match=r"control.*older than .*control.py: rebuild it with `make setup`"):
        check_compiled(str(package / "__init__.py"))


REPLAY = "import json, sys; from harness.tools.bench import autopilot_step_bench; print(json.dumps(autopilot_step_bench(sys.argv[1])))"


@pytest.mark.slow
def test_the_compiled_autopilot_answers_a_recorded_flight_exactly_as_its_sources(tmp_path, profile):
    space = SearchSpace(load_logical(FIG4, profile), profile)
    result = evaluate(space, space.sample_feasible(np.random.default_rng(1), 1)[0], seed=1, out_dir=tmp_path / "flight")
    sources = tmp_path / "sources"
    for package in ("autopilot", "simlink"):
        shutil.copytree(ROOT / package, sources / package, ignore=shutil.ignore_patterns("*.so", "*.c", "__pycache__"))
    replays = {}
    for name, path in (("compiled", ""), ("sources", str(sources))):
        done = subprocess.run([sys.executable, "-c", REPLAY, result.log_path], capture_output=True, text=True, env={"PYTHONPATH": path}, cwd=tmp_path, check=True)
        replays[name] = json.loads(done.stdout)
        modules = subprocess.run([sys.executable, "-c", "import autopilot.control, simlink.codec; print(autopilot.control.__file__, simlink.codec.__file__)"],
                                 capture_output=True, text=True, env={"PYTHONPATH": path}, cwd=tmp_path, check=True).stdout.split()
        assert all(module.endswith(".so" if name == "compiled" else ".py") for module in modules)
    assert replays["compiled"]["flew_mission"] and replays["compiled"]["steps"] > 5000
    assert replays["compiled"]["answers_sha256"] == replays["sources"]["answers_sha256"]
