"""Failure injection in the bundled autopilot (MAV_CMD_INJECT_FAILURE, as PX4 takes it) and its
shared definition in simlink/failures.py: what the command is answered, and what the estimator
and the obstacle map receive of the simulator's data once a failure is active."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import common as mavlink

from autopilot.api import ApiLink
from autopilot.app import Autopilot
from autopilot.control import euler_from_quat, quat_from_euler, quat_rotate
from autopilot.estimator import SENSOR_TIMEOUT_S, Estimator, GpsFix
from autopilot.params import ParamError, Params
from simlink import codec, failures
from simlink.failures import (
    INTERMITTENT_PERIOD_S,
    MAV_CMD_INJECT_FAILURE,
    NAME_BY_TYPE,
    NAME_BY_UNIT,
    SLOW_FACTOR,
    SUPPORTED_TYPES,
    SUPPORTED_UNITS,
    TYPE_BY_NAME,
    UNIT_BY_NAME,
    Failure,
    FailureType,
    FailureUnit,
    intermittent_dropped,
    slow_refreshed,
)

STEP_US = 4000  # the simulator's physics step
GPS_EVERY = 25  # steps: 10 Hz
OBSTACLES_EVERY = 12  # steps: about 20 Hz
UNKNOWN_CM = 65535
# A level vehicle at rest heading north, every value exact in HIL_SENSOR's float32:
# accelerometer 0:3, gyro 3:6, magnetometer 6:9, abs and diff pressure, pressure altitude, temperature.
ACCEL = (0.0, 0.0, -9.8125)
GYRO = (0.0, 0.0, 0.0)
MAG = (0.25, 0.0, 0.5)
PRESSURE_ALT_M = 100.0
TEMPERATURE_C = 15.0
LAT_DEG, LON_DEG, GPS_ALT_M = 47.397742, 8.545594, 488.0
ALL_UNITS = {value: name for name, value in vars(mavlink).items() if name.startswith("FAILURE_UNIT_") and not name.endswith("ENUM_END")}
ALL_TYPES = {value: name for name, value in vars(mavlink).items() if name.startswith("FAILURE_TYPE_") and not name.endswith("ENUM_END")}


class RecordingEstimator(Estimator):
    """The autopilot's estimator, recording each sensor update it is given."""

    def __init__(self, declination_rad: float):
        super().__init__(declination_rad)
        self.imu: list[tuple[float, tuple, tuple | None, tuple | None]] = []
        self.baro: list[float] = []
        self.gps: list[tuple[float, GpsFix]] = []

    def update_imu(self, now_s, dt, gyro, accel, mag) -> None:
        self.imu.append((now_s, gyro, accel, mag))
        super().update_imu(now_s, dt, gyro, accel, mag)

    def update_baro(self, dt, pressure_alt_m) -> None:
        self.baro.append(pressure_alt_m)
        super().update_baro(dt, pressure_alt_m)

    def update_gps(self, now_s, dt, fix) -> None:
        self.gps.append((now_s, fix))
        super().update_gps(now_s, dt, fix)


