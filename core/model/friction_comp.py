"""Reversal (quadrant-glitch) compensation of the diagnosed friction at reversals
(docs/model-loop.md, "Feeding the compensation").

The machine FMU's friction element (mtcomp.model.machine_ref.friction_step): when the motion of
the drive (the play output s) reverses, the slide sticks; it breaks away once the drive has
wound up by the breakaway delta past it, then its lag relaxes from delta to the Coulomb c_f with
time constant tau.  Uncompensated this is a lost motion at each reversal: the slide stays
behind by up to delta, the quadrant glitch of a circle test.

Controls offer a reversal spike: at a reversal of the commanded direction they add a pulse in
the new direction, of height about the breakaway, decaying with the catch-up time constant
(plus the Coulomb lag as a constant lost motion).  `friction_commands` computes that pulse for
the discrete FMU exactly: step by step it chooses the drive position s_k that puts the slide at
the target w_k, by the friction element itself (the sliding step in closed form, the breakaway
step by bisection).  Where the decay of the spike outruns a slowly starting command the drive
would have to move back, which would stick the slide again; there the drive is held or allowed
to reverse, whichever leaves the slide nearer to w_k (an error of at most the command's motion
in that step).  Written by hand: the inverse of mtcomp's own friction model.
"""
from __future__ import annotations

import math

import numpy as np


def _stepper(step: float, brk: float, cou: float, tau: float):
    """The FMU's friction element (machine_ref.friction_step) over one step as a pure function
    of a state tuple (slide, err, direction, stuck) -> the new tuple: the same arithmetic, in
    the same order, without an object per trial (the inversion tries several drive positions
    per sample)."""
    decay_h = math.exp(-step / tau) if tau > 0 else 0.0

    def after(st, s0, s1):
        slide, err, d, stuck = st
        ds = s1 - s0
        if abs(ds) > 1e-12:
            nd = 1.0 if ds > 0 else -1.0
            if d != 0.0 and nd != d:
                stuck = True
            d = nd
        if stuck:
            D1 = d * (s1 - slide)
            if D1 >= brk:
                D0 = d * (s0 - slide)
                f = (brk - D0) / (D1 - D0) if D1 > D0 else 1.0
                f = min(max(f, 0.0), 1.0)
                dec = math.exp(-((1.0 - f) * step) / tau) if tau > 0 else 0.0
                err = d * (cou + (brk - cou) * dec)
                return (s1 - err, err, d, False)
            return (slide, err, d, True)
        target = d * cou
        err = target + (err - target) * decay_h
        return (s1 - err, err, d, False)
    return after


def friction_axis(w: np.ndarray, step: float, breakaway: float, coulomb: float, tau: float) -> np.ndarray:
    """(K,) drive positions (play output, mm or deg) that make the FMU's friction element put the
    slide at w (K,) at the end of each step (the FMU's start: slide and drive at w[0], no
    direction yet)."""
    w = np.asarray(w, float)
    s = np.empty_like(w)
    after = _stepper(step, breakaway, coulomb, tau)
    st = (float(w[0]), 0.0, 0.0, False)
    s_prev = float(w[0])
    decay = math.exp(-step / tau) if tau > 0 else 0.0
    scale = breakaway + coulomb + 1e-9
    for k, target in enumerate(w.tolist()):
        slide, err, direction, stuck = st
        best, best_e, best_st = None, math.inf, None
        if direction != 0.0 and not stuck:
            c = direction * coulomb
            s1 = target + c + (err - c) * decay          # keep sliding: slide = s - err_new
            ns = after(st, s_prev, s1)
            best, best_e, best_st = s1, abs(ns[0] - target), ns
        ns = after(st, s_prev, s_prev)                    # hold the drive
        e = abs(ns[0] - target)
        if e < best_e:
            best, best_e, best_st = s_prev, e, ns
        if best_e > 1e-13:
            # move towards the target far enough to break away: the slide is monotone in s1
            # within one direction of motion (stuck, then s1 - err with err falling)
            d = 1.0 if target > slide else -1.0
            lo, hi = s_prev + d * 2e-12, s_prev + d * (abs(target - slide) + abs(err) + 2 * scale)
            if d * (after(st, s_prev, hi)[0] - target) > 0:
                for _ in range(200):
                    mid = 0.5 * (lo + hi)
                    if d * (after(st, s_prev, mid)[0] - target) < 0:
                        lo = mid
                    else:
                        hi = mid
                    if abs(hi - lo) < 1e-15 * max(1.0, abs(hi)):
                        break
                ns = after(st, s_prev, hi)
                if abs(ns[0] - target) < best_e:
                    best, best_e, best_st = hi, abs(ns[0] - target), ns
        s[k] = best
        st, s_prev = best_st, best
    return s


