"""JSBSim flight dynamics of the F450 quadrotor, with terrain under the vehicle and body drag.

Motor order is PX4's quad-X, which is also the F450's: 0 front-right, 1 aft-left, 2 front-left,
3 aft-right (`HIL_ACTUATOR_CONTROLS.controls[0..3]`, 0..1). Front-right and aft-left spin
counter-clockwise seen from above, front-left and aft-right clockwise.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import jsbsim

from sim_bridge.geo import EARTH_RADIUS_M, geodetic_from_local

FT = 0.3048
LBF = 4.4482216152605
MOTOR_PROPERTIES = ("fcs/cmdEscFR_nd", "fcs/cmdEscAL_nd", "fcs/cmdEscFL_nd", "fcs/cmdEscAR_nd")
MODEL_TEMPLATE = Path(__file__).resolve().parent / "models" / "stella_f450.xml.in"
# Centre of gravity above the ground when the gear rests on it (Gear.xml contacts at -0.1524 m).
GEAR_HEIGHT_M = 0.1524
# Body drag: 0.5 * rho * Cd * A with Cd*A about 0.05 m^2 for a 450 mm frame with battery.
DRAG_AREA_M2 = 0.05


@dataclass
class VehicleState:
    """Ground truth in the local frame: north/east/up metres from the origin, NED velocities."""

    north_m: float = 0.0
    east_m: float = 0.0
    up_m: float = 0.0
    lat_deg: float = 0.0
    lon_deg: float = 0.0
    alt_msl_m: float = 0.0
    v_north_m_s: float = 0.0
    v_east_m_s: float = 0.0
    v_down_m_s: float = 0.0
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    yaw_rad: float = 0.0
    p_rad_s: float = 0.0
    q_rad_s: float = 0.0
    r_rad_s: float = 0.0
    ax_m_s2: float = 0.0  # specific force, body FRD
    ay_m_s2: float = 0.0
    az_m_s2: float = 0.0
    agl_m: float = 0.0  # gear above the terrain under the vehicle
    on_ground: bool = True


def _model_dir() -> str:
    """A JSBSim root with our model, whose sub-files point at the installed F450."""
    root = jsbsim.get_default_root_dir()
    folder = tempfile.mkdtemp(prefix="stella-jsbsim-")
    aircraft = Path(folder) / "aircraft" / "stella_f450"
    aircraft.mkdir(parents=True)
    text = MODEL_TEMPLATE.read_text().replace("@F450@", os.path.join(root, "aircraft", "F450"))
    (aircraft / "stella_f450.xml").write_text(text)
    return folder


@contextlib.contextmanager
def _stdout_silenced():
    """JSBSim prints a banner: at the file descriptor where stdout is a file, through sys.stdout
    where that is none (a caller capturing output, as `stella bench --json` under pytest)."""
    sys.stdout.flush()
    saved = os.dup(1)
    with open(os.devnull, "wb") as devnull:
        os.dup2(devnull.fileno(), 1)
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


class Multirotor:
    """One JSBSim F450. `step` applies motor commands and advances one physics step."""

    def __init__(self, *, lat_deg: float, lon_deg: float, ground_msl_m: float, rate_hz: float, temperature_c: float):
        self._origin_lat = lat_deg
        self._origin_lon = lon_deg
        self._origin_alt = ground_msl_m
        self._cos_lat = math.cos(math.radians(lat_deg))
        folder = _model_dir()
        with _stdout_silenced():  # JSBSim prints a banner on stdout, where our result line goes
            fdm = jsbsim.FGFDMExec(folder, None)
        fdm.set_debug_level(0)
        fdm.set_engine_path(os.path.join(jsbsim.get_default_root_dir(), "engine"))
        fdm.set_systems_path(os.path.join(jsbsim.get_default_root_dir(), "systems"))
        loaded = fdm.load_model("stella_f450")
        shutil.rmtree(folder, ignore_errors=True)  # JSBSim has read every file by now
        if not loaded:
            raise RuntimeError("JSBSim could not load the stella_f450 model")
        fdm["ic/lat-geod-deg"] = lat_deg
        fdm["ic/long-gc-deg"] = lon_deg
        fdm["ic/terrain-elevation-ft"] = ground_msl_m / FT
        fdm["ic/h-agl-ft"] = GEAR_HEIGHT_M / FT
        fdm["ic/psi-true-deg"] = 0.0
        fdm.set_dt(1.0 / rate_hz)
        # ISA is 15 C at sea level; delta-T is in Rankine.
        fdm["atmosphere/delta-T"] = (temperature_c - 15.0 + 0.0065 * ground_msl_m) * 1.8
        fdm.run_ic()
        for index in range(4):
            fdm[f"propulsion/engine[{index}]/set-running"] = 1
        self.fdm = fdm
        node = fdm.get_property_manager().get_node
        self._motors = [node(name, False) for name in MOTOR_PROPERTIES]
        self._terrain = node("position/terrain-elevation-asl-ft", False)
        self._drag = [node(f"external_reactions/drag_{axis}/magnitude", False) for axis in ("north", "east", "down")]
        names = {
            "lat": "position/lat-geod-deg",
            "lon": "position/long-gc-deg",
            "alt": "position/h-sl-meters",
            "agl": "position/h-agl-ft",
            "vn": "velocities/v-north-fps",
            "ve": "velocities/v-east-fps",
            "vd": "velocities/v-down-fps",
            "phi": "attitude/phi-rad",
            "theta": "attitude/theta-rad",
            "psi": "attitude/psi-rad",
            "p": "velocities/p-rad_sec",
            "q": "velocities/q-rad_sec",
            "r": "velocities/r-rad_sec",
            "ax": "accelerations/a-pilot-x-ft_sec2",
            "ay": "accelerations/a-pilot-y-ft_sec2",
            "az": "accelerations/a-pilot-z-ft_sec2",
            "rho": "atmosphere/rho-slugs_ft3",
        }
        self._nodes = {key: node(name, False) for key, name in names.items()}
        self.state = VehicleState()
        self._read_state()

    def local_to_geodetic(self, north_m: float, east_m: float) -> tuple[float, float]:
        return geodetic_from_local(self._origin_lat, self._origin_lon, north_m, east_m)

    def _read_state(self) -> None:
        n = self._nodes
        s = self.state
        s.lat_deg = n["lat"].get_double_value()
        s.lon_deg = n["lon"].get_double_value()
        s.alt_msl_m = n["alt"].get_double_value()
        s.north_m = math.radians(s.lat_deg - self._origin_lat) * EARTH_RADIUS_M
        s.east_m = math.radians(s.lon_deg - self._origin_lon) * EARTH_RADIUS_M * self._cos_lat
        s.up_m = s.alt_msl_m - self._origin_alt
        s.v_north_m_s = n["vn"].get_double_value() * FT
        s.v_east_m_s = n["ve"].get_double_value() * FT
        s.v_down_m_s = n["vd"].get_double_value() * FT
        s.roll_rad = n["phi"].get_double_value()
        s.pitch_rad = n["theta"].get_double_value()
        s.yaw_rad = n["psi"].get_double_value()
        s.p_rad_s = n["p"].get_double_value()
        s.q_rad_s = n["q"].get_double_value()
        s.r_rad_s = n["r"].get_double_value()
        s.ax_m_s2 = n["ax"].get_double_value() * FT
        s.ay_m_s2 = n["ay"].get_double_value() * FT
        s.az_m_s2 = n["az"].get_double_value() * FT
        s.agl_m = n["agl"].get_double_value() * FT - GEAR_HEIGHT_M
        s.on_ground = s.agl_m < 0.02

    def step(self, motors: tuple[float, float, float, float], terrain_up_m: float, wind_n_m_s: float, wind_e_m_s: float,
             wind_d_m_s: float = 0.0) -> VehicleState:
        """Advance one step with motor commands in PX4's quad-X order, the terrain height under the
        vehicle and the wind (the air's velocity over the ground, NED), which acts through body drag."""
        self._terrain.set_double_value((self._origin_alt + terrain_up_m) / FT)
        s = self.state
        rho = self._nodes["rho"].get_double_value() * 515.378818  # slug/ft^3 -> kg/m^3
        k = 0.5 * rho * DRAG_AREA_M2
        air_n = s.v_north_m_s - wind_n_m_s
        air_e = s.v_east_m_s - wind_e_m_s
        air_d = s.v_down_m_s - wind_d_m_s
        speed = math.sqrt(air_n * air_n + air_e * air_e + air_d * air_d)
        self._drag[0].set_double_value(-k * speed * air_n / LBF)
        self._drag[1].set_double_value(-k * speed * air_e / LBF)
        self._drag[2].set_double_value(-k * speed * air_d / LBF)
        for node, command in zip(self._motors, motors):
            node.set_double_value(min(1.0, max(0.0, command)))
        self.fdm.run()
        self._read_state()
        return s
