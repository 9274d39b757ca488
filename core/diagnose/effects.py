"""The library of physical effects a simulation may have left out.

Every effect predicts the residual REC - SIM it would cause on one or more outputs, as
``fixed(eta) + B(eta) @ beta``: ``eta`` are the few nonlinear parameters (time constants, screw
lead, clock offset, kv) that are fitted by nonlinear least squares, ``beta`` the amplitudes that
enter linearly and are solved exactly for every ``eta`` (variable projection).  All vectors are
stacked over the outputs and divided by each output's noise floor, so outputs in mm and deg and
of different noise weigh by their information.

Signatures and parameters (documented for users in docs/diagnose.md):

- thermal_drift: r = k * (F_tau[u] - u(t0)), F_tau a first-order lag of a driver u (spindle
  speed, a logged temperature, any other slowly varying input); k in mm per unit of u, tau in s.
- backlash: r = -b/2 * d(t), d = +1/-1 the direction of the axis' last motion (kept during dwells).
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
                "squareness", "straightness", "pivot_offset", "workpiece_setting", "time_offset")


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


class Context:
    """Stacked, whitened layout of the outputs and cached driver signals."""

    def __init__(self, al: Aligned, sigma: dict | None = None):
        self.al = al
        self.outputs = al.outputs
        self.sigma = dict(sigma or al.noise_floor)
        n = al.n
        self.n = n
        self.slices = {k: slice(i * n, (i + 1) * n) for i, k in enumerate(self.outputs)}
        self.N = n * len(self.outputs)
        self.z0 = np.concatenate([(al.rec[k] - al.sim[k]) / self.sigma[k] for k in self.outputs])
        self.duration = float(al.t[-1] - al.t[0])
        self._dir = {}

    def vec(self, parts: dict) -> np.ndarray:
        """Stack per-output arrays (in output units) into a whitened vector."""
        v = np.zeros(self.N)
        for k, a in parts.items():
            v[self.slices[k]] = a / self.sigma[k]
        return v

    def direction(self, key: str) -> np.ndarray:
        if key not in self._dir:
            self._dir[key] = direction_of_motion(self.al.signals[key].values)
        return self._dir[key]


@dataclass
class Candidate:
    """One effect on given outputs driven by given inputs; subclasses define the model."""
    name: str
    outputs: tuple
    inputs: tuple
    n_lin: int = 0

    nl_names = ()  # names of the nonlinear parameters (class attribute, not a field)

    @property
    def label(self) -> str:
        return f"{self.name}[{','.join(self.outputs)}<-{','.join(self.inputs)}]"

    def n_params(self) -> int:
        return self.n_lin + len(self.nl_names)

    # -- to override --
    def bounds(self, ctx: Context):
        return [], []

    def columns(self, ctx: Context, eta) -> tuple[np.ndarray | None, np.ndarray]:
        raise NotImplementedError

    def coarse(self, ctx: Context, resid: np.ndarray, rows: np.ndarray):
        """Starting nonlinear parameters from a grid on the current residual."""
        return np.zeros(0)

    def physical(self, ctx: Context, eta, beta, cov_eta, cov_beta):
        raise NotImplementedError

    # -- helpers --
    def _grid_best(self, ctx, resid, rows, grid):
        best, best_rss = None, np.inf
        for g in grid:
            eta = np.array([g])
            fixed, B = self.columns(ctx, eta)
            y = resid[rows] - (fixed[rows] if fixed is not None else 0.0)
            if B.shape[1]:
                Br = B[rows]
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
        super().__init__("thermal_drift", (output,), (driver,), 1)
        self._cache = {}

    def bounds(self, ctx):
        lo = math.log(max(ctx.al.dt, 1e-3))
        hi = math.log(max(10 * ctx.duration, 10 * ctx.al.dt))
        return [lo], [hi]

    def columns(self, ctx, eta):
        key = round(float(eta[0]), 12)
        if key not in self._cache:
            if len(self._cache) > 64:
                self._cache.clear()
            u = ctx.al.signals[self.inputs[0]].values
            y = first_order(u, ctx.al.dt, math.exp(key)) - u[0]
            self._cache[key] = ctx.vec({self.outputs[0]: y})[:, None]
        return None, self._cache[key]

    def coarse(self, ctx, resid, rows):
        lo, hi = self.bounds(ctx)
        return self._grid_best(ctx, resid, rows, np.linspace(lo[0], hi[0], 24))

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        tau = math.exp(eta[0])
        sig = ctx.al.signals[self.inputs[0]]
        unit = sig.unit or "unit"
        return ({"gain_mm_per_" + unit.replace("/", "_"): float(beta[0]), "tau_s": tau},
                {"gain_mm_per_" + unit.replace("/", "_"): _se(cov_beta, 0),
                 "tau_s": tau * _se(cov_eta, 0)})


class Backlash(Candidate):
    def __init__(self, output):
        super().__init__("backlash", (output,), (output,), 1)
        self._col = None

    def columns(self, ctx, eta):
        if self._col is None:
            d = ctx.direction(self.outputs[0])
            self._col = ctx.vec({self.outputs[0]: -0.5 * d})[:, None]
        return None, self._col

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        u = ctx.al.units[self.outputs[0]]
        return {f"backlash_{u}": float(beta[0])}, {f"backlash_{u}": _se(cov_beta, 0)}


class ServoLag(Candidate):
    nl_names = ("log_kv",)

    def __init__(self, output):
        super().__init__("servo_lag", (output,), (output,), 0)
        self._cache = {}

    def bounds(self, ctx):
        return [math.log(max(0.5, 1.0 / ctx.duration))], [math.log(max(20.0 / ctx.al.dt, 1.0))]

    def columns(self, ctx, eta):
        key = round(float(eta[0]), 12)
        if key not in self._cache:
            if len(self._cache) > 64:
                self._cache.clear()
            p = ctx.al.signals[self.outputs[0]].values
            y = first_order(p, ctx.al.dt, math.exp(-key)) - p
            self._cache[key] = ctx.vec({self.outputs[0]: y})
        return self._cache[key], np.zeros((ctx.N, 0))

    def coarse(self, ctx, resid, rows):
        lo, hi = self.bounds(ctx)
        return self._grid_best(ctx, resid, rows, np.linspace(lo[0], hi[0], 32))

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        kv = math.exp(eta[0])
        return {"kv_per_s": kv}, {"kv_per_s": kv * _se(cov_eta, 0)}


class PeriodicPitch(Candidate):
    nl_names = ("log_lead",)

    def __init__(self, output):
        super().__init__("periodic_pitch_error", (output,), (output,), 2)

    def _range(self, ctx):
        p = ctx.al.signals[self.outputs[0]].values
        return float(np.ptp(p)), p

    def bounds(self, ctx):
        rng, p = self._range(ctx)
        step = np.median(np.abs(np.diff(p))[np.abs(np.diff(p)) > 0]) if np.any(np.diff(p)) else 1.0
        lo = max(0.2, 4 * step)
        hi = max(rng / 2.0, 1.01 * lo)
        return [math.log(lo)], [math.log(hi)]

    def columns(self, ctx, eta):
        p = ctx.al.signals[self.outputs[0]].values
        ph = 2 * np.pi * p / math.exp(eta[0])
        o = self.outputs[0]
        return None, np.column_stack([ctx.vec({o: np.sin(ph)}), ctx.vec({o: np.cos(ph)})])

    def coarse(self, ctx, resid, rows):
        # a periodogram of the residual binned by position: the screw error repeats in p, not t
        from scipy.signal import lombscargle
        lo, hi = self.bounds(ctx)
        rng, p = self._range(ctx)
        sl = ctx.slices[self.outputs[0]]
        rmask = rows[sl]
        pp, rr = p[rmask], resid[sl][rmask]
        nb = int(min(4000, max(16, len(pp) // 4)))
        edges = np.linspace(pp.min(), pp.max() + 1e-12, nb + 1)
        idx = np.clip(np.searchsorted(edges, pp, side="right") - 1, 0, nb - 1)
        cnt = np.bincount(idx, minlength=nb)
        ok = cnt > 0
        centres = 0.5 * (edges[:-1] + edges[1:])[ok]
        means = (np.bincount(idx, rr, minlength=nb)[ok]) / cnt[ok]
        means = means - means.mean()
        if len(centres) < 8:
            return np.array([0.5 * (lo[0] + hi[0])])
        fmin, fmax = math.exp(-hi[0]), math.exp(-lo[0])
        df = 1.0 / (8.0 * max(rng, 1e-9))
        nf = int(min(20000, max(64, (fmax - fmin) / df)))
        f = np.linspace(fmin, fmax, nf)
        pw = lombscargle(centres, means, 2 * np.pi * f, precenter=True)
        return np.array([-math.log(f[int(np.argmax(pw))])])

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        lead = math.exp(eta[0])
        a, b = float(beta[0]), float(beta[1])
        amp = math.hypot(a, b)
        u = ctx.al.units[self.outputs[0]]
        # amplitude error from the 2x2 covariance along the amplitude direction
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

    def columns(self, ctx, eta):
        o = self.outputs[0]
        return None, ctx.vec({o: ctx.al.signals[o].values})[:, None]

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        return {"scale": float(beta[0])}, {"scale": _se(cov_beta, 0)}


class Squareness(Candidate):
    def __init__(self, output, driver):
        super().__init__("squareness", (output,), (driver,), 1)

    def columns(self, ctx, eta):
        return None, ctx.vec({self.outputs[0]: ctx.al.signals[self.inputs[0]].values})[:, None]

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
        self._cols = None

    def _xi(self, ctx):
        p = ctx.al.signals[self.inputs[0]].values
        lo, hi = float(p.min()), float(p.max())
        return (2 * p - (lo + hi)) / max(hi - lo, 1e-12), lo, hi

    def columns(self, ctx, eta):
        if self._cols is None:
            xi, _, _ = self._xi(ctx)
            o = self.outputs[0]
            self._cols = np.column_stack([ctx.vec({o: c}) for c in legendre_cols(xi, self.ORDERS)])
        return None, self._cols

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
        self.comps = comps          # tool-edge offset components (0=x,1=y,2=z) in the plane
        self._cols = None
        self._lin = None

    def columns(self, ctx, eta):
        if self._cols is None:
            th = np.radians(ctx.al.signals[self.inputs[0]].values)
            R = rot(self.axis, th)
            cols = []
            for c in self.comps:
                col = R[:, :, c] - np.eye(3)[c]  # (R - I) e_c
                parts = {o: col[:, LIN_AXIS[ctx.al.signals[o].letter]] for o in self.outputs}
                cols.append(ctx.vec(parts))
            self._cols = np.column_stack(cols)
        return None, self._cols

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        names = [f"d{'xyz'[c]}_mm" for c in self.comps]
        return ({n: float(b) for n, b in zip(names, beta)},
                {n: _se(cov_beta, i) for i, n in enumerate(names)})


class WorkpieceSetting(Candidate):
    def __init__(self, outputs, with_rotation: bool):
        super().__init__("workpiece_setting", tuple(outputs), tuple(outputs), 0)
        self.with_rotation = with_rotation
        self._cols = None
        self._names = []

    def columns(self, ctx, eta):
        if self._cols is None:
            al = ctx.al
            lets = {al.signals[o].letter: o for o in self.outputs}
            n = al.n
            p = np.zeros((n, 3))
            for L, o in lets.items():
                p[:, LIN_AXIS[L]] = al.signals[o].values
            cols, names = [], []
            for L, o in sorted(lets.items()):
                cols.append(ctx.vec({o: -np.ones(n)}))
                names.append(f"t{L}_mm")
            if self.with_rotation:
                for ax in range(3):
                    w = np.zeros(3)
                    w[ax] = 1.0
                    r = -np.cross(w, p)  # -(w x p)
                    parts = {o: r[:, LIN_AXIS[L]] for L, o in lets.items()}
                    if all(np.ptp(v) == 0 and not v.any() for v in parts.values()):
                        continue
                    cols.append(ctx.vec(parts))
                    names.append(f"r{'xyz'[ax]}_deg")
            self._cols = np.column_stack(cols)
            self._names = names
            self.n_lin = len(names)
        return None, self._cols

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
        self._cache = {}

    def bounds(self, ctx):
        al = ctx.al
        w = max(10.0 * al.dt, 0.02 * abs(al.offset0))
        lo = (al.offset0 - w) / al.dt
        hi = (al.offset0 + w) / al.dt
        return [lo], [hi]

    def columns(self, ctx, eta):
        key = round(float(eta[0]), 10)
        if key not in self._cache:
            if len(self._cache) > 64:
                self._cache.clear()
            al = ctx.al
            tau = key * al.dt
            parts = {o: al.sim_spline[o](al.t - tau) - al.sim[o] for o in self.outputs}
            self._cache[key] = ctx.vec(parts)
        return self._cache[key], np.zeros((ctx.N, 0))

    def coarse(self, ctx, resid, rows):
        lo, hi = self.bounds(ctx)
        c = ctx.al.offset0 / ctx.al.dt
        grid = np.unique(np.clip(np.concatenate([[c], np.linspace(lo[0], hi[0], 21)]), lo[0], hi[0]))
        return self._grid_best(ctx, resid, rows, grid)

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        dt = ctx.al.dt
        return {"offset_s": float(eta[0]) * dt}, {"offset_s": _se(cov_eta, 0) * dt}


def candidates(ctx: Context) -> list[Candidate]:
    """Every effect the data could support, given the outputs' kinds and the available drivers."""
    al = ctx.al
    outs = [o for o in al.outputs if al.kinds[o] in ("length", "angle")]
    moving = {o for o in outs if np.ptp(al.sim[o]) > 0}
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
        if o in moving:
            out += [Backlash(o), ServoLag(o), ScaleError(o)]
            if al.kinds[o] == "length":
                out.append(PeriodicPitch(o))
        if al.kinds[o] == "length":
            for d in lin_drivers:
                if d == o or sig[d].letter == sig[o].letter:
                    continue
                out += [Squareness(o, d), Straightness(o, d)]
    lin_outs = {sig[o].letter: o for o in outs if al.kinds[o] == "length" and sig[o].letter in LIN_AXIS}
    for d in ang_drivers:
        ax = ROT_AXIS[sig[d].letter]
        plane = [c for c in range(3) if c != ax]
        affected = [lin_outs["xyz"[c]] for c in plane if "xyz"[c] in lin_outs]
        if affected:
            out.append(PivotOffset(affected, d, ax, tuple(plane)))
    if lin_outs:
        wo = [lin_outs[L] for L in sorted(lin_outs)]
        out.append(WorkpieceSetting(wo, False))
        if len(wo) >= 2:
            out.append(WorkpieceSetting(wo, True))
        for c in out[-2:]:
            if isinstance(c, WorkpieceSetting):
                c.columns(ctx, ())  # fixes n_lin: which rotations the outputs can see
    if moving:
        out.append(TimeOffset(tuple(o for o in al.outputs if o in moving)))
    return out
