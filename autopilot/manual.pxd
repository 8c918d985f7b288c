# Static types for the compiled module (setup.py): manual.py stays the plain Python source.
cimport simlink.pymath as math
