"""`stella sut check`: bring a SUT up against the bridge stage by stage and time each stage.

The stages are the ones an evaluation goes through before its flight: the SUT's process
starts, connects to the simulator, the lockstep runs, its API heartbeat reaches MAVSDK, every
health check passes, it arms, and it accepts a mission (mission drive) or, on the ground,
switches to Position mode when the simulated pilot's mode switch says so over the RC link
(pilot drive). Armability is judged as a flight judges it: by arming, asked again while the SUT
denies it for as long as a flight asks (evaluation.arm_retry_for: PX4's arming checks flicker
just after MAVSDK first reports it healthy), then disarmed at once; the check says how long
arming took. The first stage that fails ends the check and says why; nothing flies.
"""

from __future__ import annotations

import shutil
import time
from dataclasses import asdict, dataclass
from typing import Any, Callable

from mavsdk.plugins.telemetry import FlightMode

from harness.errors import InfrastructureError
from harness.flight import scratch
from harness.flight.bridge_control import BridgeControl
from harness.flight.evaluation import arm_retry_for, wait_booted
from harness.flight.results import RunOptions
from harness.flight.stack import Stack, simulation_stack
from harness.flight.mavsdk_session import mission_items
from harness.scenario.space import SearchSpace
from harness.scenario.world import world_spec
from sim_bridge.control import LockstepStarted, RcModeSlot, Run, Stop, SutConnected
from sim_bridge.pilot import SLOT_POSITION
import sut_adapter

STAGES = ("process started", "simulator connected", "lockstep running", "API heartbeat", "health ok", "armable")
LAST_STAGE = {"mission": "mission upload ok", "pilot": "position mode with stick input accepted"}


@dataclass
class Stage:
    name: str
    ok: bool | None  # None: not reached
    after_s: float | None = None
    detail: str = ""


def check(space: SearchSpace, x, options: RunOptions, timeout_s: float = 60.0) -> list[Stage]:
    system = sut_adapter.system_for(options.sut)
    world = world_spec(space, x, 0)
    workdir = scratch.folder("sut-check")
    stages = [Stage(name, None) for name in (*STAGES, LAST_STAGE[world.drive])]
    start = time.monotonic()
    try:
        with simulation_stack(world, options, system, workdir) as stack:
            _run_stages(stack, world, stages, start, timeout_s, arm_retry_for(system), system)
    except (InfrastructureError, sut_adapter.SutError) as error:
        failed = next((stage for stage in stages if stage.ok is None), stages[0])
        failed.ok, failed.after_s, failed.detail = False, time.monotonic() - start, str(error)
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    return stages


def _run_stages(stack: Stack, world, stages: list[Stage], start: float, timeout_s: float, arm_retry_s: float, system) -> None:
    pilot_params, _altitude_param, pilot_mode = system.capabilities.pilot_setup()
    sut, session = stack.sut, stack.session
    alive = lambda: stack.bridge.poll() is None and sut.alive()  # noqa: E731

    def passed(index: int, detail: str = "") -> None:
        stages[index].ok, stages[index].after_s, stages[index].detail = True, time.monotonic() - start, detail

    def failed(index: int, detail: str) -> None:
        if not sut.alive():
            detail += f"; {sut.how_it_ended()}"
        elif stack.bridge.poll() is not None:
            detail += f"; the simulator exited: {stack.bridge.stderr_tail()[-800:]}"
        stages[index].ok, stages[index].after_s, stages[index].detail = False, time.monotonic() - start, detail

    passed(0, f"pids {', '.join(map(str, sut.pids))}; simulator TCP {stack.ports.sim}, API UDP {stack.ports.api}")
    control = BridgeControl(stack.ports.control)
    try:
        for index, event, what in ((1, SutConnected, "the SUT never connected to the simulator"),
                                   (2, LockstepStarted, "the SUT never answered a sensor step with HIL_ACTUATOR_CONTROLS")):
            seen = control.wait_for(event, timeout_s, alive)
            if seen is None:
                return failed(index, f"{what} on TCP {stack.ports.sim} within {timeout_s:.0f} s")
            passed(index, f"at simulated t={seen.t:.3f} s")
        steps: list[tuple[int, str, Callable[[], Any]]] = [
            (3, "API heartbeat", lambda: session.discover(timeout_s, alive)),
            (4, "health ok", lambda: (wait_booted(sut, timeout_s, alive), session.set_params(sut.mavlink_params), session.wait_healthy(timeout_s))),
            (5, "armable", lambda: _arm_and_disarm(session, arm_retry_s)),
            (6, "mission upload ok", lambda: session.mission.upload_mission(mission_items(world, system.capabilities.mission_home_item))) if world.drive == "mission" else
            (6, "position mode with stick input accepted", lambda: _position_mode_by_stick(session, control, timeout_s, pilot_params, pilot_mode)),
        ]
        for index, _name, action in steps:
            try:
                outcome = action()
            except Exception as error:  # MAVSDK raises its own error type per plugin
                return failed(index, str(error))
            passed(index, outcome if index == 5 else _details(index, session, sut, world.drive, pilot_params))
    finally:
        control.send(Stop())
        control.close()


