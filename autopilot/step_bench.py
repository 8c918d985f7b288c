"""The autopilot's own cost per lockstep step (parse, estimate, control, encode), without sockets.

A recorded simulator-to-SUT byte stream is replayed into an in-process autopilot flying the
recorded mission. Its answers, and its state after each step, are kept only as digests, equal
wherever the autopilot computes the same values (compiled or not).
"""

from __future__ import annotations

import hashlib
import time
from typing import Any, Mapping

from pymavlink.dialects.v20 import common as mavlink

from autopilot.app import Autopilot
from pymavlink.dialects.v20.common import MAV_CMD_NAV_LAND, MAV_CMD_NAV_TAKEOFF, MAV_CMD_NAV_WAYPOINT

from autopilot.commander import MissionItem
from autopilot.params import Params
from simlink import codec


class _DigestSocket:
    def __init__(self):
        self.digest = hashlib.sha256()

    def sendall(self, data: bytes) -> None:
        self.digest.update(data)


def replay(stream: bytes, mission: Mapping[str, Any]) -> dict[str, Any]:
    """stream: the simulator's messages to the SUT as sent; mission: the world spec's mission
    (takeoff altitude and waypoints), armed and started once the autopilot is ready, as the
    harness does 3 s into a flight."""
    autopilot = Autopilot(Params())
    crc_extras = {m: c.crc_extra for m, c in mavlink.mavlink_map.items()}
    frames = codec.FrameSplitter(crc_extras).feed(stream)
    splitter = codec.FrameSplitter(crc_extras)
    last = mission["waypoints"][-1]
    items = [MissionItem(0, MAV_CMD_NAV_TAKEOFF, 0.0, 0.0, mission["takeoff_altitude_m"])]
    items += [MissionItem(i + 1, MAV_CMD_NAV_WAYPOINT, w["north_m"], w["east_m"], w["altitude_m"], 0.0, 2.0) for i, w in enumerate(mission["waypoints"])]
    items.append(MissionItem(len(items), MAV_CMD_NAV_LAND, last["north_m"], last["east_m"], 0.0))
    durations = []
    armed = False
    sock = _DigestSocket()
    # The answers are float32: the estimator's and controllers' doubles are compared in full too.
    state = hashlib.sha256()
    for msgid, _payload, frame in frames:
        started = time.perf_counter()
        autopilot._on_sim_data(sock, splitter, frame)
        if msgid == codec.HIL_SENSOR_ID:
            durations.append(time.perf_counter() - started)
            est = autopilot.estimator
            state.update(repr((est.q, est.rates, est.acc_ned, est.pos, est.vel, autopilot.collective, autopilot.lift,
                               autopilot.rate_control._int, autopilot.rate_control._last)).encode())
        if not armed and autopilot.now_s >= 3.0 and autopilot.ready_to_arm()[0]:
            autopilot.commander.set_mission(items)
            autopilot.commander.arm(autopilot.now_s, True, "")
            autopilot.on_armed()
            autopilot.commander.start_mission(autopilot.vehicle_estimate())
            armed = True
    durations.sort()
    return {"steps": len(durations), "median_step_us": 1e6 * durations[len(durations) // 2], "answers_sha256": sock.digest.hexdigest(),
            "state_sha256": state.hexdigest(),
            "p90_step_us": 1e6 * durations[int(0.9 * len(durations))], "flew_mission": armed}
