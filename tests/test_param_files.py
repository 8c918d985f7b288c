"""SUT parameter files (QGroundControl's .params, the competition's NAME,VALUE CSV) and how they
merge with --sut-param."""

from __future__ import annotations

import argparse
import logging

import pytest

from autopilot.params import Params
from harness.errors import InputError
from harness.interop.param_files import load_params_file
from harness.tools.cli import main
from harness.tools.commands.sut_options import sut_spec

QGC = """# Onboard parameters for Vehicle 1
#
# Stack: PX4 Pro
# Vehicle: Multi-Rotor
#
# Vehicle-Id Component-Id Name Value Type
1\t1\tCP_DIST\t2.500000000000000000\t9
1\t1\tCP_GO_NO_DATA\t1\t6
1\t1\tMPC_XY_CRUISE\t5.000000000000000000\t9
"""


def test_qgroundcontrol_params_keep_their_types(tmp_path):
    path = tmp_path / "vehicle.params"
    path.write_text(QGC)
    values = load_params_file(path)
    assert values == {"CP_DIST": 2.5, "CP_GO_NO_DATA": 1, "MPC_XY_CRUISE": 5.0}
    assert isinstance(values["CP_GO_NO_DATA"], int) and isinstance(values["MPC_XY_CRUISE"], float)


def test_competition_csv_with_or_without_a_header(tmp_path):
    path = tmp_path / "params.csv"
    path.write_text("name,value\nCP_DIST,3\nMPC_XY_VEL_MAX, 8.5\n")
    assert load_params_file(path) == {"CP_DIST": 3, "MPC_XY_VEL_MAX": 8.5}
    path.write_text("CP_DIST,3\n")
    assert load_params_file(path) == {"CP_DIST": 3}


# The UAV Testing Competition's parameter file (Aerialist's samples/flights/auto-params.csv),
# written for PX4: most of it the bundled autopilot models, four names it does not.
COMPETITION = "NAV_ACC_RAD, 1.5\nNAV_MC_ALT_RAD, 0.5\nNAV_RCL_ACT, 3\nNAV_DLL_ACT, 0\nMIS_YAW_ERR, 12.0\nMIS_TAKEOFF_ALT, 0.5\nMPC_YAW_MODE, 0\nSDLOG_PROFILE, 131\n"


def spec_args(path, **more) -> argparse.Namespace:
    return argparse.Namespace(**{"sut": "bundled", "px4_bin": None, "sut_command": None, "sut_hold": None, "sut_param": None,
                                 "sut_params_file": str(path), "sut_fault": None, "autopilot_dir": None, **more})


def test_the_bundled_autopilot_takes_the_competitions_px4_parameters_and_says_once_which_have_no_effect(tmp_path, caplog):
    path = tmp_path / "mission-params.csv"
    path.write_text(COMPETITION)
    with caplog.at_level(logging.WARNING):
        config = sut_spec(spec_args(path))
    assert config.params == load_params_file(path)
    assert [r.getMessage() for r in caplog.records] == [
        "bundled: accepted without effect (PX4 parameters it does not model): MIS_YAW_ERR, MPC_YAW_MODE, NAV_MC_ALT_RAD, SDLOG_PROFILE"]
    params = Params(dict(config.params))
    assert (params["NAV_ACC_RAD"], params["NAV_RCL_ACT"], params["NAV_DLL_ACT"], params["MIS_TAKEOFF_ALT"]) == (1.5, 3, 0, 0.5)
    assert params.unmodelled == {"MIS_YAW_ERR": 12.0, "MPC_YAW_MODE": 0, "NAV_MC_ALT_RAD": 0.5, "SDLOG_PROFILE": 131}
    assert "MIS_YAW_ERR" not in params.names()  # not listed on the parameter protocol as if it worked


def test_a_name_px4_does_not_have_is_still_refused_and_the_message_names_the_option(tmp_path, capsys):
    path = tmp_path / "typo.csv"
    path.write_text("MIS_YAW_ERR,12\nCP_DISTANCE,2\n")
    assert main(["sut", "check", "--sut-params-file", str(path)]) == 2
    assert "--sut-params-file: bundled: unknown parameter 'CP_DISTANCE' (`python -m autopilot.params` lists its parameters)" in capsys.readouterr().err


def test_sut_param_wins_over_the_file(tmp_path):
    path = tmp_path / "params.csv"
    path.write_text("CP_DIST,3\nMPC_XY_CRUISE,4\n")
    args = argparse.Namespace(sut="bundled", px4_bin=None, sut_command=None, sut_hold=None, sut_param=["CP_DIST=1.5"], sut_params_file=str(path), sut_fault=None, autopilot_dir=None)
    assert sut_spec(args).params == {"CP_DIST": 1.5, "MPC_XY_CRUISE": 4}


