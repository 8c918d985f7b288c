"""The simulator link's messages of one physics step in PX4's HIL protocol (sim_bridge/bridge.py
sends them): HIL_GPS, HIL_STATE_QUATERNION (ground truth), the range sensor as OBSTACLE_DISTANCE
and DISTANCE_SENSOR wedges, the pilot's RC_CHANNELS and, last, HIL_SENSOR; each reading as a
failure makes it, recorded where the log shows what the SUT got. ArduPilot's link
(ardupilot_link.py) takes its readings from here too.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from sim_bridge.failures import FailureSchedule
from sim_bridge.pilot import CHANNEL_COUNT
from sim_bridge.recording import Recorder
from sim_bridge.rig import RigFrames, wrong_rig_reading
from sim_bridge.sensors import FIELDS_ALL, quaternion_from_euler
from sim_bridge.world import SECTOR_DEG, World
from simlink import codec
from simlink.failures import wrong_distances, wrong_gps_position

SYSTEM_ID = 1
COMPONENT_ID = 51
UINT16_MAX = 65535
RANGE_MESSAGES = ("OBSTACLE_DISTANCE", "DISTANCE_SENSOR")


class SensorFrames:
    """A world's readings as the SUT gets them. every: steps between messages of a kind (gps,
    truth, sensor, rc), as the bridge counts them."""

    def __init__(self, world: World, range_messages: tuple[str, ...], recorder: Recorder, failures: FailureSchedule, every: Mapping[str, int],
                 companion_messages: tuple[str, ...] = (), distance_sensor_convention: str = "px4"):
        self.world = world
        self.range_messages = range_messages
        self.recorder = recorder
        self.failures = failures
        self.every = dict(every)
        self.seq = 0  # the simulator link's MAVLink sequence number
        self.companion_seq = 0
        # This step's frames for a companion computer's link (RigFrames), which the bridge sends.
        self.companion_out: list[bytes] = []
        self.wedges = _wedges(np.flatnonzero(world.sector_visible).tolist())
        # A rig's sensors, each rendered into its own messages, instead of the profile's one sensor.
        self.rig = None if world.spec.rig is None else RigFrames(
            world.spec.rig, 1.0 / world.dt, world.hull_offset, world.nearest, self.encode,
            lambda topic, time_us, message: recorder.write(topic, time_ns=time_us * 1000, message=message),
            companion_messages, self.encode_companion, distance_sensor_convention, world.spec.seed)

    def next_seq(self) -> int:
        seq = self.seq
        self.seq = (seq + 1) & 0xFF
        return seq

    def encode(self, message: codec.MessageCodec, *values) -> bytes:
        return message.encode(self.next_seq(), SYSTEM_ID, COMPONENT_ID, *values)

    def encode_companion(self, message: codec.MessageCodec, *values) -> bytes:
        """A frame of the companion computer's link: its own sequence, the vehicle's system id and
        the obstacle-avoidance component's id."""
        seq = self.companion_seq
        self.companion_seq = (seq + 1) & 0xFF
        return message.encode(seq, SYSTEM_ID, mavlink.MAV_COMP_ID_OBSTACLE_AVOIDANCE, *values)

    def step_frames(self, step: int, time_us: int) -> bytes:
        """The messages of one physics step, HIL_SENSOR last."""
        world = self.world
        s = world.state
        imu = world.imu()
        every = self.every
        frames = []
        g = self.gps_fix() if step % every["gps"] == 0 else None
        if g is not None:
            frames.append(self.encode(
                codec.HIL_GPS, time_us, g["fix_type"], g["lat"], g["lon"], g["alt"], g["eph"], g["epv"], g["vel"], g["vn"], g["ve"], g["vd"], g["cog"],
                g["satellites_visible"], 0, 0,
            ))
        if step % every["truth"] == 0:
            frames.append(self.encode(
                codec.HIL_STATE_QUATERNION,
                time_us,
                quaternion_from_euler(s.roll_rad, s.pitch_rad, s.yaw_rad),
                s.p_rad_s,
                s.q_rad_s,
                s.r_rad_s,
                int(round(s.lat_deg * 1e7)),
                int(round(s.lon_deg * 1e7)),
                int(round(s.alt_msl_m * 1000)),
                int(round(s.v_north_m_s * 100)),
                int(round(s.v_east_m_s * 100)),
                int(round(s.v_down_m_s * 100)),
                0,
                0,
                _milli_g(s.ax_m_s2),
                _milli_g(s.ay_m_s2),
                _milli_g(s.az_m_s2),
            ))
        if self.rig is not None:
            frames.extend(self.rig_frames(step, time_us))
        elif step % every["sensor"] == 0:
            frames.extend(self.obstacle_distance(time_us))
        if world.pilot is not None and step % every["rc"] == 0:
            frames.append(self.pilot_rc(time_us))
        # HIL_SENSOR goes last: a SUT that steps on it has then seen this step's other messages,
        # however TCP splits the stream. Sequence numbers count up in the order frames are sent.
        frames.append(codec.encode_hil_sensor(seq=self.next_seq(), sysid=SYSTEM_ID, compid=COMPONENT_ID, time_usec=time_us, values=imu, fields_updated=FIELDS_ALL))
        return b"".join(frames)

    def rig_frames(self, step: int, time_us: int) -> list[bytes]:
        """This step's rig messages for the simulator link; those for the companion link are
        left in companion_out."""
        simulator, self.companion_out = self.rig.step_frames(step, time_us, self.world.state.yaw_rad, self.rig_reading)
        return simulator

    def gps_fix(self) -> dict[str, Any] | None:
        """This step's HIL_GPS fields as the receiver delivers them (None: nothing delivered)."""
        fix = self.world.gps()
        if self.failures.owns("gps"):
            return self.failures.reading("gps", self.run_time(), fix, _wrong_gps)
        return fix

    def run_time(self) -> float | None:
        world = self.world
        return None if world.run_start_s is None else world.run_time(world.time_s)

    def range_reading(self, time_us: int) -> list[int] | None:
        """The range sensor's sectors as the SUT gets them (a failure's, None: nothing), recorded."""
        world = self.world
        distances = world.range_cm()
        if self.failures.owns("distance sensor"):
            reach_cm = int(world.range_m * 100)
            distances = self.failures.reading("distance sensor", self.run_time(), distances,
                                              lambda sectors: wrong_distances(sectors, max_distance_cm=reach_cm))
            if distances is None:
                return None
        self.recorder.write("/sensor/obstacle_distance", time_ns=time_us * 1000, message={"t": time_us / 1e6, "range_m": world.range_m, "distances_cm": distances})
        return distances

    def rig_reading(self, name: str, readings_cm: list[int], reach_cm: int) -> list[int] | None:
        """A rig sensor's reading as the "distance sensor" failure leaves it, which fails every
        sensor of the rig, each from its own last reading (None: nothing is sent)."""
        if not self.failures.owns("distance sensor"):
            return readings_cm
        return self.failures.reading("distance sensor", self.run_time(), readings_cm, lambda readings: wrong_rig_reading(readings, reach_cm), instance=name)

    def obstacle_distance(self, time_us: int):
        world = self.world
        distances = self.range_reading(time_us)
        if distances is None:
            return []
        reach_cm = int(world.range_m * 100)
        min_cm = int(world.min_range_m * 100)
        messages = []
        if "OBSTACLE_DISTANCE" in self.range_messages:
            messages.append(self.encode(
                codec.OBSTACLE_DISTANCE, time_us, mavlink.MAV_DISTANCE_SENSOR_LASER, distances, 0, min_cm, reach_cm, SECTOR_DEG, 0.0, mavlink.MAV_FRAME_BODY_FRD
            ))
        # The same reading as DISTANCE_SENSOR wedges: PX4's simulator link ignores OBSTACLE_DISTANCE
        # but turns DISTANCE_SENSOR into the distance_sensor topic its collision prevention reads.
        for sensor_id, (quaternion, fov_rad, sectors) in enumerate(self.wedges if "DISTANCE_SENSOR" in self.range_messages else ()):
            nearest_cm = min(min(distances[i] for i in sectors), reach_cm)
            messages.append(self.encode(
                codec.DISTANCE_SENSOR, time_us // 1000, min_cm, reach_cm, nearest_cm, mavlink.MAV_DISTANCE_SENSOR_LASER, sensor_id,
                mavlink.MAV_SENSOR_ROTATION_CUSTOM, 0, fov_rad, fov_rad, quaternion, 0,
            ))
        return messages

    def pilot_frame(self, time_us: int, channels_of=None):
        """The pilot's sticks now, recorded with the channels the SUT gets (channels_of(frame):
        its transmitter's; PX4's layout by default)."""
        pilot = self.world.pilot
        frame = self.world.pilot_frame(time_us / 1e6)
        channels = frame.channels() if channels_of is None else channels_of(frame)
        self.recorder.write("/pilot", time_ns=time_us * 1000, message={
            "t": time_us / 1e6, "phase": pilot.phase, "roll": frame.roll, "pitch": frame.pitch, "throttle": frame.throttle, "yaw": frame.yaw,
            "mode_slot": frame.slot, "channels_us": channels, "aim_north_m": pilot.aim[0], "aim_east_m": pilot.aim[1], "remaining_m": pilot.remaining_m,
            **({"segment": pilot.segment + 1} if pilot.segment is not None else {}),
        })
        return channels

    def pilot_rc(self, time_us: int):
        channels = self.pilot_frame(time_us)
        unused = [UINT16_MAX] * (18 - CHANNEL_COUNT)
        return self.encode(codec.RC_CHANNELS, time_us // 1000, CHANNEL_COUNT, *channels, *unused, 255)


WEDGE_SECTORS = 4


def _milli_g(specific_force_m_s2: float) -> int:
    """HIL_STATE_QUATERNION's int16 acceleration: a crash's impact (tens of g) saturates it."""
    return max(-32768, min(32767, int(round(specific_force_m_s2 / 9.80665 * 1000))))


def _wrong_gps(fix: dict[str, Any]) -> dict[str, Any]:
    lat_deg, _lon_deg = wrong_gps_position(fix["lat"] * 1e-7, fix["lon"] * 1e-7)
    return {**fix, "lat": int(round(lat_deg * 1e7))}


def _wedges(visible: list[int]) -> list[tuple[list[float], float, list[int]]]:
    """Visible sectors grouped WEDGE_SECTORS at a time from left to right: (body-yaw quaternion
    w, x, y, z of the wedge's centre, its width in radians, its sector indices)."""
    signed = sorted(visible, key=lambda i: ((i * SECTOR_DEG + 180.0) % 360.0) - 180.0)
    wedges = []
    for start in range(0, len(signed), WEDGE_SECTORS):
        sectors = signed[start : start + WEDGE_SECTORS]
        angles = [math.radians(((i * SECTOR_DEG + 180.0) % 360.0) - 180.0) for i in sectors]
        centre = (angles[0] + angles[-1]) / 2.0
        width = angles[-1] - angles[0] + math.radians(SECTOR_DEG)
        wedges.append(([math.cos(centre / 2.0), 0.0, 0.0, math.sin(centre / 2.0)], width, sectors))
    return wedges
