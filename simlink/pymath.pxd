# Python's math functions as C calls, for the compiled modules (setup.py): a module's .pxd says
# `cimport simlink.pymath as math`, and its `math.cos(x)` becomes C's cos(x) instead of a call
# through Python's math module (a global lookup, an attribute lookup and a float boxed each way;
# dozens a step). Python's math module computes these with the same C library functions, so for
# every value it returns the result is the same double (tests/test_compiled.py). Where Python
# raises instead (math.sqrt(-1.0), math.cos(math.inf)), C returns a NaN.
#
# What is missing here is missing on purpose, so that a module using it fails to compile rather
# than change its results: math.hypot (Python's own correctly rounded algorithm, not C's hypot:
# such modules import it by name), math.floor and math.ceil (ints in Python, doubles in C).
from libc.math cimport asin, atan2, copysign, cos, isfinite, isinf, pi, sin, sqrt, tan

cdef extern from "<math.h>":
    const double inf "INFINITY"

# Python's radians() and degrees() multiply by pi / 180 and 180 / pi, rounded once to a double.
cdef inline double radians(double x) noexcept:
    return x * (pi / 180.0)

cdef inline double degrees(double x) noexcept:
    return x * (180.0 / pi)
