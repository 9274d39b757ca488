"""Sphere fits of the probed bowls: one sphere per bowl (optionally one radius for all), with
covariance, outlier rejection and errors naming the bowl and line.

Touch probing: a probe ball of radius r inside the bowl touches its wall when the probe centre lies
on the concentric sphere of radius R - r.  The controller records the probe centre at trigger, so
that sphere is what we fit; the bowl radius is its radius plus r.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._io import InputError, MtcompError
from .bowl_touches import Touches


@dataclass(frozen=True)
class SphereFit:
    """Fit of one bowl.  centre (3,) mm; radius: bowl radius (probe-centre sphere + probe), mm;
    cov: covariance of (cx, cy, cz, rho) mm^2 (rho = probe-centre sphere radius; 3x3 when the
    radius was fixed, padded with zeros); residuals (m,) radial distances of all touches from the
    fitted sphere, mm (rejected ones included); used (m,) bool; rejected: source lines/indices of
    rejected touches; sigma: probe noise used for cov, mm; lines: source lines of the touches;
    directions: (k, 3) unit vectors from the fitted centre to the touches used."""
    bowl: int
    centre: np.ndarray
    radius: float
    cov: np.ndarray
    residuals: np.ndarray
    used: np.ndarray
    sigma: float
    lines: np.ndarray
    fixed_radius: bool = False
    directions: np.ndarray | None = None

    @property
    def centre_cov(self) -> np.ndarray:
        return self.cov[:3, :3]

    @property
    def rms(self) -> float:
        r = self.residuals[self.used]
        return float(np.sqrt(np.mean(r * r)))

    @property
    def rejected(self) -> tuple[int, ...]:
        return tuple(int(i) for i in np.flatnonzero(~self.used))


@dataclass(frozen=True)
class BowlFit:
    """Sphere fits of all bowls; `warnings` lists rejected touches and other notes for the user.

    shared_cov: (3n, 3n) covariance of all centres when one radius was fitted for all bowls;
    shared_cov_rho: (3n + 1, 3n + 1) the same with the shared probe-centre sphere radius last."""
    fits: tuple[SphereFit, ...]
    probe_radius: float
    sigma: float
    sigma_known: bool
    warnings: tuple[str, ...] = ()
    shared_cov: np.ndarray | None = None
    shared_cov_rho: np.ndarray | None = None

    def runout_shift(self, runout: float, up) -> dict:
        """{bowl: (3,) mm}: how far a known radial run-out `runout` (mm) of the ball end mill moves
        each fitted bottom point (centre - radius * up).  The cavity wall lies `runout sin(phi)`
        further out at polar angle phi from the bottom; the fit's linear response to that at the
        touches used (the same design as the fit: free, shared or fixed radius) gives the shift
        (exact to first order in run-out / radius)."""
        up = np.asarray(up, float) / np.linalg.norm(up)
        fits = list(self.fits)
        shared = self.shared_cov_rho is not None
        fixed = fits[0].fixed_radius
        rows, rhs = [], []
        n = len(fits)
        for k, f in enumerate(fits):
            d = f.directions
            if d is None:
                raise InputError("the fit carries no touch directions (refit with this version)", field="runout")
            sin_phi = np.sqrt(np.clip(1.0 - (d @ -up) ** 2, 0.0, None))
            for dj, sj in zip(d, sin_phi):
                r = np.zeros(3 * n + (0 if fixed else (1 if shared else n)))
                r[3 * k:3 * k + 3] = dj               # radial distance grows by d . dc ...
                if not fixed:
                    r[3 * n + (0 if shared else k)] = 1.0   # ... and by d rho
                rows.append(r)
                rhs.append(runout * sj)
        sol, *_ = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)
        out = {}
        for k, f in enumerate(fits):
            drho = 0.0 if fixed else sol[3 * n + (0 if shared else k)]
            out[f.bowl] = sol[3 * k:3 * k + 3] - drho * up
        return out

    def reference_points(self, design_radius: float, up, ids=None, runout: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Material reference points of the bowls and their (3n, 3n) covariance, mm, mm^2.

        The bottom of a bowl is where the cutter tip was, fixed in the material; its centre is
        one cutter radius above, so a cutter radius or run-out error moves the centre but not the
        bottom.  Returned: centre - (fitted radius - design_radius) * up per bowl, i.e. the
        bottom point (centre minus fitted radius along the blank's own z axis `up`, a unit vector
        in the machine frame) raised by the design radius: the point the plan's design centre
        (`BowlPlan.centres`, nominal radius) stands for.  Height comes from the bottom, tilt and
        x, y from the centres.  `up` from a first frame fit (centres alone give the tilt right:
        a radius error moves every centre alike).  runout: a known radial run-out (mm) of the
        cutter that made the bowls, whose bias on the fitted bottoms is removed (`runout_shift`)."""
        up = np.asarray(up, float) / np.linalg.norm(up)
        ids = self.ids if ids is None else tuple(ids)
        by = {f.bowl: k for k, f in enumerate(self.fits)}
        n = len(ids)
        pts = np.empty((n, 3))
        shift = self.runout_shift(runout, up) if runout else {}
        for i, b in enumerate(ids):
            f = self.fits[by[b]]
            pts[i] = f.centre - (f.radius - design_radius) * up - shift.get(b, 0.0)
        if self.shared_cov_rho is not None:
            N = len(self.fits)
            A = np.zeros((3 * n, 3 * N + 1))
            for i, b in enumerate(ids):
                k = by[b]
                A[3 * i:3 * i + 3, 3 * k:3 * k + 3] = np.eye(3)
                A[3 * i:3 * i + 3, -1] = -up
            cov = A @ self.shared_cov_rho @ A.T
        else:
            cov = np.zeros((3 * n, 3 * n))
            Ai = np.column_stack([np.eye(3), -up])
            for i, b in enumerate(ids):
                f = self.fits[by[b]]
                c4 = np.asarray(f.cov, float)
                cov[3 * i:3 * i + 3, 3 * i:3 * i + 3] = Ai @ c4 @ Ai.T
        return pts, 0.5 * (cov + cov.T)

    @property
    def ids(self) -> tuple[int, ...]:
        return tuple(f.bowl for f in self.fits)

    @property
    def shared_radius(self) -> bool:
        return self.shared_cov is not None

    @property
    def centre_cov_full(self) -> np.ndarray:
        """(3n, 3n) covariance of all centres, mm^2 (block diagonal unless the radius is shared)."""
        if self.shared_cov is not None:
            return self.shared_cov
        n = len(self.fits)
        out = np.zeros((3 * n, 3 * n))
        for i, f in enumerate(self.fits):
            out[3 * i:3 * i + 3, 3 * i:3 * i + 3] = f.centre_cov
        return out

    @property
    def centres(self) -> np.ndarray:
        return np.array([f.centre for f in self.fits])

    @property
    def centre_covs(self) -> np.ndarray:
        return np.array([f.centre_cov for f in self.fits])

    def summary(self) -> str:
        src = "given" if self.sigma_known else "pooled from residuals"
        shared = ", one radius for all bowls" if self.shared_radius else ""
        lines = [f"bowl sphere fits (probe radius {self.probe_radius:g} mm, probe noise "
                 f"{self.sigma * 1e3:.3f} µm {src}{shared})",
                 " bowl        cx mm        cy mm        cz mm    radius mm  s(c) µm  rms µm  touches"]
        for f in self.fits:
            sd = np.sqrt(np.clip(np.diag(f.centre_cov), 0, None)) * 1e3
            lines.append(f" {f.bowl:4d} {f.centre[0]:12.6f} {f.centre[1]:12.6f} {f.centre[2]:12.6f} "
                         f"{f.radius:12.6f} {sd.max():8.3f} {f.rms * 1e3:7.3f}  "
                         f"{int(f.used.sum())}/{len(f.used)}")
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)