class Flight:
    """The autopilot fed the simulator's frames through its own intake (as its simulator link
    delivers them), and its API link with what it sends kept instead of sent."""

    def __init__(self, **params: float):
        # No declination: the magnetometer's north is true north, so the estimated heading is 0.
        self.ap = Autopilot(Params({"SYS_FAILURE_EN": 1, "EKF2_MAG_DECL": 0.0, **params}))
        self.est = self.ap.estimator = RecordingEstimator(self.ap.estimator.declination)
        self.link = ApiLink(self.ap, ("127.0.0.1", 9))  # an ephemeral local socket, never sent from
        self.sent: list = []
        self.link.send = self.sent.append
        self.time_us = 0
        self.steps = 0
        self._sim = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self._client = mavlink.MAVLink(None, srcSystem=245, srcComponent=190)
        self._splitter = codec.FrameSplitter({m: c.crc_extra for m, c in mavlink.mavlink_map.items()})

    def close(self) -> None:
        self.link.sock.close()

    def feed(self, frame: bytes) -> None:
        self.ap._on_sim_data(_NoSocket(), self._splitter, frame)

    def step(self, *, accel=ACCEL, gyro=GYRO, mag=MAG, pressure_alt_m=PRESSURE_ALT_M) -> None:
        """One physics step: HIL_SENSOR, and HIL_GPS every GPS_EVERY steps, as the bridge sends them."""
        self.time_us += STEP_US
        self.steps += 1
        values = (*accel, *gyro, *mag, 950.0, 0.0, pressure_alt_m, TEMPERATURE_C)
        self.feed(codec.encode_hil_sensor(seq=self.steps, sysid=1, compid=1, time_usec=self.time_us, values=values, fields_updated=0x1FFF))
        if self.steps % GPS_EVERY == 0:
            self.gps()

    def gps(self, lat_deg: float = LAT_DEG) -> None:
        message = self._sim.hil_gps_encode(self.time_us, 3, round(lat_deg * 1e7), round(LON_DEG * 1e7), round(GPS_ALT_M * 1000), 80, 120, 0, 0, 0, 0, 0, 12)
        self.feed(message.pack(self._sim))

    def obstacles(self, ahead_cm: int) -> None:
        """OBSTACLE_DISTANCE: a forward sensor (+-50 degrees, 5 degree sectors) with something
        straight ahead at ahead_cm, free to 20 m elsewhere."""
        distances = [UNKNOWN_CM] * 72
        for sector in range(-10, 11):
            distances[sector % 72] = 2001
        distances[0] = ahead_cm
        message = self._sim.obstacle_distance_encode(self.time_us, mavlink.MAV_DISTANCE_SENSOR_LASER, distances, 0, 20, 2000, 5.0, 0.0, mavlink.MAV_FRAME_BODY_FRD)
        self.feed(message.pack(self._sim))

    def run(self, seconds: float, **readings) -> None:
        for _ in range(round(seconds * 1e6 / STEP_US)):
            self.step(**readings)

    @property
    def now_s(self) -> float:
        return self.ap.now_s

    def command(self, unit: int, kind: int, instance: int = 0) -> tuple[int, list[tuple[int, str]]]:
        """Sends MAV_CMD_INJECT_FAILURE as MAVSDK's failure plugin does: (ack result, [(severity, STATUSTEXT)])."""
        request = self._client.command_long_encode(1, 1, MAV_CMD_INJECT_FAILURE, 0, unit, kind, instance, 0, 0, 0, 0)
        (message,) = mavlink.MAVLink(None).parse_buffer(request.pack(self._client))
        self.sent.clear()
        self.link.handle(message)
        acks = [m for m in self.sent if m.get_type() == "COMMAND_ACK"]
        assert len(acks) == 1 and acks[0].command == MAV_CMD_INJECT_FAILURE
        assert (acks[0].target_system, acks[0].target_component) == (245, 190)
        texts = [(m.severity, m.text.decode() if isinstance(m.text, bytes) else m.text) for m in self.sent if m.get_type() == "STATUSTEXT"]
        return acks[0].result, texts


class _NoSocket:
    def sendall(self, data: bytes) -> None:
        pass


@pytest.fixture
def flight():
    """A flight 2 s into the simulation: attitude from the first IMU reading, origin from the
    first GPS fix, obstacles seen once; the estimate is healthy."""
    flight = Flight()
    flight.run(2.0)
    flight.obstacles(500)
    assert flight.ap.estimator.healthy(flight.now_s)
    yield flight
    flight.close()


# -- the shared definition ---------------------------------------------------------------------


def test_the_definitions_values_are_mavlinks():
    assert MAV_CMD_INJECT_FAILURE == mavlink.MAV_CMD_INJECT_FAILURE
    for unit in FailureUnit:
        assert unit == getattr(mavlink, f"FAILURE_UNIT_{unit.name}")
    for kind in FailureType:
        assert kind == getattr(mavlink, f"FAILURE_TYPE_{kind.name}")


