"""Cutter radius compensation (G41/G42): how far correcting the programmed contour is from
correcting the tool-centre path the control makes of it.

Under G41/G42 the control offsets the programmed contour by the tool radius r in the active
plane.  mtcomp corrects the programmed contour p -> p + c(p); the control then offsets the
corrected contour.  What the machine needs is the correction at the tool centre,
c(p + r n) (n: the in-plane unit normal of the contour).  For a correction with Jacobian J
(linear over the distance r) and a contour with in-plane unit tangent t, the control offsets
the corrected contour along its own in-plane normal n' = n - (n.J t) t (first order), so the
error, tool centre made minus tool centre wanted, is

    r (n' - n) - r J n = -r [ (n.(J + J^T) t) t + (n.J n) n ]   (in the plane)
                         -r (J n)_normal                       (along the plane normal)

An in-plane rotation (J antisymmetric in the plane) drops out: offsetting commutes with it.
What is left is bounded by r (sqrt(5) |S| + |j_n|), S the symmetric part of J in the plane
(spectral norm) and j_n the normal component of J on in-plane directions: the out-of-plane
part of a rotation (a tilt of the workpiece), table slopes, scale errors.  The radius is not
in the program: the caller gives it (option, D table) or a documented default bound.
Derived here; no library computes this.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

#: radius assumed when neither --cutter-radius nor a [D] value gives it (mm): a bound for
#: end mills up to 20 mm diameter, said so in compensate's output
DEFAULT_RADIUS = 10.0

#: active plane -> (first, second in-plane axis, normal axis)
PLANE_AXES = {17: ("X", "Y", "Z"), 18: ("Z", "X", "Y"), 19: ("Y", "Z", "X")}


def offset_error_bound(correct: Callable[[np.ndarray], np.ndarray], positions: np.ndarray,
                       plane: np.ndarray, radius: np.ndarray, axes: tuple) -> np.ndarray:
    """Per row: bound (mm) on the tool-centre error of correcting the programmed point instead
    of the tool centre under G41/G42, for the correction ``correct(q) - q`` (q: rows of axis
    positions, mm/deg, in ``axes`` order).  ``plane`` 17/18/19 and ``radius`` (mm) per row.
    The Jacobian is taken as the finite difference of the correction over ``radius`` along
    the two in-plane axes (so its change over the offset distance counts, not only the slope
    at the point)."""
    q = np.asarray(positions, float)
    n = len(q)
    out = np.zeros(n)
    if n == 0:
        return out
    r = np.asarray(radius, float)
    plane = np.asarray(plane)
    iu = np.empty(n, np.int64)
    iv = np.empty(n, np.int64)
    iw = np.empty(n, np.int64)
    for pl, (u, v, w) in PLANE_AXES.items():
        sel = plane == pl
        if sel.any():
            missing = [a for a in (u, v, w) if a not in axes]
            if missing:
                raise ValueError(f"plane G{pl} needs axes {u} {v} {w}; the machine has {' '.join(axes)}")
            iu[sel], iv[sel], iw[sel] = axes.index(u), axes.index(v), axes.index(w)
    rows = np.arange(n)
    qu = q.copy()
    qu[rows, iu] += r
    qv = q.copy()
    qv[rows, iv] += r
    c = np.asarray(correct(np.vstack([q, qu, qv]))) - np.vstack([q, qu, qv])
    du = c[n:2 * n] - c[:n]                  # r J e_u
    dv = c[2 * n:] - c[:n]                   # r J e_v
    m = np.stack([np.stack([du[rows, iu], dv[rows, iu]], -1),
                  np.stack([du[rows, iv], dv[rows, iv]], -1)], 1)      # (n, 2, 2) r J in plane
    s = 0.5 * (m + np.swapaxes(m, 1, 2))
    s_norm = np.abs(np.linalg.eigvalsh(s)).max(axis=1)
    j_n = np.hypot(du[rows, iw], dv[rows, iw])
    out[:] = np.sqrt(5.0) * s_norm + j_n
    return out


def rotary_change(correct_minus_q: np.ndarray, axes: tuple) -> np.ndarray:
    """Per row: largest correction (deg) of a rotary axis; under G41/G42 a turned rotary axis
    turns the plane the control offsets in, which this bound does not cover."""
    rot = [k for k, a in enumerate(axes) if a in "ABC"]
    if not rot:
        return np.zeros(len(correct_minus_q))
    return np.abs(np.asarray(correct_minus_q)[:, rot]).max(axis=1)


def arc_midpoints(program, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(blocks, midpoints): for the arc blocks among ``rows`` (indices of motion blocks), the
    point half way along the arc (angle and helix axis), in the word frame like
    ``program.position``.  The correction can vary along a long arc more than between its
    end points; the bound is taken there too."""
    rows = np.asarray(rows, np.int64)
    arcs = rows[np.asarray(program.is_arc)[rows]]
    if not len(arcs):
        return arcs, np.zeros((0, program.n_axes))
    P = np.asarray(program.position)
    start = np.where(arcs[:, None] > 0, P[np.maximum(arcs - 1, 0)], np.asarray(program.start)[None])
    end = P[arcs]
    mid = 0.5 * (start + end)                # other axes (helix, rotary): half way
    axes = program.axes
    xyz = {a: i for i, a in enumerate("XYZ")}
    for pl, (u, v, _) in PLANE_AXES.items():
        sel = np.asarray(program.plane)[arcs] == pl
        if not sel.any() or u not in axes or v not in axes:
            continue
        iu, iv = axes.index(u), axes.index(v)
        cu = np.asarray(program.arc_centre)[arcs[sel], xyz[u]]
        cv = np.asarray(program.arc_centre)[arcs[sel], xyz[v]]
        h = 0.5 * np.asarray(program.arc_sweep)[arcs[sel]]
        du, dv = start[sel, iu] - cu, start[sel, iv] - cv
        mid[sel, iu] = cu + np.cos(h) * du - np.sin(h) * dv
        mid[sel, iv] = cv + np.sin(h) * du + np.cos(h) * dv
    return arcs, mid
