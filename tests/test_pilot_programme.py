"""The pilot's stick programme: segments relative to the route or the nearest obstacle, searched
like any dimension, carried by concrete scenarios, flown bit for bit on the bundled autopilot,
recorded in the log and shrunk segment by segment."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT
from harness.campaigns.shrink_steps import checked, programme_steps
from harness.flight import logs
from harness.flight.evaluation import evaluate
from harness.flight.results import RunOptions
from harness.scenario.logical import load_logical
from harness.scenario.profile import load_profile
from harness.scenario.space import SearchSpace
from harness.scenario.world import space_from_concrete, world_spec
from harness.tools.cli import main
from sim_bridge.physics import VehicleState
from sim_bridge.pilot import SLOT_POSITION, Pilot
from sim_bridge.spec import PilotSegment, Point, Waypoint

EXAMPLES = ROOT / "scenarios" / "examples"
PROBE = [{"towards": "obstacle", "deflection": {"min": 0.0, "max": 1.0}, "duration_s": {"min": 1, "max": 8}},
         {"towards": "obstacle", "angle_deg": {"min": -180, "max": 180}, "deflection": {"min": 0, "max": 1}, "duration_s": {"min": 0.5, "max": 5},
          "yaw_stick": {"min": -0.5, "max": 0.5}}]


def probing_wall(tmp_path: Path, programme=PROBE) -> Path:
    scenario = json.loads((EXAMPLES / "wall.json").read_text())
    scenario["name"] = "Wall, probed by the pilot"
    scenario.setdefault("mission", {}).update({"drive": "pilot", "programme": programme})
    path = tmp_path / "wall_probe.json"
    path.write_text(json.dumps(scenario))
    return path


def test_the_pilot_flies_its_segments_in_turn_then_the_route():
    programme = (PilotSegment("obstacle", 0.0, 0.5, 2.0), PilotSegment("obstacle", 180.0, 0.3, 1.0, yaw_stick=0.2))
    # Facing north, an obstacle to the east, the route north
    pilot = Pilot(Point(0.0, 0.0, 0.0), [Waypoint(50.0, 0.0, 8.0)], 8.0, 1.0, 0.0, programme, lambda state: math.pi / 2)
    hovering = VehicleState(up_m=8.0)
    pilot.update(0.0, hovering)  # airborne and settled: the programme starts
    towards = pilot.update(0.5, hovering)
    assert pilot.phase == "programme" and pilot.segment == 0 and towards.slot == SLOT_POSITION
    assert (towards.roll, towards.pitch, towards.yaw) == pytest.approx((0.5, 0.0, 0.0), abs=1e-9)  # right stick: east
    away = pilot.update(2.5, hovering)
    assert pilot.segment == 1 and (away.roll, away.pitch, away.yaw) == pytest.approx((-0.3, 0.0, 0.2), abs=1e-9)
    route = pilot.update(3.5, hovering)
    assert pilot.phase == "cruise" and pilot.segment is None and route.pitch > 0.0  # forward, along the route


def test_a_programme_is_searched_and_reaches_the_world_through_the_concrete_scenario(tmp_path):
    profile = load_profile()
    space = SearchSpace(load_logical(probing_wall(tmp_path), profile), profile)
    names = [d["name"] for d in space.describe()["dimensions"]]
    assert {"pilot.segment_1.deflection", "pilot.segment_1.duration_s", "pilot.segment_2.angle_deg", "pilot.segment_2.yaw_stick"} <= set(names)
    assert "pilot.segment_1.angle_deg" not in names  # a number, or no value (0): fixed
    x = space.sample_feasible(np.random.default_rng(2), 1)[0]
    concrete = space.to_concrete(x)
    programme = world_spec(space, x, 0).pilot.programme
    assert [segment.towards for segment in programme] == ["obstacle", "obstacle"] and programme[0].angle_deg == 0.0
    again = space_from_concrete(concrete, "concrete")
    assert world_spec(again, again.from_concrete(concrete, "concrete"), 0).pilot.programme == programme


@pytest.mark.parametrize("segment, pointer, says", [
    ({"towards": "obstacle", "duration_s": 0}, "/mission/programme/0/duration_s", "above 0"),
    ({"towards": "obstacle", "deflection": {"min": 0.2, "max": 1.5}}, "/mission/programme/0/deflection", "within 0..1"),
    ({"towards": "route", "angle_deg": {"min": 90, "max": -90}}, "/mission/programme/0/angle_deg", "swapped bounds"),
    ({"towards": "goal"}, "/mission/programme/0/towards", "route"),
])
def test_a_bad_programme_exits_2_naming_the_field(tmp_path, capsys, segment, pointer, says):
    path = probing_wall(tmp_path, [segment])
    assert main(["space", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"{path}: {pointer}" in err and says in err


def test_shrinking_drops_segments_of_the_programme(tmp_path):
    profile = load_profile()
    space = SearchSpace(load_logical(probing_wall(tmp_path), profile), profile)
    document = checked(copy.deepcopy(space.to_concrete(space.sample_feasible(np.random.default_rng(2), 1)[0])))

    class State:
        current = document

    candidates = list(programme_steps(State))
    assert [c.description for c in candidates] == ["drop the pilot's segment 2 (towards the obstacle)", "drop the pilot's segment 1 (towards the obstacle)"]
    fewer = candidates[0].document
    assert len(fewer["pilot"]["programme"]) == 1 and len(fewer["logical_scenario"]["mission"]["programme"]) == 1


@pytest.mark.slow
def test_a_programme_flight_repeats_bit_for_bit_and_its_segments_are_in_the_log(tmp_path):
    profile = load_profile()
    space = SearchSpace(load_logical(probing_wall(tmp_path), profile), profile)
    x = space.sample_feasible(np.random.default_rng(1), 1)[0]
    first, second = (evaluate(space, x, seed=1, out_dir=tmp_path, options=RunOptions(cores=1), name=f"probe-{i}") for i in range(2))
    assert first.fitness == second.fitness and first.min_clearance_m == second.min_clearance_m
    flown = {(record["phase"], record.get("segment")) for _t, _ns, record in logs.messages(Path(first.log_path), ["/pilot"])}
    assert {("programme", 1), ("programme", 2), ("cruise", None)} <= flown
