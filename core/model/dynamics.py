"""The machine-dynamics TOML: the machine FMU's dynamic parameters (servo kv, backlash,
friction per axis; transport delay; thermal drift), keyed by the FMU's parameter names
(docs/model-loop.md).

```toml
step_s = 0.001                      # communication step the kv values are for (s)
[parameters]
"servo.kv.X" = 30.0                 # 1/s
"backlash.X" = 0.002                # mm (deg for a rotary axis)
"delay" = 0.0033                    # s
"friction.breakaway.X" = 0.003      # mm
"friction.tau.X" = 0.03             # s
"glitch.height.Y" = 0.002           # mm, quadrant glitch (spike form) peak
"glitch.time.Y" = 0.02              # s, reversal to peak
"velfriction.coulomb.C" = 0.5       # deg/s (mm/s), velocity friction of a velocity-mode axis
"velfriction.viscous.C" = 0.01      # 1
"velfriction.vs.C" = 2.0            # deg/s (mm/s), tanh smoothing speed
"encoder.period.X" = 0.02           # mm (deg), encoder signal period of the cyclic error (0: off)
"encoder.a1.X" = 0.0002             # mm (deg), first harmonic amplitude
"encoder.phase1.X" = 40.0           # deg
"thermal.driver" = 0                # 0 spindle speed, 1 temperature input, 2 none (time)
"thermal.drift.z" = 0.004           # mm/K
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

# per-axis parameters: name prefix -> MachineDynamics field
AXIS_PREFIXES = {"servo.kv.": "kv", "backlash.": "backlash", "friction.breakaway.": "friction_breakaway",
                 "friction.coulomb.": "friction_coulomb", "friction.tau.": "friction_tau",
                 "glitch.height.": "glitch_height", "glitch.time.": "glitch_time",
                 "velfriction.coulomb.": "velfriction_coulomb", "velfriction.viscous.": "velfriction_viscous",
                 "velfriction.vs.": "velfriction_vs", "encoder.period.": "encoder_period",
                 "encoder.a1.": "encoder_a1", "encoder.phase1.": "encoder_phase1", "encoder.a2.": "encoder_a2",
                 "encoder.phase2.": "encoder_phase2"}
# per-axis parameters that may be negative: their range (the FMU's)
SIGNED = {"backlash.": 1.0, "glitch.height.": 1.0, "velfriction.coulomb.": 1e4, "velfriction.viscous.": 1.0,
          "encoder.a1.": 1.0, "encoder.phase1.": 720.0, "encoder.a2.": 1.0, "encoder.phase2.": 720.0}
# scalar parameters: name -> (MachineDynamics field, lowest value, highest value)
SCALARS = {"delay": ("delay", 0.0, 1.0), "servo.interpolation": ("interpolation", 0, 1),
           "thermal.driver": ("thermal_driver", 0, 2), "thermal.gain": ("thermal_gain", 0.0, 1.0),
           "thermal.time_constant": ("thermal_time_constant", 1e-3, 1e6),
           "thermal.ambient": ("ambient", -50.0, 100.0), "thermal.initial_excess": ("initial_excess", -100.0, 100.0),
           "thermal.reference": ("reference", -50.0, 100.0)}
DRIFT = {"thermal.drift.x": 0, "thermal.drift.y": 1, "thermal.drift.z": 2}
INTEGERS = ("thermal.driver", "servo.interpolation")
PREFIXES = tuple(AXIS_PREFIXES) + tuple(SCALARS) + tuple(DRIFT)


def is_dynamics(name: str) -> bool:
    """Is `name` a dynamics parameter of the machine FMU (not a geometric or setting error)?"""
    return name in SCALARS or name in DRIFT or any(name.startswith(p) for p in AXIS_PREFIXES)


def dynamics_dict(params, step: float | None) -> dict:
    """The TOML structure of a list of mapping.Param (dynamics only)."""
    data: dict = {}
    if step:
        data["step_s"] = float(step)
    data["parameters"] = {p.name: (int(p.value) if p.name in INTEGERS else float(p.value)) for p in params}
    unc = {p.name: float(p.sigma) for p in params if p.sigma is not None and math.isfinite(p.sigma)}
    if unc:
        data["uncertainty"] = unc
    data["units"] = {p.name: p.unit for p in params}
    return data


def save_dynamics(path, params, step: float | None) -> Path:
    header = "# mtcomp machine dynamics (docs/model-loop.md): machine FMU parameter names, 1/s, mm, deg, s, K\n"
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
        pref = next((p for p in AXIS_PREFIXES if k.startswith(p)), None)
        if pref is None and k not in SCALARS and k not in DRIFT:
            raise InputError(f"unknown dynamics parameter {k!r}; expected servo.kv.<AXIS>, backlash.<AXIS>, "
                             "friction.{breakaway,coulomb,tau}.<AXIS>, glitch.{height,time}.<AXIS>, "
                             "velfriction.{coulomb,viscous,vs}.<AXIS>, encoder.{period,a1,phase1,a2,phase2}.<AXIS>, delay, servo.interpolation or thermal.*",
                             path, field=f"parameters.{k}")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise InputError(f"expected a finite number, got {v!r}", path, field=f"parameters.{k}")
        if pref is not None:
            if pref in SIGNED and abs(v) > SIGNED[pref]:
                raise InputError(f"expected a number within +-{SIGNED[pref]:g}, got {v!r}", path,
                                 field=f"parameters.{k}")
            if pref not in SIGNED and v < 0:
                raise InputError(f"expected a number >= 0, got {v!r}", path, field=f"parameters.{k}")
            ax = k[len(pref):]
            if axes is not None and ax not in axes:
                raise InputError(f"axis {ax} not on machine {machine.name!r} (axes {' '.join(axes)})", path,
                                 field=f"parameters.{k}")
        elif k in SCALARS:
            _, lo, hi = SCALARS[k]
            if not lo <= v <= hi or (k in INTEGERS and v != int(v)):
                raise InputError(f"expected {'an integer' if k in INTEGERS else 'a number'} in [{lo}, {hi}], "
                                 f"got {v!r}", path, field=f"parameters.{k}")
        elif abs(v) > 1.0:
            raise InputError(f"expected a drift within +-1 mm/K, got {v!r}", path, field=f"parameters.{k}")
        out[k] = float(v)
    return out


def apply_dynamics(base, params: dict, machine, *, combine: bool = True):
    """MachineDynamics `base` with the fitted parameters applied.

    combine: the fitted values describe what the base model lacked (the diagnosis fits
    REC - SIM): backlash widths and delays add; servo lags add as time constants in series
    (1/kv = 1/kv_base + 1/kv_fit, to first order), kv_base = 0 being the ideal servo; friction,
    the velocity friction, the quadrant glitch, the encoder cyclic error and the thermal model replace the base's (one thermal state: a fitted drift replaces the
    base's).  Without combine the fitted values replace the base ones."""
    names = machine.axis_names
    n = len(names)
    axis = {f: list(base.per_axis(getattr(base, f), n, f)) for f in AXIS_PREFIXES.values()}
    changes: dict = {}
    drift = list(base.drift)
    for k, v in params.items():
        pref = next((p for p in AXIS_PREFIXES if k.startswith(p)), None)
        if pref is not None:
            f = AXIS_PREFIXES[pref]
            i = names.index(k[len(pref):])
            if f == "kv" and combine and axis[f][i] > 0 and v > 0:
                axis[f][i] = 1.0 / (1.0 / axis[f][i] + 1.0 / v)
            elif f == "backlash" and combine:
                axis[f][i] += v
            else:
                axis[f][i] = v
        elif k in SCALARS:
            f = SCALARS[k][0]
            if f == "delay" and combine:
                v = base.delay + v
            changes[f] = int(v) if k in INTEGERS else float(v)
        elif k in DRIFT:
            drift[DRIFT[k]] = float(v)
    return replace(base, **{f: tuple(v) for f, v in axis.items()}, drift=tuple(drift), **changes)
