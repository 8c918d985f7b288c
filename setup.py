"""Compiles the per-step hot path with Cython: the bundled autopilot, the simulator link's codec
and shared-memory rings (which both sides use), and the simulator's step (its loop, world,
physics, sensors, obstacles).

The modules stay plain Python, the source of truth. A `.pxd` file beside a module gives the
compiler static types (C doubles for the controllers' arithmetic; extension types for the
estimator, the obstacle map, the parameters, the frame splitter, the autopilot, the commander,
the bridge, the world, the vehicle and its state, the sensors, the obstacles and the
dataclasses) without changing what the Python source computes for the values it gets (MAVLink's
field types). Compiled, the autopilot's computation per lockstep step takes about a third of the
Python time and the simulator's part of a step about three quarters, with the same float
arithmetic, so the same flight to the last bit (tests/test_compiled.py). Without a C compiler or
Python's headers the build skips them and the same modules run as Python.
"""

import os
import sysconfig
from pathlib import Path

from Cython.Build import cythonize
from setuptools import setup

COMPILED = [
    "autopilot/app.py",
    "autopilot/collision.py",
    "autopilot/commander.py",
    "autopilot/control.py",
    "autopilot/estimator.py",
    "autopilot/inline.py",
    "autopilot/manual.py",
    "autopilot/params.py",
    "simlink/codec.py",
    "simlink/shared_memory.py",
    "sim_bridge/bridge.py",
    "sim_bridge/frames.py",
    "sim_bridge/obstacles.py",
    "sim_bridge/physics.py",
    "sim_bridge/sensors.py",
    "sim_bridge/world.py",
]



def built_in_place_since_last_change(module: str) -> bool:
    """Its compiled module beside it is newer than everything that goes into it: its source, any
    static types (a .pxd cimports others, across the packages) and these build settings. Such a
    module is not compiled again: an edit to one module rebuilds that one in seconds, and the
    worker image compiles in a layer of its own that a change elsewhere does not invalidate."""
    built = Path(module).with_suffix(sysconfig.get_config_var("EXT_SUFFIX"))
    inputs = [Path(module), Path(__file__), *(p for package in {Path(m).parent for m in COMPILED} for p in package.glob("*.pxd"))]
    return built.exists() and built.stat().st_mtime > max(p.stat().st_mtime for p in inputs)


# `stella mutants build` compiles a mutated module again, in the mutant's folder, with exactly
# these settings: it names the modules here.
if os.environ.get("STELLA_COMPILE_ONLY"):
    COMPILED = os.environ["STELLA_COMPILE_ONLY"].split(",")
else:
    COMPILED = [m for m in COMPILED if not built_in_place_since_last_change(m)]

# Static types come from the .pxd file beside a module; its annotations are documentation only.
# cpow: a C double's `**` is C's pow(), as Python's float power is (by default Cython takes a
# fractional power of doubles through complex arithmetic, which rounds differently).
extensions = cythonize(COMPILED, compiler_directives={"language_level": 3, "annotation_typing": False, "cpow": True}, quiet=True)
for extension in extensions:
    extension.optional = True  # no compiler: warn and keep the Python module
    # C doubles round as Python's floats only without fused multiply-adds, which GCC would
    # otherwise emit wherever the target has them (aarch64, x86 with -march=native), and with
    # pow() the C library's: GCC would turn pow(x, 2.0) into x * x, which differs in the last bit
    # about once in a thousand.
    extension.extra_compile_args += ["-ffp-contract=off", "-fno-builtin-pow"]

setup(ext_modules=extensions, options={"build_ext": {"parallel": len(os.sched_getaffinity(0))}})
