"""Touch-probe calibration on a reference sphere: effective radius and direction-dependent
pre-travel (lobing), and the correction of bowl touches with it.

Model (ours; docs/workpiece-setting.md "Probe calibration").  The controller records the probe
centre at trigger.  A probe of nominal ball radius r triggers `pre-travel` late along its approach
direction a (unit).  Both effects fold into one effective radius per approach direction,

    r_eff(a) = r + delta(a),

because on a convex sphere (approach towards the centre) the recorded centre lies at R_s + r_eff
from the sphere centre, and in a concave bowl (approach away from the centre) at R - r_eff: the
same delta(a) enters both with the sign that the correction p' = p + delta(a) a removes
(|p' - c| = R_s + r, resp. R - r).  delta(a) is expanded in the probe frame (z the probe axis,
theta the approach's angle from -z, phi its azimuth):

    delta(a) = d0 + d_ax a_z^2 + sin(theta) sum_{k=2..K} (c_k cos k phi + s_k sin k phi)

d0 is the effective radius error (ball radius error and the mean pre-travel: a sphere cannot tell
them apart, and neither can the bowls, so it need not be); d_ax the axial-against-lateral
pre-travel difference; the harmonics the lobing (3 lobes for a kinematic three-point seat).  The
first harmonic and a term linear in a_z are left out: they equal a shift of the sphere's centre, so
a sphere of unknown position cannot see them (they are the probe's stylus offset, calibrated
against a known position, not here).

The fit: unknowns sphere centre (3) and the coefficients, weighted least squares on the radial
residuals |p - c| - (R_s + r + delta(a)), with the sphere's certified diameter uncertainty carried
into d0 (it moves d0 one to one for half the diameter error).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._io import InputError


def _basis(a: np.ndarray, harmonics: int, axial: bool = False) -> tuple[np.ndarray, tuple[str, ...]]:
    """Columns of delta(a) for unit approaches a (m, 3) and their names."""
    a = np.atleast_2d(np.asarray(a, float))
    sin_t = np.hypot(a[:, 0], a[:, 1])
    phi = np.arctan2(a[:, 1], a[:, 0])
    cols, names = [np.ones(len(a))], ["d0"]
    if axial:
        cols.append(a[:, 2] ** 2)
        names.append("d_axial")
    for k in range(2, harmonics + 1):
        cols += [sin_t * np.cos(k * phi), sin_t * np.sin(k * phi)]
        names += [f"c{k}", f"s{k}"]
    return np.column_stack(cols), tuple(names)


@dataclass(frozen=True)
class ProbeCalibration:
    """Result of `calibrate_probe`.  nominal_radius, sphere_radius mm; names/coefficients (mm) of
    delta(a); cov (mm^2) of the coefficients; centre (3,) mm of the sphere; residuals (m,) mm;
    sigma: probe noise used (mm); harmonics."""
    nominal_radius: float
    sphere_radius: float
    names: tuple
    coefficients: np.ndarray
    cov: np.ndarray
    centre: np.ndarray
    residuals: np.ndarray
    sigma: float
    harmonics: int
    source: str = ""

    @property
    def axial(self) -> bool:
        return "d_axial" in self.names

    @property
    def effective_radius(self) -> float:
        """Ball radius minus the mean pre-travel, mm (what a probe-centre sphere fit sees)."""
        return self.nominal_radius + float(self.coefficients[0])

    @property
    def effective_radius_sigma(self) -> float:
        return float(math.sqrt(self.cov[0, 0]))

    def delta(self, approach) -> np.ndarray:
        """delta(a) (m,) mm for unit approaches (m, 3)."""
        B, _ = _basis(approach, self.harmonics, self.axial)
        return B @ self.coefficients

    def delta_sigma(self, approach) -> np.ndarray:
        B, _ = _basis(approach, self.harmonics, self.axial)
        return np.sqrt(np.einsum("ij,jk,ik->i", B, self.cov, B))

    def lobing_pv(self) -> float:
        """Peak-to-valley of the direction-dependent part over lateral approaches, mm."""
        phi = np.linspace(0, 2 * np.pi, 361)
        a = np.column_stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)])
        d = self.delta(a) - self.coefficients[0]
        return float(d.max() - d.min())

    def correct(self, points, approach, nominal_radius: float) -> np.ndarray:
        """Touches (m, 3) mm as a probe of exactly `nominal_radius` without pre-travel would have
        recorded them: p + (r_eff(a) - nominal_radius) a."""
        a = np.atleast_2d(np.asarray(approach, float))
        shift = self.nominal_radius + self.delta(a) - nominal_radius
        return np.asarray(points, float) + shift[:, None] * a

    def summary(self) -> str:
        um = 1e3
        s = np.sqrt(np.diag(self.cov))
        lines = [f"probe calibration on a {2 * self.sphere_radius:g} mm reference sphere ({len(self.residuals)} touches):",
                 f"  effective radius {self.effective_radius:.6f} mm ({self.coefficients[0] * um:+.3f} "
                 f"± {s[0] * um:.3f} µm against the nominal {self.nominal_radius:g} mm; ball radius and mean "
                 "pre-travel together)",
                 ]
        k0 = 1
        if self.axial:
            lines.append(f"  axial - lateral pre-travel {self.coefficients[1] * um:+.3f} ± {s[1] * um:.3f} µm")
            k0 = 2
        for k in range(k0, len(self.names), 2):
            amp = math.hypot(self.coefficients[k], self.coefficients[k + 1])
            lines.append(f"  lobing {self.names[k][1:]}-lobe amplitude {amp * um:.3f} µm "
                         f"(c {self.coefficients[k] * um:+.3f} ± {s[k] * um:.3f}, s {self.coefficients[k + 1] * um:+.3f}"
                         f" ± {s[k + 1] * um:.3f} µm)")
        lines.append(f"  lateral lobing peak-to-valley {self.lobing_pv() * um:.3f} µm; residual rms "
                     f"{np.sqrt(np.mean(self.residuals ** 2)) * um:.3f} µm (noise {self.sigma * um:.3f} µm)")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {"format": "mtcomp-probe-calibration-1",
                "probe": {"nominal_radius_mm": self.nominal_radius, "effective_radius_mm": self.effective_radius,
                          "harmonics": self.harmonics, "sigma_mm": self.sigma},
                "reference_sphere": {"radius_mm": self.sphere_radius, "centre_mm": [float(v) for v in self.centre]},
                "delta": {"names": list(self.names), "coefficients_mm": [float(v) for v in self.coefficients],
                          "covariance_mm2": [[float(v) for v in row] for row in self.cov]}}


def calibrate_probe(points, approach, sphere_diameter: float, nominal_radius: float, *, harmonics: int = 3,
                    sigma: float | None = None, diameter_sigma: float = 0.0, axial: bool = False,
                    source: str = "") -> ProbeCalibration:
    """Fit the probe's delta(a) (module doc) from touches on a reference sphere of certified
    diameter (mm): recorded probe centres (m, 3) mm and unit approaches (m, 3).  sigma: probe noise
    (mm), default pooled from the residuals; diameter_sigma: the certificate's 1-sigma, mm.
    axial: also fit the axial-against-lateral term (a_z^2).  Off by default: on touches from one
    hemisphere it is nearly collinear with the centre height and d0, and its noise reaches the
    bowls' dz (0.24 µm rms for 49 touches at 0.1 µm noise to the equator, against 0.03 µm without
    it); fit it only with touches well below the equator."""
    from scipy.optimize import least_squares
    P = np.atleast_2d(np.asarray(points, float))
    A = np.atleast_2d(np.asarray(approach, float))
    if P.shape != A.shape or P.shape[1] != 3:
        raise InputError(f"expected (m, 3) points and approaches, got {P.shape} and {A.shape}", source)
    if not (np.isfinite(sphere_diameter) and sphere_diameter > 0):
        raise InputError(f"expected a positive sphere diameter, mm, got {sphere_diameter!r}", source,
                         field="sphere_diameter")
    if not (np.isfinite(nominal_radius) and 0 < nominal_radius):
        raise InputError(f"expected a positive probe radius, mm, got {nominal_radius!r}", source, field="probe_radius")
    if harmonics < 1 or harmonics > 8:
        raise InputError(f"expected 1 to 8 harmonics, got {harmonics}", source, field="harmonics")
    A = A / np.linalg.norm(A, axis=1)[:, None]
    B, names = _basis(A, harmonics, axial)
    n_par = 3 + B.shape[1]
    if len(P) < n_par + 1:
        raise InputError(f"{len(P)} touches cannot determine {n_par} unknowns (sphere centre and {len(names)} probe "
                         "terms) with a residual to spare: touch the sphere more often", source)
    Rs = sphere_diameter / 2.0
    c0 = (P + (Rs + nominal_radius) * A).mean(axis=0)   # start: where the approaches point

    def res(x):
        return np.linalg.norm(P - x[:3], axis=1) - (Rs + nominal_radius + B @ x[3:])

    def jac(x):
        d = P - x[:3]
        u = d / np.linalg.norm(d, axis=1)[:, None]
        return np.hstack([-u, -B])

    sol = least_squares(res, np.r_[c0, np.zeros(B.shape[1])], jac=jac, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    J = jac(sol.x)
    sv = np.linalg.svd(J, compute_uv=False)
    if sv[-1] < 1e-9 * sv[0]:
        raise InputError("the touches do not separate the sphere centre from the probe terms: touch the sphere "
                         "at several polar angles and at least 2K+1 azimuths", source)
    r = res(sol.x)
    dof = len(P) - n_par
    s = float(sigma) if sigma is not None else float(np.sqrt(r @ r / dof))
    cov_full = s * s * np.linalg.inv(J.T @ J)
    cov = cov_full[3:, 3:].copy()
    # a diameter error dD reads as d0 = -dD / 2 (the sphere is larger, the probe seems smaller)
    cov[0, 0] += (diameter_sigma / 2.0) ** 2
    return ProbeCalibration(float(nominal_radius), Rs, names, sol.x[3:].copy(), cov, sol.x[:3].copy(), r, s,
                            int(harmonics), source)


def sphere_directions(m: int = 49, max_polar: float = 90.0) -> np.ndarray:
    """m approach directions (unit, pointing into the sphere) spread over the cap within max_polar
    deg of the top: one at the pole, then rings of 8.  Down to the equator (90 deg) by default: on a
    smaller cap the sphere's centre height and the effective radius are correlated as in a bowl
    (60 deg: sigma(d0) 0.75 µm against 0.07 µm at 90 deg for 33 touches at 0.2 µm noise)."""
    dirs = [(0.0, 0.0, -1.0)]
    rings = max(1, (m - 1 + 7) // 8)
    k = 0
    for j in range(rings):
        th = math.radians(max_polar * (j + 1) / rings)
        n = min(8, m - 1 - k)
        for i in range(n):
            ph = 2 * math.pi * (i + 0.5 * (j % 2)) / n
            # contact normal n = (sin th cos ph, sin th sin ph, cos th); approach = -n
            dirs.append((-math.sin(th) * math.cos(ph), -math.sin(th) * math.sin(ph), -math.cos(th)))
        k += n
    return np.array(dirs[:m])


def probe_model_delta(approach, radius_error: float = 0.0, axial: float = 0.0, lobes: int = 3,
                      lobe_amplitude: float = 0.0, lobe_phase: float = 0.0) -> np.ndarray:
    """A probe's true delta(a) (mm) for simulation, written independently of the fit's basis:
    radius_error + axial a_z^2 + lobe_amplitude sin(theta) cos(lobes (phi - lobe_phase))."""
    a = np.atleast_2d(np.asarray(approach, float))
    phi = np.arctan2(a[:, 1], a[:, 0])
    return (radius_error + axial * a[:, 2] ** 2
            + lobe_amplitude * np.hypot(a[:, 0], a[:, 1]) * np.cos(lobes * (phi - lobe_phase)))


def virtual_sphere_touches(sphere_diameter: float, probe_radius: float, directions, *, centre=(0.0, 0.0, 0.0),
                           noise: float = 0.0, rng=None, **probe_model) -> tuple[np.ndarray, np.ndarray]:
    """Recorded probe centres (m, 3) mm and approaches for touches on a reference sphere: contact at
    the outward normal -a, the probe centre at R_s + probe_radius + delta(a) (probe_model_delta)
    from the sphere's centre, Gaussian noise along the approach."""
    A = np.atleast_2d(np.asarray(directions, float))
    A = A / np.linalg.norm(A, axis=1)[:, None]
    rng = np.random.default_rng(rng)
    rad = sphere_diameter / 2 + probe_radius + probe_model_delta(A, **probe_model)
    P = np.asarray(centre, float) - rad[:, None] * A
    if noise > 0:
        P = P + rng.normal(0.0, noise, len(P))[:, None] * A
    return P, A


