"""What the lockstep server (sim_bridge/bridge.py) is told and what it reports: its settings
(BridgeConfig, from the command line) and its run's summary (Summary, the harness's `Finished`
message and the log's `bridge_summary`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from sim_bridge.control import EndReason
from sim_bridge.frames import RANGE_MESSAGES


@dataclass
class BridgeConfig:
    rate_hz: float = 250.0
    hold_after_s: float = 3.0
    # "frozen": simulated time stops during the hold (for SUTs that answer MAVLink regardless of
    # their clock, like the bundled autopilot); "paced": it runs on at hold_pace with the vehicle
    # free to move (for SUTs whose every thread follows the lockstep clock, like PX4).
    hold_mode: str = "frozen"
    # A paced hold's speed in simulated seconds per wall-clock second. PX4 stretches its own
    # timeouts by a speed factor (PX4_SIM_SPEED_FACTOR) so that it can run this much faster than
    # real time. The wait for a failure injection's answer stays at real time: the faster the
    # simulation runs meanwhile, the later in simulated time the failure takes effect.
    hold_pace: float = 1.0
    # What carries the range sensor's reading to the SUT: only what it reads costs a step's time.
    range_messages: tuple[str, ...] = RANGE_MESSAGES
    stall_timeout_s: float = 10.0
    hold_timeout_s: float = 120.0
    # Poll for the SUT's answer this long before sleeping: only when the SUT has a core of its own.
    spin_s: float = 0.0
    gps_rate_hz: float = 10.0
    ground_truth_rate_hz: float = 50.0
    # The simulator link's protocol: "mavlink" (PX4's HIL messages over a stream) or
    # "ardupilot-json" (ArduPilot's JSON physics backend over UDP: sim_bridge/ardupilot_link.py).
    protocol: str = "mavlink"
    # ardupilot-json: the UDP port the SUT takes the pilot's sticks on (ArduPilot SITL's RC input).
    rc_port: int | None = None
    # A companion computer's MAVLink link to the SUT (PX4 reads OBSTACLE_DISTANCE there, not on
    # its simulator link): the UDP port it takes it on, and the rig's messages sent there.
    companion_port: int | None = None
    companion_messages: tuple[str, ...] = ()
    # The SUT opens the companion link from a port of its own to companion_port (ArduPilot SITL's
    # `udpclient:`), rather than listening on it (PX4): sim_bridge/companion.py.
    companion_connects: bool = False
    # How a rig's DISTANCE_SENSOR is written for the SUT (sim_bridge/rig.py: DISTANCE_SENSOR_CONVENTIONS).
    distance_sensor_convention: str = "px4"
    # The SUT answers every HIL_SENSOR from the first: wait for each answer from step 0 on.
    lockstep_from_start: bool = False
    # Its HIL_ACTUATOR_CONTROLS carry the time_usec of the HIL_SENSOR they answer.
    answer_times_echoed: bool = False


@dataclass
class Summary:
    end_reason: EndReason = EndReason.RUNNING
    sim_time_s: float = 0.0
    run_time_s: float = 0.0
    steps: int = 0
    airborne: bool = False
    touchdown: dict[str, Any] | None = None
    first_touchdown_s: float | None = None
    bad_frames: int = 0
    skipped_bytes: int = 0
    # Answers to an earlier step (answer_times_echoed): late ones, skipped.
    late_answers: int = 0
    wall_time_s: float = 0.0
    wall_in_run_s: float = 0.0
    wait_s: float = 0.0
    physics_s: float = 0.0
    world_s: float = 0.0
    observe_s: float = 0.0
    sensors_s: float = 0.0
    send_s: float = 0.0
    injections: list[dict[str, Any]] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)
