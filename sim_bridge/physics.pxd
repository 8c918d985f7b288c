# Static types for the compiled module (setup.py): physics.py stays the plain Python source.
cimport simlink.pymath as math
import cython

cdef class VehicleState:
    cdef public double north_m, east_m, up_m, lat_deg, lon_deg, alt_msl_m, v_north_m_s, v_east_m_s, v_down_m_s
    cdef public double roll_rad, pitch_rad, yaw_rad, p_rad_s, q_rad_s, r_rad_s, ax_m_s2, ay_m_s2, az_m_s2, agl_m
    cdef public bint on_ground

cdef class Multirotor:
    cdef public double _origin_lat, _origin_lon, _origin_alt, _cos_lat
    cdef public object fdm, _terrain
    cdef public list _motors, _drag
    cdef public dict _nodes
    cdef public VehicleState state

    @cython.locals(s=VehicleState)
    cpdef _read_state(self)

    @cython.locals(s=VehicleState, rho=cython.double, k=cython.double, air_n=cython.double, air_e=cython.double, air_d=cython.double, speed=cython.double)
    cpdef VehicleState step(self, motors, double terrain_up_m, double wind_n_m_s, double wind_e_m_s, double wind_d_m_s=*)
