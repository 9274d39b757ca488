"""mtcomp.model: close the loop from a diagnosis back into the machine model.

``export_model(diagnosis, machine, outdir)`` writes the fitted effects of `mtcomp diagnose
--json` in the model's own formats (errors TOML and tables, machine dynamics TOML, SSP
parameter set); ``simulate`` / ``resimulate`` run the machine FMU with the base and the updated
parameters and compare both with the recording.  docs/model-loop.md.

Submodules: axes (which machine axis an output follows), mapping (one function per effect:
effect -> model parameters), export (the files), dynamics (the dynamics TOML), simulate
(co-simulation, provenance sidecar, re-simulation and its figure), cli.
"""
from __future__ import annotations

__all__ = ["export_model", "ModelExport", "simulate", "resimulate", "ResimResult", "load_dynamics"]


def __getattr__(name):
    if name in ("export_model", "ModelExport"):
        from . import export
        return getattr(export, name)
    if name in ("simulate", "resimulate", "ResimResult"):
        from . import simulate
        return getattr(simulate, name)
    if name == "load_dynamics":
        from .dynamics import load_dynamics
        return load_dynamics
    raise AttributeError(f"module 'mtcomp.model' has no attribute {name!r}")