def apply_probe_model(touches, **probe_model):
    """Bowl touches as a probe with the true delta(a) (probe_model_delta) records them, from touches
    simulated with the nominal probe: in a bowl the probe centre moves in by delta along a."""
    from dataclasses import replace
    d = probe_model_delta(touches.approach, **probe_model)
    return replace(touches, points=touches.points - d[:, None] * touches.approach)


def plot_calibration(cal: ProbeCalibration):
    """Figure: delta(a) against the approach azimuth for lateral and 45 deg approaches, with
    1-sigma bands, and the fit's residuals.  Returns a matplotlib Figure."""
    from matplotlib.figure import Figure
    fig = Figure(figsize=(10, 4))
    ax1, ax2 = fig.subplots(1, 2)
    phi = np.linspace(0, 360, 361)
    for pol, col in ((90.0, "tab:blue"), (45.0, "tab:orange")):
        th, ph = np.radians(pol), np.radians(phi)
        a = np.column_stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), -np.full_like(ph, np.cos(th))])
        d, s = cal.delta(a) * 1e3, cal.delta_sigma(a) * 1e3
        ax1.plot(phi, d, color=col, label=f"approach {pol:g} deg from the probe axis")
        ax1.fill_between(phi, d - s, d + s, color=col, alpha=0.2)
    ax1.set_xlabel("approach azimuth [deg]")
    ax1.set_ylabel("effective radius - nominal [µm]")
    ax1.legend(fontsize=8)
    ax1.set_title(f"effective radius {cal.effective_radius:.6f} mm, lobing p-v {cal.lobing_pv() * 1e3:.2f} µm",
                  fontsize=9)
    ax2.plot(cal.residuals * 1e3, "o", ms=3)
    ax2.set_xlabel("touch #")
    ax2.set_ylabel("residual [µm]")
    ax2.set_title("sphere fit residuals", fontsize=9)
    fig.tight_layout()
    return fig


