# Static types for the compiled module (setup.py): app.py stays the plain Python source.
import cython

from autopilot.collision cimport ObstacleMap
from autopilot.control cimport PositionControl, RateControl
from autopilot.estimator cimport Estimator
from autopilot.params cimport Params
from simlink.codec cimport FrameSplitter

cdef class Autopilot:
    cdef public Params params
    cdef public Estimator estimator
    cdef public object commander, position_mode, api, failures
    cdef public PositionControl position_control
    cdef public RateControl rate_control
    cdef public ObstacleMap obstacles
    cdef public bint _manual_active, sensors_seen, _controlling
    cdef public double now_s, collective, lift
    cdef public object _last_time_us, _ground_truth, _last_sensor_values, _last_gps_fix, _last_obstacle_reading
    cdef public int _seq
    cdef public set _wanted_sim_messages

    @cython.locals(est=Estimator, dt=cython.double, manual=cython.bint, vn=cython.double, ve=cython.double, yaw_sp=cython.double, collective=cython.double)
    cpdef tuple step(self, time_us, values)

    @cython.locals(msgid=cython.int, fields=tuple, motors=tuple)
    cpdef _on_sim_data(self, sim, FrameSplitter splitter, data)
