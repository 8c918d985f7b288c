"""MAVLink 2 framing plus struct codecs for the simulator link's messages, byte-identical to pymavlink.

pymavlink spends 3-7 us encoding and about 10 us parsing one message; at 250 Hz in lockstep that
is a large part of the step budget. HIL_SENSOR and HIL_ACTUATOR_CONTROLS, every step, have codecs
of their own; the 10-50 Hz messages (GPS, ground truth, range, RC) go through `MessageCodec`,
which packs and unpacks pymavlink's own layout of a message without building its message
objects. tests/test_simlink_codec.py checks every byte against pymavlink.
"""

from __future__ import annotations

import select
import socket
import struct
import time
from collections import namedtuple

from fastcrc import crc16
from pymavlink.dialects.v20 import common as _mavlink

STX_V2 = 0xFD
HEADER_LEN = 10  # STX, len, incompat, compat, seq, sysid, compid, msgid (3 bytes)
CHECKSUM_LEN = 2
SIGNATURE_LEN = 13
INCOMPAT_SIGNED = 0x01

HIL_SENSOR_ID = 107
HIL_SENSOR_CRC_EXTRA = 108
HIL_ACTUATOR_CONTROLS_ID = 93
HIL_ACTUATOR_CONTROLS_CRC_EXTRA = 47

_HIL_SENSOR = struct.Struct("<Q13fIB")
_HIL_ACTUATOR_CONTROLS = struct.Struct("<QQ16fB")
_HEADER = struct.Struct("<BBBBBBBHB")  # msgid as uint16 + uint8
_CHECKSUM = struct.Struct("<H")
_mcrf4xx = crc16.mcrf4xx
# A message's CRC extra as the byte the checksum ends with, made once rather than per frame.
_EXTRA_BYTES = [bytes((extra,)) for extra in range(256)]


def _frame(msgid: int, crc_extra: int, payload: bytes, seq: int, sysid: int, compid: int) -> bytes:
    # MAVLink 2 drops trailing zero bytes of the payload, keeping at least one.
    body = payload.rstrip(b"\x00") or b"\x00"
    header = _HEADER.pack(STX_V2, len(body), 0, 0, seq & 0xFF, sysid, compid, msgid & 0xFFFF, msgid >> 16)
    crc = _mcrf4xx(header[1:] + body + _EXTRA_BYTES[crc_extra], 0xFFFF)
    return b"".join((header, body, _CHECKSUM.pack(crc)))


def encode_hil_sensor(
    *,
    seq: int,
    sysid: int,
    compid: int,
    time_usec: int,
    values: tuple[float, ...],
    fields_updated: int,
    sensor_id: int = 0,
) -> bytes:
    """values: xacc..zacc, xgyro..zgyro, xmag..zmag, abs_pressure, diff_pressure, pressure_alt, temperature."""
    payload = _HIL_SENSOR.pack(time_usec, *values, fields_updated, sensor_id)
    return _frame(HIL_SENSOR_ID, HIL_SENSOR_CRC_EXTRA, payload, seq, sysid, compid)


def decode_hil_sensor(payload: bytes) -> tuple:
    """(time_usec, 13 floats..., fields_updated, id) from a frame's payload, which MAVLink 2 may have
    truncated (trailing zeros) or a newer dialect extended (bytes beyond ours are ignored)."""
    if len(payload) >= _HIL_SENSOR.size:
        return _HIL_SENSOR.unpack_from(payload)
    return _HIL_SENSOR.unpack(payload.ljust(_HIL_SENSOR.size, b"\x00"))


def encode_hil_actuator_controls(
    *, seq: int, sysid: int, compid: int, time_usec: int, controls: tuple[float, ...], mode: int, flags: int
) -> bytes:
    payload = _HIL_ACTUATOR_CONTROLS.pack(time_usec, flags, *controls, mode)
    return _frame(HIL_ACTUATOR_CONTROLS_ID, HIL_ACTUATOR_CONTROLS_CRC_EXTRA, payload, seq, sysid, compid)


