# Static types for the compiled module (setup.py): params.py stays the plain Python source.
# An extension type's __getitem__ is a C slot: the controllers read parameters dozens of times a step.
cimport simlink.pymath as math

cdef class Params:
    cdef public object fault
    cdef public dict _values
    cdef public dict unmodelled
