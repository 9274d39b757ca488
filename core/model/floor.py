"""The floor a re-simulation can reach, and the verdict on what is left above it.

A perfect model still leaves REC - re-simulation = the recording's noise + what the comparison
itself adds: REC's quantisation (a logger writing 0.1 µm steps adds q/sqrt(12) RMS) and the
interpolation of the simulation onto REC's times (linear interpolation between samples of a
curved signal).  The floor is the root sum square of the three; a held-out residual above
3x the floor says the model is incomplete: the verdict names the output and the time span
where the excess is largest.  Written by hand: no library has this bookkeeping.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

INCOMPLETE = 3.0      # residual / floor above which the model is called incomplete


@dataclass(frozen=True)
class Floor:
    """Per output, mm (or the output's unit): noise (sensor noise sigma: the diagnosis' noise
    floor or, without one, estimated from REC's second differences), quantisation (q/sqrt(12)
    of REC's logging step q, 0 when REC is not on a grid), interpolation (RMS error of the
    linear interpolation of the simulation onto REC's times), total (their root sum square);
    noise_source: "diagnosis" | "REC"."""
    noise: float
    quantisation: float
    interpolation: float
    noise_source: str

    @property
    def total(self) -> float:
        return math.sqrt(self.noise ** 2 + self.quantisation ** 2 + self.interpolation ** 2)

    def to_dict(self) -> dict:
        return {"noise": self.noise, "quantisation": self.quantisation, "interpolation": self.interpolation,
                "total": self.total, "noise_source": self.noise_source}


def noise_from_recording(v: np.ndarray) -> float:
    """Sensor noise sigma of a recorded signal from its second differences: for white noise of
    sigma s, d2 = v[k+1] - 2 v[k] + v[k-1] has sigma s sqrt(6); the motion's own second
    difference (a h^2) is small at the sampling of a servo log and is removed by the median, the
    reversals and steps by the robust scale (1.4826 MAD)."""
    v = np.asarray(v, float)
    if v.size < 5:
        return 0.0
    d2 = v[2:] - 2.0 * v[1:-1] + v[:-2]
    mad = float(np.median(np.abs(d2 - np.median(d2))))
    return 1.4826 * mad / math.sqrt(6.0)


def quantisation_step(v: np.ndarray) -> float:
    """REC's logging step q (its values all multiples of q), 0 when they are not on a grid."""
    v = np.asarray(v, float)
    d = np.abs(np.diff(v))
    d = d[d > 1e-12]
    if d.size == 0:
        return 0.0
    q = float(np.min(d))
    k = v / q
    return q if np.allclose(k, np.round(k), atol=1e-3, rtol=0) else 0.0


def interpolation_error(t: np.ndarray, t_sim: np.ndarray, y_sim: np.ndarray) -> float:
    """RMS error of np.interp(t, t_sim, y_sim) against the signal the samples come from: 0 when
    t falls on the simulation's steps; else by Richardson from the interpolation on every other
    step (the error of linear interpolation goes with h^2: e(h) ~ (e(2h) - e(h)) / 3)."""
    t = np.asarray(t, float)
    t_sim = np.asarray(t_sim, float)
    if len(t_sim) < 5:
        return 0.0
    h = float(np.median(np.diff(t_sim)))
    k = (t - t_sim[0]) / h
    if np.allclose(k, np.round(k), atol=1e-6, rtol=0):
        return 0.0
    fine = np.interp(t, t_sim, y_sim)
    coarse = np.interp(t, t_sim[::2], y_sim[::2])
    return float(np.sqrt(np.mean((coarse - fine) ** 2))) / 3.0


def floor_of(t, rec_values, t_sim, sim_values, noise: float | None) -> Floor:
    q = quantisation_step(rec_values)
    return Floor(float(noise) if noise else noise_from_recording(rec_values), q / math.sqrt(12.0),
                 interpolation_error(t, t_sim, sim_values), "diagnosis" if noise else "REC")


def where_incomplete(t: np.ndarray, resid: np.ndarray, floor: float, n_windows: int = 20) -> str:
    """Where the residual is largest: the window (of n_windows over REC's span) with the highest
    RMS, its RMS / floor, and whether the excess is a slow drift (its running mean) or fast."""
    t = np.asarray(t, float)
    r = np.asarray(resid, float)
    edges = np.linspace(t[0], t[-1], n_windows + 1)
    idx = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, n_windows - 1)
    rms = np.array([math.sqrt(float(np.mean(r[idx == b] ** 2))) if np.any(idx == b) else 0.0
                    for b in range(n_windows)])
    b = int(np.argmax(rms))
    means = np.array([float(np.mean(r[idx == w])) if np.any(idx == w) else 0.0 for w in range(n_windows)])
    slow = float(np.sqrt(np.mean(means ** 2)))
    total = float(np.sqrt(np.mean(r ** 2)))
    kind = "a slow drift (window means)" if slow > 0.7 * total else "fast (within windows: motion, reversals)"
    return (f"largest over t = {edges[b]:.3g}..{edges[b + 1]:.3g} s ({rms[b] / floor:.1f}x the floor there); "
            f"mostly {kind}")
