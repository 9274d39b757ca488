"""Drift during the bowl probing (paper 001): a linear drift of the probe against the blank over
the probing, seen by touching the first bowl again at the end (ISO 230-3's repeated measurement),
estimated and removed before the frame fit.

Model (ours): the touches are recorded in program order; touch j is taken at tau_j = j / (n - 1)
of the probing and recorded displaced by tau_j v (v: the drift over the whole probing, mm,
machine frame).  The first bowl's two visits then differ by v (tau_2 - tau_1) (their mean times);
every touch corrected by -tau_j v is drift-free.  The estimate iterates: fit the two visits'
centres (one radius for both: the same bowl), v from their difference, correct, refit.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .._io import InputError


def touch_times(n: int) -> np.ndarray:
    """tau (n,) of n touches in program order: 0 the first, 1 the last."""
    return np.arange(n) / (n - 1) if n > 1 else np.zeros(n)


def apply_drift(touches, drift):
    """Touches as recorded under a linear drift (3,) mm over the probing (for simulation)."""
    drift = np.asarray(drift, float)
    if drift.shape != (3,) or not np.all(np.isfinite(drift)):
        raise InputError(f"expected a drift of three finite mm values, got {drift!r}", field="drift")
    tau = touch_times(len(touches.bowl))
    return replace(touches, points=touches.points + tau[:, None] * drift)


def with_repeat(touches, again, bowl_id: int | None = None):
    """The touches with the first bowl's touches of a second probing `again` appended (a repeated
    visit at the end, with its own noise)."""
    b = int(touches.bowl[0]) if bowl_id is None else int(bowl_id)
    idx = again.of(b)
    return replace(touches, bowl=np.r_[touches.bowl, again.bowl[idx]],
                   points=np.vstack([touches.points, again.points[idx]]),
                   approach=np.vstack([touches.approach, again.approach[idx]]),
                   lines=np.r_[touches.lines, again.lines[idx]])


def probe_with_repeat(true_pose, plan, noise_sigma: float, rng=None, drift=None, **kw):
    """Virtual probing (`bowl_probe.virtual_probe`) of every bowl and the first again at the end,
    each touch with its own noise, recorded under a linear drift (3,) mm over the probing."""
    from .bowl_probe import virtual_probe
    rng = np.random.default_rng(rng)
    t = with_repeat(virtual_probe(true_pose, plan, noise_sigma, rng, **kw),
                    virtual_probe(true_pose, plan, noise_sigma, rng, **kw))
    return apply_drift(t, np.zeros(3) if drift is None else drift)


def visits(touches) -> dict:
    """{bowl: [index arrays of its contiguous runs of touches]}."""
    out: dict = {}
    b = np.asarray(touches.bowl)
    start = 0
    for k in range(1, len(b) + 1):
        if k == len(b) or b[k] != b[start]:
            out.setdefault(int(b[start]), []).append(np.arange(start, k))
            start = k
    return out


@dataclass(frozen=True)
class Drift:
    """Estimated drift over the probing: value (3,) mm, cov (3, 3) mm^2, the bowl visited twice."""
    value: np.ndarray
    cov: np.ndarray
    bowl: int

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))

    def summary(self) -> str:
        return ("drift over the probing (from bowl %d visited twice): " % self.bowl + ", ".join(
            f"{c} {v * 1e3:+.3f} ± {s * 1e3:.3f} µm" for c, v, s in zip("xyz", self.value, self.sigma)))


def estimate_drift(touches, probe_radius: float, probe_sigma: float, iterations: int = 5) -> Drift | None:
    """The drift from a bowl visited twice (None if no bowl is): see the module doc."""
    from .bowl_fit import fit_bowls, fit_sphere
    rep = {b: v for b, v in visits(touches).items() if len(v) >= 2}
    if not rep:
        return None
    b, (first, second) = next(iter(rep.items()))[0], next(iter(rep.values()))[:2]
    tau = touch_times(len(touches.bowl))
    dt = tau[second].mean() - tau[first].mean()
    keep = np.ones(len(tau), bool)
    keep[second] = False
    v = np.zeros(3)
    for _ in range(iterations):
        pts = touches.points - tau[:, None] * v
        # one radius for both visits, from the shared fit of all bowls' first visits: a free
        # radius per visit would leave the centre heights (and so v_z) several times less sure
        sub = replace(touches, bowl=touches.bowl[keep], points=pts[keep], approach=touches.approach[keep],
                      lines=touches.lines[keep])
        rho = fit_bowls(sub, probe_radius, probe_sigma=probe_sigma).fits[0].radius - probe_radius
        c1, *_ = fit_sphere(pts[first], rho)
        c2, *_ = fit_sphere(pts[second], rho)
        v = v + (c2 - c1) / dt

    def ccov(idx, c):
        u = (pts[idx] - c) / np.linalg.norm(pts[idx] - c, axis=1)[:, None]
        return probe_sigma ** 2 * np.linalg.inv(u.T @ u)
    cov = (ccov(first, c1) + ccov(second, c2)) / dt ** 2
    return Drift(v, cov, b)


def remove_drift(touches, drift: Drift):
    tau = touch_times(len(touches.bowl))
    return replace(touches, points=touches.points - tau[:, None] * drift.value)


def fit_with_drift(touches, plan, probe_sigma: float, fit_kw=None, frame_kw=None):
    """(BowlFit, WorkpieceSettingEstimate, Drift or None): the drift estimated and removed when a
    bowl is visited twice, its covariance added to the pose's through the pose's sensitivity to
    it (one refit per component)."""
    from .bowl_fit import fit_bowls
    from .frame import frame_from_bowls
    fit_kw, frame_kw = dict(fit_kw or {}), dict(frame_kw or {})
    fit_kw.setdefault("probe_sigma", probe_sigma)
    dr = estimate_drift(touches, plan.probe_radius, probe_sigma)
    if dr is None:
        fit = fit_bowls(touches, plan.probe_radius, **fit_kw)
        return fit, frame_from_bowls(fit, plan, **frame_kw), None
    t0 = remove_drift(touches, dr)
    fit = fit_bowls(t0, plan.probe_radius, **fit_kw)
    est = frame_from_bowls(fit, plan, **frame_kw)
    h = 1e-4
    S = np.empty((6, 3))
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        f2 = fit_bowls(remove_drift(touches, Drift(dr.value + e, dr.cov, dr.bowl)), plan.probe_radius, **fit_kw)
        S[:, k] = (frame_from_bowls(f2, plan, **frame_kw).params - est.params) / h
    return fit, replace(est, cov=est.cov + S @ dr.cov @ S.T), dr
