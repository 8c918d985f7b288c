# Static types for the compiled module (setup.py): frames.py stays the plain Python source.
cimport simlink.pymath as math
import cython
from sim_bridge.physics cimport VehicleState
from sim_bridge.world cimport World

cdef class SensorFrames:
    cdef public World world
    cdef public object range_messages, recorder, failures, rig
    cdef public dict every
    cdef public int seq, companion_seq
    cdef public list companion_out
    cdef public list wedges

    cpdef int next_seq(self)

    @cython.locals(world=World, s=VehicleState, frames=list)
    cpdef bytes step_frames(self, long long step, long long time_us)

    cpdef gps_fix(self)