def test_scenario_names_map_to_mavlink_values_and_back():
    assert UNIT_BY_NAME == {"gyro": 0, "accelerometer": 1, "magnetometer": 2, "barometer": 3, "gps": 4, "distance sensor": 7}
    assert TYPE_BY_NAME == {"off": 1, "stuck": 2, "wrong": 4, "intermittent": 7, "slow": 5}
    assert all(NAME_BY_UNIT[unit] == name for name, unit in UNIT_BY_NAME.items()) and len(NAME_BY_UNIT) == len(UNIT_BY_NAME)
    assert all(NAME_BY_TYPE[kind] == name for name, kind in TYPE_BY_NAME.items()) and len(NAME_BY_TYPE) == len(TYPE_BY_NAME)
    assert SUPPORTED_UNITS == set(UNIT_BY_NAME.values())
    assert SUPPORTED_TYPES == {FailureType.OK, *TYPE_BY_NAME.values()}
    # Every report fits a STATUSTEXT.
    assert max(len(failures.failure_text(unit, kind)) for unit in SUPPORTED_UNITS for kind in SUPPORTED_TYPES) <= 50


def test_intermittent_drops_alternate_half_second_windows_from_the_onset():
    onset = 0.1  # not a multiple of the period, and 0.6 - 0.1 is just below 0.5 in floating point
    assert INTERMITTENT_PERIOD_S == 0.5
    assert not intermittent_dropped(onset_s=onset, now_s=0.099996)  # before the onset: no failure yet
    assert intermittent_dropped(onset_s=onset, now_s=onset)
    assert intermittent_dropped(onset_s=onset, now_s=0.599996)
    assert not intermittent_dropped(onset_s=onset, now_s=0.6)
    assert not intermittent_dropped(onset_s=onset, now_s=1.099996)
    assert intermittent_dropped(onset_s=onset, now_s=1.1)


def test_slow_refreshes_every_fifth_arrival():
    assert SLOW_FACTOR == 5
    assert [arrival for arrival in range(1, 16) if slow_refreshed(arrival)] == [5, 10, 15]


def test_wrong_readings_are_off_by_the_defined_amounts():
    assert failures.wrong_gyro((0.1, 0.2, 0.3)) == pytest.approx((0.1, 0.2, 0.35))
    assert failures.wrong_accel((0.0, 0.0, -9.8)) == (1.0, 0.0, -9.8)
    assert failures.wrong_baro_altitude(100.0) == 110.0
    assert failures.wrong_distances([UNKNOWN_CM, 300, 2001, 20], max_distance_cm=2000) == [UNKNOWN_CM, 2001, 2001, 2001]
    # GPS: 20 m north in the estimator's own conversion; longitude unchanged.
    estimator = Estimator(0.0)
    estimator.update_gps(0.0, 0.1, GpsFix(LAT_DEG, LON_DEG, GPS_ALT_M, 0.0, 0.0, 0.0, 3, 10))
    lat, lon = failures.wrong_gps_position(LAT_DEG, LON_DEG)
    assert estimator.local_from_geodetic(lat, lon) == pytest.approx((20.0, 0.0), abs=1e-6)
    # Magnetometer: a level vehicle heading 30 degrees reads 120 from the wrong field.
    heading = math.radians(30.0)
    q = quat_from_euler(0.0, 0.0, heading)
    body = quat_rotate((q[0], -q[1], -q[2], -q[3]), (0.21, 0.0, 0.43))
    x, y, z = failures.wrong_mag(body)
    assert math.degrees(math.atan2(-y, x)) == pytest.approx(120.0) and z == body[2]


@pytest.mark.parametrize("kind", sorted(SUPPORTED_TYPES - {FailureType.OK}), ids=lambda k: k.name.lower())
def test_each_failure_turns_a_sequence_of_readings_into_what_its_definition_says(kind):
    # GIVEN readings 1, 2, 3, ... every 0.25 s from the onset at 10 s, the last one before it 0
    failure = Failure(kind, onset_s=10.0, last_reading=0.0, wrong=lambda r: r + 100.0)
    delivered = [failure.apply(10.0 + 0.25 * n, float(n + 1)) for n in range(12)]
    expected = {
        FailureType.OFF: [None] * 12,
        FailureType.STUCK: [0.0] * 12,
        FailureType.WRONG: [101.0 + n for n in range(12)],
        # 10.0-10.5 dropped, 10.5-11.0 taken, 11.0-11.5 dropped, ...
        FailureType.INTERMITTENT: [None, None, 3.0, 4.0, None, None, 7.0, 8.0, None, None, 11.0, 12.0],
        FailureType.SLOW: [0.0] * 4 + [5.0] * 5 + [10.0] * 3,
    }[kind]
    assert delivered == expected


