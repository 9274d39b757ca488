"""Synthetic error sets on the increment grid every control here holds: round-trip test data.

Values are whole multiples of 0.1 µm (linear) and 0.0001 deg (rotary positioning errors, held
in rad as the radians of that many degrees), positions equally spaced over the travel with a
point at 0, pitch changes small enough for Fanuc's +-7 increments per point -- so that an export
followed by an import gives back the very same floats for every control.
"""
from __future__ import annotations

import numpy as np

from ..errors import AxisErrorTable, ErrorSet, GeometricErrors
from ..geometric.reversal import ReversalTable
from ..machine import Machine, load_machine

__all__ = ["grid_errors"]

_Q = 10_000          # 1 / 0.1 µm in mm, 1 / 0.0001 deg


def _positions(axis, n: int = 20) -> np.ndarray:
    lo, hi = axis.limits
    span = min(hi, 360.0) - max(lo, -360.0)
    step = span / n
    k = np.arange(-(n // 2), n // 2 + 1)
    return k * (step * _Q) / _Q if (step * _Q).is_integer() else k * float(int(step))


def _walk(rng, m: int, r: int, max_step: int) -> np.ndarray:
    """Integer random walk, 0 at index r, steps within +-max_step."""
    s = rng.integers(-max_step, max_step + 1, m)
    c = np.cumsum(s)
    return c - c[r]


def grid_errors(machine: Machine | str, seed: int = 0, reversal: bool = True) -> tuple[ErrorSet, dict]:
    """(ErrorSet, {axis: ReversalTable}) of a machine: pitch, straightness and angular tables of
    every linear axis, pitch of every rotary axis, squareness and rotary location errors."""
    machine = load_machine(machine)
    rng = np.random.default_rng(seed)
    tables, rev, loc = {}, {}, {}
    for a in machine.axes:
        pos = _positions(a)
        m = pos.size
        r = int(np.argmin(np.abs(pos)))
        name = a.name
        if a.is_rotary:
            n = _walk(rng, m, r, 7)
            tables[name] = AxisErrorTable(name, pos, {f"E{name}{name}": -np.radians(n / _Q)})
            continue
        # positioning: the positive direction's error is 0 at the reference position (Fanuc's convention)
        half = rng.integers(1, 4)
        mean = _walk(rng, m, r, 5) + half
        vals = {f"E{name}{name}": mean / _Q}
        for d in "XYZ":
            if d != name:
                vals[f"E{d}{name}"] = _walk(rng, m, r, 3) / _Q
        for d in "ABC":
            vals[f"E{d}{name}"] = rng.normal(0, 2e-6, m)
        tables[name] = AxisErrorTable(name, pos, vals)
        if reversal:
            # dev_up - dev_down = -2 half increments: up = mean - half, down = mean + half
            rev[name] = ReversalTable(name, pos, -np.full(m, half / _Q), np.full(m, half / _Q))
    lin = [a.name for a in machine.axes if not a.is_rotary]
    if {"X", "Y"} <= set(lin):
        loc["EC0Y"] = 3.0e-6
    for a in machine.axes:
        if a.is_rotary:
            for c in "XYZ":
                if c != "XYZ"["ABC".index(a.name)]:
                    loc[f"E{c}0{a.name}"] = int(rng.integers(-50, 51)) / _Q
            for c in "ABC":     # tilts and zero error: whole 0.00001 deg (0.17 µrad)
                loc[f"E{c}0{a.name}"] = float(np.radians(int(rng.integers(-40, 41)) / 100_000))
    return ErrorSet(geometric=GeometricErrors(tables, loc)), rev