def friction_commands(w: np.ndarray, step: float, breakaway, coulomb, tau) -> np.ndarray:
    """(K, n) drive positions for the targets w (K, n): `friction_axis` on every axis with a
    breakaway or Coulomb friction (per-axis values mm/deg, tau s); other axes unchanged."""
    w = np.asarray(w, float)
    n = w.shape[1]
    brk, cou, ftau = (np.broadcast_to(np.asarray(v, float), (n,)) for v in (breakaway, coulomb, tau))
    out = w.copy()
    for i in range(n):
        if brk[i] > 0 or cou[i] > 0:
            out[:, i] = friction_axis(w[:, i], step, float(brk[i]), float(cou[i]), float(ftau[i]))
    return out


def reversal_clock(w: np.ndarray, step: float) -> tuple:
    """For the samples w (K,) of one axis (mm or deg), the machine FMU's reversal rule
    (fmu/c/machine.c, machine_ref.axis_response): the motion over step k is w_k - w_{k-1}
    (moves of at most 1e-12 keep the direction); where it opposes the last direction the motion
    reversed at t_k = k h.  Returns (since (K,) s from the last reversal to the end of step k,
    inf before the first; direction (K,) +1/-1, 0 before the first move).  Vectorised."""
    w = np.asarray(w, float)
    K = len(w)
    dw = np.diff(w, prepend=w[:1])
    s = np.where(np.abs(dw) > 1e-12, np.sign(dw), 0.0)
    idx = np.where(s != 0, np.arange(K), -1)
    np.maximum.accumulate(idx, out=idx)
    d = np.where(idx >= 0, s[np.clip(idx, 0, None)], 0.0)
    prev = np.concatenate([[0.0], d[:-1]])
    rev = (s != 0) & (prev != 0) & (s != prev)
    k_rev = np.where(rev, np.arange(K), -1)
    np.maximum.accumulate(k_rev, out=k_rev)
    since = np.where(k_rev >= 0, (np.arange(K) + 1 - k_rev) * step, np.inf)
    return since, d


def glitch_commands(w: np.ndarray, step: float, height, time, drive: np.ndarray | None = None) -> np.ndarray:
    """(K, n) targets with the quadrant glitch (spike form) taken out: the machine FMU lags the
    axis by height s exp(1 - s), s = since/time, against its new direction after each reversal
    (machine_ref.glitch), so the target is led by the same spike: w + height d s exp(1 - s),
    the reversals found on w by the FMU's own rule (`reversal_clock`).  Exact for the ideal
    servo and with the feed-forward (the servo reaches each sample); the lead moves along the
    new direction at first, so it adds no reversal of its own while the axis is faster than
    0.37 height/time.  Per-axis height (mm or deg) and time (s); time 0: unchanged.  drive:
    (K, n) the servo's positions, whose reversals time the FMU's glitch (default w: they differ
    where a friction or backlash compensation holds the drive at a reversal)."""
    from .machine_ref import glitch
    w = np.asarray(w, float)
    n = w.shape[1]
    gh, gt = (np.broadcast_to(np.asarray(v, float), (n,)) for v in (height, time))
    out = w.copy()
    for i in range(n):
        if gt[i] > 0 and gh[i] != 0:
            since, d = reversal_clock((w if drive is None else np.asarray(drive, float))[:, i], step)
            out[:, i] = w[:, i] - glitch(since, d, float(gh[i]), float(gt[i]))
    return out

