"""Adversarial but physically possible cases for the compiled kernel's inverse model (fmu/c/mtk.c):
steep and curved error tables, uneven grids, poses on knots and at table ends, paths that cross
knots or reverse, rotary angles through +-180 and 360 deg, angle steps about the kernel's switch
from sin/cos to the angle sum (1e-2 rad), steps just under its no-evaluation thresholds, poles, threads
and chunk boundaries.  Each case asserts the truth from the forward model: the real machine at the
compensated commands puts the tool on the ideal pose (5e-10 mm, tool direction 1e-11), and the
commands agree with the numpy reference to 1e-9."""
import numpy as np
import pytest

from mtcomp import _kernel
from mtcomp.errors import (AxisErrorTable, ErrorSet, GeometricErrors, ToolSetting, WorkpieceSetting,
                           component_names)
from mtcomp.kinematics import forward, retarget
from mtcomp.machine import load_machine

from _models import random_errors

pytestmark = pytest.mark.skipif(not _kernel.available(), reason="no C compiler: the numpy reference runs alone")

POS_TOL = 5e-10     # mm: the iteration stops at steps below 1e-10 mm or deg
DIR_TOL = 1e-11     # tool direction (unit vector)
PARITY = 1e-9       # mm or deg, C against numpy


def _table(axis, pos, vals):
    """AxisErrorTable of `axis` from positions (n,) and the six components (n, 6): mm, then rad."""
    vals = np.asarray(vals, dtype=float)
    return AxisErrorTable(axis, pos, {c: vals[:, j] for j, c in enumerate(component_names(axis))})


def _assert_true_pose(m, q, E, qc, pos_tol=POS_TOL, label=""):
    """The real machine at qc puts the tool where the ideal machine puts it at q."""
    ideal, real = forward(m, q, backend="numpy"), forward(m, qc, E, backend="numpy")
    ep = np.max(np.abs(real.p - ideal.p), axis=1)
    assert ep.max() <= pos_tol, f"{label} position off by {ep.max():.3g} mm at pose {ep.argmax()}"
    if m.n_rotary:
        a = np.asarray(m.tool_axis, dtype=float)
        ev = np.max(np.abs(real.R @ a - ideal.R @ a), axis=1)
        assert ev.max() <= DIR_TOL, f"{label} tool direction off by {ev.max():.3g} at pose {ev.argmax()}"


def _check(m, q, E, parity=True, label="", **kw):
    qc = retarget(m, q, E, backend="c", check=False, **kw)
    _assert_true_pose(m, q, E, qc, label=label)
    if parity:
        qn = retarget(m, q, E, backend="numpy", check=False, **kw)
        d = np.max(np.abs(qc - qn))
        assert d <= PARITY, f"{label} C and numpy differ by {d:.3g}"
    return qc


# --------------------------------------------------------------------- steep tables, no evaluation

def _steep_vmc_tables(m, seed, off=200e-6, slope=20e-6, trans=7e-3, h=3.0):
    """Tables every h mm on X, Y, Z: a constant angle of `off` rad in a random direction plus a
    zigzag of `slope` rad per mm (a second difference of 2 slope h per knot) in another, and
    zigzag straightness of up to `trans` mm per mm."""
    rng = np.random.default_rng(seed)
    tabs = {}
    for a in m.axes:
        lo, hi = a.limits
        pos = np.arange(lo, hi + 1e-9, h)
        zig = (-1.0) ** np.arange(pos.size) * 0.5 * h
        o = rng.uniform(-1, 1, 3)
        o *= off / np.linalg.norm(o)
        s = rng.normal(size=3)
        s *= slope / np.linalg.norm(s)
        d = rng.uniform(-trans, trans, 3)
        tabs[a.name] = _table(a.name, pos, np.column_stack([np.outer(zig, d), o + np.outer(zig, s)]))
    return ErrorSet(geometric=GeometricErrors(tabs, {})), rng


@pytest.mark.parametrize("seed", [0, 17, 18, 22])
def test_steps_without_evaluation_under_large_table_angles(seed):
    """Found by search: tables with angles of 200 µrad changing by 20 µrad per mm over 3 mm
    intervals, a path of 0.2 mm steps.  The Jacobian took an error motion's angular velocity as
    the slope of its angles, exact only to first order in the angles: off by (angle x slope) / 2
    times the lever to the tool (about 1e-6 mm per mm here), so a warm-start step of 1e-3 mm taken
    without an evaluation (the bound on the model's curvature says linear to 5e-11 mm) missed the
    pose by up to 7e-10 mm.  The kernel now uses the exact rate (the rotation vector's Jacobian)."""
    m = load_machine("vmc-moving-column")
    E, rng = _steep_vmc_tables(m, seed)
    d = rng.uniform(-1, 1, 3)
    d /= np.linalg.norm(d)
    q = np.array([-150.1, -50.2, -100.3]) + 0.2 * np.outer(np.arange(200), d)
    _check(m, q, E, label=f"seed {seed}")
