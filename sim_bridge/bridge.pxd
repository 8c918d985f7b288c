# Static types for the compiled module (setup.py): bridge.py stays the plain Python source.
cimport simlink.pymath as math
import cython
from sim_bridge.physics cimport VehicleState
from sim_bridge.world cimport World
from sim_bridge.frames cimport SensorFrames

cdef class Bridge:
    cdef public object config, recorder, summary, _control, _hold_deadline, failures, _awaiting_injection, _json
    cdef public World world
    cdef public SensorFrames frames
    cdef public dict _every
    cdef public bytearray _link_out, _link_in, _link_companion
    cdef public object _companion
    cdef public tuple _clearance_batch
    cdef public bint _hold_announced

    @cython.locals(s=VehicleState)
    cpdef _record_pose(self, long long time_ns)

    @cython.locals(time_s=cython.double, time_ns=cython.longlong, batch=tuple)
    cpdef _observe(self, long long step)

    @cython.locals(world=World, answered=cython.bint, echoed=cython.bint, answer_time_us=cython.ulonglong)
    cpdef bint _receive_answer(self, sut, splitter, bint lockstep, long long time_us, double waiting_since)

    @cython.locals(world=World, step=cython.longlong, time_us=cython.longlong, time_s=cython.double, lockstep=cython.bint,
                   ts=cython.double, t_send=cython.double, t_sent=cython.double, t0=cython.double, t1=cython.double, t2=cython.double)
    cpdef run(self, sut, control)
