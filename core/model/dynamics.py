"""The machine-dynamics TOML: servo kv and backlash per axis, keyed by the machine FMU's
parameter names (docs/model-loop.md).

```toml
step_s = 0.001                      # communication step the kv values are for (s)
[parameters]
"servo.kv.X" = 30.0                 # 1/s
"backlash.X" = 0.002                # mm (deg for a rotary axis)
[uncertainty]                       # one standard deviation, same keys (informational)
"servo.kv.X" = 0.004
[units]
"servo.kv.X" = "1/s"
```
"""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

from .._io import InputError, atomic_write, dump_toml, parse_toml, read_text

PREFIXES = {"servo.kv.": "kv", "backlash.": "backlash"}


def dynamics_dict(params, step: float | None) -> dict:
    """The TOML structure of a list of mapping.Param (dynamics only)."""
    data: dict = {}
    if step:
        data["step_s"] = float(step)
    data["parameters"] = {p.name: float(p.value) for p in params}
    unc = {p.name: float(p.sigma) for p in params if p.sigma is not None and math.isfinite(p.sigma)}
    if unc:
        data["uncertainty"] = unc
    data["units"] = {p.name: p.unit for p in params}
    return data


def save_dynamics(path, params, step: float | None) -> Path:
    header = "# mtcomp machine dynamics (docs/model-loop.md): machine FMU parameter names, 1/s, mm, deg\n"
    return atomic_write(path, header + dump_toml(dynamics_dict(params, step)))


def load_dynamics(path, machine=None) -> dict:
    """{FMU parameter name: value} of a dynamics TOML, checked (names, numbers >= 0, axes of
    `machine` when given)."""
    path = Path(path)
    text = read_text(path, what="dynamics file")
    data = parse_toml(text, path)
    params = data.get("parameters", {})
    if not isinstance(params, dict):
        raise InputError("expected a table of parameters", path, field="parameters")
    axes = tuple(machine.axis_names) if machine is not None else None
    out = {}
    for k, v in params.items():
        pref = next((p for p in PREFIXES if k.startswith(p)), None)
        if pref is None:
            raise InputError(f"unknown dynamics parameter {k!r}; expected servo.kv.<AXIS> or backlash.<AXIS>",
                             path, field=f"parameters.{k}")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise InputError(f"expected a finite number >= 0, got {v!r}", path, field=f"parameters.{k}")
        ax = k[len(pref):]
        if axes is not None and ax not in axes:
            raise InputError(f"axis {ax} not on machine {machine.name!r} (axes {' '.join(axes)})", path,
                             field=f"parameters.{k}")
        out[k] = float(v)
    return out


def apply_dynamics(base, params: dict, machine, *, combine: bool = True):
    """MachineDynamics `base` with the fitted parameters applied.

    combine: the fitted values describe what the base model lacked (the diagnosis fits
    REC - SIM): backlash widths add; servo lags add as time constants in series
    (1/kv = 1/kv_base + 1/kv_fit, to first order), kv_base = 0 being the ideal servo.
    Without combine the fitted values replace the base ones."""
    names = machine.axis_names
    n = len(names)
    kv = list(base.per_axis(base.kv, n, "kv"))
    bl = list(base.per_axis(base.backlash, n, "backlash"))
    for k, v in params.items():
        if k.startswith("servo.kv."):
            i = names.index(k[len("servo.kv."):])
            if combine and kv[i] > 0 and v > 0:
                kv[i] = 1.0 / (1.0 / kv[i] + 1.0 / v)
            else:
                kv[i] = v
        elif k.startswith("backlash."):
            i = names.index(k[len("backlash."):])
            bl[i] = bl[i] + v if combine else v
    return replace(base, kv=tuple(kv), backlash=tuple(bl))
