"""Location errors of a rotary axis (ISO 230-7) from a sphere probed at several angles of the axis.

A precision sphere sits on the rotary table off its axis.  At each angle of the tested axis (the
other rotary axes at fixed angles) the probe finds the sphere's centre (a sphere fit of its
touches, e.g. `mtcomp.setting.bowl_fit.fit_sphere`); the reading is the linear axes' position
that puts the tool point on it.  Turning the axis carries the centre on a circle whose centre and
plane are the axis line: its two position location errors perpendicular to the axis (EX0C, EY0C
for a C axis along Z; EX0B, EZ0B for B along Y) and its two tilts (EA0C, EB0C; EA0B, EC0B).

The model is the machine's own forward model (`mtcomp.kinematics.forward`) with the candidate
location errors; the sphere's position on the table is unknown (estimated with them).  The zero
position error (EC0C for C) is not separable from the sphere's angular position and is not
estimated; the position error along the axis changes nothing.  Position errors are in mm at the
axis' nominal location point, tilts in rad.  Gauss-Newton with a numerical Jacobian (the tilts
enter nonlinearly; it converges in a few steps from zero).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._io import InputError

__all__ = ["SpherePlan", "plan_sphere", "default_parameters", "centre_readings", "simulate_readings",
           "RotaryEstimate", "estimate_rotary", "read_readings_csv", "sphere_from_readings"]

_LIN = "XYZ"
_ANG = "ABC"


@dataclass(frozen=True)
class SpherePlan:
    """axis: the tested rotary axis; angles: its angles (deg) at which the sphere is probed;
    sphere: nominal sphere centre in the workpiece frame (mm, at all rotary axes 0); fixed: the
    other rotary axes' angles (deg) during the test."""
    axis: str
    angles: tuple
    sphere: tuple
    fixed: dict = field(default_factory=dict)


def default_parameters(machine, axis: str) -> tuple[str, ...]:
    """The two position errors and the two tilts perpendicular to `axis` (ISO 230-1 names)."""
    ax = machine.axis(axis)
    u = np.abs(np.asarray(ax.direction, float))
    perp = [k for k in range(3) if u[k] < 0.9]
    return tuple(f"E{_LIN[k]}0{axis}" for k in perp) + tuple(f"E{_ANG[k]}0{axis}" for k in perp)


def plan_sphere(machine, axis: str, radius: float = 40.0, height: float = 20.0, n: int = 8,
                fixed: dict | None = None) -> SpherePlan:
    """A sphere `radius` mm from the axis and `height` mm above the table (along the workpiece
    z), probed at n angles spread over the axis' travel (a full turn when it allows, ends
    excluded)."""
    from ..machine import load_machine
    m = load_machine(machine)
    ax = m.axis(axis)
    if not ax.is_rotary:
        raise InputError(f"axis {axis} is not a rotary axis", field="axis")
    if ax.side != "workpiece":
        raise InputError(f"axis {axis} of {m.name} carries the tool: a sphere on the table does not turn with "
                         "it; its location errors come from the grooving plan ('mtcomp tool-setting estimate', "
                         "docs/tool-setting.md)", field="axis")
    if n < 3:
        raise InputError(f"at least 3 angles are needed to see a circle, got {n}", field="n")
    lo, hi = ax.limits
    if hi - lo >= 360.0:
        angles = np.arange(n) * 360.0 / n
    else:
        angles = np.linspace(lo, hi, n + 2)[1:-1]
    u = np.asarray(ax.direction, float)
    # the sphere off the axis: along the workpiece x unless the axis lies along x
    off = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    s = np.asarray(ax.location, float) + radius * off + height * np.array([0.0, 0.0, 1.0])
    return SpherePlan(axis, tuple(float(a) for a in angles), tuple(float(v) for v in s), dict(fixed or {}))


def _commands(machine, plan: SpherePlan) -> np.ndarray:
    q = np.zeros((len(plan.angles), machine.n_axes))
    for name, v in plan.fixed.items():
        q[:, machine.index(name)] = v
    q[:, machine.index(plan.axis)] = plan.angles
    return q


def centre_readings(machine, plan: SpherePlan, errors=None, sphere=None) -> np.ndarray:
    """Linear axis readings (K, 3) mm at which the tool point sits on the sphere centre, at each
    angle of the plan, on the machine with `errors` (ErrorSet or None).  sphere: true centre
    (workpiece frame, mm; default the plan's)."""
    from ..kinematics import forward
    q = _commands(machine, plan)
    s = np.asarray(plan.sphere if sphere is None else sphere, float)
    lin = [machine.index(a) for a in _LIN]
    p0 = forward(machine, q, errors).p
    M = np.empty((len(q), 3, 3))
    for j, i in enumerate(lin):
        dq = q.copy()
        dq[:, i] += 1.0
        M[:, :, j] = forward(machine, dq, errors).p - p0
    # exact: for fixed rotary angles the tool point is affine in the linear axes
    return np.linalg.solve(M, (s - p0)[..., None])[..., 0]


