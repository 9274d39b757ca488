"""The ground every effect stands on: the layout of the outputs (Context), the Candidate
interface, and the signal helpers the effects share (filters, directions, rotations)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..align import Aligned

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


def first_order_strided(u: np.ndarray, dt: float, tau: float, s: int) -> np.ndarray:
    """first_order(u, dt, tau)[::s], exactly, at about 1/s of the cost of the recursion.

    s steps of the ramp-invariant recursion y[k] = a y[k-1] + b0 u[k] + b1 u[k-1] compose to
    y[k+s] = a^s y[k] + sum_j w_j u[k+s-j]: a short FIR filter of the fine input (np.convolve)
    read every s-th sample, then a first-order recursion on the strided sequence.  Used while
    selecting on every s-th grid sample: the driver still enters at every grid sample."""
    from scipy.signal import lfilter
    u = np.asarray(u, float)
    if s <= 1:
        return first_order(u, dt, tau)
    x = dt / tau
    if x > 50:
        return u[::s].copy()
    a = math.exp(-x)
    c = x / 2 - x * x / 6 + x ** 3 / 24 if x < 1e-3 else 1.0 - (-math.expm1(-x)) / x
    b0, b1 = c, (1.0 - a) - c
    j = np.arange(1, s)
    w = np.empty(s + 1)
    w[0] = b0
    w[1:s] = b0 * a ** j + b1 * a ** (j - 1)
    w[s] = b1 * a ** (s - 1)
    M = len(range(0, len(u), s))
    g = np.convolve(u, w)[s::s][:M - 1]
    A = a ** s
    y0 = u[0]  # steady state before the start, as in first_order
    if M == 1:
        return np.array([y0])
    y, _ = lfilter([1.0], [1.0, -A], g, zi=np.array([A * y0]))
    return np.concatenate([[y0], y])


def direction_of_motion(p: np.ndarray, rel_threshold: float = 1e-3) -> np.ndarray:
    """+1/-1 for the direction of the last significant motion of a position signal.

    Kept through dwells (the screw stays on the flank it last pushed on); before the first
    motion the first motion's direction is assumed.
    """
    if not len(p):
        return np.zeros_like(p)
    return _hold_sign(np.gradient(p), rel_threshold)


def step_direction(p: np.ndarray, rel_threshold: float = 1e-3) -> np.ndarray:
    """+1/-1 for the direction of each step p[k] -> p[k+1] of a sampled position (n-1 values),
    held through steps without motion; the first motion's direction before it.

    For a position sampled coarser than the grid it is compared on: between two samples the
    axis moves as the step says, while a central difference at a sample where it turns (a G1
    corner) averages the two steps' directions."""
    return _hold_sign(np.diff(np.asarray(p, float)), rel_threshold)


def _hold_sign(v: np.ndarray, rel_threshold: float) -> np.ndarray:
    """The sign of each rate v, held through the rates below rel_threshold of the largest;
    before the first significant one, its sign (zeros when nothing moves)."""
    vmax = float(np.max(np.abs(v))) if len(v) else 0.0
    if vmax == 0:
        return np.zeros_like(v)
    s = np.where(np.abs(v) > rel_threshold * vmax, np.sign(v), 0.0)
    idx = np.where(s != 0, np.arange(len(s)), 0)
    np.maximum.accumulate(idx, out=idx)
    d = s[idx]
    first = np.flatnonzero(s)[0]
    d[:first] = s[first]
    return d


def coarse_native(al, tn) -> bool:
    """Is a signal's own sampling (times tn) coarser than the grid (steps of 1.5 grid steps or
    more)?  Then its direction between samples is its step's (step_direction)."""
    return len(tn) >= 2 and float(np.median(np.diff(tn))) > 1.5 * al.dt


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


def below_rounding(ctx, o: str, beta) -> str | None:
    """A periodic error in the position is refused when its amplitude is below the rounding step
    of the recorded values: the rounding error of a recording written in coarse counts or with
    few significant figures is itself a function of the position (a sawtooth of the step's
    period, aliased by the sampling) that a periodic term partly fits."""
    q = float(ctx.al.quantum.get(o, 0.0))
    amp = float(np.linalg.norm(beta)) if len(beta) else 0.0
    if q > 0 and amp < q:
        return (f"amplitude {amp:.3g} below the recording's rounding step {q:.3g} "
                f"({ctx.al.units.get(o, '')}): not identifiable from rounded values")
    return None


class Context:
    """Stacked, whitened layout of the outputs on a subset `idx` of the grid samples.

    Signals (and the filters run on them) always use the full grid; only the rows that enter
    the least-squares problems are the subset, so selection can run on a few thousand samples
    per output and the final fit on all of them.
    """

    def __init__(self, al: Aligned, idx: np.ndarray | None = None, sigma: dict | None = None):
        self.al = al
        self.idx = al.rows() if idx is None else np.asarray(idx)
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
            if sig.native and coarse_native(self.al, sig.native[0]):
                tn, vn = sig.native
                ds = step_direction(vn)
                # a grid time in (t_k, t_k+1] lies on step k
                i = np.clip(np.searchsorted(tn, self.al.t, side="left") - 1, 0, len(ds) - 1)
                self._dir[key] = ds[i]
            elif sig.native:
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

    def implausible(self, ctx: Context, eta, beta) -> str | None:
        """Why fitted parameters cannot be taken as this effect (None: they can)."""
        return None

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
