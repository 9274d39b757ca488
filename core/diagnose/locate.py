"""Find where and when the residual REC - SIM stands out of the noise, and say it in words.

A sample is flagged when the running mean square of the residual over a window of w samples
exceeds the noise variance by more than five of its standard errors (sigma^2 * sqrt(2/w)), or
when the running mean exceeds five standard errors of a mean (sigma/sqrt(w)).  Flagged samples
closer than a window are merged into spans; each span is described by the operating conditions
that distinguish it from the rest of the recording: motion (which axes move, direction, speed,
dwell), positions and angles, and temperatures or spindle speed.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .align import Aligned


@dataclass(frozen=True)
class Mismatch:
    output: str
    t_start: float
    t_end: float
    where: str
    rms: float            # RMS of the residual in the span, output unit

    def to_dict(self) -> dict:
        return {"output": self.output, "t_start": round(self.t_start, 6),
                "t_end": round(self.t_end, 6), "where": self.where, "rms": self.rms}


def _running_mean(x: np.ndarray, w: int) -> np.ndarray:
    c = np.concatenate([[0.0], np.cumsum(x)])
    n = len(x)
    i = np.arange(n)
    lo = np.clip(i - w // 2, 0, n)
    hi = np.clip(lo + w, 0, n)
    lo = np.clip(hi - w, 0, n)
    return (c[hi] - c[lo]) / (hi - lo)


def flagged(r: np.ndarray, sigma: float, w: int) -> np.ndarray:
    ms = _running_mean(r * r, w)
    mu = _running_mean(r, w)
    return (ms > sigma ** 2 * (1 + 5 * np.sqrt(2.0 / w))) | (np.abs(mu) > 5 * sigma / np.sqrt(w))


def spans(mask: np.ndarray, w: int) -> list[tuple[int, int]]:
    """Runs of True (end exclusive), gaps shorter than w merged, runs shorter than w/2 dropped."""
    idx = np.flatnonzero(mask)
    if not len(idx):
        return []
    breaks = np.flatnonzero(np.diff(idx) > w)
    starts = np.concatenate([[idx[0]], idx[breaks + 1]])
    ends = np.concatenate([idx[breaks], [idx[-1]]]) + 1
    return [(int(a), int(b)) for a, b in zip(starts, ends) if b - a >= max(w // 2, 1)]


def _fmt(v: float, unit: str) -> str:
    if unit == "mm" and abs(v) < 0.1:
        return f"{v * 1e3:.3g} µm"
    if unit == "mm/s" and abs(v) < 0.1:
        return f"{v * 1e3:.3g} µm/s"
    return f"{v:.4g} {unit}".strip()


def _num(v: float, scale: float) -> str:
    """A value for words: exactly 0 when it is below 1e-9 of the signal's scale (round-off)."""
    if abs(v) <= 1e-9 * scale:
        v = 0.0
    return f"{v:.4g}"


def describe(al: Aligned, a: int, b: int) -> str:
    """Words for the operating conditions of samples a:b against the whole recording."""
    parts = [f"t {al.t[a]:.3f}-{al.t[b - 1]:.3f} s"]
    moving, still = [], []
    seen = set()
    for k, s in al.signals.items():
        if s.kind not in ("length", "angle") or np.ptp(s.values) == 0:
            continue
        # one description per axis: an output `x` and an input `x_cmd` are the same motion
        if s.letter is not None:
            if s.letter in seen:
                continue
            seen.add(s.letter)
        v = np.gradient(s.values, al.dt)
        vs = v[a:b]
        thr = 1e-3 * np.max(np.abs(v))
        mv = np.abs(vs) > thr
        frac = float(np.mean(mv))
        unit = s.unit or ""
        if frac > 0.5:
            pos, neg = np.mean(vs[mv] > 0), np.mean(vs[mv] < 0)
            dirn = "+" if pos > 0.8 else ("-" if neg > 0.8 else "+/-")
            speed = float(np.median(np.abs(vs[mv])))
            moving.append(f"{k} moving {dirn} at {speed:.3g} {unit}/s")
        elif frac < 0.1:
            still.append(k)
        seg = s.values[a:b]
        full = np.ptp(s.values)
        if np.ptp(seg) < 0.5 * full:
            sc = float(np.max(np.abs(s.values)))
            parts.append(f"{k} in {_num(seg.min(), sc)}..{_num(seg.max(), sc)} {unit}".rstrip())
    if moving:
        parts.insert(1, ", ".join(moving))
    if still:
        parts.insert(1 + bool(moving), ("dwell of " if not moving else "") + "/".join(still) + " at rest")
    for k, s in al.signals.items():
        if s.kind not in ("temperature", "speed") or np.ptp(s.values) == 0:
            continue
        seg = s.values[a:b]
        q25, q75 = np.percentile(s.values, [25, 75])
        m = float(np.mean(seg))
        level = "high" if m > q75 else ("low" if m < q25 else None)
        if level:
            sc = float(np.max(np.abs(s.values)))
            parts.append(f"{k} {level} ({_num(seg.min(), sc)}..{_num(seg.max(), sc)} {s.unit})".replace(" )", ")"))
    return "; ".join(parts)


