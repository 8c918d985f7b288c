# Static types for the compiled module (setup.py): control.py stays the plain Python source.
import cython

@cython.locals(aw=cython.double, ax=cython.double, ay=cython.double, az=cython.double, bw=cython.double, bx=cython.double, by=cython.double, bz=cython.double)
cpdef tuple quat_multiply(a, b)

cpdef tuple quat_conjugate(q)

@cython.locals(n=cython.double)
cpdef tuple quat_normalize(q)

@cython.locals(w=cython.double, x=cython.double, y=cython.double, z=cython.double, vx=cython.double, vy=cython.double, vz=cython.double,
               tx=cython.double, ty=cython.double, tz=cython.double)
cpdef tuple quat_rotate(q, v)

cpdef tuple quat_rotate_inverse(q, v)

@cython.locals(cr=cython.double, sr=cython.double, cp=cython.double, sp=cython.double, cy=cython.double, sy=cython.double)
cpdef tuple quat_from_euler(double roll, double pitch, double yaw)

@cython.locals(w=cython.double, x=cython.double, y=cython.double, z=cython.double, roll=cython.double, pitch=cython.double, yaw=cython.double)
cpdef tuple euler_from_quat(q)

@cython.locals(norm=cython.double)
cpdef tuple limit_norm2(double x, double y, double limit)

cdef class Setpoint:
    cdef public object north_m, east_m, down_m, yaw_rad
    cdef public double v_north_m_s, v_east_m_s, v_down_m_s
    cdef public bint idle, manual

cdef class PositionControl:
    cdef public object params
    cdef public double _int_n, _int_e, _int_d, _ff_n, _ff_e
    cdef public object _last_sp

    @cython.locals(alpha=cython.double, limit=cython.double, raw_n=cython.double, raw_e=cython.double)
    cpdef tuple _feed_forward(self, double dt, vel_sp)

    @cython.locals(vn=cython.double, ve=cython.double, vd=cython.double)
    cpdef tuple velocity_setpoint(self, sp, pos, double limit_xy_m_s)

    @cython.locals(hover=cython.double, en=cython.double, ee=cython.double, ed=cython.double, kp=cython.double, ki=cython.double, kd=cython.double,
                   ff_n=cython.double, ff_e=cython.double, acc_n=cython.double, acc_e=cython.double, acc_d=cython.double, tilt_max=cython.double,
                   thr_n=cython.double, thr_e=cython.double, thr_d=cython.double, saturated_z=cython.bint)
    cpdef tuple thrust(self, double dt, vel_sp, vel, acc)

@cython.locals(tn=cython.double, te=cython.double, td=cython.double, norm=cython.double, nx=cython.double, trace=cython.double, s=cython.double)
cpdef tuple attitude_from_thrust(thrust_ned, double yaw)

@cython.locals(sign=cython.double, ex=cython.double, ey=cython.double, ez=cython.double, yaw_max=cython.double, rz=cython.double)
cpdef tuple attitude_rate_setpoint(params, q, q_sp)

cdef class RateControl:
    cdef public object params
    cdef public list _int
    cdef public object _last

    @cython.locals(axis=cython.int, kp=cython.double, ki=cython.double, kd=cython.double, error=cython.double, derivative=cython.double, value=cython.double)
    cpdef tuple update(self, double dt, rates, rates_sp, bint landed)

