"""mtcomp.diagnose: locate where a simulation and a recording disagree, name the physical
effect the simulation left out, fit it, and show the fit improve on held-out data.

``diagnose(sim, rec) -> DiagnosisResult`` (paths or mappings of arrays).  Submodules: data (CSV
and units), align (clocks, grid, noise floor), locate (spans and conditions), effects (the
library of physical effects), select (fitting, BIC and cross-validation), report, synth
(generated cases), cli.  Importing the package is cheap: numpy/scipy load on first use.
"""
from __future__ import annotations

__all__ = ["diagnose", "DiagnosisResult", "EffectResult", "Settings"]


def __getattr__(name):
    if name in ("diagnose", "DiagnosisResult", "EffectResult"):
        from . import engine
        return getattr(engine, name)
    if name == "Settings":
        from .select import Settings
        return Settings
    raise AttributeError(f"module 'mtcomp.diagnose' has no attribute {name!r}")
