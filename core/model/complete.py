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
    if out is not cand:
        # an added backlash the refit leaves within 2 sigma of 0 is not kept
        added = {f"backlash.{a}" for a in reversing_axes(machine, q)} - {p.name for p in ex.params}
        keep = [i for i, m in enumerate(out.mapped)
                if not (m.params and all(p.name in added and (p.sigma is None or abs(p.value) < 2 * p.sigma)
                                         for p in m.params))]
        if len(keep) < len(out.mapped):
            out = out.subset(keep)
    # judged against the model as it came (not the start with 1 µm plays added)
    better = out is not cand and _validation(out, t_rec, rec, program, machine, kw) < \
        _validation(ex, t_rec, rec, program, machine, kw)
    if not better:
        if log is not None:
            log.append("completion refused: the validation error does not fall below the model's as it came; "
                       + "; ".join(s for s in sub if s.startswith("refine")))
        return ex
    if log is not None:
        log += ["completion: " + s for s in sub]
    return out


def _validation(model, t_rec, rec, program, machine, kw) -> float:
    """The error on the validation samples (simulate._split) of the re-simulated model."""
    from dataclasses import replace

    from ..errors import ErrorSet
    from ..fmu.build import MachineDynamics
    from .simulate import _score, _split
    t_rec = np.asarray(t_rec, float)
    _, val, _ = _split(t_rec, kw.get("train_until"))
    base_dyn = replace(kw.get("dynamics") or MachineDynamics(), noise=0.0)
    return _score(model, t_rec, rec, val, program=program, machine=load_machine(machine),
                  base_err=kw.get("errors") or ErrorSet(), base_dyn=base_dyn, step=kw["step"],
                  spindle_speed=kw.get("spindle_speed", 0.0), temperature=kw.get("temperature"),
                  nf=dict(kw.get("noise_floor") or {}), compiler=kw.get("compiler", "cmake"))
