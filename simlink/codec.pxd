# Static types for the compiled module (setup.py): codec.py stays the plain Python source.
import cython

cpdef bytes _frame(int msgid, int crc_extra, payload, seq, sysid, compid)

cdef class FrameSplitter:
    cdef public bytearray _buffer
    cdef public dict _crc_extras
    cdef public long long skipped_bytes, bad_frames

    @cython.locals(length=cython.int, signed=cython.int, total=cython.Py_ssize_t, msgid=cython.int, crc_end=cython.Py_ssize_t)
    cpdef Py_ssize_t _check(self, bytearray buffer, Py_ssize_t start, Py_ssize_t end) except? -2

    @cython.locals(buffer=bytearray, position=cython.Py_ssize_t, end=cython.Py_ssize_t, start=cython.Py_ssize_t, total=cython.Py_ssize_t,
                   following=cython.Py_ssize_t, length=cython.int, msgid=cython.int, frame=bytes)
    cpdef list feed(self, data)
