"""The drivers a re-simulation needs, from wherever they were recorded.

The machine FMU's thermal state is driven by the spindle speed (thermal.driver = 0) or by a
logged temperature (thermal.driver = 1); a model whose drift is driven by one of them can only
be re-simulated with that driver fed over the run.  The diagnosis takes its drivers from SIM
or from REC (a temperature is often logged only with the recording), so the re-simulation
looks in the same places: REC's columns first (what was measured during the recorded run),
then SIM's (its driver columns or its constant spindle speed).  A model effect whose driver is
in neither is not re-simulated, and said so by name: silently re-simulating a thermal drift
with a constant temperature would leave its whole drift in the residual.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._io import InputError

DRIVER_NAMES = {0: "spindle_speed", 1: "temperature"}
# the column names and units a recording logs its drivers with (csvtable units)
_COLUMN = {"spindle_speed": (("spindle_speed", "spindle", "spindle_rpm"), "rpm"),
           "temperature": (("temperature", "temp", "t_machine"), "degC")}


@dataclass(frozen=True)
class ResimDrivers:
    """spindle_speed, temperature: what simulate() takes (a number, (K,) per step, or a callable
    of t in s; None: not available); sources: {driver: "REC column <name>" | "SIM ..."};
    skipped: {FMU parameter prefix: reason} of model parameters left out of the re-simulation
    (their driver was not recorded); notes: lines for the report."""
    spindle_speed: object = 0.0
    temperature: object = None
    sources: dict = field(default_factory=dict)
    skipped: dict = field(default_factory=dict)
    notes: tuple = ()


def recording_drivers(path) -> dict:
    """{"spindle_speed"|"temperature": (column name, t (K,) s, values (K,))} of the driver
    columns of a recording CSV: a column named like the driver (spindle_speed, temperature,
    ...) or, failing that, the one column whose unit is of the driver's quantity (rpm or 1/min;
    degC or K)."""
    from ..csvtable import read_csv
    tab = read_csv(path, what="recording", required=("t",))
    t = tab.numbers("t", unit="s")
    out = {}
    for drv, (names, unit) in _COLUMN.items():
        cols = [c for c in tab.columns if c.name.lower() in names and c.name.lower() != "t"]
        if not cols:
            cols = [c for c in tab.columns if c.unit and _unit_of(c.unit) == unit]
            if len(cols) != 1:
                continue
        c = cols[0]
        try:
            v = tab.numbers(c.name, unit=unit)
        except (InputError, KeyError):
            continue
        out[drv] = (c.name, t, v)
    return out


def _unit_of(u: str) -> str | None:
    u = u.strip().lower()
    if u in ("rpm", "1/min", "rev/min", "min-1", "min^-1"):
        return "rpm"
    if u in ("degc", "°c", "c", "k"):
        return "degC"
    return None


def model_driver(params: dict) -> str | None:
    """The driver the model's thermal drift needs ("spindle_speed" | "temperature"), None when
    the model has no drift or a time-driven one.  params: the model's dynamics {name: value}."""
    if not any(float(v) != 0.0 for k, v in params.items() if k.startswith("thermal.drift.")):
        return None
    return DRIVER_NAMES.get(int(params.get("thermal.driver", 0)))


def resolve(params: dict, *, sim_spindle=0.0, sim_temperature=None, rec=None) -> ResimDrivers:
    """Pick the drivers of a re-simulation.  params: the model's dynamics {name: value};
    sim_spindle / sim_temperature: SIM's (provenance: a number or (K,) per step; None: not
    logged); rec: REC's path, or {driver: (column, t, values)} (recording_drivers)."""
    rec_d = recording_drivers(rec) if isinstance(rec, (str, Path)) else dict(rec or {})
    spindle, temp, sources = sim_spindle, sim_temperature, {}
    if callable(sim_spindle) or np.ndim(sim_spindle) > 0 or (sim_spindle is not None and float(sim_spindle) != 0.0):
        sources["spindle_speed"] = "SIM"
    if sim_temperature is not None:
        sources["temperature"] = "SIM"
    for drv, (col, t, v) in rec_d.items():
        fn = _interp(np.asarray(t, float), np.asarray(v, float))
        if drv == "spindle_speed":
            spindle = fn
        else:
            temp = fn
        sources[drv] = f"REC column {col}"
    need = model_driver(params)
    skipped, notes = {}, []
    if need is not None and need not in sources:
        why = (f"its driver, the {need.replace('_', ' ')}, is logged neither in REC nor in SIM: "
               "the thermal drift is NOT re-simulated")
        skipped["thermal.drift."] = why
        notes.append(f"thermal_drift: {why}")
    for drv, src in sources.items():
        notes.append(f"driver {drv.replace('_', ' ')} from {src}"
                     + (" (used by the model's thermal drift)" if drv == need else ""))
    return ResimDrivers(spindle, temp, sources, skipped, tuple(notes))


def _interp(t, v):
    return lambda tt: np.interp(tt, t, v)


def without(params: dict, skipped: dict) -> dict:
    """The dynamics {name: value} with the skipped parameters' effect removed (drifts to 0)."""
    return {k: (0.0 if any(k.startswith(p) for p in skipped) else v) for k, v in params.items()}
