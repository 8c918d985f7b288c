# Static types for the compiled module (setup.py): obstacles.py stays the plain Python source.
cimport simlink.pymath as math
import cython

cdef class Obstacle:
    cdef public object id, form, size
    cdef public double yaw_rad
    cdef public object a, b
    cdef public double speed_m_s
    cdef public object kind, path, repeat, position, collision
    cdef public double _leg_m
    cdef public list _cumulative_m, _path_points
    cdef public tuple _a_tuple, _delta

    cpdef position_at(self, double time_s)

    @cython.locals(leg=cython.double, travelled=cython.double, fraction=cython.double, an=cython.double, ae=cython.double, au=cython.double,
                   dn=cython.double, de=cython.double, du=cython.double)
    cpdef (double, double, double) _coordinates_at(self, double time_s)

    @cython.locals(segment=cython.Py_ssize_t, length=cython.double, fraction=cython.double, pn=cython.double, pe=cython.double, pu=cython.double,
                   qn=cython.double, qe=cython.double, qu=cython.double)
    cpdef (double, double, double) _along_path(self, double travelled_m)

    @cython.locals(north=cython.double, east=cython.double, up=cython.double, position="double[::1]")
    cpdef move_to(self, double time_s)

cdef class ObstacleField:
    cdef public list obstacles
    cdef public object _body, _request, _result, _rotation, _translation

    cpdef move_to(self, double time_s)

    @cython.locals(cr=cython.double, sr=cython.double, cp=cython.double, sp=cython.double, cy=cython.double, sy=cython.double,
                   r="double[:, ::1]", t="double[::1]")
    cpdef place_body(self, double north_m, double east_m, double up_m, double roll, double pitch, double yaw)

    cpdef list clearances(self)
