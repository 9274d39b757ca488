"""Dynamic effects: a driver filtered in time (thermal drift), first-order servo lags in their
forms, and the transport delay common to every output (time offset)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .base import Candidate, _se, first_order, first_order_strided  # noqa: F401


def _stride(ctx) -> int:
    """s when ctx's rows are every s-th grid sample from the first (a selection context on a
    recording without gaps), else 1."""
    s = getattr(ctx, "_stride", None)
    if s is None:
        idx, n = ctx.idx, ctx.al.n
        s = 1
        if not ctx.full and len(idx) > 1 and idx[0] == 0:
            k = int(idx[1] - idx[0])
            if k > 1 and len(idx) == len(range(0, n, k)) and np.all(np.diff(idx) == k):
                s = k
        ctx._stride = s
    return s


# responses of drivers to first-order lags, for the alignment being diagnosed (one at a time)
_RESPONSES = {"al": None, "d": {}}

# the slowest position-loop gain named a servo lag, 1/s (time constant 0.5 s)
KV_MIN = 2.0


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
        # the driver's response does not depend on the output: computed once per driver and
        # time constant for all outputs (most of the cost of a recording with many inputs)
        if _RESPONSES["al"] is not ctx.al:  # the response is on the full grid: one per alignment
            _RESPONSES["al"], _RESPONSES["d"] = ctx.al, {}
        cache = _RESPONSES["d"]
        s = _stride(ctx)
        key = (self.inputs[0], float(eta[0]), s)
        hit = cache.get(key)
        if hit is None:
            if len(cache) > 48:  # 2 arrays per entry of the full grid
                cache.clear()
            hit = cache[key] = self._response(ctx, math.exp(eta[0]), s)
        y, tr = hit
        if s > 1 and len(y) != ctx.n:  # a sparse driver: filtered on the full grid
            y, tr = y[ctx.idx], tr[ctx.idx]
        o = self.outputs[0]
        return None, [{o: y}, {o: tr}, {o: np.ones_like(y)}]

    def _response(self, ctx, tau, s=1):
        """(response, initial transient) on the full grid, or with s > 1 on every s-th grid
        sample (a selection context on a uniform stride; the driver still enters at every
        grid sample, exactly)."""
        al = ctx.al
        sig = al.signals[self.inputs[0]]
        u = sig.values
        tn, vn = sig.native if sig.native else (al.t, u)
        dt_native = float(np.median(np.diff(tn)))
        # (a driver sampled at the grid's own rate gives a ratio of 1 + rounding: m = 1)
        m = int(np.clip(math.ceil(al.dt / dt_native - 1e-6), 1, max(1, 200_000 // al.n)))
        if s > 1 and m == 1:
            # most of the cost of a long recording with many inputs: the filter of every
            # driver at every trial time constant
            y = first_order_strided(u, al.dt, tau, s) - u[0]
            return y, np.exp(-(al.t[::s] - al.t[0]) / tau)
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
        return y, tr

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
        # a position loop slower than kv = 2 1/s (a time constant over 0.5 s) is no servo lag of
        # a machine axis, a stage or a joint (they run at 5-200 1/s): such a fit is a slow drift
        # or another effect in the lag's clothes, and at this bound it is not named
        return [math.log(max(KV_MIN, 1.0 / ctx.duration))], [math.log(hi)]

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
        # SIM on the fine grid depends on (m, warm) only, not on tau itself: evaluated once
        # for the many time constants a fit tries
        key = (id(al), m, warm)
        pf = self._fine.get(key) if hasattr(self, "_fine") else None
        if pf is None:
            k = np.arange(-warm, (al.n - 1) * m + 1)
            tf = al.t[0] + (al.t[-1] - al.t[0]) * k / ((al.n - 1) * m)
            pf = al.sim_spline[o](tf)
            self._fine = {key: pf}  # one entry: a long recording's fine grid is large
        y = first_order(pf, h, tau)[warm::m] - al.sim[o]
        return {o: y}, []

    def coarse(self, ctx, resid, rows):
        lo, hi = self.bounds(ctx)
        return self._grid_best(ctx, resid, rows, np.linspace(lo[0], hi[0], 24))

    def implausible(self, ctx, eta, beta):
        # a gain at the slowest end of its range is not a measured gain: the fit ran into the
        # bound (a time constant of seconds, as long as the recording allows), i.e. the data
        # do not identify a lag; seen on a 10 Hz acceleration output, where the filter only
        # smooths noise away
        lo, hi = self.bounds(ctx)
        e, edge = float(eta[0]), 0.02 * (hi[0] - lo[0])
        if e <= lo[0] + edge:
            return (f"time constant {math.exp(-e):.3g} s at the longest the data "
                    "allow (the bound of the fit): not identified")
        if type(self) is ServoLag and e >= hi[0] - edge:
            # the shortest lag this form may take is the one a delay cannot mimic (bounds)
            return (f"time constant {math.exp(-e) * 1e3:.3g} ms at the shortest the sampling "
                    "tells from a delay (the bound of the fit): not identified")
        return None

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        kv = math.exp(eta[0])
        s = _se(cov_eta, 0)
        # the time constant beside the gain, as every form of the lag reports it
        return {"kv_per_s": kv, "tau_s": 1.0 / kv}, {"kv_per_s": kv * s, "tau_s": s / kv}


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

    def implausible(self, ctx, eta, beta):
        # the filtered form's bound (KV_MIN), for the linear form's free time constant
        tau = float(beta[0]) if len(beta) else 0.0
        if tau > 1.0 / KV_MIN:
            return (f"time constant {tau:.3g} s, longer than any servo loop's "
                    f"({1.0 / KV_MIN:g} s): not a servo lag")
        return None

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


def sim_derivative(ctx, o: str, order: int) -> np.ndarray:
    """The `order`-th time derivative of SIM's output `o` at the grid times (full grid), by
    central differences of SIM's interpolant over half of SIM's own sample step (the
    interpolant's derivative at SIM's rate, not the grid's: a coarse grid must not smooth it)."""
    al = ctx.al
    h = 0.5 / max(al.rates["sim"], 1e-9)
    f, t = al.sim_spline[o], al.t
    if order == 1:
        return (f(t + h) - f(t - h)) / (2 * h)
    if order == 2:
        return (f(t + h) - 2 * f(t) + f(t - h)) / (h * h)
    raise ValueError(order)


class ServoLagRate(ServoLagDerivative):
    """Servo lag of a position or angle in its steady-state form: the following error of a
    position loop of gain kv is -v/kv, r = -tau v (tau = 1/kv, linear), v SIM's velocity.

    The first-order term of the filtered form F_tau[p] - p.  Beside it because a loop whose
    dynamics are not exactly first order (velocity feed-forward, a second-order drive, a
    controller that reports x - tau v) still has a following error proportional to velocity,
    and the filtered form would leave its own tau^2 a on such a signal for other effects to
    take up."""

    def __init__(self, output):
        Candidate.__init__(self, "servo_lag", (output,), (output,), 1)

    def build(self, ctx, eta):
        o = self.outputs[0]
        return None, [{o: -sim_derivative(ctx, o, 1)}]

    def implausible(self, ctx, eta, beta):
        # as for the filtered form: a lag shorter than half of the finer file's sample step
        # cannot be told from a pure delay (a clock offset left over), and a negative one is a
        # lead, not a lag
        tau = float(beta[0]) if len(beta) else 0.0
        short = 0.5 / max(ctx.al.rates["sim"], ctx.al.rates["rec"])
        if tau < short:
            return (f"time constant {tau * 1e3:.3g} ms below half the finer sample step "
                    f"({short * 1e3:.3g} ms): not told from a delay")
        return None
