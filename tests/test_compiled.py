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


FLY = """
import json, sys
import numpy as np
from pathlib import Path
from harness.flight.evaluation import evaluate
from harness.scenario.logical import load_logical
from harness.scenario.profile import load_profile
from harness.scenario.space import SearchSpace
profile = load_profile("default")
space = SearchSpace(load_logical(Path(sys.argv[1]), profile), profile)
result = evaluate(space, space.sample_feasible(np.random.default_rng(7), 1)[0], seed=7, out_dir=Path(sys.argv[2]))
print(json.dumps({"log": str(result.log_path), "status": result.status}))
"""
SIMULATED = ["/mavlink/sim", "/uav/state", "/clearance", "/scene", "/sensor/obstacle_distance", "/events", "/wind"]


@pytest.mark.slow
def test_the_compiled_simulator_flies_a_flight_exactly_as_its_sources(tmp_path):
    """Every simulated record of a flight with moving obstacles along paths, gusts and a failure
    told to the SUT: the compiled simulator's against its sources' (and, so that the comparison
    can fail, against sources with a sensor's noise changed)."""
    from harness.flight import logs

    scenario = ROOT / "scenarios" / "examples" / "intruder_gusts_failure.json"
    sources, changed = tmp_path / "sources", tmp_path / "changed"
    for copy in (sources, changed):
        shutil.copytree(ROOT / "sim_bridge", copy / "sim_bridge", ignore=shutil.ignore_patterns("*.so", "*.c", "__pycache__"))
    sensors = changed / "sim_bridge" / "sensors.py"
    sensors.write_text(sensors.read_text().replace("GPS_NOISE_M = 0.08", "GPS_NOISE_M = 0.09"))
    records = {}
    for name, path in (("compiled", ""), ("sources", str(sources)), ("changed", str(changed))):
        done = subprocess.run([sys.executable, "-c", FLY, str(scenario), str(tmp_path / f"{name}-flight")], capture_output=True, text=True,
                              env={**os.environ, "PYTHONPATH": path}, cwd=tmp_path, check=True)
        flight = json.loads(done.stdout.strip().splitlines()[-1])
        assert flight["status"] in ("ok", "violation")
        records[name] = list(logs.messages(flight["log"], SIMULATED))
    assert len(records["compiled"]) > 1000
    assert records["compiled"] == records["sources"]
    assert records["changed"] != records["sources"]
