"""The numpy reference implementation of the compensation (inverse of the forward model).

Vectorised over N poses; the compiled kernel (fmu/c/mtk.c, called by mtcomp.kinematics) mirrors it
per pose, and the tests hold both to 1e-9 mm.  The math: docs/model.md, "Compensation".
Poses in mm, axis commands in mm and deg.
"""
from __future__ import annotations

import numpy as np

from .errors import ErrorSet
from .kinematics import (CONVERGED, ORIENTATION_SCALE, WO_HELD, ConvergenceError, Machine, Pose, _as_commands,
                         _mm, axis_rotation, forward)


def _orientation_mode(machine: Machine) -> int:
    """0: position only; 2: position and tool direction; 3: position and full orientation."""
    nr = machine.n_rotary
    return 0 if nr == 0 else (3 if nr >= 3 else 2)


def _residual(machine, q, errors, target: Pose, mode, strict=False, wo=ORIENTATION_SCALE):
    """Residual rows: position (mm), then the orientation error times wo (mm per rad)."""
    pose = forward(machine, q, errors, strict, backend="numpy")
    r = [pose.p - target.p]
    if mode == 2:
        # All three components of v - v_target: the two perpendicular ones alone would also
        # vanish at v = -v_target (a tool pointing the wrong way).
        r.append(wo * (pose.v - target.v))
    elif mode == 3:
        M = np.einsum("nji,njk->nik", target.R, pose.R)  # R_target^T R
        w = 0.5 * np.stack([M[:, 2, 1] - M[:, 1, 2], M[:, 0, 2] - M[:, 2, 0], M[:, 1, 0] - M[:, 0, 1]], axis=1)
        r.append(wo * w)
    return np.concatenate(r, axis=1)


def _sub(target: Pose, idx) -> Pose:
    return Pose(target.p[idx], target.R[idx], target.tool_axis)


def _rigid_jacobian(machine: Machine, q: np.ndarray, rigid, target: Pose, mode: int, wo: float) -> np.ndarray:
    """Jacobian (N, rows, n_axes) of the residual of the rigid model (setting errors only), per mm
    or deg, analytic: a linear axis moves the tool along its direction as the axes before it
    turn it, w = R_pre u; a rotary axis turns the tool about the line through its centre
    c_w = R_pre c + t_pre along w: dp = w x (p - c_w), dR = [w]x R (per rad), in the nominal
    workpiece frame, then turned into the real one by Rw^T (mtk.c jacobian)."""
    n, m = q.shape
    eye = np.eye(3)
    R = np.broadcast_to(eye, (n, 3, 3))
    t = np.zeros((n, 3))
    pre = []
    for i, ax in enumerate(machine.axes):
        pre.append((R, t))
        u = np.asarray(ax.direction, dtype=float)
        if ax.is_rotary:
            c = np.asarray(ax.location, dtype=float)
            Rg = axis_rotation(u, np.radians(q[:, i]))
            tg = c - Rg @ c
            t = t + np.einsum("nij,nj->ni", R, tg)
            R = _mm(R, Rg) if i else Rg
        else:
            t = t + q[:, i, None] * (R @ u)
    tp = np.asarray(machine.tool_point, dtype=float)
    if rigid is not None:
        tp = tp + np.asarray(rigid.tool.offset)
    p = R @ tp + t
    v = R @ np.asarray(machine.tool_axis, dtype=float)
    RwT = rigid.workpiece.matrix.T if rigid is not None else eye
    rows = 3 if mode == 0 else 6
    J = np.zeros((n, rows, m))
    for i, ax in enumerate(machine.axes):
        Rp, tpre = pre[i]
        w = Rp @ np.asarray(ax.direction, dtype=float)
        if not ax.is_rotary:
            J[:, :3, i] = w @ RwT.T
            continue
        w = w * (np.pi / 180.0)
        cw = Rp @ np.asarray(ax.location, dtype=float) + tpre
        J[:, :3, i] = np.cross(w, p - cw) @ RwT.T
        if mode == 2:
            J[:, 3:, i] = wo * (np.cross(w, v) @ RwT.T)
        elif mode == 3:
            W = np.zeros((n, 3, 3))
            W[:, 0, 1], W[:, 0, 2], W[:, 1, 0] = -w[:, 2], w[:, 1], w[:, 2]
            W[:, 1, 2], W[:, 2, 0], W[:, 2, 1] = -w[:, 0], -w[:, 1], w[:, 0]
            dR = np.einsum("ij,njk->nik", RwT, _mm(W, R))
            dM = np.einsum("nji,njk->nik", target.R, dR)
            J[:, 3, i] = wo * 0.5 * (dM[:, 2, 1] - dM[:, 1, 2])
            J[:, 4, i] = wo * 0.5 * (dM[:, 0, 2] - dM[:, 2, 0])
            J[:, 5, i] = wo * 0.5 * (dM[:, 1, 0] - dM[:, 0, 1])
    return J


