"""Put SIM and REC on one time grid, estimate the clock offset and the noise floor.

The grid is the sample times of the more coarsely sampled file inside the common time span
(uniform grids are kept as they are; a jittery one is replaced by a uniform grid of its median
step), so the coarse file is never interpolated and its noise stays white.  The finer file is
interpolated with a cubic spline: a linear one would add a(t)*dt^2/8 of interpolation error,
about 60 nm at 500 mm/s^2 and 1 kHz, which is more than the noise of a good recording.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._io import InputError
from .data import Table

MAD_TO_SIGMA = 1.482602218505602  # 1/Phi^-1(3/4): MAD of a normal sample -> its sigma


@dataclass(frozen=True)
class Signal:
    """A signal on the common grid with what the effect models need to know about it."""
    key: str
    header: str
    kind: str
    unit: str
    values: np.ndarray
    source: str          # "sim", "rec" or "sim-output"
    letter: str | None   # ISO axis letter for length/angle signals
    native: tuple = ()   # (t, values) as sampled in its file, t on SIM's clock


@dataclass(frozen=True)
class Aligned:
    """SIM and REC on a common uniform grid (times on SIM's clock)."""
    t: np.ndarray                     # (n,) s
    dt: float                         # grid step, s
    outputs: tuple                    # output keys
    headers: dict                     # output key -> header for display
    units: dict                       # output key -> unit (mm or deg)
    kinds: dict                       # output key -> kind
    rec: dict                         # output key -> (n,) recorded values
    sim: dict                         # output key -> (n,) simulated values
    sim_spline: dict                  # output key -> callable(t) simulated values at any time
    sim_span: tuple                   # (t0, t1) of SIM
    signals: dict                     # key -> Signal (drivers: sim outputs and all inputs)
    offset0: float                    # coarse (residual) offset from cross-correlation, s
    offset_range: float               # |offset| searched, s
    quantum: dict                     # output key -> REC resolution (0 if not quantised)
    clock_offset: float = 0.0         # REC clock - SIM clock removed before the grid, s
    noise_floor: dict = field(default_factory=dict)  # output key -> sigma
    rates: dict = field(default_factory=dict)        # "sim"/"rec" -> median sample rate, Hz

    @property
    def n(self) -> int:
        return len(self.t)


def _spline(t, y):
    from scipy.interpolate import CubicSpline
    if len(t) < 4:
        return lambda x: np.interp(x, t, y)
    cs = CubicSpline(t, y, bc_type="not-a-knot", extrapolate=False)

    def f(x, _cs=cs, _t0=t[0], _t1=t[-1]):
        return _cs(np.clip(x, _t0, _t1))
    return f


def _uniform(t: np.ndarray) -> bool:
    d = np.diff(t)
    med = np.median(d)
    return bool(np.max(np.abs(d - med)) <= 0.01 * med)


def noise_sigma(r: np.ndarray, quantum: float = 0.0) -> float:
    """Robust noise floor of a residual: MAD of its second differences / sqrt(6).

    Second differences remove offsets and slopes (drifts, scale errors while moving), the median
    ignores the few jumps of a backlash or a move start.  The result is never below the
    quantisation floor q/sqrt(12) of the recorded values.
    """
    r = np.asarray(r, float)
    if len(r) < 5:
        s = float(np.std(r))
    else:
        d2 = np.diff(r, 2)
        s = float(MAD_TO_SIGMA * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))
    floor = quantum / np.sqrt(12.0)
    tiny = 1e-9 * max(float(np.max(np.abs(r))) if len(r) else 0.0, 1e-12)
    return max(s, floor, tiny)