def locate(al: Aligned, max_spans: int = 8, resid: dict | None = None,
           only=None) -> list[Mismatch]:
    """Spans per output where the residual (default REC - SIM) stands out of the noise floor,
    largest first."""
    n = al.n
    w = int(np.clip(n // 200, 5, 400))
    out = []
    for o in (only or al.outputs):
        r = resid[o] if resid and o in resid else al.rec[o] - al.sim[o]
        sig = al.noise_floor[o]
        found = []
        for a, b in spans(flagged(r, sig, w), w):
            rms = float(np.sqrt(np.mean(r[a:b] ** 2)))
            found.append(Mismatch(o, float(al.t[a]), float(al.t[b - 1]), describe(al, a, b), rms))
        found.sort(key=lambda m: -m.rms * np.sqrt(m.t_end - m.t_start + al.dt))
        out += found[:max_spans]
    return out


def conditions(al: Aligned, o: str, r: np.ndarray, sigma: float) -> list[str]:
    """Operating conditions the residual of output o depends on, in words (global view).

    The mean residual while o's own axis moves +, moves - and rests (reported when the groups
    differ by more than five standard errors and the noise floor), and the input (temperature,
    speed, position of another axis, ...) the residual correlates with most (|r| > 0.5).
    """
    out = []
    s = al.signals.get(o)
    if s is not None and np.ptp(s.values) > 0:
        # the direction of motion: the derivative of a position, the sign of a velocity
        v = (s.values if s.kind in ("velocity", "angular_velocity")
             else np.gradient(s.values, al.dt))
        thr = 1e-3 * np.max(np.abs(v))
        groups = {"moving +": v > thr, "moving -": v < -thr, "at rest": np.abs(v) <= thr}
        means = {g: (float(np.mean(r[m])), int(m.sum())) for g, m in groups.items() if m.sum() > 10}
        if len(means) >= 2:
            vals = [m for m, c in means.values()]
            se = sigma / np.sqrt(min(c for _, c in means.values()))
            if max(vals) - min(vals) > max(5 * se, sigma):
                txt = ", ".join(f"{g} {_fmt(m, al.units[o])}" for g, (m, _) in means.items())
                out.append(f"{o} residual depends on the direction of motion of {o}: {txt}")
    best = None
    rr = r - r.mean()
    nr = float(np.sqrt(rr @ rr))
    for k, sg in al.signals.items():
        if k == o or np.ptp(sg.values) == 0 or nr == 0:
            continue
        x = sg.values - sg.values.mean()
        c = float(x @ rr / (np.sqrt(x @ x) * nr))
        if abs(c) > 0.5 and (best is None or abs(c) > abs(best[1])):
            best = (k, c)
    if best:
        out.append(f"{o} residual correlates most with {best[0]} (r = {best[1]:+.2f})")
    return out


def local_flags(al: Aligned, o: str, r: np.ndarray, floor: float, ratio: float = 3.0,
                max_spans: int = 5) -> list[dict]:
    """Spans where the residual's local RMS (over the window `locate` uses) exceeds `ratio`
    times the noise floor, even when the whole record does not: a stick-slip at a few
    reversals, a fault in one stretch.  Largest first: dicts of t_start, t_end (s), rms, ratio
    and where (words)."""
    n = len(r)
    w = int(np.clip(n // 200, 5, 400))
    if n < 2 * w or floor <= 0:
        return []
    ms = _running_mean(r * r, w)
    out = []
    for a, b in spans(ms > (ratio * floor) ** 2, w):
        rms = float(np.sqrt(np.mean(r[a:b] ** 2)))
        out.append({"output": o, "t_start": float(al.t[a]), "t_end": float(al.t[b - 1]),
                    "rms": rms, "ratio": rms / floor, "where": describe(al, a, b)})
    out.sort(key=lambda d: -d["rms"] * (d["t_end"] - d["t_start"] + al.dt) ** 0.5)
    return out[:max_spans]


def empirical_dependence(al: Aligned, o: str, r: np.ndarray, folds: int = 5,
                         min_gain: float = 0.25):
    """Last resort for a residual no effect explains: the signal it depends on most, as a smooth
    function (Legendre polynomial of order 4 over the signal's range), judged on held-out time
    blocks.  Candidates: every input, and the velocity and acceleration of SIM's outputs.
    Returns a dict (signal, held-out RMS before and after, relative reduction) or None when no
    signal lowers the held-out RMS by `min_gain`.  Reported as "not a known physical effect".
    """
    from numpy.polynomial import legendre
    n = len(r)
    if n < 5 * folds:
        return None
    sigs = {}
    for k, s in al.signals.items():
        if np.ptp(s.values) > 0:
            sigs[k] = s.values
        # rates of every logged signal, the other axes' included (a gantry's yaw follows the
        # acceleration of the axis that drives it; a drift the rate of a temperature)
        if s.kind in ("length", "angle", "other", "velocity", "angular_velocity", "temperature"):
            v = np.gradient(s.values, al.dt)
            if np.ptp(v) > 0:
                sigs[f"d{k}/dt"] = v
            if s.source == "sim-output" and s.kind in ("length", "angle", "other"):
                a = np.gradient(v, al.dt)
                if np.ptp(a) > 0:
                    sigs[f"d2{k}/dt2"] = a
    edges = np.linspace(0, n, folds + 1).astype(int)
    base = float(np.sqrt(np.mean(r * r)))
    best = None
    for k, x in sigs.items():
        lo, hi = float(np.min(x)), float(np.max(x))
        xi = (2 * x - (lo + hi)) / (hi - lo)
        X = np.column_stack([legendre.legval(xi, [0] * j + [1]) for j in range(5)])
        oof = np.empty(n)
        for a, b in zip(edges[:-1], edges[1:]):
            tr = np.ones(n, bool)
            tr[a:b] = False
            c, *_ = np.linalg.lstsq(X[tr], r[tr], rcond=None)
            oof[a:b] = r[a:b] - X[a:b] @ c
        after = float(np.sqrt(np.mean(oof * oof)))
        if best is None or after < best[1]:
            best = (k, after)
    if best is None or base == 0 or 1 - best[1] / base < min_gain:
        return None
    return {"signal": best[0], "heldout_rms_before": base, "heldout_rms_after": best[1],
            "reduction": 1 - best[1] / base}
