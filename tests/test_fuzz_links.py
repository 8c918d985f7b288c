"""Both MAVLink links under generated bad input (issue 18): the bridge against a SUT that sends
malformed, truncated, oversized, out-of-order and flooding frames, and the bundled autopilot's
API link against garbage datagrams. Neither may crash or hang; a SUT that never answers sanely
ends its flight with a reason."""

from __future__ import annotations

import json
import math
import random
import socket
import subprocess
import sys
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink

import fuzz_frames
from conftest import ROOT
from harness.flight import logs
from harness.flight.ports import PortLease
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


TELEMETRY = {"HEARTBEAT", "ATTITUDE", "GLOBAL_POSITION_INT", "SYS_STATUS", "EXTENDED_SYS_STATE"}


def received_types(sock: socket.socket, seconds: float) -> set[str]:
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    seen: set[str] = set()
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            data = sock.recv(65536)
        except (socket.timeout, BlockingIOError):
            continue
        seen |= {m.get_type() for m in parser.parse_buffer(data) or []}
    return seen


def test_ten_thousand_bad_datagrams_neither_crash_the_autopilot_nor_divert_its_telemetry(tmp_path):
    world_path = tmp_path / "api.world.json"
    world_path.write_text(json.dumps(world(time_limit_s=600.0)))
    gcs_peer = mavlink.MAVLink(None, srcSystem=255)
    heartbeat = gcs_peer.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(gcs_peer)
    rng = random.Random(21)
    sent: dict[str, int] = {}
    with PortLease(first_slot=111) as ports, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as gcs, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger:
        gcs.bind(("127.0.0.1", ports.api))
        gcs.settimeout(0.2)
        # The simulator holds the vehicle at real-time pace (no harness sends "run"), so the
        # autopilot stays up for as long as the fuzzing takes.
        bridge = subprocess.Popen([sys.executable, "-m", "sim_bridge", "--world", str(world_path), "--sim-port", str(ports.sim),
                                   "--control-port", str(ports.control), "--mcap", str(tmp_path / "api.mcap"), "--hold-after-s", "0.5"],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT)
        autopilot = subprocess.Popen([sys.executable, "-m", "autopilot", "--sim", f"tcp:127.0.0.1:{ports.sim}", "--api", f"udp:127.0.0.1:{ports.api}"],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=ROOT)
        try:
            deadline = time.monotonic() + 30
            target = None
            while target is None:
                assert time.monotonic() < deadline, "no heartbeat from the autopilot"
                try:
                    data, address = gcs.recvfrom(65536)
                except socket.timeout:
                    continue
                if any(m.get_type() == "HEARTBEAT" for m in mavlink.MAVLink(None).parse_buffer(data) or []):
                    target = address
            gcs.sendto(heartbeat, target)
            assert TELEMETRY <= received_types(gcs, 2.0)
            for index in range(FRAMES_PER_LINK):
                kind, datagram = fuzz_frames.junk(rng)
                sent[kind] = sent.get(kind, 0) + 1
                stranger.sendto(datagram, target)
                if index % 50 == 0:
                    gcs.sendto(heartbeat, target)
                    time.sleep(0.005)  # the autopilot reads its API socket between steps: leave the kernel's buffer room
            assert autopilot.poll() is None, autopilot.stderr.read().decode()[-3000:]
            gcs.sendto(heartbeat, target)
            received_types(gcs, 0.5)  # what was queued during the fuzzing
            assert TELEMETRY <= received_types(gcs, 2.0)
            assert autopilot.poll() is None
        finally:
            autopilot.terminate()
            bridge.terminate()
            _out, err = autopilot.communicate(timeout=30)
            bridge.wait(timeout=30)
    assert sum(sent.values()) == FRAMES_PER_LINK and set(sent) == set(fuzz_frames.KINDS)
    assert "Traceback" not in err.decode(), err.decode()[-3000:]
