"""Bowl plans designed for the estimate (paper 001): bowl positions and touch rings chosen by an
optimal-design criterion over the workpiece setting's covariance, within the blank and the part.

The estimate's covariance (`frame.frame_from_bowls`, first-order propagation of the sphere fits'
covariances, probe sigma known) depends on the geometry only, so it is computed exactly by running
the real chain on noise-free virtual touches: probe -> fit_bowls -> frame_from_bowls.  The free
choices are

* the bowls' distance from the blank's edges (`edge_distance`): the farther apart the bowls, the
  smaller the tilt and rotation uncertainty, limited by the rim margin to the blank's edges, the
  part's keep-out circle and the other bowls (`plan_bowls` refuses what does not fit);
* the inner touch ring's polar angle as a fraction of the outer ring's (`inner`): the outer ring
  stays `margin` deg below the rim (the probe must not catch the rim);
* with a target 1-sigma, the number of touches per bowl (more touches, smaller sigma as 1/sqrt).

Criteria: "D" minimises log det of the (6, 6) covariance of (dx, dy, dz, a, b, c) (the ranking
does not depend on the units), "A" minimises its trace with the angles expressed as the
displacement they cause at the blank's corner (rad x half-diagonal, mm), so both terms are mm^2.
The target 1-sigma (mm) applies to dx, dy, dz and to each angle at that lever arm.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._io import InputError

NAMES = ("dx", "dy", "dz", "a", "b", "c")


def predicted_pose_covariance(plan, probe_sigma: float, reference: str = "bottom", method: str = "auto",
                              shared_radius: bool = True) -> np.ndarray:
    """(6, 6) covariance of (dx, dy, dz mm, a, b, c deg) that `workpiece-setting fit` will report
    for this plan at probe noise probe_sigma (mm)."""
    from .bowl_fit import fit_bowls
    from .bowl_probe import virtual_probe
    from .frame import frame_from_bowls
    touches = virtual_probe(None, plan, 0.0)
    fit = fit_bowls(touches, plan.probe_radius, probe_sigma=probe_sigma, shared_radius=shared_radius,
                    bowls=plan.ids)
    return frame_from_bowls(fit, plan, method=method, reference=reference).cov


def lever_arm(plan) -> float:
    """Half-diagonal of the blank's top face, mm: where an angle error moves the part most."""
    return float(np.hypot(plan.blank[0], plan.blank[1]) / 2.0)


def _as_mm(cov: np.ndarray, lever: float) -> np.ndarray:
    s = np.r_[np.ones(3), np.full(3, np.radians(1.0) * lever)]
    return cov * np.outer(s, s)


def _score(cov_mm: np.ndarray, criterion: str) -> float:
    if criterion == "D":
        return float(np.linalg.slogdet(cov_mm)[1])
    return float(np.trace(cov_mm))


@dataclass(frozen=True)
class DesignedBowlPlan:
    """The chosen plan, its predicted covariance (dx, dy, dz mm, a, b, c deg) and the choices."""
    plan: object
    cov: np.ndarray
    criterion: str
    probe_sigma: float
    edge_distance: float
    inner: float
    touches: int
    searched: int
    target_sigma: float | None = None

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))

    @property
    def sigma_mm(self) -> np.ndarray:
        """1-sigma with the angles as displacement at the blank's corner, mm."""
        return np.sqrt(np.diag(_as_mm(self.cov, lever_arm(self.plan))))

    def summary(self) -> str:
        how = (f"designed for the estimate, {self.criterion}-optimal over {self.searched} layouts"
               if self.searched else "as given")
        lines = [f"Plan {how} (probe sigma {self.probe_sigma * 1e3:g} µm): bowls {self.edge_distance:.3f} mm "
                 f"from the edges, inner ring at {self.inner:.2f} of the outer, {self.touches} touches per bowl",
                 "Predicted 1-sigma of every estimated error:"]
        s, smm = self.sigma, self.sigma_mm
        for k, n in enumerate(NAMES):
            over = self.target_sigma is not None and smm[k] > self.target_sigma
            if k < 3:
                lines.append(f"  {n:3s} {s[k] * 1e3:8.3f} µm{'  (above target)' if over else ''}")
            else:
                lines.append(f"  {n:3s} {s[k] * 3600:8.3f} arcsec ({smm[k] * 1e3:.3f} µm at the blank's corner)"
                             f"{'  (above target)' if over else ''}")
        return "\n".join(lines)


