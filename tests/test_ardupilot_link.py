"""ArduPilot's JSON physics link without ArduPilot: the protocol's encoding and decoding against the
frame layout of ArduPilot's SIM_JSON.h, the adapter's command line and parameters, and the bridge
as a real process against a small ArduPilot that obeys the protocol (tests/fake_ardupilot.py):
lockstep, a line lost, counts skipped or started again, and junk between the frames; and a
recorded flight replayed to it as `stella bench --limit` does."""

from __future__ import annotations

import json
import math
import stat
import struct
import subprocess
import sys

import pytest
from pymavlink.dialects.v20 import common as mavlink

from conftest import ROOT
from fake_ardupilot import parse_like_ardupilot
from harness.flight import logs
from harness.flight.ports import PortLease
from harness.tools.sut_alone import json_link_steps, recorded_link, replay_json
from sim_bridge import ardupilot_json, geo
from sim_bridge.ardupilot_json import FrameCounter, FrameError, decode_servo_frame, encode_servo_frame, motor_commands, rangefinder_distances_m, state_line
from sim_bridge.ardupilot_link import accept, listen_udp
from sim_bridge.spec import WorldSpec
from simlink.failures import TYPE_BY_NAME, UNIT_BY_NAME
from sut_adapter import SutError, get
from sut_adapter.ardupilot import DEFAULT_PARAMS, PARAMS_FILE, ArduPilotSitl
from sut_adapter.ardupilot_failures import failure_params
from test_bridge_lockstep import world

FAKE_ARDUPILOT = ROOT / "tests" / "fake_ardupilot.py"


# -- the protocol -----------------------------------------------------------------------------

def test_a_servo_frame_in_ardupilots_layout_decodes_to_its_rate_count_and_pwm():
    # SIM_JSON.h servo_packet_16: uint16 magic = 18458, uint16 frame_rate, uint32 frame_count, uint16 pwm[16]
    datagram = struct.pack("<HHI16H", 18458, 400, 123456, *range(1000, 1016))
    frame = decode_servo_frame(datagram)
    assert (frame.frame_rate_hz, frame.frame_count, frame.pwm_us) == (400, 123456, tuple(range(1000, 1016)))
    assert len(datagram) == 40
    wide = decode_servo_frame(struct.pack("<HHI32H", 29569, 1200, 7, *range(1100, 1132)))
    assert wide.frame_count == 7 and len(wide.pwm_us) == 32
    assert encode_servo_frame(400, 123456, range(1000, 1016)) == datagram


@pytest.mark.parametrize("datagram", [b"", b"\x1a\x48" * 5, struct.pack("<HHI16H", 18459, 400, 1, *[1500] * 16),
                                      struct.pack("<HHI32H", 18458, 400, 1, *[1500] * 32), struct.pack("<HHI16H", 18458, 400, 1, *[1500] * 16) + b"\x00"])
def test_anything_else_is_refused_with_what_is_wrong(datagram):
    with pytest.raises(FrameError):
        decode_servo_frame(datagram)


def test_servo_frames_are_found_again_in_a_recorded_stream_with_junk_and_repeats_between_them():
    frames = [encode_servo_frame(400, count, [1000 + count] * 16) for count in range(5)]
    stream = b"junk" + frames[0] + frames[1] + frames[1] + b"\x00\x01" + frames[2] + struct.pack("<HHI32H", 29569, 400, 3, *[1500] * 32) + frames[4][:10]
    assert [f.frame_count for f in ardupilot_json.servo_frames_in(stream)] == [0, 1, 2, 3]


def test_pwm_maps_to_motor_commands_in_order_and_saturates_as_an_esc_does():
    assert motor_commands((1000, 1500, 2000, 1250, 1900)) == (0.0, 0.5, 1.0, 0.25)
    assert motor_commands((0, 900, 2100, 65535)) == (0.0, 0.0, 1.0, 1.0)


def test_frame_counts_tell_new_repeated_restarted_and_lost_frames():
    counter = FrameCounter()
    kinds = [counter.classify(count) for count in (5, 6, 6, 7, 10, 0, 1)]
    assert kinds == ["new", "new", "repeated", "new", "new", "restarted", "new"]
    assert (counter.repeated, counter.lost, counter.restarts) == (1, 2, 1)


