# Static types for the compiled module (setup.py): commander.py stays the plain Python source.
# Its dataclasses become extension types that are still dataclasses (fields, repr, eq, replace).

cdef class MissionItem:
    cdef public int seq, command
    cdef public double north_m, east_m, altitude_m, param1, param2, param3, param4
    cdef public bint has_position

cdef class VehicleEstimate:
    cdef public double north_m, east_m, down_m, v_north_m_s, v_east_m_s, v_down_m_s, yaw_rad

cdef class Commander:
    cdef public object params, mode, home, mission, _hold, _cruise_m_s, _land_candidate_s, _landed_at_s, manual, _mode_slot
    cdef public bint armed, landed, mission_finished
    cdef public int current
    cdef public list events
    cdef public double _target_alt_m, _wait_until_s, _yaw_sp
    cdef public str _phase
