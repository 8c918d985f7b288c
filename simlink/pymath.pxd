# Python's math functions as C calls, for the compiled modules (setup.py): a module's .pxd says
# `cimport simlink.pymath as math`, and its `math.cos(x)` becomes C's cos(x) instead of a call
# through Python's math module (a global lookup, an attribute lookup and a float boxed each way;
# dozens a step). Python's math module computes these with the same C library functions, so for
# every value it returns the result is the same double (tests/test_compiled.py). Where Python
# raises instead (math.sqrt(-1.0), math.cos(math.inf)), C returns a NaN.
#
# A name not declared here (math.hypot, math.floor, ...) stays what it was, a call to Python's
# math module: hypot is Python's own algorithm, not C's, and floor returns an int in Python.
from libc.math cimport NAN, asin, atan2 as _c_atan2, copysign, cos, isfinite, isinf, isnan, pi, sin, sqrt, tan

cdef extern from "<math.h>":
    const double inf "INFINITY"

# Python's radians() and degrees() multiply by pi / 180 and 180 / pi, rounded once to a double.
cdef inline double radians(double x) noexcept:
    return x * (pi / 180.0)

cdef inline double degrees(double x) noexcept:
    return x * (180.0 / pi)

# Python's atan2 answers a NaN argument with its own (positive) NaN; C's passes the argument's
# NaN on, sign included, which would change the bytes of a float32 on the link.
cdef inline double atan2(double y, double x) noexcept:
    if isnan(y) or isnan(x):
        return NAN
    return _c_atan2(y, x)