def state(**overrides):
    values = dict(timestamp_s=12.0025, gyro_rad_s=(0.01, -0.02, 0.5), accel_body_m_s2=(0.1, -0.2, -9.81), position_ned_m=(10.5, -3.25, -20.0),
                  velocity_ned_m_s=(1.0, 2.0, -0.5), quaternion=(0.9238795, 0.0, 0.0, 0.3826834), ranges_m=(4.5, None, 20.01, 1.2, None, 3.0))
    return state_line(**{**values, **overrides})


def test_a_state_line_is_compact_json_between_newlines_that_ardupilots_parser_reads_whole():
    line = state()
    assert line.startswith(b"\n{") and line.endswith(b"}\n") and line.count(b"\n") == 2
    assert b": " not in line and b", " not in line  # its parser reads a value right after the colon
    document = json.loads(line)
    fields = parse_like_ardupilot(line.decode().strip())
    assert fields["timestamp"] == pytest.approx(12.0025) and document["timestamp"] == pytest.approx(12.0025)
    assert fields["gyro"] == pytest.approx([0.01, -0.02, 0.5]) and fields["accel_body"] == pytest.approx([0.1, -0.2, -9.81])
    assert fields["position"] == pytest.approx([10.5, -3.25, -20.0]) and fields["velocity"] == pytest.approx([1.0, 2.0, -0.5])
    assert fields["quaternion"] == pytest.approx([0.9238795, 0.0, 0.0, 0.3826834])
    assert (fields["rng_1"], fields["rng_3"], fields["rng_4"], fields["rng_6"]) == pytest.approx((4.5, 20.01, 1.2, 3.0))
    assert "rng_2" not in fields and "rng_5" not in fields


def test_a_state_that_is_not_finite_is_refused_rather_than_sent_as_garbage():
    with pytest.raises(ValueError, match="position"):
        state(position_ned_m=(math.nan, 0.0, 0.0))


def test_rangefinders_read_the_nearest_sector_of_their_wedge_and_nothing_outside_the_field_of_view():
    sectors = 72
    reach_m = 20.0
    distances = [2001] * sectors
    distances[2] = 450  # 10 degrees right of the nose: the forward rangefinder's wedge
    distances[18] = 300  # 90 degrees: right
    visible = [min(i * 5.0, 360.0 - i * 5.0) <= 100.0 for i in range(sectors)]  # a 200-degree field of view
    forward, forward_right, right, back, left, forward_left = rangefinder_distances_m(distances, visible, 5.0, reach_m)
    assert forward == pytest.approx(4.5) and right == pytest.approx(3.0)
    assert forward_right == pytest.approx(reach_m + 0.01) and forward_left == pytest.approx(reach_m + 0.01)
    assert back is None and left == pytest.approx(reach_m + 0.01)
    assert len(ardupilot_json.RANGEFINDER_ORIENTATION) == len(ardupilot_json.RANGEFINDER_YAW_DEG) == 6


def test_the_pilots_transmitter_for_ardupilot_mirrors_pitch_and_puts_the_switch_in_ardupilots_positions():
    from sim_bridge.pilot import SLOT_HOLD, SLOT_LAND, SLOT_POSITION, RcFrame

    forward = RcFrame(roll=0.2, pitch=0.5, throttle=0.0, yaw=-0.1, slot=SLOT_POSITION)
    px4 = forward.channels()
    channels = ardupilot_json.rc_channels(forward)
    assert px4[1] > 1500 and channels[1] == 3000 - px4[1]  # ArduPilot: a low pitch pulse flies forward
    assert channels[0] == px4[0] and channels[2] == px4[2] and channels[3] == px4[3]
    # ArduPilot's mode switch (RC_Channel): position 2 is 1231..1360 us, position 3 1361..1490 us.
    assert 1231 <= channels[4] <= 1360 and 1361 <= ardupilot_json.rc_channels(RcFrame(0.0, 0.0, 0.0, 0.0, SLOT_LAND))[4] <= 1490
    assert struct.unpack("<8H", ardupilot_json.rc_packet(channels)) == tuple(channels)
    # Until the take-off is done the throttle rests at its bottom: ArduCopter arms in Stabilize only so.
    assert ardupilot_json.rc_channels(RcFrame(0.0, 0.0, 0.0, 0.0, SLOT_HOLD))[2] == 1000 and channels[2] == 1500


