"""Circular interpolation: centre and sweep as the control reads them, samples, whether a
transformed arc can stay an arc (and with which words), and linearisation points."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .program import Program
from .tokens import _fail


def _plane_cols(axes, plane):
    """Column indices (u, v, w) of the plane axes and IJK indices for each block's plane."""
    ix = {a: k for k, a in enumerate(axes)}
    table = {17: ("X", "Y", "Z"), 18: ("Z", "X", "Y"), 19: ("Y", "Z", "X")}
    ijk = {"X": 0, "Y": 1, "Z": 2}
    u = np.empty(len(plane), np.int64)
    v = np.empty(len(plane), np.int64)
    w = np.empty(len(plane), np.int64)
    iu = np.empty(len(plane), np.int64)
    iv = np.empty(len(plane), np.int64)
    iw = np.empty(len(plane), np.int64)
    for p, (a, b_, c) in table.items():
        sel = plane == p
        if not sel.any():
            continue
        for name in (a, b_, c):
            if name not in ix:
                return None, name
        u[sel], v[sel], w[sel] = ix[a], ix[b_], ix[c]
        iu[sel], iv[sel], iw[sel] = ijk[a], ijk[b_], ijk[c]
    return (u, v, w, iu, iv, iw), None


def _arc_geometry(axes, position, start_vec, motion, plane, ijk, ijk_present, radius, is_arc,
                  blines, arc_tol, filename, arc_centre, arc_sweep, res_ax=None, ijk_absolute=None,
                  offset=None):
    """Centre and signed sweep of every arc block; refuses arcs it cannot interpret."""
    k = np.flatnonzero(is_arc)
    cols, missing = _plane_cols(axes, plane[k])
    if cols is None:
        _fail(f"circular interpolation needs axis {missing}, which the machine does not have",
              blines[k[0]], filename)
    u, v, w, iu, iv, iw = cols
    # start of each arc: the block before's end, the start before the first (rows taken, not
    # a copy of every position)
    prev = np.where((k > 0)[:, None], position[np.maximum(k - 1, 0)], start_vec[None, :])
    end = position[k]
    r_ = np.arange(len(k))
    # axes other than the plane and its normal must not move during an arc
    other = np.ones((len(k), len(axes)), bool)
    other[r_, u] = other[r_, v] = other[r_, w] = False
    moved = other & ((np.abs(end - prev) > 1e-12) | (np.isnan(prev) != np.isnan(end)))
    if moved.any():
        j = int(np.argmax(moved.any(axis=1)))
        a = axes[int(np.argmax(moved[j]))]
        _fail(f"axis {a} moves during circular interpolation (G{motion[k[j]]}): not supported",
              blines[k[j]], filename)
    badw = ijk_present[k, iw] if len(k) else np.zeros(0, bool)
    if badw.any():
        j = int(np.argmax(badw))
        _fail(f"arc word {'IJK'[iw[j]]} does not belong to plane G{plane[k[j]]}", blines[k[j]], filename)
    # an arc from a start the program has not fixed in its plane (the axes not written yet):
    # the control runs it from wherever the axes are, so its centre is not known here; it is
    # read with its end point (where the program writes it) and no geometry (centre and sweep
    # NaN), and the rewrite passes it unchanged, as it does every block before the pose is
    # known (it can only stand among those, or be the first block with a known end)
    nowhere = np.isnan(prev[r_, u]) | np.isnan(prev[r_, v])
    if nowhere.any():
        keep = ~nowhere
        k, u, v, w, iu, iv, iw, prev, end = (x[keep] for x in (k, u, v, w, iu, iv, iw, prev, end))
        r_ = np.arange(len(k))
        if not len(k):
            return
    su, sv = prev[r_, u], prev[r_, v]
    eu, ev = end[r_, u], end[r_, v]
    dirs = np.where(motion[k] == 3, 1.0, -1.0)
    rfmt = ~np.isnan(radius[k])
    both = rfmt & ijk_present[k].any(axis=1)
    if both.any():
        _fail("arc with both R and I/J/K", blines[k[np.argmax(both)]], filename)
    cu = su + ijk[k, iu]
    cv = sv + ijk[k, iv]
    if ijk_absolute is not None and ijk_absolute[k].any():
        # G90.1: I J K are the centre in program coordinates
        ab = ijk_absolute[k]
        cu = np.where(ab, ijk[k, iu] + offset[k, u], cu)
        cv = np.where(ab, ijk[k, iv] + offset[k, v], cv)
    # the control reads every word at its resolution: an end equal to the start there is a
    # full circle, whatever digits lie below the resolution
    resu, resv = (res_ax[u], res_ax[v]) if res_ax is not None else (1e-9, 1e-9)
    same = (np.rint(eu / resu) == np.rint(su / resu)) & (np.rint(ev / resv) == np.rint(sv / resv))
    if rfmt.any():
        R = radius[k]
        du, dv = eu - su, ev - sv
        d = np.hypot(du, dv)
        bad = rfmt & (same | (np.abs(R) < 1e-12))
        if bad.any():
            _fail("R-format arc with equal start and end point (or zero radius): the circle is "
                  "undefined; write I/J/K", blines[k[np.argmax(bad)]], filename)
        h2 = R * R - d * d / 4
        bad = rfmt & (h2 < -(arc_tol * (np.abs(R) + d)))
        if bad.any():
            j = int(np.argmax(bad))
            _fail(f"R-format arc: chord {d[j]:.6f} mm longer than the diameter {2 * abs(R[j]):.6f} mm",
                  blines[k[j]], filename)
        h = np.sqrt(np.maximum(h2, 0.0))
        dsafe = np.where(d > 0, d, 1.0)
        nu, nv = -dv / dsafe, du / dsafe                      # left normal of the chord
        s = dirs * np.sign(np.where(rfmt, R, 1.0))
        cu = np.where(rfmt, (su + eu) / 2 + s * h * nu, cu)
        cv = np.where(rfmt, (sv + ev) / 2 + s * h * nv, cv)
    r0 = np.hypot(su - cu, sv - cv)
    r1 = np.hypot(eu - cu, ev - cv)
    bad = r0 < np.maximum(resu, resv)
    if bad.any():
        j = int(np.argmax(bad))
        _fail(f"arc radius {r0[j]:.3g} mm is below the axis resolution: the control cannot "
              "run it as a circle", blines[k[j]], filename)
    bad = np.abs(r1 - r0) > arc_tol
    if bad.any():
        j = int(np.argmax(bad))
        _fail(f"arc end point is not on the circle: radius {r0[j]:.6f} mm at the start, "
              f"{r1[j]:.6f} mm at the end (tolerance {arc_tol} mm)", blines[k[j]], filename)
    a0 = np.arctan2(sv - cv, su - cu)
    a1 = np.arctan2(ev - cv, eu - cu)
    sweep = dirs * np.mod(dirs * (a1 - a0), 2 * np.pi)
    sweep = np.where(same & ~rfmt, dirs * 2 * np.pi, sweep)
    bad = np.abs(sweep) * np.maximum(r0, r1) < np.maximum(resu, resv)
    if bad.any():
        j = int(np.argmax(bad))
        _fail("arc end point at the start angle but not at the start point (a spiral of no or "
              "a full turn): ambiguous, controls differ; write a full circle and a line",
              blines[k[j]], filename)
    centre = np.empty((len(k), 3))
    centre[r_, iu] = cu
    centre[r_, iv] = cv
    centre[r_, iw] = prev[r_, w]
    arc_centre[k] = centre
    arc_sweep[k] = sweep



