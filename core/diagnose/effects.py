"""The library of physical effects a simulation may have left out.

Every effect predicts the residual REC - SIM it would cause on one or more outputs, as
``fixed(eta) + B(eta) @ beta``: ``eta`` are the few nonlinear parameters (time constants, screw
lead, clock offset, kv) that are fitted by nonlinear least squares, ``beta`` the amplitudes that
enter linearly and are solved exactly for every ``eta`` (variable projection).  All vectors are
stacked over the outputs and divided by each output's noise floor, so outputs in mm and deg and
of different noise weigh by their information.

Signatures and parameters (documented for users in docs/diagnose.md):

- thermal_drift: r = k (F_tau[u] - u(t0)) + r0 exp(-(t - t0)/tau) + c, F_tau a first-order lag
  of a driver u (spindle speed, a logged temperature, any other slowly varying input) started
  in steady state; k in mm per unit of u, tau in s, r0 the unknown initial thermal state and c
  the unknown reference (mm).
- backlash: play operator of width b on the axis position: after a reversal at p_rev the
  error moves from +-b/2 to -+b/2 over the first b of travel, r = clip(d b/2 - (p - p_rev), -b/2, b/2),
  d = +1/-1 the direction of the last motion (kept during dwells).
- servo_lag: r = F_{1/kv}[p] - p, p the simulated axis position: a first-order position loop
  of gain kv (1/s); the steady following error is v/kv.
- periodic_pitch_error: r = A sin(2 pi p / L) + B cos(2 pi p / L), L the screw lead (mm).
- scale_error: r = s * p (s dimensionless, about the axis zero).
- squareness: r_o = g * p_j, p_j the position of another linear axis (g in rad, reported in deg).
- straightness: r_o = sum_k c_k P_k(xi), xi the other axis' position mapped to [-1, 1],
  Legendre orders 0..4 (squareness is its one-parameter, linear special case).
- pivot_offset: r = (R_axis(theta) - I) d, d the tool edge's offset from a rotary axis' centre
  in the plane of rotation (mm); zero at theta = 0 where the tool was set.
- workpiece_setting: r = -(T + w x p): workpiece frame translated by T (mm) and turned by the
  small angles w (reported in deg), p the simulated tool position.
- time_offset: r = sim(t - tau) - sim(t) on every output at once: REC's clock lags by tau (s).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .align import Aligned

EFFECT_NAMES = ("thermal_drift", "backlash", "servo_lag", "periodic_pitch_error", "scale_error",
                "squareness", "straightness", "pivot_offset", "workpiece_setting", "time_offset",
                "friction", "quadrant_glitch")


def first_order(u: np.ndarray, dt: float, tau: float) -> np.ndarray:
    """First-order lag y' = (u - y)/tau of a sampled input, starting in steady state y(0) = u(0).

    Discretised exactly for an input linear between samples (ramp invariant): the usual
    zero-order hold would add half a sample of delay, which a servo-lag or clock-offset fit
    would then absorb.  Written out because scipy.signal has no ramp-invariant first-order filter
    with this initial state; the recursion itself runs in scipy.signal.lfilter.
    """
    from scipy.signal import lfilter
    x = dt / tau
    if x > 50:
        return np.array(u, float)
    a = math.exp(-x)
    # c = 1 - (1 - a)/x, by its series for small x to avoid cancellation
    c = x / 2 - x * x / 6 + x ** 3 / 24 if x < 1e-3 else 1.0 - (-math.expm1(-x)) / x
    b = [c, (1.0 - a) - c]
    # steady state before the start (u[-1] = y[-1] = u0) as the state of lfilter's direct form
    # II transposed: y[k] = b0 u[k] + z[k-1], z[k] = b1 u[k] + a y[k]
    zi = np.array([b[1] * u[0] + a * u[0]])
    y, _ = lfilter(b, [1.0, -a], u, zi=zi)
    return y


def direction_of_motion(p: np.ndarray, rel_threshold: float = 1e-3) -> np.ndarray:
    """+1/-1 for the direction of the last significant motion of a position signal.

    Kept through dwells (the screw stays on the flank it last pushed on); before the first
    motion the first motion's direction is assumed.
    """
    v = np.gradient(p)
    vmax = float(np.max(np.abs(v))) if len(v) else 0.0
    if vmax == 0:
        return np.zeros_like(p)
    s = np.where(np.abs(v) > rel_threshold * vmax, np.sign(v), 0.0)
    idx = np.where(s != 0, np.arange(len(s)), 0)
    np.maximum.accumulate(idx, out=idx)
    d = s[idx]
    first = np.flatnonzero(s)[0]
    d[:first] = s[first]
    return d


def visited_spacing(p: np.ndarray) -> float:
    """Typical spacing of the positions a signal visits: the median gap between its distinct
    values (1e-6 of the travel apart).  Dense motion gives a tiny spacing; a stop-and-measure
    run the distance between its targets."""
    p = np.asarray(p, float)
    rng = float(np.ptp(p))
    if rng == 0:
        return 0.0
    u = np.unique(np.round(p / (1e-6 * rng)))
    if len(u) < 2:
        return rng
    return float(np.median(np.diff(u))) * 1e-6 * rng


def legendre_cols(xi: np.ndarray, orders=(2, 3, 4)) -> list[np.ndarray]:
    from numpy.polynomial import legendre
    return [legendre.legval(xi, [0] * k + [1]) for k in orders]


ROT_AXIS = {"a": 0, "b": 1, "c": 2}
LIN_AXIS = {"x": 0, "y": 1, "z": 2}


def rot(axis: int, theta_rad: np.ndarray) -> np.ndarray:
    """(n,3,3) right-hand rotations about X/Y/Z (ISO 841 A/B/C)."""
    c, s = np.cos(theta_rad), np.sin(theta_rad)
    n = len(theta_rad)
    R = np.zeros((n, 3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R[:, axis, axis] = 1.0
    R[:, i, i] = c
    R[:, j, j] = c
    R[:, i, j] = -s
    R[:, j, i] = s
    return R


def backlash_play(p: np.ndarray, b: float, d: np.ndarray | None = None) -> np.ndarray:
    """Error y - p of a play (backlash) operator of width b driven by the position p.

    Vectorised form of y_k = clip(y_{k-1}, p_k - b/2, p_k + b/2): between reversals the output
    is at most b/2 behind; right after a reversal at p_rev it stands still until the input has
    travelled b.  Before the first motion the play is assumed taken up in that motion's direction.
    """
    d = direction_of_motion(p) if d is None else d
    h = 0.5 * b
    n = len(p)
    change = np.flatnonzero(d[1:] != d[:-1]) + 1
    # reversal position: the position just before the direction changed
    rev_idx = np.zeros(n, dtype=np.intp)
    rev_idx[change] = change - 1
    np.maximum.accumulate(rev_idx, out=rev_idx)
    p_rev = p[rev_idx]
    r = np.clip(d * h - (p - p_rev), -h, h)
    if len(change):
        r[:change[0]] = -d[0] * h
    else:
        r[:] = -d[0] * h
    return r


class Context:
    """Stacked, whitened layout of the outputs on a subset `idx` of the grid samples.

    Signals (and the filters run on them) always use the full grid; only the rows that enter
    the least-squares problems are the subset, so selection can run on a few thousand samples
    per output and the final fit on all of them.
    """

    def __init__(self, al: Aligned, idx: np.ndarray | None = None, sigma: dict | None = None):
        self.al = al
        self.idx = np.arange(al.n) if idx is None else np.asarray(idx)
        self.full = len(self.idx) == al.n
        self.outputs = al.outputs
        self.sigma = dict(sigma or al.noise_floor)
        n = len(self.idx)
        self.n = n
        self.slices = {k: slice(i * n, (i + 1) * n) for i, k in enumerate(self.outputs)}
        self.N = n * len(self.outputs)
        self.t = al.t[self.idx]
        self.z0 = np.concatenate([(al.rec[k] - al.sim[k])[self.idx] / self.sigma[k]
                                  for k in self.outputs])
        self.duration = float(al.t[-1] - al.t[0])
        self._dir = {}

    def values(self, key: str) -> np.ndarray:
        """Full-grid values of a driver signal."""
        return self.al.signals[key].values

    def vec(self, parts: dict) -> np.ndarray:
        """Stack full-grid per-output arrays (output units) into a whitened vector on idx."""
        v = np.zeros(self.N)
        for k, a in parts.items():
            a = np.asarray(a)
            if not self.full and len(a) == self.al.n:
                a = a[self.idx]
            v[self.slices[k]] = a / self.sigma[k]
        return v

    def direction(self, key: str) -> np.ndarray:
        """Direction of the last significant motion at each grid time, from the signal as
        sampled in its file (an interpolant between samples can ring at starts and stops, and
        a stop-and-measure grid does not see the motion between readings)."""
        if key not in self._dir:
            sig = self.al.signals[key]
            if sig.native:
                tn, vn = sig.native
                dn = direction_of_motion(np.asarray(vn, float))
                i = np.clip(np.searchsorted(tn, self.al.t, side="right") - 1, 0, len(tn) - 1)
                self._dir[key] = dn[i]
            else:
                self._dir[key] = direction_of_motion(self.values(key))
        return self._dir[key]


@dataclass(eq=False)
class Candidate:
    """One effect on given outputs driven by given inputs; subclasses define the model."""
    name: str
    outputs: tuple
    inputs: tuple
    n_lin: int = 0

    nl_names = ()  # names of the nonlinear parameters (class attribute, not a field)

    def __post_init__(self):
        self._cache = {}

    @property
    def label(self) -> str:
        return f"{self.name}[{','.join(self.outputs)}<-{','.join(self.inputs)}]"

    def n_params(self) -> int:
        return self.n_lin + len(self.nl_names)

    def bounds(self, ctx: Context):
        return [], []

    def columns(self, ctx: Context, eta) -> tuple:
        """(fixed (N,) or None, B (N, n_lin)) on ctx's rows, whitened; cached per (ctx, eta)."""
        key = (id(ctx),) + tuple(round(float(e), 10) for e in np.atleast_1d(eta))
        hit = self._cache.get(key)
        if hit is None:
            if len(self._cache) > 48:
                self._cache.clear()
            fixed, cols = self.build(ctx, np.atleast_1d(np.asarray(eta, float)))
            B = (np.column_stack([ctx.vec(c) for c in cols]) if cols
                 else np.zeros((ctx.N, 0)))
            hit = (ctx.vec(fixed) if fixed is not None else None, B)
            self._cache[key] = hit
        return hit

    # -- to override --
    def build(self, ctx: Context, eta) -> tuple:
        """(fixed part {output: full-grid array} or None, [column {output: array}, ...])."""
        raise NotImplementedError

    def coarse(self, ctx: Context, resid: np.ndarray, rows: np.ndarray):
        """Starting nonlinear parameters from a grid on the current residual."""
        return np.zeros(0)

    def physical(self, ctx: Context, eta, beta, cov_eta, cov_beta):
        raise NotImplementedError

    # -- helpers --
    def _rows_for(self, ctx, rows):
        m = np.zeros(ctx.N, bool)
        for o in self.outputs:
            m[ctx.slices[o]] = True
        return np.flatnonzero(m & rows)

    def _grid_best(self, ctx, resid, rows, grid):
        ir = self._rows_for(ctx, rows)
        best, best_rss = None, np.inf
        for g in grid:
            eta = np.atleast_1d(g)
            fixed, B = self.columns(ctx, eta)
            y = resid[ir] - (fixed[ir] if fixed is not None else 0.0)
            if B.shape[1]:
                Br = B[ir]
                beta, *_ = np.linalg.lstsq(Br, y, rcond=None)
                y = y - Br @ beta
            rss = float(y @ y)
            if rss < best_rss:
                best, best_rss = eta, rss
        return best


