"""The bundled autopilot inside the simulator's process: its simulator link through memory.

`InProcessLink` is what the bridge's SutLink protocol (sim_bridge/sut_link.py) asks of a SUT:
the bridge hands it a step's frames, the autopilot steps on them at once as it does on bytes from
its socket, and its answer waits in a buffer for the bridge to read. Same bytes, same order, so
the same flight as over TCP, without a socket round trip and a process switch per step. Its
API link stays a UDP socket (MAVSDK knows no other), served between steps as `serve` does.
"""

from __future__ import annotations

import sys
import time
import traceback

from autopilot.api import ApiLink
from autopilot.app import _CRC_EXTRAS, TELEMETRY_CHECK_S, Autopilot
from simlink import codec


class InProcessLink:
    def __init__(self, autopilot: Autopilot, api_address: tuple[str, int]):
        self.autopilot = autopilot
        autopilot.api = ApiLink(autopilot, api_address)
        self._splitter = codec.FrameSplitter(_CRC_EXTRAS)
        self._answers = bytearray()
        self._next_check = 0.0

    # The autopilot's side: its simulator "socket".
    def sendall(self, data: bytes) -> None:
        self._answers += data

    # The bridge's side.
    def send(self, data: bytes) -> None:
        try:
            self.autopilot._on_sim_data(self, self._splitter, data)
        except Exception as error:  # the SUT crashed: in a process of its own it would have died
            raise _crashed(error) from error

    def receive(self, spin_s: float) -> bytes:
        self._serve_api()
        if not self._answers:
            raise BlockingIOError("the autopilot did not answer")
        return self._take()

    def readable(self, timeout_s: float) -> bool:
        self._serve_api()
        if not self._answers and timeout_s > 0.0:
            time.sleep(timeout_s)
        return bool(self._answers)

    def idle(self) -> bytes:
        # Simulated time stands still while the harness sets up over the API link: answer it at once.
        self._serve_api(now=True)
        return self._take()

    def waitable(self):
        return self.autopilot.api.sock

    def close(self) -> None:
        self.autopilot.api.sock.close()

    def _take(self) -> bytes:
        data = bytes(self._answers)
        self._answers.clear()
        return data

    def _serve_api(self, now: bool = False) -> None:
        """The API link at most every TELEMETRY_CHECK_S of wall time, as Autopilot.serve does
        (its incoming messages at once too when `now`)."""
        wall = time.perf_counter()
        api = self.autopilot.api
        try:
            if wall < self._next_check:
                if now:
                    api.receive()
                return
            api.receive()
            api.check_link(self.autopilot.params["COM_DL_LOSS_T"])  # before the events: its failsafe's are reported at once
            api.report_events()
            api.telemetry(wall)
        except Exception as error:  # as in send(): the SUT crashed
            raise _crashed(error) from error
        self._next_check = wall + TELEMETRY_CHECK_S


def _crashed(error: Exception) -> ConnectionAbortedError:
    """The bridge ends the run as sut_disconnected on an OSError; the harness reports a crashed
    SUT with the end of the process's stderr, which gets the traceback."""
    traceback.print_exception(error, file=sys.stderr)
    return ConnectionAbortedError(f"the autopilot crashed: {error!r}")