@dataclass
class _ArcGeo:
    k: np.ndarray          # block indices
    u: np.ndarray          # plane axis columns
    v: np.ndarray
    w: np.ndarray          # normal axis column
    iu: np.ndarray         # I/J/K index of u, v
    iv: np.ndarray
    S: np.ndarray          # (m, n) start, end
    E: np.ndarray
    cu: np.ndarray         # centre
    cv: np.ndarray
    r0: np.ndarray
    r1: np.ndarray
    a0: np.ndarray
    sweep: np.ndarray
    dirs: np.ndarray       # +1 G3, -1 G2
    full: np.ndarray
    rfmt: np.ndarray

    def point(self, row, t):
        """Points on the commanded arcs ``row`` at parameters ``t`` (n-dim)."""
        P = self.S[row].copy()
        ang = self.a0[row] + self.sweep[row] * t
        rad = self.r0[row] + (self.r1[row] - self.r0[row]) * t
        r_ = np.arange(len(row))
        P[r_, self.u[row]] = self.cu[row] + rad * np.cos(ang)
        P[r_, self.v[row]] = self.cv[row] + rad * np.sin(ang)
        wr = self.w[row]
        P[r_, wr] = self.S[row, wr] + (self.E[row, wr] - self.S[row, wr]) * t
        return P


