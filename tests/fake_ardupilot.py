"""A small ArduPilot that obeys the JSON physics protocol as ArduPilot SITL does (libraries/SITL/
SIM_JSON.cpp), for the bridge's tests where no ArduPilot is built.

It sends a servo frame (<HHI16H>, magic 18458) from a UDP port of its own to the simulator port,
waits for a state line, reads it the way ArduPilot's parser does (`parse_like_ardupilot`: key
by strstr, vectors by sscanf "[%f, %f, %f]" right after `"key":`), counts its frame up by one
per line it parsed and sends the next frame. Without an answer it sends the same frame again,
as ArduPilot does after a second (here --resend-after-s). Its misbehaviours, each on request:
forget an answer (so its frame comes again), skip frame counts, restart its count, put junk
datagrams between its frames. It prints one JSON line of what it saw when the bridge stops
answering.

With --serial1-port it opens SERIAL1 as ArduPilot's `--serial1 udpclient:127.0.0.1:PORT` does: a
heartbeat from a port of its own at start and each simulated second, and it counts the
DISTANCE_SENSOR and OBSTACLE_DISTANCE messages that come back, as its MAVLink proximity backend
would read them.

    python tests/fake_ardupilot.py --port SIM_PORT [--frames N] [--pwm 1000] [--junk K --seed S]
        [--ignore-every N] [--skip-every N] [--restart-at N] [--serial1-port PORT]
"""

from __future__ import annotations

import argparse
import json
import random
import re
import socket
import struct
import sys

from pymavlink.dialects.v20 import common as mavlink

FRAME = struct.Struct("<HHI16H")
MAGIC = 18458
REQUIRED = (("", "timestamp"), ("imu", "gyro"), ("imu", "accel_body"), ("", "position"), ("", "velocity"))
OPTIONAL = (("", "quaternion"), ("", "attitude")) + tuple(("", f"rng_{n}") for n in range(1, 7))
_FLOAT = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


def parse_like_ardupilot(line: str) -> dict[str, object]:
    """The fields ArduPilot's JSON backend reads from one line, as its parser reads them: a key is
    found by plain substring search (after its section's name), its value starts two characters
    after the key (the quote and the colon), a vector is read by sscanf("[%f, %f, %f]"). A field
    it would fail on raises ValueError naming it."""
    fields: dict[str, object] = {}
    for section, key in REQUIRED + OPTIONAL:
        start = line.find(section) if section else 0
        at = line.find(key, start + len(section) + (1 if section else 1))
        if at < 0 or start < 0:
            if (section, key) in REQUIRED:
                raise ValueError(f"missing {section}/{key}")
            continue
        value = line[at + len(key) + 2:]
        if key in ("gyro", "accel_body", "position", "velocity", "quaternion", "attitude"):
            count = 4 if key == "quaternion" else 3
            pattern = r"\[" + r",\s*".join([rf"\s*({_FLOAT})"] * count) + r"\]"
            match = re.match(pattern, value)
            if match is None:
                raise ValueError(f"cannot read {key} as {count} numbers from {value[:40]!r}")
            fields[key] = [float(v) for v in match.groups()]
        else:
            match = re.match(rf"\s*({_FLOAT})", value)
            if match is None:
                raise ValueError(f"cannot read {key} as a number from {value[:40]!r}")
            fields[key] = float(match.group(1))
    return fields


def junk_datagram(rng: random.Random, count: int) -> bytes:
    """A datagram that is no servo frame ArduPilot would send: noise, a frame cut short or too
    long, a wrong magic, a 32-channel frame with the 16-channel magic."""
    kind = rng.randrange(5)
    if kind == 0:
        return bytes(rng.randrange(256) for _ in range(rng.randrange(0, 120)))
    frame = FRAME.pack(MAGIC, 400, count, *([1500] * 16))
    if kind == 1:
        return frame[: rng.randrange(1, len(frame))]
    if kind == 2:
        return frame + bytes(rng.randrange(1, 30))
    if kind == 3:
        return struct.pack("<H", rng.choice([0, 1, 29569 + 1, 0xFFFF])) + frame[2:]
    return struct.pack("<HHI32H", MAGIC, 400, count, *([1500] * 32))


