"""Is what is left noise?  Tests of a residual: lag-one autocorrelation, flatness of its
spectrum, and patterns locked to the position (per revolution of a rotary axis).

A residual below a difference-based floor may still be structure (an error that alternates from
sample to sample has large differences); these tests say so instead of calling it noise.
"""
from __future__ import annotations

import math

import numpy as np

# a lag-one autocorrelation beyond this (and beyond 5 standard errors) is not white noise
RHO_MAX = 0.3
# share of the residual's variance explained by its mean per position bin, beyond which the
# residual repeats with the position
LOCKED_SHARE = 0.5
BINS = 64


def lag1(r: np.ndarray) -> float:
    """Lag-one autocorrelation of a residual (mean removed)."""
    r = np.asarray(r, float) - float(np.mean(r))
    den = float(r @ r)
    return float(r[1:] @ r[:-1]) / den if den > 0 else 0.0


def flatness(r: np.ndarray) -> float:
    """Spectral flatness (geometric / arithmetic mean of the periodogram, 0..1; about 0.56 for
    white noise): low when a few frequencies hold the power."""
    r = np.asarray(r, float) - float(np.mean(r))
    p = np.abs(np.fft.rfft(r))[1:] ** 2
    p = p[p > 0]
    if len(p) < 4:
        return float("nan")
    return float(np.exp(np.mean(np.log(p))) / np.mean(p))


def locked_share(r: np.ndarray, phase: np.ndarray, bins: int = BINS) -> float:
    """Share of the residual's variance explained by its mean in `bins` bins of a phase in
    [0, 1) (the position modulo a period), corrected for the share noise alone explains."""
    r = np.asarray(r, float) - float(np.mean(r))
    k = np.clip((np.asarray(phase) * bins).astype(int), 0, bins - 1)
    n = np.bincount(k, minlength=bins)
    if np.count_nonzero(n >= 2) < bins // 2:
        return 0.0
    m = np.bincount(k, weights=r, minlength=bins) / np.maximum(n, 1)
    tot = float(r @ r)
    if tot <= 0:
        return 0.0
    share = float(np.sum(n * m * m)) / tot
    return max(0.0, (share - bins / len(r)) / (1.0 - bins / len(r)))


def check_residual(r: np.ndarray, kind: str, position: np.ndarray | None = None) -> dict:
    """Whiteness of a residual: lag-one correlation, spectral flatness, per-revolution lock
    (angles), and `white` (bool) with the reasons it is not."""
    r = np.asarray(r, float)
    out = {"lag1": lag1(r), "flatness": flatness(r), "reasons": []}
    n = len(r)
    if n >= 20 and abs(out["lag1"]) > max(RHO_MAX, 5.0 / math.sqrt(n)):
        out["reasons"].append(f"lag-one autocorrelation {out['lag1']:+.2f} (white noise: 0)")
    if position is not None and kind == "angle" and np.ptp(position) >= 360.0 and n >= 4 * BINS:
        share = locked_share(r, np.mod(position, 360.0) / 360.0)
        out["per_revolution"] = share
        if share > LOCKED_SHARE:
            out["reasons"].append(f"{100 * share:.0f} % of it repeats with the position per "
                                  "revolution")
    out["white"] = not out["reasons"]
    return out