def _solve(machine: Machine, target: Pose, errors, q0: np.ndarray, tol: float, max_iter: int,
           free: np.ndarray | None = None, wo: float = ORIENTATION_SCALE):
    """The Gauss-Newton iteration of `compensate`; returns (q, residual rows (N, 3 or 6)).
    free (N, n_axes) bool: axes that may move (None: all); the others keep q0's value."""
    q0 = _as_commands(machine, q0)
    n, m = q0.shape
    mode = _orientation_mode(machine)
    rigid = None if errors is None else ErrorSet(errors.tool, errors.workpiece)
    rot = np.array([a.is_rotary for a in machine.axes])
    lam = 1e-12
    q = q0.copy()
    active = np.arange(n)
    res = lambda qq, idx, err: _residual(machine, qq, err, _sub(target, idx), mode, wo=wo)  # noqa: E731
    its = np.zeros(n, dtype=int)  # iterations per point (a point's budget does not depend on the batch)
    while active.size:
        active = active[its[active] < max_iter]
        if not active.size:
            break
        qa = q[active]
        # Chord Jacobian (of the rigid model) at the current iterate of the still active points.
        J = _rigid_jacobian(machine, qa, rigid, _sub(target, active), mode, wo)
        if free is not None:
            J *= free[active][:, None, :]
        JT = np.transpose(J, (0, 2, 1))
        A = _mm(JT, J) + lam * np.eye(m)
        K = np.linalg.solve(A, JT)
        r = res(qa, active, errors)
        nr = np.linalg.norm(r, axis=1)
        done = np.zeros(active.size, bool)
        live = np.arange(active.size)  # points still iterating on this Jacobian
        for _ in range(8):
            its[active[live]] += 1
            L = live
            # Damped least squares (lam): no component along a null direction of the Jacobian,
            # so where the orientation leaves an axis free it keeps the seed's value, and no
            # pull toward the seed that would bias the converged point.
            step = np.einsum("nij,nj->ni", K[L], r[L])
            if free is not None:
                step = np.where(free[active[L]], step, 0.0)
            # Damping: limit rotary steps to 20 deg (scaling the whole step, so the linear axes
            # stay consistent) and halve steps that do not reduce the residual.
            big = np.max(np.abs(step[:, rot]), axis=1, initial=0.0)
            scale = np.minimum(1.0, 20.0 / np.maximum(big, 1e-300))
            # A step below the tolerance is convergence: no evaluation, no backtracking (at the
            # rounding floor a trial cannot lower the residual and would only be halved away).
            todo = np.nonzero(np.max(np.abs(step), axis=1) >= tol)[0]
            qn, rn, nn = qa[L], r[L], nr[L].copy()
            for _bt in range(30 if todo.size else 0):
                qt = qa[L[todo]] - scale[todo, None] * step[todo]
                rt = res(qt, active[L[todo]], errors)
                nt = np.linalg.norm(rt, axis=1)
                ok = (nt < nr[L[todo]]) | (nt <= 1e-12)
                qn[todo[ok]], rn[todo[ok]], nn[todo[ok]] = qt[ok], rt[ok], nt[ok]
                todo = todo[~ok]
                if not todo.size:
                    break
                scale[todo] *= 0.5
            stepped = np.max(np.abs(qn - qa[L]), axis=1)
            fin = (stepped < tol) | (nn <= 1e-12)
            # contraction too weak: re-linearise these (with a held axis every step: the
            # least-squares residual does not vanish, and only the Jacobian at the iterate leads
            # to the least-squares point rather than to one biased by a stale Jacobian)
            slow = (nn > 0.1 * nr[L]) & ~fin
            qa[L], r[L], nr[L] = qn, rn, nn
            done[L[fin]] = True
            live = L[~fin & ~slow]
            if not live.size:
                break
        q[active] = qa
        active = active[~done]
    return q, _residual(machine, q, errors, target, mode, wo=wo)