def design_bowl_plan(n: int = 3, *, criterion: str = "D", probe_sigma: float = 0.0005,
                     target_sigma: float | None = None, touches: int = 9, max_touches: int = 41,
                     reference: str = "bottom", **plan_kw) -> DesignedBowlPlan:
    """A bowl plan (`plan_bowls` with n bowls and plan_kw) whose edge distance and inner ring are
    chosen by the criterion; with target_sigma (mm) touches per bowl are added (4 at a time, up
    to max_touches) until every predicted 1-sigma meets it.  InputError if it cannot."""
    from .bowl_plan import plan_bowls
    if criterion not in ("D", "A"):
        raise InputError(f"expected a criterion D or A, got {criterion!r}", field="criterion")
    if not (np.isfinite(probe_sigma) and probe_sigma > 0):
        raise InputError(f"expected a positive probe sigma, mm, got {probe_sigma!r}", field="probe_sigma")
    if target_sigma is not None and not (np.isfinite(target_sigma) and target_sigma > 0):
        raise InputError(f"expected a positive target sigma, mm, got {target_sigma!r}", field="target_sigma")
    if plan_kw.get("positions") is not None:
        edges = [None]
    else:
        blank = plan_kw.get("blank", (20.0, 20.0, 5.0))
        R, h = plan_kw.get("tool_radius", 2.0), plan_kw.get("depth", 1.0)
        opening = np.sqrt(max(R * R - (R - h) ** 2, 0.0))
        lo = np.ceil((opening + plan_kw.get("margin", 0.5)) * 100 + 1e-6) / 100
        hi = min(blank[0], blank[1]) / 2.0
        edges = [float(e) for e in np.arange(lo, hi, 0.5)]
    inners = (0.3, 0.4, 0.5, 0.6, 0.7, 0.8)
    best, searched, err = None, 0, None
    for e in edges:
        for f in inners:
            kw = dict(plan_kw, inner=f, touches=touches)
            if e is not None:
                kw["edge_distance"] = e
            try:
                plan = plan_bowls(n, **kw)
                cov = predicted_pose_covariance(plan, probe_sigma, reference)
            except InputError as exc:
                err = exc
                continue
            searched += 1
            sc = _score(_as_mm(cov, lever_arm(plan)), criterion)
            if best is None or sc < best[0] - 1e-12:
                best = (sc, plan, cov, e, f)
    if best is None:
        raise err if err is not None else InputError("no feasible bowl layout", field="positions")
    _, plan, cov, e, f = best
    m = touches
    kw = dict(plan_kw, inner=f)
    if e is not None:
        kw["edge_distance"] = e
    edge = e if e is not None else float("nan")
    d = DesignedBowlPlan(plan, cov, criterion, probe_sigma, edge, f, m, searched, target_sigma)
    while target_sigma is not None and np.any(d.sigma_mm > target_sigma) and m + 4 <= max_touches:
        m += 4
        plan = plan_bowls(n, **dict(kw, touches=m))
        d = DesignedBowlPlan(plan, predicted_pose_covariance(plan, probe_sigma, reference), criterion,
                             probe_sigma, edge, f, m, searched, target_sigma)
    if target_sigma is not None and np.any(d.sigma_mm > target_sigma):
        over = [f"{n_} {s * 1e3:.3f} µm" for n_, s in zip(NAMES, d.sigma_mm) if s > target_sigma]
        raise InputError(f"target 1-sigma {target_sigma * 1e3:g} µm not reachable with {max_touches} touches per "
                         f"bowl at probe sigma {probe_sigma * 1e3:g} µm: " + ", ".join(over)
                         + " (a finer probe, more or larger bowls)", field="target_sigma")
    return d
