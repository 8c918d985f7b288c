# Static types for the compiled module (setup.py): commander.py stays the plain Python source.
# Its dataclasses become extension types that are still dataclasses (fields, repr, eq, replace).
cimport simlink.pymath as math
import cython

from autopilot.control cimport Setpoint
from autopilot.params cimport Params

cdef class MissionItem:
    cdef public int seq, command
    cdef public double north_m, east_m, altitude_m, param1, param2, param3, param4
    cdef public bint has_position

cdef class VehicleEstimate:
    cdef public double north_m, east_m, down_m, v_north_m_s, v_east_m_s, v_down_m_s, yaw_rad

cdef class Commander:
    cdef public Params params
    cdef public object mode, home, mission, _hold, _cruise_m_s, _land_candidate_s, _landed_at_s, manual, _mode_slot, _delayed
    cdef public bint armed, landed, mission_finished
    cdef public int current
    cdef public list events
    cdef public double _target_alt_m, _wait_until_s, _yaw_sp
    cdef public str _phase, failsafe

    cpdef double _altitude(self, VehicleEstimate estimate)

    cpdef double _down_for(self, double altitude_m)

    cpdef double _cruise(self)

    @cython.locals(dn=cython.double, de=cython.double, distance=cython.double, speed=cython.double)
    cpdef tuple _fly_to(self, VehicleEstimate estimate, double north, double east, double altitude_m)

    cpdef Setpoint _hold_setpoint(self)

    @cython.locals(hover=cython.double)
    cpdef bint _detect_landing(self, double now_s, VehicleEstimate estimate, double lift, bint descending_commanded)

    cpdef Setpoint _land(self, double now_s, VehicleEstimate estimate, double lift, double north, double east)

    @cython.locals(item=MissionItem, target=cython.double, radius=cython.double, distance=cython.double)
    cpdef Setpoint _mission(self, double now_s, VehicleEstimate estimate, double lift)

    cpdef data_link_lost(self, double now_s, VehicleEstimate estimate)

    cpdef _fall_back(self, double now_s, VehicleEstimate estimate, bint position_valid)

    cpdef Setpoint _descend(self, double now_s, VehicleEstimate estimate, double lift)

    cpdef Setpoint update(self, double now_s, VehicleEstimate estimate, double lift, bint position_valid=*)
