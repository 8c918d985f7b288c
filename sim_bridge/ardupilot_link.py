"""The bridge's side of ArduPilot's JSON physics link (the protocol: sim_bridge/ardupilot_json.py).

ArduPilot is the UDP client: it sends each servo frame to the simulator port from a port of its
own and takes its state line from wherever the answer comes. `UdpLink` carries the datagrams
(one servo frame per `receive`); `JsonSteps` is what the bridge's loop does with them instead
of MAVLink: one state line per step out, one servo frame per step in, in lockstep. The world,
its sensors and obstacles, scoring and recording are the bridge's own, as for every SUT.
"""

from __future__ import annotations

import select
import socket
import time
from typing import Callable, Mapping

from sim_bridge.ardupilot_json import (REPEATED, RESTARTED, FrameCounter, FrameError, decode_servo_frame, motor_commands, rangefinder_distances_m, rc_channels,
                                       rc_packet, state_line)
from sim_bridge.control import EndReason
from sim_bridge.frames import SensorFrames
from sim_bridge.sensors import quaternion_from_euler
from sim_bridge.world import SECTOR_DEG, World

PROTOCOLS = ("mavlink", "ardupilot-json")


def listen_udp(port: int, host: str = "127.0.0.1") -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind((host, port))
    return sock


def _readable(sock: socket.socket, timeout_s: float) -> bool:
    return bool(select.select([sock], [], [], timeout_s)[0])


def accept(sock: socket.socket, timeout_s: float, stall_timeout_s: float, wait_readable: Callable[[socket.socket, float], bool] = _readable) -> "UdpLink":
    """The link once ArduPilot's first servo frame came (socket.timeout if none within timeout_s,
    or wait_readable gave up), opened by the newest frame waiting: ArduPilot sends its first frame
    again every second until it has an answer, so those before it are the same frame, stale. What
    is no servo frame is ignored."""
    deadline = time.monotonic() + timeout_s
    first: tuple[bytes, tuple[str, int]] | None = None
    while True:
        wait_s = 0.0 if first is not None else deadline - time.monotonic()
        if wait_s < 0 or not wait_readable(sock, wait_s):
            if first is None:
                raise socket.timeout(f"no servo frame within {timeout_s:.0f} s, or the harness stopped waiting for one")
            return UdpLink(sock, first[1], stall_timeout_s, first=first[0])
        datagram, peer = sock.recvfrom(65536)
        try:
            decode_servo_frame(datagram)
        except FrameError:
            continue
        first = (datagram, peer)


class UdpLink:
    """ArduPilot's datagrams: `receive` gives one at a time, and answers go to whoever sent the
    last one (an ArduPilot restarted has a port of its own). UDP has no hang-up: a SUT that went
    is a SUT that stays silent for the stall timeout."""

    can_hang_up = False

    def __init__(self, sock: socket.socket, peer: tuple[str, int], stall_timeout_s: float, first: bytes):
        self.sock = sock
        self.peer = peer
        self.first = first
        self._stall_timeout_s = stall_timeout_s

    def send(self, data: bytes) -> None:
        self.sock.sendto(data, self.peer)

    def receive(self, spin_s: float) -> bytes:
        """The next datagram, first polling for up to spin_s of wall time as the MAVLink link does
        (simlink/codec.py's receive: with a core of its own the bridge sees the answer without
        being woken), then waiting up to the stall timeout."""
        if spin_s > 0.0:
            deadline = time.perf_counter() + spin_s
            while True:
                try:
                    datagram, self.peer = self.sock.recvfrom(65536, socket.MSG_DONTWAIT)
                    return datagram
                except BlockingIOError:
                    if time.perf_counter() > deadline:
                        break
        if not self.readable(self._stall_timeout_s):
            raise BlockingIOError(f"nothing from ArduPilot for {self._stall_timeout_s:.0f} s")
        datagram, self.peer = self.sock.recvfrom(65536)
        return datagram

    def readable(self, timeout_s: float) -> bool:
        return _readable(self.sock, timeout_s)

    def idle(self) -> bytes:
        data = b""
        while self.readable(0.0):
            datagram, self.peer = self.sock.recvfrom(65536)
            data += datagram
        return data

    def waitable(self) -> socket.socket:
        return self.sock

    def close(self) -> None:
        self.sock.close()