def save_calibration(cal: ProbeCalibration, path):
    from .._io import atomic_write, dump_toml
    return atomic_write(path, "# mtcomp probe calibration (docs/workpiece-setting.md)\n" + dump_toml(cal.to_dict()))


def load_calibration(path) -> ProbeCalibration:
    """Read a probe.toml written by `save_calibration`; errors name the file and field."""
    from .._io import load_toml
    d = load_toml(path)
    if d.get("format") != "mtcomp-probe-calibration-1":
        raise InputError(f"not a probe calibration (format {d.get('format')!r}, expected "
                         "'mtcomp-probe-calibration-1')", path, field="format")
    try:
        p, s, dl = d["probe"], d["reference_sphere"], d["delta"]
        names = tuple(dl["names"])
        coef = np.asarray(dl["coefficients_mm"], float)
        cov = np.asarray(dl["covariance_mm2"], float)
        nominal, h, sig = float(p["nominal_radius_mm"]), int(p["harmonics"]), float(p["sigma_mm"])
        Rs, centre = float(s["radius_mm"]), np.asarray(s["centre_mm"], float)
    except KeyError as exc:
        raise InputError(f"missing key {exc}", path) from None
    except (TypeError, ValueError) as exc:
        raise InputError(f"bad value ({exc})", path) from None
    want = _basis(np.array([[0.0, 0.0, -1.0]]), h, "d_axial" in names)[1]
    if names != want or coef.shape != (len(names),) or cov.shape != (len(names),) * 2 \
            or not np.all(np.isfinite(coef)) or not np.all(np.isfinite(cov)):
        raise InputError(f"delta must hold {len(want)} coefficients {', '.join(want)} and their covariance", path,
                         field="delta")
    if not (nominal > 0 and abs(coef[0]) < 0.5 * nominal):
        raise InputError("the effective radius error must be well below the radius", path, field="delta")
    return ProbeCalibration(nominal, Rs, names, coef, cov, centre, np.zeros(0), sig, h, str(path))