def _se(cov, i):
    return float(np.sqrt(max(cov[i, i], 0.0))) if cov is not None and cov.size else float("nan")


class ThermalDrift(Candidate):
    nl_names = ("log_tau",)

    def __init__(self, output, driver):
        super().__init__("thermal_drift", (output,), (driver,), 3)

    def bounds(self, ctx):
        lo = math.log(max(ctx.al.dt, 1e-3))
        # up to 3x the recording: a longer time constant makes the driver's response, the free
        # initial transient and the offset nearly collinear, and they cancel at large amplitudes
        hi = math.log(max(3 * ctx.duration, 10 * ctx.al.dt))
        return [lo], [hi]

    def build(self, ctx, eta):
        al = ctx.al
        sig = al.signals[self.inputs[0]]
        u = sig.values
        tau = math.exp(eta[0])
        tn, vn = sig.native if sig.native else (al.t, u)
        dt_native = float(np.median(np.diff(tn)))
        m = int(np.clip(math.ceil(al.dt / dt_native), 1, max(1, 200_000 // al.n)))
        if m > 1:
            # a sparse grid: filter the driver as it was sampled (a spindle-speed step smeared
            # over one coarse step would shift the response by half a step)
            k = np.arange((al.n - 1) * m + 1)
            tf = al.t[0] + (al.t[-1] - al.t[0]) * k / ((al.n - 1) * m)
            uf = np.interp(tf, tn, vn)
            y = first_order(uf, al.dt / m, tau)[::m] - uf[0]
        else:
            y = first_order(u, al.dt, tau) - u[0]
        # the structure's thermal state at the start is unknown: a free initial transient, and
        # a free offset (the drift is measured from an unknown reference state)
        tr = np.exp(-(ctx.al.t - ctx.al.t[0]) / tau)
        o = self.outputs[0]
        return None, [{o: y}, {o: tr}, {o: np.ones_like(y)}]

    def coarse(self, ctx, resid, rows):
        lo, hi = self.bounds(ctx)
        return self._grid_best(ctx, resid, rows, np.linspace(lo[0], hi[0], 20))

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        tau = math.exp(eta[0])
        unit = (ctx.al.signals[self.inputs[0]].unit or "unit").replace("/", "_").replace("%", "pct")
        g = "gain_mm_per_" + unit
        u = ctx.al.units[self.outputs[0]]
        return ({g: float(beta[0]), "tau_s": tau, f"initial_{u}": float(beta[1]),
                 f"offset_{u}": float(beta[2])},
                {g: _se(cov_beta, 0), "tau_s": tau * _se(cov_eta, 0), f"initial_{u}": _se(cov_beta, 1),
                 f"offset_{u}": _se(cov_beta, 2)})


class ThermalDirect(ThermalDrift):
    """Thermal drift that follows a logged temperature directly: r = k (u - u(t0)) + c.

    The reading of a sensor on the structure already is its thermal state, so the lag and the
    free initial transient of ThermalDrift are often not identifiable: when the temperature
    itself rises like exp(-t/tau), k (u - u0) equals c' + r0' exp(-t/tau) exactly, and the full
    model can trade its gain for a cancelling transient and offset (a gain of 0.01 +- 0.02
    µm/degC beside an initial -12 µm and offset +12 µm was seen).  Offered beside the full model
    for temperature drivers; with two parameters instead of four, BIC keeps it unless the lag
    is really there.
    """
    nl_names = ()

    def __init__(self, output, driver):
        Candidate.__init__(self, "thermal_drift", (output,), (driver,), 2)

    @property
    def label(self) -> str:
        return f"thermal_drift_direct[{self.outputs[0]}<-{self.inputs[0]}]"

    def bounds(self, ctx):
        return [], []

    def build(self, ctx, eta):
        u = ctx.al.signals[self.inputs[0]].values
        o = self.outputs[0]
        return None, [{o: u - u[0]}, {o: np.ones_like(u)}]

    def coarse(self, ctx, resid, rows):
        return np.zeros(0)

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        unit = (ctx.al.signals[self.inputs[0]].unit or "unit").replace("/", "_").replace("%", "pct")
        g = "gain_mm_per_" + unit
        u = ctx.al.units[self.outputs[0]]
        # tau 0: the response follows the reading without a lag of its own; no initial transient
        return ({g: float(beta[0]), "tau_s": 0.0, f"initial_{u}": 0.0, f"offset_{u}": float(beta[1])},
                {g: _se(cov_beta, 0), "tau_s": 0.0, f"initial_{u}": 0.0, f"offset_{u}": _se(cov_beta, 1)})


class Backlash(Candidate):
    nl_names = ("log_b",)

    def __init__(self, output):
        # one linear column: the state of the play before the axis first moves is unknown (a
        # machine switched on mid-gap); it is free until the first motion takes the play up
        super().__init__("backlash", (output,), (output,), 1)

    def _before_first(self, ctx):
        if not hasattr(self, "_first"):
            al = ctx.al
            sig = al.signals[self.outputs[0]]
            tn, vn = sig.native if sig.native else (al.t, sig.values)
            vn = np.asarray(vn, float)
            dv = np.abs(np.diff(vn))
            mv = np.flatnonzero(dv > 1e-3 * (dv.max() if len(dv) and dv.max() > 0 else 1.0))
            t_first = tn[mv[0]] if len(mv) else np.inf
            self._first = (al.t <= t_first).astype(float)
        return self._first

    def bounds(self, ctx):
        span = float(np.ptp(ctx.values(self.outputs[0])))
        return [math.log(1e-8 * max(span, 1e-6))], [math.log(0.05 * max(span, 1e-6))]

    def build(self, ctx, eta):
        o = self.outputs[0]
        b = math.exp(eta[0])
        sig = ctx.al.signals[o]
        first = [{o: self._before_first(ctx)}]
        if not sig.native or len(sig.native[0]) == ctx.al.n:
            return {o: backlash_play(ctx.values(o), b, ctx.direction(o))}, first
        # a grid coarser than SIM: the reversal positions come from SIM as sampled (on a 10 Hz
        # grid the sample before a reversal can be far from where the axis turned)
        if not hasattr(self, "_prev"):
            tn, vn = sig.native
            vn = np.asarray(vn, float)
            dn = direction_of_motion(vn)
            ch = np.flatnonzero(dn[1:] != dn[:-1]) + 1
            k = np.searchsorted(tn[ch], ctx.al.t, side="right") - 1 if len(ch) else np.full(ctx.al.n, -1)
            self._prev = (np.where(k >= 0, vn[ch[np.clip(k, 0, None)] - 1] if len(ch) else 0.0, np.nan),
                          ctx.direction(o), float(dn[0]))
        p_rev, d, d0 = self._prev
        h = 0.5 * b
        r = np.clip(d * h - (ctx.values(o) - p_rev), -h, h)
        r = np.where(np.isnan(p_rev), -d0 * h, r)
        return {o: r}, first

    def coarse(self, ctx, resid, rows):
        # the linear (instant-reversal) approximation gives b directly
        o = self.outputs[0]
        ir = self._rows_for(ctx, rows)
        col = ctx.vec({o: -0.5 * ctx.direction(o)})[ir]
        den = float(col @ col)
        b = float(col @ resid[ir]) / den if den > 0 else 0.0
        lo, hi = self.bounds(ctx)
        return np.array([float(np.clip(math.log(max(b, 1e-300)), lo[0], hi[0]))])

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        u = ctx.al.units[self.outputs[0]]
        b = math.exp(eta[0])
        return ({f"backlash_{u}": b, f"initial_state_{u}": float(beta[0]) if len(beta) else 0.0},
                {f"backlash_{u}": b * _se(cov_eta, 0), f"initial_state_{u}": _se(cov_beta, 0)})


class ServoLag(Candidate):
    nl_names = ("log_kv",)

    def __init__(self, output):
        super().__init__("servo_lag", (output,), (output,), 0)

    def bounds(self, ctx):
        # up to 20 per grid step, or 5x SIM's rate when the recording is sparse (the lag is
        # resolved through SIM, which is dense)
        hi = max(20.0 / ctx.al.dt, 5.0 * ctx.al.rates["sim"], 1.0)
        if type(self) is ServoLag:
            # identifiable: a lag shorter than half of the finer file's sample step cannot be
            # told from a pure delay (time_offset), which then has to explain it
            hi = min(hi, 2.0 * max(ctx.al.rates["sim"], ctx.al.rates["rec"]))
        return [math.log(max(0.5, 1.0 / ctx.duration))], [math.log(hi)]

    def build(self, ctx, eta):
        # the filter runs on a finer grid from SIM's spline: the ramp-invariant step assumes the
        # input linear between samples, and a moving axis is parabolic while it accelerates;
        # at least 4x finer, and fine against SIM's own step and the lag itself.  It starts
        # up to 20 lags before the grid (SIM permitting): the axis may be moving at the start.
        al = ctx.al
        o = self.outputs[0]
        tau = math.exp(-eta[0])
        h_want = min(0.25 / al.rates["sim"], tau / 8)
        m = int(np.clip(math.ceil(al.dt / h_want), 4, max(4, 400_000 // al.n)))
        h = al.dt / m
        warm = int(min(max(al.t[0] - al.sim_span[0], 0.0), 20 * tau) / h)
        k = np.arange(-warm, (al.n - 1) * m + 1)
        tf = al.t[0] + (al.t[-1] - al.t[0]) * k / ((al.n - 1) * m)
        pf = al.sim_spline[o](tf)
        y = first_order(pf, h, tau)[warm::m] - al.sim[o]
        return {o: y}, []

    def coarse(self, ctx, resid, rows):
        lo, hi = self.bounds(ctx)
        return self._grid_best(ctx, resid, rows, np.linspace(lo[0], hi[0], 24))

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        kv = math.exp(eta[0])
        return {"kv_per_s": kv}, {"kv_per_s": kv * _se(cov_eta, 0)}


class PeriodicPitch(Candidate):
    nl_names = ("log_lead",)

    def __init__(self, output):
        super().__init__("periodic_pitch_error", (output,), (output,), 2)

    def bounds(self, ctx):
        p = ctx.values(self.outputs[0])
        rng = float(np.ptp(p))
        # identifiable leads only: at least twice the spacing of the positions that were
        # visited (a shorter period aliases), and at most half the travel
        lo = max(0.2, rng / 4000.0, 2.0 * visited_spacing(p))
        hi = max(rng / 2.0, 1.01 * lo)
        return [math.log(lo)], [math.log(hi)]

    def identifiable(self, ctx) -> bool:
        p = ctx.values(self.outputs[0])
        return 2.0 * visited_spacing(p) < float(np.ptp(p)) / 2.0

    def build(self, ctx, eta):
        ph = 2 * np.pi * ctx.values(self.outputs[0]) / math.exp(eta[0])
        o = self.outputs[0]
        return None, [{o: np.sin(ph)}, {o: np.cos(ph)}]

    def coarse(self, ctx, resid, rows):
        # periodogram of the residual binned by position (the screw error repeats in p, not in
        # t): bin means on a uniform position grid, empty bins zero, FFT zero-padded 8x
        lo, hi = self.bounds(ctx)
        o = self.outputs[0]
        sl = ctx.slices[o]
        rm = rows[sl]
        pp = ctx.values(o)[ctx.idx][rm]
        rr = resid[sl][rm]
        pmin, pmax = float(pp.min()), float(pp.max())
        lead_min = math.exp(lo[0])
        nb = int(min(8192, max(16, 4 * (pmax - pmin) / lead_min)))
        h = (pmax - pmin) / nb if pmax > pmin else 1.0
        idx = np.clip(((pp - pmin) / h).astype(int), 0, nb - 1)
        cnt = np.bincount(idx, minlength=nb)
        ok = cnt > 0
        means = np.zeros(nb)
        means[ok] = np.bincount(idx, rr, minlength=nb)[ok] / cnt[ok]
        means[ok] -= means[ok].mean()
        nfft = 8 * nb
        spec = np.abs(np.fft.rfft(means, nfft)) ** 2
        f = np.fft.rfftfreq(nfft, h)  # cycles per mm
        keep = (f >= math.exp(-hi[0])) & (f <= math.exp(-lo[0]))
        if not keep.any():
            return np.array([0.5 * (lo[0] + hi[0])])
        k = np.flatnonzero(keep)[np.argmax(spec[keep])]
        return np.array([float(np.clip(-math.log(f[k]), lo[0], hi[0]))])

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        lead = math.exp(eta[0])
        a, b = float(beta[0]), float(beta[1])
        amp = math.hypot(a, b)
        u = ctx.al.units[self.outputs[0]]
        if cov_beta is not None and cov_beta.size and amp > 0:
            g = np.array([a / amp, b / amp])
            s_amp = float(np.sqrt(max(g @ cov_beta[:2, :2] @ g, 0)))
            gp = np.array([-b, a]) / amp ** 2
            s_ph = float(np.sqrt(max(gp @ cov_beta[:2, :2] @ gp, 0)))
        else:
            s_amp = s_ph = float("nan")
        return ({"lead_mm": lead, f"amplitude_{u}": amp, "phase_deg": math.degrees(math.atan2(b, a))},
                {"lead_mm": lead * _se(cov_eta, 0), f"amplitude_{u}": s_amp,
                 "phase_deg": math.degrees(s_ph)})


class ScaleError(Candidate):
    def __init__(self, output):
        super().__init__("scale_error", (output,), (output,), 1)

    def build(self, ctx, eta):
        o = self.outputs[0]
        return None, [{o: ctx.values(o)}]

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        return {"scale": float(beta[0])}, {"scale": _se(cov_beta, 0)}


class Squareness(Candidate):
    def __init__(self, output, driver):
        super().__init__("squareness", (output,), (driver,), 1)

    def build(self, ctx, eta):
        return None, [{self.outputs[0]: ctx.values(self.inputs[0])}]

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        return ({"angle_deg": math.degrees(float(beta[0]))},
                {"angle_deg": math.degrees(_se(cov_beta, 0))})


class Straightness(Candidate):
    # constant and linear terms are included: a straightness profile is measured against no
    # particular line, so neither its offset nor its slope is known to be zero; squareness is
    # the one-parameter, linear special case
    ORDERS = (0, 1, 2, 3, 4)

    def __init__(self, output, driver):
        super().__init__("straightness", (output,), (driver,), len(self.ORDERS))

    def _xi(self, ctx):
        p = ctx.values(self.inputs[0])
        lo, hi = float(p.min()), float(p.max())
        return (2 * p - (lo + hi)) / max(hi - lo, 1e-12), lo, hi

    def build(self, ctx, eta):
        xi, _, _ = self._xi(ctx)
        return None, [{self.outputs[0]: c} for c in legendre_cols(xi, self.ORDERS)]

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        _, lo, hi = self._xi(ctx)
        u = ctx.al.units[self.outputs[0]]
        xi = np.linspace(-1, 1, 201)
        prof = np.column_stack(legendre_cols(xi, self.ORDERS)) @ np.asarray(beta)
        par = {f"P{k}_{u}": float(b) for k, b in zip(self.ORDERS, beta)}
        unc = {f"P{k}_{u}": _se(cov_beta, i) for i, k in enumerate(self.ORDERS)}
        # peak-to-valley about the best straight line through the profile (ISO 230-1 style)
        lin = np.polyval(np.polyfit(xi, prof, 1), xi)
        par.update({f"peak_to_valley_{u}": float(np.ptp(prof - lin)), "range_lo_mm": lo,
                    "range_hi_mm": hi})
        return par, unc


class PivotOffset(Candidate):
    def __init__(self, outputs, driver, axis: int, comps: tuple):
        super().__init__("pivot_offset", tuple(outputs), (driver,), len(comps))
        self.axis = axis
        self.comps = comps  # tool-edge offset components (0=x,1=y,2=z) in the plane of rotation

    def build(self, ctx, eta):
        R = rot(self.axis, np.radians(ctx.values(self.inputs[0])))
        cols = []
        for c in self.comps:
            col = R[:, :, c] - np.eye(3)[c]  # (R - I) e_c
            cols.append({o: col[:, LIN_AXIS[ctx.al.signals[o].letter]] for o in self.outputs})
        return None, cols

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        names = [f"d{'xyz'[c]}_mm" for c in self.comps]
        return ({n: float(b) for n, b in zip(names, beta)},
                {n: _se(cov_beta, i) for i, n in enumerate(names)})


class WorkpieceSetting(Candidate):
    def __init__(self, al: Aligned, outputs, with_rotation: bool):
        super().__init__("workpiece_setting", tuple(outputs), tuple(outputs), 0)
        self.with_rotation = with_rotation
        lets = {al.signals[o].letter: o for o in self.outputs}
        names = [f"t{L}_mm" for L in sorted(lets)]
        self._rot = []
        if with_rotation:
            for ax in range(3):
                # w about ax moves the two other components, each needs the third's position
                seen = [L for L in lets if LIN_AXIS[L] != ax
                        and "xyz"[3 - ax - LIN_AXIS[L]] in lets]
                if seen:
                    self._rot.append(ax)
                    names.append(f"r{'xyz'[ax]}_deg")
        self._names = names
        self.n_lin = len(names)

    @property
    def label(self) -> str:
        return super().label + ("+rotation" if self.with_rotation else "")

    def build(self, ctx, eta):
        al = ctx.al
        lets = {al.signals[o].letter: o for o in self.outputs}
        p = np.zeros((al.n, 3))
        for L, o in lets.items():
            p[:, LIN_AXIS[L]] = ctx.values(o)
        cols = [{o: -np.ones(al.n)} for L, o in sorted(lets.items())]
        for ax in self._rot:
            w = np.zeros(3)
            w[ax] = 1.0
            r = -np.cross(w, p)  # -(w x p)
            cols.append({o: r[:, LIN_AXIS[L]] for L, o in lets.items()})
        return None, cols

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        par, unc = {}, {}
        for i, (nm, b) in enumerate(zip(self._names, beta)):
            f = math.degrees(1.0) if nm.endswith("_deg") else 1.0
            par[nm] = float(b) * f
            unc[nm] = _se(cov_beta, i) * f
        return par, unc


class TimeOffset(Candidate):
    nl_names = ("tau_dt",)

    def __init__(self, outputs):
        super().__init__("time_offset", tuple(outputs), ("t",), 0)

    def bounds(self, ctx):
        al = ctx.al
        w = max(10.0 * al.dt, 0.02 * abs(al.offset0))
        return [(al.offset0 - w) / al.dt], [(al.offset0 + w) / al.dt]

    def build(self, ctx, eta):
        al = ctx.al
        tau = float(eta[0]) * al.dt
        # evaluated on ctx's rows only: the spline needs no neighbours
        return {o: al.sim_spline[o](ctx.t - tau) - al.sim[o][ctx.idx] for o in self.outputs}, []

    def coarse(self, ctx, resid, rows):
        lo, hi = self.bounds(ctx)
        c = ctx.al.offset0 / ctx.al.dt
        grid = np.unique(np.clip(np.concatenate([[c], np.linspace(lo[0], hi[0], 21)]), lo[0], hi[0]))
        return self._grid_best(ctx, resid, rows, grid)

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        dt = ctx.al.dt
        return {"offset_s": float(eta[0]) * dt}, {"offset_s": _se(cov_eta, 0) * dt}


class ServoLagDerivative(Candidate):
    """Servo lag of a velocity output, linearised through a logged commanded acceleration:
    r = -tau a_cmd (tau linear; kv = 1/tau).

    The first-order term of F_tau[c] - c.  Beside the filtered form (ServoLagHermite) because
    real loggers sample command and actual a little apart within a cycle: the linear form uses
    the logged acceleration only at the sample itself and degrades more gracefully then.
    """

    def __init__(self, output, derivative):
        super().__init__("servo_lag", (output,), (output, derivative), 1)

    @property
    def label(self) -> str:
        return super().label + "(linear)"

    def build(self, ctx, eta):
        return None, [{self.outputs[0]: -ctx.values(self.inputs[1])}]

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        tau = float(beta[0])
        s_tau = _se(cov_beta, 0)
        kv = 1.0 / tau if tau > 0 else float("inf")
        return ({"kv_per_s": kv, "tau_s": tau},
                {"kv_per_s": s_tau / tau ** 2 if tau > 0 else float("nan"), "tau_s": s_tau})


class ServoLagHermite(ServoLag):
    """Servo lag of a velocity (or acceleration) output, using a logged commanded derivative.

    A first-order loop of time constant tau = 1/kv lags its command c by r = F_tau[c] - c
    (-tau dc/dt to first order).  At a coarse logging rate (10 Hz) c between its samples is
    poorly known; with the commanded acceleration logged beside the commanded velocity the
    command is a cubic Hermite curve through both (exact slopes at the samples), which is what
    the lag filter runs on, on a grid fine against tau.
    """

    def __init__(self, output, derivative):
        Candidate.__init__(self, "servo_lag", (output,), (output, derivative), 0)
        self._herm = None

    def _hermite(self, ctx):
        if self._herm is None:
            from scipy.interpolate import CubicHermiteSpline
            al = ctx.al
            tv, v = al.signals[self.outputs[0]].native
            sd = al.signals[self.inputs[1]]
            td, a = sd.native if sd.native else (al.t, sd.values)
            a_v = np.interp(tv, td, a)
            h = CubicHermiteSpline(tv, v, a_v, extrapolate=False)
            self._herm = lambda x, _h=h, _a=tv[0], _b=tv[-1]: _h(np.clip(x, _a, _b))
        return self._herm

    def build(self, ctx, eta):
        al = ctx.al
        o = self.outputs[0]
        tau = math.exp(-eta[0])
        m = int(np.clip(math.ceil(al.dt / (tau / 8)), 4, max(4, 400_000 // al.n)))
        h = al.dt / m
        warm = int(min(max(al.t[0] - al.sim_span[0], 0.0), 20 * tau) / h)
        k = np.arange(-warm, (al.n - 1) * m + 1)
        tf = al.t[0] + (al.t[-1] - al.t[0]) * k / ((al.n - 1) * m)
        cf = self._hermite(ctx)(tf)
        y = first_order(cf, h, tau)[warm::m] - al.sim[o]
        return {o: y}, []

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        kv = math.exp(eta[0])
        s = _se(cov_eta, 0)
        return {"kv_per_s": kv, "tau_s": 1.0 / kv}, {"kv_per_s": kv * s, "tau_s": s / kv}


class Friction(Candidate):
    """Coulomb + viscous friction seen on a velocity output: the drive loses a constant c
    against the direction of motion and b per unit of velocity: r = -c sign(v) - b v.

    sign(v) is smoothed over 2 % of the peak velocity (a Stribeck-like transition) so that
    noise at rest does not switch it.
    """
    def __init__(self, output):
        super().__init__("friction", (output,), (output,), 2)

    def build(self, ctx, eta):
        o = self.outputs[0]
        v = ctx.values(o)
        vs = 0.02 * float(np.max(np.abs(v))) or 1.0
        return None, [{o: -np.tanh(v / vs)}, {o: -v}]

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        u = ctx.al.units[self.outputs[0]]
        return ({f"coulomb_{u.replace('/', '_per_')}": float(beta[0]), "viscous": float(beta[1])},
                {f"coulomb_{u.replace('/', '_per_')}": _se(cov_beta, 0), "viscous": _se(cov_beta, 1)})


class QuadrantGlitch(Candidate):
    """Friction at velocity reversals (quadrant glitch) on a position output.

    When an axis reverses, Coulomb friction flips sign and the velocity loop needs time to
    rebuild the torque: the axis sticks while the command moves away, then catches up.  The
    error is a spike against the new direction after every reversal,
    r = -A d_new s exp(1 - s), s = (t - t_rev)/tau (peak A at tau after the reversal).
    A in mm (linear), tau in s (nonlinear, 2 grid steps .. 1 s).
    """
    nl_names = ("log_tau",)

    def __init__(self, output):
        super().__init__("quadrant_glitch", (output,), (output,), 1)
        self._rev = None

    def _reversals(self, ctx):
        if self._rev is None:
            al = ctx.al
            sig = al.signals[self.outputs[0]]
            tn, vn = sig.native if sig.native else (al.t, sig.values)
            dn = direction_of_motion(np.asarray(vn, float))
            ch = np.flatnonzero(dn[1:] != dn[:-1]) + 1
            t_rev = 0.5 * (tn[ch - 1] + tn[ch]) if len(ch) else np.zeros(0)
            k = np.searchsorted(t_rev, al.t, side="right") - 1
            since = np.where(k >= 0, al.t - t_rev[np.clip(k, 0, None)] if len(t_rev) else np.inf, np.inf)
            self._rev = (since, ctx.direction(self.outputs[0]), len(ch))
        return self._rev

    def bounds(self, ctx):
        return [math.log(2 * ctx.al.dt)], [math.log(max(1.0, 4 * ctx.al.dt))]

    def build(self, ctx, eta):
        since, d, _ = self._reversals(ctx)
        s = since / math.exp(eta[0])
        shape = np.where(np.isfinite(s), s * np.exp(1.0 - np.minimum(s, 700.0)), 0.0)
        return None, [{self.outputs[0]: -d * shape}]

    def coarse(self, ctx, resid, rows):
        lo, hi = self.bounds(ctx)
        return self._grid_best(ctx, resid, rows, np.linspace(lo[0], hi[0], 16))

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        u = ctx.al.units[self.outputs[0]] or "mm"
        tau = math.exp(eta[0])
        return ({f"peak_{u}": float(beta[0]), "tau_s": tau},
                {f"peak_{u}": _se(cov_beta, 0), "tau_s": tau * _se(cov_eta, 0)})


class StickSlip(QuadrantGlitch):
    """Stick-slip at velocity reversals on a position output: the other form of the quadrant
    glitch (same effect name, label suffix "(stick-slip)").

    After a reversal static friction holds the slide where it stopped while the command moves
    away; the drive winds up until the command has left the reversal point by the breakaway
    distance delta (static friction over the drive's stiffness), then the slide slips and
    catches up with time constant tau.  With D = |p_cmd(t) - p_cmd(t_rev)|:
    r = -d_new D while D < delta (stuck: the slide does not move, the error grows with the
    command's own motion, parabolic from a smooth reversal), then
    r = -d_new delta exp(-(t - t_b)/tau), t_b the breakaway.  No free amplitude: a slide that
    moved while "stuck" would not be stick-slip, and a free one could take any sign.  The spike
    form (QuadrantGlitch) has a fixed shape in time; this one follows the command.
    delta in the output's unit, tau in s (both nonlinear).
    """
    nl_names = ("log_breakaway", "log_tau")

    def __init__(self, output):
        super().__init__(output)
        self.n_lin = 0
        self._prev = None

    @property
    def label(self) -> str:
        return super().label + "(stick-slip)"

    def _segments(self, ctx):
        if self._prev is None:
            al = ctx.al
            o = self.outputs[0]
            sig = al.signals[o]
            tn, vn = sig.native if sig.native else (al.t, sig.values)
            dn = direction_of_motion(np.asarray(vn, float))
            ch = np.flatnonzero(dn[1:] != dn[:-1]) + 1
            t_rev = 0.5 * (tn[ch - 1] + tn[ch]) if len(ch) else np.zeros(0)
            k = np.searchsorted(t_rev, al.t, side="right") - 1
            # the reversal point is the command's extremum between the two native samples
            # (the midpoint can miss it by half a sample, and D grows quadratically from it)
            p_rev = np.zeros(len(t_rev))
            for j, c in enumerate(ch):
                tt = np.linspace(tn[max(c - 2, 0)], tn[min(c + 1, len(tn) - 1)], 64)
                pp = al.sim_spline[o](tt)
                p_rev[j] = pp.min() if dn[c] > 0 else pp.max()
            D = np.where(k >= 0, np.abs(al.sim[o] - p_rev[np.clip(k, 0, None)]) if len(t_rev) else 0.0, 0.0)
            self._prev = (k, D, len(t_rev))
        return self._prev

    def bounds(self, ctx):
        span = float(np.ptp(ctx.al.sim[self.outputs[0]])) or 1.0
        return ([math.log(1e-5 * span), math.log(ctx.al.dt / 2)],
                [math.log(0.2 * span), math.log(max(1.0, 4 * ctx.al.dt))])

    def build(self, ctx, eta):
        k, D, nrev = self._segments(ctx)
        d = ctx.direction(self.outputs[0])
        delta, tau = math.exp(eta[0]), math.exp(eta[1])
        t = ctx.al.t
        shape = np.zeros_like(D)
        for j in range(nrev):
            seg = np.flatnonzero(k == j)
            if not len(seg):
                continue
            broken = np.flatnonzero(D[seg] >= delta)
            if not len(broken):
                shape[seg] = D[seg]
                continue
            b = broken[0]
            shape[seg[:b]] = D[seg[:b]]
            # the breakaway instant, between two samples: where D crosses delta
            tb = t[seg[b]]
            if b > 0 and D[seg[b]] > D[seg[b - 1]]:
                f = (delta - D[seg[b - 1]]) / (D[seg[b]] - D[seg[b - 1]])
                tb = t[seg[b - 1]] + f * (t[seg[b]] - t[seg[b - 1]])
            shape[seg[b:]] = delta * np.exp(-np.minimum((t[seg[b:]] - tb) / tau, 700.0))
        return {self.outputs[0]: -d * shape}, []

    def coarse(self, ctx, resid, rows):
        lo, hi = self.bounds(ctx)
        grid = [np.array([a, b]) for a in np.linspace(lo[0], hi[0], 14)
                for b in np.linspace(lo[1], hi[1], 6)]
        return self._grid_best(ctx, resid, rows, grid)

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        u = ctx.al.units[self.outputs[0]] or "mm"
        delta, tau = math.exp(eta[0]), math.exp(eta[1])
        return ({f"breakaway_{u}": delta, "tau_s": tau},
                {f"breakaway_{u}": delta * _se(cov_eta, 0), "tau_s": tau * _se(cov_eta, 1)})


class Group(Candidate):
    """The same effect on several outputs at once, each with its own parameters (e.g. a servo
    lag on every axis).  Tried beside the single-output candidates because one effect common
    to all outputs (a time offset) can explain to first order what each output's own effect
    explains, and a greedy step adding one output's effect at a time cannot leave it."""

    def __init__(self, members):
        m0 = members[0]
        super().__init__(m0.name, tuple(o for m in members for o in m.outputs),
                         tuple(dict.fromkeys(i for m in members for i in m.inputs)),
                         sum(m.n_lin for m in members))
        self.members = list(members)

    @property
    def label(self) -> str:
        return "+".join(m.label for m in self.members)

    def n_params(self) -> int:
        return sum(m.n_params() for m in self.members)

    @property
    def nl_names(self):
        return tuple(n for m in self.members for n in m.nl_names)

    def split_eta(self, eta):
        out, i = [], 0
        for m in self.members:
            k = len(m.nl_names)
            out.append(np.asarray(eta[i:i + k]))
            i += k
        return out

    def split_beta(self, beta):
        out, i = [], 0
        for m in self.members:
            out.append(np.asarray(beta[i:i + m.n_lin]))
            i += m.n_lin
        return out

    def bounds(self, ctx):
        lo, hi = [], []
        for m in self.members:
            a, b = m.bounds(ctx)
            lo += list(a)
            hi += list(b)
        return lo, hi

    def build(self, ctx, eta):
        fixed, cols = None, []
        for m, e in zip(self.members, self.split_eta(eta)):
            f, c = m.build(ctx, e)
            if f is not None:
                fixed = dict(fixed or {})
                for k, v in f.items():
                    fixed[k] = fixed.get(k, 0.0) + v
            cols += c
        return fixed, cols

    def coarse(self, ctx, resid, rows):
        return np.concatenate([np.atleast_1d(m.coarse(ctx, resid, rows)) for m in self.members])


# effects that act on a machine at rest (the only candidates of a stop-and-measure recording)
AT_REST = ("thermal_drift", "backlash", "periodic_pitch_error", "scale_error", "squareness",
           "straightness", "pivot_offset", "workpiece_setting")
_DERIV = {"velocity": "acceleration", "angular_velocity": "angular_acceleration"}


_ROLE_WORDS = {"v", "vel", "velo", "velocity", "spd", "speed", "feed", "feedrate", "a", "acc",
               "accel", "acceleration", "cmd", "command", "commanded", "act", "actual", "set",
               "nom", "meas", "measured", "des"}


def _stem(key: str) -> str:
    """A name without the words that say which derivative or which side it is:
    `spd_axis` and `acc_axis` -> 'axis', `X1_CommandVelocity` -> 'x1'."""
    from .data import _tokens
    return "".join(w for w in _tokens(key) if w not in _ROLE_WORDS)


def _pairs_with(sig_o, key_o: str, sig_d, key_d: str, n_rate_outs: int, n_derivs: int) -> bool:
    """Is the derivative signal d the commanded derivative of output o?"""
    if sig_o.letter is not None and sig_d.letter is not None:
        return sig_o.letter == sig_d.letter
    if _stem(key_o) and _stem(key_o) == _stem(key_d):
        return True
    return n_rate_outs == 1 and n_derivs == 1


def candidates(al: Aligned) -> list[Candidate]:
    """Every effect the data could support, given the outputs' kinds and the available drivers."""
    # outputs of unknown kind (no unit, a name that says nothing) are treated as positions of
    # an unnamed axis: the effects that need an axis letter do not apply to them
    outs = [o for o in al.outputs if al.kinds[o] in ("length", "angle", "other")]
    rates = [o for o in al.outputs if al.kinds[o] in ("velocity", "angular_velocity",
                                                        "acceleration", "angular_acceleration")]
    moving = {o for o in outs + rates if np.ptp(al.sim[o]) > 0}
    sig = al.signals
    lin_drivers = [k for k, s in sig.items() if s.kind == "length" and np.ptp(s.values) > 0]
    ang_drivers = [k for k, s in sig.items() if s.kind == "angle" and np.ptp(s.values) > 0
                   and s.letter in ROT_AXIS]
    thermal_drivers = [k for k, s in sig.items() if s.source != "sim-output"
                       and s.kind in ("temperature", "speed", "other") and np.ptp(s.values) > 0]
    out = []
    for o in outs:
        for d in thermal_drivers:
            out.append(ThermalDrift(o, d))
            if sig[d].kind == "temperature":
                out.append(ThermalDirect(o, d))
        if o in moving:
            out += [Backlash(o), ServoLag(o), ScaleError(o)]
            if not al.at_rest:
                qg = QuadrantGlitch(o)
                if qg._reversals(Context(al, np.arange(0, al.n, max(1, al.n // 2000))))[2] >= 2:
                    out += [qg, StickSlip(o)]
            if al.kinds[o] in ("length", "other"):
                pp = PeriodicPitch(o)
                if pp.identifiable(Context(al, np.arange(0, al.n, max(1, al.n // 2000)))):
                    out.append(pp)
        if al.kinds[o] == "length":
            for d in lin_drivers:
                if d == o or (sig[d].letter is not None and sig[d].letter == sig[o].letter):
                    continue
                out += [Squareness(o, d), Straightness(o, d)]
    for o in rates:
        if o not in moving:
            continue
        # servo lag through a logged commanded derivative of the same axis when there is one
        dk = _DERIV.get(al.kinds[o])
        all_d = [k for k, s in sig.items() if dk and s.kind == dk and s.source == "sim"
                 and np.ptp(s.values) > 0]
        n_rate = sum(al.kinds[r] == al.kinds[o] for r in rates)
        derivs = [k for k in all_d if _pairs_with(sig[o], o, sig[k], k, n_rate, len(all_d))]
        out += ([c for d in derivs for c in (ServoLagDerivative(o, d), ServoLagHermite(o, d))]
                or [ServoLag(o)])
        if al.kinds[o] in ("velocity", "angular_velocity"):
            out.append(Friction(o))
    lin_outs = {sig[o].letter: o for o in outs if al.kinds[o] == "length" and sig[o].letter in LIN_AXIS}
    for d in ang_drivers:
        ax = ROT_AXIS[sig[d].letter]
        plane = [c for c in range(3) if c != ax]
        affected = [lin_outs["xyz"[c]] for c in plane if "xyz"[c] in lin_outs]
        if affected:
            out.append(PivotOffset(affected, d, ax, tuple(plane)))
    if lin_outs:
        wo = [lin_outs[L] for L in sorted(lin_outs)]
        out.append(WorkpieceSetting(al, wo, False))
        ws = WorkpieceSetting(al, wo, True)
        if ws._rot:
            out.append(ws)
    if moving:
        out.append(TimeOffset(tuple(o for o in al.outputs if o in moving)))
        lags = [c for c in out if type(c) is ServoLag]
        # the common offset and the axes' lags are entangled (the correlation peak that starts
        # the offset holds both, and a delay and a lag agree to first order): one lag added to
        # a shared offset cannot improve the fit while the other axes still need the offset as
        # it is, so the lags of all axes are also tried as one group
        if len(lags) >= 2:
            out.append(Group(lags))
    if al.at_rest:
        out = [c for c in out if c.name in AT_REST]
    return out
