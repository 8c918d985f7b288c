"""The world spec, the contract between the harness and the simulator: typed and frozen between
the edges, JSON at them, and refused on load with the JSON pointer of what is wrong."""

from __future__ import annotations

import copy
import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT
from harness.scenario.logical import load_logical
from harness.scenario.space import SearchSpace
from harness.scenario.world import world_spec
from sim_bridge.spec import SpecError, WorldSpec

SCENARIOS = [ROOT / "scenarios" / "table3" / "scenario_09.json", ROOT / "scenarios" / "examples" / "plan_mission.json",
             ROOT / "scenarios" / "faults" / "logical" / "hill_landing.json"]


@pytest.fixture(params=SCENARIOS, ids=lambda p: p.stem)
def world(request, profile) -> WorldSpec:
    space = SearchSpace(load_logical(request.param, profile), profile)
    return world_spec(space, space.sample_feasible(np.random.default_rng(3), 1)[0], seed=7)


def test_the_spec_survives_json_unchanged(world):
    document = json.loads(json.dumps(world.as_dict()))
    assert WorldSpec.from_dict(document) == world
    assert json.loads(json.dumps(WorldSpec.from_dict(document).as_dict())) == document


def test_the_spec_is_frozen(world):
    with pytest.raises(dataclasses.FrozenInstanceError):
        world.atmosphere.wind_north_m_s = 3.0


@pytest.mark.parametrize("change, pointer, message", [
    (lambda d: d["atmosphere"].pop("temperature_c"), "/atmosphere/temperature_c", "missing"),
    (lambda d: d["atmosphere"].update(wind_east_m_s="3"), "/atmosphere/wind_east_m_s", "'3' is not a finite number"),
    (lambda d: d["mission"]["waypoints"][0].update(altitude_m=float("nan")), "/mission/waypoints/0/altitude_m", "is not a finite number"),
    (lambda d: d["uav"]["body"].update(mass_kg=1.4), "/uav/body/mass_kg", "unknown field of Body"),
    (lambda d: d.update(seed=1.5), "/seed", "1.5 is not an integer"),
    (lambda d: d.update(obstacles={}), "/obstacles", "is not a list"),
    (lambda d: d["mission"].update(land="yes"), "/mission/land", "'yes' is not true or false"),
    (lambda d: d.update(drive="autopilot"), "/drive", "'autopilot' is neither 'mission' nor 'pilot'"),
    (lambda d: d.update(drive="pilot"), "/pilot", "missing: the pilot drive needs"),
    (lambda d: d["mission"].update(waypoints=[]), "/mission/waypoints", "empty"),
    (lambda d: d.update(format="stella.world/0"), "/format", "a world spec of another version"),
])
def test_a_bad_spec_is_refused_with_the_pointer_of_the_bad_value(world, change, pointer, message):
    document = copy.deepcopy(world.as_dict())
    change(document)
    with pytest.raises(SpecError) as raised:
        WorldSpec.from_dict(document)
    assert raised.value.pointer == pointer and message in raised.value.message


def test_the_simulator_refuses_a_bad_world_file_naming_the_field(tmp_path, world):
    document = world.as_dict()
    del document["sensor"]["fov_deg"]
    path = tmp_path / "world.json"
    path.write_text(json.dumps(document))
    done = subprocess.run([sys.executable, "-m", "sim_bridge", "--world", str(path), "--sim-port", "0", "--mcap", str(tmp_path / "x.mcap")],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and done.stderr.strip() == f"{path}: /sensor/fov_deg: missing"
    assert not (tmp_path / "x.mcap").exists()
