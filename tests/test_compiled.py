"""The modules setup.py compiles (the bundled autopilot, the simulator link's codec, the simulator's
step): in use, and computing what their sources do, to the last bit of every double."""

from __future__ import annotations

import ast
import importlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

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
        replays[name] = json.loads(_python(REPLAY, result.log_path, pythonpath=path, cwd=tmp_path))
        modules = _python("import autopilot.control, simlink.codec; print(autopilot.control.__file__, simlink.codec.__file__)", pythonpath=path, cwd=tmp_path).split()
        assert all(module.endswith(".so" if name == "compiled" else ".py") for module in modules)
    assert replays["compiled"]["flew_mission"] and replays["compiled"]["steps"] > 5000
    assert replays["compiled"]["answers_sha256"] == replays["sources"]["answers_sha256"]
    assert replays["compiled"]["state_sha256"] == replays["sources"]["state_sha256"]


def _python(script: str, *args: str, pythonpath: str, cwd: Path) -> str:
    """A script's stdout, run with `pythonpath` ahead of the installed project ("": the compiled modules)."""
    done = subprocess.run([sys.executable, "-c", script, *args], capture_output=True, text=True, env={**os.environ, "PYTHONPATH": pythonpath}, cwd=cwd)
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout


def _sources(tmp_path: Path, packages: tuple[str, ...]) -> dict[str, str]:
    """PYTHONPATHs: the compiled modules, the packages' sources alone, and those sources with one
    noise constant changed, which every comparison must see (or it compared the same modules)."""
    paths = {"compiled": ""}
    for name in ("sources", "changed"):
        for package in packages:
            shutil.copytree(ROOT / package, tmp_path / name / package, ignore=shutil.ignore_patterns("*.so", "*.c", "__pycache__"))
        paths[name] = str(tmp_path / name)
    sensors = tmp_path / "changed" / "sim_bridge" / "sensors.py"
    text = sensors.read_text()
    assert "GPS_NOISE_M = 0.08" in text
    sensors.write_text(text.replace("GPS_NOISE_M = 0.08", "GPS_NOISE_M = 0.09"))
    return paths


COMPILED_MODULES = "import autopilot.control, simlink.codec, sim_bridge.bridge, sim_bridge.world; modules = [autopilot.control, simlink.codec, sim_bridge.bridge, sim_bridge.world]"

FULL_PRECISION = COMPILED_MODULES + """
import hashlib, json, random, sys
from pathlib import Path
import numpy as np
from harness.scenario.logical import load_logical
from harness.scenario.profile import load_profile
from harness.scenario.space import SearchSpace
from harness.scenario.world import world_spec
from autopilot import control
from sim_bridge import sensors
from sim_bridge.physics import VehicleState
from sim_bridge.world import World
digest = hashlib.sha256()
add = lambda value: digest.update(repr(value).encode())
rng = random.Random(1)
r = lambda scale=1.0: rng.uniform(-scale, scale)
for _ in range(20000):
    add(sensors.pressure_hpa(rng.uniform(-100.0, 5000.0)))
    q = control.quat_normalize((r(), r(), r(), r()))
    add((q, control.quat_rotate(q, (r(9), r(9), r(9))), control.euler_from_quat(q), control.quat_multiply(q, control.quat_from_euler(r(3), r(1.5), r(3)))))
    add((control.attitude_from_thrust((r(), r(), -abs(r())), r(3)), control.mix(rng.uniform(0.0, 1.0), (r(0.5), r(0.5), r(0.5)), 0.05)))
model = sensors.SensorModel(3, 15.0)
for _ in range(5000):
    add(model.hil_sensor_values(VehicleState(north_m=r(50), east_m=r(50), up_m=rng.uniform(0, 50), alt_msl_m=rng.uniform(400, 500), roll_rad=r(0.5),
                                             pitch_rad=r(0.5), yaw_rad=r(3), p_rad_s=r(), q_rad_s=r(), r_rad_s=r(), ax_m_s2=r(3), ay_m_s2=r(3),
                                             az_m_s2=r(3) - 9.8, on_ground=False)))
profile = load_profile("default")
space = SearchSpace(load_logical(Path(sys.argv[1]), profile), profile)
world = World(world_spec(space, space.sample_feasible(np.random.default_rng(2), 1)[0], 2), 250.0)
world.start_run(0.0)
for step in range(3000):
    world.step((0.5 + r(0.2), 0.5 + r(0.2), 0.5 + r(0.2), 0.5 + r(0.2)))
    world.check_end()
    s = world.state
    add((s.north_m, s.east_m, s.up_m, s.roll_rad, s.pitch_rad, s.yaw_rad, s.v_down_m_s, s.agl_m, world.imu(), world.clearance(), world.range_cm(),
         world.touchdown, world.end_reason, world.gps() if step % 25 == 0 else None))
print(json.dumps({"digest": digest.hexdigest(), "modules": [m.__file__ for m in modules]}))
"""


