"""Seeded faults: realistic bugs that can be switched on in the bundled autopilot's own code paths
(`python -m autopilot --fault NAME`, `stella ... --sut-fault NAME`), to measure whether a search
finds real faults. Each is off unless selected; at most one is active. The code that a fault
breaks branches on `params.fault` where the bug would live.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Fault:
    name: str
    area: str  # collision prevention, sensing, estimation, control, commander, failsafe
    breaks: str  # what goes wrong
    kin: str  # the kind of bug it imitates, in PX4 or elsewhere
    revealed_by: str  # scenario features that should reveal it
    # The safety properties (harness/properties) its witness is judged by; none: the clearance
    # and the mission, as for a fault that makes the vehicle unsafe or fail.
    properties: tuple[str, ...] = ()


FAULTS: tuple[Fault, ...] = (
    Fault("cp_ignores_delay", "collision prevention",
          "The stopping distance leaves out CP_DELAY * speed, so braking starts late by the distance flown during the sensor and estimation delay (2 m at 5 m/s).",
          "a term dropped from a braking-distance formula",
          "an obstacle across the route at cruise speed"),
    Fault("cp_braking_without_jerk", "collision prevention",
          "The stopping distance leaves out the jerk limit (v = sqrt(2 a s)), as if full deceleration came at once, so braking starts too late while the vehicle tilts back.",
          "a textbook formula in place of the jerk-limited one",
          "an obstacle across the route at cruise speed"),
    Fault("cp_off_above_cruise", "collision prevention",
          "Collision prevention is skipped while the requested horizontal speed exceeds 4 m/s.",
          "an early return meant for a manual fast mode left in every mode",
          "an obstacle across the route with the default 5 m/s cruise speed"),
    Fault("cp_narrow_view", "collision prevention",
          "Only obstacle sectors within 15 degrees of the direction of travel constrain the velocity, so an obstacle beside the path is ignored while guidance slides along it.",
          "a field-of-view check applied to the constraint instead of to the sensor",
          "an obstacle partly across the route, a wide or rotated box the vehicle must slide past"),
    Fault("cp_sector_mirrored", "collision prevention",
          "With the heading past 180 degrees (flying west of north-south) the sector index is mirrored, so obstacles are mapped to the wrong side.",
          "an angle wrapped to [0, 360) on one path and to (-180, 180] on another",
          "a route heading west (mission waypoints or a plan) with an obstacle across it"),
    Fault("range_frame_world", "sensing",
          "OBSTACLE_DISTANCE sectors are taken as world-fixed (north-referenced) instead of body-fixed, so whenever the vehicle does not face north, obstacles appear rotated by its heading.",
          "MAV_FRAME_BODY_FRD and MAV_FRAME_LOCAL_NED confused in OBSTACLE_DISTANCE's frame field",
          "a route that does not head north, with an obstacle across it"),
    Fault("baro_temperature_drift", "estimation",
          "The barometer's altitude drifts with the sensor's temperature above 15 degC (0.4 m per degC, uncorrected), so the vehicle flies and lands lower than it believes on a hot day.",
          "a missing temperature compensation of a pressure sensor",
          "hot weather with obstacles whose tops are just below the cruise altitude, or raised terrain"),
    Fault("yaw_fixed_heading", "control",
          "In missions the vehicle keeps the heading it took off with instead of facing where it flies, so the forward range sensor looks away from the route after a turn.",
          "MPC_YAW_MODE's 'fixed heading' taken as the default",
          "a route that turns away from north (waypoints or a plan) with an obstacle on the new leg"),
    Fault("land_detect_home_altitude", "commander",
          "Landing is only detected within 0.5 m of home's altitude, so on ground higher or lower than home the vehicle never detects its landing, never disarms and the mission never ends.",
          "a land detector taking the home altitude for the ground",
          "a landing point higher or lower than the start: the elevation, depression or steep transition landform"),
    Fault("acceptance_radius_10x", "commander",
          "A waypoint counts as reached within ten times its acceptance radius, so the vehicle turns early and cuts corners.",
          "a unit slip (decimetres for metres) in the acceptance radius",
          "a route with turns (waypoints or a plan), obstacles inside the corner"),
    Fault("noaid_timeout_ms", "failsafe",
          "EKF2_NOAID_TOUT (microseconds) is read as milliseconds, so the position counts as valid for 5,000 s instead of 5 s without GPS: the position-loss failsafe never descends, and the vehicle flies its mission on a drifting dead-reckoned position.",
          "a parameter's unit slip (PX4's time parameters mix s, ms and us)",
          "a GPS that goes off for more than 5 s in flight",
          ("gps_loss_lands",)),
)

BY_NAME = {fault.name: fault for fault in FAULTS}


def markdown_table() -> str:
    lines = [
        "# Seeded faults of the bundled autopilot",
        "",
        "Generated by `python -m autopilot.faults` from `autopilot/faults.py`; do not edit by hand.",
        "Each is off unless selected with `--sut-fault NAME`; its witness, a concrete scenario that",
        "reveals it (unsafe or failed with the fault, `ok` without), is `scenarios/faults/NAME.json`.",
        "",
        "| name | area | what it breaks | the kind of bug | revealed by |",
        "| --- | --- | --- | --- | --- |",
    ]
    lines += [f"| `{f.name}` | {f.area} | {f.breaks} | {f.kin} | {f.revealed_by} |" for f in FAULTS]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(markdown_table(), end="")
