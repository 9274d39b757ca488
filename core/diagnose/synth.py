"""Synthetic SIM/REC pairs with concealed effects, for tests, the benchmark suite and demos.

The machine moves along random point-to-point moves with trapezoidal velocity (evaluated
analytically at any time, so SIM and REC sample the same motion at their own rates) and dwells.
SIM is the ideal motion; REC is the motion with the chosen effects added, evaluated on REC's own
clock, plus white noise, optionally quantised and in um.  Effects are computed independently of
the diagnosis code where it matters (servo lag and thermal responses on a 10x finer grid).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

RANGES = {"x": (0.0, 100.0), "y": (0.0, 80.0), "z": (-30.0, 10.0), "b": (-40.0, 40.0)}


@dataclass(frozen=True)
class Case:
    """A generated pair: arrays keyed by CSV header (units in brackets where not default)."""
    sim: dict
    rec: dict
    truth: tuple            # ((name, outputs, params), ...)
    noise: float            # mm
    info: dict = field(default_factory=dict)


class Trajectory:
    """Piecewise trapezoidal point-to-point motion of one axis with dwells."""

    def __init__(self, rng, lo, hi, t_end, vmax, acc, dwell=(0.2, 2.0)):
        self.seg = []  # (t0, p0, p1, v, a, t_acc, t_total)
        t, p = 0.0, rng.uniform(lo, hi)
        self.p_start = p
        while t < t_end:
            t += rng.uniform(*dwell)
            p1 = rng.uniform(lo, hi)
            d = abs(p1 - p)
            v = rng.uniform(0.2, 1.0) * vmax
            ta = v / acc
            if acc * ta * ta > d:  # triangle profile
                ta = math.sqrt(d / acc)
                v = acc * ta
                T = 2 * ta
            else:
                T = 2 * ta + (d - acc * ta * ta) / v
            self.seg.append((t, p, p1, v, acc, ta, T))
            t += T
            p = p1
        self.t0 = np.array([s[0] for s in self.seg])

    def __call__(self, t, deriv=0):
        t = np.asarray(t, float)
        out = np.empty_like(t)
        i = np.searchsorted(self.t0, t, side="right") - 1
        before = i < 0
        ic = np.clip(i, 0, len(self.seg) - 1)
        S = np.array(self.seg)
        t0, p0, p1, v, a, ta, T = (S[ic, k] for k in range(7))
        sgn = np.sign(p1 - p0)
        tau = np.clip(t - t0, 0, T)
        d_acc = 0.5 * a * ta ** 2
        if deriv == 0:
            s = np.where(tau < ta, 0.5 * a * tau ** 2,
                         np.where(tau < T - ta, d_acc + v * (tau - ta),
                                  np.abs(p1 - p0) - 0.5 * a * (T - tau) ** 2))
            out = p0 + sgn * s
            out[before] = self.p_start
        else:
            s = np.where(tau < ta, a * tau, np.where(tau < T - ta, v, a * (T - tau)))
            s = np.where((t - t0) > T, 0.0, s)
            out = sgn * s
            out[before] = 0.0
        return out


def _first_order(u, dt, tau):
    """Reference first-order lag on a fine grid by the trapezoidal (bilinear) rule: second-order
    accurate and independent of the diagnosis' ramp-invariant filter."""
    from scipy.signal import lfilter
    x = dt / tau
    b = [x / (2 + x), x / (2 + x)]
    a = [1.0, -(2 - x) / (2 + x)]
    y, _ = lfilter(b, a, u, zi=[u[0] * (1 - b[0])])
    return y


def _play(p, b, first_dir):
    """Output of a play operator of width b (sequential reference implementation)."""
    h = 0.5 * b
    y = np.empty_like(p)
    cur = p[0] - first_dir * h
    for k, pk in enumerate(p.tolist()):
        cur = min(max(cur, pk - h), pk + h)
        y[k] = cur
    return y


