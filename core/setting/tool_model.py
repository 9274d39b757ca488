"""The grooving model's parameters: tool offset and rotary-axis location errors, their observability,
and the setting error "against" each rotary axis as paper 000 reports it.

Parameters (all mm): the tool setting error t = (t_x, t_y, t_z) in the tool frame (edge minus the
nominal common point of the rotary axes) and the ISO 230-1 position location errors of the
tool-side rotary axes perpendicular to their own direction (EX0C, EY0C of C; EY0A, EZ0A of A;
EX0B, EZ0B of B on a machine whose A, B, C lie along X, Y, Z).  A groove point is affine in all of
them (a rotation about a shifted line is the rotation about the nominal line plus a constant), so
the model stays linear and its Jacobian is exact.

Gauge: moving the tool edge and every rotary axis line by the same vector is a rigid shift of the
tool side; no groove sees it (the per-test origins take it).  Of the nine parameters at most six
are therefore observable.  `observable_parameters` picks them greedily in a fixed priority (t
first, then the axis that carries the tool, then the others in chain order), so the unobservable
ones are fixed at zero: they define the reference point.  On robonano-ui with the default plan this
estimates t, EX0C, EY0C, EZ0A, with the B axis line (x, z) and the A axis line (y) as reference.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

COMPONENTS = ("t_x", "t_y", "t_z")
_LIN = "XYZ"


def location_candidates(machine) -> tuple[str, ...]:
    """Position location errors of the tool-side rotary axes that can move a groove: the two
    components perpendicular to each axis (the one along the axis moves nothing).  Ordered by
    priority: the axis that carries the tool first, then the others from the base outward."""
    rot = [a for a in machine.axes if a.is_rotary and a.side == "tool"]
    if not rot:
        return ()
    order = [rot[-1]] + rot[:-1]
    out = []
    for ax in order:
        u = np.abs(np.asarray(ax.direction, float))
        for k, c in enumerate(_LIN):
            if u[k] < 0.9:
                out.append(f"E{c}0{ax.name}")
    return tuple(out)


def _errors_with(base, tool=(0.0, 0.0, 0.0), location=None):
    """ErrorSet = base (workpiece, geometric) + a tool offset + extra location errors (mm)."""
    from ..errors import ErrorSet, GeometricErrors, ToolSetting
    loc = dict(base.geometric.location) if base is not None else {}
    for k, v in (location or {}).items():
        loc[k] = loc.get(k, 0.0) + float(v)
    tables = base.geometric.tables if base is not None else {}
    wp = base.workpiece if base is not None else None
    kw = {"workpiece": wp} if wp is not None else {}
    return ErrorSet(tool=ToolSetting(tuple(float(x) for x in tool)),
                    geometric=GeometricErrors(tables=tables, location=loc), **kw)


def parameter_jacobian(machine, q, names, base=None):
    """Edge positions p0 (N,3) with all parameters zero and dp/dparam (N,3,P), mm/mm, for axis
    commands q (N, n_axes).  Exact: p is affine in every parameter (unit steps)."""
    from ..kinematics import forward
    p0 = forward(machine, q, _errors_with(base)).p
    J = np.empty(p0.shape + (len(names),))
    for k, name in enumerate(names):
        if name in COMPONENTS:
            e = np.zeros(3)
            e[COMPONENTS.index(name)] = 1.0
            p = forward(machine, q, _errors_with(base, tool=e)).p
        else:
            p = forward(machine, q, _errors_with(base, location={name: 1.0})).p
        J[:, :, k] = p - p0
    return p0, J


def errors_from_parameters(names, values, known=None):
    """ErrorSet with tool offset and location errors from parameter values (mm), on top of the
    errors of `known` (its tool setting is replaced: that is what was estimated)."""
    values = np.asarray(values, float)
    t = [values[names.index(c)] if c in names else 0.0 for c in COMPONENTS]
    loc = {n: v for n, v in zip(names, values) if n not in COMPONENTS}
    return _errors_with(known, tool=t, location=loc)


@dataclass(frozen=True)
class Observability:
    """Which parameters a grooving plan determines.  estimated: the greedy maximal set (in
    priority order); unobservable: {name: reason}, the reason naming the combination that the
    grooves cannot separate."""
    estimated: tuple
    unobservable: dict
    rank: int

    def summary(self) -> str:
        lines = [f"Observable from this plan (estimated): {', '.join(self.estimated)}"]
        for k, why in self.unobservable.items():
            lines.append(f"  not observable: {k}: {why}")
        return "\n".join(lines)


def _rank(A, tol=1e-9):
    if A.shape[1] == 0:
        return 0
    s = np.linalg.svd(A / np.maximum(np.linalg.norm(A, axis=0), 1e-300), compute_uv=False)
    return int(np.sum(s > tol * s[0]))


def _null_vector(A):
    scale = np.maximum(np.linalg.norm(A, axis=0), 1e-300)
    _, s, Vt = np.linalg.svd(A / scale, full_matrices=False)
    v = Vt[-1] / scale
    return v / np.max(np.abs(v))


def design_rows(machine, plan, names, base=None):
    """Jacobian rows (M, P + K) of every (u, v, depth) value of every measured point of the plan
    for the parameters `names` plus one offset per test and component (u, v, depth)."""
    from .tool_plan import commands_for_points
    items = plan.features()
    pts, ang, bases, keys = [], [], [], []
    for gid, feat in items:
        g = plan.groove(gid)
        face = plan.face_of(g)
        pts.append(face.point(g.point(feat), g.depth)[0])
        ang.append(g.angles)
        bases.append(face.basis)
        keys.append(g.test)
    q = commands_for_points(machine, np.array(pts), np.array(ang))
    _, J = parameter_jacobian(machine, q, names, base)
    Jf = np.einsum("nij,njk->nik", np.array(bases), J)          # (N, 3, P) face components
    nuis = sorted({f"{t}:{c}" for t in keys for c in "uvd"})
    rows = []
    for n, t in enumerate(keys):
        for c, cn in enumerate("uvd"):
            r = np.zeros(len(nuis))
            r[nuis.index(f"{t}:{cn}")] = 1.0
            rows.append(np.concatenate([Jf[n, c], r]))
    return np.array(rows)


def observable_parameters(machine, plan, candidates=None, base=None) -> Observability:
    """Greedy maximal observable set: t_x, t_y, t_z, then the location candidates in priority
    order, each kept if it raises the rank of the design (with the per-test offsets)."""
    from ..machine import load_machine
    m = load_machine(machine)
    cand = COMPONENTS + tuple(location_candidates(m) if candidates is None else candidates)
    key = (m, tuple(plan.grooves), tuple(plan.faces.items()), cand)
    if base is None or base.is_zero:
        hit = _OBS_CACHE.get(key)
        if hit is None:
            hit = _OBS_CACHE[key] = _observable(m, plan, cand, None)
        return hit
    return _observable(m, plan, cand, base)


#: Observability depends only on the machine and the plan: memoised (Monte Carlo runs).
_OBS_CACHE: dict = {}


def _observable(m, plan, cand, base) -> Observability:
    A = design_rows(m, plan, cand, base)
    P = len(cand)
    nuis = A[:, P:]
    chosen, unobs = [], {}
    r0 = _rank(nuis)
    for k, name in enumerate(cand):
        cols = [cand.index(c) for c in chosen] + [k]
        sub = np.hstack([A[:, cols], nuis])
        if _rank(sub) == r0 + len(cols):
            chosen.append(name)
            continue
        v = _null_vector(sub)[:len(cols)]
        terms = [(cand[c], v[i]) for i, c in enumerate(cols) if abs(v[i]) > 1e-6]
        if len(terms) == 1:
            unobs[name] = "no groove of the plan moves with it"
            continue
        combo = _combination(terms)
        unobs[name] = (f"changing {combo} together moves no groove of the plan (relative to the per-test "
                       f"origins)" + ("; a rigid shift of the tool side: fixed at 0, it defines the reference"
                                      if _rigid_shift(terms) else ""))
    return Observability(tuple(chosen), unobs, r0 + len(chosen))


def _combination(terms) -> str:
    """'t_y + EY0C + EY0A' from [(name, coefficient)], first coefficient made positive."""
    sgn = 1.0 if terms[0][1] > 0 else -1.0
    out = ""
    for i, (n, x) in enumerate(terms):
        x *= sgn
        mag = "" if np.isclose(abs(x), 1.0, rtol=1e-3) else f"{abs(x):.3g} "
        out += (("- " if x < 0 else "+ ") if i else ("-" if x < 0 else "")) + mag + n + " "
    return out.strip()


def _rigid_shift(terms) -> bool:
    """True if the null combination is the same shift of the edge and of axis lines along one
    machine axis (the gauge of the problem)."""
    comps = set()
    for n, _ in terms:
        comps.add(n[2] if n in COMPONENTS else n[1].lower())
    vals = [abs(x) for _, x in terms]
    return len(comps) == 1 and np.allclose(vals, vals[0], rtol=1e-3)


def against_axes(machine, plan, names, values, cov, base=None) -> dict:
    """The setting error against each rotary axis tested by the plan, as paper 000 reports it:
    the offset of the real edge from the real axis line, in the tool frame, at the test's first
    groove (for the A test: at its lowest A), perpendicular to the axis.

    Returns {axis: (component names (2,), values (2,) mm, covariance (2,2) mm^2)}."""
    values = np.asarray(values, float)
    out = {}
    for test, (comp, v0, L) in _against_maps(machine, plan, tuple(names), base).items():
        out[test] = (comp, v0 + L @ values, L @ cov @ L.T)
    return out


def _against_maps(machine, plan, names, base) -> dict:
    """{axis: (component names, v0 (2,), L (2, P))}: against-axis offset = v0 + L @ values (exact,
    affine).  Memoised for base = None (it depends on the machine and the plan only)."""
    key = (machine, tuple(plan.grooves), tuple(plan.faces.items()), names)
    if base is None or base.is_zero:
        hit = _AGAINST_CACHE.get(key)
        if hit is None:
            hit = _AGAINST_CACHE[key] = _against_maps_uncached(machine, plan, names, None)
        return hit
    return _against_maps_uncached(machine, plan, names, base)


_AGAINST_CACHE: dict = {}


def _against_maps_uncached(machine, plan, names, base) -> dict:
    from ..kinematics import forward
    from .tool_plan import commands_for_points
    out = {}
    for test in plan.tests():
        gs = [g for g in plan.grooves if g.test == test]
        g = min(gs, key=lambda g: g.angles[0])
        q = commands_for_points(machine, np.zeros((1, 3)), np.array([g.angles]))
        # The axis line's point: the rotaries before it are at 0 on this pose (checked), so it is
        # its nominal location plus its location error, shifted by the linear axes of the pose.
        ax = machine.axis(test)
        idx = machine.index(test)
        if any(machine.axes[i].is_rotary and q[0, i] != 0 for i in range(idx)):
            continue
        lin = np.zeros_like(q)
        lin[:, [machine.index(c) for c in _LIN]] = q[:, [machine.index(c) for c in _LIN]]
        shift = forward(machine, lin).p[0] - np.asarray(machine.tool_point, float)

        def vec(vals):
            e = errors_from_parameters(names, vals, base)
            pose = forward(machine, q, e)
            d0, _ = e.geometric.location_of(test)
            c = np.asarray(ax.location, float) + d0 + shift
            R = pose.R[0]
            return R.T @ (pose.p[0] - c), R.T @ np.asarray(ax.direction, float)

        v0, u = vec(np.zeros(len(names)))
        keep = sorted(int(k) for k in np.argsort(np.abs(u))[:2])
        L = np.empty((2, len(names)))
        for j in range(len(names)):
            e = np.zeros(len(names))
            e[j] = 1.0
            L[:, j] = (vec(e)[0] - v0)[keep]
        out[test] = (tuple(f"d{'xyz'[k]}" for k in keep), v0[keep], L)
    if len(_AGAINST_CACHE) > 256:
        _AGAINST_CACHE.clear()
    return out
