"""Several recordings of one machine on one grid: shared physics, a clock of their own each.

Each SIM/REC pair is aligned on its own (its clock offset, interpolant and gaps are its own);
the aligned pairs are then laid end to end on one uniform grid, each shifted in time to start a
gap after the one before.  The grid samples in the gaps are backed by no data (they take no
part in any fit or RMS): the drivers are ramped across them so that the effects' filters (lags,
thermal responses) settle before the next recording starts.  The effects are then fitted to all
recordings at once (one set of physical parameters), and validated leave-one-recording-out:
each recording is predicted by the model fitted on the others.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._io import InputError
from .align import Aligned, Signal, noise_sigma

# the grid samples between two recordings: long enough for a servo lag's or a delay's filter
# to settle on the ramp (several time constants of the slowest lag the library fits, 0.5 s)
GAP_S = 2.5
GAP_MIN_SAMPLES = 50


@dataclass(frozen=True)
class Recording:
    """Where one recording lies on the joint grid and how it was aligned."""
    name: str
    start: int            # first grid index
    stop: int             # one past the last grid index
    shift_s: float        # joint grid time = the recording's own (SIM clock) time + shift
    clock_offset_s: float  # REC clock - SIM clock of this pair, s

    def to_dict(self) -> dict:
        return {"name": self.name, "samples": self.stop - self.start,
                "clock_offset_s": self.clock_offset_s}


def _ramped(parts: list, gap: int) -> np.ndarray:
    """Arrays end to end, each gap filled by a straight line from one's last value to the
    next one's first."""
    out = [np.asarray(parts[0], float)]
    for a in parts[1:]:
        a = np.asarray(a, float)
        ramp = np.linspace(out[-1][-1], a[0], gap + 2)[1:-1]
        out += [ramp, a]
    return np.concatenate(out)


def _piecewise(funcs: list, shifts: list, spans: list, own: list):
    """One callable of the joint time from each recording's callable of its own time: a time
    in a recording's grid span (`spans`, with half the gap around) is that recording's; its
    callable is held beyond its own span `own` (joint times)."""
    edges = [0.5 * (spans[k][1] + spans[k + 1][0]) for k in range(len(spans) - 1)]

    def f(x):
        x = np.asarray(x, float)
        k = np.searchsorted(edges, x)
        out = np.empty_like(x)
        for j, (g, s, (a, b)) in enumerate(zip(funcs, shifts, own)):
            m = k == j
            if np.any(m):
                out[m] = g(np.clip(x[m], a, b) - s)
        return out
    return f


def join(als: list, names: list) -> Aligned:
    """The aligned pairs `als` (same outputs, same grid step within 1 %) on one grid.

    Raises InputError when the recordings cannot be joined (other outputs, another rate)."""
    first = als[0]
    for al, nm in zip(als[1:], names[1:]):
        if tuple(al.outputs) != tuple(first.outputs):
            raise InputError(f"recording {nm}: outputs {', '.join(al.outputs)}, expected the same "
                             f"as {names[0]} ({', '.join(first.outputs)})", field="--rec")
        if abs(al.dt - first.dt) > 0.01 * first.dt:
            raise InputError(f"recording {nm}: compared every {al.dt:g} s, expected the step of "
                             f"{names[0]} ({first.dt:g} s): recordings of one machine are joined "
                             "on one grid", field="--rec")
    dt = first.dt
    gap = max(GAP_MIN_SAMPLES, int(math.ceil(GAP_S / dt)))
    recs, shifts, spans = [], [], []
    start, t_next = 0, float(first.t[0])
    for al, nm in zip(als, names):
        shift = t_next - float(al.t[0])
        recs.append(Recording(nm, start, start + al.n, shift, al.clock_offset))
        shifts.append(shift)
        spans.append((float(al.t[0]) + shift, float(al.t[-1]) + shift))
        start += al.n + gap
        t_next += (al.n - 1 + gap + 1) * dt
    n = start - gap
    t = float(first.t[0]) + dt * np.arange(n)
    valid = np.zeros(n, bool)
    for al, r in zip(als, recs):
        valid[r.start:r.stop] = True if al.valid is None else al.valid
    outs = first.outputs
    rec = {o: _ramped([al.rec[o] for al in als], gap) for o in outs}
    sim = {o: _ramped([al.sim[o] for al in als], gap) for o in outs}
    keys = [k for k in first.signals if all(k in al.signals for al in als)]
    notes = []
    dropped = sorted({k for al in als for k in al.signals} - set(keys))
    if dropped:
        notes.append(f"columns not in every recording take no part: {', '.join(dropped)}")
    signals = {}
    for k in keys:
        s0 = first.signals[k]
        native = ()
        if all(al.signals[k].native for al in als):
            native = (np.concatenate([al.signals[k].native[0] + s for al, s in zip(als, shifts)]),
                      np.concatenate([al.signals[k].native[1] for al in als]))
        signals[k] = Signal(k, s0.header, s0.kind, s0.unit,
                            _ramped([al.signals[k].values for al in als], gap), s0.source,
                            s0.letter, native)
    own = [(al.sim_span[0] + s, al.sim_span[1] + s) for al, s in zip(als, shifts)]
    sim_spline = {o: _piecewise([al.sim_spline[o] for al in als], shifts, spans, own)
                  for o in outs}
    sim_native = {o: (np.concatenate([al.sim_native[o][0] + s for al, s in zip(als, shifts)]),
                      np.concatenate([al.sim_native[o][1] for al in als])) for o in outs}
    for al, r in zip(als, recs):
        notes += [f"{r.name}: {x}" for x in al.notes]
    notes.append(f"{len(als)} recordings of one machine joined ({', '.join(names)}): one set of "
                 "physical parameters, each recording's clock aligned on its own; held out: each "
                 "recording predicted by the model fitted on the others")
    joined = Aligned(
        t=t, dt=dt, outputs=outs, headers=dict(first.headers), units=dict(first.units),
        kinds=dict(first.kinds), rec=rec, sim=sim, sim_spline=sim_spline,
        sim_span=(own[0][0], own[-1][1]),
        signals=signals, offset0=0.0, offset_range=min(al.offset_range for al in als),
        quantum={o: max(al.quantum[o] for al in als) for o in outs}, clock_offset=0.0,
        rates=dict(first.rates), at_rest=all(al.at_rest for al in als),
        interp=dict(first.interp), roles=dict(first.roles), notes=tuple(notes),
        sim_native=sim_native, valid=None if valid.all() else valid,
        same_clock=all(al.same_clock for al in als), recordings=tuple(recs))
    for o in outs:
        # one floor per output: the recordings' floors pooled by their samples
        v = sum(al.noise_floor[o] ** 2 * len(al.rows()) for al in als)
        joined.noise_floor[o] = math.sqrt(v / sum(len(al.rows()) for al in als))
    return joined


def recording_blocks(al: Aligned, idx: np.ndarray) -> list | None:
    """Per recording, the positions in `idx` (grid indices of a context's rows) that belong to
    it; None when the grid holds one recording."""
    recs = getattr(al, "recordings", ())
    if len(recs) < 2:
        return None
    return [np.flatnonzero((idx >= r.start) & (idx < r.stop)) for r in recs]


__all__ = ["join", "Recording", "recording_blocks", "noise_sigma"]
