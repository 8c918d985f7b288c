"""The SUT-alone replay (`stella bench --limit`) against the bundled autopilot, which speaks PX4's
simulator protocol over TCP as PX4 does: a recorded flight's simulator link, cut into its steps
and replayed to a fresh autopilot process, keeps it in lockstep step for step. PX4's own run is
in tests/test_px4.py."""

from __future__ import annotations

from pathlib import Path

import pytest

from conftest import ROOT
from harness.flight import logs
from harness.tools.cli import main
from harness.tools.sut_alone import link_steps, recorded_link, sut_alone
from sut_adapter import SutConfig

SCENARIO = str(ROOT / "scenarios" / "table3" / "scenario_31.json")


@pytest.fixture(scope="module")
def flight_log(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("flight")
    assert main(["run", SCENARIO, "--seed", "4", "--transport", "tcp", "--out", str(out), "--json"]) in (0, 1)
    return next(out.glob("*.mcap"))


def test_a_recorded_link_is_cut_into_the_bridges_steps_each_ending_with_its_hil_sensor(flight_log):
    stream = b"".join(bytes.fromhex(m["hex"]) for _t, _ns, m in logs.messages(flight_log, ["/mavlink/sim"]) if m["direction"] == "to_sut")
    steps, times = link_steps(stream)
    summary = logs.json_metadata(flight_log, "bridge_summary")
    assert len(steps) == summary["steps"]
    assert times == [round(i * 1e6 * summary["sim_time_s"] / summary["steps"]) for i in range(len(steps))]
    assert b"".join(steps) == stream  # nothing dropped or reordered
    with pytest.raises(ValueError, match="stray bytes"):
        link_steps(b"\x00garbage" + stream[:1000])


@pytest.mark.slow
def test_the_replay_keeps_a_fresh_autopilot_in_lockstep_and_times_the_run(flight_log):
    recorded = recorded_link(flight_log)
    alone = sut_alone(flight_log, SutConfig(), cores=1, repeats=1)
    assert alone["in_step"], "an answer carried another step's time: the replay lost lockstep"
    assert alone["timed_steps"] == len(recorded["steps"]) - recorded["run_step"] > 0
    assert alone["real_time_factor"] > 1.0
