"""The lockstep server around the simulated world (world.py): PX4's simulator protocol to the SUT.

Protocol (as PX4's simulator_mavlink expects it): the bridge listens on TCP, the SUT connects.
Every physics step the bridge sends HIL_SENSOR (time_usec drives the SUT's clock), about 10 Hz
HIL_GPS, 50 Hz HIL_STATE_QUATERNION (ground truth) and OBSTACLE_DISTANCE at the sensor's rate.
Until the SUT's first HIL_ACTUATOR_CONTROLS the bridge runs at real-time pace with the vehicle
resting on the ground; from then on it waits for one actuator answer per step (lockstep). A SUT
that answers every step from the first (the bundled autopilot) is in lockstep from step 0, so its
flight does not depend on how fast it came up; one whose answers carry the time_usec of the
HIL_SENSOR they answer (PX4, the bundled autopilot) has an answer that came a step late told
from the step's own, so a late first answer does not put the whole flight one step behind.

The control channel to the harness (sim_bridge/channel.py) carries the messages of
sim_bridge/control.py, whose docstring tells the protocol.

With the pilot drive (world "drive": "pilot") a simulated pilot (sim_bridge/pilot.py) flies the
route with RC_CHANNELS frames every 20 ms of simulated time, sent before HIL_SENSOR like the
other messages of a step; a pilot that makes no progress for 20 s ends the run ("blocked").

Run time t_run starts at "run" (or at the first step when there is no hold); dynamic obstacles
move and the time limit counts in run time, so the flight is independent of how long the
harness took to set up.
"""

from __future__ import annotations

import logging
import socket
import time
from typing import Any, Mapping

from pymavlink.dialects.v20 import common as mavlink

from sim_bridge.ardupilot_link import JsonSteps
from sim_bridge.bridge_io import BridgeConfig, Summary
from sim_bridge.channel import ControlChannel
from sim_bridge.companion import CompanionLink
from sim_bridge.control import (STEP_TIMERS, EndReason, Event, FailureInjected, Holding, InjectFailure, LockstepStarted, ObstacleOp, Op, RcModeSlot,
                                Rejected, Run, Stop, SutConnected)
from sim_bridge.failures import FailureSchedule
from sim_bridge.frames import SensorFrames
from sim_bridge.pilot import RC_PERIOD_S
from sim_bridge.recording import COMPANION_TOPIC, Recorder, enu, enu_flu_orientation, path_entity, scene_entity, stamp, terrain_entity
from sim_bridge.spec import WorldSpec
from sim_bridge.sut_link import SutLink
from sim_bridge.world import World
from simlink import codec

log = logging.getLogger(__name__)

RECORD_EVERY_S = 0.04
SCENE_EVERY_S = 0.1
LINK_FLUSH_EVERY_S = 0.1
# Simulation milestones the harness hears of on the control channel as well (`stella sut check`).
FORWARDED_EVENTS = {"sut_connected": SutConnected, "lockstep_started": LockstepStarted}
_CRC_EXTRAS = {msgid: cls.crc_extra for msgid, cls in mavlink.mavlink_map.items()}


