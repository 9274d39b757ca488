"""The `--cosim` claim with the model's own uncertainty: a band, not a number.

`compare_compensations` runs the compensated program on the machine the model describes: the
model judging itself.  Its fitted parameters are uncertain (the sigmas the export wrote beside
them), so the part error a real machine of that description leaves is uncertain too.  The band
re-runs the compensated program on machines drawn from the model's parameter distribution
(independent normal draws of every parameter with a sigma: dynamics and location errors) and
reports the spread of the part error: [lowest, highest] over the draws, widened to mean +/- 2
standard deviations where that is wider.  What the band cannot hold is physics the model lacks
(a wrong effect shape); an independent simulator shows that (benchmarks/model_judged.py).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .._io import parse_toml, read_text
from ..errors import ErrorSet, GeometricErrors
from ..machine import load_machine


def model_sigmas(folder) -> dict:
    """{parameter name: 1 sigma} of a model folder: dynamics.toml's and errors.toml's
    [uncertainty] tables (scalar entries only)."""
    out = {}
    for name in ("dynamics.toml", "errors.toml"):
        p = Path(folder) / name
        if not p.is_file():
            continue
        unc = parse_toml(read_text(p, what="model file"), p).get("uncertainty", {})
        if isinstance(unc, dict):
            for k, v in unc.items():
                if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0:
                    out[str(k)] = float(v)
    return out


def _drawn(errors: ErrorSet, params: dict, sigmas: dict, rng, machine):
    from .compensate import model_dynamics
    p = dict(params)
    loc = dict(errors.geometric.location)
    for k, s in sigmas.items():
        if k in p and k not in ("thermal.driver", "servo.interpolation"):
            v = p[k] + rng.normal(0.0, s)
            # the FMU's ranges: gains, times and plays stay positive where they were
            p[k] = max(v, 1e-9) if p[k] > 0 and k.startswith(("servo.kv.", "thermal.time_constant", "friction.tau.",
                                                                "glitch.time.")) else v
        elif k.startswith("location."):
            key = k[len("location."):]
            loc[key] = loc.get(key, 0.0) + rng.normal(0.0, s)
    err = ErrorSet(errors.tool, errors.workpiece, GeometricErrors(errors.geometric.tables, loc))
    return err, p


def claim_band(program: str, compensated: str, machine, errors: ErrorSet, dynamics, sigmas: dict, *,
               draws: int = 8, seed: int = 0, rapid: float = 3000.0, compiler: str = "cmake") -> dict:
    """{"max"|"rms": (low, high) mm} of the part error of the compensated program on machines
    drawn from the model (dynamics: compensate.ModelDynamics; sigmas: model_sigmas), and
    "draws": the number of draws (0 when no parameter has a sigma: the band is the claim),
    "unidentified": the parameters left out of the draws (sigma above their value)."""
    from .compensate import model_dynamics, part_error
    from .simulate import simulate
    from .thermal_comp import spindle_profile
    machine = load_machine(machine)
    rng = np.random.default_rng(seed)
    used = {k: s for k, s in sigmas.items() if k in dynamics.params or k.startswith("location.")}
    # a parameter whose sigma exceeds its value was not identified by the fit: drawing it would
    # run machines far outside anything the data allow (or the FMU's ranges); listed apart
    loc = errors.geometric.location
    vague = sorted(k for k, s in used.items()
                   if s > abs(dynamics.params.get(k, loc.get(k[len("location."):], 0.0) if k.startswith("location.")
                                                  else 0.0)))
    used = {k: s for k, s in used.items() if k not in vague}
    if not used:
        draws = 0
    figs = {"max": [], "rms": []}
    sp = spindle_profile(compensated, machine, dynamics.step, rapid=rapid)
    from .._io import MtcompError
    for _ in range(max(draws, 1)):
        err, params = _drawn(errors, dynamics.params, used, rng, machine) if draws else (errors, dynamics.params)
        dyn = model_dynamics(params, machine, dynamics.step).machine_dynamics(machine)
        try:
            sig = simulate(compensated, machine, err, dyn, step=dynamics.step, compiler=compiler,
                           spindle_speed=np.abs(sp) if np.any(sp) else 0.0)
        except MtcompError:     # a draw outside the FMU's ranges
            continue
        pe = part_error(program, sig, machine, rapid=rapid)
        figs["max"].append(pe["max"])
        figs["rms"].append(pe["rms"])
    out = {"draws": draws, "unidentified": vague}
    for k, v in figs.items():
        v = np.asarray(v)
        lo, hi = float(v.min()), float(v.max())
        if len(v) > 2:
            lo, hi = min(lo, max(0.0, float(v.mean() - 2 * v.std(ddof=1)))), max(hi, float(v.mean() + 2 * v.std(ddof=1)))
        out[k] = (lo, hi)
    return out