def _max_abs(r: np.ndarray) -> np.ndarray:
    return np.max(np.abs(r), axis=1)  # NaN propagates: a NaN residual never passes


def _orientation_angle(r: np.ndarray, mode: int) -> np.ndarray:
    """Angle (rad) of unweighted orientation residual rows r (N,3)."""
    x = np.linalg.norm(r, axis=1)
    return 2.0 * np.arcsin(np.minimum(1.0, 0.5 * x)) if mode == 2 else np.arcsin(np.minimum(1.0, x))


def _pole_axis_of(machine: Machine, cols: list, thr: float) -> np.ndarray:
    """(N,) the rotary axis whose orientation column (cols[k] (N,3): rotary axis k's effect on the
    orientation per rad) lies within thr (a sine) of the span of the others' (C at B = 0 on a B-C
    table turns the tool about itself; A and C at B = 90 on an A-B-C head turn it about the same
    line), or -1.  Of several, the last in the chain (mtk.c pole_axis_cols)."""
    rot = list(machine.rotary_indices)
    hold = np.full(len(cols[0]), -1)
    for a, ka in enumerate(rot):
        basis = []
        for b in range(len(rot)):
            if b == a:
                continue
            w = cols[b].copy()
            for e in basis:
                w -= np.sum(w * e, axis=1)[:, None] * e
            s = np.linalg.norm(w, axis=1)
            basis.append(np.where(s[:, None] > 1e-9, w / np.maximum(s, 1e-300)[:, None], 0.0))
        v = cols[a].copy()
        for e in basis:
            v -= np.sum(v * e, axis=1)[:, None] * e
        hold = np.where(np.linalg.norm(v, axis=1) < thr, ka, hold)
    return hold


