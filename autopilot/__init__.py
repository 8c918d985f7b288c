"""The bundled PX4-like autopilot: a real system under test with collision prevention.

It talks PX4's simulator protocol to the simulator and looks like PX4 to MAVSDK on its API
link. It imports nothing from `harness` or `sim_bridge`.
"""

from pathlib import Path


def check_compiled(package_init: str) -> None:
    """Refuse to import a package whose compiled modules (see setup.py) are older than their
    sources: Python would load the stale compiled code and silently ignore the edit."""
    folder = Path(package_init).parent
    for compiled in folder.glob("*.so"):
        source = folder / (compiled.name.split(".", 1)[0] + ".py")
        if source.exists() and source.stat().st_mtime > compiled.stat().st_mtime:
            raise ImportError(f"{compiled} is older than {source}: rebuild it with `make setup` "
                              f"(or `pip install -e .`), or delete the .so files to run the Python sources")


check_compiled(__file__)
