"""Both MAVLink links under generated bad input (issue 18): the bridge against a SUT that sends
malformed, truncated, oversized, out-of-order and flooding frames, and the bundled autopilot's
API link against garbage datagrams. Neither may crash or hang; a SUT that never answers sanely
ends its flight with a reason."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest

import fuzz_frames
from conftest import ROOT
from harness import logs
from harness.ports import PortLease
from test_bridge_lockstep import SCRIPTED_SUT, world

pytestmark = pytest.mark.slow
FRAMES_PER_LINK = 10_000


def fly_fuzzed(tmp_path, mode: str, *extra: str, time_limit_s: float = 14.0, stall_timeout_s: float = 3.0):
    """The bridge against the scripted SUT in a fuzzing mode: (exit code, summary, bad frames the SUT sent by kind)."""
    world_path = tmp_path / f"{mode}.world.json"
    world_path.write_text(json.dumps(world(time_limit_s=time_limit_s)))
    with PortLease(first_slot=110) as ports:
        bridge = subprocess.Popen(
            [sys.executable, "-m", "sim_bridge", "--world", str(world_path), "--sim-port", str(ports.sim), "--mcap", str(tmp_path / f"{mode}.mcap"),
             "--hold-after-s", "0", "--stall-timeout-s", str(stall_timeout_s), "--connect-timeout-s", "20"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT,
        )
        sut = subprocess.Popen([sys.executable, str(SCRIPTED_SUT), "--port", str(ports.sim), "--mode", mode, *extra], cwd=ROOT, stdout=subprocess.PIPE)
        try:
            out, err = bridge.communicate(timeout=120)
            sent, _ = sut.communicate(timeout=30)
        finally:
            sut.kill()
            bridge.kill()
    assert "Traceback" not in err.decode(), err.decode()[-3000:]
    counts = json.loads(sent.decode().strip().splitlines()[-1]) if sent.strip() else {}
    return bridge.returncode, json.loads(out.decode().strip().splitlines()[-1]), counts


def test_the_bridge_flies_on_through_ten_thousand_bad_frames_between_its_answers(tmp_path):
    code, summary, sent = fly_fuzzed(tmp_path, "fuzz", "--junk", "3", "--seed", "11")
    assert sum(sent.values()) >= FRAMES_PER_LINK and set(sent) == set(fuzz_frames.SURVIVABLE)
    assert code == 0 and summary["end_reason"] == "time_limit" and summary["steps"] == 14 * 250
    assert summary["bad_frames"] > 0 and summary["skipped_bytes"] > 0


def test_actuator_values_that_are_not_finite_or_out_of_range_act_as_an_esc_takes_them(tmp_path):
    """NaN stops a motor and anything beyond [0, 1] saturates, as an ESC does; the simulation stays finite."""
    code, summary, sent = fly_fuzzed(tmp_path, "fuzz", "--junk", "3", "--seed", "12", "--odd-actuators")
    assert sent.get("odd_actuator", 0) > 1000
    assert code == 0 and summary["end_reason"] == "time_limit" and summary["steps"] == 14 * 250
    states = [state for _topic, _ns, state in logs.messages(tmp_path / "fuzz.mcap", ["/uav/state"])]
    assert len(states) > 100 and all(math.isfinite(state[key]) for state in states for key in ("north_m", "east_m", "up_m"))


def test_a_sut_that_floods_without_answering_is_ended_as_stalled(tmp_path):
    code, summary, _sent = fly_fuzzed(tmp_path, "flood", "--steps", "100", "--seed", "13", stall_timeout_s=2.0)
    assert code == 3 and summary["end_reason"] == "sut_stalled" and summary["steps"] == 100
    assert summary["bad_frames"] > 1000


def test_a_flood_before_the_first_answer_leaves_the_bridge_at_real_time_pace(tmp_path):
    code, summary, _sent = fly_fuzzed(tmp_path, "flood", "--steps", "0", "--seed", "14", time_limit_s=2.0)
    assert code == 0 and summary["end_reason"] == "time_limit" and summary["steps"] == 2 * 250
    assert summary["wall_time_s"] >= 2.0 * 0.9
