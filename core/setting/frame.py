"""Workpiece frame from bowl centres: the paper-001 frame, the best-fit rigid transform, covariance.

Convention (mtcomp.errors.WorkpieceSetting): the real workpiece frame sits in the nominal one at
x_nominal = R x_real + t, R = Rz(c) Ry(b) Rx(a), angles (a, b, c) deg, t mm.  A bowl centre with
design coordinates d_i (real frame, fixed in the material) is measured at m_i = R d_i + t in the
machine's nominal workpiece frame.

Paper 001 writes the NC correction as  x -> [ex ey ez](x - X) + (X + d)  with S1 = X in the design
and X + d measured, ex, ey, ez the measured frame axes in machine coordinates.  Expanding,
x -> E x + (X + d - E X): the pose above with R = E and t = X + d - E X (`pose_from_paper`).  E is
the measured frame only when the design frame's axes are the workpiece axes (S1S2 along x, plane
S1S2S3 horizontal); in general R = F_measured F_design^T (`paper_rotation`).

Units: mm, deg.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from .._io import InputError
from ..errors import WorkpieceSetting, angles_from_matrix
from ..errors import rotation_matrix_xyz as matrix_from_angles

__all__ = [
    "pose_matrix", "make_pose", "apply_pose",
    "paper_frame", "paper_rotation", "paper_transform", "pose_from_paper", "check_bowl_geometry",
    "rigid_fit", "WorkpieceSettingEstimate", "frame_from_points", "frame_from_bowls",
]

PARAM_NAMES = ("dx", "dy", "dz", "a", "b", "c")
PARAM_UNITS = ("mm", "mm", "mm", "deg", "deg", "deg")


def pose_matrix(pose) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) of a WorkpieceSetting (or anything with .translation mm and .angles deg)."""
    return matrix_from_angles(pose.angles), np.asarray(pose.translation, float)


def make_pose(R, t) -> WorkpieceSetting:
    """WorkpieceSetting from a rotation matrix and a translation (mm)."""
    return WorkpieceSetting.from_frame(np.asarray(R, float), np.asarray(t, float))


def apply_pose(pose, x) -> np.ndarray:
    """Nominal-frame coordinates of real-frame points x (..., 3): R x + t, mm."""
    R, t = pose_matrix(pose)
    return np.asarray(x, float) @ R.T + t


# --------------------------------------------------------------------------------------------
# Paper 001
# --------------------------------------------------------------------------------------------
def paper_frame(s1, s2, s3) -> np.ndarray:
    """Orthonormalised frame of paper 001 from three points: columns ex, ey, ez.

    ex along S1S2, ez normal to the plane S1S2S3 (right-handed with S1S3), ey = ez x ex.  S1S3 is
    in general not perpendicular to S1S2; the paper's "S1S3 is the Y axis" is only its direction
    in the plane after this orthonormalisation.
    """
    s1, s2, s3 = (np.asarray(s, float) for s in (s1, s2, s3))
    u, v = s2 - s1, s3 - s1
    ex = u / np.linalg.norm(u)
    ez = _cross(u, v)
    ez /= np.linalg.norm(ez)
    return np.column_stack([ex, _cross(ez, ex), ez])


def paper_rotation(measured, design) -> np.ndarray:
    """R mapping the design frame of S1..S3 onto the measured one: F_measured F_design^T."""
    return paper_frame(*measured[:3]) @ paper_frame(*design[:3]).T


def paper_transform(x, E, X, d) -> np.ndarray:
    """Paper 001's NC correction x -> E (x - X) + (X + d) for points x (..., 3) mm.

    E = [ex ey ez] (3, 3) measured frame axes as columns, X the nominal S1, d its measured shift.
    """
    X, d = np.asarray(X, float), np.asarray(d, float)
    return (np.asarray(x, float) - X) @ np.asarray(E, float).T + X + d


def pose_from_paper(E, X, d):
    """The WorkpieceSetting equal to paper_transform(., E, X, d): R = E, t = X + d - E X."""
    E, X, d = (np.asarray(v, float) for v in (E, X, d))
    return make_pose(E, X + d - E @ X)