@pytest.mark.slow
def test_the_compiled_modules_compute_every_double_as_their_sources(tmp_path):
    """Messages carry float32, which hides a difference in a double's last bit: the simulator's
    world and sensors and the controllers' geometry, compared double for double on seeded inputs."""
    paths = _sources(tmp_path, ("autopilot", "simlink", "sim_bridge"))
    scenario = str(ROOT / "scenarios" / "examples" / "intruder_gusts_failure.json")
    runs = {name: json.loads(_python(FULL_PRECISION, scenario, pythonpath=path, cwd=tmp_path)) for name, path in paths.items()}
    assert all(module.endswith(".so") for module in runs["compiled"]["modules"])
    assert all(module.endswith(".py") for module in runs["sources"]["modules"])
    assert runs["compiled"]["digest"] == runs["sources"]["digest"] != runs["changed"]["digest"]


FLY = COMPILED_MODULES + """
import json, sys
import numpy as np
from pathlib import Path
from harness.flight.evaluation import evaluate
from harness.scenario.logical import load_logical
from harness.scenario.profile import load_profile
from harness.scenario.space import SearchSpace
profile = load_profile("default")
space = SearchSpace(load_logical(Path(sys.argv[1]), profile), profile)
seed = int(sys.argv[3])
result = evaluate(space, space.sample_feasible(np.random.default_rng(seed), 1)[0], seed=seed, out_dir=Path(sys.argv[2]))
print(json.dumps({"log": str(result.log_path), "status": result.status, "modules": [m.__file__ for m in modules]}))
"""
SIMULATED = ["/mavlink/sim", "/uav/state", "/clearance", "/scene", "/sensor/obstacle_distance", "/events", "/wind"]


@pytest.mark.slow
@pytest.mark.parametrize("scenario, seed", [
    ("scenarios/examples/intruder_gusts_failure.json", 7),  # moving obstacles along paths, gusts, a range sensor failed in the simulator
    ("tests/data/scenarios/wall_baro_wrong_gps_off.json", 2),  # failures told to the SUT: the bridge's injection hold
])
def test_the_compiled_simulator_flies_a_flight_exactly_as_its_sources(tmp_path, scenario, seed):
    """Every simulated record of a flight: the compiled simulator's against its sources'."""
    from harness.flight import logs

    records, statuses = {}, {}
    for name, path in _sources(tmp_path, ("sim_bridge",)).items():
        flight = json.loads(_python(FLY, str(ROOT / scenario), str(tmp_path / f"{name}-flight"), str(seed), pythonpath=path, cwd=tmp_path).splitlines()[-1])
        assert all(module.endswith(".so" if name == "compiled" or "sim_bridge" not in module else ".py") for module in flight["modules"])
        records[name], statuses[name] = list(logs.messages(flight["log"], SIMULATED)), flight["status"]
    assert len(records["compiled"]) > 1000 and statuses["compiled"] == statuses["sources"]
    assert records["compiled"] == records["sources"] != records["changed"]
    if "wall_baro" in scenario:
        assert any(m["event"] == "failure" and m["detail"].get("delivery") == "sut" for topic, _ns, m in records["compiled"] if topic == "/events")