def _smooth_walk(rng, t, amp, n_terms=4):
    out = np.zeros_like(t)
    D = t[-1] - t[0]
    for _ in range(n_terms):
        per = rng.uniform(0.5, 3.0) * D
        out += rng.normal() * np.sin(2 * np.pi * (t - t[0]) / per + rng.uniform(0, 2 * np.pi))
    out = out - out[0]
    s = np.max(np.abs(out)) or 1.0
    return amp * out / s


def sample_params(name: str, rng) -> dict:
    """Random parameters of an effect in plausible ranges (mm, s, deg) for the suite."""
    u = rng.uniform
    sgn = lambda: rng.choice([-1.0, 1.0])  # noqa: E731
    if name == "thermal_drift":
        return {"driver": rng.choice(["s", "t_spindle"]), "amp_mm": sgn() * u(1e-3, 5e-3),
                "tau_frac": u(0.1, 0.5)}
    if name == "backlash":
        return {"backlash_mm": u(1e-3, 8e-3)}
    if name == "servo_lag":
        return {"kv_per_s": u(20.0, 100.0)}
    if name == "periodic_pitch_error":
        return {"lead_mm": u(2.0, 20.0), "amplitude_mm": u(0.3e-3, 2e-3), "phase_deg": u(-180, 180)}
    if name == "scale_error":
        return {"scale": sgn() * u(10e-6, 50e-6)}
    if name == "squareness":
        return {"angle_deg": math.degrees(sgn() * u(10e-6, 60e-6))}
    if name == "straightness":
        return {"P2_mm": sgn() * u(0.5e-3, 2e-3), "P3_mm": rng.normal() * 0.5e-3}
    if name == "pivot_offset":
        return {"dx_mm": sgn() * u(3e-3, 30e-3), "dz_mm": sgn() * u(3e-3, 30e-3)}
    if name == "workpiece_setting":
        return {"tx_mm": sgn() * u(2e-3, 20e-3), "ty_mm": sgn() * u(2e-3, 20e-3),
                "tz_mm": sgn() * u(2e-3, 20e-3), "rz_deg": math.degrees(sgn() * u(20e-6, 100e-6))}
    if name == "time_offset":
        return {"offset_s": sgn() * u(2e-3, 20e-3)}
    raise ValueError(name)


# which output each effect acts on in the generated cases (the others' drivers in brackets)
TARGET = {"thermal_drift": "z", "backlash": "x", "servo_lag": "y", "periodic_pitch_error": "x",
          "scale_error": "y", "squareness": "y", "straightness": "y", "pivot_offset": "x,z",
          "workpiece_setting": "x,y,z", "time_offset": "x,y,z"}


