# Static types for the compiled module (setup.py): sensors.py stays the plain Python source.
cimport simlink.pymath as math
import cython
from sim_bridge.physics cimport VehicleState

cpdef double pressure_hpa(double alt_msl_m)

ctypedef (double, double, double) Row

@cython.locals(cr=cython.double, sr=cython.double, cp=cython.double, sp=cython.double, cy=cython.double, sy=cython.double)
cpdef (Row, Row, Row) rotation_ned_from_body(double roll, double pitch, double yaw)

@cython.locals(cr=cython.double, sr=cython.double, cp=cython.double, sp=cython.double, cy=cython.double, sy=cython.double)
cpdef tuple quaternion_from_euler(double roll, double pitch, double yaw)

cdef class SensorModel:
    cdef public object _rng
    cdef public double _temperature_c
    cdef public (double, double, double) _accel_bias, _gyro_bias
    cdef public list _noise, _gps_noise
    cdef public object _scale

    cpdef list _next_noise(self)

    @cython.locals(n=list, ax=cython.double, ay=cython.double, az=cython.double, r=(Row, Row, Row), mn=cython.double, me=cython.double, md=cython.double,
                   mag_x=cython.double, mag_y=cython.double, mag_z=cython.double, pressure=cython.double, pressure_alt=cython.double)
    cpdef tuple hil_sensor_values(self, VehicleState s)