def decode_hil_actuator_controls(payload: bytes) -> tuple[int, int, tuple[float, ...], int]:
    """(time_usec, flags, controls[16], mode); truncated or extended payloads as decode_hil_sensor."""
    size = _HIL_ACTUATOR_CONTROLS.size
    fields = _HIL_ACTUATOR_CONTROLS.unpack_from(payload) if len(payload) >= size else _HIL_ACTUATOR_CONTROLS.unpack(payload.ljust(size, b"\x00"))
    return fields[0], fields[1], fields[2:18], fields[18]


class MessageCodec:
    """One message in pymavlink's layout (its wire-order struct, field order, array lengths and
    CRC extra, read off pymavlink's message class), without pymavlink's message objects."""

    def __init__(self, message_class):
        if any(kind == "char" for kind in message_class.fieldtypes):
            raise ValueError(f"{message_class.msgname}: char fields are not supported")
        self.msgid = message_class.id
        self._crc_extra = message_class.crc_extra
        self._struct = message_class.unpacker
        declared, wire = message_class.fieldnames, message_class.ordered_fieldnames
        lengths = dict(zip(wire, message_class.array_lengths))
        self._wire = [(declared.index(name), lengths[name]) for name in wire]
        self._declared_at = [wire.index(name) for name in declared]
        self._fields = namedtuple(message_class.msgname, declared)

    def encode(self, seq: int, sysid: int, compid: int, *values) -> bytes:
        """values: the fields in pymavlink's `*_encode` order, arrays as sequences."""
        flat = []
        for index, length in self._wire:
            if length:
                flat.extend(values[index])
            else:
                flat.append(values[index])
        return _frame(self.msgid, self._crc_extra, self._struct.pack(*flat), seq, sysid, compid)

    def decode(self, payload: bytes):
        """The fields by name (arrays as tuples) from a frame's payload, truncated or extended as
        decode_hil_sensor takes it."""
        size = self._struct.size
        flat = self._struct.unpack(payload[:size].ljust(size, b"\x00"))
        wire = []
        position = 0
        for _index, length in self._wire:
            if length:
                wire.append(flat[position : position + length])
                position += length
            else:
                wire.append(flat[position])
                position += 1
        return self._fields(*[wire[at] for at in self._declared_at])


class FrameSplitter:
    """Splits a byte stream into MAVLink 2 frames; counts and skips garbage and bad checksums.

    A frame counts only if its message id has a CRC extra in the caller's table and its
    checksum matches; pass pymavlink's table to accept the whole dialect.
    """

    def __init__(self, crc_extras: dict[int, int]):
        self._buffer = bytearray()
        self._crc_extras = crc_extras
        self.skipped_bytes = 0
        self.bad_frames = 0

    def _check(self, buffer: bytearray, start: int, end: int) -> int:
        """Length of a valid frame at start; 0 if incomplete; -1 if it is not a valid frame."""
        if end - start < HEADER_LEN:
            return 0
        length = buffer[start + 1]
        signed = buffer[start + 2] & INCOMPAT_SIGNED
        total = HEADER_LEN + length + CHECKSUM_LEN + (SIGNATURE_LEN if signed else 0)
        if end - start < total:
            return 0
        msgid = buffer[start + 7] | (buffer[start + 8] << 8) | (buffer[start + 9] << 16)
        crc_extra = self._crc_extras.get(msgid)
        if crc_extra is None:
            return -1
        crc_end = start + HEADER_LEN + length
        crc = _mcrf4xx(buffer[start + 1 : crc_end] + _EXTRA_BYTES[crc_extra], 0xFFFF)
        return total if crc == buffer[crc_end] | (buffer[crc_end + 1] << 8) else -1

    def feed(self, data: bytes) -> list[tuple[int, bytes, bytes]]:
        """(msgid, payload, whole frame) for each complete, valid frame; keeps partial frames."""
        frames = []
        buffer = self._buffer
        buffer += data
        position = 0
        end = len(buffer)
        while True:
            start = buffer.find(STX_V2, position)
            if start < 0:
                self.skipped_bytes += end - position
                position = end
                break
            self.skipped_bytes += start - position
            total = self._check(buffer, start, end)
            if total == 0:
                # A stray STX can announce a length that never arrives; a lockstep peer would
                # then wait forever for an answer stuck behind it. Skip it if a valid frame follows.
                following = buffer.find(STX_V2, start + 1)
                while following >= 0 and self._check(buffer, following, end) <= 0:
                    following = buffer.find(STX_V2, following + 1)
                if following >= 0:
                    self.bad_frames += 1
                    self.skipped_bytes += following - start
                    position = following
                    continue
                position = start
                break
            if total < 0:
                self.bad_frames += 1
                self.skipped_bytes += 1
                position = start + 1
                continue
            frame = bytes(buffer[start : start + total])
            length = buffer[start + 1]
            msgid = frame[7] | (frame[8] << 8) | (frame[9] << 16)
            frames.append((msgid, frame[HEADER_LEN : HEADER_LEN + length], frame))
            position = start + total
        del buffer[:position]
        return frames