def make_case(effects=(), seed: int = 0, duration: float = 60.0, sim_rate: float = 200.0,
              rec_rate: float = 500.0, noise: float = 20e-6, rec_start: float = -0.5,
              rec_end: float | None = None, n_temps: int = 3, n_junk: int = 2,
              um_headers: bool = False, quantum: float = 0.0, rotary: bool | None = None) -> Case:
    """Generate one SIM/REC pair; `effects` is a sequence of (name, params) or names."""
    rng = np.random.default_rng(seed)
    eff = []
    for e in effects:
        if isinstance(e, str):
            eff.append((e, sample_params(e, rng)))
        else:
            eff.append((e[0], dict(e[1])))
    names = [e[0] for e in eff]
    if rotary is None:
        rotary = "pivot_offset" in names
    axes = {k: Trajectory(rng, *RANGES[k], duration, vmax=20.0, acc=200.0) for k in "xyz"}
    if rotary:
        axes["b"] = Trajectory(rng, *RANGES["b"], duration, vmax=30.0, acc=300.0)
    # the spindle runs in a few blocks: a thermal load that does not follow the moves
    s_knots = np.sort(rng.uniform(0.05, 0.9, 3)) * duration
    s_levels = rng.choice([0.0, 8000.0, 12000.0, 20000.0], size=4)
    s_levels[0] = 0.0
    s_levels[1] = rng.choice([8000.0, 12000.0, 20000.0])

    def spindle(t):
        return s_levels[np.searchsorted(s_knots, t, side="right")]

    # fine time base for the dynamic effects (covers REC's span and the offsets)
    rec_end = duration + 0.3 if rec_end is None else rec_end
    tf0, tf1 = min(0.0, rec_start) - 1.0, max(duration, rec_end) + 1.0
    dtf = min(1.0 / sim_rate, 1.0 / rec_rate) / 10.0
    tf = np.arange(tf0, tf1, dtf)
    temps_f = {f"t_{nm}": 20.0 + _smooth_walk(rng, tf, rng.uniform(0.2, 1.0))
               for nm in ["spindle", "bed", "room", "coolant", "cabinet"][:max(n_temps, 1)]}
    # the spindle temperature follows the spindle speed (as it would) plus the room
    sp_f = spindle(tf)
    temps_f["t_spindle"] = (20.0 + 0.3 * _smooth_walk(rng, tf, 1.0)
                            + 2.0 * _first_order(sp_f / 20000.0, dtf, 0.3 * duration))

    t_sim = np.arange(0.0, duration, 1.0 / sim_rate)
    t_rec = np.arange(rec_start, rec_end, 1.0 / rec_rate)
    offset = sum(p.get("offset_s", 0.0) for n, p in eff if n == "time_offset")
    tp = t_rec - offset  # physical time of each REC sample
    true = {k: tr(tp) for k, tr in axes.items()}
    err = {k: np.zeros_like(t_rec) for k in "xyz"}
    truth = []
    for name, p in eff:
        if name == "thermal_drift":
            drv = p["driver"]
            u_f = sp_f if drv == "s" else temps_f[drv]
            tau = p["tau_frac"] * duration
            y = _first_order(u_f, dtf, tau) - u_f[0]
            rng_y = np.max(np.abs(y)) or 1.0
            gain = p["amp_mm"] / rng_y
            err["z"] += gain * np.interp(tp, tf, y)
            unit = "rpm" if drv == "s" else "degC"
            truth.append((name, ("z",), {f"gain_mm_per_{unit}": gain, "tau_s": tau, "driver": drv}))
        elif name == "backlash":
            # play operator stepped sample by sample (rate independent, and exact here because
            # every reversal happens at rest)
            seg0 = axes["x"].seg[0]
            err["x"] += _play(true["x"], p["backlash_mm"], np.sign(seg0[2] - seg0[1])) - true["x"]
            truth.append((name, ("x",), dict(p)))
        elif name == "servo_lag":
            pf = axes["y"](tf)
            lag = _first_order(pf, dtf, 1.0 / p["kv_per_s"]) - pf
            err["y"] += np.interp(tp, tf, lag)
            truth.append((name, ("y",), dict(p)))
        elif name == "periodic_pitch_error":
            a, b = (p["amplitude_mm"] * math.cos(math.radians(p["phase_deg"])),
                    p["amplitude_mm"] * math.sin(math.radians(p["phase_deg"])))
            ph = 2 * np.pi * true["x"] / p["lead_mm"]
            err["x"] += a * np.sin(ph) + b * np.cos(ph)
            truth.append((name, ("x",), dict(p)))
        elif name == "scale_error":
            err["y"] += p["scale"] * true["y"]
            truth.append((name, ("y",), dict(p)))
        elif name == "squareness":
            err["y"] += math.radians(p["angle_deg"]) * true["x"]
            truth.append((name, ("y",), dict(p)))
        elif name == "straightness":
            lo, hi = RANGES["x"]
            xi = (2 * true["x"] - (lo + hi)) / (hi - lo)
            from numpy.polynomial import legendre
            err["y"] += legendre.legval(xi, [0, 0, p["P2_mm"], p["P3_mm"]])
            truth.append((name, ("y",), dict(p)))
        elif name == "pivot_offset":
            th = np.radians(true["b"])
            dx, dz = p["dx_mm"], p["dz_mm"]
            # R_y(th) (dx, 0, dz) - (dx, 0, dz)
            err["x"] += (np.cos(th) - 1) * dx + np.sin(th) * dz
            err["z"] += -np.sin(th) * dx + (np.cos(th) - 1) * dz
            truth.append((name, ("x", "z"), dict(p)))
        elif name == "workpiece_setting":
            w = np.array([0.0, 0.0, math.radians(p.get("rz_deg", 0.0))])
            P = np.column_stack([true["x"], true["y"], true["z"]])
            r = -(np.array([p.get("tx_mm", 0.0), p.get("ty_mm", 0.0), p.get("tz_mm", 0.0)])
                  + np.cross(w, P))
            for i, k in enumerate("xyz"):
                err[k] += r[:, i]
            truth.append((name, ("x", "y", "z"), dict(p)))
        elif name == "time_offset":
            truth.append((name, ("x", "y", "z"), dict(p)))
        else:
            raise ValueError(f"unknown effect {name!r}")

    sim = {"t": t_sim}
    for k in "xyz":
        sim[k] = axes[k](t_sim)
    if rotary:
        sim["b"] = axes["b"](t_sim)  # commanded angle: an input (REC does not log it)
    sim["s[rpm]"] = spindle(t_sim)
    sim["feed_override[%]"] = np.full_like(t_sim, 100.0)
    rec = {"t": t_rec}
    for k in "xyz":
        v = true[k] + err[k] + rng.normal(0, noise, len(t_rec))
        if quantum:
            v = np.round(v / quantum) * quantum
        if um_headers and k == "z":
            rec["z[um]"] = v * 1e3
        else:
            rec[k] = v
    for nm, Tf in temps_f.items():
        rec[f"{nm}[degC]"] = np.round(np.interp(tp, tf, Tf), 3)
    for j in range(n_junk):
        rec[f"aux{j}"] = np.round(rng.normal(0, 1, len(t_rec)).cumsum() * 0.01 + 5, 4)
    return Case(sim, rec, tuple(truth), noise,
                {"duration": duration, "sim_rate": sim_rate, "rec_rate": rec_rate})


