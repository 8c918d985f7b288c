"""The SUT-alone replay (`stella bench --limit`) against the bundled autopilot, which speaks PX4's
simulator protocol over TCP as PX4 does: a recorded flight's simulator link, cut into its steps
and replayed to a fresh autopilot process, keeps it in lockstep step for step. PX4's own run is
in tests/test_px4.py."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from conftest import ROOT
from harness.flight import logs
from harness.tools.cli import main
from harness.tools.sut_alone import STARTING_UP_STEP_S, link_steps, recorded_link, replay, sut_alone
from simlink import codec
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
    # The autopilot shares the one core with the stand-in: its CPU time is a part of each step's wall time.
    assert 0.0 < alone["sut_cpu_us"] < alone["step_us"]


def test_a_flight_says_what_its_sut_process_computed_over_the_steps_it_timed(flight_log):
    """The SUT's CPU time over the flight's run (`stella bench` reports it a step, beside the
    replay's): the autopilot, a process pinned to a core of its own, computes in at most the
    run's wall time (to the 10 ms clock ticks /proc counts in), and computes something."""
    timings = logs.json_metadata(flight_log, "result")["timings"]
    assert 0.0 < timings["sut_cpu_in_run_s"] <= timings["wall_in_run_s"] + 0.02


class _AnsweringLink:
    """A SUT that answers every HIL_SENSOR at once with its time, and notes when each came."""

    def __init__(self):
        self.pending = b""
        self.sent_at: list[float] = []

    def send(self, data: bytes) -> None:
        self.sent_at.append(time.perf_counter())
        for _msgid, payload, _frame in codec.FrameSplitter({codec.HIL_SENSOR_ID: codec.HIL_SENSOR_CRC_EXTRA}).feed(data):
            self.pending += codec.encode_hil_actuator_controls(seq=0, sysid=1, compid=1, time_usec=codec.decode_hil_sensor(payload)[0],
                                                               controls=(0.0,) * 16, mode=0, flags=1)

    def readable(self, timeout_s: float) -> bool:
        return bool(self.pending)

    def receive(self, spin_s: float) -> bytes:
        data, self.pending = self.pending, b""
        return data


def test_the_replay_holds_at_the_flights_pace_and_times_the_run_once_the_sut_has_started_up():
    """GIVEN a flight's 100 steps at 250 Hz, held from step 20 at 10x real time and run from step
    60 WHEN a SUT that answers at once but finishes starting up 0.2 s into the replay is replayed
    to THEN the hold's 40 steps take at least their 16 ms, longer while the SUT starts up, and
    the run's first step waits for the start-up: the timed steps are those of a started SUT, as
    in a flight. One that never finishes starting up is timed after a second, and said to be."""
    dt_s, times = 0.004, [4000 * i for i in range(100)]
    steps = [codec.encode_hil_sensor(seq=0, sysid=1, compid=1, time_usec=t, values=(0.0,) * 13, fields_updated=0) for t in times]
    link = _AnsweringLink()
    started = time.perf_counter()
    result = replay(link, steps, times, dt_s, timed_from=60, spin_s=0.0, hold=(20, 10.0), ready=lambda: time.perf_counter() - started > 0.2)
    assert result["in_step"] and result["timed_steps"] == 40 and result["started_up"]
    assert link.sent_at[59] - link.sent_at[20] >= 39 * STARTING_UP_STEP_S
    assert link.sent_at[60] - started > 0.2
    assert link.sent_at[99] - link.sent_at[60] < 0.1  # the run itself is not paced
    started_up = _AnsweringLink()
    replay(started_up, steps, times, dt_s, timed_from=60, spin_s=0.0, hold=(20, 1.0))
    assert started_up.sent_at[59] - started_up.sent_at[20] >= 39 * dt_s  # the hold's own pace, real time here
    assert started_up.sent_at[19] - started_up.sent_at[0] < 19 * dt_s  # before the hold, as fast as the SUT answers
    never = replay(_AnsweringLink(), steps, times, dt_s, timed_from=60, spin_s=0.0, hold=(20, 10.0), ready=lambda: False)
    assert never["in_step"] and not never["started_up"]