class Bridge:
    """The server around the world (sim_bridge/world.py): PX4's simulator protocol to the SUT in
    lockstep, the hold while the harness sets up, the control channel, and the MCAP recording."""

    def __init__(self, world: WorldSpec, config: BridgeConfig, recorder: Recorder):
        self.config = config
        self.recorder = recorder
        self.summary = Summary()
        self._control: ControlChannel | None = None
        self.world = World(world, config.rate_hz, on_event=self._event, on_obstacles_changed=self._obstacles_changed)
        self._every = {
            "gps": max(1, round(config.rate_hz / config.gps_rate_hz)),
            "truth": max(1, round(config.rate_hz / config.ground_truth_rate_hz)),
            "sensor": max(1, round(config.rate_hz / world.sensor.update_hz)),
            "record": max(1, round(RECORD_EVERY_S * config.rate_hz)),
            "scene": max(1, round(SCENE_EVERY_S * config.rate_hz)),
            "flush": max(1, round(LINK_FLUSH_EVERY_S * config.rate_hz)),
            "control": max(1, round(0.05 * config.rate_hz)),
        }
        if self.world.pilot is not None:
            self._every["rc"] = max(1, round(RC_PERIOD_S * config.rate_hz))
        self._link_out = bytearray()
        self._link_in = bytearray()
        self._clearance_batch: tuple[list, list, list, list] = ([], [], [], [])
        self._hold_deadline: float | None = None
        self._hold_announced = False
        self.failures = FailureSchedule(world.failures or (), lambda event, detail: self._event(self.world.time_s, event, detail))
        self.frames = SensorFrames(self.world, config.range_messages, recorder, self.failures, self._every,
                                   config.companion_messages if config.companion_port is not None else (), config.distance_sensor_convention)
        self._link_companion = bytearray()
        # Where a rig's messages go that the SUT does not read on the simulator link.
        self._companion: CompanionLink | None = None
        if config.companion_port is not None and any(s.message in config.companion_messages for s in world.rig or ()):
            self._companion = CompanionLink(config.companion_port, sut_connects=config.companion_connects)
        self._awaiting_injection: dict[str, Any] | None = None
        self._json: JsonSteps | None = None  # the exchange with an ArduPilot (protocol "ardupilot-json")

    # -- recording ---------------------------------------------------------------------------

    def _event(self, time_s: float, event: str, detail: Mapping[str, Any] | None = None) -> None:
        detail = dict(detail or {})
        log.info("t=%.3f %s %s", time_s, event, detail)
        self.recorder.write("/events", time_ns=int(time_s * 1e9), message={"t": time_s, "event": event, "detail": detail})
        if event in FORWARDED_EVENTS and self._control is not None:
            self._control.send(FORWARDED_EVENTS[event](t=time_s, **detail))

    def _obstacles_changed(self, time_s: float, removed_id: str | None) -> None:
        time_ns = int(time_s * 1e9)
        if removed_id is not None:
            deletions = [{"timestamp": stamp(time_ns), "type": 1, "id": entity} for entity in (removed_id, f"{removed_id}/path")]
            self.recorder.write("/scene", time_ns=time_ns, message={"deletions": deletions, "entities": []})
        self._record_scene(time_ns, everything=True)

    def _record_scene(self, time_ns: int, everything: bool) -> None:
        entities = [scene_entity(o, time_ns) for o in self.world.field.obstacles if everything or o.moving]
        if everything:
            entities += [path for path in (path_entity(o, time_ns) for o in self.world.field.obstacles) if path is not None]
            entities.append(terrain_entity(self.world.terrain, self.world.water))
        if entities:
            self.recorder.write("/scene", time_ns=time_ns, message={"deletions": [], "entities": entities})

    def _record_pose(self, time_ns: int) -> None:
        s = self.world.state
        position = enu(s.north_m, s.east_m, s.up_m)
        orientation = enu_flu_orientation(s.roll_rad, s.pitch_rad, s.yaw_rad)
        self.recorder.write(
            "/tf",
            time_ns=time_ns,
            message={"timestamp": stamp(time_ns), "parent_frame_id": "world", "child_frame_id": "uav", "translation": position, "rotation": orientation},
        )
        self.recorder.write("/uav/pose", time_ns=time_ns, message={"timestamp": stamp(time_ns), "frame_id": "world", "pose": {"position": position, "orientation": orientation}})
        self.recorder.write("/uav/fix", time_ns=time_ns, message={"timestamp": stamp(time_ns), "frame_id": "uav", "latitude": s.lat_deg, "longitude": s.lon_deg,
                                                               "altitude": s.alt_msl_m, "position_covariance_type": 0})
        self.recorder.write(
            "/uav/state",
            time_ns=time_ns,
            message={
                "t": time_ns / 1e9,
                "north_m": s.north_m,
                "east_m": s.east_m,
                "up_m": s.up_m,
                "v_ned_m_s": [s.v_north_m_s, s.v_east_m_s, s.v_down_m_s],
                "rpy_rad": [s.roll_rad, s.pitch_rad, s.yaw_rad],
                "motors": list(self.world.motors),
                "agl_m": s.agl_m,
            },
        )

    def _flush_clearance(self) -> None:
        """One /clearance message per batch of physics steps: every step's value, few MCAP records."""
        times, distances, obstacles, heights = self._clearance_batch
        if times:
            self.recorder.write("/clearance", time_ns=int(round(times[0] * 1e9)), message={"t": times, "d": distances, "o": obstacles, "g": heights})
            self._clearance_batch = ([], [], [], [])

    def _flush_link(self, time_ns: int) -> None:
        for direction, buffer in (("to_sut", self._link_out), ("from_sut", self._link_in)):
            if buffer:
                self.recorder.write("/mavlink/sim", time_ns=time_ns, message={"link": "sim", "direction": direction, "hex": buffer.hex()})
                buffer.clear()
        if self._link_companion:
            self.recorder.write(COMPANION_TOPIC, time_ns=time_ns, message={"link": "companion", "direction": "to_sut", "hex": self._link_companion.hex()})
            self._link_companion.clear()

    def _observe(self, step: int) -> None:
        """Score and record the state after `step` physics steps: the UAV's clearance to the
        nearest obstacle, and at their rates its pose, the moving obstacles and the link traffic."""
        every = self._every
        time_s = step * self.world.dt
        distance, obstacle = self.world.clearance()
        time_ns = int(round(time_s * 1e9))
        batch = self._clearance_batch
        batch[0].append(time_s)
        batch[1].append(distance)
        batch[2].append(obstacle)
        batch[3].append(self.world.state.agl_m)
        if step % every["record"] == 0:
            self._record_pose(time_ns)
            if self.world.wind_field.varies:
                self.recorder.write("/wind", time_ns=time_ns, message={"t": time_s, "wind_ned_m_s": list(self.world.wind_now)})
        if step % every["scene"] == 0:
            self._record_scene(time_ns, everything=False)
        if step % every["flush"] == 0:
            self._flush_link(time_ns)
            self._flush_clearance()

    # -- the control channel -----------------------------------------------------------------

    def _serve_control(self, control: ControlChannel, time_s: float, timeout_s: float = 0.0, wake: socket.socket | None = None) -> None:
        """Carry out the harness's ops. A harness that hung up mid-flight is dead (its death
        signal normally stops us first, but may never come: killed while starting us); flying on,
        or holding for it up to the hold timeout, would keep a campaign's ports and core."""
        self._handle_ops(control.poll(timeout_s, wake=wake), time_s)
        if control.hung_up:
            self.world.end(EndReason.HARNESS_GONE)

    def _handle_ops(self, ops: list[Op], time_s: float) -> None:
        for op in ops:
            if isinstance(op, Run):
                self.world.start_run(time_s)
            elif isinstance(op, Stop):
                self.world.end(EndReason.STOPPED)
            elif isinstance(op, RcModeSlot):
                self.world.forced_slot = int(op.slot)
            elif isinstance(op, FailureInjected):
                self._injected(str(op.result), time_s)
            elif isinstance(op, ObstacleOp) and op.at_s is not None:
                self.world.schedule(op)
            elif isinstance(op, ObstacleOp):
                self.world.apply(op, time_s)
            elif isinstance(op, Rejected) and op.name is not None:
                self._event(time_s, "injection_rejected", {"reason": op.why})
            else:  # not JSON, or an op for a serving simulator between flights
                log.warning("ignoring control message %r", op)

    # -- failures told to the SUT -------------------------------------------------------------

    def _ask_for_injection(self, sut: SutLink, splitter: codec.FrameSplitter, control: ControlChannel, time_s: float) -> None:
        """Each MAV_CMD_INJECT_FAILURE now due, through the harness: frozen, wait for its answer
        here; paced, the loop runs on at real-time pace until it comes."""
        while self._awaiting_injection is None and self.world.running:
            due = self.failures.command_due(self.frames.run_time())
            if due is None:
                return
            spec, kind = due
            request = {"unit": spec.unit, "type": kind, "failure": spec.type, "duration_s": spec.duration_s}
            if not control.connected:
                self._event(time_s, "failure_undelivered", {**request, "reason": "no harness on the control channel"})
                continue
            self._awaiting_injection = request
            control.send(InjectFailure(t=time_s, unit=spec.unit, type=kind))
            if self.config.hold_mode != "paced":
                self._frozen_until(lambda: self._awaiting_injection is None, sut, splitter, control, time_s)

    def _injected(self, result: str, time_s: float) -> None:
        request = self._awaiting_injection
        if request is None:
            return
        self._awaiting_injection = None
        # A SUT that refuses (PX4 without SYS_FAILURE_EN, an unsupported unit) flies on unfailed.
        event = "failure_refused" if result != "SUCCESS" else "failure_cleared" if request["type"] == "ok" else "failure"
        detail = {"unit": request["unit"], "type": request["failure"], "delivery": "sut", "result": result}
        if request["type"] != "ok":
            detail["duration_s"] = request["duration_s"]
        self._event(time_s, event, detail)

    # -- the loop ----------------------------------------------------------------------------

    def _receive_answer(self, sut: SutLink, splitter: codec.FrameSplitter, lockstep: bool, time_us: int, waiting_since: float) -> bool:
        """Read the SUT until the HIL_ACTUATOR_CONTROLS of the step at time_us (lockstep), or for
        one step at most (before it); whether the answer came. Ends the world's run if the SUT
        went away, stalled or floods without answering.

        With answer_times_echoed, an answer to an earlier step is late and not this step's: one
        step's answer that misses the real-time pace before lockstep would otherwise be taken for
        the next step's, and every later one too. It also says that the SUT answers, so the
        bridge waits for this step's answer from then on."""
        world = self.world
        echoed = self.config.answer_times_echoed
        while True:
            try:
                if not lockstep and not sut.readable(world.dt):
                    return False
                data = sut.receive(self.config.spin_s if lockstep else 0.0)
            except BlockingIOError:
                world.end(EndReason.SUT_STALLED)
                return False
            except OSError:
                world.end(EndReason.SUT_DISCONNECTED)
                return False
            if not data:
                world.end(EndReason.SUT_DISCONNECTED)
                return False
            self._link_in += data
            answered = False
            for msgid, payload, _frame in splitter.feed(data):
                if msgid == codec.HIL_ACTUATOR_CONTROLS_ID:
                    answer_time_us, _flags, controls, _mode = codec.decode_hil_actuator_controls(payload)
                    if echoed and answer_time_us < time_us:
                        self._late_answer(answer_time_us, time_us)
                        lockstep = True
                        continue
                    world.motors = controls[:4]
                    answered = True
            if answered:
                return True
            if not lockstep:
                return False  # before lockstep the step goes on at real-time pace, answered or not
            if time.perf_counter() - waiting_since > self.config.stall_timeout_s:
                # Bytes keep coming but no answer among them: a flood stalls a step as silence does.
                world.end(EndReason.SUT_STALLED)
                return False

    def _late_answer(self, answer_time_us: int, time_us: int) -> None:
        """Counted; the first said in the log, as a SUT declared to echo the step's time that does
        not (time_usec 0, its own clock) has every answer skipped and stalls."""
        self.summary.late_answers += 1
        if self.summary.late_answers == 1:
            log.warning("an answer for the step at %d us came in the step at %d us and was skipped (a SUT whose answers do not carry "
                        "the time_usec of the HIL_SENSOR they answer must not be declared echoes_step_time)", answer_time_us, time_us)

    def run(self, sut: SutLink, control: ControlChannel) -> Summary:
        summary = self.summary
        world = self.world
        config = self.config
        self._control = control
        splitter = codec.FrameSplitter(_CRC_EXTRAS)
        if config.protocol == "ardupilot-json":
            self._json = JsonSteps(world, config, self.frames, self._every, self._event, self._link_in, sut, getattr(sut, "first", None))
        json_steps = self._json
        wall_start = time.perf_counter()
        perf = time.perf_counter
        hold_enabled = config.hold_after_s > 0
        if not hold_enabled:
            world.run_start_s = 0.0
        paced_hold = config.hold_mode == "paced"
        lockstep = False
        self._record_scene(0, everything=True)
        self._event(0.0, "sut_connected")
        wall_run_started = None
        setup_timers: dict[str, float] = {}
        # The step just simulated is scored and recorded, and the obstacles moved on to the next
        # step's time, after the next sensor messages went out, while the SUT computes its answer:
        # on two cores this work costs the step nothing.
        unobserved_step: int | None = None
        while world.running:
            step = world.steps
            time_us = step * world.dt_us
            time_s = time_us / 1e6
            holding = hold_enabled and world.run_start_s is None and time_s >= config.hold_after_s
            if holding and not paced_hold:
                self._hold(sut, splitter, control, time_s)
                if not world.running:
                    break
                holding = False
            elif holding:
                self._paced_hold(control, time_s)
                if not world.running:
                    break
            if world.run_start_s is not None and self._awaiting_injection is None:
                self._ask_for_injection(sut, splitter, control, time_s)
                if not world.running:
                    break
            if wall_run_started is None and hold_enabled and world.run_start_s is not None:
                wall_run_started = perf()
                # Step timers count the run only: before it the loop runs at real-time pace.
                setup_timers = {name: getattr(summary, name) for name in STEP_TIMERS}
            ts = perf()
            frames_out = self.frames.step_frames(step, time_us) if json_steps is None else json_steps.state(step, time_us)
            t_send = perf()
            summary.sensors_s += t_send - ts
            if self._companion is not None and self.frames.companion_out:
                self._send_companion(self.frames.companion_out)
            try:
                sut.send(frames_out)
            except OSError:
                world.end(EndReason.SUT_DISCONNECTED)
                break
            self._link_out += frames_out
            t_sent = perf()
            summary.send_s += t_sent - t_send
            if unobserved_step is not None:
                self._observe(unobserved_step)
                unobserved_step = None
            world.move_obstacles_for_next_step()
            t0 = perf()
            summary.observe_s += t0 - t_sent
            if json_steps is None:
                answered = self._receive_answer(sut, splitter, lockstep or config.lockstep_from_start, time_us, t0)
            else:
                # ArduPilot waits for the answer to each of its servo frames, the first included:
                # its link is in lockstep from the frame that opened it, one step per frame.
                answered = json_steps.receive_answer(sut, t0)
            if not world.running:
                break
            if answered and not lockstep:
                lockstep = True
                self._event(time_s, "lockstep_started", {"step": step})
            t1 = perf()
            summary.wait_s += t1 - t0
            world.step(world.motors if lockstep else (0.0, 0.0, 0.0, 0.0))
            t2 = perf()
            summary.physics_s += t2 - t1
            if world.steps % self._every["control"] == 0 or self._awaiting_injection is not None:
                self._serve_control(control, world.time_s)
            world.check_end()
            unobserved_step = world.steps
            summary.world_s += perf() - t2
            if not lockstep or self._awaiting_injection is not None:
                time.sleep(max(0.0, world.dt - (perf() - t_sent)))
            elif holding:
                time.sleep(max(0.0, world.dt / config.hold_pace - (perf() - t_sent)))
        if unobserved_step is not None:
            self._observe(unobserved_step)
        return self._finished(splitter, started_s=wall_start, run_started_s=wall_run_started, setup_timers=setup_timers)

    def _send_companion(self, frames: list[bytes]) -> None:
        """This step's companion frames, before the step's simulator frames: PX4 stamps a reading
        with its clock when its MAVLink thread reads it, which the next HIL_SENSOR moves on."""
        self._link_companion += self._companion.send(frames)

    def close(self) -> None:
        if self._companion is not None:
            self._companion.close()

    def _finished(self, splitter: codec.FrameSplitter, *, started_s: float, run_started_s: float | None, setup_timers: dict[str, float]) -> Summary:
        """The run's summary once its loop ended: outcome, counts and times (the step timers of
        the run alone where it held for set-up), with the last of the link and clearance recorded."""
        world, summary, json_steps = self.world, self.summary, self._json
        self.settle_outcome()
        summary.steps = world.steps
        summary.sim_time_s = world.steps * world.dt
        summary.run_time_s = world.run_time(summary.sim_time_s)
        summary.bad_frames = splitter.bad_frames + (json_steps.bad_frames if json_steps is not None else 0)
        summary.skipped_bytes = splitter.skipped_bytes + (json_steps.skipped_bytes if json_steps is not None else 0)
        summary.wall_time_s = time.perf_counter() - started_s
        if run_started_s is not None:
            summary.wall_in_run_s = time.perf_counter() - run_started_s
            for name, before in setup_timers.items():
                setattr(summary, name, getattr(summary, name) - before)
        self._flush_link(int(summary.sim_time_s * 1e9))
        self._flush_clearance()
        self._event(summary.sim_time_s, "finished", {"reason": summary.end_reason})
        return summary

    def settle_outcome(self) -> None:
        """The world's outcome into the summary: at the end of the run, or where it was interrupted."""
        world, summary = self.world, self.summary
        summary.end_reason = world.end_reason
        summary.airborne = world.airborne
        summary.touchdown = world.touchdown
        summary.first_touchdown_s = world.first_touchdown_s
        summary.injections = world.injections

    def _paced_hold(self, control: ControlChannel, time_s: float) -> None:
        """One step of a paced hold: announce it once the harness listens, give up after the timeout."""
        if self._hold_deadline is None:
            self._event(time_s, "holding")
            self._hold_deadline = time.monotonic() + self.config.hold_timeout_s
        if not self._hold_announced and control.connected:
            control.send(Holding(t=time_s))
            self._hold_announced = True
        if time.monotonic() > self._hold_deadline:
            self.world.end(EndReason.HOLD_TIMEOUT)

    def _hold(self, sut: SutLink, splitter: codec.FrameSplitter, control: ControlChannel, time_s: float) -> None:
        """Pause the simulation until the harness says run; keep reading what the SUT sends."""
        self._event(time_s, "holding")
        self._frozen_until(lambda: self.world.run_start_s is not None, sut, splitter, control, time_s, announce=Holding(t=time_s))

    def _frozen_until(self, done, sut: SutLink, splitter: codec.FrameSplitter, control: ControlChannel, time_s: float,
                      announce: Event | None = None) -> None:
        """Simulated time stands still until done() (the harness's ops are handled meanwhile) or
        the hold timeout; the SUT's traffic is read so that it never blocks on a full socket."""
        world = self.world
        deadline = time.monotonic() + self.config.hold_timeout_s
        while not done() and world.running:
            if announce is not None and control.connected:
                control.send(announce)
                announce = None
            if time.monotonic() > deadline:
                world.end(EndReason.HOLD_TIMEOUT)
                return
            try:
                data = sut.idle()
            except OSError:
                world.end(EndReason.SUT_DISCONNECTED)
                return
            if data:
                self._link_in += data
                splitter.feed(data)
            self._serve_control(control, time_s, 0.01, sut.waitable())
