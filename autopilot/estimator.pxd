# Static types for the compiled module (setup.py): estimator.py stays the plain Python source.
cimport simlink.pymath as math
import cython

from autopilot.control cimport quat_from_euler, quat_normalize, quat_rotate, quat_rotate_inverse

cdef class GpsFix:
    cdef public double lat_deg, lon_deg, alt_m, v_north_m_s, v_east_m_s, v_down_m_s
    cdef public int fix_type, satellites

cdef class Estimator:
    cdef public double declination
    cdef public (double, double, double, double) q
    cdef public (double, double, double) rates, acc_ned
    cdef public object origin, _baro_ref, last_gps
    cdef public list pos, vel, _gyro_bias
    cdef public bint attitude_ready
    cdef public double _baro_alt, last_gps_s, last_imu_s

    @cython.locals(ex=cython.double, ey=cython.double, ez=cython.double, a_norm=cython.double, ux=cython.double, uy=cython.double, uz=cython.double,
                   px=cython.double, py=cython.double, pz=cython.double, mn=cython.double, me=cython.double, yaw_error=cython.double,
                   bx=cython.double, by=cython.double, bz=cython.double, wx=cython.double, wy=cython.double, wz=cython.double,
                   w=cython.double, x=cython.double, y=cython.double, z=cython.double, half=cython.double, fn=cython.double, fe=cython.double, fd=cython.double,
                   axis=cython.int, q=(cython.double, cython.double, cython.double, cython.double))
    cpdef update_imu(self, double now_s, double dt, gyro, accel, mag)

    cpdef bint position_valid(self, double now_s, double dead_reckoning_s)

    @cython.locals(innovation=cython.double)
    cpdef update_baro(self, double dt, double pressure_alt_m)
