"""SUT adapters: the generic command template, PX4 SITL's command line, ports, parameters and
ULog collection (without PX4), and the generic adapter flying the bundled autopilot for real."""

from __future__ import annotations

import json
import re
import os
import stat
import sys
import textwrap
import time

import numpy as np
import pytest

from conftest import ROOT
from harness.flight import logs
from harness.flight.evaluation import _crash, evaluate
from harness.flight.results import RunOptions
from harness.scenario.logical import load_logical
from harness.scenario.space import SearchSpace
from harness.scenario.world import world_spec
from harness.tools.cli import main
import sut_adapter
from sut_adapter import SutConfig, registry
from sut_adapter.base import start_process
from sut_adapter.command import CommandSut
from sut_adapter.processes import ManagedProcess
from sut_adapter.px4 import API_STREAM_RATES_HZ, DEFAULT_PARAMS, Px4Sitl, collect_artifacts

FIG4 = ROOT / "scenarios" / "examples" / "fig4.json"
AUTOPILOT = f"{sys.executable} -m autopilot --sim tcp:127.0.0.1:{{sim_port}} --api udp:127.0.0.1:{{api_port}}"


def fake_px4_build(tmp_path, script: str):
    """A folder shaped like build/px4_sitl_default whose bin/px4 is a shell script."""
    build = tmp_path / "build"
    (build / "bin").mkdir(parents=True)
    (build / "etc" / "init.d-posix").mkdir(parents=True)
    (build / "etc" / "init.d-posix" / "rcS").write_text("# PX4's startup script\n")
    binary = build / "bin" / "px4"
    binary.write_text("#!/bin/sh\n" + textwrap.dedent(script))
    binary.chmod(binary.stat().st_mode | stat.S_IXUSR)
    return build


# -- the generic command template ---------------------------------------------------------------


def test_a_template_is_split_like_a_shell_and_filled_word_by_word(tmp_path):
    sut = CommandSut({"command": "ap --sim 'tcp:127.0.0.1:{sim_port}' --gcs udp:127.0.0.1:{api_port} --id {instance} --dir {workdir}"})
    workdir = tmp_path / "with space"
    assert sut.argv(sim_port=4561, api_port=14541, instance=1, workdir=workdir) == [
        "ap", "--sim", "tcp:127.0.0.1:4561", "--gcs", "udp:127.0.0.1:14541", "--id", "1", "--dir", str(workdir)]
    assert sut.capabilities.hold_mode == "paced" and sut.capabilities.hold_pace == 1.0  # an unknown SUT is held at real time


@pytest.mark.parametrize(("config", "message"), [
    ({"command": ""}, "--sut-command is empty"),
    ({"command": "ap {sim_port} {api_port} {port}"}, "unknown placeholder(s) {port}; available: {sim_port}, {api_port}, {instance}, {workdir}"),
    ({"command": "ap --sim {sim_port}"}, "--sut-command must use {api_port}"),
    ({"command": "ap 'unclosed {sim_port} {api_port}"}, "cannot be split into words"),
    ({"command": "ap {sim_port} {api_port}", "hold": "later"}, "--sut-hold 'later' is not one of frozen, paced"),
    ({"command": "ap {sim_port} {api_port}", "px4_bin": "x"}, "unknown configuration ['px4_bin']"),
])
def test_bad_templates_say_what_to_fix(config, message):
    with pytest.raises(sut_adapter.SutError) as error:
        CommandSut(config)
    assert message in str(error.value)


def test_the_cli_refuses_a_bad_sut_before_flying(capsys):
    assert main(["run", str(FIG4), "--sut", "command", "--sut-command", "ap {sim_port}"]) == 2
    assert "--sut: command: --sut-command must use {api_port}" in capsys.readouterr().err
    assert main(["run", str(FIG4), "--sut", "nope"]) == 2
    assert "unknown SUT; available: ardupilot, bundled, command, px4" in capsys.readouterr().err


# -- PX4 SITL, without PX4 -----------------------------------------------------------------------


def test_px4_needs_a_build_and_says_where_to_give_it(tmp_path, monkeypatch):
    monkeypatch.delenv("STELLA_PX4_BIN", raising=False)
    with pytest.raises(sut_adapter.SutError, match="pass --px4-bin PATH .* or set STELLA_PX4_BIN"):
        Px4Sitl({})
    with pytest.raises(sut_adapter.SutError, match="is not an executable px4 binary"):
        Px4Sitl({"px4_bin": str(tmp_path)})
    build = fake_px4_build(tmp_path, "exit 0\n")
    (build / "etc" / "init.d-posix" / "rcS").unlink()
    with pytest.raises(sut_adapter.SutError, match="init.d-posix/rcS not found"):
        Px4Sitl({"px4_bin": str(build / "bin" / "px4")})