def write_csv(path, columns: dict) -> None:
    """Write a mapping header -> array as CSV (full precision, atomically)."""
    from .._io import atomic_write
    keys = list(columns)
    arr = np.column_stack([np.asarray(columns[k], float) for k in keys])
    lines = [",".join(keys)]
    lines += [",".join(f"{v:.10g}" for v in row) for row in arr]
    atomic_write(path, "\n".join(lines) + "\n")


def polyline_axes(rng, duration: float, corner_dt: float | None = None, vmax: float = 20.0,
                  axes: str = "xyz"):
    """Piecewise-linear motion (G1 moves, corners with a velocity jump) of each axis: a function
    t -> {axis: position, mm}.  Corners fall at multiples of `corner_dt` s when given (a SIM
    that samples its program at those instants holds every corner), else at random times."""
    knots = {}
    for k in axes:
        lo, hi = RANGES[k]
        t, tk = 0.0, [0.0]
        while t < duration + 2.0:
            t += rng.uniform(0.4, 2.5)
            if corner_dt:
                t = round(t / corner_dt) * corner_dt
            tk.append(t)
        tk = np.array(tk)
        pk = np.empty(len(tk))
        pk[0] = rng.uniform(lo, hi)
        for i in range(1, len(tk)):
            # speed at most vmax, sometimes a dwell (same position), inside the range
            step = rng.uniform(-1, 1) * vmax * (tk[i] - tk[i - 1]) * (rng.uniform() > 0.2)
            pk[i] = np.clip(pk[i - 1] + step, lo, hi)
        knots[k] = (tk, pk)
    return lambda t: {k: np.interp(t, *knots[k]) for k in axes}


NULL_KINDS = ("white", "random_walk", "coarse_kinked", "separate_clocks")


