"""Real ArduCopter SITL flying against our bridge through its JSON physics backend. Runs where
STELLA_ARDUPILOT_BIN names an ArduCopter SITL build (the arducopter binary or build/sitl);
ArduPilot is built from source, see docs/suts.md."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink

from conftest import ROOT
from harness.flight import logs
from harness.flight.fitness import PENALTY
from harness.flight.inspect_log import summarize
from harness.tools.cli import main

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not os.environ.get("STELLA_ARDUPILOT_BIN"), reason="STELLA_ARDUPILOT_BIN is not set: no ArduCopter SITL build to fly against"),
]
SCENARIO = str(ROOT / "scenarios" / "table3" / "scenario_05.json")
WALL = str(ROOT / "scenarios" / "examples" / "wall_concrete.json")


def api_messages(log_path: Path, kind: str) -> list:
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    return [message for _t, _ns, m in logs.messages(log_path, ["/mavlink/api"]) if m["direction"] == "from_sut"
            for message in parser.parse_buffer(bytes.fromhex(m["hex"])) or [] if message.get_type() == kind]


def test_sut_check_passes_every_stage(capsys):
    assert main(["sut", "check", "--sut", "ardupilot", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert all(stage["ok"] for stage in report["stages"]), report["stages"]


def test_ardupilot_flies_a_table3_mission_with_a_finite_fitness_and_its_dataflash_log(capsys, tmp_path):
    assert main(["run", SCENARIO, "--sut", "ardupilot", "--seed", "3", "--out", str(tmp_path), "--json"]) in (0, 1)
    result = json.loads(capsys.readouterr().out)
    assert result["status"] in ("ok", "violation"), result["why"]
    assert math.isfinite(result["fitness"]) and result["fitness"] < PENALTY
    assert summarize(Path(result["log_path"]))["fitness"] == result["fitness"]
    assert any(a.endswith(".BIN") and Path(a).stat().st_size > 0 for a in result["artifacts"])
    # Every servo frame was one, each step answered in lockstep.
    assert logs.json_metadata(Path(result["log_path"]), "bridge_summary")["bad_frames"] == 0


def run_wall(capsys, tmp_path, name: str, *arguments: str) -> dict:
    assert main(["run", "--concrete", WALL, "--sut", "ardupilot", "--out", str(tmp_path / name), "--json", *arguments]) in (0, 1)
    return json.loads(capsys.readouterr().out)


def test_ardupilot_flies_into_the_wall_on_a_mission_without_its_path_planner(capsys, tmp_path):
    mission = run_wall(capsys, tmp_path, "mission", "--drive", "mission")
    assert mission["min_clearance_m"] <= 0.0 and mission["status"] == "violation", mission["why"]


def test_ardupilots_path_planner_and_its_simple_avoidance_keep_it_off_the_wall(capsys, tmp_path):
    """BendyRuler (OA_TYPE 1) steers the Auto mission around the wall; in Loiter the pilot's
    sticks are stopped short of it, and ArduPilot's proximity sees what our sensor sees."""
    planner = run_wall(capsys, tmp_path, "planner", "--drive", "mission", "--sut-param", "OA_TYPE=1")
    assert planner["min_clearance_m"] > 0.0 and planner["status"] == "ok", planner["why"]
    pilot = run_wall(capsys, tmp_path, "pilot", "--drive", "pilot")
    assert pilot["min_clearance_m"] > 0.0, pilot["why"]
    log_path = Path(pilot["log_path"])
    relayed_cm = min(m.current_distance for m in api_messages(log_path, "DISTANCE_SENSOR") if m.orientation == 0)
    sensed_cm = min(m["distances_cm"][0] for _t, _ns, m in logs.messages(log_path, ["/sensor/obstacle_distance"]))
    assert abs(relayed_cm - sensed_cm) <= 2