def test_a_stuck_unit_without_an_earlier_reading_holds_the_first_after_the_onset():
    failure = Failure(FailureType.STUCK, onset_s=0.0, last_reading=None)
    assert [failure.apply(t, r) for t, r in ((0.004, 7.0), (0.008, 8.0))] == [7.0, 7.0]


def test_ok_and_undefined_types_are_not_failures_and_wrong_needs_its_reading():
    for kind in (FailureType.OK, FailureType.GARBAGE, FailureType.DELAYED):
        with pytest.raises(ValueError, match="not a failure defined here"):
            Failure(kind, onset_s=0.0, last_reading=None)
    with pytest.raises(ValueError, match="wrong="):
        Failure(FailureType.WRONG, onset_s=0.0, last_reading=None)


# -- the command ---------------------------------------------------------------------------------


def test_sys_failure_en_is_a_px4_parameter_off_by_default():
    assert Params()["SYS_FAILURE_EN"] == 0
    with pytest.raises(ParamError, match="outside"):
        Params({"SYS_FAILURE_EN": 2})


def test_injection_is_denied_unless_sys_failure_en_is_1():
    flight = Flight(SYS_FAILURE_EN=0)
    try:
        flight.run(0.1)
        result, texts = flight.command(mavlink.FAILURE_UNIT_SENSOR_BARO, mavlink.FAILURE_TYPE_WRONG)
        assert result == mavlink.MAV_RESULT_DENIED and texts == []
        flight.est.baro.clear()
        flight.run(0.1)
        assert flight.ap.failures == {} and set(flight.est.baro) == {PRESSURE_ALT_M}
    finally:
        flight.close()


@pytest.mark.parametrize("unit", sorted(ALL_UNITS), ids=ALL_UNITS.get)
def test_every_unit_and_type_is_accepted_exactly_when_it_is_implemented(flight, unit):
    for kind in sorted(ALL_TYPES):
        result, texts = flight.command(unit, kind)
        if unit in SUPPORTED_UNITS and kind in SUPPORTED_TYPES:
            assert result == mavlink.MAV_RESULT_ACCEPTED, ALL_TYPES[kind]
            severity = mavlink.MAV_SEVERITY_INFO if kind == FailureType.OK else mavlink.MAV_SEVERITY_WARNING
            assert texts == [(severity, f"CMD_INJECT_FAILURE, {NAME_BY_UNIT[unit]} {FailureType(kind).name.lower()}")]
            assert (unit in flight.ap.failures) == (kind != FailureType.OK)
        else:
            assert result == mavlink.MAV_RESULT_UNSUPPORTED, ALL_TYPES[kind]
            assert texts == []
    if unit in SUPPORTED_UNITS:
        assert flight.command(unit, FailureType.OK)[0] == mavlink.MAV_RESULT_ACCEPTED
    assert flight.ap.failures == {}


def test_instances_other_than_all_or_the_first_are_unsupported(flight):
    assert flight.command(FailureUnit.SENSOR_GPS, FailureType.OFF, instance=2)[0] == mavlink.MAV_RESULT_UNSUPPORTED
    assert flight.ap.failures == {}
    assert flight.command(FailureUnit.SENSOR_GPS, FailureType.OFF, instance=1)[0] == mavlink.MAV_RESULT_ACCEPTED
    assert set(flight.ap.failures) == {FailureUnit.SENSOR_GPS}


# -- what the flight stack receives ---------------------------------------------------------------


def test_barometer_wrong_reads_10_m_high_from_the_next_step_until_ok(flight):
    flight.est.baro.clear()
    assert flight.command(FailureUnit.SENSOR_BARO, FailureType.WRONG)[0] == mavlink.MAV_RESULT_ACCEPTED
    flight.run(0.1)
    assert flight.est.baro == [PRESSURE_ALT_M + 10.0] * 25
    assert flight.command(FailureUnit.SENSOR_BARO, FailureType.OK)[0] == mavlink.MAV_RESULT_ACCEPTED
    flight.est.baro.clear()
    flight.run(0.1)
    assert flight.est.baro == [PRESSURE_ALT_M] * 25 and flight.ap.failures == {}


