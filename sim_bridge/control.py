"""The control channel between the harness and the simulator: its messages, typed, and how a
flight ends. Both ends import this module; the wire stays newline-delimited JSON, one object a
line, `{"op": NAME, ...fields}` from the harness and `{"event": NAME, ...fields}` from the
simulator, so a client in any language can speak it. A field left None is left out on the
wire; a field the wire leaves out is None.

The protocol (over TCP, one client, the harness; the messages below name their records):
  bridge -> harness: {"event": "loaded"} once the flight's recording is open, before the SUT
      connects; {"event": "sut_connected", "t": 0.0} and {"event": "lockstep_started",
      "t": ..., "step": N} as they happen; {"event": "holding", "t": ...} once `hold_after_s` of
      simulation have passed: the harness can now connect, upload and arm while simulated time
      stands still (hold mode "frozen") or runs on at `hold_pace` times real time (hold mode
      "paced", for SUTs whose threads follow the lockstep clock); {"event": "finished",
      ...summary} at the end. Messages sent before the harness connects wait for it.
  harness -> bridge: {"op": "run"} ends the hold; {"op": "stop"} ends the run;
      {"op": "add_obstacle", "obstacle": {...world-spec obstacle...}, "at_s": T};
      {"op": "move_obstacle", "id": ID, "a": {...}, "b": {...} | null, "speed_m_s": V, "at_s": T};
      {"op": "remove_obstacle", "id": ID, "at_s": T}. `at_s` is run time (simulation seconds
      since "run"); without it the change applies at the next step.
      {"op": "rc_mode_slot", "slot": N}: with the pilot drive, hold the pilot's mode switch in
      slot N from now on (`stella sut check` asks a SUT on the ground for Position mode so).
      A harness that hangs up before "finished" is gone: the run ends ("harness_gone").
  Serving (`--serve`): each harness connection starts with
      {"op": "load", "world": PATH, "mcap": PATH} and ends after {"event": "finished"}, which
      then also means the MCAP file is complete ({"event": "load_refused", "why": ...} for a
      world that does not load); {"op": "quit"} ends the process. The world is flown with a
      fresh SUT: inside the bridge's process, or the next one to connect to the simulator port,
      whose link the bridge keeps open after "finished" until that SUT hangs up (at most
      --linger-s).
  Failures the SUT is to be told of (world "failures" with delivery "sut"): at each onset and
      end the bridge sends {"event": "inject_failure", "unit": U, "type": T (or "ok" at the
      end), "t": ...} and waits, simulated time frozen (hold mode "frozen") or paced, until the
      harness answers {"op": "failure_injected", "result": R} with the SUT's answer to
      MAV_CMD_INJECT_FAILURE; /events records it ("failure" or "failure_cleared").
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, ClassVar, Mapping


# The simulator's exit code when a flight ended otherwise than normally: its SUT never connected,
# stalled or went away, the hold timed out, the harness went, or SIGTERM came as the recording
# was being finished. A simulator that failed itself exits otherwise (a Python error: 1).
EXIT_CUT_SHORT = 3


class EndReason(StrEnum):
    """Why a flight ended (the simulator's summary, "end_reason"). A str, so it is its own JSON."""

    RUNNING = "running"  # not ended yet
    # The flight's own ends: the world says how it went.
    LANDED = "landed"
    TIME_LIMIT = "time_limit"
    STOPPED = "stopped"  # the harness said stop
    CRASHED = "crashed"
    BLOCKED = "blocked"  # the pilot made no progress
    # The simulator's or the SUT's failure: the flight says nothing about the SUT's safety.
    SUT_NEVER_CONNECTED = "sut_never_connected"
    SUT_DISCONNECTED = "sut_disconnected"
    SUT_STALLED = "sut_stalled"
    HOLD_TIMEOUT = "hold_timeout"
    HARNESS_GONE = "harness_gone"
    INTERRUPTED = "interrupted"

    @property
    def normal(self) -> bool:
        """Whether the flight ended on its own, as opposed to the simulator's or the SUT's failure."""
        return self in NORMAL_ENDS

    @property
    def sut_lost(self) -> bool:
        """Whether the SUT went away or stopped answering mid-flight (the harness scores it sut_crashed)."""
        return self in (EndReason.SUT_DISCONNECTED, EndReason.SUT_STALLED)


NORMAL_ENDS = frozenset({EndReason.LANDED, EndReason.TIME_LIMIT, EndReason.STOPPED, EndReason.CRASHED, EndReason.BLOCKED})


class ControlError(ValueError):
    """A control line that is no message of this protocol."""


@dataclass(frozen=True)
class _Message:
    KEY: ClassVar[str]  # "op" or "event"
    NAME: ClassVar[str]

    def as_dict(self) -> dict[str, Any]:
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        return {self.KEY: self.NAME, **{key: value for key, value in fields.items() if value is not None}}

    def encode(self) -> bytes:
        return json.dumps(self.as_dict()).encode() + b"\n"

    @classmethod
    def from_dict(cls, document: Mapping[str, Any]):
        names = {f.name for f in dataclasses.fields(cls)}
        try:
            return cls(**{key: value for key, value in document.items() if key in names})
        except TypeError as error:  # a field it must have is missing
            raise ControlError(f"{cls.KEY} {cls.NAME!r}: {error}") from None


# -- harness -> simulator ---------------------------------------------------------------------


@dataclass(frozen=True)
class Op(_Message):
    KEY = "op"


@dataclass(frozen=True)
class Run(Op):
    """Ends the hold: run time starts."""

    NAME = "run"


@dataclass(frozen=True)
class Stop(Op):
    NAME = "stop"


@dataclass(frozen=True)
class ObstacleOp(Op):
    """A change to the world's obstacles at run time at_s (None: at the next step)."""

    at_s: float | None = field(default=None, kw_only=True)


@dataclass(frozen=True)
class AddObstacle(ObstacleOp):
    NAME = "add_obstacle"
    obstacle: Mapping[str, Any]  # a world spec's obstacle


@dataclass(frozen=True)
class MoveObstacle(ObstacleOp):
    """The obstacle `id` now moves from a to b (None: stands at a) at speed_m_s."""

    NAME = "move_obstacle"
    id: str
    a: Mapping[str, float]
    b: Mapping[str, float] | None = None
    speed_m_s: float | None = None
    yaw_rad: float | None = None  # None: as it was


@dataclass(frozen=True)
class RemoveObstacle(ObstacleOp):
    NAME = "remove_obstacle"
    id: str


@dataclass(frozen=True)
class RcModeSlot(Op):
    """With the pilot drive: hold the pilot's mode switch in this slot from now on."""

    NAME = "rc_mode_slot"
    slot: int


@dataclass(frozen=True)
class FailureInjected(Op):
    """The SUT's answer to the MAV_CMD_INJECT_FAILURE that an InjectFailure event asked for."""

    NAME = "failure_injected"
    result: str


@dataclass(frozen=True)
class Load(Op):
    """To a serving simulator (--serve): fly this world, recording to this MCAP file."""

    NAME = "load"
    world: str
    mcap: str


@dataclass(frozen=True)
class Quit(Op):
    """To a serving simulator: end the process."""

    NAME = "quit"


@dataclass(frozen=True)
class Rejected(Op):
    """What the simulator makes of a line that is no op it knows: `name` as the line gave it."""

    NAME = "rejected"
    name: Any
    why: str


# -- simulator -> harness ---------------------------------------------------------------------


@dataclass(frozen=True)
class Event(_Message):
    KEY = "event"


@dataclass(frozen=True)
class Loaded(Event):
    """The flight's recording is open: however the flight ends from here, its file will be
    complete (a serving simulator stopped before this had not begun the flight)."""

    NAME = "loaded"


@dataclass(frozen=True)
class SutConnected(Event):
    NAME = "sut_connected"
    t: float


@dataclass(frozen=True)
class LockstepStarted(Event):
    NAME = "lockstep_started"
    t: float
    step: int


@dataclass(frozen=True)
class Holding(Event):
    """Simulated time holds (or runs paced) until Run: the harness sets the SUT up now."""

    NAME = "holding"
    t: float


@dataclass(frozen=True)
class InjectFailure(Event):
    """Tell the SUT of a failure (type "ok": of its end) and answer with FailureInjected."""

    NAME = "inject_failure"
    t: float
    unit: str
    type: str


# The summary's timers of a lockstep step's parts, over the run (before it the loop runs at
# real-time pace): sensor messages, sending them, scoring and recording while the SUT computes,
# waiting for its answer, JSBSim, the rest of the step.
STEP_TIMERS = ("sensors_s", "send_s", "observe_s", "wait_s", "physics_s", "world_s")


@dataclass(frozen=True)
class Finished(Event):
    """The flight's end, its recording complete: the simulator's summary (its end_reason an EndReason)."""

    NAME = "finished"
    summary: Mapping[str, Any]

    def as_dict(self) -> dict[str, Any]:
        return {self.KEY: self.NAME, **self.summary}

    @classmethod
    def from_dict(cls, document: Mapping[str, Any]) -> "Finished":
        summary = {key: value for key, value in document.items() if key != cls.KEY}
        if "end_reason" in summary:
            summary["end_reason"] = end_reason(summary["end_reason"])
        return cls(summary)

    @property
    def end_reason(self) -> EndReason | None:
        return self.summary.get("end_reason")


@dataclass(frozen=True)
class LoadRefused(Event):
    NAME = "load_refused"
    why: str


OPS: dict[str, type[Op]] = {cls.NAME: cls for cls in (Run, Stop, AddObstacle, MoveObstacle, RemoveObstacle, RcModeSlot, FailureInjected, Load, Quit)}
EVENTS: dict[str, type[Event]] = {cls.NAME: cls for cls in (Loaded, SutConnected, LockstepStarted, Holding, InjectFailure, Finished, LoadRefused)}


def end_reason(value: str) -> EndReason:
    try:
        return EndReason(value)
    except ValueError:
        raise ControlError(f"end_reason {value!r} is none of {', '.join(EndReason)}") from None


def decode_op(line: bytes | str) -> Op:
    """The op a line carries; one the simulator does not know, or cannot read, as Rejected."""
    try:
        document = json.loads(line)
    except json.JSONDecodeError:
        return Rejected(None, f"not JSON: {line[:80]!r}")
    if not isinstance(document, dict):
        return Rejected(None, f"not a JSON object: {line[:80]!r}")
    kind = OPS.get(document.get("op"))
    if kind is None:
        return Rejected(document.get("op"), f"unknown op {document.get('op')!r}")
    try:
        return kind.from_dict(document)
    except ControlError as error:
        return Rejected(kind.NAME, str(error))


def decode_event(line: bytes | str) -> Event:
    """The event a line carries (ControlError: none this harness knows)."""
    try:
        document = json.loads(line)
    except json.JSONDecodeError:
        raise ControlError(f"not JSON: {line[:80]!r}") from None
    kind = EVENTS.get(document.get("event")) if isinstance(document, dict) else None
    if kind is None:
        raise ControlError(f"no event this harness knows: {line[:80]!r}")
    return kind.from_dict(document)
