"""The simulator link's wire format, shared by sim_bridge and the bundled autopilot.

Struct codecs for the two messages exchanged on every lockstep step (HIL_SENSOR and
HIL_ACTUATOR_CONTROLS) and, from pymavlink's own layouts, for the simulator's 10-50 Hz messages,
and a MAVLink 2 frame splitter; compiled where a C compiler is found (setup.py). Its own package so that the autopilot need not import the simulator.
"""

from pathlib import Path

_PYMATH = Path(__file__).parent / "pymath.pxd"


def check_compiled(package_init: str) -> None:
    """Refuse to import a package whose compiled modules (see setup.py) are older than their
    sources or their static types (.pxd): Python would load the stale compiled code and silently
    ignore the edit."""
    folder = Path(package_init).parent
    for compiled in folder.glob("*.so"):
        stem = compiled.name.split(".", 1)[0]
        # The compiled modules' .pxd files cimport pymath.pxd (C's math functions) too.
        for source in (folder / f"{stem}.py", folder / f"{stem}.pxd", _PYMATH):
            if source.exists() and source.stat().st_mtime > compiled.stat().st_mtime:
                raise ImportError(f"{compiled} is older than {source}: rebuild it with `make setup` "
                                  f"(or `pip install -e .`), or delete the .so files to run the Python sources")


check_compiled(__file__)