def _xcorr_offset(tc, sims, recs, max_lag_s):
    """Lag (s) at which REC best matches SIM, from the cross-correlation of the velocities.

    Velocities, not positions: positions correlate with themselves at every lag during long
    moves, while velocity peaks pin the start and end of each move.  Returns (lag, quality).
    """
    from scipy.signal import correlate, correlation_lags
    dtc = tc[1] - tc[0]
    total = None
    for s, r in zip(sims, recs):
        vs = np.gradient(s, dtc)
        vr = np.gradient(r, dtc)
        vs = vs - vs.mean()
        vr = vr - vr.mean()
        ns, nr = np.linalg.norm(vs), np.linalg.norm(vr)
        if ns == 0 or nr == 0:
            continue
        c = correlate(vr, vs, mode="full", method="fft") / (ns * nr)
        total = c if total is None else total + c
    if total is None:
        return 0.0, 0.0
    lags = correlation_lags(len(tc), len(tc), mode="full")
    # unbiased: at lag L only n - |L| products overlap; without this the peak is pulled toward
    # zero lag (by about 14 ms for a 0.25 s offset in a 10 s recording of slow moves)
    total = total * len(tc) / (len(tc) - np.abs(lags))
    keep = np.abs(lags * dtc) <= max_lag_s
    idx = np.flatnonzero(keep)
    k = idx[np.argmax(total[idx])]
    lag = float(lags[k])
    if 0 < k < len(total) - 1:  # parabolic refinement of the peak
        y0, y1, y2 = total[k - 1], total[k], total[k + 1]
        den = y0 - 2 * y1 + y2
        if den < 0:
            lag += 0.5 * (y0 - y2) / den
    return lag * dtc, float(total[k] / len(sims))


# Offsets of at least this much are a difference between the recorder's and the simulation's
# clocks (another start): REC is moved onto SIM's clock before anything else.  Smaller ones are
# left to the `time_offset` effect (trigger or transport latency), which must earn its place.
CLOCK_OFFSET_MIN = 0.1  # s


