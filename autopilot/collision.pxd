# Static types for the compiled module (setup.py): collision.py stays the plain Python source.
cimport simlink.pymath as math
import cython

cdef class ObstacleMap:
    cdef public object fault
    cdef public list distances, occupied, unknown, view_at_reach, seen_at_reach
    cdef public double updated_s, max_range_m
    cdef public dict sources

    @cython.locals(bins=list, step=cython.double, offset=cython.double, reference=cython.double, sign=cython.double, index=cython.Py_ssize_t,
                   raw=cython.long, world=cython.double, target=cython.int, value=cython.double)
    cpdef update(self, double now_s, double yaw_rad, list distances_cm, double increment_deg, double angle_offset_deg, long min_cm, long max_cm)

    cpdef tuple _frame(self, double yaw_rad)

    @cython.locals(reading=cython.double, value=cython.double, centre_deg=cython.double, half_deg=cython.double, bin_deg=cython.double,
                   reference=cython.double, sign=cython.double, body_bin=cython.int, world=cython.double, bins=list)
    cpdef update_distance_sensor(self, double now_s, double yaw_rad, int sensor_id, double distance_m, double min_m, double max_m,
                                 double sensor_yaw_rad, double fov_rad, double horizontal_scale)

    @cython.locals(reaches=list)
    cpdef _enter(self, tuple source, double now_s, double reach_m, list bins)

    cpdef bint fresh(self, double now_s)

@cython.locals(bins=list, reaches=list, latest=list, heard_s=cython.double, reach_m=cython.double, i=cython.Py_ssize_t, better=cython.bint)
cpdef tuple _fused(list sources)

cpdef int _round_half_away(double x)

cpdef int _bin_of(double angle_rad)

cpdef _clearance_around(list distances, int index)

@cython.locals(b=cython.double)
cpdef double max_speed_from_distance(double jerk, double accel, double distance)

@cython.locals(home=cython.int, span=cython.int, offset=cython.int)
cpdef double guided_direction(ObstacleMap obstacles, double direction_rad, double guide_angle_rad, double needed_m)

@cython.locals(cp_dist=cython.double, vn=cython.double, ve=cython.double, speed=cython.double, acc=cython.double, jerk=cython.double, delay=cython.double,
               narrow_view=cython.bint, braking_m=cython.double, direction=cython.double, bin_n=cython.double, bin_e=cython.double,
               distance=cython.double, towards=cython.double, stop_distance=cython.double, allowed=cython.double, along=cython.double, changed=cython.bint)
cpdef constrain_velocity(params, ObstacleMap obstacles, double now_s, setpoint_ne, velocity_ne)

cpdef double _stick_scale(double distance, double keep, double scale_distance)

@cython.locals(best_cost=cython.double, best=cython.int, span=cython.int, i=cython.int, j=cython.int, mean=cython.double, cost=cython.double)
cpdef int px4_guided_bin(list view, int home, double keep, double guide_angle_deg)

@cython.locals(a_n=cython.double, a_e=cython.double, length=cython.double, keep=cython.double, scale_distance=cython.double,
               closest_n=cython.double, closest_e=cython.double, closest=cython.double, dir_n=cython.double, dir_e=cython.double,
               new_n=cython.double, new_e=cython.double, towards=cython.double, normal_n=cython.double, normal_e=cython.double,
               tangential_n=cython.double, tangential_e=cython.double, along=cython.double, normal_scale=cython.double,
               tangential_scale=cython.double, delay=cython.double, age=cython.double, gain=cython.double, braking=cython.double,
               brake_n=cython.double, brake_e=cython.double, bin_n=cython.double, bin_e=cython.double, distance=cython.double,
               parallel=cython.double, delay_m=cython.double, stop_distance=cython.double, constraint=cython.double, index=cython.int, home=cython.int, in_range=cython.bint,
               view=list, seen=list)
cpdef tuple px4_stick_acceleration(params, ObstacleMap obstacles, double now_s, tuple accel_ne, tuple velocity_ne)