def simulate_readings(machine, plan: SpherePlan, errors, sigma: float = 0.0005, seed=None, sphere=None) -> np.ndarray:
    """`centre_readings` with Gaussian noise of `sigma` mm per coordinate (the sphere fit's)."""
    rng = np.random.default_rng(seed)
    r = centre_readings(machine, plan, errors, sphere)
    return r + rng.normal(0.0, sigma, r.shape)


@dataclass(frozen=True)
class RotaryEstimate:
    """Location errors of one rotary axis: names, values (mm for positions, rad for tilts), cov,
    the sphere's fitted position (mm), residuals (K, 3) mm, chi2 and dof."""
    axis: str
    names: tuple
    values: np.ndarray
    cov: np.ndarray
    sphere: np.ndarray
    residuals: np.ndarray
    chi2: float
    dof: int

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))

    @property
    def location(self) -> dict:
        return {n: float(v) for n, v in zip(self.names, self.values)}

    def errors(self, known=None):
        """ErrorSet with these location errors added to `known`'s."""
        from ..errors import ErrorSet, GeometricErrors
        loc = dict(known.geometric.location) if known is not None else {}
        for n, v in self.location.items():
            loc[n] = loc.get(n, 0.0) + v
        geo = GeometricErrors(tables=known.geometric.tables if known is not None else {}, location=loc)
        if known is None:
            return ErrorSet(geometric=geo)
        return ErrorSet(tool=known.tool, workpiece=known.workpiece, geometric=geo)

    def summary(self) -> str:
        lines = [f"Location errors of axis {self.axis} (ISO 230-7, sphere probed at {len(self.residuals)} angles):"]
        for n, v, s in zip(self.names, self.values, self.sigma):
            if n[1] in _LIN:
                lines.append(f"  {n} = {v * 1e3:+10.3f} µm   ± {s * 1e3:.3f} µm (1σ)")
            else:
                lines.append(f"  {n} = {v * 1e6:+10.3f} µrad ± {s * 1e6:.3f} µrad (1σ)")
        rms = float(np.sqrt(np.mean(self.residuals ** 2))) * 1e3
        lines.append(f"  sphere at ({', '.join(f'{x:.4f}' for x in self.sphere)}) mm; fit chi2 {self.chi2:.2f} on "
                     f"{self.dof} dof, residual rms {rms:.3f} µm")
        return "\n".join(lines)


