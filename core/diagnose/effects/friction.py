"""Effects of contact and friction at reversals: backlash (a play operator), friction of a
velocity output, quadrant glitches and stick-slip."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .base import Candidate, _se, backlash_play, coarse_native, direction_of_motion, step_direction  # noqa: F401


class Backlash(Candidate):
    """Reversal error of an axis: a play (backlash) of width b, or with `sign` -1 the same
    error of the other sign, B = -b < 0 (ISO 230-2 reversal value B negative).

    A play lags the command by b/2 against the direction of motion and, after a reversal, stands
    still until the command has travelled b.  A negative width is the error that leads the
    command by |B|/2 in the direction of motion: the control's backlash compensation is larger
    than the play it compensates (over-compensated).  Modelled as the mirror image of the play
    (the error moves to its new side over a travel of |B|); from readings at rest and away from
    the reversals only the sign and the size of B matter.  Both signs are candidates; the
    selection keeps at most one per output.
    """
    nl_names = ("log_b",)

    def __init__(self, output, sign: int = 1):
        # one linear column: the state of the play before the axis first moves is unknown (a
        # machine switched on mid-gap); it is free until the first motion takes the play up
        super().__init__("backlash", (output,), (output,), 1)
        self.sign = 1 if sign >= 0 else -1

    @property
    def label(self) -> str:
        return super().label + ("(negative)" if self.sign < 0 else "")

    def implausible(self, ctx, eta, beta) -> str | None:
        """A negative width is taken only where it is identifiable: an error that leads the
        command in the direction of motion is, while the axis moves at one speed, also what a
        lead proportional to the speed gives (a time lead, a command held over a control
        cycle).  A reversal error stays when the axis rests; a lead vanishes.  So readings at
        rest after motion in both directions are needed (or a stop-and-measure run)."""
        if self.sign > 0 or ctx.al.at_rest:
            return None
        o = self.outputs[0]
        v = np.abs(np.gradient(ctx.values(o)))
        vmax = float(v.max()) if len(v) else 0.0
        rest = (v <= 1e-3 * vmax)[ctx.idx]
        d = ctx.direction(o)[ctx.idx]
        need = max(5, int(0.01 * len(ctx.idx)))
        n_pos, n_neg = int((rest & (d > 0)).sum()), int((rest & (d < 0)).sum())
        if min(n_pos, n_neg) < need:
            return (f"negative width not identifiable: {n_pos} and {n_neg} samples at rest after "
                    f"motion in + and - (at least {need} each are needed to tell a reversal error "
                    "from a lead proportional to the speed)")
        return None

    def meaning(self, params: dict) -> str | None:
        if self.sign > 0:
            return None
        return ("negative backlash: the reversal error leads the command (ISO 230-2 reversal "
                "value B negative), i.e. the control over-compensates the backlash by |B| more "
                "than the play it has")

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
            return {o: self.sign * backlash_play(ctx.values(o), b, ctx.direction(o))}, first
        # a grid coarser than SIM: the reversal positions come from SIM as sampled (on a 10 Hz
        # grid the sample before a reversal can be far from where the axis turned)
        if not hasattr(self, "_prev") and coarse_native(ctx.al, sig.native[0]):
            # SIM coarser than the grid: each step of SIM has its own direction; the axis
            # turned at the sample where the step's direction changed (a G1 corner)
            tn, vn = sig.native
            vn = np.asarray(vn, float)
            ds = step_direction(vn)
            ch = np.flatnonzero(ds[1:] != ds[:-1]) + 1      # first step of a new direction
            k = np.searchsorted(tn[ch], ctx.al.t, side="left") - 1 if len(ch) else np.full(ctx.al.n, -1)
            self._prev = (np.where(k >= 0, vn[ch[np.clip(k, 0, None)]] if len(ch) else 0.0, np.nan),
                          ctx.direction(o), float(ds[0]))
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
        return {o: self.sign * r}, first

    def coarse(self, ctx, resid, rows):
        # the linear (instant-reversal) approximation gives b directly
        o = self.outputs[0]
        ir = self._rows_for(ctx, rows)
        col = ctx.vec({o: -0.5 * ctx.direction(o)})[ir]
        den = float(col @ col)
        b = self.sign * float(col @ resid[ir]) / den if den > 0 else 0.0
        lo, hi = self.bounds(ctx)
        return np.array([float(np.clip(math.log(max(b, 1e-300)), lo[0], hi[0]))])

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        u = ctx.al.units[self.outputs[0]]
        b = math.exp(eta[0])
        return ({f"backlash_{u}": self.sign * b,
                 f"initial_state_{u}": float(beta[0]) if len(beta) else 0.0},
                {f"backlash_{u}": b * _se(cov_eta, 0), f"initial_state_{u}": _se(cov_beta, 0)})


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
            # k is nondecreasing in time: segment j is one slice of the grid (found once; a
            # mask per reversal and per evaluation was most of the cost of a long recording)
            j = np.arange(len(t_rev))
            self._prev = (k, D, len(t_rev), np.searchsorted(k, j, side="left"),
                          np.searchsorted(k, j, side="right"))
        return self._prev

    def bounds(self, ctx):
        span = float(np.ptp(ctx.al.sim[self.outputs[0]])) or 1.0
        return ([math.log(1e-5 * span), math.log(ctx.al.dt / 2)],
                [math.log(0.2 * span), math.log(max(1.0, 4 * ctx.al.dt))])

    def build(self, ctx, eta):
        k, D, nrev, lo, hi = self._segments(ctx)
        d = ctx.direction(self.outputs[0])
        delta, tau = math.exp(eta[0]), math.exp(eta[1])
        t = ctx.al.t
        shape = np.zeros_like(D)
        for j in range(nrev):
            a, e = int(lo[j]), int(hi[j])
            if e <= a:
                continue
            Ds = D[a:e]
            broken = np.flatnonzero(Ds >= delta)
            if not len(broken):
                shape[a:e] = Ds
                continue
            b = int(broken[0])
            shape[a:a + b] = Ds[:b]
            # the breakaway instant, between two samples: where D crosses delta
            tb = t[a + b]
            if b > 0 and Ds[b] > Ds[b - 1]:
                f = (delta - Ds[b - 1]) / (Ds[b] - Ds[b - 1])
                tb = t[a + b - 1] + f * (t[a + b] - t[a + b - 1])
            shape[a + b:e] = delta * np.exp(-np.minimum((t[a + b:e] - tb) / tau, 700.0))
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


def loop_shape(ctx, o: str, resid: np.ndarray, floor: float, bins: int = 8) -> dict | None:
    """Does the reversal error of output `o` follow a play (a step within the play's travel,
    flat after it)?  The residual left after a backlash is fitted, signed by the direction of
    motion, is averaged in bins of the travel since the last reversal (quantiles, moving
    samples only).  A play leaves no trend; a gradual hysteresis loop (friction pre-sliding,
    Preisach-type) leaves one sign just after each reversal and the other later.  Returns
    {"share": variance share of the bin means (noise share removed), "swing": largest minus
    smallest bin mean (output unit), "significant": bool} or None when there are too few
    reversals."""
    al = ctx.al
    p = al.sim[o][ctx.idx]
    d = ctx.direction(o)[ctx.idx]
    ch = np.flatnonzero(d[1:] != d[:-1]) + 1
    if len(ch) < 4:
        return None
    k = np.searchsorted(ch, np.arange(len(p)), side="right") - 1
    ok = k >= 0
    p_rev = np.where(ok, p[ch[np.clip(k, 0, None)] - 1], np.nan)
    travel = np.abs(p - p_rev)
    v = np.abs(np.gradient(p))
    moving = ok & (v > 1e-3 * max(float(v.max()), 1e-300)) & np.isfinite(travel)
    if moving.sum() < 4 * bins:
        return None
    x, r = travel[moving], (resid * d)[moving]
    edges = np.quantile(x, np.linspace(0, 1, bins + 1))
    b = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, bins - 1)
    n = np.bincount(b, minlength=bins)
    m = np.bincount(b, weights=r, minlength=bins) / np.maximum(n, 1)
    r0 = r - r.mean()
    tot = float(r0 @ r0)
    if tot <= 0:
        return None
    share = float(np.sum(n * (m - r.mean()) ** 2)) / tot
    share = max(0.0, (share - bins / len(r)) / (1.0 - bins / len(r)))
    swing = float(m[n > 0].max() - m[n > 0].min())
    se = floor / math.sqrt(max(int(n[n > 0].min()), 1))
    return {"share": share, "swing": swing, "significant": bool(share > 0.2 and swing > 6 * se
                                                              and swing > 3 * floor)}