def _algebraic_sphere(p: np.ndarray) -> tuple[np.ndarray, float]:
    # |p|^2 = 2 c.p + (rho^2 - |c|^2) is linear in (c, k): a good start for the geometric fit.
    A = np.column_stack([2 * p, np.ones(len(p))])
    b = np.einsum("ij,ij->i", p, p)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    c = sol[:3]
    return c, math.sqrt(max(sol[3] + c @ c, 1e-12))


def fit_sphere(points: np.ndarray, radius: float | None = None, x0=None):
    """Geometric least-squares sphere through points (m, 3) mm (scipy, Levenberg-Marquardt).

    radius=None fits the radius too (needs m >= 4), else it is held fixed (m >= 3).
    Returns (centre (3,), rho, residuals (m,), jacobian (m, 4 or 3)).
    """
    from scipy.optimize import leastsq
    p = np.asarray(points, float)
    if x0 is None:
        if len(p) >= 4:
            c0, r0 = _algebraic_sphere(p)
        else:
            c0, r0 = p.mean(axis=0), radius
        if not np.all(np.isfinite(c0)):
            c0 = p.mean(axis=0)
    else:
        c0, r0 = np.asarray(x0[:3], float), float(x0[3]) if len(x0) > 3 else radius
    free = radius is None

    def res(x):
        d = np.linalg.norm(p - x[:3], axis=1)
        return d - (x[3] if free else radius)

    def jac(x):
        d = p - x[:3]
        n = np.linalg.norm(d, axis=1)[:, None]
        J = -d / n
        return np.column_stack([J, -np.ones(len(p))]) if free else J

    # Levenberg-Marquardt (MINPACK through scipy.optimize.leastsq: the thin wrapper matters in
    # Monte Carlo loops) from the algebraic start converges in a few steps; it needs at least as
    # many touches as unknowns, which the callers check with a clear message.
    x0v = np.r_[c0, r0] if free else np.asarray(c0, float)
    x, ier = leastsq(res, x0v, Dfun=jac, xtol=1e-14, ftol=1e-15, maxfev=400)
    if ier not in (1, 2, 3, 4):
        raise MtcompError(f"sphere fit did not converge (MINPACK code {ier})")
    rho = float(x[3]) if free else float(radius)
    return x[:3].copy(), rho, res(x), jac(x)


