"""What the UAV is to do in a scenario: its route (waypoints, or a QGroundControl plan), cruise
speed, whether it lands, and how it is flown (a mission, or a pilot on the sticks)."""

from __future__ import annotations

from dataclasses import dataclass

from harness.scenario.logical import LogicalScenario
from harness.scenario.plan import Plan
from harness.scenario.profile import Profile
from sim_bridge.terrain import max_height_on_segment_m


@dataclass(frozen=True)
class Mission:
    waypoints: tuple[tuple[float, float, float], ...]  # north_m, east_m, altitude_m above start
    cruise_speed_m_s: float
    land: bool
    drive: str = "mission"  # or "pilot": see README, Drives
    plan: Plan | None = None  # a QGroundControl plan flown item by item

    @property
    def landing_point(self) -> tuple[float, float]:
        if self.plan is not None and self.drive == "mission":
            return self.plan.landing_point
        return self.waypoints[-1][0], self.waypoints[-1][1]


def mission_for(logical: LogicalScenario, profile: Profile) -> Mission:
    """The scenario's mission override, or the landform's: take off, fly to the goal, land."""
    uav = profile.uav
    m = logical.mission or {}
    cruise_speed_m_s = float(m.get("cruise_speed_m_s", uav["cruise_speed_m_s"]))
    plan = logical.plan
    if plan is not None:
        return Mission(
            waypoints=tuple(point[:3] for point in plan.route),
            cruise_speed_m_s=cruise_speed_m_s,
            land=plan.lands,
            drive=logical.drive,
            plan=plan,
        )
    if "waypoints" in m:
        return Mission(
            waypoints=tuple((w["north_m"], w["east_m"], w["altitude_m"]) for w in m["waypoints"]),
            cruise_speed_m_s=cruise_speed_m_s,
            land=bool(m.get("land", True)),
            drive=logical.drive,
        )
    landform = profile.landforms[logical.landform]
    goal = (landform.goal_north_m, landform.goal_east_m)
    highest = max_height_on_segment_m(landform.terrain, (0.0, 0.0), goal)
    altitude_m = uav["cruise_altitude_agl_m"] + max(0.0, highest)
    return Mission(
        waypoints=((goal[0], goal[1], altitude_m),),
        cruise_speed_m_s=cruise_speed_m_s,
        land=bool(m.get("land", True)),
        drive=logical.drive,
    )