# -- the adapter ------------------------------------------------------------------------------

@pytest.fixture
def arducopter(tmp_path):
    """An executable where a build folder keeps arducopter (the adapter only builds its command line here)."""
    binary = tmp_path / "build" / "sitl" / "bin" / "arducopter"
    binary.parent.mkdir(parents=True)
    binary.write_text("#!/bin/sh\nexit 0\n")
    binary.chmod(binary.stat().st_mode | stat.S_IXUSR)
    return binary


def test_the_adapter_finds_arducopter_from_a_build_folder_or_source_tree_and_says_how_to_build_one(arducopter, tmp_path, monkeypatch):
    assert get("ardupilot", {"ardupilot_bin": str(arducopter.parent.parent)}).binary == arducopter
    assert get("ardupilot", {"ardupilot_bin": str(tmp_path)}).binary == arducopter
    monkeypatch.setenv("STELLA_ARDUPILOT_BIN", str(arducopter))
    assert get("ardupilot").binary == arducopter
    monkeypatch.delenv("STELLA_ARDUPILOT_BIN")
    with pytest.raises(SutError, match="--ardupilot-bin"):
        get("ardupilot")
    with pytest.raises(SutError, match="waf copter"):
        get("ardupilot", {"ardupilot_bin": str(tmp_path / "nothing")})


def test_arducopter_is_started_on_the_port_blocks_ports_at_the_worlds_origin_with_the_f450s_parameters(arducopter, tmp_path):
    system = get("ardupilot", {"ardupilot_bin": str(arducopter)})
    spec = WorldSpec.from_dict(world())
    workdir = tmp_path / "evaluation"
    workdir.mkdir()
    handle = system.start(sim_port=4567, api_port=14547, instance=7, workdir=workdir, params={"OA_TYPE": 1}, world=spec)
    handle.stop()
    ardupilot_dir = workdir / "ardupilot"
    command = system.command(sim_port=4567, api_port=14547, instance=7, workdir=ardupilot_dir, origin=(47.397742, 8.545594, 488.0))
    options = dict(zip(command[1::2], command[2::2]))
    assert options["--model"] == "JSON:127.0.0.1" and options["--sim-port-out"] == "4567" and options["--instance"] == "7"
    assert options["--serial0"] == "udpclient:127.0.0.1:14547" and options["--home"] == "47.39774200,8.54559400,488.00,0"
    assert options["--defaults"] == str(ardupilot_dir / PARAMS_FILE)
    params = dict(line.split() for line in (ardupilot_dir / PARAMS_FILE).read_text().splitlines())
    assert params["FRAME_CLASS"] == "1" and params["FRAME_TYPE"] == "1"  # quad X, as the F450
    assert params["OA_TYPE"] == "1" and params["RNGFND1_MAX"] == "20" and params["PRX1_TYPE"] == "4"
    assert [params[f"RNGFND{n}_ORIENT"] for n in range(1, 7)] == ["0", "1", "2", "4", "6", "7"]
    # The world's sensor sees 100 degrees about the nose: no rangefinder right, back or left (one without data fails pre-arm).
    assert [params[f"RNGFND{n}_TYPE"] for n in range(1, 7)] == ["100", "100", "0", "0", "0", "100"]
    assert system.capabilities.rate_hz >= 1.8 * 400  # its gyros sample at the physics rate
    assert handle.mavlink_params == {"OA_TYPE": 1}
    assert set(DEFAULT_PARAMS) <= set(params)


# -- the bridge against an ArduPilot that obeys the protocol ---------------------------------

