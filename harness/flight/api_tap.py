"""A UDP relay between the SUT's API link and MAVSDK that records every frame for the MCAP log.

The SUT sends to the API port as it would to a ground station; the tap forwards to MAVSDK on a
port of its own and relays the answers back. Frames are stamped with the SUT's own clock
(the latest `time_boot_ms` it sent), which in lockstep is simulation time, so they line up
with the bridge's recording.

The tap also sends the ground station's heartbeat once per second of the SUT's clock, in
MAVSDK's name. MAVSDK's own is paced by the wall clock: a flight at 20 times real time hears one
per 20 simulated seconds, and a SUT that declares the link lost after 10 s of its own time
(PX4's `COM_DL_LOSS_T`) would do so while nothing is wrong. A scenario's data-link failure
silences both (`blackout`).
"""

from __future__ import annotations

import re
import select
import socket
import struct
import threading

from pymavlink.dialects.v20 import common as mavlink

from simlink import codec


def _time_boot_ms_offsets() -> dict[int, int]:
    """Per message id that has time_boot_ms, its byte offset in the payload (wire order)."""
    offsets = {}
    for msgid, message in mavlink.mavlink_map.items():
        if "time_boot_ms" in message.ordered_fieldnames:
            fields = re.findall(r"\d*[a-zA-Z?]", message.unpacker.format[1:])
            offsets[msgid] = struct.calcsize("<" + "".join(fields[: message.ordered_fieldnames.index("time_boot_ms")]))
    return offsets


class SutClock:
    """The SUT's own clock on its API link: the latest time_boot_ms it sent, in ns. Read from
    the frames' bytes with the compiled frame splitter: a PX4 flight sends about 500 frames per
    simulated second, and decoding each with pymavlink cost the harness as much CPU time as a
    tenth of PX4's. A datagram the splitter cannot take whole (MAVLink 1, a bad checksum, stray
    bytes) goes through pymavlink's robust parser, as every datagram did before; each datagram is
    parsed on its own, as UDP carries whole frames (a stream parser let a broken length swallow
    the next datagrams' frames)."""

    _OFFSETS = _time_boot_ms_offsets()
    _CRC_EXTRAS = {msgid: message.crc_extra for msgid, message in mavlink.mavlink_map.items()}

    def __init__(self):
        self.time_ns = 0
        self._splitter = codec.FrameSplitter(self._CRC_EXTRAS)

    def feed(self, datagram: bytes) -> None:
        splitter = self._splitter
        skipped, bad = splitter.skipped_bytes, splitter.bad_frames
        frames = splitter.feed(datagram)
        if splitter.skipped_bytes != skipped or splitter.bad_frames != bad:
            self._splitter = codec.FrameSplitter(self._CRC_EXTRAS)  # nothing of that datagram kept for the next
            parser = mavlink.MAVLink(None)
            parser.robust_parsing = True
            for message in parser.parse_buffer(datagram) or []:
                time_boot_ms = getattr(message, "time_boot_ms", None)
                if time_boot_ms is not None:
                    self.time_ns = max(self.time_ns, int(time_boot_ms) * 1_000_000)
            return
        offsets = self._OFFSETS
        for msgid, payload, _frame in frames:
            offset = offsets.get(msgid)
            if offset is not None:
                # MAVLink 2 drops a payload's trailing zero bytes.
                time_boot_ms = int.from_bytes(payload[offset : offset + 4].ljust(4, b"\x00"), "little")
                self.time_ns = max(self.time_ns, time_boot_ms * 1_000_000)


class ApiTap:
    def __init__(self, listen_port: int, client_port: int):
        self._sut_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sut_side.bind(("127.0.0.1", listen_port))
        self._client_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._client_side.bind(("127.0.0.1", 0))
        self._client_address = ("127.0.0.1", client_port)
        self._sut_address: tuple[str, int] | None = None
        self._clock = SutClock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="api-tap", daemon=True)
        self.records: list[tuple[int, str, bytes]] = []  # (sut time ns, direction, datagram)
        # A scenario's data-link failure: nothing passes either way, while the SUT's own frames
        # are still recorded (what it said, unheard).
        self.blackout = False
        self._gcs: mavlink.MAVLink | None = None  # encodes heartbeats as MAVSDK's system and component, once it has spoken
        self._next_heartbeat_ns = 0

    def __enter__(self) -> "ApiTap":
        self._thread.start()
        return self

    def __exit__(self, *exc_info) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._sut_side.close()
        self._client_side.close()

    @property
    def sut_time_ns(self) -> int:
        """The SUT's own clock as its API link last told it (0 before it spoke)."""
        return self._clock.time_ns

    def restart(self) -> None:
        """A new SUT behind the same port (a warm stack's next flight): new records, its own clock,
        and nothing relayed to it before it speaks."""
        self.records = []
        self._clock = SutClock()
        self._sut_address = None
        self.blackout = False
        self._next_heartbeat_ns = 0

    def _run(self) -> None:
        sockets = [self._sut_side, self._client_side]
        while not self._stop.is_set():
            readable, _, _ = select.select(sockets, [], [], 0.05)
            for sock in readable:
                try:
                    datagram, address = sock.recvfrom(65536)
                except OSError:
                    continue
                if sock is self._sut_side:
                    self._sut_address = address
                    self._clock.feed(datagram)
                    self.records.append((self._clock.time_ns, "from_sut", datagram))
                    if not self.blackout:
                        self._client_side.sendto(datagram, self._client_address)
                        self._heartbeat_on_sut_time(address)
                else:
                    if self._gcs is None:
                        self._gcs = _ground_station(datagram)
                    sut_address = self._sut_address  # once: restart() may clear it meanwhile
                    if sut_address is not None and not self.blackout:
                        self.records.append((self._clock.time_ns, "to_sut", datagram))
                        self._sut_side.sendto(datagram, sut_address)

    def _heartbeat_on_sut_time(self, sut_address: tuple[str, int]) -> None:
        now_ns = self._clock.time_ns
        if self._gcs is None or now_ns < self._next_heartbeat_ns:
            return
        self._next_heartbeat_ns = now_ns + 1_000_000_000
        datagram = self._gcs.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE).pack(self._gcs)
        self._gcs.seq = (self._gcs.seq + 1) % 256
        self.records.append((now_ns, "to_sut", datagram))
        self._sut_side.sendto(datagram, sut_address)


def _ground_station(datagram: bytes) -> mavlink.MAVLink | None:
    """An encoder in the name of the client's system and component, read from any of its messages:
    a fast flight may be over before MAVSDK's first heartbeat, never before its first command."""
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    for message in parser.parse_buffer(datagram) or []:
        if message.get_type() != "BAD_DATA":
            return mavlink.MAVLink(None, srcSystem=message.get_srcSystem(), srcComponent=message.get_srcComponent())
    return None