def test_px4_command_line_airframe_and_instance_ports(tmp_path, monkeypatch):
    build = fake_px4_build(tmp_path, "exit 0\n")
    monkeypatch.setenv("STELLA_PX4_BIN", str(build))
    px4 = Px4Sitl({})
    argv, env = px4.command(instance=3, workdir=tmp_path / "w")
    assert argv == [str(build / "bin" / "px4"), "-i", "3", "-d", "-w", str(tmp_path / "w"), str(build / "etc")]
    assert (env["PX4_SYS_AUTOSTART"], env["PX4_SIM_MODEL"]) == ("10016", "none_iris")
    assert px4.capabilities.hold_mode == "paced"
    # Its hold runs as fast as its timeouts were stretched for.
    assert px4.capabilities.hold_pace == float(env["PX4_SIM_SPEED_FACTOR"]) > 1.0
    with pytest.raises(sut_adapter.SutError, match="instance 10 is out of range"):
        px4.command(instance=10, workdir=tmp_path)
    with pytest.raises(sut_adapter.SutError, match="uses simulator port 4563 and API port 14543"):
        px4.start(sim_port=4560, api_port=14540, instance=3, workdir=tmp_path, params={})


def test_px4_is_started_in_a_fresh_directory_with_its_parameters_for_mavlink(tmp_path):
    build = fake_px4_build(tmp_path, """\
        echo "$@" > args.txt
        echo "$PX4_SYS_AUTOSTART $PX4_SIM_MODEL" > env.txt
        pwd > cwd.txt
        """)
    workdir = tmp_path / "evaluation"
    workdir.mkdir()
    handle = Px4Sitl({"px4_bin": str(build)}).start(sim_port=4562, api_port=14542, instance=2, workdir=workdir, params={"CP_DIST": 2.5, "MPC_XY_CRUISE": 4.0})
    deadline = time.monotonic() + 10.0
    while handle.alive() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert handle.stop() == 0
    px4_dir = workdir / "px4"
    assert (px4_dir / "args.txt").read_text().split() == ["-i", "2", "-d", "-w", str(px4_dir), str(build / "etc")]
    assert (px4_dir / "env.txt").read_text().split() == ["10016", "none_iris"]
    assert (px4_dir / "cwd.txt").read_text().strip() == str(px4_dir)
    assert handle.mavlink_params == {**DEFAULT_PARAMS, "CP_DIST": 2.5, "MPC_XY_CRUISE": 4.0}


def test_a_px4_whose_start_up_takes_parameters_from_its_environment_gets_the_flights_there(tmp_path, profile):
    """PX4's rcS sets PX4_PARAM_* before it starts its modules: the pilot drive's take-off
    altitude reaches its navigator from the start, not over MAVLink just before the take-off."""
    build = fake_px4_build(tmp_path, """\
        env | grep '^PX4_PARAM_' | sort > params.txt
        """)
    (build / "etc" / "init.d-posix" / "rcS").write_text("# PX4's startup script\n# export PX4_PARAM_{name}={value}\n")
    px4 = Px4Sitl({"px4_bin": str(build)})
    assert px4.capabilities.params_at_start and not Px4Sitl.capabilities.params_at_start
    world = wall_world(profile, "pilot")
    flight = px4.capabilities.flight_params(world)
    assert flight["MIS_TAKEOFF_ALT"] == world.mission.takeoff_altitude_m and flight["COM_RC_IN_MODE"] == 0
    workdir = tmp_path / "evaluation"
    workdir.mkdir()
    handle = px4.start(sim_port=4562, api_port=14542, instance=2, workdir=workdir, params={"CP_DIST": 2.5, "MIS_TAKEOFF_ALT": 4.0}, flight_params=flight)
    deadline = time.monotonic() + 10.0
    while handle.alive() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert handle.stop() == 0
    # the user's values win; instance 2 is system 1 as every instance is
    expected = {**DEFAULT_PARAMS, "MAV_SYS_ID": 1, **flight, "CP_DIST": 2.5, "MIS_TAKEOFF_ALT": 4.0}
    assert (workdir / "px4" / "params.txt").read_text().splitlines() == sorted(f"PX4_PARAM_{name}={value}" for name, value in expected.items())
    # The user's go over MAVLink too, where PX4 refuses a name it does not have.
    assert handle.mavlink_params == {"CP_DIST": 2.5, "MIS_TAKEOFF_ALT": 4.0}
    # A mission takes none of the pilot's.
    assert px4.capabilities.flight_params(wall_world(profile, "mission")) == {}


