"""The world's injected failures over run time (simlink/failures.py defines what each type means).

Readings the simulator owns (the distance sensor's, the GPS's) fail here, on their way to the
SUT, as PX4's simulator fails its own sensors. The others are commands to the SUT: the bridge
stops at each onset and end, the harness sends MAV_CMD_INJECT_FAILURE (type ok at the end), and
the flight goes on once the SUT has answered (sim_bridge/bridge.py, the control channel).
"""

from __future__ import annotations

from typing import Any, Callable

from sim_bridge.spec import FailureSpec
from simlink.failures import TYPE_BY_NAME, Failure


class FailureSchedule:
    def __init__(self, failures: tuple[FailureSpec, ...], on_event: Callable[[str, dict[str, Any]], None]):
        self._on_event = on_event
        # By unit, and for a rig's range sensors by unit/sensor where a failure names one.
        self._owned = {f.unit if f.sensor is None else f"{f.unit}/{f.sensor}": f for f in failures if f.delivery == "simulator"}
        self._owned_units = {f.unit for f in failures if f.delivery == "simulator"}
        self._active: dict[str, Failure] = {}
        self._cleared: set[str] = set()
        self._last: dict[str, Any] = {}
        commands = [(f.onset_s, f, f.type) for f in failures if f.delivery == "sut"]
        commands += [(f.onset_s + f.duration_s, f, "ok") for f in failures if f.delivery == "sut"]
        self._commands = sorted(commands, key=lambda command: command[0])

    def owns(self, unit: str) -> bool:
        return unit in self._owned_units

    def reading(self, unit: str, run_time_s: float | None, reading: Any, wrong: Callable[[Any], Any], instance: str | None = None) -> Any | None:
        """What the SUT receives of a reading of a unit the simulator owns at a run time (None
        before the run): the reading itself, its failed form, or None when nothing is sent. A unit
        of several instances (a rig's range sensors) fails in each, from each one's last reading."""
        key = unit if instance is None else f"{unit}/{instance}"
        spec = self._owned.get(key) or self._owned.get(unit)
        if spec is None:  # a failure of another of the rig's sensors
            return reading
        named = {} if instance is None else {"sensor": instance}
        if run_time_s is None or run_time_s < spec.onset_s or key in self._cleared:
            self._last[key] = reading
            return reading
        if run_time_s >= spec.onset_s + spec.duration_s:
            self._cleared.add(key)
            self._active.pop(key, None)
            self._on_event("failure_cleared", {"unit": unit, "type": spec.type, "delivery": "simulator", **named})
            return reading
        failure = self._active.get(key)
        if failure is None:
            failure = self._active[key] = Failure(TYPE_BY_NAME[spec.type], onset_s=spec.onset_s, last_reading=self._last.get(key), wrong=wrong)
            self._on_event("failure", {"unit": unit, "type": spec.type, "delivery": "simulator", "duration_s": spec.duration_s, **named})
        return failure.apply(run_time_s, reading)

    def command_due(self, run_time_s: float | None) -> tuple[FailureSpec, str] | None:
        """The next MAV_CMD_INJECT_FAILURE due by this run time: its failure and the type to send
        (the failure's, or "ok" at its end); taken off the schedule."""
        if run_time_s is None or not self._commands or self._commands[0][0] > run_time_s:
            return None
        _at, spec, kind = self._commands.pop(0)
        return spec, kind
