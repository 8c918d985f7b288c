"""The bundled PX4-like autopilot: a real system under test with collision prevention.

It talks PX4's simulator protocol to the simulator and looks like PX4 to MAVSDK on its API
link. It imports nothing from `harness` or `sim_bridge`.
"""

from simlink import check_compiled

check_compiled(__file__)