#: What `fit` says when the probe is not calibrated (issue: the height moves 1:1 with the probe).
UNCALIBRATED_NOTE = ("probe not calibrated: dz (the height, from the bowl bottoms) carries the probe's effective "
                     "radius error one to one (1 µm of ball radius or uniform pre-travel is 1 µm of dz; bowls "
                     "cannot tell it from the cutter radius); run 'workpiece-setting probe-calibrate' on a "
                     "reference sphere and fit with --probe")


def corrected_touches(touches, cal: ProbeCalibration, nominal_radius: float, extra=None):
    """Touches with every recorded centre corrected by the calibration (`ProbeCalibration.correct`)
    to a probe of exactly nominal_radius (the plan's) without pre-travel; extra: (m,) mm added to
    delta (for sensitivities)."""
    from dataclasses import replace
    pts = cal.correct(touches.points, touches.approach, nominal_radius)
    if extra is not None:
        pts = pts + np.asarray(extra)[:, None] * touches.approach
    return replace(touches, points=pts)


def fit_with_probe(touches, plan, cal: ProbeCalibration | None, *, fit_kw=None, frame_kw=None):
    """(BowlFit, WorkpieceSettingEstimate) of the touches; with a calibration the touches are
    corrected first and the calibration's covariance is added to the pose covariance through the
    pose's sensitivity to each coefficient of delta(a) (one refit per coefficient; first order);
    without one the estimate carries UNCALIBRATED_NOTE among its warnings."""
    from dataclasses import replace
    from .bowl_fit import fit_bowls
    from .frame import frame_from_bowls
    fit_kw, frame_kw = dict(fit_kw or {}), dict(frame_kw or {})
    if cal is None:
        fit = fit_bowls(touches, plan.probe_radius, **fit_kw)
        est = frame_from_bowls(fit, plan, **frame_kw)
        return fit, replace(est, warnings=tuple(est.warnings) + (UNCALIBRATED_NOTE,))
    fit = fit_bowls(corrected_touches(touches, cal, plan.probe_radius), plan.probe_radius, **fit_kw)
    est = frame_from_bowls(fit, plan, **frame_kw)
    B, _ = _basis(touches.approach, cal.harmonics, cal.axial)
    h = 1e-4   # mm: well above rounding, far below where the chain bends
    S = np.empty((6, B.shape[1]))
    for j in range(B.shape[1]):
        fj = fit_bowls(corrected_touches(touches, cal, plan.probe_radius, h * B[:, j]), plan.probe_radius, **fit_kw)
        S[:, j] = (frame_from_bowls(fj, plan, **frame_kw).params - est.params) / h
    return fit, replace(est, cov=est.cov + S @ cal.cov @ S.T)