@pytest.mark.parametrize("in_file, given, blamed", [("CP_DIST,3\n", ["CP_DISTANCE=2"], "--sut-param"), ("CP_DISTANCE,3\n", ["CP_DIST=2"], "--sut-params-file"),
                                                    ("CP_DIST,3\n", ["CP_DIST=99"], "--sut-param")])
def test_a_refused_parameter_is_put_on_the_option_it_came_from(tmp_path, in_file, given, blamed):
    path = tmp_path / "params.csv"
    path.write_text(in_file)
    with pytest.raises(InputError) as refused:
        sut_spec(spec_args(path, sut_param=given))
    assert [problem.file for problem in refused.value.problems] == [blamed]


# ArduPilot's own layouts: its SITL defaults (Tools/autotest/default_params/copter.parm, with a
# tab-separated line and an inline comment as in its other .parm files), MAVProxy's `param save`
# and Mission Planner's .param export.
ARDUPILOT_PARM = """FRAME_TYPE\t0
FS_THR_ENABLE   1
FENCE_RADIUS    150
FLTMODE6\t\t0
# we need small INS_ACC offsets so INS is recognised as being calibrated
INS_ACCOFFS_X   0.001
TECS_SPDWEIGHT 1.7 # allow some altitude control
"""
MAVPROXY = "FENCE_ALT_MAX    120.000000\nAVOID_MARGIN     1.500000\n"
MISSION_PLANNER = "#NOTE: 4/7/2017 9:02:52 PM Plane: Vee-gull 005\nACRO_LOCKING,0\nACRO_PITCH_RATE,180\n"


@pytest.mark.parametrize("text, values", [
    (ARDUPILOT_PARM, {"FRAME_TYPE": 0, "FS_THR_ENABLE": 1, "FENCE_RADIUS": 150, "FLTMODE6": 0, "INS_ACCOFFS_X": 0.001, "TECS_SPDWEIGHT": 1.7}),
    (MAVPROXY, {"FENCE_ALT_MAX": 120.0, "AVOID_MARGIN": 1.5}),
    (MISSION_PLANNER, {"ACRO_LOCKING": 0, "ACRO_PITCH_RATE": 180}),
    ("OA_TYPE=1\n", {"OA_TYPE": 1}),
])
def test_ardupilot_parameter_files_read_as_ardupilot_reads_them(tmp_path, text, values):
    path = tmp_path / "vehicle.parm"
    path.write_text(text)
    assert load_params_file(path) == values


def test_ardupilots_read_only_flag_is_said_to_be_ignored(tmp_path, caplog):
    path = tmp_path / "locked.parm"
    path.write_text("AVOID_MARGIN 2 @READONLY\n")
    with caplog.at_level(logging.WARNING):
        assert load_params_file(path) == {"AVOID_MARGIN": 2}
    assert "AVOID_MARGIN is set to 2; stella does not make it read-only (@READONLY ignored)" in caplog.text


@pytest.mark.parametrize("text, line, message", [
    ("CP_DIST\n", "line 1", "expected NAME,VALUE"),
    ("CP_DIST,near\n", "line 1", "not a finite number"),
    ("CP_DIST,nan\n", "line 1", "not a finite number"),
    ("CP_DIST,2\nCP_DIST,3\n", "line 2", "set twice"),
    ("AVOID_MARGIN 2 3\n", "line 1", "ArduPilot's NAME VALUE"),
    ("1\t1\tCP_GO_NO_DATA\t0.5\t6\n", "line 1", "not a finite number of the right type"),
    ("1\t1\tCP_DIST\t2\t42\n", "line 1", "unknown MAV_PARAM_TYPE 42"),
    ("THIS_NAME_IS_FAR_TOO_LONG,1\n", "line 1", "is not a parameter name"),
    ("# only a comment\n", "", "no parameters in this file"),
])
def test_a_bad_line_is_located_and_the_command_exits_2(tmp_path, capsys, text, line, message):
    path = tmp_path / "bad.params"
    path.write_text(text)
    with pytest.raises(InputError) as raised:
        load_params_file(path)
    located = f"{path}: {line}: " if line else f"{path}: "  # the file as a whole has no line
    assert str(raised.value).startswith(located) and message in str(raised.value)
    assert main(["sut", "check", "--sut-params-file", str(path)]) == 2
    assert located in capsys.readouterr().err