def _pole_columns(machine: Machine, target: Pose, errors) -> list | None:
    """The orientation columns the pole rule tests: those of the rigid model (nominal axes, the
    workpiece setting's rotation Rw) at its exact solution for the target's orientation, so that
    the decision depends on the target alone and on the real machine's distance from its pole.
    The rigid orientation R(u1, th1) R(u2, th2) [R(u3, th3)] = Rw R_t; the columns' lengths and
    mutual projections depend on th2 alone, found from v = Rw R_t a (a the tool axis, with three
    rotary axes u3) as x = R(u2, th2) a = al u1 + be u2 + ga u1 x u2 (Paden-Kahan subproblem 2;
    either sign of ga gives the same lengths and projections; ga^2 < 0, an orientation out of
    reach: ga = 0).  Columns in the frame before the first turn: u1 x x, u2 x x (two rotary
    axes), u1, u2, x (three), u1 x a (one).  None where the first two rotary axes are parallel
    (mtk.c pole_columns)."""
    rot = list(machine.rotary_indices)
    n = len(target)
    u = [np.asarray(machine.axes[k].direction, dtype=float) for k in rot]
    ta = np.asarray(machine.tool_axis, dtype=float)
    if len(rot) == 1:
        return [np.broadcast_to(np.cross(u[0], ta), (n, 3)).copy()]
    c = float(u[0] @ u[1])
    if not 1.0 - c * c > 1e-6 or len(rot) > 3:
        return None
    Rw = errors.workpiece.matrix if errors is not None else np.eye(3)
    a = u[2] if len(rot) == 3 else ta
    v = (target.R @ a) @ Rw.T
    iden = 1.0 / (1.0 - c * c)
    u1v = v @ u[0]
    u2a = float(u[1] @ a)
    al = (u1v - c * u2a) * iden
    be = (u2a - c * u1v) * iden
    ga2 = (float(a @ a) - al * al - be * be - 2.0 * al * be * c) * iden
    ga = np.sqrt(np.maximum(ga2, 0.0))
    x = al[:, None] * u[0] + be[:, None] * u[1] + ga[:, None] * np.cross(u[0], u[1])
    if len(rot) == 3:
        return [np.broadcast_to(u[0], (n, 3)).copy(), np.broadcast_to(u[1], (n, 3)).copy(), x]
    return [np.cross(u[0], x), np.cross(u[1], x)]


def _pole_axis(machine: Machine, target: Pose, errors, q: np.ndarray, pole_tolerance: float) -> np.ndarray:
    """(N,) the rotary axis held at a pole for each target, or -1 (_pole_axis_of on _pole_columns,
    a sine of pole_tolerance deg).  Where those columns do not apply, the rigid model's Jacobian
    columns at q (the programmed commands), as the chord Jacobian's (mtk.c pole_decision)."""
    thr = np.sin(np.radians(pole_tolerance))
    cols = _pole_columns(machine, target, errors)
    if cols is None:
        mode = _orientation_mode(machine)
        rigid = None if errors is None else ErrorSet(errors.tool, errors.workpiece)
        J = _rigid_jacobian(machine, q, rigid, target, mode, 1.0)
        cols = [J[:, 3:, k] * (180.0 / np.pi) for k in machine.rotary_indices]
    return _pole_axis_of(machine, cols, thr)


#: Rotary offsets (deg) tried as new starting points where the iteration from the programmed
#: angles fails; nearest first.
_SEED_OFFSETS = (90.0, -90.0, 180.0)


def compensate_numpy(machine: Machine, target: Pose, errors, q0: np.ndarray, tol: float, max_iter: int,
                      pole_tolerance: float) -> np.ndarray:
    """The reference implementation of `compensate` (the compiled kernel mirrors it per pose)."""
    n, m = q0.shape
    mode = _orientation_mode(machine)
    q = q0.copy()
    held = np.full(n, -1)
    if pole_tolerance > 0 and mode >= 2:
        hold = _pole_axis(machine, target, errors, q0, pole_tolerance)
        idx = np.nonzero(hold >= 0)[0]
        if idx.size:
            free = np.ones((idx.size, m), bool)
            free[np.arange(idx.size), hold[idx]] = False
            qh, rh = _solve(machine, _sub(target, idx), errors, q0[idx], tol, max_iter, free, WO_HELD)
            ok = ((_max_abs(rh[:, :3]) < CONVERGED)
                  & (_orientation_angle(rh[:, 3:] / WO_HELD, mode) <= np.radians(pole_tolerance)))
            q[idx[ok]] = qh[ok]
            held[idx[ok]] = hold[idx[ok]]
    rest = np.nonzero(held < 0)[0]
    if rest.size:
        sub = _sub(target, rest)
        qr, rr = _solve(machine, sub, errors, q0[rest], tol, max_iter)
        err = _max_abs(rr)
        bad = np.nonzero(~(err < CONVERGED))[0]
        if bad.size:
            rot = list(machine.rotary_indices)
            seeds = [{k: o} for k in rot for o in _SEED_OFFSETS]
            seeds += [{k: o, j: p} for i, k in enumerate(rot) for j in rot[i + 1:]
                      for o in _SEED_OFFSETS for p in _SEED_OFFSETS]
            best = np.full(bad.size, np.inf)
            sb = _sub(sub, bad)
            qb0 = q0[rest[bad]]
            for seed in seeds:
                qs = qb0.copy()
                for k, o in seed.items():
                    qs[:, k] += o
                qt, rt = _solve(machine, sb, errors, qs, tol, max_iter)
                et = _max_abs(rt)
                change = np.sum(np.abs(qt[:, rot] - qb0[:, rot]), axis=1)
                # solutions within 1e-6 (deg) of rotary change are ties: the first seed wins, so
                # neighbouring points of a path take the same branch
                better = (et < CONVERGED) & (change < best - 1e-6)
                qr[bad[better]] = qt[better]
                best[better] = change[better]
            failed = np.nonzero(best == np.inf)[0]
            if failed.size:
                i = bad[failed[0]]
                raise ConvergenceError(int(rest[i]), float(err[i]))
        q[rest] = qr
    # Strict evaluation: a converged command outside an error table's range is an error.
    forward(machine, q, errors, True, backend="numpy")
    return q