def wall_world(profile, drive: str):
    space = SearchSpace(load_logical(ROOT / "scenarios" / "examples" / "wall.json", profile, drive), profile)
    return world_spec(space, space.sample_feasible(np.random.default_rng(3), 1)[0], 3)


def test_px4s_rcs_sources_its_own_mavlink_start_up_and_then_the_adapters_lower_api_rates(tmp_path):
    # As PX4 starts rcS: its bin/ first on PATH, its init.d-posix/ appended last, then `. px4-rc.mavlink`.
    build = fake_px4_build(tmp_path, """\
        mavlink() { echo "mavlink $*" >> streams.txt; }
        PATH="$(dirname "$0"):$PATH:$(dirname "$0")/../etc/init.d-posix"
        . px4-rc.mavlink
        """)
    (build / "etc" / "init.d-posix" / "px4-rc.mavlink").write_text('echo "PX4\'s own MAVLink start-up" >> streams.txt\n')
    workdir = tmp_path / "evaluation"
    workdir.mkdir()
    handle = Px4Sitl({"px4_bin": str(build)}).start(sim_port=4562, api_port=14542, instance=2, workdir=workdir, params={})
    deadline = time.monotonic() + 10.0
    while handle.alive() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert handle.stop() == 0
    streams = (workdir / "px4" / "streams.txt").read_text().splitlines()
    assert streams[0] == "PX4's own MAVLink start-up"
    # PX4 instance 2's API link listens on UDP 14582 (px4-rc.mavlink's udp_offboard_port_local).
    assert streams[1:] == [f"mavlink stream -u 14582 -s {name} -r {rate}" for name, rate in API_STREAM_RATES_HZ.items()]
    assert API_STREAM_RATES_HZ["ATTITUDE"] < 100 and API_STREAM_RATES_HZ["DISTANCE_SENSOR"] > 0  # the ranges PX4 got stay in the log


@pytest.mark.parametrize("returned", ["INFO  [px4] Startup script returned successfully", "ERROR [px4] Startup script returned with return value: 1"])
def test_px4_counts_as_booted_only_once_its_start_up_script_returned(tmp_path, returned):
    """PX4 heartbeats on its API link before its rcS ends, and drops parameter messages until then."""
    build = fake_px4_build(tmp_path, f"""\
        echo "INFO  [mavlink] mode: Onboard, data rate: 4000000 B/s on udp port 14582 remote port 14542"
        until [ -e go ]; do sleep 0.01; done
        printf '{returned[:30]}'
        until [ -e go-on ]; do sleep 0.01; done
        echo '{returned[30:]}'
        sleep 10
        """)
    workdir = tmp_path / "evaluation"
    workdir.mkdir()
    handle = Px4Sitl({"px4_bin": str(build)}).start(sim_port=4562, api_port=14542, instance=2, workdir=workdir, params={})
    console = workdir / "px4.stdout.log"

    def after(printed: str) -> bool:
        deadline = time.monotonic() + 10.0
        while printed not in console.read_text() and time.monotonic() < deadline:
            time.sleep(0.01)
        return handle.booted()

    try:
        assert not after("mode: Onboard")
        (workdir / "px4" / "go").touch()
        assert not after(returned[:30])
        (workdir / "px4" / "go-on").touch()
        assert after(returned)
    finally:
        handle.stop()


def test_px4_ulogs_and_console_are_its_artifacts(tmp_path):
    (tmp_path / "log" / "2026-11-22").mkdir(parents=True)
    (tmp_path / "log" / "2026-11-22" / "10_00_01.ulg").write_bytes(b"ULog\x01\x12\x35")
    console = tmp_path / "px4.stdout.log"
    console.write_text("INFO  [px4] startup\n")
    empty = tmp_path / "px4.stderr.log"
    empty.write_text("")
    assert collect_artifacts(tmp_path, [console, empty]) == [tmp_path / "log" / "2026-11-22" / "10_00_01.ulg", console]


