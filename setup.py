"""Compiles the bundled autopilot, the per-step hot path on the SUT's side, with Cython.

The modules stay plain Python (the source of truth; nothing in them is Cython-specific).
Compiled, the autopilot's computation per lockstep step takes about half the time, with the
same float arithmetic, so the same fitness to the last bit (tests/test_compiled.py). Without a
C compiler or Python's headers the build skips them and the same modules run as Python.
"""

import os

from Cython.Build import cythonize
from setuptools import setup

COMPILED = [
    "autopilot/app.py",
    "autopilot/collision.py",
    "autopilot/commander.py",
    "autopilot/control.py",
    "autopilot/estimator.py",
    "autopilot/manual.py",
    "autopilot/params.py",
]

extensions = cythonize(COMPILED, compiler_directives={"language_level": 3}, quiet=True)
for extension in extensions:
    extension.optional = True  # no compiler: warn and keep the Python module

setup(ext_modules=extensions, options={"build_ext": {"parallel": len(os.sched_getaffinity(0))}})
