"""mtcomp: machine-tool error compensation for ultraprecision and multi-axis machining.

Units at every interface: mm, deg, s, degC.  Heavy optional dependencies (cadquery, fmpy,
pymodbus) are imported lazily by the modules that need them, never from here.
"""
__version__ = "0.1.0"

from ._io import MtcompError, InputError  # noqa: F401