# --------------------------------------------------------------------------------------------
# Estimation
# --------------------------------------------------------------------------------------------
def check_bowl_geometry(points, ids, what: str = "measured", min_separation: float = 0.1,
                        min_spread: float = 0.05, file=None) -> None:
    """Raise InputError naming the bowls when points coincide or lie on one line.

    min_spread: smallest allowed ratio of the second to the first singular value of the centred
    points (for three bowls about the sine of the smallest triangle angle).
    """
    p = np.asarray(points, float)
    ids = list(ids)
    if len(p) < 3:
        raise InputError(f"{len(p)} {what} bowl(s) {ids}: at least 3 needed to define a frame",
                         file, field="bowl")
    dist = np.sqrt(((p[:, None, :] - p[None, :, :]) ** 2).sum(axis=-1))
    dist[np.tril_indices(len(p))] = np.inf
    i, j = np.unravel_index(int(np.argmin(dist)), dist.shape)
    if dist[i, j] < min_separation:
        raise InputError(f"{what} bowls {ids[i]} and {ids[j]} coincide ({dist[i, j]:.4f} mm "
                         f"apart, need >= {min_separation:g} mm)", file, field="bowl")
    sv = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
    if sv[1] < min_spread * sv[0]:
        # name the bowls that span the line: the direction of the largest singular value
        raise InputError(f"{what} bowls {', '.join(str(i) for i in ids)} are (nearly) collinear "
                         f"(spread ratio {sv[1] / sv[0]:.4f} < {min_spread:g}): they do not fix the "
                         "rotation about their line", file, field="bowl")
    if len(p) == 3:
        u, v = p[1] - p[0], p[2] - p[0]
        s = math.sqrt(_cross(u, v) @ _cross(u, v) / ((u @ u) * (v @ v)))
        if s < min_spread:
            raise InputError(f"{what} bowls {ids[0]}, {ids[1]}, {ids[2]} are (nearly) collinear "
                             f"(sin of the angle at bowl {ids[0]} = {s:.4f})", file, field="bowl")


