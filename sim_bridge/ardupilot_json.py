"""ArduPilot's JSON physics protocol (ArduPilot libraries/SITL/SIM_JSON.cpp): a servo frame in,
one line of JSON state out, in lockstep.

ArduPilot SITL started with `--model JSON:127.0.0.1` sends its outputs as one UDP datagram per
physics step: `<HHI16H>` (magic 18458, its frame rate in Hz, its frame count, 16 PWM values in
microseconds) or `<HHI32H>` (magic 29569) with 32 channels. It then blocks until it has one line
of state. Its parser is no JSON parser: it finds each key with strstr and reads vectors with
sscanf("[%f, %f, %f]") right after `"key":`, so the line is compact (no space after a colon)
and begins and ends with a newline (it parses what lies between the last two).

State fields (SI, NED, body FRD): timestamp (s, our simulated time, which ArduPilot's clock
follows), imu.gyro (rad/s), imu.accel_body (specific force, m/s^2), position (m from home),
velocity (m/s), quaternion (w, x, y, z, body to NED), and rng_1..rng_6 (m): six rangefinders,
one orientation each, which ArduPilot's SITL rangefinder type (RNGFNDn_TYPE 100) reads.

Pure functions; the bridge does the sockets.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import TYPE_CHECKING, Sequence

from sim_bridge.pilot import MODE_SWITCH, PITCH, SLOT_HOLD, THROTTLE

if TYPE_CHECKING:
    from sim_bridge.pilot import RcFrame

MAGIC_16 = 18458
MAGIC_32 = 29569
_FRAME_16 = struct.Struct("<HHI16H")
_FRAME_32 = struct.Struct("<HHI32H")
_MAGIC = struct.Struct("<H")
MOTORS = 4
# ArduCopter's quad-X (FRAME_CLASS 1, FRAME_TYPE 1) numbers its motors as PX4's quad-X does:
# 1 front-right and 2 aft-left counter-clockwise, 3 front-left and 4 aft-right clockwise, on
# servo outputs 1-4 (SERVOn_FUNCTION 33-36). So output n drives our F450's motor n-1 as it is.
PWM_MIN_US = 1000.0
PWM_MAX_US = 2000.0
# The rangefinders' yaw in body FRD (degrees) and ArduPilot's orientation value for each
# (RNGFNDn_ORIENT: 0 forward, 1 forward-right, 2 right, 4 back, 6 left, 7 forward-left): the
# six ArduPilot's JSON backend can carry, weighted forward, where a flight meets what is ahead.
RANGEFINDER_YAW_DEG = (0.0, 45.0, 90.0, 180.0, 270.0, 315.0)
RANGEFINDER_ORIENTATION = (0, 1, 2, 4, 6, 7)
RANGEFINDER_HALF_WIDTH_DEG = 22.5
# A bad frame (wrong size or magic) or one repeated has no new PWM: the bridge says which.
NEW, REPEATED, RESTARTED = "new", "repeated", "restarted"


class FrameError(ValueError):
    """A datagram that is no servo frame."""


@dataclass(frozen=True)
class ServoFrame:
    frame_rate_hz: int
    frame_count: int
    pwm_us: tuple[int, ...]


def decode_servo_frame(datagram: bytes) -> ServoFrame:
    """The servo frame in one datagram; FrameError naming what is wrong with anything else."""
    if len(datagram) == _FRAME_16.size:
        layout, magic = _FRAME_16, MAGIC_16
    elif len(datagram) == _FRAME_32.size:
        layout, magic = _FRAME_32, MAGIC_32
    else:
        raise FrameError(f"{len(datagram)} bytes: a servo frame has {_FRAME_16.size} (16 channels) or {_FRAME_32.size} (32)")
    found, rate, count, *pwm = layout.unpack(datagram)
    if found != magic:
        raise FrameError(f"magic {found} in a {len(datagram)}-byte frame, not {magic}")
    return ServoFrame(rate, count, tuple(pwm))


def encode_servo_frame(frame_rate_hz: int, frame_count: int, pwm_us: Sequence[int]) -> bytes:
    """A servo frame as ArduPilot sends it (16 or 32 channels): for tests and fakes."""
    if len(pwm_us) == 16:
        return _FRAME_16.pack(MAGIC_16, frame_rate_hz, frame_count, *pwm_us)
    if len(pwm_us) == 32:
        return _FRAME_32.pack(MAGIC_32, frame_rate_hz, frame_count, *pwm_us)
    raise ValueError(f"a servo frame carries 16 or 32 PWM values, not {len(pwm_us)}")


def servo_frames_in(stream: bytes) -> list[ServoFrame]:
    """The servo frames in a recorded stream of ArduPilot's datagrams (the MCAP's /mavlink/sim,
    from the SUT), skipping what is none, each frame sent again but once."""
    frames: list[ServoFrame] = []
    at = 0
    while at + _FRAME_16.size <= len(stream):
        magic = _MAGIC.unpack_from(stream, at)[0]
        layout = _FRAME_16 if magic == MAGIC_16 else _FRAME_32 if magic == MAGIC_32 else None
        if layout is None or at + layout.size > len(stream):
            at += 1
            continue
        frame = decode_servo_frame(stream[at:at + layout.size])
        if not frames or frame.frame_count != frames[-1].frame_count:
            frames.append(frame)
        at += layout.size
    return frames


def motor_commands(pwm_us: Sequence[int]) -> tuple[float, float, float, float]:
    """The first four outputs as motor commands 0..1 in our F450's order; 0 (output off) and
    anything outside the PWM range saturate as an ESC takes them."""
    return tuple(min(1.0, max(0.0, (pwm - PWM_MIN_US) / (PWM_MAX_US - PWM_MIN_US))) for pwm in pwm_us[:MOTORS])


class FrameCounter:
    """Which frames carry new PWM. ArduPilot counts its frames up by one per state line it parsed
    and sends the same frame again when a line did not reach it (after a second's wait); it starts
    from 0 when it restarts. A count that jumps ahead means frames were lost on the way: their
    PWM is gone, the newest counts."""

    def __init__(self) -> None:
        self.last: int | None = None
        self.lost = 0
        self.repeated = 0
        self.restarts = 0

    def classify(self, frame_count: int) -> str:
        last = self.last
        self.last = frame_count
        if last is None or frame_count == last + 1:
            return NEW
        if frame_count == last:
            self.repeated += 1
            return REPEATED
        if frame_count < last:
            self.restarts += 1
            return RESTARTED
        self.lost += frame_count - last - 1
        return NEW


def rangefinders_in_view(fov_deg: float) -> list[bool]:
    """Which rangefinders' wedges the range sensor sees any of (a field of view centred on the nose)."""
    half_fov = fov_deg / 2.0
    return [abs((yaw + 180.0) % 360.0 - 180.0) - RANGEFINDER_HALF_WIDTH_DEG <= half_fov + 1e-9 for yaw in RANGEFINDER_YAW_DEG]


def rangefinder_distances_m(distances_cm: Sequence[int], visible: Sequence[bool], sector_deg: float, reach_m: float) -> list[float | None]:
    """Each rangefinder's reading from the range sensor's sectors (body FRD, OBSTACLE_DISTANCE's
    convention): the nearest sector within its 45-degree wedge, in metres; reach + 1 cm where
    nothing is in reach (ArduPilot: out of range high); None where no sector of its wedge is in
    the sensor's field of view."""
    readings: list[float | None] = []
    for yaw_deg in RANGEFINDER_YAW_DEG:
        nearest = None
        for index, distance_cm in enumerate(distances_cm):
            offset = (index * sector_deg - yaw_deg + 180.0) % 360.0 - 180.0
            if visible[index] and abs(offset) <= RANGEFINDER_HALF_WIDTH_DEG:
                nearest = distance_cm if nearest is None else min(nearest, distance_cm)
        readings.append(None if nearest is None else min(nearest / 100.0, reach_m + 0.01))
    return readings


def state_line(*, timestamp_s: float, gyro_rad_s: Sequence[float], accel_body_m_s2: Sequence[float], position_ned_m: Sequence[float],
               velocity_ned_m_s: Sequence[float], quaternion: Sequence[float], ranges_m: Sequence[float | None] = ()) -> bytes:
    """One step's state as ArduPilot's JSON backend reads it, newline before and after."""
    for name, values in (("gyro", gyro_rad_s), ("accel_body", accel_body_m_s2), ("position", position_ned_m), ("velocity", velocity_ned_m_s),
                         ("quaternion", quaternion)):
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"{name} {tuple(values)} is not finite: ArduPilot's parser would read garbage")
    gx, gy, gz = gyro_rad_s
    ax, ay, az = accel_body_m_s2
    pn, pe, pd = position_ned_m
    vn, ve, vd = velocity_ned_m_s
    qw, qx, qy, qz = quaternion
    ranges = "".join(f',"rng_{i + 1}":{r:.3f}' for i, r in enumerate(ranges_m) if r is not None)
    return (f'\n{{"timestamp":{timestamp_s:.6f},"imu":{{"gyro":[{gx:.6f},{gy:.6f},{gz:.6f}],"accel_body":[{ax:.5f},{ay:.5f},{az:.5f}]}},'
            f'"position":[{pn:.4f},{pe:.4f},{pd:.4f}],"velocity":[{vn:.4f},{ve:.4f},{vd:.4f}],'
            f'"quaternion":[{qw:.7f},{qx:.7f},{qy:.7f},{qz:.7f}]{ranges}}}\n').encode()