@pytest.mark.slow
def test_a_px4_that_dies_before_connecting_is_classified_and_its_ulog_kept(tmp_path, profile):
    build = fake_px4_build(tmp_path, """\
        mkdir -p log/2026-11-22 && printf 'ULog' > log/2026-11-22/10_00_01.ulg
        echo "ERROR [simulator_mavlink] gave up" >&2
        exit 1
        """)
    space = SearchSpace(load_logical(FIG4, profile), profile)
    x = space.sample_feasible(np.random.default_rng(1), 1)[0]
    options = RunOptions(sut=SutConfig("px4", px4_bin=str(build)), setup_timeout_s=10.0)
    result = evaluate(space, x, seed=1, out_dir=tmp_path / "out", options=options)
    assert result.status == "sut_crashed" and "gave up" in result.why
    assert [os.path.basename(a) for a in result.artifacts] == ["10_00_01.ulg", "px4.stderr.log"]
    assert open(result.artifacts[0], "rb").read() == b"ULog"


# -- the generic adapter flying the bundled autopilot, and the stage check ------------------------


@pytest.mark.slow
def test_the_command_adapter_flies_the_bundled_autopilot_exactly_as_the_bundled_adapter(tmp_path, profile):
    space = SearchSpace(load_logical(FIG4, profile), profile)
    x = space.sample_feasible(np.random.default_rng(1), 1)[0]
    bundled = evaluate(space, x, seed=1, out_dir=tmp_path, name="bundled")
    generic = evaluate(space, x, seed=1, out_dir=tmp_path, name="generic", options=RunOptions(sut=SutConfig("command", command=AUTOPILOT, hold="frozen")))
    assert generic.status == bundled.status == "ok"
    assert generic.fitness == bundled.fitness
    traces = [[m["d"] for _t, _ns, m in logs.messages(r.log_path, ["/clearance"])] for r in (bundled, generic)]
    assert traces[0] == traces[1]
    assert generic.artifacts == []  # the autopilot printed nothing, so no empty console logs are kept


def test_a_sut_that_dies_of_a_signal_says_which_rather_than_its_last_console_line(tmp_path, profile):
    # GIVEN the bundled autopilot, printing start-up noise, that dies of SIGFPE a second after it starts
    # (in flight or, on a slow machine, during set-up: both must say so)
    dying = (f"{sys.executable} -c \"import os, signal, sys, threading, runpy; print('uxrce_dds_client: not found', file=sys.stderr); "
             "threading.Timer(1.0, lambda: os.kill(os.getpid(), signal.SIGFPE)).start(); "
             "sys.argv = ['autopilot', '--sim', 'tcp:127.0.0.1:{sim_port}', '--api', 'udp:127.0.0.1:{api_port}']; "
             "runpy.run_module('autopilot', run_name='__main__')\"")
    space = SearchSpace(load_logical(FIG4, profile), profile)
    x = space.sample_feasible(np.random.default_rng(1), 1)[0]
    result = evaluate(space, x, seed=1, out_dir=tmp_path, options=RunOptions(sut=SutConfig("command", command=dying, hold="frozen")))
    # THEN the flight is a crash that names the signal before the console's noise
    assert result.status == "sut_crashed"
    assert "command died of SIGFPE (Floating point exception); its console ends:" in result.why and "uxrce_dds_client: not found" in result.why


@pytest.mark.slow
def test_parameters_reach_the_sut_over_mavlink(tmp_path, profile):
    """CP_DIST set through the generic adapter (over MAVLink) changes where a wall stops the vehicle."""
    space = SearchSpace(load_logical(ROOT / "tests" / "data" / "scenarios" / "wall.json", profile), profile)
    x = space.vector_from({})
    results = {}
    for cp_dist in (1.0, 3.0):
        options = RunOptions(sut=SutConfig("command", {"CP_DIST": cp_dist}, command=AUTOPILOT, hold="frozen"))
        results[cp_dist] = evaluate(space, x, seed=1, out_dir=tmp_path, name=f"cp{cp_dist}", options=options)
    assert results[3.0].min_clearance_m == pytest.approx(results[1.0].min_clearance_m + 2.0, abs=0.6)