def test_barometer_slow_is_refreshed_every_fifth_step(flight):
    # GIVEN a pressure altitude rising 0.25 m per step, 100.0 at the last step before the onset
    flight.run(0.004, pressure_alt_m=100.0)
    flight.command(FailureUnit.SENSOR_BARO, FailureType.SLOW)
    flight.est.baro.clear()
    for n in range(1, 13):
        flight.step(pressure_alt_m=100.0 + 0.25 * n)
    # THEN the estimator gets the pre-onset reading for four steps, then every fifth one held
    assert flight.est.baro == [100.0] * 4 + [101.25] * 5 + [102.5] * 3


def test_gps_off_gives_the_estimator_no_fix_until_ok(flight):
    flight.command(FailureUnit.SENSOR_GPS, FailureType.OFF)
    onset, fixes = flight.now_s, len(flight.est.gps)
    flight.run(1.0)
    assert len(flight.est.gps) == fixes  # ten fixes arrived, none was used
    assert not flight.ap.estimator.healthy(flight.now_s)  # GPS_TIMEOUT_S without one
    flight.command(FailureUnit.SENSOR_GPS, FailureType.OK)
    flight.run(0.1)
    assert [t for t, _ in flight.est.gps[fixes:]] == [pytest.approx(onset + 1.1)]
    assert flight.ap.estimator.healthy(flight.now_s)


def test_gps_wrong_puts_the_fix_20_m_north(flight):
    flight.command(FailureUnit.SENSOR_GPS, FailureType.WRONG)
    flight.run(0.1)
    _, fix = flight.est.gps[-1]
    north, east = flight.ap.estimator.local_from_geodetic(fix.lat_deg, fix.lon_deg)
    true_north, true_east = flight.ap.estimator.local_from_geodetic(round(LAT_DEG * 1e7) * 1e-7, round(LON_DEG * 1e7) * 1e-7)
    assert (north - true_north, east - true_east) == pytest.approx((20.0, 0.0), abs=1e-6)


def test_gyro_intermittent_is_dropped_in_the_first_half_second_and_used_in_the_second(flight):
    flight.command(FailureUnit.SENSOR_GYRO, FailureType.INTERMITTENT)
    onset_us = flight.time_us
    flight.est.imu.clear()
    flight.run(1.496)
    used_us = [round(t * 1e6) - onset_us for t, *_ in flight.est.imu]
    # Steps at 4 ms .. 1496 ms after the onset: 0-496 and 1000-1496 ms are dropped, 500-996 ms taken.
    assert used_us == list(range(500_000, 1_000_000, STEP_US))
    assert all(gyro == GYRO and accel == ACCEL and mag == MAG for _, gyro, accel, mag in flight.est.imu)


def test_gyro_off_stops_the_imu_step_and_the_estimate_turns_unhealthy(flight):
    # GIVEN the vehicle turning at 0.5 rad/s when the gyro fails
    flight.run(0.2, gyro=(0.0, 0.0, 0.5))
    flight.command(FailureUnit.SENSOR_GYRO, FailureType.OFF)
    q, rates, updates = flight.ap.estimator.q, flight.ap.estimator.rates, len(flight.est.imu)
    flight.run(SENSOR_TIMEOUT_S + 0.004, gyro=(0.0, 0.0, 0.5))
    # THEN no IMU step: the attitude and the rates stay as they were, the estimator's IMU is late
    assert len(flight.est.imu) == updates
    assert flight.ap.estimator.q == q and flight.ap.estimator.rates == rates
    assert not flight.ap.estimator.healthy(flight.now_s)


