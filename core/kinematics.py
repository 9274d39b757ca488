"""Forward model and compensation (inverse) of a machine with setting and geometric errors.

Exact homogeneous transforms, vectorised over N poses.  The math is written out in
docs/model.md; every axis contributes

    G_i(q) = M_i(q) . E_i(q)   or   E_i(q) . M_i(q)

(M_i = L_i N_i L_i^-1 nominal motion with location errors, E_i = T(loc_i) D_i T(-loc_i) the
component error motion from the tables about the axis' reference point; which side E_i stands on
depends on the body that carries the errors, see docs/model.md), and the tool edge in the real workpiece frame is

    p = Rw^T ( G_1 ... G_n (tool_point + tool_offset) - tw ).

Poses in mm, axis commands in mm and deg, error angles in rad.

The hot loops run in the compiled kernel (fmu/c/mtk.c through mtcomp._kernel); this module holds
the numpy forward model, the public API and the dispatch; mtcomp._solver the numpy reference of
the compensation, the fallback without a C compiler.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._io import InputError, MtcompError
from .errors import ErrorSet
from .machine import Machine

#: Length (mm) that converts orientation residuals (rad) into the position scale of the
#: Gauss-Newton problem; it only weights the residuals, the solution satisfies both exactly.
ORIENTATION_SCALE = 100.0
#: Orientation weight (mm per rad) while an axis at a pole is held: the orientation is then met
#: in least squares, and the small weight keeps the position exact even where the tables'
#: angular errors couple the linear axes into the orientation (mtk.c WO_HELD).
WO_HELD = ORIENTATION_SCALE * 1e-3
#: Largest residual (mm; orientation in ORIENTATION_SCALE units) accepted as converged.
CONVERGED = 1e-7
#: Default pole tolerance (deg), see `compensate` (mtk.h MTK_POLE_TOL).
POLE_TOLERANCE = 0.2


class LimitError(MtcompError):
    """A compensated command leaves the travel of an axis."""

    def __init__(self, axis: str, index: int, value: float, limits):
        self.axis, self.index, self.value = axis, index, value
        super().__init__(f"axis {axis} would have to move to {value:.6f}, outside its travel "
                         f"[{limits[0]:g}, {limits[1]:g}] (point {index})")


class ConvergenceError(MtcompError):
    def __init__(self, index: int, residual: float):
        self.index = index
        super().__init__(f"compensation did not converge at point {index} (residual {residual:.3g}); "
                         "the target may be unreachable or at a kinematic singularity")


@dataclass(frozen=True)
class Pose:
    """Tool poses in the workpiece frame: p (N,3) tool edge in mm, R (N,3,3) tool frame
    orientation (columns: tool frame axes).  `v` is the tool axis direction (N,3)."""
    p: np.ndarray
    R: np.ndarray
    tool_axis: tuple = (0.0, 0.0, 1.0)

    @property
    def v(self) -> np.ndarray:
        return self.R @ np.asarray(self.tool_axis, dtype=float)

    def __len__(self):
        return len(self.p)


def _mm(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Stacked matrix products A[n] @ B[n]: einsum with optimize=True runs several times faster
    than matmul on stacks of small matrices."""
    return np.einsum("nij,njk->nik", A, B, optimize=True)


def rotvec_matrix(w: np.ndarray) -> np.ndarray:
    """Rotation matrices (N,3,3) of rotation vectors w (N,3) in rad (Rodrigues, exact)."""
    w = np.asarray(w, dtype=float)
    th = np.linalg.norm(w, axis=-1)
    small = th < 1e-8
    th_safe = np.where(small, 1.0, th)
    # sin(th)/th and (1-cos th)/th^2 with series near zero to keep full precision.
    a = np.where(small, 1.0 - th**2 / 6.0, np.sin(th_safe) / th_safe)
    b = np.where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(th_safe)) / th_safe**2)
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    K = np.zeros(w.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 0] = -z, y, z
    K[..., 1, 2], K[..., 2, 0], K[..., 2, 1] = -x, -y, x
    eye = np.eye(3)
    KK = _mm(K, K) if K.ndim == 3 else K @ K
    return eye + a[..., None, None] * K + b[..., None, None] * KK


