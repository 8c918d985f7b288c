"""The scenario language's failures (simlink/failures.py) as ArduPilot SITL's own failure means.

ArduPilot has no MAV_CMD_INJECT_FAILURE; its SITL fails its simulated sensors through SIM_*
parameters instead, set over MAVLink (PARAM_SET) at the failure's onset and set back at its end.
Through the JSON backend ArduPilot makes its GPS, barometer and compass itself from the true
state, and adds its IMU's SIM_* errors to ours, so these are the failures' only way in. A unit
and type without such a parameter is refused (`failure_refused` in /events), as before.

Each mapping gives the unit's readings the meaning simlink/failures.py gives the type:

| unit | type | ArduPilot SITL | what it does there |
| --- | --- | --- | --- |
| gyro | off | SIM_GYR_FAIL_MSK 7 | no new gyro samples from any IMU (AP_InertialSensor_SITL) |
| gyro | wrong | SIM_GYRn_BIAS_Z 0.05 | +0.05 rad/s about z on every IMU |
| accelerometer | off | SIM_ACC_FAIL_MSK 7 | no new accelerometer samples |
| accelerometer | wrong | SIM_ACCn_BIAS_X 1.0 | +1 m/s^2 along x on every IMU |
| magnetometer | off | SIM_MAGn_FAIL 1 | no data (AP_Compass_SITL) |
| magnetometer | stuck | SIM_MAGn_FAIL 2 | the last field, over and over |
| magnetometer | wrong | SIM_MAGn_ORIENT 2 | the field turned by yaw 90: the heading reads 90 degrees clockwise |
| barometer | off | SIM_BARO_DISABLE 1 (and BAR2) | no samples (AP_Baro_SITL) |
| barometer | stuck | SIM_BARO_FREEZE 1 (and BAR2) | the last altitude, over and over |
| barometer | wrong | SIM_BARO_GLITCH 10 (and BAR2) | 10 m high |
| gps | off | SIM_GPS1_ENABLE 0 | no lock (SIM_GPS.cpp: have_lock needs it) |
| gps | wrong | SIM_GPS1_GLTCH_X 20 m of latitude | 20 m north |
| gps | slow | SIM_GPS1_HZ 1 | 1 Hz instead of its 5 Hz: every 5th reading |

Refused: intermittent (every unit), stuck gyro, accelerometer and GPS, slow gyro,
accelerometer, magnetometer and barometer. The end of a failure sets the parameters it set back
to SITL's defaults. The distance sensor's failures are the simulator's own (the rangefinders it
sends), for every SUT.
"""

from __future__ import annotations

from typing import Mapping

# SITL simulates up to three IMUs and compasses and two barometers; a failure of a unit fails all
# of its instances, as MAV_CMD_INJECT_FAILURE's instance 0 does.
IMUS = (1, 2, 3)
COMPASSES = (1, 2, 3)
BAROMETERS = ("BARO", "BAR2")
ALL_IMUS_MASK = 0b111
GYRO_WRONG_RAD_S = 0.05  # simlink/failures.py's
ACCEL_WRONG_M_S2 = 1.0
BARO_WRONG_M = 10.0
GPS_WRONG_NORTH_M = 20.0
METRES_PER_DEGREE_LATITUDE = 111_319.49
GPS_RATE_HZ = 5  # SIM_GPS1_HZ's default
GPS_SLOW_RATE_HZ = 1  # simlink/failures.py's SLOW_FACTOR of 5
ROTATION_YAW_90 = 2  # ArduPilot's Rotation enum

# unit -> (type -> parameters that fail it, the parameters' values without a failure)
_MEANS: dict[str, tuple[dict[str, dict[str, float]], dict[str, float]]] = {
    "gyro": ({"off": {"SIM_GYR_FAIL_MSK": ALL_IMUS_MASK},
              "wrong": {f"SIM_GYR{n}_BIAS_Z": GYRO_WRONG_RAD_S for n in IMUS}},
             {"SIM_GYR_FAIL_MSK": 0, **{f"SIM_GYR{n}_BIAS_Z": 0.0 for n in IMUS}}),
    "accelerometer": ({"off": {"SIM_ACC_FAIL_MSK": ALL_IMUS_MASK},
                       "wrong": {f"SIM_ACC{n}_BIAS_X": ACCEL_WRONG_M_S2 for n in IMUS}},
                      {"SIM_ACC_FAIL_MSK": 0, **{f"SIM_ACC{n}_BIAS_X": 0.0 for n in IMUS}}),
    "magnetometer": ({"off": {f"SIM_MAG{n}_FAIL": 1 for n in COMPASSES},
                      "stuck": {f"SIM_MAG{n}_FAIL": 2 for n in COMPASSES},
                      "wrong": {f"SIM_MAG{n}_ORIENT": ROTATION_YAW_90 for n in COMPASSES}},
                     {**{f"SIM_MAG{n}_FAIL": 0 for n in COMPASSES}, **{f"SIM_MAG{n}_ORIENT": 0 for n in COMPASSES}}),
    "barometer": ({"off": {f"SIM_{b}_DISABLE": 1 for b in BAROMETERS},
                   "stuck": {f"SIM_{b}_FREEZE": 1 for b in BAROMETERS},
                   "wrong": {f"SIM_{b}_GLITCH": BARO_WRONG_M for b in BAROMETERS}},
                  {**{f"SIM_{b}_DISABLE": 0 for b in BAROMETERS}, **{f"SIM_{b}_FREEZE": 0 for b in BAROMETERS},
                   **{f"SIM_{b}_GLITCH": 0.0 for b in BAROMETERS}}),
    "gps": ({"off": {"SIM_GPS1_ENABLE": 0},
             "wrong": {"SIM_GPS1_GLTCH_X": GPS_WRONG_NORTH_M / METRES_PER_DEGREE_LATITUDE},
             "slow": {"SIM_GPS1_HZ": GPS_SLOW_RATE_HZ}},
            {"SIM_GPS1_ENABLE": 1, "SIM_GPS1_GLTCH_X": 0.0, "SIM_GPS1_HZ": GPS_RATE_HZ}),
}
# The units ArduPilot's SITL fails itself, of those the simulator would otherwise fail on their
# way: the JSON backend carries no GPS, ArduPilot makes its own from the true position.
SUT_FAILURE_UNITS = ("gps",)


def failure_params(unit: str, kind: str) -> Mapping[str, float] | None:
    """The SIM_* parameters that give ArduPilot SITL this unit's failure of this type, or (kind
    "ok") those a failure of the unit may set at their values without one; None where SITL has no means."""
    means = _MEANS.get(unit)
    if means is None:
        return None
    failing, unfailed = means
    if kind == "ok":
        return dict(unfailed)
    params = failing.get(kind)
    return None if params is None else dict(params)