def rigid_fit(measured, design) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rigid transform (Kabsch via SVD, scipy align_vectors): measured ~ R design + t."""
    from scipy.spatial.transform import Rotation
    m, d = np.asarray(measured, float), np.asarray(design, float)
    mc, dc = m.mean(axis=0), d.mean(axis=0)
    rot, _ = Rotation.align_vectors(m - mc, d - dc)
    R = rot.as_matrix()
    return R, mc - R @ dc


def _cross(u, v):
    # np.cross is slow on small stacks (axis juggling); the Jacobian calls this thousands of times
    return np.stack([u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1],
                     u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2],
                     u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]], axis=-1)


def _frames(P):
    """paper_frame over a stack P (K, >=3, 3) -> (K, 3, 3)."""
    u = P[:, 1] - P[:, 0]
    v = P[:, 2] - P[:, 0]
    ex = u / np.linalg.norm(u, axis=-1, keepdims=True)
    ez = _cross(u, v)
    ez = ez / np.linalg.norm(ez, axis=-1, keepdims=True)
    return np.stack([ex, _cross(ez, ex), ez], axis=-1)


def _estimate_batch(M, design, method):
    """Pose estimates (R (K,3,3), t (K,3)) for a stack of measured centre sets M (K, n, 3)."""
    d = np.asarray(design, float)
    if method == "paper":
        R = _frames(M) @ _frames(d[None])[0].T
        return R, M[:, 0] - d[0] @ R.transpose(0, 2, 1)
    # Kabsch: rotation maximising sum m_i . R d_i is U diag(1, 1, det) V^T of the cross-covariance
    mc = M.mean(axis=1, keepdims=True)
    dc = d.mean(axis=0)
    H = (M - mc).transpose(0, 2, 1) @ (d - dc)
    U, _, Vt = np.linalg.svd(H)
    det = np.sign(np.linalg.det(U @ Vt))
    D = np.zeros_like(H)
    D[:, 0, 0] = 1
    D[:, 1, 1] = 1
    D[:, 2, 2] = det
    R = U @ D @ Vt
    return R, mc[:, 0] - dc @ R.transpose(0, 2, 1)


def _estimate(measured, design, method) -> tuple[np.ndarray, np.ndarray]:
    if method == "paper":
        R = paper_rotation(measured, design)
        return R, measured[0] - R @ design[0]
    return rigid_fit(measured, design)


@functools.lru_cache(maxsize=64)
def _chi2_quantile(p: float, dof: int) -> float:
    from scipy.stats import chi2
    return float(chi2.ppf(p, dof))


@dataclass(frozen=True)
class WorkpieceSettingEstimate:
    """Workpiece setting estimated from bowl centres.

    pose: WorkpieceSetting (translation mm, angles deg).  cov: (6, 6) covariance of
    (dx, dy, dz mm, a, b, c deg) propagated from the centres' covariances (first order).
    ids, measured (n, 3), design (n, 3): bowl centres, mm.  residuals (n, 3): measured minus
    fitted centres, mm; residual_stat (n,): each bowl's residual squared in units of its own
    propagated residual covariance (chi-square with `residual_dof` degrees of freedom).
    method: "paper" (three-bowl frame of paper 001) or "lsq" (least-squares rigid fit).
    """
    pose: object
    cov: np.ndarray
    ids: tuple
    measured: np.ndarray
    design: np.ndarray
    residuals: np.ndarray
    residual_stat: np.ndarray
    residual_dof: np.ndarray
    method: str
    warnings: tuple[str, ...] = ()
    fit: object = field(default=None, repr=False)

    @property
    def R(self) -> np.ndarray:
        return matrix_from_angles(self.pose.angles)

    @property
    def t(self) -> np.ndarray:
        return np.asarray(self.pose.translation, float)

    @property
    def params(self) -> np.ndarray:
        """(dx, dy, dz mm, a, b, c deg)."""
        return np.r_[self.pose.translation, self.pose.angles]

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.cov), 0, None))

    def to_errorset(self):
        from ..errors import ErrorSet
        return ErrorSet(workpiece=self.pose)

    def save(self, path, meta: dict | None = None):
        """Write the errors TOML (mtcomp.errors format) atomically, recording the 1-sigma values and
        the 6x6 covariance (dx dy dz mm, a b c deg) under [uncertainty]."""
        from ..errors import save_errors
        sd = self.std
        return save_errors(self.to_errorset(), path, meta=meta, uncertainty={
            "workpiece_setting.translation": [float(v) for v in sd[:3]],
            "workpiece_setting.angles": [float(v) for v in sd[3:]],
            "workpiece_setting.covariance_order": list(PARAM_NAMES),
            "workpiece_setting.covariance": [[float(v) for v in row] for row in self.cov]})

    def to_dict(self) -> dict:
        """Report data (TOML-ready): pose, standard deviations, covariance, per-bowl residuals."""
        return {
            "format": "mtcomp-workpiece-estimate-1",
            "method": self.method,
            "translation_mm": [float(v) for v in self.pose.translation],
            "angles_deg": [float(v) for v in self.pose.angles],
            "std": {n: float(s) for n, s in zip(PARAM_NAMES, self.std)},
            "covariance_order": list(PARAM_NAMES),
            "covariance": [[float(v) for v in row] for row in self.cov],
            "bowls": [{"id": int(i), "measured_mm": [float(v) for v in m],
                       "design_mm": [float(v) for v in d], "residual_mm": [float(v) for v in r],
                       "residual_chi2": float(s), "residual_dof": int(k)}
                      for i, m, d, r, s, k in zip(self.ids, self.measured, self.design,
                                                  self.residuals, self.residual_stat,
                                                  self.residual_dof)],
            "warnings": list(self.warnings),
        }

    def summary(self) -> str:
        sd = self.std
        p = self.params
        out = [f"workpiece setting ({'paper 001 three-bowl frame' if self.method == 'paper' else 'least-squares rigid fit'}, "
               f"{len(self.ids)} bowls)",
               "          value          1 sigma"]
        for k in range(3):
            out.append(f" d{'xyz'[k]} {p[k] * 1e3:12.4f} µm {sd[k] * 1e3:10.4f} µm")
        for k in range(3):
            out.append(f" {'abc'[k]}  {p[3 + k] * 3600:12.4f} arcsec {sd[3 + k] * 3600:7.4f} arcsec "
                       f"({p[3 + k]:.7f} deg)")
        out.append(" bowl  residual x y z (µm)            chi2/dof")
        for i, r, s, k in zip(self.ids, self.residuals, self.residual_stat, self.residual_dof):
            out.append(f" {i:4d} {r[0] * 1e3:9.4f} {r[1] * 1e3:9.4f} {r[2] * 1e3:9.4f}"
                       f"   {s:7.2f}/{k}")
        out += [f"warning: {w}" for w in self.warnings]
        return "\n".join(out)


def _loo_stat(m, d, covs, i, others):
    """Bowl i against the rigid fit of `others`: chi-square of measured minus predicted centre."""
    mo, do = m[others], d[others]
    k = len(others)
    h = 1e-5 * max(1.0, float(np.abs(d).max()))
    E = np.eye(3 * k).reshape(3 * k, k, 3) * h
    M = np.concatenate([mo[None], mo[None] + E, mo[None] - E])
    Rb, tb = _estimate_batch(M, do, "lsq")
    pred = Rb @ d[i] + tb                                    # (1 + 6k, 3)
    J = ((pred[1:3 * k + 1] - pred[3 * k + 1:]) / (2 * h)).T   # (3, 3k)
    S = np.zeros((3 * k, 3 * k))
    for j, o in enumerate(others):
        S[3 * j:3 * j + 3, 3 * j:3 * j + 3] = covs[o]
    C = J @ S @ J.T + covs[i] + np.eye(3) * 1e-14
    r = m[i] - pred[0]
    return float(r @ np.linalg.solve(C, r)), r


def _disagreeing_bowls(m, d, covs, ids, stat, Sr, res, alarm) -> list[str]:
    """Warnings for bowls that disagree with the others beyond their uncertainty.

    With four or more bowls each bowl is judged against the rigid fit of the others (leave one
    out), so one bad bowl is named alone instead of smearing its error over all residuals; the
    worst is reported and the rest re-checked without it.  Three bowls only allow the joint
    test of the full-fit residuals (the triangle's shape).
    """
    n = len(m)
    if not np.any(covs):
        return []
    out = []
    if n >= 4:
        active = list(range(n))
        lim = _chi2_quantile(alarm, 3)
        while len(active) >= 4:
            scores = []
            for i in active:
                others = [o for o in active if o != i]
                c2, r = _loo_stat(m, d, covs, i, others)
                scores.append((c2, i, r))
            c2, i, r = max(scores, key=lambda s: s[0])
            if c2 <= lim:
                break
            out.append(f"bowl {ids[i]} disagrees with the other bowls: {np.linalg.norm(r) * 1e3:.3f} µm "
                       f"from where they put it, {math.sqrt(c2):.1f} sigma (chi2 {c2:.1f} > {lim:.1f}, "
                       "3 dof): check the bowl (burr, chip, wrong id)")
            active.remove(i)
        return out
    # joint test of all residuals against their (rank 3n - 6) propagated covariance
    w, V = np.linalg.eigh(0.5 * (Sr + Sr.T))
    keep = w > 1e-6 * w.max()
    z = V.T @ res.ravel()
    tot, k = float(np.sum(z[keep] ** 2 / (w[keep] + 1e-14))), int(keep.sum())
    lim = _chi2_quantile(alarm, k)
    if tot > lim:
        worst = int(np.argmax(stat))
        out.append(f"bowls {', '.join(map(str, ids))} do not form the planned triangle: chi2 "
                   f"{tot:.1f} > {lim:.1f} ({k} dof), largest misfit at bowl {ids[worst]}: check the "
                   "bowls (burr, chip, wrong id) or the plan")
    return out


def frame_from_points(measured, design, centre_covs=None, ids=None, method: str = "auto",
                      fit=None, alarm: float = 0.999, gross_limit: float = 0.1,
                      file=None) -> WorkpieceSettingEstimate:
    """Workpiece setting from measured and design bowl centres (n, 3) mm.

    method: "paper" (needs exactly the first three used: S1 origin, S1S2, plane), "lsq"
    (least-squares rigid fit over all bowls), "auto" = paper for 3 bowls, lsq for more.
    centre_covs: (n, 3, 3) mm^2 per bowl, or (3n, 3n) with the correlations between bowls (shared
    radius fit), propagated to the pose by the estimator's Jacobian (central
    differences of the whole estimator, so it holds for either method).  A bowl whose residual
    exceeds the `alarm` quantile of its chi-square distribution gives a warning; one more than
    `gross_limit` mm off is an InputError naming it.
    """
    m = np.asarray(measured, float).reshape(-1, 3)
    d = np.asarray(design, float).reshape(-1, 3)
    n = len(m)
    ids = tuple(range(1, n + 1)) if ids is None else tuple(ids)
    if len(d) != n:
        raise InputError(f"{n} measured but {len(d)} design bowls", file, field="bowl")
    if method == "auto":
        method = "paper" if n == 3 else "lsq"
    if method not in ("paper", "lsq"):
        raise InputError(f"method must be auto, paper or lsq, got {method!r}", field="method")
    check_bowl_geometry(d, ids, "design", file=file)
    check_bowl_geometry(m, ids, "measured", file=file)
    if method == "paper" and n != 3:
        raise InputError(f"the paper-001 frame uses exactly three bowls, got {n}; use method lsq",
                         field="method")
    R, t = _estimate(m, d, method)
    if centre_covs is None:
        S = np.zeros((3 * n, 3 * n))
    else:
        cc = np.asarray(centre_covs, float)
        if cc.shape == (3 * n, 3 * n):
            S = 0.5 * (cc + cc.T)
        elif cc.shape == (n, 3, 3):
            S = np.zeros((3 * n, 3 * n))
            for i in range(n):
                S[3 * i:3 * i + 3, 3 * i:3 * i + 3] = cc[i]
        else:
            raise ValueError(f"centre_covs must be ({n}, 3, 3) or ({3 * n}, {3 * n}), got {cc.shape}")
    covs = np.array([S[3 * i:3 * i + 3, 3 * i:3 * i + 3] for i in range(n)])

    r0 = (m - (d @ R.T + t)).ravel()
    # Jacobians of the estimator (pose parameters and residuals) by central differences over
    # every centre coordinate, all perturbed sets in one batch
    h = 1e-5 * max(1.0, float(np.abs(d).max()))
    E = np.eye(3 * n).reshape(3 * n, n, 3) * h
    M = np.concatenate([m[None] + E, m[None] - E])
    Rb, tb = _estimate_batch(M, d, method)
    P = np.concatenate([tb, angles_from_matrix(Rb)], axis=1)
    Rs = (M - (d @ Rb.transpose(0, 2, 1) + tb[:, None, :])).reshape(len(M), -1)
    Jp = ((P[:3 * n] - P[3 * n:]) / (2 * h)).T
    Jr = ((Rs[:3 * n] - Rs[3 * n:]) / (2 * h)).T
    cov = Jp @ S @ Jp.T
    cov = 0.5 * (cov + cov.T)
    Sr = Jr @ S @ Jr.T
    res = r0.reshape(n, 3)
    # a gross misfit (swapped bowl ids, a bowl milled elsewhere) would give a confident but wrong
    # pose; it is an input error, not a statistic
    worst = int(np.argmax(np.linalg.norm(res, axis=1)))
    if np.linalg.norm(res[worst]) > gross_limit:
        raise InputError(f"bowl {ids[worst]} is {np.linalg.norm(res[worst]) * 1e3:.1f} µm away from "
                         f"where the other bowls put it (limit {gross_limit * 1e3:.0f} µm): wrong "
                         "bowl id or plan?", file, field="bowl")
    stat = np.zeros(n)
    dof = np.zeros(n, int)
    for i in range(n):
        blk = Sr[3 * i:3 * i + 3, 3 * i:3 * i + 3]
        w, V = np.linalg.eigh(0.5 * (blk + blk.T))
        if not w.max() > 0:
            continue  # no uncertainty given: nothing to judge against
        keep = w > 1e-6 * w.max()  # directions the fit leaves free of residual (rank deficit)
        ri = V.T @ res[i]
        # (0.1 nm)^2 floor: numerical resolution, so rounding never raises an alarm
        stat[i] = float(np.sum(ri[keep] ** 2 / (w[keep] + 1e-14)))
        dof[i] = int(keep.sum())
    warnings = _disagreeing_bowls(m, d, covs, ids, stat, Sr, res, alarm)
    return WorkpieceSettingEstimate(pose=make_pose(R, t), cov=cov, ids=ids, measured=m, design=d,
                                    residuals=res, residual_stat=stat, residual_dof=dof,
                                    method=method, warnings=tuple(warnings), fit=fit)


REFERENCES = ("bottom", "centre")


def frame_from_bowls(fit, plan, method: str = "auto", alarm: float = 0.999,
                     file=None, reference: str = "bottom", runout: float = 0.0) -> WorkpieceSettingEstimate:
    """Workpiece setting from sphere fits (BowlFit) and the plan's design centres (BowlPlan).

    reference: "bottom" (default): the height of each bowl from its bottom point (fitted centre
    minus fitted radius along the blank's z), tilt and x, y from the centres
    (`BowlFit.reference_points`), so a cutter radius or run-out error of the ball end mill that
    cut the bowls does not read as a height error; the radius uncertainty is propagated.
    "centre": the fitted centres against the design centres of the nominal radius (a cutter
    radius error dR then reads as dz = dR).  runout: known radial run-out (mm) of the ball end
    mill that cut the bowls; its small bias on the fitted bottoms is removed (reference "bottom").

    Uses the bowls present in both, in the plan's order (S1 = first plan bowl).  Bowls of the plan
    without touches are an error naming them: a frame silently built from other bowls than
    planned would hide a probing failure.
    """
    if reference not in REFERENCES:
        raise InputError(f"reference must be one of {', '.join(REFERENCES)}, got {reference!r}",
                         field="reference")
    fitted = {f.bowl: f for f in fit.fits}
    missing = [b for b in plan.ids if b not in fitted]
    if missing:
        raise InputError(f"bowl(s) {', '.join(map(str, missing))} of the plan have no touches",
                         file, field="bowl")
    unknown = [b for b in fitted if b not in plan.ids]
    if unknown:
        raise InputError(f"touches for bowl(s) {', '.join(map(str, unknown))} not in the plan "
                         f"(plan bowls {list(plan.ids)})", file, field="bowl")
    ids = plan.ids
    m = np.array([fitted[b].centre for b in ids])
    order = [fit.ids.index(b) for b in ids]
    sel = np.concatenate([[3 * i, 3 * i + 1, 3 * i + 2] for i in order])
    covs = fit.centre_cov_full[np.ix_(sel, sel)]
    est = frame_from_points(m, plan.centres, covs, ids, method, fit=fit, alarm=alarm, file=file)
    if reference == "centre":
        return est
    up = est.R[:, 2]
    if not (np.isfinite(runout) and 0 <= runout < 0.1 * plan.tool_radius):
        raise InputError(f"run-out must be >= 0 mm and small against the bowl radius, got {runout!r}", file,
                         field="runout")
    pts, cov = fit.reference_points(plan.tool_radius, up, ids, runout=runout)
    return frame_from_points(pts, plan.centres, cov, ids, method, fit=fit, alarm=alarm, file=file)
