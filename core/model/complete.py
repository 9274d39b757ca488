"""Complete a model the re-simulation calls incomplete: try the dynamics the diagnosis may have
missed, through the machine model itself.

A servo lag seen together with a small backlash is often diagnosed as the lag alone, its gain
biased to absorb the reversals (lag 8 ms + backlash 3 µm: kv 113 for 125 1/s, no backlash);
the re-simulation then stays far above its floor.  For each linear axis that reverses and
has no backlash in the model, a backlash is added (started at 1 µm) and every scalar refitted
through the machine FMU (simulate.refine: fitted on the first 70 % of the training samples,
kept only when the other 30 % agree).  Written by hand: a model search through an FMU has no
library.
"""
from __future__ import annotations

import numpy as np

from ..machine import load_machine
from .mapping import Mapped, Param


def reversing_axes(machine, q: np.ndarray, tol: float = 1e-9) -> list:
    """Linear axes whose commands q (K, n) change direction at least once."""
    machine = load_machine(machine)
    out = []
    for i, a in enumerate(machine.axes):
        if a.is_rotary:
            continue
        d = np.diff(np.asarray(q, float)[:, i])
        s = np.sign(d[np.abs(d) > tol])
        if s.size and np.any(s[1:] != s[:-1]):
            out.append(a.name)
    return out


def with_backlash(ex, axes, start: float = 1e-3):
    """The export with a backlash effect added on each of `axes` that has none."""
    from .export import _assemble
    have = {p.name for p in ex.params}
    extra = tuple(Mapped("backlash", a.lower(), (Param(f"backlash.{a}", float(start), float(start), "mm"),),
                         notes=("added by the model completion (not named by the diagnosis)",))
                  for a in axes if f"backlash.{a}" not in have)
    if not extra:
        return ex
    return _assemble(ex.mapped + extra, ex.unmapped, ex.machine_obj, ex.step)


def complete(ex, t_rec, rec: dict, *, program, machine, q, log: list | None = None, **kw):
    """The export completed with the backlash of the reversing axes, refitted through the model
    (kw: simulate.refine's keywords), or `ex` when the validation samples do not agree."""
    from .simulate import refine
    cand = with_backlash(ex, reversing_axes(machine, q))
    if cand is ex:
        return ex
    sub: list = []
    out = refine(cand, t_rec, rec, program=program, machine=machine, log=sub, **kw)
    if out is cand:     # refused: nothing changed but the added effects
        if log is not None:
            log.append("completion refused: " + "; ".join(sub))
        return ex
    if log is not None:
        log += ["completion: " + s for s in sub]
    return out
