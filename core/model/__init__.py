"""mtcomp.model: close the loop from a diagnosis back into the machine model.

``export_model(diagnosis, machine, outdir)`` writes the fitted effects of `mtcomp diagnose
--json` in the model's own formats (errors TOML and tables, machine dynamics TOML, SSP
parameter set); ``simulate`` / ``resimulate`` run the machine FMU with the base and the updated
parameters and compare both with the recording; ``compensate_with_model`` writes the program
compensated for the model's geometric errors, backlash, servo lag, friction at reversals, the
quadrant glitch and thermal drift (each switchable).  docs/model-loop.md.

Submodules: axes (which machine axis an output follows), mapping (one function per effect:
effect -> model parameters), export (the files), dynamics (the dynamics TOML), simulate
(co-simulation, provenance sidecar, re-simulation and its figure), loop (the loop in one
call), compensate (program compensation with the model, part error), friction_comp
(reversal spikes, the quadrant glitch's lead), thermal_comp (thermal offsets from the program's spindle speed or time; the
control's parameters for a logged temperature), story (the loop end to
end, the demo's stage: servo, backlash, squareness; then friction and thermal drift), machine_ref (the machine FMU's dynamics in Python, the reference the C
model is tested against), cli.
"""
from __future__ import annotations

__all__ = ["export_model", "ModelExport", "resimulate", "ResimResult", "close_loop", "load_dynamics",
           "compensate_with_model", "read_model", "part_error", "simulate_reference"]

# name -> submodule; the functions load on first use (numpy, scipy, fmpy stay unloaded until then).
# `simulate` is a submodule, so the function of that name is imported from it explicitly.
_WHERE = {"export_model": "export", "ModelExport": "export", "resimulate": "simulate",
          "ResimResult": "simulate", "close_loop": "loop", "load_dynamics": "dynamics",
          "compensate_with_model": "compensate", "read_model": "compensate", "part_error": "compensate",
          "simulate_reference": "machine_ref"}


def __getattr__(name):
    import importlib
    if name in _WHERE:
        return getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
    raise AttributeError(f"module 'mtcomp.model' has no attribute {name!r}")