@pytest.mark.slow
def test_sut_check_passes_every_stage_for_the_bundled_autopilot(capsys):
    assert main(["sut", "check", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert [stage["name"] for stage in report["stages"]] == ["process started", "simulator connected", "lockstep running", "API heartbeat",
                                                              "health ok", "armable", "mission upload ok"]
    assert all(stage["ok"] for stage in report["stages"])
    times = [stage["after_s"] for stage in report["stages"]]
    assert times == sorted(times)


def late_armable(late_s: float, refusal: str = "denied") -> list[str]:
    """A paced SUT (as PX4) that denies arming for late_s of simulated time after MAVSDK reports
    it healthy; refusal "failed" answers as ArduPilot does, MAV_RESULT_FAILED."""
    return ["--sut", "command", "--sut-command",
            f"{sys.executable} {ROOT / 'tests' / 'late_armable_sut.py'} {{sim_port}} {{api_port}} {late_s} {refusal}"]


@pytest.mark.slow
def test_sut_check_judges_armability_as_a_flight_does_and_says_how_long_arming_took(capsys, tmp_path):
    # GIVEN a SUT healthy but not yet armable, as PX4 just after its start-up
    assert main(["sut", "check", *late_armable(1.0), "--json"]) == 0
    armable = json.loads(capsys.readouterr().out)["stages"][5]
    # THEN the check arms it as a flight would, asking again while it denies
    assert armable["name"] == "armable" and armable["ok"], armable
    assert armable["detail"].startswith("armed ") and "s after asking (a flight asks again for up to 10 s), then disarmed" in armable["detail"]
    # ... and a flight of the same SUT arms too
    assert main(["run", str(ROOT / "scenarios" / "examples" / "fig4.json"), "--seed", "1", *late_armable(1.0), "--out", str(tmp_path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["status"] in ("ok", "violation")


@pytest.mark.slow
def test_an_arming_refused_as_arducopter_refuses_it_is_asked_again_too(capsys):
    # GIVEN a SUT that answers MAV_RESULT_FAILED while its pre-arm checks fail, as ArduCopter does
    code = main(["sut", "check", *late_armable(1.0, "failed"), "--json"])
    stages = json.loads(capsys.readouterr().out)["stages"]
    # THEN it is armed once its checks pass, as one answering DENIED is
    assert code == 0 and stages[5]["name"] == "armable" and stages[5]["ok"], stages


@pytest.mark.slow
def test_sut_check_fails_at_armable_a_sut_that_denies_arming_longer_than_a_flight_asks(capsys):
    assert main(["sut", "check", *late_armable(1e6), "--json"]) == 3
    stages = json.loads(capsys.readouterr().out)["stages"]
    assert [stage["ok"] for stage in stages] == [True, True, True, True, True, False, None]
    assert "arming refused" in stages[5]["detail"] and "as long as a flight asks" in stages[5]["detail"]
    assert "pre-arm checks still running" in stages[5]["detail"]  # the SUT's own reason, from its status texts


@pytest.mark.slow
def test_sut_check_names_the_stage_a_silent_sut_fails_at(capsys):
    silent = f"{sys.executable} -c 'import time, sys; time.sleep(60)' {{sim_port}} {{api_port}}"
    assert main(["sut", "check", "--sut", "command", "--sut-command", silent, "--timeout-s", "3", "--json"]) == 3
    stages = json.loads(capsys.readouterr().out)["stages"]
    assert [stage["ok"] for stage in stages] == [True, False, None, None, None, None, None]
    assert "the SUT never connected to the simulator on TCP" in stages[1]["detail"]


@pytest.mark.parametrize("pace", [0, -1.0, float("nan"), float("inf"), "20"])
def test_a_sut_adapter_with_a_bad_hold_pace_is_a_sut_error(pace, monkeypatch):
    class Adapter:
        name = "custom"
        capabilities = sut_adapter.Capabilities(hold_mode="paced", range_messages=("DISTANCE_SENSOR",), hold_pace=pace)

        def __init__(self, config):
            pass

    monkeypatch.setattr(registry, "_REGISTRY", {**registry._REGISTRY, "custom": Adapter})
    with pytest.raises(sut_adapter.SutError, match="custom: its hold_pace"):
        sut_adapter.get("custom")


def test_a_sut_adapter_that_declares_no_capabilities_is_told_how_to_declare_them(monkeypatch):
    class Adapter:
        name = "custom"
        hold_mode = "paced"  # the attributes adapters had before capabilities were declared in one record

        def __init__(self, config):
            pass

    monkeypatch.setattr(registry, "_REGISTRY", {**registry._REGISTRY, "custom": Adapter})
    with pytest.raises(sut_adapter.SutError, match=r"custom: its adapter declares no capabilities: give it `capabilities = sut_adapter.Capabilities\("):
        sut_adapter.get("custom")


@pytest.mark.parametrize("simulator_exit", [3, 1], ids=["simulator lost its SUT", "simulator failed after"])
def test_a_sut_dead_of_a_signal_crashed_the_flight_whoever_is_found_gone_first(tmp_path, simulator_exit):
    # GIVEN a SUT that died of SIGSEGV and a simulator that exited after it (with the code it
    # gives when its SUT's link went, or any other): both gone before the harness looks, as
    # happens with every core busy
    sut = start_process("px4", ManagedProcess("px4", [sys.executable, "-c", "import os, signal; os.kill(os.getpid(), signal.SIGSEGV)"], log_dir=tmp_path))
    try:
        with ManagedProcess("bridge", [sys.executable, "-c", f"import time; time.sleep(0.2); raise SystemExit({simulator_exit})"], log_dir=tmp_path) as bridge:
            assert bridge.wait(10.0) == simulator_exit and sut.settled_exit_status() is not None
            # WHEN the harness says why set-up failed, THEN it is the SUT's crash, named by its signal
            failure = _crash(bridge, sut, "setup: no heartbeat")
    finally:
        sut.stop()
    assert failure.status == "sut_crashed" and "px4 died of SIGSEGV" in failure.why


def test_a_simulator_that_failed_while_its_sut_ran_crashed_the_flight(tmp_path):
    sut = start_process("px4", ManagedProcess("px4", [sys.executable, "-c", "import time; time.sleep(30)"], log_dir=tmp_path))
    try:
        with ManagedProcess("bridge", [sys.executable, "-c", "raise SystemExit(1)"], log_dir=tmp_path) as bridge:
            bridge.wait(10.0)
            failure = _crash(bridge, sut, "setup: no heartbeat")
    finally:
        sut.stop()
    assert failure.status == "sim_crashed" and "simulator exited with 1" in failure.why


@pytest.mark.slow
def test_a_sut_frozen_before_it_connects_is_the_suts_failure_not_the_simulators(tmp_path, profile):
    """The simulator gives up on a SUT that never connected after as long as the harness waits for
    its heartbeat, and exits (EXIT_CUT_SHORT) just after the harness gave up: the flight is still
    the SUT's failure, as the simulator says, not a simulator that crashed."""
    stalling = f"sh -c '{AUTOPILOT} & sleep 0.02; kill -STOP $!; wait'"
    space = SearchSpace(load_logical(FIG4, profile), profile)
    x = space.sample_feasible(np.random.default_rng(1), 1)[0]
    result = evaluate(space, x, seed=1, out_dir=tmp_path, options=RunOptions(sut=SutConfig("command", command=stalling, hold="frozen")))
    assert result.status == "sut_crashed", result.why
    assert result.why.startswith("command never connected to its simulator link"), result.why


@pytest.mark.slow
def test_a_sut_that_stops_answering_says_when_and_after_what_before_its_console(tmp_path, profile):
    # GIVEN the bundled autopilot, frozen (SIGSTOP) 0.8 s after it starts: alive, silent on both links
    stalling = f"sh -c '{AUTOPILOT} & sleep 0.8; kill -STOP $!; wait'"
    space = SearchSpace(load_logical(FIG4, profile), profile)
    x = space.sample_feasible(np.random.default_rng(1), 1)[0]
    result = evaluate(space, x, seed=1, out_dir=tmp_path, options=RunOptions(sut=SutConfig("command", command=stalling, hold="frozen")))
    # THEN the flight is the SUT's failure, saying what stopped, when, and what it had last been asked
    assert result.status == "sut_crashed", result.why
    # (when depends on the machine's load: before it connected, in set-up or in flight)
    said = re.fullmatch(r"command (never connected to its simulator link|stopped answering its simulator link "
                        r"(in set-up, [0-9.]+ s of simulated time after it started|[0-9.]+ s into the flight))"
                        r"(, after (?P<request>[^;]+))?; command still ran but stopped answering; its console ends: .*", result.why, re.DOTALL)
    assert said, result.why
    assert "into the flight" not in result.why or said["request"] in ("the mission was started", "take-off was requested"), result.why
