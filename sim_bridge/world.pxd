# Static types for the compiled module (setup.py): world.py stays the plain Python source.
cimport simlink.pymath as math
import cython
from sim_bridge.physics cimport Multirotor, VehicleState
from sim_bridge.sensors cimport SensorModel
from sim_bridge.obstacles cimport ObstacleField

cdef class World:
    cdef public object spec, on_event, on_obstacles_changed, terrain, water, wind_field, wind_now
    cdef public bint _gust_announced, airborne, _moved_for_next_step
    cdef public Multirotor vehicle
    cdef public SensorModel sensors
    cdef public ObstacleField field
    cdef public double range_m, min_range_m, _reach_from_centre_m, dt
    cdef public object sector_visible, _sector_angles, _hull_offsets
    cdef public list _nothing_in_reach, injections, _pending_ops
    cdef public long long dt_us, steps
    cdef public object motors
    cdef public object run_start_s, end_reason, touchdown, first_touchdown_s, forced_slot, _landed_since, pilot

    cpdef double run_time(self, double time_s)

    cpdef tuple imu(self)

    @cython.locals(s=VehicleState)
    cpdef tuple clearance(self)

    @cython.locals(s=VehicleState, time_s=cython.double, run_time=cython.double)
    cpdef step(self, motors)

    @cython.locals(s=VehicleState, airspeed=cython.double)
    cpdef _advance_wind(self)

    @cython.locals(s=VehicleState, time_s=cython.double, run_time=cython.double, speed=cython.double)
    cpdef check_end(self)

    cpdef move_obstacles_for_next_step(self)
