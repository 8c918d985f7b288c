"""A small scripted SUT for bridge tests: speaks PX4's simulator protocol, no flight stack.

python tests/scripted_sut.py --port P --mode MODE [--steps N]
  hover       climb to 3 m on a PD loop over ground truth for 5 s of simulation, then hold the
              F450's hover throttle (0.4174) as collective until the bridge ends the run; a
              PD attitude loop keeps it level throughout (the F450 leaves the ground with a
              small pitch rate that nothing in the airframe damps)
  disconnect  answer N steps, then close the connection
  stall       answer N steps, then stop answering (keeps the connection open)
  garbage     answer every step, with garbage bytes before every 10th answer
  fuzz        answer every step (zero throttle), each answer after --junk generated bad frames
              (tests/fuzz_frames.py, seeded by --seed) of the kinds after which an answer
              still arrives; --odd-actuators adds well-formed actuator frames with non-finite
              or absurd values; prints the count of bad frames by kind as JSON at the end
  flood       answer N steps, then send generated bad frames (none an answer) without pause
  clock       answer every step with motor commands that tell which step they answer (0.001 plus
              a thousandth per step, modulo 97: the vehicle stays on the ground)

--late-first-s S: answer the first HIL_SENSOR S seconds late, as a SUT still coming up would;
the ones that came meanwhile are read and answered after it.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import socket
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

from simlink import codec  # noqa: E402

sys.path.insert(0, os.path.dirname(__file__))
import fuzz_frames  # noqa: E402

HOVER_THROTTLE = 0.4174
CLIMB_UNTIL_S = 5.0
TARGET_UP_M = 3.0


def clock_command(time_usec: int, step_us: int = 4000) -> float:
    """The "clock" mode's motor command for the HIL_SENSOR at time_usec (250 Hz steps)."""
    return 0.001 + (time_usec // step_us % 97) / 1000.0


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--mode", required=True, choices=["hover", "disconnect", "stall", "garbage", "fuzz", "flood", "clock"])
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--junk", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--odd-actuators", action="store_true")
    parser.add_argument("--late-first-s", type=float, default=0.0)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    sent: dict[str, int] = {}
    deadline = time.monotonic() + 20
    while True:
        try:
            sock = socket.create_connection(("127.0.0.1", args.port))
            break
        except OSError:
            if time.monotonic() > deadline:
                return 3
            time.sleep(0.05)
    splitter = codec.FrameSplitter({m: c.crc_extra for m, c in mavlink.mavlink_map.items()})
    decoder = mavlink.MAVLink(None)
    start_alt_mm = None
    up_m, climb_m_s = 0.0, 0.0
    roll = pitch = 0.0
    answered = 0
    while True:
        try:
            data = sock.recv(65536)
        except OSError:
            data = b""
        if not data:
            print(json.dumps(sent), flush=True)
            return 0
        for msgid, payload, frame in splitter.feed(data):
            if msgid == mavlink.MAVLINK_MSG_ID_HIL_STATE_QUATERNION:
                truth = decoder.decode(bytearray(frame))
                start_alt_mm = truth.alt if start_alt_mm is None else start_alt_mm
                up_m, climb_m_s = (truth.alt - start_alt_mm) / 1000.0, -truth.vz / 100.0
                w, x, y, z = truth.attitude_quaternion
                roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
                pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
            if msgid != codec.HIL_SENSOR_ID:
                continue
            sensor = codec.decode_hil_sensor(payload)
            time_usec = sensor[0]
            motors = (0.0,) * 4
            if args.mode == "clock":
                motors = (clock_command(time_usec),) * 4
            if args.mode == "hover":
                if time_usec / 1e6 < CLIMB_UNTIL_S:
                    collective = min(0.7, max(0.2, HOVER_THROTTLE + 0.3 * (TARGET_UP_M - up_m) - 0.25 * climb_m_s))
                else:
                    collective = HOVER_THROTTLE
                roll_cmd = -0.3 * roll - 0.05 * sensor[4]
                pitch_cmd = -0.3 * pitch - 0.05 * sensor[5]
                # PX4 quad-X: front-right, aft-left, front-left, aft-right.
                motors = (collective - roll_cmd + pitch_cmd, collective + roll_cmd - pitch_cmd, collective + roll_cmd + pitch_cmd, collective - roll_cmd - pitch_cmd)
            if args.mode == "flood" and answered >= args.steps:
                try:
                    while True:
                        sock.sendall(fuzz_frames.junk(rng, fuzz_frames.NEVER_ANSWERS, answers=False)[1])
                except OSError:
                    return 0
            if args.mode in ("disconnect", "stall") and answered >= args.steps:
                if args.mode == "disconnect":
                    sock.close()
                    return 0
                time.sleep(3600)
            answer = codec.encode_hil_actuator_controls(seq=answered, sysid=1, compid=1, time_usec=time_usec, controls=motors + (0.0,) * 12, mode=0, flags=1)
            if args.mode == "garbage" and answered % 10 == 0:
                answer = b"\xfd\x05garbage\x00\xfd" + answer
            if args.mode == "fuzz":
                kinds = fuzz_frames.SURVIVABLE + (("odd_actuator",) if args.odd_actuators else ())
                bad = [fuzz_frames.junk(rng, kinds) for _ in range(args.junk)]
                for kind, _data in bad:
                    sent[kind] = sent.get(kind, 0) + 1
                answer = b"".join(data for _kind, data in bad) + answer
            if answered == 0 and args.late_first_s:
                time.sleep(args.late_first_s)
            try:
                sock.sendall(answer)
            except OSError:
                print(json.dumps(sent), flush=True)
                return 0
            answered += 1


if __name__ == "__main__":
    sys.exit(main())