# ArduPilot's mode switch has six positions (RC_Channel's read of FLTMODE_CH: up to 1230, 1360,
# 1490, 1620, 1749 us, above): the middle of each, for the pilot's mode slot of that number.
MODE_SWITCH_US = (1165, 1295, 1425, 1555, 1685, 1875)
_RC_PACKET = struct.Struct("<8H")


def rc_channels(frame: "RcFrame") -> list[int]:
    """The simulated pilot's transmitter as ArduPilot reads one: its pitch stick gives a low pulse
    for forward (PX4's the opposite), and its mode switch sits in the middle of ArduPilot's
    position for the pilot's slot (FLTMODE1..6). Until the take-off is done (the hold slot) the
    throttle stick rests at its bottom: ArduCopter refuses to arm in Stabilize, its mode at
    boot, with the throttle up, and in Guided, where it takes off, the stick does nothing."""
    channels = frame.channels()
    channels[PITCH - 1] = 3000 - channels[PITCH - 1]
    if frame.slot == SLOT_HOLD:
        channels[THROTTLE - 1] = int(PWM_MIN_US)
    channels[MODE_SWITCH - 1] = MODE_SWITCH_US[frame.slot - 1]
    return channels


def rc_packet(channels_us: Sequence[int]) -> bytes:
    """ArduPilot SITL's RC input datagram (AP_RCProtocol_UDP): 8 (or 16) uint16 pulse widths."""
    return _RC_PACKET.pack(*channels_us)
