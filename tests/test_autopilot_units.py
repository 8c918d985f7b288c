"""The bundled autopilot's pure parts: collision prevention, mixer, controllers, estimator, commander, parameters."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20.common import MAV_CMD_DO_CHANGE_SPEED, MAV_CMD_NAV_LAND, MAV_CMD_NAV_TAKEOFF, MAV_CMD_NAV_WAYPOINT

from autopilot.app import Autopilot
from autopilot.collision import BINS, ObstacleMap, constrain_velocity, guided_direction, px4_stick_acceleration
from autopilot.commander import MAIN_AUTO, SUB_AUTO_MISSION, Commander, MissionItem, VehicleEstimate
from autopilot.control import QUAD_X_MIX, attitude_from_thrust, euler_from_quat, mix, quat_from_euler, quat_rotate
from autopilot.estimator import Estimator, GpsFix
from autopilot.params import SPECS, ParamError, Params
from autopilot.params_doc import markdown_table
from conftest import ROOT

UNKNOWN = 65535


def obstacle_ahead(distance_m: float, now_s: float = 0.0, yaw: float = 0.0, sectors=(0,), fov_sectors=range(-10, 11)) -> ObstacleMap:
    """A forward sensor (body FRD, 5 degree sectors) seeing an obstacle in the given sectors."""
    distances = [UNKNOWN] * BINS
    for sector in fov_sectors:
        distances[sector % BINS] = 2001  # free up to 20 m
    for sector in sectors:
        distances[sector % BINS] = int(distance_m * 100)
    m = ObstacleMap()
    m.update(now_s, yaw, distances, 5.0, 0.0, 20, 2000)
    return m


def wall_ahead(distance_m: float, now_s: float = 0.0, yaw: float = 0.0) -> ObstacleMap:
    """A wall across the heading at distance_m, seen by the +-50 degree forward sensor."""
    distances = [UNKNOWN] * BINS
    for sector in range(-10, 11):
        slant = distance_m / math.cos(math.radians(5.0 * sector))
        distances[sector % BINS] = int(slant * 100) if slant <= 20.0 else 2001
    m = ObstacleMap()
    m.update(now_s, yaw, distances, 5.0, 0.0, 20, 2000)
    return m


class PointMass:
    """A vehicle that tracks its velocity setpoint with MPC_ACC_HOR, for closed-loop checks."""

    def __init__(self, params):
        self.params = params
        self.north = 0.0
        self.v = 0.0

    def step(self, setpoint: float, dt: float) -> None:
        acc = self.params["MPC_ACC_HOR"]
        self.v += max(-acc * dt, min(acc * dt, setpoint - self.v))
        self.north += self.v * dt


def test_obstacle_straight_ahead_at_3m_with_5m_s_setpoint_keeps_cp_dist():
    # GIVEN an obstacle straight ahead at 3 m and a 5 m/s setpoint towards it
    params = Params()
    vehicle = PointMass(params)
    wall_m = 3.0
    dt = 0.004
    # WHEN the setpoint is constrained at every step while the vehicle flies
    closest = wall_m
    for step in range(2500):
        now = step * dt
        m = wall_ahead(wall_m - vehicle.north, now_s=now)
        vn, ve = constrain_velocity(params, m, now, (5.0, 0.0), (vehicle.v, 0.0))
        assert ve == pytest.approx(0.0, abs=1e-9)
        vehicle.step(vn, dt)
        closest = min(closest, wall_m - vehicle.north)
    # THEN the stopping distance keeps CP_DIST
    assert closest >= params["CP_DIST"] - 0.05
    assert closest <= params["CP_DIST"] + 0.3  # it does approach; it does not stop needlessly far away


def test_the_first_constrained_setpoint_is_the_stopping_speed():
    params = Params()
    vn, _ = constrain_velocity(params, wall_ahead(3.0), 0.0, (5.0, 0.0), (0.0, 0.0))
    a, j, s = params["MPC_ACC_HOR"], params["MPC_JERK_AUTO"], 3.0 - params["CP_DIST"]
    b = 4 * a * a / j
    assert vn == pytest.approx((-b + math.sqrt(b * b + 8 * a * s)) / 2, rel=1e-6)  # PX4's jerk-limited stop


def test_world_fixed_sectors_follow_the_heading_at_measurement():
    params = Params()
    # Vehicle heading east sees an obstacle dead ahead: it must block eastward, not northward, motion.
    m = wall_ahead(1.0, yaw=math.pi / 2)
    assert constrain_velocity(params, m, 0.0, (0.0, 3.0), (0.0, 0.0))[1] <= 1e-6  # nothing towards the wall
    # Along the wall only its slanted sectors restrict: conservative, as PX4's sector model is.
    assert constrain_velocity(params, m, 0.0, (3.0, 0.0), (0.0, 0.0))[0] > 1.0


def test_guidance_turns_a_blocked_setpoint_within_cp_guide_ang():
    params = Params()
    # An obstacle 4 m ahead in sectors -3..3 (15 degrees either side); free beyond.
    m = obstacle_ahead(4.0, sectors=range(-3, 4))
    turned = math.degrees(guided_direction(m, 0.0, math.radians(params["CP_GUIDE_ANG"]), 8.0))
    assert 15.0 < abs(turned) <= params["CP_GUIDE_ANG"]  # the smallest turn into the gap
    vn, ve = constrain_velocity(params, m, 0.0, (5.0, 0.0), (0.0, 0.0))
    guided_speed = math.hypot(vn, ve)
    # A wall offers no gap: no turn, just the stopping speed.
    vn, ve = constrain_velocity(params, wall_ahead(4.0), 0.0, (5.0, 0.0), (0.0, 0.0))
    assert ve == pytest.approx(0.0, abs=1e-9) and vn < 5.0
    params.set("CP_GUIDE_ANG", 0.0)
    vn, ve = constrain_velocity(params, m, 0.0, (5.0, 0.0), (0.0, 0.0))
    assert ve == pytest.approx(0.0) and vn < guided_speed  # straight on it must brake harder
    params.set("CP_GUIDE_ANG", 30.0)


def test_sliding_keeps_the_component_along_a_wall():
    params = Params()
    m = wall_ahead(1.0)  # at CP_DIST: no motion towards it at all
    vn, ve = constrain_velocity(params, m, 0.0, (3.0, 3.0), (0.0, 0.0))
    assert vn <= 1e-9 and ve > 2.0
    vn, _ = constrain_velocity(params, wall_ahead(0.8), 0.0, (0.0, 0.0), (0.0, 0.0))
    assert vn == pytest.approx(-0.2, abs=0.01)  # too close: back off


def test_stale_range_data_stops_horizontal_motion_and_disabled_cp_does_nothing():
    params = Params()
    m = obstacle_ahead(10.0, now_s=0.0)
    assert constrain_velocity(params, m, 0.6, (3.0, 1.0), (0.0, 0.0)) == (0.0, 0.0)
    params.set("CP_DIST", -1.0)
    assert constrain_velocity(params, m, 0.6, (3.0, 1.0), (0.0, 0.0)) == (3.0, 1.0)


def test_directions_without_data_block_only_when_cp_go_no_data_is_0():
    params = Params()
    m = obstacle_ahead(10.0)  # the sensor sees only +-50 degrees
    assert constrain_velocity(params, m, 0.0, (-2.0, 0.0), (0.0, 0.0)) == pytest.approx((-2.0, 0.0))
    params.set("CP_GO_NO_DATA", 0)
    assert constrain_velocity(params, m, 0.0, (-2.0, 0.0), (0.0, 0.0)) == pytest.approx((0.0, 0.0), abs=0.01)


def sees_nothing(reach_m: float) -> ObstacleMap:
    """The forward sensor seeing nothing within its reach (OBSTACLE_DISTANCE's max + 1)."""
    distances = [UNKNOWN] * BINS
    for sector in range(-10, 11):
        distances[sector % BINS] = int(reach_m * 100) + 1
    m = ObstacleMap()
    m.update(0.0, 0.0, distances, 5.0, 0.0, 20, int(reach_m * 100))
    return m


def test_px4s_stick_collision_prevention_crawls_in_fog_and_slows_down_long_before_an_obstacle():
    params = Params()
    params.set("CP_STICK_ACCEL", 1)
    push = (6.0, 0.0)  # full stick forward: 2 MPC_ACC_HOR
    # In clear air nothing seen within 20 m leaves the stick alone; in thick fog, a sensor that
    # reaches 2.5 m holds an obstacle there wherever it looks: ((2.5 - 1) / (10 / 0.95))^2 of the stick
    assert px4_stick_acceleration(params, sees_nothing(20.0), 0.0, push, (0.0, 0.0)) == pytest.approx(push)
    fog_n, fog_e = px4_stick_acceleration(params, sees_nothing(2.5), 0.0, push, (0.0, 0.0))
    assert fog_n == pytest.approx(6.0 * (1.5 / (10.0 / 0.95)) ** 2, rel=0.01) and fog_e == pytest.approx(0.0, abs=1e-9)
    # A wall 5 m ahead: the push towards it scaled down, a push along it not
    ahead = wall_ahead(5.0)
    toward_n, _ = px4_stick_acceleration(params, ahead, 0.0, push, (0.0, 0.0))
    assert toward_n == pytest.approx(6.0 * (4.0 / (10.0 / 0.95)) ** 2, rel=0.01)
    assert px4_stick_acceleration(params, ahead, 0.0, (0.0, 6.0), (0.0, 0.0)) == pytest.approx((0.0, 6.0))
    # Flying at 4 m/s at it from 2.5 m, it brakes whatever the stick says; a released stick is PX4's own business
    brake_n, _ = px4_stick_acceleration(params, obstacle_ahead(2.5), 0.0, push, (4.0, 0.0))
    assert brake_n < -3.0
    assert px4_stick_acceleration(params, obstacle_ahead(2.5), 0.0, (0.0, 0.0), (4.0, 0.0)) == (0.0, 0.0)


def test_px4s_stick_collision_prevention_turns_into_a_gap_and_refuses_directions_without_data():
    params = Params()
    params.set("CP_STICK_ACCEL", 1)
    # An obstacle 4 m ahead in sectors -3..3, free beyond: PX4's guidance turns the push 25 degrees
    # into the gap, whose part along the obstacle is kept and the rest scaled down
    gap = obstacle_ahead(4.0, sectors=range(-3, 4))
    a_n, a_e = px4_stick_acceleration(params, gap, 0.0, (6.0, 0.0), (0.0, 0.0))
    assert a_e == pytest.approx(-6.0 * math.sin(math.radians(25.0)), rel=0.01)
    assert a_n == pytest.approx(6.0 * math.cos(math.radians(25.0)) * (3.0 / (10.0 / 0.95)) ** 2, rel=0.01)
    params.set("CP_GUIDE_ANG", 0.0)
    assert px4_stick_acceleration(params, gap, 0.0, (6.0, 0.0), (0.0, 0.0))[1] == pytest.approx(0.0, abs=1e-9)
    params.set("CP_GUIDE_ANG", 30.0)
    # Backwards, where the forward sensor has no data: refused as PX4 refuses it (CP_GO_NO_DATA 0), allowed with 1
    params.set("CP_GO_NO_DATA", 0)
    assert px4_stick_acceleration(params, obstacle_ahead(10.0), 0.0, (-6.0, 0.0), (0.0, 0.0)) == pytest.approx((0.0, 0.0), abs=1e-9)
    params.set("CP_GO_NO_DATA", 1)
    assert px4_stick_acceleration(params, obstacle_ahead(10.0), 0.0, (-6.0, 0.0), (0.0, 0.0)) == pytest.approx((-6.0, 0.0))


def lidar_360(m: ObstacleMap, now_s: float, reach_m: float, obstacle_m: float | None = None) -> None:
    """A 360 degree lidar (OBSTACLE_DISTANCE, 72 sectors) seeing nothing within reach_m, or
    obstacle_m straight ahead."""
    distances = [int(reach_m * 100) + 1] * BINS
    if obstacle_m is not None:
        distances[0] = int(obstacle_m * 100)
    m.update(now_s, 0.0, distances, 5.0, 0.0, 20, int(reach_m * 100))


def front_rangefinder(m: ObstacleMap, now_s: float, reading_m: float, reach_m: float = 5.0, sensor_id: int = 1, scale: float = 1.0) -> None:
    """A forward DISTANCE_SENSOR of 10 degrees field of view."""
    m.update_distance_sensor(now_s, 0.0, sensor_id, reading_m, 0.1, reach_m, 0.0, math.radians(10.0), scale)


def test_a_distance_sensor_fills_the_bins_px4_rounds_into_its_field_of_view():
    m = ObstacleMap()
    front_rangefinder(m, 0.0, 3.0)
    # PX4's bins round((0 -+ 5) / 5): -1, 0 and 1, all at 3 m; nothing else known
    assert [m.distances[i] for i in (71, 0, 1)] == [3.0, 3.0, 3.0]
    assert sum(d is not None for d in m.distances) == 3 and m.max_range_m == 5.0
    # Its reach reads as nothing within range; a reading at or below its minimum is dropped
    front_rangefinder(m, 0.1, 5.0)
    assert m.distances[0] == math.inf and m.updated_s == 0.1
    front_rangefinder(m, 0.2, 0.05)
    assert m.distances[0] == math.inf and m.updated_s == 0.1
    # Pitched, the slant reading is projected onto the horizon as PX4 projects it
    front_rangefinder(m, 0.3, 4.0, scale=math.cos(math.radians(30.0)))
    assert m.distances[0] == pytest.approx(4.0 * math.cos(math.radians(30.0)))


def test_sources_are_fused_as_px4s_enter_data_leaves_them():
    m = ObstacleMap()
    # A lidar reaching 30 m sees nothing; a rangefinder reaching 5 m sees 2 m ahead: the
    # rangefinder's obstacle, and each bin clamped at the reach of the sensor that saw nothing
    lidar_360(m, 0.0, 30.0)
    front_rangefinder(m, 0.05, 2.0)
    assert m.distances[0] == 2.0 and m.distances[36] == math.inf
    assert m.view_at_reach[0] == 2.0 and m.view_at_reach[36] == 30.0 and m.max_range_m == 30.0
    # Both see one: the shorter-reaching sensor's reading stays, whichever is closer and later
    lidar_360(m, 0.1, 30.0, obstacle_m=1.5)
    assert m.distances[0] == 2.0
    # The rangefinder sees nothing any more: the lidar's obstacle comes through
    front_rangefinder(m, 0.15, 5.0)
    assert m.distances[0] == 1.5
    # Nothing within range of either: the lidar's longer reach
    lidar_360(m, 0.2, 30.0)
    assert m.distances[0] == math.inf and m.view_at_reach[0] == 30.0
    # A source not heard for more than 0.5 s no longer counts
    front_rangefinder(m, 0.25, 2.0)
    lidar_360(m, 0.9, 30.0)
    assert m.distances[0] == math.inf and m.updated_s == 0.9


def test_mixer_turns_torques_into_px4_quad_x_motor_commands():
    # Positive roll (right wing down) needs the left motors (1 aft-left, 2 front-left) faster.
    roll = mix(0.5, (0.1, 0.0, 0.0))
    assert roll[1] > 0.5 and roll[2] > 0.5 and roll[0] < 0.5 and roll[3] < 0.5
    pitch = mix(0.5, (0.0, 0.1, 0.0))  # nose up: front motors 0 and 2 faster
    assert pitch[0] > 0.5 and pitch[2] > 0.5
    yaw = mix(0.5, (0.0, 0.0, 0.1))  # nose right: the counter-clockwise motors 0 and 1 faster
    assert yaw[0] > 0.5 and yaw[1] > 0.5
    assert len(QUAD_X_MIX) == 4


def test_mixer_keeps_outputs_in_range_and_torque_priority_at_saturation():
    out = mix(0.95, (0.3, 0.0, 0.0))
    assert all(0.0 <= m <= 1.0 for m in out)
    assert out[1] - out[0] == pytest.approx(0.6, abs=1e-9)  # the full roll differential survives
    low = mix(0.02, (0.0, 0.0, 0.0), idle=0.05)
    assert min(low) >= 0.05


def test_attitude_from_thrust_tilts_towards_the_requested_acceleration():
    q, collective = attitude_from_thrust((0.1, 0.0, -0.42), yaw=0.0)
    roll, pitch, yaw = euler_from_quat(q)
    assert pitch < -0.1 and abs(roll) < 1e-9 and abs(yaw) < 1e-9  # nose down to accelerate north
    assert collective == pytest.approx(math.hypot(0.1, 0.42))


def test_estimator_converges_on_a_resting_vehicle():
    estimator = Estimator(math.radians(3.0))
    # A level vehicle heading 40 degrees, at rest: specific force -g, Earth's field rotated into the body.
    yaw = math.radians(40.0)
    q_true = quat_from_euler(0.0, 0.0, yaw)
    field_ned = (0.214, 0.011, 0.43)
    body_field = quat_rotate((q_true[0], -q_true[1], -q_true[2], -q_true[3]), field_ned)
    for step in range(2500):
        now = step * 0.004
        estimator.update_imu(now, 0.004, (0.0, 0.0, 0.0), (0.0, 0.0, -9.80665), body_field)
        estimator.update_baro(0.004, 100.0)
        if step % 25 == 0:
            estimator.update_gps(now, 0.1, GpsFix(47.4 + 1e-5, 8.5, 500.0, 0.0, 0.0, 0.0, 3, 10))
    roll, pitch, estimated_yaw = euler_from_quat(estimator.q)
    assert abs(roll) < 0.01 and abs(pitch) < 0.01
    assert estimated_yaw == pytest.approx(yaw, abs=math.radians(2.0))
    assert max(abs(v) for v in estimator.pos) < 0.05 and max(abs(v) for v in estimator.vel) < 0.05
    assert estimator.healthy(now)


def estimate(north=0.0, east=0.0, down=0.0, vd=0.0, yaw=0.0):
    return VehicleEstimate(north, east, down, 0.0, 0.0, vd, yaw)


def test_mission_state_machine_takes_off_flies_lands_and_disarms():
    params = Params()
    commander = Commander(params)
    commander.home = (0.0, 0.0, 0.0)
    commander.set_mission([
        MissionItem(0, MAV_CMD_NAV_TAKEOFF, 0.0, 0.0, 5.0),
        MissionItem(1, MAV_CMD_DO_CHANGE_SPEED, 0.0, 0.0, 0.0, 1.0, 3.0, has_position=False),
        MissionItem(2, MAV_CMD_NAV_WAYPOINT, 20.0, 0.0, 5.0, 0.0, 2.0),
        MissionItem(3, MAV_CMD_NAV_LAND, 20.0, 0.0, 0.0),
    ])
    assert commander.arm(0.0, True, "")[0]
    assert commander.start_mission(estimate())
    assert commander.mode == (MAIN_AUTO, SUB_AUTO_MISSION)
    # Climbing: hold position, aim for 5 m.
    sp = commander.update(0.1, estimate(), 0.42)
    assert sp.down_m == pytest.approx(-5.0) and not commander.landed
    commander.update(1.0, estimate(down=-4.5), 0.42)  # within the vertical acceptance: takeoff reached
    commander.update(1.1, estimate(down=-5.0), 0.42)  # change speed, immediately reached
    sp = commander.update(1.2, estimate(down=-5.0), 0.42)
    assert sp.v_north_m_s == pytest.approx(3.0) and sp.yaw_rad == pytest.approx(0.0)  # cruise at the new speed
    sp = commander.update(5.0, estimate(north=18.5, down=-5.0), 0.42)  # inside the 2 m acceptance radius
    sp = commander.update(5.1, estimate(north=20.0, down=-5.0), 0.42)
    assert sp.v_down_m_s == pytest.approx(params["MPC_LAND_SPEED"])
    t = 5.2
    while not commander.landed:  # on the ground: no more descent, thrust well below hover
        commander.update(t, estimate(north=20.0, down=0.0, vd=0.0), 0.1)
        t += 0.1
        assert t < 10.0
    reached = [value for kind, value in commander.events if kind == "item_reached"]
    assert reached == [0, 1, 2, 3]
    commander.update(t + params["COM_DISARM_LAND"] + 0.1, estimate(north=20.0), 0.0)
    assert not commander.armed and commander.mission_finished


def test_arming_is_refused_when_not_ready_and_disarming_in_air_needs_force():
    commander = Commander(Params())
    ok, reason = commander.arm(0.0, False, "position estimate not ready")
    assert not ok and "position estimate" in reason
    commander.arm(0.0, True, "")
    commander.landed = False
    assert not commander.disarm()[0]
    assert commander.disarm(force=True)[0]


def test_parameters_are_validated_and_ints_travel_bytewise():
    params = Params()
    with pytest.raises(ParamError, match="outside"):
        params.set("CP_DIST", 99.0)
    with pytest.raises(ParamError, match="unknown"):
        params.set("CP_DISTT", 1.0)
    wire = params.wire_value("CP_GO_NO_DATA")
    assert params.from_wire("CP_GO_NO_DATA", wire, 6) == 1
    assert len({s.name for s in SPECS}) == len(SPECS)


def test_the_parameter_documentation_is_generated_from_the_declarations():
    assert (ROOT / "docs" / "autopilot_parameters.md").read_text() == markdown_table(), "run: python -m autopilot.params_doc > docs/autopilot_parameters.md"


def test_garbage_datagrams_from_another_port_do_not_divert_the_telemetry():
    """Issue 18, defect 1: the API link took the sender of any datagram as its ground station."""
    import socket
    import time

    from pymavlink.dialects.v20 import common as mavlink

    from autopilot.api import ApiLink
    from autopilot.app import Autopilot

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as gcs, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger:
        gcs.bind(("127.0.0.1", 0))
        stranger.bind(("127.0.0.1", 0))
        gcs.settimeout(2.0)
        link = ApiLink(Autopilot(Params()), gcs.getsockname())
        target = link.sock.getsockname()
        for garbage in (b"\x00" * 40, b"\xfd\x09garbage-not-mavlink", bytes(range(256))):
            stranger.sendto(garbage, target)
        time.sleep(0.05)
        link.receive()
        assert link.remote == gcs.getsockname()
        link.heartbeat()
        # the flight's clock first, for a recorder to stamp the heartbeat with
        assert [mavlink.MAVLink(None).parse_buffer(gcs.recv(2048))[0].get_type() for _ in range(2)] == ["SYSTEM_TIME", "HEARTBEAT"]
        peer = mavlink.MAVLink(None, srcSystem=255)
        stranger.sendto(peer.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(peer), target)
        time.sleep(0.05)
        link.receive()
        assert link.remote == stranger.getsockname()  # the first peer to speak MAVLink is the partner, as in PX4
        gcs.sendto(peer.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(peer), target)
        time.sleep(0.05)
        link.receive()
        assert link.remote == stranger.getsockname() and link.last_gcs_heartbeat is not None  # heard, but the partner stays
        link.sock.close()


def test_a_clients_first_command_gets_every_stream_at_once():
    """MAVSDK waits for SYS_STATUS's health before arming: a client that starts asking must not
    wait up to a stream's period for it."""
    import socket
    import time

    from pymavlink.dialects.v20 import common as mavlink

    from autopilot.api import ApiLink
    from autopilot.app import Autopilot

    def received(sock) -> set[str]:
        kinds = set()
        sock.setblocking(False)
        while True:
            try:
                kinds |= {m.get_type() for m in mavlink.MAVLink(None).parse_buffer(sock.recv(65536)) or []}
            except BlockingIOError:
                return kinds

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as gcs:
        gcs.bind(("127.0.0.1", 0))
        link = ApiLink(Autopilot(Params()), gcs.getsockname())
        link.telemetry(100.0)
        time.sleep(0.05)
        assert "SYS_STATUS" in received(gcs)
        link.telemetry(100.05)  # within every stream's period: nothing is due
        time.sleep(0.05)
        assert received(gcs) == set()
        client = mavlink.MAVLink(None, srcSystem=245)
        request = client.command_long_encode(1, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, mavlink.MAVLINK_MSG_ID_HOME_POSITION, 0, 0, 0, 0, 0, 0)
        gcs.sendto(request.pack(client), link.sock.getsockname())
        time.sleep(0.05)
        link.receive()
        link.telemetry(100.06)
        time.sleep(0.05)
        assert {"SYS_STATUS", "HEARTBEAT", "EXTENDED_SYS_STATE"} <= received(gcs)
        link.sock.close()


def test_the_autopilot_takes_any_timestamp_hil_sensor_can_carry():
    """time_usec is a uint64: the compiled autopilot must not overflow where Python would not."""
    autopilot = Autopilot(Params())
    assert autopilot.step(2**64 - 1, (0.0, 0.0, -9.81, 0.0, 0.0, 0.0, 0.2, 0.0, 0.4, 1013.0, 0.0, 0.0, 15.0)) == (0.0, 0.0, 0.0, 0.0)
    assert autopilot.now_s == (2**64 - 1) / 1e6


def test_a_px4_parameter_it_does_not_model_is_acknowledged_over_mavlink_as_without_effect():
    """A client (QGroundControl, MAVSDK's param plugin) setting a PX4 parameter waits for the
    PARAM_VALUE echo; the bundled autopilot gives it, says the value has no effect, and still
    refuses a name PX4 does not have."""
    import socket
    import time

    from pymavlink.dialects.v20 import common as mavlink

    from autopilot.api import ApiLink
    from autopilot.app import Autopilot

    def answers(sock) -> list:
        time.sleep(0.05)
        link.receive()
        sock.setblocking(False)
        messages = []
        while True:
            try:
                messages += mavlink.MAVLink(None).parse_buffer(sock.recv(65536)) or []
            except BlockingIOError:
                return messages

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as gcs:
        gcs.bind(("127.0.0.1", 0))
        autopilot = Autopilot(Params())
        link = ApiLink(autopilot, gcs.getsockname())
        client = mavlink.MAVLink(None, srcSystem=245)
        for name in (b"MIS_YAW_ERR", b"CP_DISTANCE"):
            gcs.sendto(client.param_set_encode(1, 1, name, 12.0, mavlink.MAV_PARAM_TYPE_REAL32).pack(client), link.sock.getsockname())
        kinds = [(m.get_type(), m.param_id if m.get_type() == "PARAM_VALUE" else m.text) for m in answers(gcs) if m.get_type() in ("PARAM_VALUE", "STATUSTEXT")]
        assert ("PARAM_VALUE", "MIS_YAW_ERR") in kinds and ("STATUSTEXT", "MIS_YAW_ERR accepted without effect") in kinds
        assert not any(kind == "PARAM_VALUE" and name == "CP_DISTANCE" for kind, name in kinds)
        assert autopilot.params.unmodelled == {"MIS_YAW_ERR": 12.0} and "MIS_YAW_ERR" not in autopilot.params.names()
        link.sock.close()


def test_a_disarm_without_the_force_parameter_is_answered():
    """MAVSDK's action.disarm() sends param2 as NaN; the autopilot took int() of it and its API
    link died."""
    import socket
    import time

    from pymavlink.dialects.v20 import common as mavlink

    from autopilot.api import ApiLink
    from autopilot.app import Autopilot

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as gcs:
        gcs.bind(("127.0.0.1", 0))
        link = ApiLink(Autopilot(Params()), gcs.getsockname())
        client = mavlink.MAVLink(None, srcSystem=245)
        disarm = client.command_long_encode(1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0.0, float("nan"), 0, 0, 0, 0, 0)
        gcs.sendto(disarm.pack(client), link.sock.getsockname())
        time.sleep(0.05)
        link.receive()
        gcs.settimeout(1.0)
        acks = []
        while not acks:
            acks = [m for m in mavlink.MAVLink(None).parse_buffer(gcs.recv(65536)) or [] if m.get_type() == "COMMAND_ACK"]
        assert (acks[0].command, acks[0].result) == (mavlink.MAV_CMD_COMPONENT_ARM_DISARM, mavlink.MAV_RESULT_ACCEPTED)  # already disarmed
        link.sock.close()


def test_later_news_of_nothing_in_range_from_a_sensor_of_the_same_reach_clears_an_obstacle():
    m = ObstacleMap()
    front_rangefinder(m, 0.0, 3.0, reach_m=5.0, sensor_id=1)
    front_rangefinder(m, 0.05, 5.0, reach_m=5.0, sensor_id=2)  # a second rangefinder of the same reach sees nothing
    assert m.distances[0] == math.inf
    front_rangefinder(m, 0.1, 3.0, reach_m=5.0, sensor_id=1)
    assert m.distances[0] == 3.0