def _refine_offset(sim, rec, outputs, sim_splines, offset0, step):
    """Clock offset to a small fraction of a sample: least squares of REC(t) - SIM(t - offset)
    near offset0 (scan, then Brent), outputs weighted by their noise."""
    from scipy.optimize import minimize_scalar
    keep = (rec.t - offset0 >= sim.t[0]) & (rec.t - offset0 <= sim.t[-1])
    idx = np.flatnonzero(keep)[::max(1, int(np.count_nonzero(keep) // 20000))]
    t = rec.t[idx]
    ys = [rec.columns[k].values[idx] for k in outputs]
    w = [1.0 / noise_sigma(y - sim_splines[k](t - offset0)) for k, y in zip(outputs, ys)]

    def cost(tau):
        return sum(float(np.sum(((y - sim_splines[k](t - tau)) * wk) ** 2))
                   for k, y, wk in zip(outputs, ys, w))
    # the correlation peak of slow, smooth moves can be off by several steps: scan a bracket
    # first, then Brent around the best point of the scan
    half = max(5 * step, 0.05 * abs(offset0), 0.02)
    grid = offset0 + np.linspace(-half, half, 41)
    best = int(np.argmin([cost(g) for g in grid]))
    h = grid[1] - grid[0]
    res = minimize_scalar(cost, bounds=(grid[best] - h, grid[best] + h), method="bounded",
                          options={"xatol": 1e-7})
    return float(res.x) if res.success else float(grid[best])


def align(sim: Table, rec: Table, clock_offset: float = 0.0) -> Aligned:
    """Common grid, outputs, inputs and coarse clock offset of a SIM/REC pair."""
    common = [k for k in sim.columns if k in rec.columns]
    if not common:
        raise InputError(
            f"no output to compare: no column other than t is in both files "
            f"(SIM has {', '.join(sim.columns) or 'none'}; REC has {', '.join(rec.columns) or 'none'})",
            rec.path)
    outputs = []
    for k in common:
        cs, cr = sim.columns[k], rec.columns[k]
        if cs.kind != cr.kind or cs.unit != cr.unit:
            raise InputError(f"column {k!r} is {cs.unit or cs.kind} in SIM but {cr.unit or cr.kind} in REC "
                             "(expected the same quantity)", rec.path, 1, field=cr.header)
        outputs.append(k)
    t0 = max(sim.t[0], rec.t[0])
    t1 = min(sim.t[-1], rec.t[-1])
    if t1 <= t0:
        raise InputError(
            f"time spans do not overlap: SIM covers {sim.t[0]:g}..{sim.t[-1]:g} s, "
            f"REC covers {rec.t[0]:g}..{rec.t[-1]:g} s", rec.path, field="t")
    dts, dtr = float(np.median(np.diff(sim.t))), float(np.median(np.diff(rec.t)))
    overlap = t1 - t0
    n_sim_in = np.count_nonzero((sim.t >= t0) & (sim.t <= t1))
    n_rec_in = np.count_nonzero((rec.t >= t0) & (rec.t <= t1))
    if min(n_sim_in, n_rec_in) < 8:
        raise InputError(
            f"time spans overlap by {overlap:g} s only ({n_sim_in} SIM and {n_rec_in} REC samples): "
            "expected at least 8 samples of each in the common span", rec.path, field="t")

    # outputs: cubic splines (smooth motion, interpolation error far below the noise); inputs:
    # linear (spindle speed steps, logged temperatures: a cubic would ring at every step)
    def interp(t, y, cubic):
        return _spline(t, y) if cubic else (lambda x, _t=t, _y=y: np.interp(x, _t, _y))
    sim_splines = {k: interp(sim.t, c.values, k in common) for k, c in sim.columns.items()}
    rec_splines = {k: interp(rec.t, c.values, k in common) for k, c in rec.columns.items()}

    # coarse offset: search up to a quarter of the overlap, on a grid of at most 2^15 points
    max_lag = 0.25 * overlap
    nc = int(min(2 ** 15, max(64, overlap / min(dts, dtr))))
    tc = np.linspace(t0, t1, nc)
    offset0, _ = _xcorr_offset(tc, [sim_splines[k](tc) for k in outputs],
                               [rec_splines[k](tc) for k in outputs], max_lag)
    if abs(offset0) < 0.5 * min(dts, dtr):
        offset0 = 0.0
    if abs(offset0) >= CLOCK_OFFSET_MIN and clock_offset == 0.0:
        offset = _refine_offset(sim, rec, outputs, sim_splines, offset0, tc[1] - tc[0])
        shifted = Table(rec.path, rec.t - offset, rec.columns)
        return align(sim, shifted, clock_offset=offset)

    # grid: REC's own times when REC is the coarser (or equal) file, else SIM's
    margin = abs(offset0) + 2 * max(dts, dtr)
    ga, gb = t0 + (margin if offset0 > 0 else 0.0), t1 - (margin if offset0 < 0 else 0.0)
    base = rec.t if dtr >= 0.999 * dts else sim.t
    sel = (base >= ga) & (base <= gb)
    tg = base[sel]
    if len(tg) < 8:
        raise InputError(f"after aligning the clocks (REC lags SIM by {offset0:g} s) fewer than 8 "
                         "samples remain in the common span", rec.path, field="t")
    if not _uniform(tg):
        step = float(np.median(np.diff(tg)))
        tg = np.arange(tg[0], tg[-1] + 0.5 * step, step)
    dt = float((tg[-1] - tg[0]) / (len(tg) - 1))
    rec_on = {k: (rec.columns[k].values[sel] if base is rec.t and len(tg) == np.count_nonzero(sel)
                  else rec_splines[k](tg)) for k in rec.columns}
    sim_on = {k: sim_splines[k](tg) for k in sim.columns}

    signals = {}
    for k in outputs:
        c = sim.columns[k]
        signals[k] = Signal(k, c.header, c.kind, c.unit, sim_on[k], "sim-output", _letter(k, c.kind))
    for tab, on, src in ((sim, sim_on, "sim"), (rec, rec_on, "rec")):
        for k, c in tab.columns.items():
            if k in outputs or k in signals:
                continue
            v = on[k]
            if c.kind == "other" and np.ptp(v) == 0:
                continue
            signals[k] = Signal(k, c.header, c.kind, c.unit, v, src, _letter(k, c.kind),
                                (tab.t, c.values))
    al = Aligned(
        t=tg, dt=dt, outputs=tuple(outputs),
        headers={k: sim.columns[k].header for k in outputs},
        units={k: sim.columns[k].unit for k in outputs},
        kinds={k: sim.columns[k].kind for k in outputs},
        rec={k: rec_on[k] for k in outputs}, sim={k: sim_on[k] for k in outputs},
        sim_spline={k: sim_splines[k] for k in outputs}, sim_span=(float(sim.t[0]), float(sim.t[-1])),
        signals=signals, offset0=float(offset0), offset_range=float(max_lag),
        clock_offset=float(clock_offset),
        quantum={k: rec.columns[k].quantum for k in outputs},
        rates={"sim": 1.0 / dts, "rec": 1.0 / dtr})
    for k in outputs:
        al.noise_floor[k] = noise_sigma(al.rec[k] - al.sim[k], al.quantum[k])
    return al


def _letter(key, kind):
    from .data import axis_letter
    return axis_letter(key, kind)