class Serial1:
    """SERIAL1 as a MAVLink UDP client: heartbeats out each simulated second, proximity messages in."""

    def __init__(self, port: int):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.target = ("127.0.0.1", port)
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.parser = mavlink.MAVLink(None)
        self.last_heartbeat_s: float | None = None
        self.seen: dict[str, object] = {"DISTANCE_SENSOR": 0, "OBSTACLE_DISTANCE": 0, "orientations": [], "first_t": None, "sources": []}

    def step(self, time_s: float) -> None:
        if self.last_heartbeat_s is None or time_s - self.last_heartbeat_s >= 1.0:
            self.last_heartbeat_s = time_s
            heartbeat = self.mav.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0)
            self.sock.sendto(heartbeat.pack(self.mav), self.target)
        while True:
            try:
                datagram = self.sock.recv(65536)
            except BlockingIOError:
                return
            for message in self.parser.parse_buffer(datagram) or []:
                kind = message.get_type()
                if kind not in ("DISTANCE_SENSOR", "OBSTACLE_DISTANCE"):
                    continue
                self.seen[kind] += 1
                self.seen["first_t"] = self.seen["first_t"] if self.seen["first_t"] is not None else time_s
                source = [message.get_srcSystem(), message.get_srcComponent()]
                if source not in self.seen["sources"]:
                    self.seen["sources"].append(source)
                if kind == "DISTANCE_SENSOR" and message.orientation not in self.seen["orientations"]:
                    self.seen["orientations"].append(message.orientation)


def _timestamp(line: bytes) -> float | None:
    try:
        return parse_like_ardupilot(line.decode())["timestamp"]
    except (ValueError, UnicodeDecodeError, KeyError):
        return None  # a bad line, judged as such where it is taken


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--frames", type=int, default=1000, help="stop after this many parsed lines")
    parser.add_argument("--pwm", type=int, default=1000)
    parser.add_argument("--junk", type=int, default=0, help="junk datagrams before each frame")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--ignore-every", type=int, default=0, help="act as if every Nth line was lost")
    parser.add_argument("--skip-every", type=int, default=0, help="jump the frame count by two every Nth frame")
    parser.add_argument("--restart-at", type=int, default=0, help="start the count again from 0 at this count")
    parser.add_argument("--resend-after-s", type=float, default=1.0, help="as ArduPilot: the same frame again after this long without a line")
    parser.add_argument("--quiet-after-s", type=float, default=3.0, help="give up when nothing comes for this long")
    parser.add_argument("--start-timeout-s", type=float, default=60.0, help="give up when the first line does not come for this long")
    parser.add_argument("--serial1-port", type=int, help="SERIAL1 as a MAVLink UDP client of this port: count the proximity messages")
    args = parser.parse_args()
    serial1 = Serial1(args.serial1_port) if args.serial1_port else None
    rng = random.Random(args.seed)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(args.resend_after_s)
    target = ("127.0.0.1", args.port)
    count, parsed, resent, ignored, duplicates, junk, bad_lines, ranges_seen = 0, 0, 0, 0, 0, 0, [], 0
    timestamps: list[float] = []

    def send_frame() -> None:
        sock.sendto(FRAME.pack(MAGIC, 400, count, *([args.pwm] * 4 + [0] * 12)), target)

    while parsed < args.frames:
        # None before the simulator has answered: it may not be listening yet, and what it never got it cannot count.
        for _ in range(args.junk if parsed else 0):
            sock.sendto(junk_datagram(rng, count), target)
            junk += 1
        send_frame()
        line, quiet_s, resends = None, 0.0, 0
        while line is None:
            try:
                datagram = sock.recv(65536)
            except socket.timeout:
                quiet_s += args.resend_after_s
                # Before its first line the simulator may still be starting: ArduPilot waits for it.
                if quiet_s >= (args.quiet_after_s if parsed else args.start_timeout_s):
                    break
                resends += parsed > 0  # ArduPilot's count moves on a parsed line only: the same frame again
                send_frame()
                continue
            if args.ignore_every and (parsed + 1) % args.ignore_every == 0 and ignored <= parsed // args.ignore_every:
                ignored += 1  # as if this line was lost on the way
                continue
            candidate = next((part for part in reversed(datagram.split(b"\n")) if part.strip()), b"")
            if timestamps and _timestamp(candidate) == timestamps[-1]:
                # The simulator's second answer to a frame sent again while its first was on the way
                # (a second's wait on a loaded machine), not this frame's answer.
                duplicates += 1
                continue
            line = candidate
        if line is None:
            break
        try:
            fields = parse_like_ardupilot(line.decode())
        except (ValueError, UnicodeDecodeError) as error:
            bad_lines.append(str(error))
            continue
        resent += resends  # those the simulator answered, not those after it stopped
        timestamps.append(fields["timestamp"])
        if serial1 is not None:
            serial1.step(fields["timestamp"])
        ranges_seen += any(key.startswith("rng_") for key in fields)
        parsed += 1
        count += 1
        if args.skip_every and parsed % args.skip_every == 0:
            count += 1
        if args.restart_at and count == args.restart_at:
            count = 0
    steps = [round((b - a) * 1e6) for a, b in zip(timestamps, timestamps[1:])]
    print(json.dumps({"parsed": parsed, "resent": resent, "ignored": ignored, "duplicates": duplicates, "junk": junk, "bad_lines": bad_lines[:5],
                      "step_us": sorted(set(steps)), "ranges_seen": ranges_seen, "first_t": timestamps[0] if timestamps else None,
                      **({"serial1": serial1.seen} if serial1 is not None else {})}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
