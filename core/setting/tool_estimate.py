"""Estimating the tool setting error from measured grooves: closed forms and weighted least squares.

Measurement model (exact, see docs/tool-setting.md): a groove point programmed at face
coordinates y0 = (u, v, D) is measured at

    y = y0 + B_f (p(q, t) - p(q, 0)) + n_test + noise,      p(q, t) - p(q, 0) = R(q) t

with B_f the face basis (rows eu, ev, -normal), R(q) the tool frame orientation from
`mtcomp.kinematics.forward`, and n_test an unknown per-test offset of the microscope origin
(u, v) and of the surface (depth).  The model is linear in t, so the weighted least-squares
solution and its covariance are exact (no iteration, no linearisation error).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._io import InputError
from ..errors import rotation_matrix_xyz
from .tool_model import COMPONENTS, against_axes, errors_from_parameters, observable_parameters, parameter_jacobian
from .tool_plan import Plan, commands_for_points, repeated_grooves

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from matplotlib.figure import Figure

#: Warn when a component's 1-sigma exceeds this multiple of the coarsest measurement sigma: the
#: geometry then amplifies the instrument noise more than tenfold.
ILL_CONDITIONED_FACTOR = 10.0


# ---------------------------------------------------------------------------------------------
# Closed forms (our derivation; sign convention: t = real edge minus rotation centre, tool frame)

def b_depth_closed_form(theta2, theta3, d1, d2, d3):
    """(t_x, t_z) mm from the depths d1, d2, d3 (mm) of B grooves cut at B = 0, theta2, theta3 deg.

    Rigid rotation about Y of the edge offset (t_x, t_z): the edge height at B = theta is
    -sin(theta) t_x + cos(theta) t_z, so with the surface touched off at B = 0
        d(theta) - d(0) = sin(theta) t_x + (1 - cos(theta)) t_z,
    two equations in two unknowns (Cramer's rule)."""
    s2, s3 = np.sin(np.radians(theta2)), np.sin(np.radians(theta3))
    k2, k3 = 1 - np.cos(np.radians(theta2)), 1 - np.cos(np.radians(theta3))
    det = s2 * k3 - s3 * k2
    e2, e3 = np.subtract(d2, d1), np.subtract(d3, d1)
    return (e2 * k3 - e3 * k2) / det, (s2 * e3 - s3 * e2) / det


def b_depth_closed_form_sigma(theta2, theta3, sigma_depth):
    """1-sigma (mm) of (t_x, t_z) from `b_depth_closed_form` for independent depth noise sigma_depth."""
    s2, s3 = np.sin(np.radians(theta2)), np.sin(np.radians(theta3))
    k2, k3 = 1 - np.cos(np.radians(theta2)), 1 - np.cos(np.radians(theta3))
    det = s2 * k3 - s3 * k2
    gx = np.array([-(k3 - k2), k3, -k2]) / det      # d t_x / d (d1, d2, d3)
    gz = np.array([-(s2 - s3), -s3, s2]) / det      # d t_z / d (d1, d2, d3)
    return sigma_depth * np.linalg.norm(gx), sigma_depth * np.linalg.norm(gz)


def b_position_closed_form(theta2, theta3, w2, w3):
    """(t_x, t_z) mm from lateral groove shifts w2, w3 (mm) of B grooves at theta2, theta3 deg,
    each relative to the B = 0 groove after removing the programmed spacing:
        w(theta) = (cos(theta) - 1) t_x + sin(theta) t_z      (first order in t_z)."""
    s2, s3 = np.sin(np.radians(theta2)), np.sin(np.radians(theta3))
    c2, c3 = np.cos(np.radians(theta2)) - 1, np.cos(np.radians(theta3)) - 1
    det = c2 * s3 - c3 * s2
    return (w2 * s3 - w3 * s2) / det, (c2 * w3 - c3 * w2) / det


def paper_eq1_dx(theta2, theta3, d1, d2, D):
    """Paper 000 eq. (1) as printed: Delta X from depths d1 (at theta2), d2 (at theta3) and the
    depth of cut D.  It equals -t_x: the paper's (Delta X, Delta Z) is the correction (rotation
    centre minus edge), i.e. -(t_x, t_z) in our convention."""
    s2, s3 = np.sin(np.radians(theta2)), np.sin(np.radians(theta3))
    k2, k3 = 1 - np.cos(np.radians(theta2)), 1 - np.cos(np.radians(theta3))
    return (-(d1 - D) * k3 + (d2 - D) * k2) / (s2 * k3 - s3 * k2)


def paper_eq2_dz_printed(theta2, theta3, d1, d2, D):
    """Paper 000 eq. (2) exactly as printed (a misprint: it does not recover Delta Z)."""
    s2, s3 = np.sin(np.radians(theta2)), np.sin(np.radians(theta3))
    k2, k3 = 1 - np.cos(np.radians(theta2)), 1 - np.cos(np.radians(theta3))
    return ((d1 - D) * s2 + (d2 - D) * s3) / (s2 * k3 - s3 * k2)


def paper_eq2_dz_derived(theta2, theta3, d1, d2, D):
    """Eq. (2) re-derived in the paper's notation and sign (Delta Z = -t_z): the sines of the
    printed form are swapped and one sign is flipped:
        Delta Z = ((d1 - D) sin(theta3) - (d2 - D) sin(theta2)) / Det."""
    s2, s3 = np.sin(np.radians(theta2)), np.sin(np.radians(theta3))
    k2, k3 = 1 - np.cos(np.radians(theta2)), 1 - np.cos(np.radians(theta3))
    return ((d1 - D) * s3 - (d2 - D) * s2) / (s2 * k3 - s3 * k2)


def a_closed_form(delta_u, delta_v):
    """(t_x, t_y) mm from the shift (delta_u, delta_v) mm of the A = 180 pattern against the A = 0
    pattern on the side face (tool axis along X): the shift is (-2 t_y, 2 t_x)."""
    return delta_v / 2.0, -delta_u / 2.0


def c_closed_form(c_from, c_to, gap):
    """(t_x, t_y) mm from the gap (du, dv) mm at a triangle vertex between the end of the side cut
    at C = c_from and the start of the side cut at C = c_to (deg): gap = (Rz(c_to) - Rz(c_from)) t."""
    def rz(c):
        return rotation_matrix_xyz((0.0, 0.0, c))[:2, :2]
    return tuple(np.linalg.solve(rz(c_to) - rz(c_from), np.asarray(gap, float)))


def _mean_finite(values) -> float:
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    return float(np.mean(v)) if v.size else np.nan


def closed_forms(meas) -> dict[str, tuple]:
    """The closed-form estimates per test from a measurement set of the default pattern
    (averaging start and end points): {"A": (t_x, t_y), "C": (t_x, t_y), "B_depth": (t_x, t_z),
    "B_position": (t_x, t_z)}, mm.  Tests without the needed points are left out."""
    plan = meas.plan
    pt = {(p.groove, p.feature): p for p in meas.points}

    def get(g, f, attr):
        p = pt.get((g.id, f))
        if p is None and f == "start":
            # shared start point listed once for the first groove with the same start and angles
            for h in plan.grooves:
                if h.test == g.test and h.angles == g.angles and h.start == g.start and (h.id, f) in pt:
                    p = pt[(h.id, f)]
                    break
        return np.nan if p is None else getattr(p, attr)

    out = {}
    a = [g for g in plan.grooves if g.test == "A"]
    if a:
        angs = sorted({g.angles[0] for g in a})
        if angs == [0.0, 180.0] and all(g.angles[1] == 90.0 and g.angles[2] == 0.0 for g in a):
            du, dv = [], []
            for g0 in (g for g in a if g.angles[0] == angs[0]):
                g1 = next((g for g in a if g.angles[0] == angs[1] and g.start == g0.start and g.end == g0.end), None)
                if g1 is None:
                    continue
                for f in ("start", "end"):
                    du.append(get(g1, f, "u") - get(g0, f, "u"))
                    dv.append(get(g1, f, "v") - get(g0, f, "v"))
            if du and np.all(np.isfinite(du)):
                out["A"] = a_closed_form(float(np.mean(du)), float(np.mean(dv)))
    c = [g for g in plan.grooves if g.test == "C" and g.id not in repeated_grooves(plan)]
    if len(c) >= 2:
        ests = []
        for k in range(len(c)):
            g0, g1 = c[k - 1], c[k]
            if np.allclose(g0.end, g1.start, atol=1e-9):
                gap = (get(g1, "start", "u") - get(g0, "end", "u"), get(g1, "start", "v") - get(g0, "end", "v"))
                if np.all(np.isfinite(gap)):
                    ests.append(c_closed_form(g0.angles[2], g1.angles[2], gap))
        if ests:
            out["C"] = tuple(map(float, np.mean(ests, axis=0)))
    b = [g for g in plan.grooves if g.test == "B"]
    if len(b) >= 3 and b[0].angles[1] == 0:
        g1, g2, g3 = b[:3]
        th2, th3 = g2.angles[1], g3.angles[1]
        # measured depth minus the programmed depth's excess over the reference groove's
        # (designed plans cut inclined grooves deeper, tool_design.b_depth)
        dep = [_mean_finite([get(g, f, "depth") for f in ("start", "end")]) - (g.depth - g1.depth)
               for g in (g1, g2, g3)]
        if np.all(np.isfinite(dep)):
            out["B_depth"] = tuple(map(float, b_depth_closed_form(th2, th3, *dep)))
        lat = [_mean_finite([get(g, f, "u") for f in ("start", "end")]) - g.start[0] for g in (g1, g2, g3)]
        if np.all(np.isfinite(lat)):
            out["B_position"] = tuple(map(float, b_position_closed_form(th2, th3, lat[1] - lat[0], lat[2] - lat[0])))
    return out


# ---------------------------------------------------------------------------------------------
# General weighted least squares

@dataclass(frozen=True)
class Design:
    """The linear measurement model: rows y = y0 + J t + N n + noise (mm)."""
    y: np.ndarray          # (M,) measured
    y0: np.ndarray         # (M,) predicted with t = 0 and no offsets
    J: np.ndarray          # (M, P) d y / d parameters
    N: np.ndarray          # (M, K) nuisance indicator columns
    sigma: np.ndarray      # (M,) 1-sigma, mm
    labels: tuple          # (M,) "groove feature component"
    lines: tuple           # (M,) line in the source file (or None)
    nuisance_names: tuple  # (K,)
    point: np.ndarray = None   # (M,) index of the measured point of each row
    comp: np.ndarray = None    # (M,) 0 = u, 1 = v, 2 = depth
    tests: tuple = ()          # (P,) test of each measured point
    Y0: np.ndarray = None      # (P,3) nominal (u, v, depth) of each point
    JJ: np.ndarray = None      # (P,3,n) d(u, v, depth)/d parameters of each point
    names: tuple = COMPONENTS  # (n,) parameter names


def _rows_for(machine, plan: Plan, items, known=None, names=COMPONENTS):
    """Predicted values y0 (P,3) with every parameter zero and Jacobians (P,3,n) [component,
    parameter] of groove points for the parameters `names` (tool offset components and location
    errors, mm; see tool_model).  known: ErrorSet of errors already known (geometric, workpiece
    setting) that the prediction includes; its tool setting is ignored (that is what is estimated)."""
    from ..errors import ErrorSet
    base = ErrorSet()
    if known is not None and not (known.geometric.is_zero and known.workpiece.is_zero):
        base = ErrorSet(workpiece=known.workpiece, geometric=known.geometric)
    names = tuple(names)
    key = (machine, tuple(plan.grooves), tuple(plan.faces.items()), tuple(items), names)
    hit = _ROWS_CACHE.get(key) if base.is_zero else None
    if hit is not None:
        return hit
    pts, ang, bases, origins = [], [], [], []
    for gid, feat in items:
        g = plan.groove(gid)
        face = plan.face_of(g)
        pts.append(face.point(g.point(feat), g.depth)[0])
        ang.append(g.angles)
        bases.append(face.basis)
        origins.append(face.origin)
    q = commands_for_points(machine, np.array(pts), np.array(ang))
    # Exact: the edge is affine in t and in the rotary axes' position location errors.
    p0, dp = parameter_jacobian(machine, q, names, base)
    B = np.array(bases)
    J = np.einsum("nij,njk->nik", B, dp)
    y0 = np.einsum("nij,nj->ni", B, p0 - np.array(origins))
    out = (y0, J)
    for a in out:
        a.setflags(write=False)
    if base.is_zero:
        if len(_ROWS_CACHE) > 256:
            _ROWS_CACHE.clear()
        _ROWS_CACHE[key] = out
    return out


#: The model rows depend only on the machine and the plan (not on the data): memoised.
_ROWS_CACHE: dict = {}


def build_design(machine, meas, known=None, names=COMPONENTS) -> Design:
    """Stack every measured scalar (u, v, depth of each point) into the linear model for the
    parameters `names` (default: the tool offset only)."""
    from ..machine import load_machine
    m = load_machine(machine)
    plan = meas.plan
    items = [(p.groove, p.feature) for p in meas.points]
    if not items:
        raise InputError("no measured points", meas.source)
    Y0, JJ = _rows_for(m, plan, items, known, names)
    y, y0, J, sig, labels, lines, nkeys, pidx, comp = [], [], [], [], [], [], [], [], []
    for k, p in enumerate(meas.points):
        g = plan.groove(p.groove)
        for c, (name, val) in enumerate((("u", p.u), ("v", p.v), ("depth", p.depth))):
            if not np.isfinite(val):
                continue
            s = (p.sigma_depth or meas.sigma_depth) if c == 2 else (p.sigma_pos or meas.sigma_pos)
            y.append(val)
            y0.append(Y0[k, c])
            J.append(JJ[k, c])
            sig.append(s)
            labels.append(f"{p.groove} {p.feature} {name}")
            lines.append(p.line)
            nkeys.append(f"{g.test}:{name}")
            pidx.append(k)
            comp.append(c)
    big = [k for k, v in enumerate(y) if abs(v) > 1e6]
    if big:
        raise InputError(f"measured value {y[big[0]]!r} mm ({labels[big[0]]}) is beyond 1e6 mm", meas.source,
                         lines[big[0]])
    names = tuple(dict.fromkeys(nkeys))
    N = np.zeros((len(y), len(names)))
    for r, key in enumerate(nkeys):
        N[r, names.index(key)] = 1.0
    tests = tuple(plan.groove(p.groove).test for p in meas.points)
    return Design(np.array(y), np.array(y0), np.array(J), N, np.array(sig), tuple(labels), tuple(lines), names,
                  np.array(pidx), np.array(comp), tests, Y0, JJ, tuple(names))


def _model(d: Design, x: np.ndarray, extra: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Model values F (M,) and Jacobian A (M, n_par) at parameters x = [t, offsets, frame terms].

    Without frame terms the model is linear: F = y0 + [J N] x.  extra: (test, "rot" | "scale")
    per further column: a rotation phi (rad) of the test's microscope frame and / or a scale
    error k of its (u, v) readings (magnification) map the true (u, v) to (1 + k) Rot(phi) (u, v)
    (then the offset is added); exact here and solved by Gauss-Newton."""
    K = d.N.shape[1]
    P = d.J.shape[1]
    t = x[:P]
    F = d.y0 + d.J @ t + d.N @ x[P:P + K]
    A = np.hstack([d.J, d.N, np.zeros((d.y.size, len(extra)))])
    col = {e: P + K + j for j, e in enumerate(extra)}
    for test in dict.fromkeys(tt for tt, _ in extra):
        jr, js = col.get((test, "rot")), col.get((test, "scale"))
        phi = x[jr] if jr is not None else 0.0
        k = x[js] if js is not None else 0.0
        c, s_ = np.cos(phi), np.sin(phi)
        pts = np.array([n for n, tt in enumerate(d.tests) if tt == test])
        uv = d.Y0[pts, :2] + d.JJ[pts, :2] @ t                      # true (u, v) of the points
        Juv = d.JJ[pts, :2]                                         # (p, 2, n)
        rot = np.array([[c, -s_], [s_, c]])
        drot = np.array([[-s_, -c], [c, -s_]])
        ruv, duv = uv @ rot.T, uv @ drot.T
        rJ = np.einsum("ij,pjk->pik", rot, Juv)
        where = {int(n): i for i, n in enumerate(pts)}
        for r in np.nonzero(d.comp < 2)[0]:
            i = where.get(int(d.point[r]))
            if i is None:
                continue
            cc = d.comp[r]
            F[r] += (1 + k) * ruv[i, cc] - uv[i, cc]
            A[r, :P] = (1 + k) * rJ[i, cc]
            if jr is not None:
                A[r, jr] = (1 + k) * duv[i, cc]
            if js is not None:
                A[r, js] = ruv[i, cc]
    return F, A


@dataclass(frozen=True)
class ToolSettingEstimate:
    """Result of `estimate`: the tool setting error and the rotary axes' location errors with
    their covariance, the setting error against each rotary axis, and the fit diagnostics.

    tool_setting: ToolSetting (mm, tool frame).  cov: (3,3) mm^2 of t.  parameters, values,
    param_cov: every estimated parameter (t_x, t_y, t_z, then location errors such as EX0C), mm,
    and their joint covariance, mm^2.  location: {name: mm} of the estimated location errors
    (increments over `known`).  against: {axis: (component names, values mm, cov mm^2)}, the edge
    offset from each tested axis line in the tool frame (paper 000's "setting errors against A /
    C").  unobservable: {name: reason} of candidate parameters the plan cannot separate (held at
    their known value).  nuisance: per-test offsets of the microscope origin / surface (mm).
    residuals: (M,) mm, measured minus fitted, with labels; chi2 and dof of the weighted fit."""
    tool_setting: object
    cov: np.ndarray
    nuisance: dict
    residuals: np.ndarray
    normalized: np.ndarray
    labels: tuple
    lines: tuple
    chi2: float
    dof: int
    warnings: tuple = ()
    closed: dict = field(default_factory=dict)
    source: str = ""
    nuisance_sigma: dict = field(default_factory=dict)
    parameters: tuple = COMPONENTS
    values: np.ndarray = None
    param_cov: np.ndarray = None
    against: dict = field(default_factory=dict)
    unobservable: dict = field(default_factory=dict)

    @property
    def offset(self) -> np.ndarray:
        return np.asarray(self.tool_setting.offset)

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))

    @property
    def location(self) -> dict:
        return {n: float(v) for n, v in zip(self.parameters, self._values) if n not in COMPONENTS}

    @property
    def location_sigma(self) -> dict:
        s = np.sqrt(np.diag(self._param_cov))
        return {n: float(v) for n, v in zip(self.parameters, s) if n not in COMPONENTS}

    @property
    def _values(self) -> np.ndarray:
        return self.offset if self.values is None else np.asarray(self.values)

    @property
    def _param_cov(self) -> np.ndarray:
        return self.cov if self.param_cov is None else np.asarray(self.param_cov)

    def mahalanobis2(self, true_offset) -> float:
        """Squared Mahalanobis distance of the estimate from a true offset (mm) under `cov`."""
        d = self.offset - np.asarray(true_offset, float)
        return float(d @ np.linalg.solve(self.cov, d))

    def mahalanobis2_all(self, true_values) -> float:
        """Squared Mahalanobis distance of every estimated parameter from true values (mm, in
        the order of `parameters`) under `param_cov`."""
        d = self._values - np.asarray(true_values, float)
        return float(d @ np.linalg.solve(self._param_cov, d))

    def errors(self, known=None):
        """An ErrorSet with this tool setting and the estimated location errors (for `retarget`
        and the errors TOML), on top of the geometric and workpiece setting errors of `known`."""
        return errors_from_parameters(self.parameters, self._values, known)

    def summary(self) -> str:
        um = 1e3
        lines = ["Tool setting error (edge minus nominal rotation centre, tool frame), weighted least squares:"]
        for k, name in enumerate(COMPONENTS):
            lines.append(f"  {name} = {self.offset[k] * um:+10.3f} µm  ± {self.sigma[k] * um:.3f} µm (1σ)")
        corr = self.cov / np.outer(self.sigma, self.sigma)
        lines.append("  correlation: " + "; ".join(f"{COMPONENTS[i]}/{COMPONENTS[j]} {corr[i, j]:+.2f}"
                                                 for i, j in ((0, 1), (0, 2), (1, 2))))
        loc, ls = self.location, self.location_sigma
        if loc:
            lines.append("Rotary axis location errors (ISO 230-1), estimated with it:")
            for n, v in loc.items():
                lines.append(f"  {n} = {v * um:+10.3f} µm  ± {ls[n] * um:.3f} µm (1σ)")
        for n, why in self.unobservable.items():
            lines.append(f"  {n} not estimated: {why}")
        if self.against:
            lines.append("Setting error against each rotary axis (edge minus axis line, tool frame; paper 000):")
            for ax, (comp, val, cv) in self.against.items():
                sg = np.sqrt(np.diag(cv))
                lines.append(f"  against {ax}: " + ", ".join(
                    f"{c} {v * um:+.3f} ± {s * um:.3f} µm" for c, v, s in zip(comp, val, sg))
                    + f" (correlation {cv[0, 1] / (sg[0] * sg[1]):+.2f})")
        rms = np.sqrt(np.mean(self.residuals ** 2)) * um if self.residuals.size else float("nan")
        worst = int(np.argmax(np.abs(self.normalized))) if self.normalized.size else None
        lines.append(f"  fit: {self.residuals.size} values, chi2 = {self.chi2:.2f} on {self.dof} dof, "
                     f"residual rms {rms:.3f} µm")
        if worst is not None:
            where = f" (line {self.lines[worst]})" if self.lines[worst] else ""
            lines.append(f"  largest normalised residual: {self.normalized[worst]:+.2f} at "
                         f"{self.labels[worst]}{where}")
        if "drift:x" in self.nuisance:
            dv = [self.nuisance[k] * um for k in DRIFT_NAMES]
            ds = [self.nuisance_sigma.get(k, np.nan) * um for k in DRIFT_NAMES]
            lines.append("  drift over the procedure (tool against workpiece, workpiece frame, from the repeated "
                         "groove): " + ", ".join(f"{c} {v:+.3f} ± {e:.3f} µm" for c, v, e in zip("xyz", dv, ds)))
        scales = [k for k in self.nuisance if k.endswith(":scale")]
        if scales:
            lines.append("  microscope scale error: " + "; ".join(
                f"{k[:-6]} test {self.nuisance[k] * 1e6:+.0f} ± {self.nuisance_sigma.get(k, np.nan) * 1e6:.0f} ppm"
                for k in scales))
        rots = [k for k in self.nuisance if k.endswith(":rot")]
        if rots:
            lines.append("  microscope frame rotation: " + "; ".join(
                f"{k[:-4]} test {self.nuisance[k] * 1e3:+.3f} +- {self.nuisance_sigma.get(k, np.nan) * 1e3:.3f} mrad"
                for k in rots))
        if self.closed:
            lines.append("  closed forms (tool offset only, no location errors): " + "; ".join(
                f"{k} ({', '.join(f'{x * um:+.2f}' for x in v)}) µm" for k, v in self.closed.items()))
        for w in self.warnings:
            lines.append(f"  WARNING: {w}")
        return "\n".join(lines)


def _location_names(m, plan, locations, known) -> tuple[tuple, dict]:
    """Location error names to estimate and the unobservable candidates with their reasons."""
    from .tool_model import location_candidates
    if locations is None or locations == () or locations == "none":
        return (), {}
    if locations == "auto":
        obs = observable_parameters(m, plan, base=known)
        return tuple(n for n in obs.estimated if n not in COMPONENTS), obs.unobservable
    names = tuple(locations)
    cand = location_candidates(m)
    bad = [n for n in names if n not in cand]
    if bad:
        raise InputError(f"cannot estimate {', '.join(bad)}: the grooving model takes the position location "
                         f"errors of the tool-side rotary axes, {', '.join(cand) or 'none on this machine'}",
                         field="locations")
    obs = observable_parameters(m, plan, candidates=names, base=known)
    lost = [n for n in names if n not in obs.estimated]
    if lost:
        raise InputError("singular geometry: the plan does not separate " + "; ".join(
            f"{n} ({obs.unobservable[n]})" for n in lost), field="locations")
    return names, {}


DRIFT_NAMES = ("drift:x", "drift:y", "drift:z")


def with_drift(d: Design, plan) -> Design:
    """The design with a linear drift of the tool against the workpiece over the procedure
    (workpiece frame, mm over the whole cutting order, `tool_plan.cutting_times`) as three more
    nuisance columns: a groove point cut at tau moves by B_f (tau * drift).  A repeated groove
    (`tool_plan.repeated_grooves`) makes it observable: its only difference from the first cut is
    the drift between them."""
    from dataclasses import replace
    from .tool_plan import cutting_times
    tau = cutting_times(plan)
    cols = np.zeros((d.y.size, 3))
    for r in range(d.y.size):
        gid = d.labels[r].split(" ")[0]
        g = plan.groove(gid)
        cols[r] = tau[gid] * plan.face_of(g).basis[d.comp[r]]
    return replace(d, N=np.hstack([d.N, cols]), nuisance_names=d.nuisance_names + DRIFT_NAMES)


def estimate(machine, meas, closed: bool = True, fit_rotation: bool = False, known=None,
             locations="auto", fit_scale: bool = False, drift="auto") -> ToolSettingEstimate:
    """Weighted least-squares tool setting error and rotary-axis location errors from a
    GroovingMeasurements (any grooves, any angles), with covariance (known measurement sigmas,
    not rescaled by chi2), residuals, the setting error against each tested axis, closed-form
    estimates for comparison and warnings.  Raises InputError on singular geometry (a parameter
    the measured grooves cannot see).

    locations: "auto" (default) estimates every position location error of the tool-side rotary
    axes that the plan makes observable (tool_model.observable_parameters; on robonano-ui with the
    default plan EX0C, EY0C, EZ0A), () the tool offset only, or a tuple of names.
    fit_rotation: also estimate a rotation of the microscope frame per test (rad, in `nuisance`
    as "<test>:rot"), for sheets measured without aligning the microscope to the face axes.
    fit_scale: also estimate a scale error of the microscope's (u, v) readings per test
    (magnification, in `nuisance` as "<test>:scale", relative), seen from the programmed groove
    lengths and spacings; it costs precision on t (mostly t_z, from the B grooves' positions).
    known: ErrorSet of already known geometric / workpiece setting errors, included in the
    model (estimated location errors are increments over its values).
    drift: "auto" (default) fits a linear drift of the tool against the workpiece over the
    procedure when the plan repeats a groove (`with_drift`; reported among the nuisance values as
    drift:x, drift:y, drift:z, mm), True always (grooves at equal angles in other directions see
    it too, less well), None never."""
    from ..errors import ToolSetting
    from ..machine import load_machine
    from scipy import stats
    m = load_machine(machine)
    locs, unobs = _location_names(m, meas.plan, locations, known)
    names = COMPONENTS + locs
    P = len(names)
    d = build_design(m, meas, known, names)
    if drift is True or (drift == "auto" and repeated_grooves(meas.plan)):
        d = with_drift(d, meas.plan)
    frame_tests = tuple(t for t in dict.fromkeys(d.tests)
                        if f"{t}:u" in d.nuisance_names and f"{t}:v" in d.nuisance_names)
    rot_tests = tuple((t, "rot") for t in frame_tests if fit_rotation)
    rot_tests += tuple((t, "scale") for t in frame_tests if fit_scale)
    n_par = P + d.N.shape[1] + len(rot_tests)
    if d.y.size < n_par:
        raise InputError(f"{d.y.size} measured values cannot determine {n_par} unknowns ({P} setting and "
                         f"location parameters and {n_par - P} per-test offsets/rotations): measure more grooves",
                         meas.source)
    try:
        return _estimate(m, meas, d, names, locs, unobs, rot_tests, n_par, closed, known)
    except np.linalg.LinAlgError as exc:
        # SVD failure: values or weights outside what the geometry can take (huge or tiny)
        raise InputError(f"the least-squares fit failed ({exc}): check the measured values and sigmas for "
                         "extreme numbers", meas.source) from None


def _estimate(m, meas, d, names, locs, unobs, rot_tests, n_par, closed, known):
    from ..errors import ToolSetting
    from scipy import stats
    P = len(names)
    x = np.zeros(n_par)
    # Gauss-Newton; the model is linear without rotations, so one step is then exact.
    for it in range(30):
        F, A = _model(d, x, rot_tests)
        Aw = A / d.sigma[:, None]
        scale = np.linalg.norm(Aw, axis=0)
        scale[scale == 0] = 1.0
        U, s, Vt = np.linalg.svd(Aw / scale, full_matrices=False)
        if it == 0:
            _check_singular(s, Vt, meas.source, names)
        dx = (Vt.T @ ((U.T @ ((d.y - F) / d.sigma)) / s)) / scale
        x = x + dx
        if not rot_tests or np.max(np.abs(dx)) < 1e-12:   # mm and rad
            break
    else:
        raise InputError("the fit with microscope frame rotations / scales did not converge", meas.source)
    fit, A = _model(d, x, rot_tests)
    Aw = A / d.sigma[:, None]
    scale = np.linalg.norm(Aw, axis=0)
    scale[scale == 0] = 1.0
    U, s, Vt = np.linalg.svd(Aw / scale, full_matrices=False)
    cov_full = (Vt.T / s ** 2) @ Vt / np.outer(scale, scale)
    t = x[:3]
    cov = cov_full[:3, :3]
    res = d.y - fit
    norm = res / d.sigma
    dof = int(d.y.size - n_par)
    chi2 = float(norm @ norm)
    warnings = []
    sig = np.sqrt(np.diag(cov_full))[:P]
    floor = float(np.max(d.sigma))
    for k, name in enumerate(names):
        if sig[k] > ILL_CONDITIONED_FACTOR * floor:
            why = ""
            if name == "t_z":
                why = (": depths carry t_z only to second order (1 - cos theta) at small B inclinations; "
                       "measure the lateral positions of the B grooves or add grooves at larger |B|")
            warnings.append(f"ill-conditioned: {name} has sigma {sig[k] * 1e3:.2f} µm, "
                            f"{sig[k] / floor:.0f}x the measurement noise{why}")
    if dof > 0 and stats.chi2.sf(chi2, dof) < 1e-3:
        worst = int(np.argmax(np.abs(norm)))
        where = f" line {d.lines[worst]}" if d.lines[worst] else ""
        hint = "" if locs else "; rotary axis location errors not estimated (locations=()) can cause this"
        warnings.append(f"residuals exceed the stated noise (chi2 {chi2:.1f} on {dof} dof); check{where} "
                        f"({d.labels[worst]}, {norm[worst]:+.1f} sigma) or the sigmas{hint}")
    cf = {}
    if closed:
        try:
            cf = closed_forms(meas)
        except (ValueError, KeyError, np.linalg.LinAlgError):
            cf = {}
    nnames = d.nuisance_names + tuple(f"{t_}:{kind}" for t_, kind in rot_tests)
    nuis_sig = np.sqrt(np.diag(cov_full))[P:]
    pcov = cov_full[:P, :P]
    try:
        against = against_axes(m, meas.plan, names, x[:P], pcov, known)
    except (ValueError, KeyError, np.linalg.LinAlgError):
        against = {}
    return ToolSettingEstimate(ToolSetting(tuple(t)), cov, dict(zip(nnames, x[P:])), res, norm,
                               d.labels, d.lines, chi2, dof, tuple(warnings), cf, meas.source,
                               dict(zip(nnames, nuis_sig)), names, x[:P].copy(), pcov, against, unobs)


def _check_singular(s, Vt, source, names=COMPONENTS):
    tol = s[0] * 1e-9
    if s[-1] <= tol:
        null = Vt[s <= tol]
        lost = [names[k] for k in range(len(names)) if np.max(np.abs(null[:, k])) > 1e-3]
        hint = ""
        if "t_z" in lost:
            hint = " (t_z needs B grooves at two or more inclinations, at least one non-zero)"
        elif lost:
            hint = (" (t_x and t_y need the A pattern at A = 0 and 180, or C grooves at two or more C angles; "
                    "a location error needs the test of its axis)")
        what = ", ".join(lost) if lost else "the per-test offsets or rotations (too few points in a test)"
        raise InputError(f"singular geometry: the measured grooves do not determine {what}{hint}", source)

# ---------------------------------------------------------------------------------------------
# Which extra groove helps most

@dataclass(frozen=True)
class GrooveSuggestion:
    """A candidate extra groove and the expected 1-sigma of t (mm) with it added."""
    groove: object
    sigma: np.ndarray
    trace_reduction: float   # reduction of trace(cov) in µm²


def _information(machine, plan, items, sig_pos, sig_depth, nuis_names, names=COMPONENTS):
    _, J = _rows_for(machine, plan, items, names=names)
    rows = []
    for k, (gid, _f) in enumerate(items):
        g = plan.groove(gid)
        for c, name in enumerate(("u", "v", "depth")):
            s = sig_depth if c == 2 else sig_pos
            r = np.zeros(len(nuis_names))
            key = f"{g.test}:{name}"
            if key in nuis_names:
                r[nuis_names.index(key)] = 1.0
            rows.append(np.concatenate([J[k, c], r]) / s)
    return np.array(rows)


def suggest_grooves(machine, meas, candidates=None, top: int = 3, names=None) -> list[GrooveSuggestion]:
    """Rank candidate extra grooves by the expected reduction of trace(cov t), measured like the
    others (start and end points, u, v and depth, default sigmas), with the parameters `names`
    estimated (default: those `estimate` takes by default, the observable ones).  Candidates default to B
    grooves at +-5 .. +-45 deg and C sides at 60, 180, 300 deg that the plan lacks."""
    from dataclasses import replace
    from ..machine import load_machine
    from .tool_plan import Groove
    m = load_machine(machine)
    plan = meas.plan
    if names is None:
        names = COMPONENTS + _location_names(m, plan, "auto", None)[0]
    d = build_design(m, meas, names=names)
    nuis = list(d.nuisance_names)
    A = np.hstack([d.J, d.N]) / d.sigma[:, None]
    info0 = A.T @ A
    if candidates is None:
        candidates = []
        b = [g for g in plan.grooves if g.test == "B"]
        if b:
            have = {g.angles[1] for g in b}
            last = b[-1]
            from .tool_design import MIN_FLANK
            lim = plan.options.tip_angle / 2 - MIN_FLANK    # a flatter flank cuts no second edge
            for th in (5, -5, 10, -10, 15, -15, 20, -20, 25, -25, 30, -30):
                if float(th) not in have and abs(th) <= lim:
                    du = plan.options.spacing if plan.options.spacing else 2.0
                    candidates.append(replace(last, id=f"B{th:+g}*", angles=(0.0, float(th), 0.0),
                                              start=(last.start[0] + du, last.start[1]),
                                              end=(last.end[0] + du, last.end[1])))
        c = [g for g in plan.grooves if g.test == "C"]
        if c:
            have = {g.angles[2] % 360 for g in c}
            for cc in (60.0, 180.0, 300.0):
                if cc not in have:
                    candidates.append(Groove(f"C{cc:g}*", "C", c[0].face, (0.0, 0.0, cc), c[0].start,
                                             tuple(np.add(c[0].start, 3.0 * np.array(
                                                 [-np.sin(np.radians(cc)), np.cos(np.radians(cc))]))),
                                             c[0].depth))
    base_cov = np.linalg.pinv(info0)[:3, :3]
    out = []
    for cand in candidates:
        p2 = Plan(plan.machine, plan.options, plan.grooves + (cand,), plan.faces)
        rows = _information(m, p2, [(cand.id, "start"), (cand.id, "end")], meas.sigma_pos, meas.sigma_depth, nuis,
                            names)
        info = info0 + rows.T @ rows
        try:
            cov = np.linalg.inv(info)[:3, :3]
        except np.linalg.LinAlgError:
            cov = np.linalg.pinv(info)[:3, :3]
        out.append(GrooveSuggestion(cand, np.sqrt(np.diag(cov)), float(np.trace(base_cov - cov)) * 1e6))
    out.sort(key=lambda s: -s.trace_reduction)
    return out[:top]


# ---------------------------------------------------------------------------------------------
# Compensation outputs and report

def write_errors(est: ToolSettingEstimate, path, source: str = "", known=None) -> object:
    """Write the errors TOML (docs/errors-format.md) that `mtcomp compensate` reads: the tool
    setting and the estimated location errors (on top of `known`, see `estimate`), with the
    1-sigma of every estimated parameter recorded under [uncertainty]."""
    from ..errors import save_errors
    meta = {"produced_by": "mtcomp tool-setting estimate", "method": "weighted least squares (paper 000 grooving)"}
    if source:
        meta["measurements"] = source
    if est.unobservable:
        meta["not_estimated"] = "; ".join(f"{k}: {v}" for k, v in est.unobservable.items())
    unc = {"tool_setting.offset": [float(x) for x in est.sigma]}
    unc.update({f"geometric.location.{k}": v for k, v in est.location_sigma.items()})
    return save_errors(est.errors(known), path, uncertainty=unc, meta=meta)


def predicted_residuals(machine, plan: Plan, est: ToolSettingEstimate) -> dict:
    """1-sigma (mm) of the Table 1 distances after compensation, from the estimate's covariance:
    the residual parameter error (x - x_hat ~ N(0, param_cov)) moves the grooves linearly."""
    from ..machine import load_machine
    m = load_machine(machine)
    names = est.parameters
    cov = est._param_cov
    out = {}
    a = [g for g in plan.grooves if g.test == "A"]
    angs = sorted({g.angles[0] for g in a})
    if len(angs) == 2:
        g0 = next(g for g in a if g.angles[0] == angs[0])
        g1 = next(g for g in a if g.angles[0] == angs[1] and g.start == g0.start)
        _, J = _rows_for(m, plan, [(g0.id, "start"), (g1.id, "start")], names=names)
        D = J[1, :2] - J[0, :2]
        out["A"] = tuple(np.sqrt(np.diag(D @ cov @ D.T)))
    rep = repeated_grooves(plan)        # a drift repeat is no side of the triangle
    c = [g for g in plan.grooves if g.test == "C" and g.id not in rep]
    if len(c) >= 2:
        _, J = _rows_for(m, plan, [(c[0].id, "start"), (c[-1].id, "end")], names=names)
        D = J[0, :2] - J[1, :2]
        out["C"] = tuple(np.sqrt(np.diag(D @ cov @ D.T)))
    return out


def report_text(machine, meas, est: ToolSettingEstimate) -> str:
    """Plain-text report: estimate +- sigma, fit, closed forms, predicted residual after
    compensation, and the groove that would help most."""
    lines = [f"mtcomp tool-setting report: machine {meas.plan.machine}, measurements {meas.source}", "",
             est.summary(), ""]
    pr = predicted_residuals(machine, meas.plan, est)
    if pr:
        lines.append("Predicted groove distances after compensation (1 sigma, from the covariance):")
        for k, (du, dv) in pr.items():
            lines.append(f"  {k} test: du {du * 1e3:.3f} µm, dv {dv * 1e3:.3f} µm")
        lines.append("")
    sug = suggest_grooves(machine, meas, names=est.parameters)
    if sug:
        lines.append("Extra groove that would help most (expected 1 sigma of t_x, t_y, t_z with it):")
        for s in sug:
            g = s.groove
            lines.append(f"  {g.id.rstrip('*')} at A{g.angles[0]:g} B{g.angles[1]:g} C{g.angles[2]:g}: "
                         f"({', '.join(f'{x * 1e3:.3f}' for x in s.sigma)}) µm, "
                         f"trace(cov) -{s.trace_reduction:.3f} µm²")
    return "\n".join(lines) + "\n"


def plot_report(machine, meas, est: ToolSettingEstimate, path=None) -> Figure:
    """Report figure (a Figure; PNG at `path` only when given): every estimated parameter with 3-sigma bars, normalised residuals, and
    the predicted grooves before/after compensation on each face."""
    from matplotlib.figure import Figure
    from pathlib import Path
    from .._io import save_figure
    from .tool import cut_grooves
    m = machine
    plan = meas.plan
    fig = Figure(figsize=(13, 8))
    ax1 = fig.add_subplot(2, 2, 1)
    vals, sig = est._values * 1e3, np.sqrt(np.diag(est._param_cov)) * 1e3
    x = np.arange(len(vals))
    ax1.bar(x, vals, color=["tab:blue"] * 3 + ["tab:orange"] * (len(vals) - 3), alpha=0.7)
    ax1.errorbar(x, vals, yerr=3 * sig, fmt="none", ecolor="k", capsize=6, label="3σ")
    ax1.set_xticks(x, est.parameters)
    ax1.set_ylabel("µm")
    ax1.set_title("tool setting (tool frame) and rotary axis location errors", fontsize=9)
    for k in range(len(vals)):
        ax1.text(k, vals[k], f"{vals[k]:+.2f}\n±{sig[k]:.2f}", ha="center", va="bottom", fontsize=8)
    ax1.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    ax2 = fig.add_subplot(2, 2, 2)
    ax2.plot(est.normalized, "o", ms=3)
    ax2.axhline(3, color="r", lw=0.6)
    ax2.axhline(-3, color="r", lw=0.6)
    ax2.set_ylabel("residual / σ")
    ax2.set_xlabel("measured value #")
    ax2.set_title(f"normalised residuals (χ² {est.chi2:.1f} on {est.dof} dof)", fontsize=9)
    before = cut_grooves(m, plan, est.errors())
    after = cut_grooves(m, plan, est.errors(), compensation=est.errors())
    faces = [f for f in plan.faces if any(g.face == f for g in plan.grooves)]
    for i, fname in enumerate(faces[:2]):
        ax = fig.add_subplot(2, 2, 3 + i)
        for g in (g for g in plan.grooves if g.face == fname):
            ax.plot(*zip(g.start, g.end), color="0.6", lw=3, alpha=0.5)
        for cs, col, lab in ((before, "tab:red", "as cut (estimated errors)"), (after, "tab:green", "compensated")):
            first = True
            for c in (c for c in cs if c.groove.face == fname):
                ax.plot(*zip(c.start, c.end), color=col, lw=1, label=lab if first else None)
                first = False
        ax.set_aspect("equal")
        ax.set_title(f"{fname} face: nominal (grey), predicted grooves", fontsize=9)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
        ax.set_xlabel("u [mm]")
        ax.set_ylabel("v [mm]")
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path, dpi=100)
    return fig