def _linear_axis_matrix(machine: Machine, q: np.ndarray):
    """Nominal chain rotation R_c (N,3,3) and the matrix A (N,3,3) whose columns are the
    directions of the three linear axes as the rotary axes before them in the chain turn them:
    with the rotary angles fixed, the nominal tool position is affine in the linear axes, dp = A dq."""
    n = q.shape[0]
    R = None
    cols = []
    for i, ax in enumerate(machine.axes):
        u = np.asarray(ax.direction)
        if ax.is_rotary:
            Rg = axis_rotation(u, np.radians(q[:, i]))
            R = Rg if R is None else _mm(R, Rg)
        else:
            cols.append(np.broadcast_to(u, (n, 3)) if R is None else R @ u)
    if R is None:
        R = np.broadcast_to(np.eye(3), (n, 3, 3))
    return R, np.stack(cols, axis=2)


def _solve3(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve N 3x3 systems A x = b by Cramer's rule (much faster than a batched LU for 3x3)."""
    c0, c1, c2 = A[:, :, 0], A[:, :, 1], A[:, :, 2]
    det = np.einsum("ni,ni->n", c0, np.cross(c1, c2))
    return np.stack([np.einsum("ni,ni->n", b, np.cross(c1, c2)),
                     np.einsum("ni,ni->n", c0, np.cross(b, c2)),
                     np.einsum("ni,ni->n", c0, np.cross(c1, b))], axis=1) / det[:, None]


def retarget_rigid(machine: Machine, q: np.ndarray, errors: ErrorSet) -> np.ndarray | None:
    """Closed form for rigid setting errors when the rotary angles need not change (no
    geometric errors, and no workpiece rotation unless the machine has no rotary axes):
    A(theta) dq_lin = Rw p_ideal + tw - R_c (tool_point + t) - t_c(q).  None if not applicable."""
    lin = [i for i, a in enumerate(machine.axes) if not a.is_rotary]
    if (not errors.geometric.is_zero or len(lin) != 3
            or (machine.n_rotary and any(errors.workpiece.angles))):
        return None
    R, A = _linear_axis_matrix(machine, q)
    t = np.asarray(errors.tool.offset)
    tw = np.asarray(errors.workpiece.translation)
    rhs = tw - R @ t
    if any(errors.workpiece.angles):  # 3-axis machine: the ideal point turns with the workpiece
        p_ideal = forward(machine, q, backend="numpy").p
        rhs = rhs + p_ideal @ errors.workpiece.matrix.T - p_ideal
    out = q.copy()
    out[:, lin] += _solve3(A, rhs)
    return out
