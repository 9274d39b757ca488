"""FMUs of the compensation core and a machine model (FMI 2.0 and 3.0 Co-Simulation), and
co-simulation with fmpy as the master (docs/fmu.md).

The entry points are imported on first use, so `import mtcomp.fmu` stays light:
`build_compensator_fmu`, `build_machine_fmu`, `build_passthrough_fmu`, `MachineDynamics`
(mtcomp.fmu.build), `cosimulate`, `interpolate_program`, `CosimResult`, `CosimFailed` (mtcomp.fmu.cosim), `write_ssp`
(mtcomp.fmu.ssp), `build_python_compensator_fmu` (mtcomp.fmu.pyfmu).
"""
from importlib import import_module

_ENTRY_POINTS = {
    "build_compensator_fmu": "build", "build_machine_fmu": "build", "MachineDynamics": "build",
    "build_passthrough_fmu": "build", "cosimulate": "cosim", "interpolate_program": "cosim",
    "CosimResult": "cosim", "CosimFailed": "cosim",
    "write_ssp": "ssp", "build_python_compensator_fmu": "pyfmu",
}

__all__ = sorted(_ENTRY_POINTS)


def __getattr__(name):
    if name in _ENTRY_POINTS:
        return getattr(import_module(f"{__name__}.{_ENTRY_POINTS[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