def axis_rotation(u, angle_rad: np.ndarray) -> np.ndarray:
    """Rotation matrices (N,3,3) about the unit vector u by angles (N,) in rad."""
    u = np.asarray(u, dtype=float)
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    C = 1.0 - c
    x, y, z = u
    R = np.empty(np.shape(angle_rad) + (3, 3))
    R[..., 0, 0] = c + x * x * C
    R[..., 0, 1] = x * y * C - z * s
    R[..., 0, 2] = x * z * C + y * s
    R[..., 1, 0] = y * x * C + z * s
    R[..., 1, 1] = c + y * y * C
    R[..., 1, 2] = y * z * C - x * s
    R[..., 2, 0] = z * x * C - y * s
    R[..., 2, 1] = z * y * C + x * s
    R[..., 2, 2] = c + z * z * C
    return R


def _as_commands(machine: Machine, q) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    if q.ndim == 1:
        q = q[None, :]
    if q.ndim != 2 or q.shape[1] != machine.n_axes:
        raise ValueError(f"commands must have shape (N, {machine.n_axes}) for axes "
                         f"{' '.join(machine.axis_names)}, got {q.shape}")
    return q


def chain(machine: Machine, q, errors: ErrorSet | None = None, strict: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Pose (R (N,3,3), t (N,3)) of the last tool-side frame in the nominal workpiece frame."""
    q = _as_commands(machine, q)
    n = q.shape[0]
    geo = errors.geometric if errors is not None else None
    R = None  # identity until the first rotation, which saves matrix products
    t = np.zeros((n, 3))
    for i, ax in enumerate(machine.axes):
        qi = q[:, i]
        u = np.asarray(ax.direction)
        loc = np.asarray(ax.location)
        # Location errors: tilt of the axis (squareness), offset of a rotary axis, zero error.
        d0, e0 = geo.location_of(ax.name) if geo is not None else (np.zeros(3), np.zeros(3))
        if ax.is_rotary:
            zero = float(e0 @ u)
            tilt = e0 - zero * u
            u_eff = rotvec_matrix(tilt[None])[0] @ u if np.any(tilt) else u
            c = loc + d0
            Rg = axis_rotation(u_eff, np.radians(qi) + zero)
            tg = c - Rg @ c
        else:
            # A translation of a straight line changes nothing, so only the tilt of a linear
            # axis (squareness) acts; positional location errors of linear axes are ignored.
            u_eff = rotvec_matrix(e0[None])[0] @ u if np.any(e0) else u
            Rg = None
            tg = qi[:, None] * u_eff
        # Component error motions from the tables, acting about the reference point.  They
        # belong to the moving body for a linear axis (the far-from-base body: the child on the
        # tool side, the parent on the workpiece side) and to the non-rotating body for a
        # rotary axis (ISO 230-7 error motions in the fixed frame: the parent on the tool side,
        # the child on the workpiece side).
        table = geo.tables.get(ax.name) if geo is not None else None
        if table is not None:
            d, e = table.evaluate(qi, strict)
            Re = rotvec_matrix(e)
            te = loc + d - Re @ loc
            before = (ax.side == "workpiece") != ax.is_rotary  # D_i . N_i instead of N_i . D_i
            if before:  # (Re, te) . (Rg, tg)
                tg = np.einsum("nij,nj->ni", Re, tg) + te
                Rg = Re if Rg is None else _mm(Re, Rg)
            elif Rg is None:
                Rg, tg = Re, te + tg
            else:  # (Rg, tg) . (Re, te)
                tg = np.einsum("nij,nj->ni", Rg, te) + tg
                Rg = _mm(Rg, Re)
        # Compose: (R, t) . (Rg, tg)
        if Rg is None:
            t = t + (tg if R is None else np.einsum("nij,nj->ni", R, tg))
        else:
            t = t + (tg if R is None else np.einsum("nij,nj->ni", R, tg))
            R = Rg if R is None else _mm(R, Rg)
    if R is None:
        R = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    return R, t


def _finite_commands(machine: Machine, q: np.ndarray) -> None:
    """InputError naming the first point and axis whose command is not a finite number."""
    if np.isfinite(q).all():  # the usual case: one pass, no index array (a fifth of a closed-form retarget)
        return
    bad = np.argwhere(~np.isfinite(q))
    if bad.size:
        i, k = bad[0]
        raise InputError(f"point {i}: the {machine.axes[k].name} command is {q[i, k]}, not a finite number",
                         field=machine.axes[k].name)


def _backend(backend: str | None):
    """The compiled kernel (ctypes library) or None for the numpy reference implementation."""
    if backend == "numpy":
        return None
    if backend not in (None, "c"):
        raise ValueError(f"backend must be None, 'c' or 'numpy', got {backend!r}")
    from . import _kernel
    lib = _kernel.load()
    if lib is None and backend == "c":
        raise RuntimeError(f"the compiled kernel is unavailable ({_kernel._state.get('reason')})")
    return lib


def forward(machine: Machine, q, errors: ErrorSet | None = None, strict: bool = True, *,
            backend: str | None = None) -> Pose:
    """Real tool edge position (mm) and tool frame orientation in the real workpiece frame for
    axis commands q (N, n_axes) in mm and deg, with all errors of `errors` (None: ideal).

    backend: None (the compiled kernel where available, else numpy), "c" or "numpy"."""
    q = _as_commands(machine, q)
    lib = _backend(backend)
    if lib is not None:
        from . import _kernel
        p, R, bad = _kernel.forward(lib, machine, q, errors, strict)
        if bad < 0:
            return Pose(p, R, machine.tool_axis)
        # outside a table: the numpy model raises the same error the reference raises
    R, t = chain(machine, q, errors, strict)
    tp = np.asarray(machine.tool_point, dtype=float)
    if errors is not None:
        tp = tp + np.asarray(errors.tool.offset)
    p = np.einsum("nij,j->ni", R, tp) + t
    if errors is not None and not errors.workpiece.is_zero:
        Rw = errors.workpiece.matrix
        tw = np.asarray(errors.workpiece.translation)
        p = (p - tw) @ Rw  # Rw^T (p - tw), row-vector form
        R = np.einsum("ji,njk->nik", Rw, R)
    return Pose(p, R, machine.tool_axis)


def forward_position(machine: Machine, q, errors: ErrorSet | None = None, strict: bool = True, *,
                     backend: str | None = None) -> np.ndarray:
    """The tool edge positions (N, 3) mm of `forward` alone: the compiled kernel neither writes
    nor allocates the orientations (a verification of millions of blocks needs the positions
    only).  Same arguments as `forward`."""
    q = _as_commands(machine, q)
    lib = _backend(backend)
    if lib is not None:
        from . import _kernel
        p, _, bad = _kernel.forward(lib, machine, q, errors, strict, orientation=False)
        if bad < 0:
            return p
    return forward(machine, q, errors, strict, backend="numpy").p


def deviations(machine: Machine, q_prog, q_emit, errors: ErrorSet | None, strict: bool = True, *,
               backend: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Distances (N,) mm of the real tool edge (errors) from the ideal machine's at the programmed
    commands q_prog: at q_prog (before compensation) and at the emitted commands q_emit (after).
    The check of a compensated program: with the compiled kernel one pass that shares the rotary
    sines and cosines of a pose's three positions, else three `forward_position` passes."""
    q_prog = _as_commands(machine, q_prog)
    q_emit = _as_commands(machine, q_emit)
    if q_prog.shape != q_emit.shape:
        raise ValueError(f"q_prog {q_prog.shape} and q_emit {q_emit.shape} differ in shape")
    lib = _backend(backend)
    if lib is not None:
        from . import _kernel
        before, after, bad = _kernel.check(lib, machine, q_prog, q_emit, errors, strict)
        if bad < 0:
            return before, after
    target = forward_position(machine, q_prog, backend=backend)
    norm = lambda d: np.sqrt(np.einsum("ij,ij->i", d, d))  # noqa: E731
    return (norm(forward_position(machine, q_prog, errors, strict, backend=backend) - target),
            norm(forward_position(machine, q_emit, errors, strict, backend=backend) - target))


class SwingError(MtcompError):
    """The compensation would turn a rotary axis further in one block than allowed."""

    def __init__(self, index: int, axis: str, swing: float, limit: float):
        self.index, self.axis, self.swing = index, axis, swing
        super().__init__(
            f"point {index}: the compensation turns axis {axis} by {swing:.4f} deg beyond the programmed "
            f"motion in one block (max_swing {limit:g} deg); alternatives: position-only compensation with "
            "the rotary axes as programmed (3-axis mode: mtcomp workpiece-setting compensate --mode 3axis), "
            "holding the pole axis (a larger pole_tolerance), or a larger max_swing to accept this branch")


def _check_swing(machine: Machine, q: np.ndarray, q0: np.ndarray, max_swing: float | None) -> None:
    """Raise SwingError at the first block whose rotary correction changes by more than
    max_swing (deg) from the previous block's (the first block: from the programmed angles)."""
    rot = list(machine.rotary_indices)
    if max_swing is None or not rot or not len(q):
        return
    c = q[:, rot] - q0[:, rot]
    s = np.abs(np.diff(c, axis=0, prepend=0.0))
    over = np.argwhere(~(s <= max_swing))
    if over.size:
        i, j = over[0]
        raise SwingError(int(i), machine.axes[rot[j]].name, float(s[i, j]), max_swing)


def _raise_kernel_failures(machine: Machine, errors, q, res, status, info) -> None:
    from . import _kernel
    from .errors import TableRangeError
    if not status.any():  # the usual case: one pass, no index arrays
        return
    bad = np.nonzero(status == _kernel.E_CONVERGE)[0]
    if bad.size:
        raise ConvergenceError(int(bad[0]), float(res[bad[0]]))
    bad = np.nonzero(status == _kernel.E_RANGE)[0]
    if bad.size:
        i = int(bad[0])
        ax = machine.axes[int(info[i])].name
        lo, hi = errors.geometric.tables[ax].range
        raise TableRangeError(ax, i, float(q[i, int(info[i])]), lo, hi)
    if np.any(status != 0):
        raise RuntimeError(f"kinematic kernel status {int(status[status != 0][0])}")


def compensate(machine: Machine, target: Pose, errors: ErrorSet | None = None, q0=None, *,
               tol: float = 1e-10, max_iter: int = 60, pole_tolerance: float | None = None,
               continuation: bool = True, max_swing: float | None = None,
               backend: str | None = None) -> np.ndarray:
    """Axis commands (N, n_axes) in mm and deg that put the real tool edge at target.p and the
    tool in target's orientation (tool direction on machines with 1-2 rotary axes, full
    orientation with 3), under `errors`.

    q0 seeds the iteration (usually the programmed commands, in path order).  Gauss-Newton with
    a chord Jacobian, the analytic one of the rigid (setting-error) model: the geometric tables
    change it by their slopes only (1e-3 at most), so each step contracts the error by about
    that factor.  Points that do not contract (large workpiece rotations near a singularity)
    get their Jacobian re-taken at the current iterate, i.e. full Newton.  Steps are damped
    least squares without components along null directions: where the tool direction leaves
    a rotary axis free it keeps q0's value.  The compiled kernel uses the full model's analytic
    Jacobian (table slopes in it) where there are tables or location errors; the results agree
    to 1e-9.  docs/model.md gives the details.

    Poles (pole_tolerance, deg; default POLE_TOLERANCE, 0 disables): where a rotary axis' effect
    on the orientation lies within the tolerance of what the other rotary axes do (C at B = 0 on
    a B-C table, A and C at B = 90 on an A-B-C head) at the exact solution for the target's
    orientation (the rigid model with the blank's rotation: the real machine's pole, decided by
    the target alone, docs/model.md), that axis keeps its programmed value, the
    others meet the orientation in least squares and the position exactly, as controls hold
    the pole axis; this is kept if the orientation is then within pole_tolerance, so a small
    blank tilt never turns C by tens of degrees.  Otherwise the exact solution: from q0 (along a
    path first or then from the previous point's correction, see continuation) and, where that
    fails, from rotary seeds offset by +-90 and 180 deg (one axis, then pairs), keeping the
    smallest rotary change.  Points that fail from every seed raise ConvergenceError.

    continuation: the compiled kernel starts each point from the previous point's correction
    (warm start: fewer iterations, and a path keeps the rotary branch it is on); the numpy
    reference solves every point from q0 (both agree wherever the solution is unique).
    max_swing (deg, None: no bound): SwingError at the first point whose rotary correction
    changes by more than this from the previous point's.
    backend: None (compiled kernel where available, else numpy), "c" or "numpy" (reference).
    """
    if q0 is None:
        raise ValueError("compensate needs initial commands q0 (e.g. the programmed axis positions)")
    q0 = _as_commands(machine, q0)
    if len(target) != len(q0):
        raise ValueError(f"target has {len(target)} poses, q0 has {len(q0)}")
    _finite_commands(machine, q0)
    pole_tolerance = POLE_TOLERANCE if pole_tolerance is None else float(pole_tolerance)
    lib = _backend(backend)
    if lib is not None:
        from . import _kernel
        q, res, status, info = _kernel.solve(lib, machine, errors, q0, target=target, tol=tol, max_iter=max_iter,
                                             pole_tolerance=pole_tolerance, continuation=continuation)
        _raise_kernel_failures(machine, errors, q, res, status, info)
    else:
        from ._solver import compensate_numpy
        q = compensate_numpy(machine, target, errors, q0, tol, max_iter, pole_tolerance)
    _check_swing(machine, q, q0, max_swing)
    return q


def round_to_resolution(machine: Machine, q: np.ndarray) -> np.ndarray:
    """Round commands to each axis' resolution (the machine can only be told multiples of it)."""
    res = machine.resolutions
    return np.round(q / res) * res


def check_limits(machine: Machine, q: np.ndarray) -> None:
    """Raise LimitError naming the first point and axis outside its travel."""
    for k, ax in enumerate(machine.axes):
        lo, hi = ax.limits
        tol = 0.5 * ax.resolution  # a command rounded to the resolution may sit a few ulp outside
        bad = np.nonzero((q[:, k] < lo - tol) | (q[:, k] > hi + tol))[0]
        if bad.size:
            raise LimitError(ax.name, int(bad[0]), float(q[bad[0], k]), ax.limits)


def retarget(machine: Machine, q_programmed, errors: ErrorSet | None, *, round_result: bool = False,
             check: bool = True, pole_tolerance: float | None = None, continuation: bool = True,
             max_swing: float | None = None, backend: str | None = None) -> np.ndarray:
    """Compensated commands for a program written for the ideal machine: the real machine with
    `errors` then puts the tool where the ideal machine would have put it.  q_programmed in
    program order (see `compensate` for the pole, continuation, max_swing and backend options)."""
    q_programmed = _as_commands(machine, q_programmed)
    if errors is None or errors.is_zero:
        q = q_programmed.copy()
    else:
        _finite_commands(machine, q_programmed)
        pole_tolerance = POLE_TOLERANCE if pole_tolerance is None else float(pole_tolerance)
        lib = _backend(backend)
        if lib is not None:
            from . import _kernel
            q, res, status, info = _kernel.solve(lib, machine, errors, q_programmed, tol=1e-10, max_iter=60,
                                                 pole_tolerance=pole_tolerance, continuation=continuation)
            _raise_kernel_failures(machine, errors, q, res, status, info)
        else:
            from ._solver import compensate_numpy, retarget_rigid
            q = retarget_rigid(machine, q_programmed, errors)
            if q is None:
                q = compensate_numpy(machine, forward(machine, q_programmed, backend="numpy"), errors,
                                     q_programmed, 1e-10, 60, pole_tolerance)
        _check_swing(machine, q, q_programmed, max_swing)
    if round_result:
        q = round_to_resolution(machine, q)
    if check:
        check_limits(machine, q)
    return q