def estimate_rotary(machine, plan: SpherePlan, readings, sigma: float = 0.0005, names=None,
                    known=None) -> RotaryEstimate:
    """Weighted least squares of the axis' location errors (default `default_parameters`) and the
    sphere position from the centre readings (K, 3) mm with noise `sigma` mm; `known`: other
    errors of the machine (ErrorSet) included in the model."""
    from ..errors import ErrorSet, GeometricErrors
    from ..machine import load_machine
    m = load_machine(machine)
    names = default_parameters(m, plan.axis) if names is None else tuple(names)
    bad = [n for n in names if len(n) != 4 or n[0] != "E" or n[2] != "0" or n[3] != plan.axis
           or n[1] not in _LIN + _ANG]
    if bad:
        raise InputError(f"expected location errors of axis {plan.axis} (e.g. {', '.join(default_parameters(m, plan.axis))}), "
                         f"got {', '.join(bad)}", field="names")
    y = np.asarray(readings, float)
    if y.shape != (len(plan.angles), 3) or not np.all(np.isfinite(y)):
        raise InputError(f"expected ({len(plan.angles)}, 3) finite readings in mm, got shape {y.shape}", field="readings")
    if not (np.isfinite(sigma) and sigma > 0):
        raise InputError(f"expected a positive sigma in mm, got {sigma!r}", field="sigma")
    n_par = 3 + len(names)
    if y.size <= n_par:
        raise InputError(f"{y.size} readings cannot determine {n_par} unknowns: probe at more angles",
                         field="angles")
    base_loc = dict(known.geometric.location) if known is not None else {}

    def model(x):
        loc = dict(base_loc)
        for n, v in zip(names, x[3:]):
            loc[n] = loc.get(n, 0.0) + v
        e = ErrorSet(tool=known.tool if known is not None else ErrorSet().tool,
                     workpiece=known.workpiece if known is not None else ErrorSet().workpiece,
                     geometric=GeometricErrors(tables=known.geometric.tables if known is not None else {},
                                               location=loc))
        return centre_readings(m, plan, e, x[:3]).ravel()

    x = np.concatenate([np.asarray(plan.sphere, float), np.zeros(len(names))])
    steps = np.array([1e-3] * 3 + [1e-3 if n[1] in _LIN else 1e-6 for n in names])
    def jacobian(x):
        J = np.empty((y.size, n_par))
        for k in range(n_par):
            dx = np.zeros(n_par)
            dx[k] = steps[k]
            J[:, k] = (model(x + dx) - model(x - dx)) / (2 * steps[k])
        return J

    J = jacobian(x)
    # The readings are affine in the sphere position and in the position errors and nearly so in
    # the small tilts: the Jacobian at zero serves every step (chord method), the final one is
    # re-evaluated at the solution for the covariance.
    for _ in range(30):
        f = model(x)
        scale = np.linalg.norm(J, axis=0)
        if np.any(scale == 0):
            lost = [(("sx", "sy", "sz") + names)[k] for k in np.flatnonzero(scale == 0)]
            raise InputError(f"the plan does not see {', '.join(lost)}", field="names")
        U, s, Vt = np.linalg.svd(J / scale, full_matrices=False)
        if s[-1] < 1e-9 * s[0]:
            v = Vt[-1] / scale
            v = v / np.max(np.abs(v))
            lost = [(("sphere x", "sphere y", "sphere z") + names)[k] for k in np.flatnonzero(np.abs(v) > 1e-3)]
            raise InputError(f"singular plan: the readings do not separate {', '.join(lost)} (probe at more "
                             "angles, or estimate fewer location errors)", field="names")
        step = (Vt.T @ ((U.T @ (y.ravel() - f)) / s)) / scale
        x = x + step
        if np.all(np.abs(step) < steps * 1e-4):   # 0.1 nm, 0.1 nrad
            break
    f = model(x)
    J = jacobian(x)
    cov = np.linalg.inv(J.T @ J) * sigma ** 2
    res = (y.ravel() - f).reshape(-1, 3)
    chi2 = float(np.sum(res ** 2) / sigma ** 2)
    return RotaryEstimate(plan.axis, names, x[3:].copy(), cov[3:, 3:], x[:3].copy(), res, chi2, int(y.size - n_par))


def read_readings_csv(path) -> tuple[np.ndarray, np.ndarray]:
    """Read sphere-centre readings: CSV with columns angle_deg,x,y,z ('#' comments), one row per
    angle of the tested axis, linear axis readings in mm.  Returns (angles (K,), readings (K, 3));
    errors name the file, line and column."""
    import csv
    from pathlib import Path
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except (FileNotFoundError, IsADirectoryError):
        raise InputError("readings file not found", path) from None
    rows = [(n, ln) for n, ln in enumerate(text.splitlines(), 1) if ln.strip() and not ln.lstrip().startswith("#")]
    if not rows:
        raise InputError("empty readings file: expected a header angle_deg,x,y,z and one row per angle", path)
    header = [c.strip().lower() for c in next(csv.reader([rows[0][1]]))]
    cols = ("angle_deg", "x", "y", "z")
    missing = [c for c in cols if c not in header]
    if missing:
        raise InputError(f"header lacks {', '.join(missing)}; expected angle_deg,x,y,z", path, rows[0][0])
    ang, val = [], []
    for n, ln in rows[1:]:
        cells = [c.strip() for c in next(csv.reader([ln]))]
        if len(cells) != len(header):
            raise InputError(f"expected {len(header)} values, got {len(cells)}", path, n)
        rec = []
        for c in cols:
            s = cells[header.index(c)]
            try:
                v = float(s)
            except ValueError:
                raise InputError(f"expected a number, got {s!r}", path, n, c) from None
            if not np.isfinite(v) or abs(v) > 1e5:
                raise InputError(f"expected a finite number of at most 1e5, got {s!r}", path, n, c)
            rec.append(v)
        if any(abs(rec[0] - a) < 1e-9 for a in ang):
            raise InputError(f"angle {rec[0]:g} deg appears twice", path, n, "angle_deg")
        ang.append(rec[0])
        val.append(rec[1:])
    if len(ang) < 3:
        raise InputError(f"{len(ang)} angles: at least 3 are needed to see a circle", path)
    return np.array(ang), np.array(val)


def sphere_from_readings(machine, axis: str, angles, readings, fixed: dict | None = None) -> np.ndarray:
    """Start value of the sphere centre (workpiece frame, mm): the ideal machine's tool point at
    each reading, turned back to the axis at 0, averaged."""
    from ..kinematics import forward
    plan = SpherePlan(axis, tuple(float(a) for a in angles), (0.0, 0.0, 0.0), dict(fixed or {}))
    q = _commands(machine, plan)
    q[:, [machine.index(a) for a in _LIN]] = readings
    return forward(machine, q).p.mean(axis=0)