class JsonSteps:
    """The bridge's per-step exchange in ArduPilot's JSON protocol: the world's readings from
    `frames`, at the bridge's rates (`every`), its events through `on_event` and the bytes
    received added to `link_in` for the bridge's recording."""

    def __init__(self, world: World, config, frames: SensorFrames, every: Mapping[str, int], on_event: Callable[..., None], link_in: bytearray,
                 link, first_frame: bytes | None = None):
        self.world = world
        self.config = config
        self.readings = frames
        self.every = every
        self.on_event = on_event
        self.link_in = link_in
        self.link = link
        rc_port = config.rc_port
        self._rc_address = ("127.0.0.1", rc_port) if rc_port is not None and world.pilot is not None else None
        self.frames = FrameCounter()
        self.bad_frames = 0
        self.skipped_bytes = 0
        self._last_line = b""
        self._ranges: list[float | None] = []
        # ArduPilot makes its GPS from the true position it is sent (its SITL GPS model): a GPS
        # failure the simulator would deliver cannot reach it.
        for spec in world.spec.failures or ():
            if spec.delivery == "simulator" and spec.unit != "distance sensor":
                on_event(0.0, "failure_refused", {"unit": spec.unit, "type": spec.type, "delivery": "simulator",
                                                       "result": "UNSUPPORTED: ArduPilot's JSON backend makes its own GPS from the true position"})
        unsent = [sensor.name for sensor in world.spec.rig or () if sensor.message not in config.companion_messages or config.companion_port is None]
        if unsent:
            raise ValueError(f"the rig's {', '.join(unsent)}: ArduPilot's JSON link carries no MAVLink; send them on its companion link "
                             "(--companion-port, --companion-messages)")
        if first_frame is not None:
            # The frame that opened the link was sent before any state: no step answers it.
            self.frames.classify(decode_servo_frame(first_frame).frame_count)

    def state(self, step: int, time_us: int) -> bytes:
        """This step's state line: the IMU with the world's sensor noise, the true position and
        velocity (ArduPilot's SITL makes its GPS, barometer and compass from them) and, at the
        range sensor's rate its six rangefinders, held in between. The pilot's sticks go to ArduPilot's RC input
        first, so that the step this line starts reads them."""
        world = self.world
        if self._rc_address is not None and step % self.every["rc"] == 0:
            self.link.sock.sendto(rc_packet(self.readings.pilot_frame(time_us, rc_channels)), self._rc_address)
        s = world.state
        imu = world.imu()
        if self.readings.rig is not None:
            # A rig reaches ArduPilot over MAVLink, its proximity backend's (the bridge's companion link)
            self.readings.rig_frames(step, time_us)
        elif step % self.every["sensor"] == 0:
            distances = self.readings.range_reading(time_us)
            # Held until the next reading: ArduPilot prints the fields it got whenever they change.
            self._ranges = [] if distances is None else rangefinder_distances_m(distances, world.sector_visible.tolist(), SECTOR_DEG, world.range_m)
        ranges = self._ranges
        line = state_line(timestamp_s=time_us / 1e6, gyro_rad_s=imu[3:6], accel_body_m_s2=imu[0:3], position_ned_m=(s.north_m, s.east_m, -s.up_m),
                          velocity_ned_m_s=(s.v_north_m_s, s.v_east_m_s, s.v_down_m_s), quaternion=quaternion_from_euler(s.roll_rad, s.pitch_rad, s.yaw_rad),
                          ranges_m=ranges)
        self._last_line = line
        return line

    def receive_answer(self, sut, waiting_since: float) -> bool:
        """Read until this step's servo frame; whether it came. A frame sent again means our line
        was lost: it gets the same line again, and the world takes no second step. A count that
        starts again is an ArduPilot restarted: recorded, and flown on. What is no servo frame is
        counted and skipped."""
        world = self.world
        while True:
            try:
                datagram = sut.receive(self.config.spin_s)
            except BlockingIOError:
                world.end(EndReason.SUT_STALLED)
                return False
            except OSError:
                world.end(EndReason.SUT_DISCONNECTED)
                return False
            self.link_in += datagram
            try:
                frame = decode_servo_frame(datagram)
            except FrameError:
                self.bad_frames += 1
                self.skipped_bytes += len(datagram)
                if time.perf_counter() - waiting_since > self.config.stall_timeout_s:
                    world.end(EndReason.SUT_STALLED)
                    return False
                continue
            kind = self.frames.classify(frame.frame_count)
            if kind == REPEATED:
                if not self._last_line:
                    continue  # the frame that opened the link, once more: no line went out yet
                try:
                    sut.send(self._last_line)
                except OSError:
                    world.end(EndReason.SUT_DISCONNECTED)
                    return False
                continue
            if kind == RESTARTED:
                self.on_event(world.time_s, "sut_restarted", {"frame_count": frame.frame_count})
            world.motors = motor_commands(frame.pwm_us)
            return True