def _subset(geo: _ArcGeo, sel) -> _ArcGeo:
    return _ArcGeo(**{f: getattr(geo, f)[sel] for f in geo.__dataclass_fields__})


def _arc_params(program: Program, ak) -> _ArcGeo:
    cols, _ = _plane_cols(program.axes, np.asarray(program.plane)[ak])
    u, v, w, iu, iv, _ = cols
    P = np.asarray(program.position)
    ak = np.asarray(ak)
    S = np.where((ak > 0)[:, None], P[np.maximum(ak - 1, 0)], np.asarray(program.start)[None, :])
    E = P[ak]
    r_ = np.arange(len(ak))
    centre = np.asarray(program.arc_centre)[ak]
    cu, cv = centre[r_, iu], centre[r_, iv]
    r0 = np.hypot(S[r_, u] - cu, S[r_, v] - cv)
    r1 = np.hypot(E[r_, u] - cu, E[r_, v] - cv)
    a0 = np.arctan2(S[r_, v] - cv, S[r_, u] - cu)
    sweep = np.asarray(program.arc_sweep)[ak]
    dirs = np.where(np.asarray(program.motion)[ak] == 3, 1.0, -1.0)
    full = np.abs(np.abs(sweep) - 2 * np.pi) < 1e-12
    rfmt = ~np.isnan(np.asarray(program.radius)[ak])
    return _ArcGeo(ak, u, v, w, iu, iv, S, E, cu, cv, r0, r1, a0, sweep, dirs, full, rfmt)


def _n_samples(geo):
    """q = ceil(|sweep| / 90 deg) per arc: the check takes 4q - 1 interior samples at t = j/4q,
    at most 22.5 deg apart."""
    q = np.maximum(1, np.ceil(np.abs(geo.sweep) / (np.pi / 2) - 1e-9)).astype(np.int64)
    return q


def _arc_samples(geo: _ArcGeo) -> np.ndarray:
    q = _n_samples(geo)
    m = 4 * q - 1
    row = np.repeat(np.arange(len(q)), m)
    j = np.arange(m.sum()) - np.repeat(np.cumsum(m) - m, m) + 1
    t = j / np.repeat(4 * q, m)
    return geo.point(row, t)


def _circumcentre(ax, ay, bx, by, cx, cy):
    d = 2 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by))
    a2, b2, c2 = ax * ax + ay * ay, bx * bx + by * by, cx * cx + cy * cy
    with np.errstate(divide="ignore", invalid="ignore"):
        ux = (a2 * (by - cy) + b2 * (cy - ay) + c2 * (ay - by)) / d
        uy = (a2 * (cx - bx) + b2 * (ax - cx) + c2 * (bx - ax)) / d
    return ux, uy


def _r_centre(su, sv, eu, ev, R, dirs):
    """Centre the control computes for an R-format arc (R < 0: more than 180 deg)."""
    du, dv = eu - su, ev - sv
    d = np.hypot(du, dv)
    h = np.sqrt(np.maximum(R * R - d * d / 4, 0.0))
    dsafe = np.where(d > 0, d, 1.0)
    s = dirs * np.sign(R)
    return (su + eu) / 2 + s * h * (-dv / dsafe), (sv + ev) / 2 + s * h * (du / dsafe)