def _position_mode_by_stick(session, control: BridgeControl, timeout_s: float, pilot_params, pilot_mode: str) -> None:
    """With the pilot's RC layout set, the simulation running and the pilot's mode switch in its
    Position slot, the SUT must report Position mode (nothing is armed)."""
    session.set_params(pilot_params)
    control.send(Run())
    control.send(RcModeSlot(SLOT_POSITION))
    deadline = time.monotonic() + timeout_s
    mode = session.telemetry.flight_mode()
    while mode != FlightMode[pilot_mode]:
        if time.monotonic() > deadline:
            raise InfrastructureError(f"the SUT stayed in {mode.name} instead of switching to Position mode within {timeout_s:.0f} s; "
                                      f"status texts: {session.status_texts[-5:]}")
        time.sleep(0.05)
        mode = session.telemetry.flight_mode()


def _arm_and_disarm(session, retry_s: float) -> str:
    """Arm as a flight does, then disarm; what it took."""
    asked = time.monotonic()
    try:
        session.arm(retry_s)
    except Exception as error:  # MAVSDK's ActionError: denied for longer than a flight asks, or no answer
        raise InfrastructureError(f"arming refused ({error}) after {time.monotonic() - asked:.2f} s of asking, as long as a flight asks; "
                                  f"MAVSDK's health: {vars(session.telemetry.health())}; status texts: {session.status_texts[-5:]}") from None
    took_s = time.monotonic() - asked
    session.action.disarm()
    asks = f"a flight asks again for up to {retry_s:g} s" if retry_s else "held frozen, a flight asks once"
    return f"armed {took_s:.2f} s after asking ({asks}), then disarmed"


def _details(index: int, session, sut, drive: str, pilot_params) -> str:
    if index == 4:
        return f"parameters set over MAVLink: {dict(sut.mavlink_params)}" if sut.mavlink_params else ""
    if index == 6:
        return {"mission": "mission with takeoff, speed, waypoints and land accepted",
                "pilot": f"the pilot's RC with {pilot_params or 'its defaults'}; Position mode reported"}[drive]
    return ""


def report_text(sut: str, stages: list[Stage]) -> str:
    lines = [f"SUT {sut}:"]
    for stage in stages:
        mark = {True: "ok  ", False: "FAIL", None: "-   "}[stage.ok]
        when = f"{stage.after_s:7.2f} s" if stage.after_s is not None else "      -  "
        lines.append(f"  {mark} {stage.name:<40} {when}" + (f"  {stage.detail}" if stage.detail else ""))
    verdict = "every stage passed" if all(stage.ok for stage in stages) else "failed at " + next(s.name for s in stages if not s.ok)
    lines.append(verdict)
    return "\n".join(lines)


def as_dicts(stages: list[Stage]) -> list[dict[str, Any]]:
    return [asdict(stage) for stage in stages]