def null_case(kind: str, seed: int = 0, duration: float = 20.0) -> Case:
    """A pair whose honest diagnosis names no effect of the machine.

    white: REC = SIM + white noise; random_walk: the same beside 20 random-walk inputs;
    coarse_kinked: piecewise-linear moves whose corners fall between SIM's 10 Hz samples, REC
    at 25 Hz (the mismatch is resampling, not physics); separate_clocks: REC on its own clock,
    started 0.59 ms .. 40 ms off SIM's (a clock offset, not a lag)."""
    rng = np.random.default_rng(10_000 + seed)
    if kind == "white":
        return make_case((), seed=seed, duration=duration, sim_rate=200.0, rec_rate=500.0)
    if kind == "random_walk":
        return make_case((), seed=seed, duration=duration, sim_rate=200.0, rec_rate=500.0,
                         n_junk=20)
    if kind == "separate_clocks":
        off = float(rng.choice([5.9e-4, 2e-3, 1.3e-2, 4e-2]))
        return make_case([("time_offset", {"offset_s": off})], seed=seed, duration=duration,
                         sim_rate=200.0, rec_rate=500.0)
    if kind == "coarse_kinked":
        path = polyline_axes(rng, duration)
        t_sim = np.arange(0.0, duration, 0.1)
        t_rec = np.arange(0.0, duration, 0.04)
        sim = {"t": t_sim, **path(t_sim)}
        p = path(t_rec)
        rec = {"t": t_rec, **{k: v + rng.normal(0, 20e-6, len(t_rec)) for k, v in p.items()}}
        return Case(sim, rec, (), 20e-6, {"duration": duration, "sim_rate": 10.0, "rec_rate": 25.0})
    raise ValueError(f"unknown null case {kind!r} (expected one of {', '.join(NULL_KINDS)})")


def polyline_case(effect: tuple | None = None, seed: int = 0, duration: float = 40.0,
                  sim_rate: float = 10.0, rec_rate: float = 25.0, noise: float = 20e-6,
                  corner_dt: float | None = 0.1) -> Case:
    """G1 moves (piecewise linear, corners at multiples of `corner_dt`) simulated at `sim_rate`
    and recorded at `rec_rate` with one effect (name, params): backlash on x, servo_lag on y
    (first-order lag on a 100x finer grid), scale_error on y; or none."""
    rng = np.random.default_rng(20_000 + seed)
    path = polyline_axes(rng, duration, corner_dt)
    t_sim = np.arange(0.0, duration, 1.0 / sim_rate)
    t_rec = np.arange(0.0, duration, 1.0 / rec_rate)
    dtf = 1.0 / rec_rate / 100.0
    tf = np.arange(-2.0, duration + 1.0, dtf)
    pf = path(tf)
    errf = {k: np.zeros_like(tf) for k in "xyz"}
    truth = ()
    if effect is not None:
        name, p = effect
        if name == "backlash":
            first = np.sign(pf["x"][np.flatnonzero(np.diff(pf["x"]))[0] + 1] - pf["x"][0]) or 1.0
            errf["x"] = _play(pf["x"], p["backlash_mm"], first) - pf["x"]
        elif name == "servo_lag":
            errf["y"] = _first_order(pf["y"], dtf, 1.0 / p["kv_per_s"]) - pf["y"]
        elif name == "scale_error":
            errf["y"] = p["scale"] * pf["y"]
        else:
            raise ValueError(f"polyline_case: no effect {name!r}")
        truth = ((name, ("x",) if name == "backlash" else ("y",), dict(p)),)
    sim = {"t": t_sim, **path(t_sim)}
    rec = {"t": t_rec}
    for k in "xyz":
        rec[k] = (np.interp(t_rec, tf, pf[k] + errf[k]) + rng.normal(0, noise, len(t_rec)))
    return Case(sim, rec, truth, noise, {"duration": duration, "sim_rate": sim_rate,
                                          "rec_rate": rec_rate})