def _cov(J: np.ndarray, sigma: float) -> np.ndarray:
    JTJ = J.T @ J
    return sigma * sigma * np.linalg.inv(JTJ)


def _shared_fit(done, touches, gross_limit, limit, src, probe_radius):
    """Joint fit of all bowl centres with one probe-centre radius over the touches kept.

    Returns the updated per-bowl records, (J^T J)^-1 of (c_1 .. c_n, rho), SSR and dof.
    """
    from scipy.optimize import leastsq
    n = len(done)
    pts = [touches.points[touches.of(bid)] for bid, *_ in done]
    used = [rec[4] for rec in done]
    P = np.concatenate([p[u] for p, u in zip(pts, used)])
    owner = np.concatenate([np.full(int(u.sum()), b) for b, u in enumerate(used)])
    x0 = np.r_[np.concatenate([rec[1] for rec in done]), np.mean([rec[2] for rec in done])]

    def res(x):
        C = x[:3 * n].reshape(n, 3)[owner]
        return np.sqrt(((P - C) ** 2).sum(axis=1)) - x[-1]

    def jac(x):
        C = x[:3 * n].reshape(n, 3)[owner]
        D = P - C
        D /= np.sqrt((D * D).sum(axis=1))[:, None]
        J = np.zeros((len(P), 3 * n + 1))
        for a in range(3):
            J[np.arange(len(P)), 3 * owner + a] = -D[:, a]
        J[:, -1] = -1.0
        return J

    x, ier = leastsq(res, x0, Dfun=jac, xtol=1e-14, ftol=1e-15, maxfev=400)
    if ier not in (1, 2, 3, 4):
        raise MtcompError(f"joint sphere fit did not converge (MINPACK code {ier})")
    J = jac(x)
    inv = np.linalg.inv(J.T @ J)
    r = res(x)
    if np.max(np.abs(r)) > limit:
        # name the bowl whose own radius is furthest from the others'
        radii = np.array([rec[2] for rec in done])
        b = int(np.argmax(np.abs(radii - np.median(radii))))
        own = ", ".join(f"{rec[0]}: {rec[2] + probe_radius:.4f}" for rec in done)
        raise InputError(f"bowl {done[b][0]}: the bowls do not share one radius (own fits, bowl: "
                         f"radius mm: {own}; joint misfit up to {np.max(np.abs(r)) * 1e3:.2f} µm > "
                         f"{limit * 1e3:.2f} µm): cut with another tool? fit a radius per bowl",
                         src, field="bowl")
    out = []
    for b, (bid, _c, _rho, _resid, u, lines, _J) in enumerate(done):
        c = x[3 * b:3 * b + 3]
        resid = np.sqrt(((pts[b] - c) ** 2).sum(axis=1)) - x[-1]
        far = np.flatnonzero(np.abs(resid) > gross_limit)
        if len(far):
            j = far[np.argmax(np.abs(resid[far]))]
            where = f"line {int(lines[j])}" if lines[j] else f"touch {j + 1}"
            raise InputError(f"bowl {bid}: {where} is {resid[j] * 1e3:.1f} µm off the sphere with "
                             f"the radius shared by all bowls (limit {gross_limit * 1e3:.0f} µm): "
                             "was this bowl cut with another tool?", src, field="bowl")
        out.append((bid, c.copy(), float(x[-1]), resid, u, lines, None))
    return out, inv, float(r @ r), len(P) - (3 * n + 1)


