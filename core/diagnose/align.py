"""Put SIM and REC on one time grid, estimate the clock offset and the noise floor.

The grid is REC's own sample times inside the common time span (a jittery clock is replaced by
a uniform grid of its median step), so the recording is never interpolated and its noise stays
white.  SIM, the smooth and noise-free side, is evaluated at those times with the interpolant
that predicts SIM best by cross-validation on SIM itself (linear for piecewise-linear commands,
cubic spline for smooth motion, held values for steps); the cross-validated error gives the
interpolation error bound reported with the result.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

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
    at_rest: bool = False             # REC sampled only while SIM rests (stop-and-measure)
    interp: dict = field(default_factory=dict)       # output -> (interpolant of SIM, error bound)
    roles: dict = field(default_factory=dict)        # column -> (role, kind, unit, kind from)
    notes: tuple = ()                 # what the alignment decided, in words
    sim_native: dict = field(default_factory=dict)   # output -> (t, values) of SIM as sampled
    # grid samples backed by data (None: all): False in a gap of either file or where an
    # output's cell was missing; those samples take no part in fits, noise floors or RMS
    valid: np.ndarray | None = None
    same_clock: bool = False          # SIM and REC share one clock (no clock offset estimated)
    # several recordings of one machine laid end to end (recordings.join): where each lies
    recordings: tuple = ()

    @property
    def n(self) -> int:
        return len(self.t)

    def rows(self, step: int = 1) -> np.ndarray:
        """Indices of the grid samples backed by data, every `step`-th."""
        idx = np.arange(self.n) if self.valid is None else np.flatnonzero(self.valid)
        return idx[::max(1, int(step))]


def _spline(t, y):
    from scipy.interpolate import CubicSpline
    if len(t) < 4:
        return lambda x: np.interp(x, t, y)
    cs = CubicSpline(t, y, bc_type="not-a-knot", extrapolate=False)

    def f(x, _cs=cs, _t0=t[0], _t1=t[-1]):
        return _cs(np.clip(x, _t0, _t1))
    return f


def _linear(t, y):
    return lambda x, _t=t, _y=y: np.interp(x, _t, _y)


def _hold(t, y):
    def f(x, _t=t, _y=y):
        i = np.clip(np.searchsorted(_t, x, side="right") - 1, 0, len(_t) - 1)
        return _y[i]
    return f


def _pchip(t, y):
    from scipy.interpolate import PchipInterpolator
    if len(t) < 3:
        return _linear(t, y)
    f = PchipInterpolator(t, y, extrapolate=False)
    return lambda x, _f=f, _t0=t[0], _t1=t[-1]: _f(np.clip(x, _t0, _t1))


INTERPOLANTS = {"linear": _linear, "cubic": _spline, "pchip": _pchip, "hold": _hold}
# order of the error in the step h of each interpolant: halving the samples multiplies it by 2^p
_ORDER = {"linear": 2, "cubic": 4, "pchip": 3, "hold": 1}


def choose_interpolant(t: np.ndarray, y: np.ndarray, kinds=("linear", "cubic", "hold")):
    """Interpolant that predicts a sampled signal best, by cross-validation on the signal itself.

    Every other sample is predicted from the remaining ones (both halves in turn); the
    interpolant with the smallest RMS prediction error wins.  The error at the full sampling
    rate is that RMS divided by 2^p (p the order of the interpolant in the step), an estimate
    of the interpolation error bound.  Returns (name, callable, error bound in y's unit).
    """
    n = len(t)
    if n < 8 or np.ptp(y) == 0:
        return "linear", _linear(t, y), 0.0
    # at most about 40,000 points enter the test: a strided block keeps the local step
    errs = {}
    for name in kinds:
        se, cnt = 0.0, 0
        for par in (0, 1):
            keep = np.arange(n) % 2 == par
            tk, yk = t[keep], y[keep]
            f = INTERPOLANTS[name](tk, yk)
            m = ~keep
            inside = m & (t > tk[0]) & (t < tk[-1])
            d = f(t[inside]) - y[inside]
            se += float(d @ d)
            cnt += int(inside.sum())
        errs[name] = math.sqrt(se / max(cnt, 1))
    best = min(kinds, key=lambda k: (errs[k], list(kinds).index(k)))
    return best, INTERPOLANTS[best](t, y), errs[best] / 2 ** _ORDER[best]


# REC's own instants are the grid up to this many samples in the common span
REC_GRID_MAX = 200_000


def corners(t: np.ndarray, y: np.ndarray):
    """SIM as piecewise-linear motion: None when it is not, else (starts, ends, bound, errors)
    of the steps between two samples that hold a corner, the RMS resampling error bound of
    linear interpolation over all steps, and the largest error in each such step.

    A slope that changes at one sample only is a corner on that sample (linear interpolation
    is exact around it); one that changes at two neighbouring samples k, k+1 has its corner
    between them, where linear interpolation cuts it by up to |change of slope| h / 4.  The
    signal is piecewise linear when the slope is constant at most samples (60 %) and every
    change of slope spans at most two samples (acceleration ramps span many)."""
    n = len(t)
    if n < 8:
        return None
    s = np.diff(y) / np.diff(t)
    smax = float(np.max(np.abs(s)))
    if smax == 0:
        return None
    ds = np.diff(s)
    bend = np.abs(ds) > 1e-6 * smax
    if bend.mean() > 0.4 or not bend.any():
        return None
    # runs of consecutive bends
    edges = np.diff(np.concatenate([[0], bend.astype(np.int8), [0]]))
    a, b = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    if np.any(b - a > 2):
        return None
    two = a[(b - a) == 2]            # bends at interior samples two+1, two+2
    lo, hi = t[two + 1], t[two + 2]
    err = np.abs(ds[two] + ds[two + 1]) * (hi - lo) / 4.0
    bound = float(np.sqrt(np.sum(err ** 2 * (hi - lo) / 3.0) / max(t[-1] - t[0], 1e-300)))
    return lo, hi, bound, err


def _uniform(t: np.ndarray) -> bool:
    d = np.diff(t)
    med = np.median(d)
    return bool(np.max(np.abs(d - med)) <= 0.01 * med)


def _d2_sigma(r: np.ndarray) -> float:
    """sigma of white noise from the MAD of second differences (their variance is 6 sigma^2)."""
    d2 = np.diff(r, 2)
    return float(MAD_TO_SIGMA * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))


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
        s = _d2_sigma(r)
        if len(r) >= 40:
            # the same on every other sample: white noise gives the same sigma, while a pattern
            # that alternates from sample to sample (a full-step or pole-pair error sampled
            # twice per period, a lag-1 correlation near -1) inflates the first estimate and
            # cancels in this one; structure is not noise, so the smaller is taken
            s = min(s, max(_d2_sigma(r[0::2]), _d2_sigma(r[1::2])))
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


def _lagged(sim_f, t0, t1, h, taus):
    """First-order lags of a SIM signal on a fine grid: {tau: (grid, filtered)} (tau 0 = SIM)."""
    from .effects import first_order
    tg = np.arange(t0, t1 + 0.5 * h, h)
    p = sim_f(tg)
    return tg, {tau: (p if tau == 0 else first_order(p, h, tau)) for tau in taus}


def _refine_offset(sim, rec, outputs, sim_f, offset0, step):
    """Clock offset estimated jointly with a first-order lag per output (filtered, or in its
    linear form p - tau v, whichever fits).

    A servo lag delays a moving axis by about 1/kv: an offset fitted alone takes the true clock
    difference plus the lag, and the lag is then lost to the effects.  Here each output's
    offset is scored with its best lag (0 .. 0.5 s: a grid, then a bounded scalar search), the
    lag filter running on a grid fine against both files' steps; the outputs' offsets are
    averaged with weights inverse to their misfit.  Returns (offset, cost at offset, cost at
    zero offset), costs in noise-weighted squares.
    """
    from scipy.optimize import minimize_scalar
    lo_t, hi_t = float(sim.t[0]), float(sim.t[-1])
    keep = (rec.t - offset0 >= lo_t) & (rec.t - offset0 <= hi_t) & (rec.t >= lo_t) & (rec.t <= hi_t)
    idx = np.flatnonzero(keep)[::max(1, int(np.count_nonzero(keep) // 8000))]
    if len(idx) < 8:
        return offset0, 0.0, np.inf
    t = rec.t[idx]
    ys = [rec.columns[k].values[idx] for k in outputs]
    w = [1.0 / noise_sigma(y - sim_f[k](t - offset0)) for k, y in zip(outputs, ys)]
    h = max(min(float(np.median(np.diff(sim.t))), float(np.median(np.diff(rec.t)))) / 4,
            (hi_t - lo_t) / 60000)
    taus = np.concatenate([[0.0], np.geomspace(max(h, 1e-4), 0.5, 36)])
    lag = {k: _lagged(sim_f[k], lo_t, hi_t, h, taus) for k in outputs}
    # SIM's velocity on the fine grid, for the lag's linear (steady-state) form y = p - tau v
    vel = {k: np.gradient(lag[k][1][0.0], h) for k in outputs}

    def linear_cost(x, k, y, wk):
        # a following error x - tau v (a loop that is not exactly first order) is as much a lag
        # as the filtered form: without it the offset takes the lag whole (a shift fits x - tau v
        # better than a first-order filter does), and nothing is left to name but model error
        tg, fl = lag[k]
        e = (y - np.interp(x, tg, fl[0.0])) * wk
        v = np.interp(x, tg, vel[k]) * wk
        vv = float(v @ v)
        tau = max(0.0, -float(e @ v) / vv) if vv > 0 else 0.0
        r = e + tau * v
        return float(r @ r)

    def grid_costs(x, k, y, wk):
        tg, fl = lag[k]
        return np.array([float(np.sum(((y - np.interp(x, tg, f)) * wk) ** 2)) for f in fl.values()]
                        + [linear_cost(x, k, y, wk)])

    def cost_k(off, j):
        # one output: the least cost over the grid of lags (the scan)
        x = np.clip(t - off, lo_t, hi_t)
        return float(grid_costs(x, outputs[j], ys[j], w[j]).min())

    def fine_k(off, j):
        # one output: the least cost over a continuous lag (bounded scalar search between the
        # neighbours of the best grid lag): a grid minimum alone is bumpy in the offset, and
        # the offset would take up the lag's rounding
        from .effects import first_order
        k, y, wk = outputs[j], ys[j], w[j]
        x = np.clip(t - off, lo_t, hi_t)
        c = grid_costs(x, k, y, wk)
        c_lin = float(c[-1])
        c = c[:-1]
        i = int(np.argmin(c))
        tg, fl = lag[k]
        p0 = fl[taus[0]]
        # the bracket reaches down to (almost) no lag when the best grid lag is the smallest:
        # a lag of one fine step and a shorter offset are nearly the same curve
        lo_l = math.log(taus[i - 1] if i >= 2 else taus[1] * 1e-3)
        hi_l = math.log(taus[min(i + 1, len(taus) - 1)])

        def ck(lt):
            f = first_order(p0, h, math.exp(lt))
            return float(np.sum(((y - np.interp(x, tg, f)) * wk) ** 2))
        r = minimize_scalar(ck, bounds=(lo_l, hi_l), method="bounded", options={"xatol": 2e-3})
        return min(float(r.fun), float(c[i]), float(c[0]), c_lin)

    # the correlation peak includes the lags (REC late by clock + lag): the scan reaches
    # 0.15 s before it, and past it for slow, smooth moves whose peak is broad
    half = max(5 * step, 0.05 * abs(offset0), 0.15)
    grid = offset0 + np.linspace(-half, half, 121)
    hstep = grid[1] - grid[0]
    # each output's own offset (scan, then Brent on the continuous-lag profile: the scan's lag
    # grid is coarse, its best offset can be a step or two off), then a weighted mean: an
    # output the lag model fits badly (a backlash, friction) says little about the clock and
    # weighs by its poor fit
    offs, wts = [], []
    for j in range(len(outputs)):
        costs = [cost_k(g, j) for g in grid]
        best = int(np.argmin(costs))
        res = minimize_scalar(lambda o, _j=j: fine_k(o, _j),
                              bounds=(grid[best] - 4 * hstep, grid[best] + 4 * hstep),
                              method="bounded", options={"xatol": 1e-5})
        o_j = float(res.x) if res.success else float(grid[best])
        offs.append(o_j)
        wts.append(len(t) / max(fine_k(o_j, j), 1e-12 * len(t)))
    off = float(np.average(offs, weights=wts))
    total = lambda o: sum(fine_k(o, j) for j in range(len(outputs)))  # noqa: E731
    return off, total(off), total(0.0)


def _stop_and_measure(sim, outputs, t) -> bool:
    """Are the times t (REC's samples) taken only while SIM rests, though SIM moves often?

    Stop-and-measure: at least 90 % of the readings fall where every SIM output rests, and the
    readings taken in motion are fewer than a fifth of the share of time SIM spends moving (an
    axis that simply rests most of the time, recorded at a steady rate, is not one).
    """
    still_t = np.ones(len(t), bool)
    still_sim = np.ones(len(sim.t), bool)
    moving_any = False
    for k in outputs:
        c = sim.columns[k]
        if c.kind in ("acceleration", "angular_acceleration"):
            continue
        # the speed: the derivative of a position, a velocity itself
        v = (c.values if c.kind in ("velocity", "angular_velocity")
             else np.gradient(c.values, sim.t))
        vmax = float(np.max(np.abs(v)))
        if vmax == 0:
            continue
        moving_any = True
        fast = np.abs(v) > 1e-3 * vmax
        # a sample is at rest when SIM rests at it and at its neighbours in SIM's own samples
        i = np.clip(np.searchsorted(sim.t, t), 1, len(sim.t) - 1)
        still_t &= ~fast[i] & ~fast[i - 1]
        still_sim &= ~fast
    if not moving_any:
        return False
    w = np.gradient(sim.t)  # time each SIM sample stands for
    moving_time = float(np.sum(w[~still_sim]) / np.sum(w))
    moving_reads = 1.0 - float(np.mean(still_t))
    return moving_reads <= 0.1 and moving_reads < 0.2 * moving_time


def align(sim: Table, rec: Table, clock_offset: float = 0.0, outputs=None, inputs=None,
          notes: tuple = (), same_clock: bool = False) -> Aligned:
    """Common grid, outputs, inputs and coarse clock offset of a SIM/REC pair.

    outputs / inputs: column names to compare / to use as inputs only (default: the columns in
    both files are outputs).  Names are case-sensitive.  same_clock: SIM and REC share one
    clock (the user says so): no clock offset is estimated; the cross-correlation's delay only
    starts the `time_offset` effect, which is then a transport delay.
    """
    from .columns import MOTION_KINDS
    common = [k for k in sim.columns if k in rec.columns]
    for opt, names in (("--output", outputs), ("--input", inputs)):
        for k in names or ():
            if k not in sim.columns and k not in rec.columns:
                raise InputError(f"{opt} {k!r}: no such column (SIM has {', '.join(sim.columns)}; "
                                 f"REC has {', '.join(rec.columns)})", field=opt)
    if outputs:
        for k in outputs:
            if k not in common:
                raise InputError(f"--output {k!r} must be a column of both SIM and REC", field="--output")
        common = [k for k in common if k in outputs]
    if inputs:
        common = [k for k in common if k not in inputs]
    if not outputs:
        # a logged temperature or spindle speed copied into SIM is what drove the simulation,
        # not something it predicts: an input (a thermal drift needs it as its driver)
        drivers = [k for k in common if sim.columns[k].kind in ("temperature", "speed")
                   and rec.columns[k].kind == sim.columns[k].kind]
        if drivers and len(drivers) < len(common):
            common = [k for k in common if k not in drivers]
            notes = tuple(notes) + tuple(
                f"column {k!r} is in both files but is a {sim.columns[k].kind}: used as an input "
                f"(give --output {k} to compare it)" for k in drivers)
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
                             "(expected the same quantity)", rec.path, None, field=cr.header)
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
    if min(n_sim_in, n_rec_in) < 8 and clock_offset == 0.0:
        raise InputError(
            f"time spans overlap by {overlap:g} s only ({n_sim_in} SIM and {n_rec_in} REC samples): "
            "expected at least 8 samples of each in the common span", rec.path, field="t")

    # the grid is the coarser file's own times (its values are never interpolated, its noise
    # stays white); the finer file is evaluated at them with the interpolant that predicts it
    # best by cross-validation on itself (linear for piecewise-linear commands, splines for
    # smooth motion, held values for steps), which also gives the interpolation error bound
    # a REC on an irregular clock is never interpolated either: its samples go onto a fine
    # uniform grid (below)
    rec_in_span = rec.t[(rec.t >= t0) & (rec.t <= t1)]
    rec_irregular = len(rec_in_span) >= 3 and not _uniform(rec_in_span)
    # a piecewise-linear SIM (G1 moves) is exact between its samples, linearly: REC is then
    # compared on its own instants even when it is the denser file (interpolating REC across a
    # corner of the path that falls between its samples would cut the corner, micrometres that
    # no effect has); a smooth SIM is not exact between samples, so the coarser file's instants
    # stay the grid then
    from .columns import MOTION_KINDS as _MK
    piecewise = any(corners(sim.t, sim.columns[k].values) is not None for k in common
                    if sim.columns[k].kind in _MK + ("other",))
    rec_grid = (dtr >= 0.999 * dts or rec_irregular
                or (piecewise and n_rec_in <= REC_GRID_MAX))
    interp = {}
    kinked = {}  # output -> SIM's corners between samples (corners())
    sim_f, rec_f = {}, {}
    for tab, fs, is_grid in ((sim, sim_f, not rec_grid), (rec, rec_f, rec_grid)):
        for k, c in tab.columns.items():
            motion = k in common or c.kind in MOTION_KINDS
            kinds = ("linear", "cubic", "pchip", "hold") if motion else ("linear", "hold")
            if tab is rec and k not in common:
                kinds = ("linear",)  # REC inputs: logged temperatures and the like
            tt, vv = tab.t, c.values
            if tab is rec and k in common and rec.excluded is not None:
                # rows removed by the row filter do not feed REC's interpolant (a spline would
                # carry a removed value to its neighbours); grid times next to them are set
                # aside below
                tt, vv = tt[~rec.excluded], vv[~rec.excluded]
            pl = corners(tt, vv) if (tab is sim and k in common and motion) else None
            if pl is not None:
                # piecewise linear (G1 moves): linear between its samples is exact except in
                # the steps that hold a corner between two samples; no overshoot at corners
                name, f, bound = "linear", _linear(tt, vv), pl[2]
                kinked[k] = pl
            else:
                name, f, bound = choose_interpolant(tt, vv, kinds)
            if tab is rec and k in common and bound > 0:
                # the cross-validated error of a noisy signal includes its noise (the held-out
                # sample's and, about half, its neighbours'): what is left is interpolation
                sn = noise_sigma(vv) * 2 ** _ORDER[name]
                bound = math.sqrt(max((bound * 2 ** _ORDER[name]) ** 2 - 1.5 * sn ** 2, 0.0)) / 2 ** _ORDER[name]
            fs[k] = f
            if k in common and not is_grid:
                interp[k] = (("SIM " if tab is sim else "REC ") + name, bound)
            elif k in common:
                interp.setdefault(k, ("none (grid)", 0.0))
    # outputs always need a smooth evaluation of SIM at any time (lags, offsets)
    for k in common:
        if rec_grid is False and k not in interp:
            interp[k] = ("none (grid)", 0.0)

    # stop-and-measure: REC samples only where SIM rests (ISO 230-2 runs, probing, CMM). No
    # clock can be aligned on motion that was not recorded, and only effects that act at rest
    # are candidates.
    rec_in = rec.t[(rec.t >= t0) & (rec.t <= t1)]
    # outputs of unknown kind are taken as positions of an unnamed axis (as by the effects)
    motion_outs = [k for k in outputs if sim.columns[k].kind in MOTION_KINDS + ("other",)]
    at_rest = (clock_offset == 0.0 and len(motion_outs) > 0 and len(rec_in) >= 8
               and _stop_and_measure(sim, motion_outs, rec_in))
    notes = tuple(notes)
    offset0 = 0.0
    max_lag = 0.25 * overlap
    if at_rest:
        notes += ("REC holds readings at rest only (stop-and-measure): no clock alignment, "
                  "only effects that act at rest are candidates",)
    elif motion_outs:
        # coarse offset: search up to a quarter of the overlap, on a grid of at most 2^15 points
        nc = int(min(2 ** 15, max(64, overlap / min(dts, dtr))))
        tc = np.linspace(t0, t1, nc)
        offset0, _ = _xcorr_offset(tc, [sim_f[k](tc) for k in motion_outs],
                                   [rec_f[k](tc) for k in motion_outs], max_lag)
        if abs(offset0) < 0.5 * min(dts, dtr):
            offset0 = 0.0
        if same_clock:
            notes += ("SIM and REC share one clock (--same-clock): no clock offset is estimated; "
                      "a delay found is a transport delay of the machine or its loop",)
        elif abs(offset0) >= CLOCK_OFFSET_MIN and clock_offset == 0.0:
            offset, c_off, c_zero = _refine_offset(sim, rec, motion_outs, sim_f, offset0,
                                                   tc[1] - tc[0])
            # materially lower (10 %): on motion that repeats itself (a sine, a program run
            # twice) shifts by whole periods fit as well as none, and which one wins by a
            # hair is decided by the noise and the effects, not by the clocks
            if c_off < 0.9 * c_zero:
                shifted = replace(rec, t=rec.t - offset)
                note = (f"clocks aligned: REC's clock runs {offset:+.6g} s from SIM's (estimated "
                        "jointly with a first-order lag per output; it lowers the residual "
                        + (f"{math.sqrt(c_zero / c_off):.3g}x" if c_off > 0 and c_zero / c_off < 1e6
                         else "to the noise") + " against no alignment; a pure transport delay of "
                        "the machine is a time shift too and cannot be told from it: if the clocks "
                        "are known to agree, say so with --same-clock)")
                return align(sim, shifted, clock_offset=offset, outputs=outputs, inputs=inputs,
                             notes=notes + (note,))
            notes += (f"a clock offset of {offset:+.4g} s was tried and rejected: it does not "
                      "lower the residual materially (by 10 %) against no alignment",)
            offset0 = 0.0

    # grid: the coarser file's own times inside the common span (minus a margin for a
    # remaining offset); REC's for a stop-and-measure recording
    margin = abs(offset0) + 2 * max(dts, dtr)
    ga, gb = t0 + (margin if offset0 > 0 else 0.0), t1 - (margin if offset0 < 0 else 0.0)
    base = rec.t if (rec_grid or at_rest) else sim.t
    sel = (base >= ga) & (base <= gb)
    tg = base[sel]
    if len(tg) < 8:
        raise InputError(f"after aligning the clocks (REC lags SIM by {offset0:g} s) fewer than 8 "
                         "samples remain in the common span", rec.path, field="t")
    regular = _uniform(tg) or at_rest
    if not regular:
        step = float(np.median(np.diff(tg)))
        if base is rec.t:
            # each REC sample is put on the nearest point of a grid fine against both files'
            # steps (an effect is then evaluated within h/2 of the sample's time: a servo lag's
            # residual changes by a tau h/2 there), at most about 100,000 points
            h0 = min(step, dts)
            step = h0 / 4
            while step > h0 / 64 and (tg[-1] - tg[0]) / (step / 2) <= 100_000:
                step /= 2
        tg = np.arange(tg[0], tg[-1] + 0.5 * step, step)
    dt = float((tg[-1] - tg[0]) / (len(tg) - 1))
    on_rec = base is rec.t and regular
    on_sim = base is sim.t and regular
    rec_on = {k: (rec.columns[k].values[sel] if on_rec else rec_f[k](tg)) for k in rec.columns}
    sim_on = {k: (sim.columns[k].values[sel] if on_sim else sim_f[k](tg)) for k in sim.columns}
    hit = np.ones(len(tg), bool)
    if base is rec.t and not regular:
        # REC on an irregular clock: SIM (smooth, noise-free) is evaluated at REC's own times and
        # each sample's residual REC - SIM is put on the grid point nearest to it (within half
        # a step; the nearest sample wins); grid points without a sample are set aside.
        # Interpolating REC would add the curvature of the motion between samples (a h^2 / 8:
        # micrometres at 10 ms and 200 mm/s^2) and smooth its noise
        step = float(tg[1] - tg[0])
        j = np.rint((rec.t - tg[0]) / step).astype(np.int64)
        d = np.abs(rec.t - (tg[0] + j * step))
        ok = (j >= 0) & (j < len(tg)) & (d <= 0.5 * step)
        order = np.flatnonzero(ok)[np.argsort(d[ok], kind="stable")[::-1]]
        pick = np.full(len(tg), -1)
        pick[j[order]] = order  # the nearest sample is written last
        hit = pick >= 0
        for k in outputs:
            r = rec.columns[k].values - sim_f[k](rec.t)
            p = rec.columns[k].present
            rec_on[k] = sim_on[k] + np.where(hit, r[np.maximum(pick, 0)], 0.0)
            if p is not None:
                hit &= np.where(pick >= 0, p[np.maximum(pick, 0)], False)
            interp[k] = ("none (REC's samples on the nearest grid point, SIM at their times)", 0.0)
    # no recorded output is interpolated across a gap (a pause of the logger, rows with missing
    # cells): grid samples not backed by REC are set aside, and said so.  SIM is the noise-free
    # side, interpolated by evidence (a command may well be written only at its corners); only
    # its missing cells count
    valid = hit.copy()
    if not hit.all():
        notes += (f"REC's clock is irregular: {int((~hit).sum())} of {len(tg)} points of the "
                  f"uniform {tg[1] - tg[0]:.4g} s grid have no REC sample within half a step and "
                  "take no part",)
    for tab, own, step in ((rec, on_rec, dtr), (sim, on_sim, np.inf)):
        ok, longest = _backed(tab, outputs, tg, step, sel if own else None)
        if not ok.all():
            notes += (f"{int((~ok).sum())} of {len(tg)} grid samples fall in gaps of "
                      f"{'REC' if tab is rec else 'SIM'} (longest {longest:.4g} s) or on rows "
                      "with a missing output value: they take no part in the fit or the RMS"
                      if tab is rec else f"{int((~ok).sum())} of {len(tg)} grid samples fall on "
                      "rows of SIM with a missing output value: they take no part in the fit "
                      "or the RMS",)
        valid &= ok
    removed = np.zeros(len(tg), bool)
    for tab, own in ((rec, on_rec), (sim, on_sim)):
        if tab.excluded is not None:
            p = pick if (tab is rec and base is rec.t and not regular) else None
            removed |= _excluded_on_grid(tab, tg, sel if own else None, p)
    if removed.any():
        notes += (f"row filter: {int(removed.sum())} of {len(tg)} grid samples fall on rows it "
                  "removed or between such a row and its neighbour: they take no part in the fit, "
                  "the held-out RMS, the noise floor or the RMS (nothing is interpolated across "
                  "them)",)
        valid &= ~removed
    if rec_grid and kinked:
        inside = np.zeros(len(tg), bool)
        worst = 0.0
        for k, (lo_c, hi_c, _, err) in kinked.items():
            if len(lo_c):
                j = np.searchsorted(lo_c, tg, side="right") - 1
                jc = np.clip(j, 0, len(lo_c) - 1)
                inside |= (j >= 0) & (tg > lo_c[jc]) & (tg < hi_c[jc])
                worst = max(worst, float(np.max(err)))
        if inside.any():
            notes += (f"SIM is piecewise linear with {int(sum(len(v[0]) for v in kinked.values()))} "
                      f"corners between its samples: the {int(inside.sum())} grid samples inside "
                      "those steps take no part (where the corner lies between two samples no "
                      f"interpolant knows the path: up to {worst:.3g} "
                      f"{sim.columns[next(iter(kinked))].unit or 'units'} off there)",)
            valid &= ~inside
    if valid.sum() < 8 and removed.any():
        raise InputError(f"the row filter leaves {int(valid.sum())} usable samples of the common "
                         "span (expected at least 8)", field="--where")
    if valid.sum() < 8:
        raise InputError(f"fewer than 8 samples of the common span are backed by data in both "
                         f"files ({int(valid.sum())})", rec.path, field="t")
    if not valid.all():
        for k in outputs:
            rec_on[k] = np.where(valid, rec_on[k], sim_on[k])
    if at_rest:
        # readings at rest: SIM at the reading is the position it rests at (no interpolant
        # between a move's samples can matter there)
        for k in outputs:
            sim_on[k] = _hold(sim.t, sim.columns[k].values)(tg)
            interp[k] = ("SIM hold (at rest)", 0.0)

    signals = {}
    roles = {}
    for k in outputs:
        c = sim.columns[k]
        signals[k] = Signal(k, c.header, c.kind, c.unit, sim_on[k], "sim-output", _letter(k, c.kind),
                            (sim.t, c.values))
        roles[k] = ("output", c.kind, c.unit, c.kind_from)
    for tab, on, src in ((sim, sim_on, "sim"), (rec, rec_on, "rec")):
        for k, c in tab.columns.items():
            if k in outputs or k in signals:
                continue
            v = on[k]
            roles[k] = ("input", c.kind, c.unit, c.kind_from)
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
        sim_spline={k: sim_f[k] for k in outputs}, sim_span=(float(sim.t[0]), float(sim.t[-1])),
        signals=signals, offset0=float(offset0), offset_range=float(max_lag),
        clock_offset=float(clock_offset),
        quantum={k: rec.columns[k].quantum for k in outputs},
        rates={"sim": 1.0 / dts, "rec": 1.0 / dtr}, at_rest=bool(at_rest), interp=interp,
        roles=roles, notes=notes,
        sim_native={k: (sim.t, sim.columns[k].values) for k in outputs},
        valid=None if valid.all() else valid, same_clock=bool(same_clock))
    for k in outputs:
        al.noise_floor[k] = noise_sigma((al.rec[k] - al.sim[k])[valid], al.quantum[k])
    return al


# a grid sample between two samples of a file further apart than this many of its median
# steps lies in a gap: it is not filled by interpolation
GAP_STEPS = 3.0


def _backed(tab: Table, outputs, tg: np.ndarray, step: float, sel) -> tuple[np.ndarray, float]:
    """Which grid times are backed by samples of `tab` holding every output: on its own rows
    (`sel`, the rows taken as the grid) the row must hold them; between rows the two rows
    around must be at most GAP_STEPS median steps apart.  Also the longest gap, s."""
    pres = np.ones(tab.n, bool)
    for k in outputs:
        p = tab.columns[k].present
        if p is not None:
            pres &= p
    if sel is not None:
        ok = pres[sel]
    else:
        tt = tab.t[pres]
        if len(tt) < 2:
            return np.zeros(len(tg), bool), float(tab.t[-1] - tab.t[0])
        i = np.clip(np.searchsorted(tt, tg), 1, len(tt) - 1)
        exact = np.isclose(tt[np.clip(np.searchsorted(tt, tg), 0, len(tt) - 1)], tg, rtol=0,
                           atol=1e-9 * (step if math.isfinite(step) else 1.0))
        ok = exact | ((tt[i] - tt[i - 1]) <= GAP_STEPS * step)
        ok &= (tg >= tt[0]) & (tg <= tt[-1])
    tp = tab.t[pres]
    longest = float(np.max(np.diff(tp))) if len(tp) > 1 else 0.0
    return ok, longest


def _excluded_on_grid(tab: Table, tg: np.ndarray, sel, pick) -> np.ndarray:
    """Grid samples that depend on a row of `tab` removed by the row filter: on its own rows
    (`sel`) the row itself; for an irregular REC put onto the grid (`pick`: the sample on each
    grid point, -1 none) that sample; otherwise the two rows around the grid time (the one it
    falls on when it falls on a row), so that no value is interpolated across a removed row."""
    ex = tab.excluded
    if sel is not None:
        return ex[sel]
    if pick is not None:
        return np.where(pick >= 0, ex[np.maximum(pick, 0)], False)
    t = tab.t
    i = np.clip(np.searchsorted(t, tg), 0, len(t) - 1)
    on = np.abs(t[i] - tg) <= 1e-9 * max(float(np.median(np.diff(t))), 1e-12)
    lo = np.clip(i - 1, 0, len(t) - 1)
    return np.where(on, ex[i], ex[i] | ex[lo])


def _letter(key, kind):
    from .columns import axis_letter
    return axis_letter(key, kind)