def _arc_keep(program, geo: _ArcGeo, St, prev, new, res, fm, tol, arc_tol=0.02, offc=None):
    """Decide per arc whether the transformed arc is still a circle the control can run with
    rounded words (every transformed sample within ``tol`` of the control's path), and with
    which I J K / R words: the programmed ones if they still fit (so a translation leaves them
    untouched), else those of the circle through the transformed points."""
    n_ax = len(program.axes)
    k = geo.k
    m_arcs = len(k)
    r_ = np.arange(m_arcs)
    u, v, w = geo.u, geo.v, geo.w
    Sc_i, Ec_i = prev[k], new[k]
    Sc, Ec = Sc_i * res, Ec_i * res
    q = _n_samples(geo)
    m = 4 * q - 1
    first = np.cumsum(m) - m
    rowS = np.repeat(r_, m)
    su, sv, eu, ev = Sc[r_, u], Sc[r_, v], Ec[r_, u], Ec[r_, v]
    resu, resv = res[u], res[v]
    full_c = (Sc_i[r_, u] == Ec_i[r_, u]) & (Sc_i[r_, v] == Ec_i[r_, v])
    base_ok = full_c == geo.full
    # other axes (rotary) must not move, neither at the end nor at any sample
    other = np.ones((m_arcs, n_ax), bool)
    other[r_, u] = other[r_, v] = other[r_, w] = False
    base_ok &= np.all(~other | (Ec_i == Sc_i), axis=1)
    St_i = np.rint(St / res).astype(np.int64)
    samp_ok = np.all(~other[rowS] | (St_i == Sc_i[rowS]), axis=1)
    pu, pv = St[np.arange(len(St)), u[rowS]], St[np.arange(len(St)), v[rowS]]
    ws = w[rowS]
    pw = St[np.arange(len(St)), ws]
    sw_, ew_ = Sc[rowS, ws], Ec[rowS, ws]

    def path_ok(ccu, ccv):
        """Every sample within tol of the control's arc around (ccu, ccv)."""
        r0c = np.hypot(su - ccu, sv - ccv)
        r1c = np.hypot(eu - ccu, ev - ccv)
        a0c = np.arctan2(sv - ccv, su - ccu)
        a1c = np.arctan2(ev - ccv, eu - ccu)
        swc = np.where(full_c, 2 * np.pi, np.mod(geo.dirs * (a1c - a0c), 2 * np.pi))
        # a programmed radius difference (read as a spiral, as controls do) may remain
        ok = base_ok & (np.abs(r1c - r0c) <= arc_tol + tol) & (swc > 0) & np.isfinite(ccu + ccv)
        cu_s, cv_s = ccu[rowS], ccv[rowS]
        f = np.mod(geo.dirs[rowS] * (np.arctan2(pv - cv_s, pu - cu_s) - a0c[rowS]), 2 * np.pi) \
            / np.where(swc[rowS] > 0, swc[rowS], 1.0)
        rad_dev = np.abs(np.hypot(pu - cu_s, pv - cv_s) - (r0c[rowS] + (r1c - r0c)[rowS] * f))
        w_dev = np.abs(pw - (sw_ + (ew_ - sw_) * f))
        good = samp_ok & (f > 0) & (f < 1) & (rad_dev <= tol) & (w_dev <= tol)
        mono = np.ones(len(f), bool)
        mono[1:] = (f[1:] > f[:-1]) | (rowS[1:] != rowS[:-1])
        good &= mono
        return ok & np.logical_and.reduceat(good, first)

    # candidate 1: the programmed words
    I0u = np.rint(np.asarray(program.ijk)[k, geo.iu] / resu).astype(np.int64)
    I0v = np.rint(np.asarray(program.ijk)[k, geo.iv] / resv).astype(np.int64)
    R0 = np.rint(np.nan_to_num(np.asarray(program.radius)[k]) / resu).astype(np.int64)
    # I J K are offsets from the start (G91.1), or the centre itself (G90.1, in the frame of
    # the block's work offset)
    ab = np.asarray(program.ijk_absolute)[k]
    ou = offc[k, u] * resu if offc is not None else 0.0
    ov = offc[k, v] * resv if offc is not None else 0.0
    bu, bv = np.where(ab, ou, su), np.where(ab, ov, sv)
    c1u, c1v = bu + I0u * resu, bv + I0v * resv
    if geo.rfmt.any():
        ru, rv = _r_centre(su, sv, eu, ev, R0 * resu, geo.dirs)
        c1u, c1v = np.where(geo.rfmt, ru, c1u), np.where(geo.rfmt, rv, c1v)
    ok1 = path_ok(c1u, c1v)
    # candidate 2: circle through the control's start and end and the transformed middle
    # sample (full circles: through the samples at a quarter, half and three quarters)
    mid = St[first + 2 * q - 1]
    qa, qc = St[first + q - 1], St[first + 3 * q - 1]
    fu, fv = _circumcentre(np.where(geo.full, qa[r_, u], su), np.where(geo.full, qa[r_, v], sv),
                           mid[r_, u], mid[r_, v],
                           np.where(geo.full, qc[r_, u], eu), np.where(geo.full, qc[r_, v], ev))
    fu, fv = np.nan_to_num(fu, nan=np.inf), np.nan_to_num(fv, nan=np.inf)
    with np.errstate(invalid="ignore", over="ignore"):
        I1u = np.rint(np.where(np.isfinite(fu), (fu - bu) / resu, 0)).astype(np.int64)
        I1v = np.rint(np.where(np.isfinite(fv), (fv - bv) / resv, 0)).astype(np.int64)
    c2u, c2v = np.where(np.isfinite(fu), bu + I1u * resu, np.inf), np.where(np.isfinite(fv), bv + I1v * resv, np.inf)
    R1 = R0.copy()
    if geo.rfmt.any():
        rfit = np.hypot(su - fu, sv - fv)
        fsw = np.mod(geo.dirs * (np.arctan2(ev - fv, eu - fu) - np.arctan2(sv - fv, su - fu)), 2 * np.pi)
        # near 180 deg both signs describe the arc: keep the programmed one
        near = np.abs(fsw - np.pi) * np.where(np.isfinite(rfit), rfit, 0) <= tol
        sign = np.where(near, np.sign(np.where(R0 != 0, R0, 1)), np.where(fsw > np.pi, -1, 1))
        with np.errstate(invalid="ignore"):
            R1 = np.where(np.isfinite(rfit), np.rint(rfit / resu), 0).astype(np.int64) * sign.astype(np.int64)
        ru, rv = _r_centre(su, sv, eu, ev, R1 * resu, geo.dirs)
        c2u, c2v = np.where(geo.rfmt, ru, c2u), np.where(geo.rfmt, rv, c2v)
    # (where the programmed words fit every arc, the usual case under a rigid correction, the
    # second candidate's test is not run: its answer would be masked by ~ok1 everywhere)
    ok2 = ~ok1 & path_ok(c2u, c2v) if not ok1.all() else np.zeros_like(ok1)
    keep = ok1 | ok2
    Iu, Iv, Rc = np.where(ok1, I0u, I1u), np.where(ok1, I0v, I1v), np.where(ok1, R0, R1)

    # words of kept arcs: I J K (the two of the plane) or R
    N = len(program)
    a_counts = np.zeros((N, 4), np.int64)
    a_rep = np.zeros((N, 4), bool)
    a_ins = np.zeros((N, 4), bool)
    cw = np.asarray(program.col_word)
    for idx_c, cnt, orig in ((geo.iu, Iu, I0u), (geo.iv, Iv, I0v)):
        sel = keep & ~geo.rfmt
        rows, cols = k[sel], idx_c[sel]
        a_counts[rows, cols] = cnt[sel]
        pres = cw[rows, n_ax + cols] >= 0
        a_rep[rows, cols] = pres & (cnt[sel] != orig[sel])
        a_ins[rows, cols] = ~pres & (cnt[sel] != 0)
    sel = keep & geo.rfmt
    a_counts[k[sel], 3] = Rc[sel]
    a_rep[k[sel], 3] = Rc[sel] != R0[sel]
    a_fmt = [fm.get("X", (6, 1)), fm.get("Y", (6, 1)), fm.get("Z", (6, 1)), (6, 1)]
    if sel.any():
        a_fmt[3] = fm[program.axes[int(u[sel][0])]]
    return keep, (a_rep, a_ins, a_counts, a_fmt)


@dataclass
class _Segments:
    points: np.ndarray     # (M, n) interior points of all linearised arcs
    first: np.ndarray      # index of each arc's first interior point
    count: np.ndarray      # number of interior points per arc
    counts: np.ndarray = None


def _linearisation_points(geo: _ArcGeo, n_ax, tol) -> _Segments:
    """Interior points so that each chord deviates from the arc by at most tol/2 (the other
    half is left for rounding and for transforms that are not isometries)."""
    r = np.maximum(geo.r0, geo.r1)
    x = np.clip(1 - 0.5 * tol / np.maximum(r, 1e-300), -1, 1)
    step = np.minimum(2 * np.arccos(x), np.pi / 8)
    nseg = np.maximum(1, np.ceil(np.abs(geo.sweep) / step - 1e-9)).astype(np.int64)
    count = nseg - 1
    first = np.cumsum(count) - count
    row = np.repeat(np.arange(len(count)), count)
    i = np.arange(count.sum()) - np.repeat(first, count) + 1
    t = i / np.repeat(nseg, count)
    pts = geo.point(row, t) if len(row) else np.zeros((0, n_ax))
    return _Segments(pts, first, count)

