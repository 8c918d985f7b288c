# Static types for the compiled module (setup.py): control.py stays the plain Python source.
# Vectors and quaternions are C tuples, (double, double, double[, double]): between compiled
# modules they pass without a Python float per component; Python callers see plain tuples.
cimport simlink.pymath as math
import cython

@cython.locals(aw=cython.double, ax=cython.double, ay=cython.double, az=cython.double, bw=cython.double, bx=cython.double, by=cython.double, bz=cython.double)
cpdef (double, double, double, double) quat_multiply((double, double, double, double) a, (double, double, double, double) b)

cpdef (double, double, double, double) quat_conjugate((double, double, double, double) q)

@cython.locals(n=cython.double)
cpdef (double, double, double, double) quat_normalize((double, double, double, double) q)

@cython.locals(w=cython.double, x=cython.double, y=cython.double, z=cython.double, vx=cython.double, vy=cython.double, vz=cython.double,
               tx=cython.double, ty=cython.double, tz=cython.double)
cpdef (double, double, double) quat_rotate((double, double, double, double) q, (double, double, double) v)

cpdef (double, double, double) quat_rotate_inverse((double, double, double, double) q, (double, double, double) v)

@cython.locals(cr=cython.double, sr=cython.double, cp=cython.double, sp=cython.double, cy=cython.double, sy=cython.double)
cpdef (double, double, double, double) quat_from_euler(double roll, double pitch, double yaw)

@cython.locals(w=cython.double, x=cython.double, y=cython.double, z=cython.double, roll=cython.double, pitch=cython.double, yaw=cython.double)
cpdef (double, double, double) euler_from_quat((double, double, double, double) q)

@cython.locals(norm=cython.double)
cpdef (double, double) limit_norm2(double x, double y, double limit)

cdef class Setpoint:
    cdef public object north_m, east_m, down_m, yaw_rad
    cdef public double v_north_m_s, v_east_m_s, v_down_m_s
    cdef public bint idle, manual, level, tilt_from_sticks

cdef class PositionControl:
    cdef public object params
    cdef public double _int_n, _int_e, _int_d, _ff_n, _ff_e
    cdef public object _last_sp

    cpdef hold_level(self)

    @cython.locals(alpha=cython.double, limit=cython.double, raw_n=cython.double, raw_e=cython.double)
    cpdef (double, double) _feed_forward(self, double dt, (double, double, double) vel_sp)

    @cython.locals(vn=cython.double, ve=cython.double, vd=cython.double)
    cpdef (double, double, double) velocity_setpoint(self, sp, pos, double limit_xy_m_s)

    @cython.locals(hover=cython.double, en=cython.double, ee=cython.double, ed=cython.double, kp=cython.double, ki=cython.double, kd=cython.double,
                   ff_n=cython.double, ff_e=cython.double, acc_n=cython.double, acc_e=cython.double, acc_d=cython.double, tilt_max=cython.double,
                   thr_n=cython.double, thr_e=cython.double, thr_d=cython.double, saturated_z=cython.bint)
    cpdef (double, double, double) thrust(self, double dt, (double, double, double) vel_sp, vel, (double, double, double) acc)

@cython.locals(tn=cython.double, te=cython.double, td=cython.double, norm=cython.double, nx=cython.double, trace=cython.double, s=cython.double,
               zb=(cython.double, cython.double, cython.double), yc=(cython.double, cython.double, cython.double),
               xb=(cython.double, cython.double, cython.double), yb=(cython.double, cython.double, cython.double),
               m=((cython.double, cython.double, cython.double), (cython.double, cython.double, cython.double), (cython.double, cython.double, cython.double)),
               q=(cython.double, cython.double, cython.double, cython.double))
cpdef ((double, double, double, double), double) attitude_from_thrust((double, double, double) thrust_ned, double yaw)

@cython.locals(sign=cython.double, ex=cython.double, ey=cython.double, ez=cython.double, yaw_max=cython.double, rz=cython.double,
               qe=(cython.double, cython.double, cython.double, cython.double))
cpdef (double, double, double) attitude_rate_setpoint(params, (double, double, double, double) q, (double, double, double, double) q_sp)

cdef class RateControl:
    cdef public object params
    cdef public list _int
    cdef public object _last

    @cython.locals(axis=cython.int, kp=cython.double, ki=cython.double, kd=cython.double, error=cython.double, derivative=cython.double, value=cython.double)
    cpdef tuple update(self, double dt, rates, rates_sp, bint landed)


@cython.locals(roll=cython.double, pitch=cython.double, yaw=cython.double, high=cython.double, low=cython.double, spread=cython.double, room=cython.double,
               scale=cython.double)
cpdef (double, double, double, double) mix(double collective, (double, double, double) torque, double idle=*)