@pytest.mark.parametrize("unit", [FailureUnit.SENSOR_ACCEL, FailureUnit.SENSOR_MAG], ids=["accelerometer", "magnetometer"])
def test_accelerometer_or_magnetometer_off_reaches_the_estimator_as_no_reading(flight, unit):
    flight.command(unit, FailureType.OFF)
    flight.est.imu.clear()
    flight.run(0.1)
    assert len(flight.est.imu) == 25  # the gyro still steps the estimator
    off = unit == FailureUnit.SENSOR_ACCEL
    assert [(accel is None, mag is None) for _, _, accel, mag in flight.est.imu] == [(off, not off)] * 25
    assert flight.ap.estimator.healthy(flight.now_s)


def test_accelerometer_wrong_and_stuck_reach_the_estimator_as_defined(flight):
    flight.command(FailureUnit.SENSOR_ACCEL, FailureType.WRONG)
    flight.est.imu.clear()
    flight.run(0.008)
    assert [accel for *_, accel, _ in flight.est.imu] == [(1.0, 0.0, -9.8125)] * 2
    flight.command(FailureUnit.SENSOR_ACCEL, FailureType.STUCK)  # replaces wrong; holds the raw reading
    flight.est.imu.clear()
    flight.run(0.008, accel=(0.5, 0.0, -9.8125))
    assert [accel for *_, accel, _ in flight.est.imu] == [ACCEL] * 2


def test_distance_sensor_stuck_keeps_the_pre_onset_reading_in_the_obstacle_map(flight):
    obstacles = flight.ap.obstacles
    assert obstacles.distances[0] == 5.0
    flight.command(FailureUnit.SENSOR_DISTANCE_SENSOR, FailureType.STUCK)
    flight.run(0.05)
    flight.obstacles(300)  # the obstacle came closer; the sensor keeps saying 5 m
    assert obstacles.distances[0] == 5.0 and obstacles.updated_s == flight.now_s
    flight.command(FailureUnit.SENSOR_DISTANCE_SENSOR, FailureType.OK)
    flight.run(0.05)
    flight.obstacles(300)
    assert obstacles.distances[0] == 3.0


def test_distance_sensor_wrong_sees_nothing_in_reach_and_off_lets_the_map_go_stale(flight):
    obstacles = flight.ap.obstacles
    flight.command(FailureUnit.SENSOR_DISTANCE_SENSOR, FailureType.WRONG)
    flight.obstacles(300)
    assert obstacles.distances[0] == math.inf and obstacles.occupied == []
    flight.command(FailureUnit.SENSOR_DISTANCE_SENSOR, FailureType.OFF)
    seen_s = obstacles.updated_s
    for _ in range(12):
        flight.run(0.048)
        flight.obstacles(300)
    assert obstacles.updated_s == seen_s and not obstacles.fresh(flight.now_s)


def test_estimator_without_accelerometer_predicts_constant_velocity_and_without_magnetometer_keeps_its_heading():
    # GIVEN a level estimator heading 40 degrees, moving north at 2 m/s
    estimator = Estimator(0.0)
    heading = math.radians(40.0)
    q = quat_from_euler(0.0, 0.0, heading)
    field = quat_rotate((q[0], -q[1], -q[2], -q[3]), (0.21, 0.0, 0.43))
    estimator.update_imu(0.0, 0.004, GYRO, ACCEL, field)
    estimator.update_gps(0.0, 0.1, GpsFix(LAT_DEG, LON_DEG, GPS_ALT_M, 2.0, 0.0, 0.0, 3, 10))
    # WHEN a second passes without accelerometer and magnetometer, the gyro still
    for step in range(1, 251):
        estimator.update_imu(0.004 * step, 0.004, GYRO, None, None)
    # THEN position follows the velocity alone, and the heading stays where the gyro leaves it
    assert estimator.acc_ned == (0.0, 0.0, 0.0)
    assert estimator.vel == [2.0, 0.0, 0.0] and estimator.pos == pytest.approx([2.0, 0.0, 0.0])
    assert euler_from_quat(estimator.q) == pytest.approx((0.0, 0.0, heading), abs=1e-12)
    # AND with a magnetometer whose field says north, the heading turns towards north
    estimator.update_imu(1.004, 0.004, GYRO, None, quat_rotate((1.0, 0.0, 0.0, 0.0), (0.21, 0.0, 0.43)))
    assert euler_from_quat(estimator.q)[2] < heading - 1e-6