def fit_bowls(touches: Touches, probe_radius: float, *, probe_sigma: float | None = None,
              bowl_radius: float | None = None, shared_radius: bool = True, k: float = 5.0,
              gross_limit: float = 0.05, bowls=None) -> BowlFit:
    """Fit every bowl's sphere from its touches, with the probe radius accounted for.

    probe_sigma: probe noise (1 sigma along the approach, mm); None pools it from the residuals.
    bowl_radius: fix the bowl radius (mm) instead of fitting it.  shared_radius (default): fit one
    radius for all bowls (one ball end mill cut them all): the bowls' centre heights then no longer
    carry independent radius errors, which cuts the tilt uncertainty several times; the centres
    become correlated (BowlFit.centre_cov_full).  Robustness: a touch whose
    leave-one-out residual exceeds k sigma is rejected (at most one per bowl, with a warning);
    any touch still beyond k sigma after that, or one more than `gross_limit` mm off its sphere
    (the probe hit the rim, the top face or another bowl), is an error naming the bowl and line.
    bowls: ids to fit (default all ids in the touches, sorted).
    """
    if probe_radius <= 0:
        raise InputError(f"probe radius must be > 0 mm, got {probe_radius}", field="probe_radius")
    if not k > 0:
        raise InputError(f"outlier threshold must be > 0 sigma, got {k}", field="k")
    src = touches.source
    ids = sorted(set(int(b) for b in touches.bowl)) if bowls is None else list(bowls)
    npar = 4 if bowl_radius is None else 3
    fixed_rho = None if bowl_radius is None else bowl_radius - probe_radius
    if fixed_rho is not None and fixed_rho <= 0:
        raise InputError(f"bowl radius {bowl_radius} must exceed the probe radius {probe_radius}",
                         field="bowl_radius")
    warnings: list[str] = []
    raw = []
    for bid in ids:
        idx = touches.of(bid)
        m = len(idx)
        if m < npar + 1:
            raise InputError(f"bowl {bid}: {m} touches, at least {npar + 1} needed (a sphere with "
                             f"{'free' if npar == 4 else 'fixed'} radius has {npar} unknowns, plus "
                             "one to see the fit's residual)", src, field="bowl")
        p = touches.points[idx]
        # degenerate touch sets (all in one spot or on one circle) leave the sphere undetermined
        sv = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
        if sv[1] < 1e-3 * max(sv[0], 1e-12) or sv[0] < 1e-6:
            raise InputError(f"bowl {bid}: touches are coincident or collinear; spread them over "
                             "the bowl wall", src, field="bowl")
        if npar == 4 and sv[2] < 1e-3 * sv[0]:
            raise InputError(f"bowl {bid}: touches are coplanar (one circle); a sphere with free "
                             "radius needs touches at two or more depths", src, field="bowl")
        c, rho, r, J = fit_sphere(p, fixed_rho)
        raw.append((bid, idx, p, c, rho, r, J))
    if probe_sigma is not None:
        if not probe_sigma >= 0:
            raise InputError(f"probe noise must be >= 0 mm, got {probe_sigma}", field="probe_sigma")
        thr_sigma = float(probe_sigma)
    else:
        # robust pooled scale for the outlier decisions: one bad touch must not inflate it
        allr = np.concatenate([r for *_, r, _J in raw])
        dof = sum(len(r) - npar for *_, r, _J in raw)
        s_pool = math.sqrt(float(allr @ allr) / dof)
        mad = 1.4826 * float(np.median(np.abs(allr))) * math.sqrt(len(allr) / dof)
        thr_sigma = min(s_pool, 2 * mad) if mad > 0 else s_pool
    # resolution floor: decisions against a zero noise estimate would flag rounding
    thr_sigma = max(thr_sigma, 1e-6)
    done = []
    for bid, idx, p, c, rho, r, J in raw:
        m = len(idx)
        used = np.ones(m, bool)
        lines = touches.lines[idx]
        where = lambda j: (f"line {int(lines[j])}" if lines[j] else f"touch {j + 1}")  # noqa: E731
        need = bool(np.max(np.abs(r)) > k * thr_sigma)
        if need or probe_sigma is None:
            # leave-one-out: the outlier's own residual is shrunk by its leverage in the full fit
            # (with an estimated scale it can hide completely), so judge each touch against the
            # sphere of the others
            best = None
            if m - 1 >= npar:
                for j in range(m):
                    keep = np.arange(m) != j
                    cj, rhoj, rj, _ = fit_sphere(p[keep], fixed_rho, x0=np.r_[c, rho])
                    out = abs(np.linalg.norm(p[j] - cj) - rhoj)
                    worst_rest = float(np.max(np.abs(rj)))
                    if best is None or worst_rest < best[1] - 1e-12 or \
                            (abs(worst_rest - best[1]) <= 1e-12 and out > best[2]):
                        best = (j, worst_rest, out, cj, rhoj)
            can = best is not None and m - 1 >= npar + 1 and best[1] <= k * thr_sigma
            if need and not can:
                jw = int(np.argmax(np.abs(r)))
                raise InputError(f"bowl {bid}: touches disagree with one sphere by up to "
                                 f"{np.max(np.abs(r)) * 1e3:.2f} µm at {where(jw)} (noise "
                                 f"{thr_sigma * 1e3:.3f} µm, limit {k:g} sigma): more than one bad "
                                 "touch, or too few touches to reject one", src, field="bowl")
            if can and (need or best[2] > k * thr_sigma):
                j, worst_rest, out, cj, rhoj = best
                used[j] = False
                warnings.append(f"bowl {bid}: {where(j)} rejected, {out * 1e3:.2f} µm off the "
                                f"sphere of the other touches ({out / thr_sigma:.1f} sigma)")
                c, rho, _r, _J = fit_sphere(p[used], fixed_rho, x0=np.r_[cj, rhoj])
        resid = np.linalg.norm(p - c, axis=1) - rho
        far = np.flatnonzero(np.abs(resid) > gross_limit)
        if len(far):
            j = far[np.argmax(np.abs(resid[far]))]
            raise InputError(f"bowl {bid}: {where(j)} is {resid[j] * 1e3:.1f} µm off the bowl's "
                             f"sphere (limit {gross_limit * 1e3:.0f} µm): the probe did not touch "
                             "this bowl's wall (rim, top face, wrong bowl id?)", src, field="bowl")
        d = p[used] - c
        Ju = -d / np.linalg.norm(d, axis=1)[:, None]
        if fixed_rho is None:
            Ju = np.column_stack([Ju, -np.ones(len(d))])
        if np.linalg.cond(Ju) > 1e8:
            raise InputError(f"bowl {bid}: touches do not determine the sphere (ill-conditioned)",
                             src, field="bowl")
        done.append((bid, c, rho, resid, used, lines, Ju))
    if probe_sigma is not None:
        sigma, known = float(probe_sigma), True
    else:
        ssr = sum(float(d[3][d[4]] @ d[3][d[4]]) for d in done)
        dof = sum(int(d[4].sum()) - npar for d in done)
        sigma, known = math.sqrt(ssr / dof), False
    full = None
    if shared_radius and fixed_rho is None and len(done) > 1:
        done, full, ssr, dof = _shared_fit(done, touches, gross_limit, k * thr_sigma, src,
                                           probe_radius)
        if probe_sigma is None:
            sigma = math.sqrt(ssr / dof)
    fits = []
    for b, (bid, c, rho, resid, used, lines, Ju) in enumerate(done):
        if full is not None:
            sel = [3 * b, 3 * b + 1, 3 * b + 2, 3 * len(done)]
            cov = sigma * sigma * full[np.ix_(sel, sel)]
        else:
            cov = _cov(Ju, sigma)
        if fixed_rho is not None:
            cov = np.pad(cov, ((0, 1), (0, 1)))
        dvec = touches.points[touches.of(bid)][used] - c
        fits.append(SphereFit(bowl=bid, centre=c, radius=rho + probe_radius, cov=cov,
                              residuals=resid, used=used, sigma=sigma, lines=lines,
                              fixed_radius=fixed_rho is not None,
                              directions=dvec / np.linalg.norm(dvec, axis=1)[:, None]))
    if full is not None:
        n3 = 3 * len(done)
        return BowlFit(fits=tuple(fits), probe_radius=float(probe_radius), sigma=sigma,
                       sigma_known=known, warnings=tuple(warnings),
                       shared_cov=sigma * sigma * full[:n3, :n3], shared_cov_rho=sigma * sigma * full)
    return BowlFit(fits=tuple(fits), probe_radius=float(probe_radius), sigma=sigma,
                   sigma_known=known, warnings=tuple(warnings))