def fly_fake(tmp_path, *fake_args: str, time_limit_s: float = 4.0, stall_timeout_s: float = 5.0, failures=(), bridge_args=(), rig=None):
    """The bridge (protocol ardupilot-json) against tests/fake_ardupilot.py: (exit code, bridge summary, what the fake saw).
    With a rig, its messages go to the fake's SERIAL1 as the ArduPilot adapter has them sent."""
    world_path = tmp_path / "world.json"
    world_path.write_text(json.dumps({**world(time_limit_s=time_limit_s), "failures": list(failures), **({"rig": rig} if rig else {})}))
    with PortLease(first_slot=120) as ports:
        if rig:
            capabilities = ArduPilotSitl.capabilities
            companion_port = str(capabilities.companion_port(ports.slot))
            bridge_args = (*bridge_args, "--companion-port", companion_port, "--companion-messages", ",".join(capabilities.companion_messages),
                           "--companion-connects", "--distance-sensor-convention", capabilities.distance_sensor_convention)
            fake_args = (*fake_args, "--serial1-port", companion_port)
        bridge = subprocess.Popen(
            [sys.executable, "-m", "sim_bridge", "--world", str(world_path), "--sim-port", str(ports.sim), "--mcap", str(tmp_path / "run.mcap"),
             "--sim-protocol", "ardupilot-json", "--hold-after-s", "0", "--stall-timeout-s", str(stall_timeout_s), "--connect-timeout-s", "20",
             "--rate-hz", "400", *bridge_args],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT,
        )
        fake = subprocess.Popen([sys.executable, str(FAKE_ARDUPILOT), "--port", str(ports.sim), "--frames", "100000", *fake_args],
                                cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        try:
            out, err = bridge.communicate(timeout=180)
            seen, fake_err = fake.communicate(timeout=30)
        finally:
            fake.kill()
            bridge.kill()
    assert "Traceback" not in err.decode() and "Traceback" not in fake_err.decode(), (err.decode()[-2000:], fake_err.decode()[-2000:])
    return bridge.returncode, json.loads(out.decode().strip().splitlines()[-1]), json.loads(seen.decode().strip().splitlines()[-1])


# With two cores the bridge polls for the answer before it sleeps (--spin-us, as for MAVLink).
SPIN = pytest.mark.parametrize("bridge_args", [(), ("--spin-us", "2000")], ids=["sleeping", "polling"])


@pytest.mark.slow
@SPIN
def test_each_servo_frame_is_answered_by_one_step_and_the_lines_are_what_ardupilot_parses(tmp_path, bridge_args):
    code, summary, seen = fly_fake(tmp_path, bridge_args=bridge_args)
    assert code == 0 and summary["end_reason"] == "time_limit" and summary["steps"] == 4 * 400
    # One line per frame, one step apart in simulated time, each whole to ArduPilot's parser.
    assert seen["parsed"] == summary["steps"] and seen["step_us"] == [2500] and seen["bad_lines"] == []
    # No frame was sent again but one whose line was still on the way (a second's wait on a loaded machine).
    assert seen["ranges_seen"] == seen["parsed"] and seen["resent"] == seen["duplicates"] and summary["bad_frames"] == 0


@pytest.mark.slow
def test_a_rig_reaches_ardupilot_as_mavlink_on_its_serial1_and_its_json_carries_no_rangefinders(tmp_path):
    """ArduPilot's proximity backend reads a rig's OBSTACLE_DISTANCE and DISTANCE_SENSOR on a
    MAVLink serial port that sends to the bridge from a port of its own (`udpclient:`)."""
    from dataclasses import asdict

    from harness.scenario.profile import load_profile
    from harness.scenario.rig import load_rig, rig_sensors

    rig = [asdict(sensor) for sensor in rig_sensors(load_rig("lidar_and_rangefinders"), load_profile().sensor, 10000.0)]
    code, summary, seen = fly_fake(tmp_path, rig=rig)
    assert code == 0 and summary["end_reason"] == "time_limit" and seen["parsed"] == summary["steps"] == 4 * 400
    serial1 = seen["serial1"]
    # From its first heartbeat, at its first step, on: the lidar at 10 Hz, front and back at 25 Hz each, 4 s
    assert serial1["first_t"] <= 0.1 and serial1["OBSTACLE_DISTANCE"] >= 39 and serial1["DISTANCE_SENSOR"] >= 2 * 99
    assert sorted(serial1["orientations"]) == [mavlink.MAV_SENSOR_ROTATION_NONE, mavlink.MAV_SENSOR_ROTATION_YAW_180]
    assert serial1["sources"] == [[1, mavlink.MAV_COMP_ID_OBSTACLE_AVOIDANCE]] and seen["ranges_seen"] == 0


@pytest.mark.slow
def test_a_lost_line_is_sent_again_without_a_second_step_and_skipped_or_restarted_counts_fly_on(tmp_path):
    code, summary, seen = fly_fake(tmp_path, "--ignore-every", "200", "--skip-every", "300", "--restart-at", "700")
    assert code == 0 and summary["end_reason"] == "time_limit" and summary["steps"] == 4 * 400
    # Each lost line was answered again when its frame came again; on a loaded machine a frame can
    # also come again while its line is on the way, and then its second answer is a duplicate.
    assert seen["ignored"] >= 7 and seen["resent"] == seen["ignored"] + seen["duplicates"]
    assert seen["parsed"] == summary["steps"] and seen["step_us"] == [2500] and seen["bad_lines"] == []


@pytest.mark.slow
@SPIN
def test_the_bridge_flies_on_through_ten_thousand_junk_datagrams_between_the_frames(tmp_path, bridge_args):
    code, summary, seen = fly_fake(tmp_path, "--junk", "7", "--seed", "3", time_limit_s=4.0, bridge_args=bridge_args)
    assert seen["junk"] >= 10_000
    assert code == 0 and summary["end_reason"] == "time_limit" and seen["parsed"] == summary["steps"] == 4 * 400
    # Each frame after the first came after seven junk datagrams, each counted and skipped (the
    # fake sends none before the first answer, when the simulator may not be listening yet; the
    # seven after the last answer count if they come before the simulator closes its socket).
    assert 7 * (summary["steps"] - 1) <= summary["bad_frames"] <= 7 * summary["steps"]


@pytest.mark.slow
def test_a_recorded_flight_replays_to_ardupilot_alone_one_line_per_servo_frame(tmp_path):
    # GIVEN the bridge's recording of a flight against the fake, two of whose lines were lost on
    # the way, so that their frames came again and the bridge sent those lines again
    code, summary, _seen = fly_fake(tmp_path, "--ignore-every", "500", time_limit_s=2.0)
    assert code == 0
    recorded = recorded_link(tmp_path / "run.mcap", "ardupilot-json")
    # THEN the replay has each step once, as the line that was sent, a step apart
    steps, times = recorded["steps"], recorded["times_us"]
    assert len(steps) == summary["steps"] and recorded["dt_s"] == 1 / 400
    assert {b - a for a, b in zip(times, times[1:])} == {2500} and all(line.startswith(b"\n{") and line.endswith(b"}\n") for line in steps)
    with pytest.raises(ValueError, match="not a bridge's recording of ArduPilot's JSON link"):
        json_link_steps(b"\xfe\x21junk\n" + b"".join(steps[:3]))

    # WHEN it is replayed to a fresh ArduPilot (here the fake) by the stand-in of `stella bench --limit`
    with PortLease(first_slot=120) as ports:
        listener = listen_udp(ports.sim)
        fake = subprocess.Popen([sys.executable, str(FAKE_ARDUPILOT), "--port", str(ports.sim), "--frames", str(len(steps))], cwd=ROOT,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        try:
            result = replay_json(accept(listener, 20.0, 5.0), steps, recorded["dt_s"], 100, spin_s=0.0)
            seen = json.loads(fake.communicate(timeout=30)[0].decode().strip().splitlines()[-1])
        finally:
            fake.kill()
            listener.close()
    # THEN each of its frames was answered by the next line, in lockstep, and timed from step 100
    assert result["in_step"] and result["timed_steps"] == len(steps) - 100 and result["real_time_factor"] > 0
    assert seen["parsed"] == len(steps) and seen["step_us"] == [2500] and seen["resent"] == 0 and seen["bad_lines"] == []


@pytest.mark.slow
def test_an_ardupilot_that_goes_silent_ends_the_flight_as_stalled(tmp_path):
    code, summary, seen = fly_fake(tmp_path, "--quiet-after-s", "0.5", "--frames", "300", time_limit_s=30.0, stall_timeout_s=1.0)
    # Its last line answered, it sends no frame: the step it would have answered never comes. The
    # link is in lockstep from its first frame, however late the fake's first answer on a loaded
    # machine: no step is flown without a frame to answer.
    assert code == 3 and summary["end_reason"] == "sut_stalled" and seen["parsed"] == 300 and summary["steps"] == 299


@pytest.mark.slow
def test_a_gps_failure_the_simulator_would_deliver_is_recorded_as_refused_and_a_distance_sensor_failure_silences_the_rangefinders(tmp_path):
    failures = [{"unit": "gps", "type": "off", "onset_s": 1.0, "duration_s": 1.0, "delivery": "simulator"},
                {"unit": "distance sensor", "type": "off", "onset_s": 0.0, "duration_s": 10.0, "delivery": "simulator"}]
    code, summary, seen = fly_fake(tmp_path, failures=failures)
    assert code == 0 and seen["parsed"] == summary["steps"]
    assert seen["ranges_seen"] == 0
    events = [m for _t, _ns, m in logs.messages(tmp_path / "run.mcap", ["/events"])]
    assert [e["detail"]["unit"] for e in events if e["event"] == "failure_refused"] == ["gps"]


# -- failures through ArduPilot SITL's parameters ---------------------------------------------

def test_each_failure_ardupilot_sitl_can_make_is_a_parameter_set_its_end_sets_back_and_the_rest_are_refused():
    mapped = {(unit, kind): failure_params(unit, kind) for unit in UNIT_BY_NAME for kind in TYPE_BY_NAME}
    assert sorted(key for key, params in mapped.items() if params is not None) == sorted([
        ("gyro", "off"), ("gyro", "wrong"), ("accelerometer", "off"), ("accelerometer", "wrong"), ("magnetometer", "off"),
        ("magnetometer", "stuck"), ("magnetometer", "wrong"), ("barometer", "off"), ("barometer", "stuck"), ("barometer", "wrong"),
        ("gps", "off"), ("gps", "wrong"), ("gps", "slow")])
    for (unit, _kind), params in mapped.items():
        if params is not None:
            unfailed = failure_params(unit, "ok")
            assert set(params) <= set(unfailed) and all(unfailed[name] != value for name, value in params.items())
    # The distance sensor's failures are the simulator's, for ArduPilot as for every SUT.
    assert failure_params("distance sensor", "off") is None
    # The meanings are simlink/failures.py's: 20 m north, 10 m high, +0.05 rad/s of yaw rate, one reading in five.
    north_m = geo.local_from_geodetic(47.0, 8.0, 47.0 + failure_params("gps", "wrong")["SIM_GPS1_GLTCH_X"], 8.0)[0]
    assert north_m == pytest.approx(20.0, abs=0.1)
    assert failure_params("barometer", "wrong")["SIM_BARO_GLITCH"] == 10.0 and failure_params("gyro", "wrong")["SIM_GYR1_BIAS_Z"] == 0.05
    assert failure_params("gps", "slow")["SIM_GPS1_HZ"] * 5 == failure_params("gps", "ok")["SIM_GPS1_HZ"]


def test_ardupilots_gps_failures_are_told_to_it_and_the_distance_sensors_stay_the_simulators(arducopter):
    failures = [{"unit": "gps", "type": "off", "onset_s": 1.0, "duration_s": 1.0, "delivery": "simulator"},
                {"unit": "distance sensor", "type": "off", "onset_s": 0.0, "duration_s": 10.0, "delivery": "simulator"}]
    spec = WorldSpec.from_dict({**world(), "failures": failures})
    placed = get("ardupilot", {"ardupilot_bin": str(arducopter)}).capabilities.with_failure_deliveries(spec)
    assert [(f.unit, f.delivery) for f in placed.failures] == [("gps", "sut"), ("distance sensor", "simulator")]
    assert get("bundled").capabilities.with_failure_deliveries(spec) is spec
