"""A UDP relay between the SUT's API link and MAVSDK that records every frame for the MCAP log.

The SUT sends to the API port as it would to a ground station; the tap forwards to MAVSDK on a
port of its own and relays the answers back. Frames are stamped with the SUT's own clock
(the latest `time_boot_ms` it sent), which in lockstep is simulation time, so they line up
with the bridge's recording.
"""

from __future__ import annotations

import select
import socket
import threading

from pymavlink.dialects.v20 import common as mavlink


class ApiTap:
    def __init__(self, listen_port: int, client_port: int):
        self._sut_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sut_side.bind(("127.0.0.1", listen_port))
        self._client_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._client_side.bind(("127.0.0.1", 0))
        self._client_address = ("127.0.0.1", client_port)
        self._sut_address: tuple[str, int] | None = None
        self._parser = mavlink.MAVLink(None)
        self._parser.robust_parsing = True
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="api-tap", daemon=True)
        self.records: list[tuple[int, str, bytes]] = []  # (sut time ns, direction, datagram)
        self._sut_time_ns = 0

    def __enter__(self) -> "ApiTap":
        self._thread.start()
        return self

    def __exit__(self, *exc_info) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._sut_side.close()
        self._client_side.close()

    def restart(self) -> None:
        """A new SUT behind the same port (a warm stack's next flight): new records, its own clock,
        and nothing relayed to it before it speaks."""
        self.records = []
        self._sut_time_ns = 0
        self._sut_address = None

    def _stamp_from(self, datagram: bytes) -> None:
        for message in self._parser.parse_buffer(datagram) or []:
            time_boot_ms = getattr(message, "time_boot_ms", None)
            if time_boot_ms is not None:
                self._sut_time_ns = max(self._sut_time_ns, int(time_boot_ms) * 1_000_000)

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
                    self._stamp_from(datagram)
                    self.records.append((self._sut_time_ns, "from_sut", datagram))
                    self._client_side.sendto(datagram, self._client_address)
                else:
                    sut_address = self._sut_address  # once: restart() may clear it meanwhile
                    if sut_address is not None:
                        self.records.append((self._sut_time_ns, "to_sut", datagram))
                        self._sut_side.sendto(datagram, sut_address)