UNIX_ADDRESS_MAX = 107  # sockaddr_un's sun_path less its terminating NUL


def unix_socket_address(name: str) -> str:
    """A Unix-domain socket's address: a path, or "@NAME" for Linux's abstract namespace (no
    file to remove, however its owner ends). ValueError for an empty or too long name."""
    address = "\0" + name[1:] if name.startswith("@") else name
    if not name.removeprefix("@") or len(address.encode()) > UNIX_ADDRESS_MAX:
        raise ValueError(f"{name!r} is not a Unix-domain socket name: give a path or @NAME of 1 to {UNIX_ADDRESS_MAX - 1} bytes")
    return address


def send_at_once(sock: socket.socket) -> None:
    """No Nagle delay on a TCP link: every lockstep message is small and awaited (a Unix-domain
    socket has none to turn off)."""
    if sock.family != socket.AF_UNIX:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)


def set_receive_timeout(sock, timeout_s: float) -> None:
    """A kernel-side receive timeout on a blocking socket: one recv() syscall per message instead
    of Python's poll() + recv() for sockets with a timeout. recv() then raises BlockingIOError
    (EAGAIN) when the timeout passes."""
    sock.settimeout(None)
    seconds = int(timeout_s)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, struct.pack("ll", seconds, int((timeout_s - seconds) * 1e6)))


def receive(sock: socket.socket, spin_s: float = 0.0, *, also: socket.socket | None = None, wait_s: float = 0.0) -> bytes:
    """recv() on a blocking socket, first polling for up to spin_s of wall time.

    Waking a sleeping process on another core costs about 40 us here, more than either side's
    work in a lockstep step; a peer with a core of its own answers a polling reader in a few us.
    With both peers on one core, polling only delays the peer: leave spin_s at 0 there.

    also: a second socket whose input ends the wait too (then, or after wait_s, BlockingIOError),
    so that its peer is answered at once while sock stays silent. Without it, wait_s does not
    apply: the socket's own receive timeout does (set_receive_timeout), if any.
    """
    if spin_s > 0.0:
        deadline = time.perf_counter() + spin_s
        while True:
            try:
                return sock.recv(65536, socket.MSG_DONTWAIT)
            except BlockingIOError:
                if time.perf_counter() > deadline:
                    break
    if also is not None and sock not in select.select([sock, also], [], [], wait_s)[0]:
        raise BlockingIOError("nothing on the socket yet")
    return sock.recv(65536)


HIL_GPS = MessageCodec(_mavlink.MAVLink_hil_gps_message)
HIL_STATE_QUATERNION = MessageCodec(_mavlink.MAVLink_hil_state_quaternion_message)
OBSTACLE_DISTANCE = MessageCodec(_mavlink.MAVLink_obstacle_distance_message)
DISTANCE_SENSOR = MessageCodec(_mavlink.MAVLink_distance_sensor_message)
RC_CHANNELS = MessageCodec(_mavlink.MAVLink_rc_channels_message)
