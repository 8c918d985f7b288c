# Static types for the compiled module (setup.py): app.py stays the plain Python source.
cimport simlink.pymath as math
import cython

from autopilot.collision cimport ObstacleMap
from autopilot.commander cimport Commander, VehicleEstimate
from autopilot.control cimport PositionControl, RateControl, Setpoint, attitude_from_thrust, attitude_rate_setpoint, euler_from_quat, mix
from autopilot.estimator cimport Estimator
from autopilot.params cimport Params
from simlink.codec cimport FrameSplitter

cdef class Autopilot:
    cdef public Params params
    cdef public Estimator estimator
    cdef public Commander commander
    cdef public object position_mode, api, failures
    cdef public PositionControl position_control
    cdef public RateControl rate_control
    cdef public ObstacleMap obstacles
    cdef public bint _manual_active, sensors_seen, _controlling
    cdef public double now_s, collective, lift, _position_mode_since_s
    cdef public object _last_time_us, _ground_truth, _last_sensor_values, _last_gps_fix, _last_obstacle_reading
    cdef public int _seq
    cdef public set _wanted_sim_messages

    cpdef (double, double, double) euler(self)

    cpdef double yaw_rad(self)

    cpdef VehicleEstimate vehicle_estimate(self)

    cpdef double _baro_drift_m(self, double temperature_c)

    @cython.locals(est=Estimator, commander=Commander, sp=Setpoint, estimate=VehicleEstimate, dt=cython.double, manual=cython.bint, vn=cython.double,
                   ve=cython.double, yaw_sp=cython.double, positioned=cython.bint, horizontal=(cython.double, cython.double), collective=cython.double, q_sp=(cython.double, cython.double, cython.double, cython.double),
                   rates_sp=(cython.double, cython.double, cython.double), torque=(cython.double, cython.double, cython.double), vel_sp=(cython.double, cython.double, cython.double),
                   thrust=(cython.double, cython.double, cython.double))
    cpdef tuple step(self, time_us, values)

    @cython.locals(msgid=cython.int, fields=tuple, motors=tuple)
    cpdef _on_sim_data(self, sim, FrameSplitter splitter, data)
