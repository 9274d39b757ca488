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

from _models import kernel_stats, random_errors

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


# --------------------------------------------------------------------- grids, knots and table ends

#: Steepest slopes of a real error table: 10 µm and 20 µrad per mm on a linear axis, 1 µm and
#: 5 µrad per deg on a rotary one (a table twice as steep as its travel is not a machine: the
#: corrected position is then not unique).
SLOPE_LIN = np.array([10e-3] * 3 + [20e-6] * 3)
SLOPE_ROT = np.array([1e-3] * 3 + [5e-6] * 3)


def _curved_tables(m, rng, n_knots=41, uneven=True, trans=30e-3, ang=60e-6, rot_span=None):
    """Tables on every axis over its travel with large curvature: values alternating in sign knot
    to knot (second differences of up to 4x the amplitude, as steep as SLOPE_* allows), knots
    crowded unevenly (spacings from a fraction of a mm to tens of mm)."""
    tabs = {}
    for a in m.axes:
        lo, hi = a.limits if rot_span is None or not a.is_rotary else rot_span
        if uneven:
            u = np.sort(rng.uniform(0.0, 1.0, n_knots - 2))
            pos = lo + (hi - lo) * np.concatenate([[0.0], u ** 2, [1.0]])
            pos = np.unique(pos)
        else:
            pos = np.linspace(lo, hi, n_knots)
        sign = (-1.0) ** np.arange(pos.size)
        gap = np.diff(pos)
        gap = np.minimum(np.concatenate([[gap[0]], gap]), np.concatenate([gap, [gap[-1]]]))
        amp = np.minimum(np.array([trans] * 3 + [ang] * 3)[None, :],
                         0.5 * gap[:, None] * (SLOPE_ROT if a.is_rotary else SLOPE_LIN)[None, :])
        vals = sign[:, None] * rng.uniform(0.3, 1.0, (pos.size, 6)) * amp
        tabs[a.name] = _table(a.name, pos, vals)
    return tabs


def _errors_with(m, tabs, rng, wp_angle=0.05):
    base = random_errors(m, rng, wp_angle=wp_angle if m.n_rotary else 0.5)
    return ErrorSet(base.tool, base.workpiece, GeometricErrors(tabs, base.geometric.location))


PRESETS = ["robonano-ui", "robonano-a0ib", "vmc-moving-column"]


def _mid_commands(m, n, rng, span=0.3):
    lo = np.array([20.0 if a.is_rotary else a.limits[0] * span for a in m.axes])
    hi = np.array([50.0 if a.is_rotary else a.limits[1] * span for a in m.axes])
    return rng.uniform(lo, hi, (n, m.n_axes))


@pytest.mark.parametrize("name", PRESETS)
def test_poses_on_knots_of_uneven_curved_tables(name):
    """Programmed poses exactly on knots (every axis at once, and one axis at a time), at the
    first and last knot of a rotary table spanning less than the travel, and paths whose every
    pose lies on a knot: the iterates start in the interval right of the knot and the solution
    lies left or right of it."""
    m = load_machine(name)
    rng = np.random.default_rng(31)
    tabs = _curved_tables(m, rng)
    E = _errors_with(m, tabs, rng)
    q = _mid_commands(m, 300, rng)
    for k, a in enumerate(m.axes):
        pos = tabs[a.name].position
        inner = pos[(pos > (20.0 if a.is_rotary else 0.3 * a.limits[0])) &
                    (pos < (50.0 if a.is_rotary else 0.3 * a.limits[1]))]
        if inner.size:
            q[:100, k] = rng.choice(inner, 100)            # all axes on knots
            q[100 + 30 * k:130 + 30 * k, k] = rng.choice(inner, 30)
    _check(m, q, E, label="knots")
    # a path stepping from knot to knot on one axis at a time, then back (reversal on a knot)
    for k, a in enumerate(m.axes):
        pos = tabs[a.name].position
        sel = pos[(pos > (0.0 if a.is_rotary else 0.2 * a.limits[0])) &
                  (pos < (60.0 if a.is_rotary else 0.2 * a.limits[1]))][:40]
        path = np.repeat(_mid_commands(m, 1, rng), 2 * sel.size, axis=0)
        path[:, k] = np.concatenate([sel, sel[::-1]])
        _check(m, path, E, label=f"knot path {a.name}")


@pytest.mark.parametrize("name", ["robonano-a0ib", "vmc-moving-column"])
def test_table_ends_and_beyond_the_last_knot(name):
    """Poses at the first and last knot, where the correction pushes the axis outward (beyond
    the table: both backends raise TableRangeError naming the same axis and pose) or inward."""
    from mtcomp.errors import TableRangeError
    m = load_machine(name)
    rng = np.random.default_rng(41)
    tabs = _curved_tables(m, rng, rot_span=(-30.0, 80.0))
    E = _errors_with(m, tabs, rng)
    lin = [k for k, a in enumerate(m.axes) if not a.is_rotary][0]
    name_l = m.axes[lin].name
    lo, hi = tabs[name_l].range
    base = _mid_commands(m, 1, rng)[0]
    outcomes = {}
    for end in (lo, hi):
        q = np.repeat(base[None], 3, axis=0)
        q[1, lin] = end
        res = {}
        for be in ("c", "numpy"):
            try:
                res[be] = retarget(m, q, E, backend=be, check=False)
            except TableRangeError as exc:
                res[be] = (exc.axis, exc.index)
        assert type(res["c"]) is type(res["numpy"]), (end, res)
        if isinstance(res["c"], tuple):
            assert res["c"] == res["numpy"] == (name_l, 1)
        else:
            _assert_true_pose(m, q, E, res["c"])
            assert np.max(np.abs(res["c"] - res["numpy"])) <= PARITY
        outcomes[end] = isinstance(res["c"], tuple)
    # inside by more than the correction (setting errors up to 1 mm each): exact
    q = np.repeat(base[None], 50, axis=0)
    q[:25, lin] = lo + np.geomspace(3.0, 8.0, 25)
    q[25:, lin] = hi - np.geomspace(3.0, 8.0, 25)
    _check(m, q, E, label="near ends")
    # a program beyond the last knot is the reference's error, not a silent hold of the end values
    q[3, lin] = hi + 1e-3
    for be in ("c", "numpy"):
        with pytest.raises(TableRangeError) as exc:
            retarget(m, q, E, backend=be, check=False)
        assert exc.value.axis == name_l and exc.value.index == 3


@pytest.mark.parametrize("name", PRESETS)
def test_paths_crossing_a_knot_every_pose_and_reversing(name):
    """Knots every 0.05 mm (0.05 deg) over a stretch, a path of 0.07 mm (deg) steps crossing one
    at almost every pose, then back over the same stretch with a reversal every 7 poses: the
    previous interval (the hint) is wrong at almost every lookup."""
    m = load_machine(name)
    rng = np.random.default_rng(51)
    tabs = {}
    for a in m.axes:
        lo, hi = a.limits
        pos = np.concatenate([[lo], np.arange(-3.0, 30.0, 0.05), [hi]])
        vals = (-1.0) ** np.arange(pos.size)[:, None] * rng.uniform(0.3, 1, (pos.size, 6)) \
            * np.array([2e-4] * 3 + [2e-6] * 3)   # 4 µm per mm, 40 µrad per mm
        tabs[a.name] = _table(a.name, pos, vals)
    E = _errors_with(m, tabs, rng)
    n = 400
    s = 0.07 * np.arange(n)
    zig = np.abs(((np.arange(n) + 3) % 14) - 7) * 0.07     # forth and back every 7 poses
    q = np.empty((2 * n, m.n_axes))
    for k, a in enumerate(m.axes):
        q[:n, k] = 0.013 * (k + 1) + s * (0.5 + 0.1 * k) % 25.0
        q[n:, k] = 5.0 + 0.021 * k + zig * (1 + 0.3 * k)
        if a.is_rotary and a.name == "B" and name == "robonano-a0ib":
            q[:, k] += 10.0   # away from the pole (its own test)
    _check(m, q, E, label="crossing")


# --------------------------------------------------------------------- rotary angles

DEG_PER_RAD = 180.0 / np.pi


def _rotary_path(m, n, rng, rot_values):
    """A path with the linear axes moving slowly and the rotary axes given per pose (dict)."""
    q = np.repeat(_mid_commands(m, 1, rng), n, axis=0)
    for k, a in enumerate(m.axes):
        if not a.is_rotary:
            q[:, k] += np.linspace(0.0, 2.0, n) * (0.3 + 0.2 * k)
        elif a.name in rot_values:
            q[:, k] = rot_values[a.name]
    return q


@pytest.mark.parametrize("name", ["robonano-a0ib", "robonano-ui"])
def test_rotary_angles_through_180_and_360(name):
    """C through +-180 deg (continuously, and as a program that wraps from 179.99 to -179.99), up
    to 359 and down to -359 deg; on the head A through +-180 too.  The C table spans the whole
    travel, so its knots sit at the wrap."""
    m = load_machine(name)
    rng = np.random.default_rng(61)
    tabs = _curved_tables(m, rng, uneven=False, n_knots=145)   # C: a knot every 5 deg
    E = _errors_with(m, tabs, rng)
    n = 240
    t = np.linspace(0.0, 1.0, n)
    cases = {
        "C through 180": {"C": 170.0 + 20.0 * t},
        "C through -180": {"C": -170.0 - 20.0 * t},
        "C wraps": {"C": np.where(t < 0.5, 179.9 + 0.18 * t, -179.99 + 0.18 * (t - 0.5))},
        "C to 359": {"C": 340.0 + 19.0 * t},
        "C to -359": {"C": -340.0 - 19.0 * t},
    }
    if name == "robonano-ui":
        cases["A through 180"] = {"A": 175.0 + 10.0 * t, "B": 30.0 + 0 * t}
        cases["A through -180"] = {"A": -175.0 - 10.0 * t, "B": -30.0 + 0 * t}
    for label, rot in cases.items():
        if "B" not in rot:
            rot = dict(rot, B=25.0 + 5.0 * t)   # away from the poles
        _check(m, _rotary_path(m, n, rng, rot), E, label=label)


@pytest.mark.parametrize("name", ["robonano-a0ib", "robonano-ui"])
def test_rotary_steps_about_the_sincos_switch(name):
    """The kernel takes a rotary angle's sine and cosine by the angle sum from a reference angle
    within 1e-2 rad, else directly (and makes it the reference): steps of 1e-2 rad and a hair
    below and above, a slow drift away from the reference over many poses, and an oscillation
    about the switch's distance."""
    m = load_machine(name)
    rng = np.random.default_rng(71)
    E = _errors_with(m, _curved_tables(m, rng), rng)
    sw = 1e-2 * DEG_PER_RAD
    n = 200
    k = np.arange(n)
    cases = {
        "at": 20.0 + sw * k * 0.25,
        "below": 20.0 + (sw * (1 - 1e-9)) * k * 0.25,
        "above": 20.0 + (sw * (1 + 1e-9)) * k * 0.25,
        "one switch per pose": 20.0 + (sw * (1 + 1e-12)) * k,
        "drift": 20.0 + 1e-4 * k ** 1.5,
        "oscillation": 20.0 + sw * (1 + 1e-7 * (-1) ** k) * (k % 2),
    }
    for label, c in cases.items():
        _check(m, _rotary_path(m, n, rng, {"C": c, "B": 25.0 + 0.3 * np.sin(0.1 * k)}), E, label=label)


# --------------------------------------------------------------------- steps about the thresholds

@pytest.mark.parametrize("name", PRESETS)
def test_steps_just_under_and_over_the_no_evaluation_thresholds(name):
    """Program steps that make the corrections change by about what the kernel takes without an
    evaluation (linear steps of 1e-4 mm, rotary steps of 1e-5 deg, within one table interval):
    steps of 0.9, 1, 1.1, 10 and 100 times those, at the far ends of the travels (the largest
    levers) and with tool and workpiece offsets of 1 mm."""
    m = load_machine(name)
    rng = np.random.default_rng(81)
    E = _errors_with(m, _curved_tables(m, rng, uneven=False), rng)
    mult = np.array([0.9, 1.0, 1.1, 10.0, 100.0, 0.99, 1.01])
    n = 350
    q = np.empty((n, m.n_axes))
    for k, a in enumerate(m.axes):
        unit = 1e-5 if a.is_rotary else 1e-4
        steps = unit * mult[(np.arange(n) + k) % mult.size] * rng.choice([-1.0, 1.0], n)
        if a.is_rotary:
            start = 35.0 if a.name != "B" else 40.0
        else:
            start = 0.9 * a.limits[1] if k % 2 else 0.9 * a.limits[0]
        q[:, k] = start + np.cumsum(steps)
    _check(m, q, E, label="thresholds")


# --------------------------------------------------------------------- poles

@pytest.mark.parametrize("name,pole", [("robonano-a0ib", 0.0), ("robonano-ui", 90.0)])
def test_near_pole_poses_with_tables(name, pole):
    """B at, inside and just outside the pole tolerance (0.2 deg) of the pole, with tables and a
    blank tilted by 0.01 deg: the position is exact (held pole axis: the tool direction is then
    met in least squares, so within the tolerance; else exactly), the commands those of numpy."""
    m = load_machine(name)
    b = [k for k, a in enumerate(m.axes) if a.name == "B"][0]
    rng = np.random.default_rng(91)
    E = _errors_with(m, _curved_tables(m, rng), rng, wp_angle=0.01)
    offs = np.array([0.0, 1e-9, 1e-6, 0.1, 0.19, 0.199, 0.2, 0.201, 0.21, 0.3, 1.0])
    offs = np.concatenate([offs, -offs[1:]])
    q = np.repeat(_mid_commands(m, 1, rng), offs.size * 4, axis=0)
    q[:, b] = pole + np.tile(offs, 4)
    q += np.repeat(rng.uniform(-0.5, 0.5, (4, m.n_axes)), offs.size, axis=0) * \
        np.array([0.0 if a.name == "B" else 1.0 for a in m.axes])
    for cont in (False, True):
        qc = retarget(m, q, E, backend="c", check=False, continuation=cont)
        ideal, real = forward(m, q, backend="numpy"), forward(m, qc, E, backend="numpy")
        assert np.max(np.abs(real.p - ideal.p)) <= 1e-9
        a = np.asarray(m.tool_axis, dtype=float)
        ang = np.degrees(np.arccos(np.clip(np.sum((real.R @ a) * (ideal.R @ a), axis=1), -1, 1)))
        assert np.max(ang) <= 0.2
        far = np.abs(q[:, b] - pole) > 0.5   # beyond the tolerance: exact
        assert np.max(np.abs(real.R[far] @ a - ideal.R[far] @ a)) <= DIR_TOL
        if not cont:
            qn = retarget(m, q, E, backend="numpy", check=False, continuation=False)
            assert np.max(np.abs(qc - qn)) <= PARITY


def _real_pole_distance(m, q, Rw):
    """Angle (deg) between the C axis and the tool on a0ib at the exact solution for the ideal
    poses of q with the blank turned by Rw: the C table carries the blank, so the C axis is z in
    the blank's frame and the tool must point along Rw v_ideal there (analytic, no solve)."""
    v = forward(m, q, backend="numpy").v @ Rw.T
    return np.degrees(np.arccos(np.clip(v[:, 2], -1.0, 1.0)))


@pytest.mark.parametrize("tables", [False, True])
def test_pole_rule_is_the_real_machines_pole_distance_of_the_target(tables):
    """The pole axis is held where the real machine (its blank turned) would be within the pole
    tolerance of its pole at the exact solution, whatever the programmed angles say: the exact
    solution turns the pole axis by about (direction error) / sin(distance), which the rule bounds,
    and the held solution misses the tool direction by at most that distance.  The decision is the
    target's alone: C with and without continuation and numpy hold the same poses and give the
    same commands, and along a path it changes only where the distance crosses the tolerance.
    a0ib (C on B carry the blank); setting errors alone (the closed form) and with tables."""
    m = load_machine("robonano-a0ib")
    rng = np.random.default_rng(141)

    def errs(angles):
        ws = WorkpieceSetting((0.03, -0.02, 0.01), angles)
        if not tables:
            return ErrorSet(workpiece=ws)
        return ErrorSet(workpiece=ws, geometric=GeometricErrors(_curved_tables(m, rng, ang=5e-6, trans=1e-3), {}))

    a = np.asarray(m.tool_axis, dtype=float)

    def run(q, E):
        out = {cont: _kernel.solve(_kernel.load(), m, E, q, tol=1e-10, max_iter=60, pole_tolerance=0.2,
                                   continuation=cont) for cont in (True, False)}
        for cont, (qc, _, st, _) in out.items():
            assert not st.any()
            ideal, real = forward(m, q, backend="numpy"), forward(m, qc, E, backend="numpy")
            assert np.max(np.abs(real.p - ideal.p)) <= POS_TOL
        qn = retarget(m, q, E, backend="numpy", check=False)
        # C within a degree of the real pole: its difference as it turns the tool (times the sine
        # of the distance over that of 1 deg), as the iterations stop on the residual (1e-10 deg
        # of C turn the tool by 1e-10 sin(distance))
        s = np.minimum(1.0, np.sin(np.radians(_real_pole_distance(m, q, E.workpiece.matrix))) / np.sin(np.radians(1.0)))
        for cont in (True, False):
            d = np.abs(out[cont][0] - qn)
            d[:, 0] *= s
            assert np.max(d) <= PARITY
        assert np.array_equal(out[True][3], out[False][3])
        return out[True][0], out[True][3], forward(m, out[True][0], E, backend="numpy")

    # A 3-axis raster at B = C = 0 (paper 001's pyramid program) on a blank tilted 0.277 deg off
    # the C axis: outside the tolerance at every pose, although the program sits on the pole.
    n = 400
    q = np.zeros((n, 5))
    q[:, 2] = np.linspace(-2.0, 2.0, n)
    q[:, 3] = 0.5 * np.sin(np.linspace(0.0, 9.0, n))
    q[:, 4] = -1.0 + 0.1 * np.cos(np.linspace(0.0, 5.0, n))
    E = errs((0.12, -0.25, 0.8))
    Rw = E.workpiece.matrix
    dist = _real_pole_distance(m, q, Rw)
    assert np.all(dist > 0.27)
    qc, held, real = run(q, E)
    assert np.all(held == -1)
    assert np.max(np.abs(real.v - forward(m, q, backend="numpy").v)) <= DIR_TOL
    assert np.abs(np.abs(qc[:, 1]) - dist).max() <= (1e-3 if tables else 1e-9)
    # C turned once, the same at every pose (tables: their µrad over the sine of the distance)
    assert np.ptp(qc[:, 0]) <= (0.2 if tables else 1e-8)
    # The same program on a blank tilted within the tolerance (0.156 deg): every pose held at C = 0.
    E = errs((0.1, -0.12, 0.5))
    qc, held, real = run(q, E)
    assert np.all(held == 0) and np.all(qc[:, 0] == 0.0)
    miss = np.degrees(np.arccos(np.clip(np.sum(real.v * forward(m, q, backend="numpy").v, axis=1), -1, 1)))
    assert np.max(miss) <= np.max(_real_pole_distance(m, q, E.workpiece.matrix)) + 1e-3
    # B programmed from -1 to 1 deg at C = 0 on a blank tilted 0.15 deg about y and 0.03 deg about x:
    # the real machine's pole lies at B = -0.15 deg of the program (0.03 deg off it); the held poses
    # are those within 0.2 deg of it (B from -0.345 to 0.045, one stretch), not those within 0.2 deg
    # of the programmed pole.  At B = 0.1 the program is within the tolerance and the real machine
    # 0.25 deg off (solved exactly); at B = -0.3 the reverse (held: the exact solution would turn C
    # by about 11 deg).
    n = 401
    q = np.zeros((n, 5))
    q[:, 1] = np.linspace(-1.0, 1.0, n)
    q[:, 2] = np.linspace(-1.0, 1.0, n)
    E = errs((0.03, 0.15, 0.0))
    dist = _real_pole_distance(m, q, E.workpiece.matrix)
    qc, held, real = run(q, E)
    clear = np.abs(dist - 0.2) > 2e-3         # (tables: the rule's rigid model within µrad)
    assert np.array_equal((held == 0)[clear], (dist < 0.2)[clear])
    hi = np.nonzero(held == 0)[0]
    assert hi.size and np.array_equal(hi, np.arange(hi[0], hi[-1] + 1))     # one stretch
    for b in (0.1, -0.3):
        i = int(np.argmin(np.abs(q[:, 1] - b)))
        assert (held[i] == 0) == (b == -0.3)
    assert np.all(qc[held == 0, 0] == 0.0)
    far = held < 0
    assert np.max(np.abs(real.v[far] - forward(m, q[far], backend="numpy").v)) <= DIR_TOL


# --------------------------------------------------------------------- threads and chunks

def test_threads_and_chunk_boundaries_on_a_knot_crossing_path(monkeypatch):
    """Two chunks and a bit (4,096 poses each) of a path crossing knots of steep tables, on 1 and
    2 threads: the same bits, and every pose on the ideal pose, also the ones after a chunk
    boundary (started from the run-in before it)."""
    m = load_machine("robonano-a0ib")
    rng = np.random.default_rng(101)
    E = _errors_with(m, _curved_tables(m, rng), rng)
    n = 2 * _kernel.CHUNK + 50
    t = np.linspace(0.0, 1.0, n)
    q = np.empty((n, 5))
    q[:, 0] = 10.0 + 40.0 * t          # C
    q[:, 1] = 20.0 + 10.0 * np.sin(9 * t)   # B
    q[:, 2] = -30.0 + 60.0 * t         # X
    q[:, 3] = 10.0 * np.cos(17 * t)    # Y (reverses)
    q[:, 4] = -5.0 + 3.0 * t           # Z
    out = {}
    for th in ("1", "2"):
        monkeypatch.setenv("MTCOMP_THREADS", th)
        out[th] = retarget(m, q, E, backend="c", check=False)
    assert np.array_equal(out["1"], out["2"])
    _assert_true_pose(m, q, E, out["1"], label="chunked")
    edge = np.r_[_kernel.CHUNK - 20:_kernel.CHUNK + 20, 2 * _kernel.CHUNK - 20:2 * _kernel.CHUNK + 20]
    qn = retarget(m, q[edge], E, backend="numpy", check=False)
    assert np.max(np.abs(out["1"][edge] - qn)) <= PARITY


@pytest.mark.parametrize("name,pole", [("robonano-a0ib", 0.0), ("robonano-ui", 90.0)])
def test_pole_decision_with_repeated_programmed_angles_and_new_targets(name, pole):
    """The kernel decides the pole axis once while the programmed rotary angles and the target
    orientation stay the same: given targets (compensate) whose orientations change from pose to
    pose under the same programmed angles (in stretches, inside and outside the tolerance) get
    each their own decision, the reference's."""
    from mtcomp.kinematics import compensate
    m = load_machine(name)
    b = [k for k, a in enumerate(m.axes) if a.name == "B"][0]
    rng = np.random.default_rng(111)
    E = _errors_with(m, _curved_tables(m, rng), rng, wp_angle=0.01)
    n = 8
    q0 = np.repeat(_mid_commands(m, 1, rng), n, axis=0)
    q0[:, b] = pole + np.repeat([0.19, 0.21, 0.1, 0.3], n // 4)   # (at 0.2 exactly: a tie by rounding)
    qt = q0.copy()
    qt[:, b] = pole + np.where(np.arange(n) % 2, 0.05, 0.5) + rng.uniform(-0.03, 0.03, n)
    target = forward(m, qt, backend="numpy")
    for cont in (False, True):
        qc = compensate(m, target, E, q0, backend="c", continuation=cont)
        real = forward(m, qc, E, backend="numpy")
        assert np.max(np.abs(real.p - target.p)) <= 1e-9
        if not cont:
            assert np.max(np.abs(qc - compensate(m, target, E, q0, backend="numpy"))) <= PARITY


# --------------------------------------------------------------------- paths on an earlier Jacobian

def _earlier_jacobian_path(m, n=3000):
    """A path sweeping every axis, the step length changing, with a stop and a reversal; B from 3 deg
    above its pole (0 deg on a B-C table, 90 on an A-B-C head) through it to 3 deg below."""
    pole = 90.0 if m.n_rotary == 3 else 0.0
    t = np.concatenate([np.linspace(0.0, 0.4, 1200), np.full(10, 0.4), np.linspace(0.4, 1.0, 1200),
                        np.linspace(1.0, 0.7, n - 2410)])
    q = np.empty((t.size, m.n_axes))
    for k, a in enumerate(m.axes):
        lo, hi = a.limits
        if a.is_rotary:
            q[:, k] = pole + 3.0 - 6.0 * t if a.name == "B" else 20.0 + 50.0 * t
        else:
            q[:, k] = 0.5 * (lo + hi) + 0.02 * (hi - lo) * np.sin(3.0 * (k + 1) * t)
    return q, pole


@pytest.mark.parametrize("name", ["robonano-a0ib", "vmc-moving-column", "robonano-ui"])
def test_paths_solved_on_an_earlier_poses_jacobian(name):
    """Along a fine path a pose is solved on the Jacobian of an earlier pose: its residual
    evaluated, the chord step taken where the second-order bound (with three rotary axes plus the
    term for the target frame's turn since that pose) keeps the model linear over it.  A path
    sweeping every axis through steep curved tables and their knots, with the step length
    changing, a stop and a reversal, B through its pole (a0ib at 0 deg, ui at 90 deg, where the
    pole test on each pose's target must hand the poses near it back): each pose on the ideal
    pose (held ones: the position, the tool within the pole tolerance; else the tool direction,
    and with three rotary axes the whole tool frame), the same commands as the poses solved one
    by one and as numpy's."""
    m = load_machine(name)
    rng = np.random.default_rng(131)
    E = _errors_with(m, _curved_tables(m, rng), rng, wp_angle=0.01 if m.n_rotary else 0.3)
    q, pole = _earlier_jacobian_path(m)
    qc = retarget(m, q, E, backend="c", check=False)
    ideal, real = forward(m, q, backend="numpy"), forward(m, qc, E, backend="numpy")
    assert np.max(np.abs(real.p - ideal.p)) <= POS_TOL
    if m.n_rotary:
        b = [k for k, a in enumerate(m.axes) if a.name == "B"][0]
        a = np.asarray(m.tool_axis, dtype=float)
        ang = np.degrees(np.arccos(np.clip(np.sum((real.R @ a) * (ideal.R @ a), axis=1), -1, 1)))
        assert np.max(ang) <= 0.2
        far = np.abs(q[:, b] - pole) > 0.5
        assert np.max(np.abs(real.R[far] @ a - ideal.R[far] @ a)) <= DIR_TOL
        if m.n_rotary == 3:
            assert np.max(np.abs(real.R[far] - ideal.R[far])) <= DIR_TOL
        clear = np.abs(np.abs(q[:, b] - pole) - 0.2) > 0.05   # (at the tolerance either decision is right)
    else:
        clear = np.ones(len(q), dtype=bool)
    one = retarget(m, q, E, backend="c", check=False, continuation=False)
    assert np.max(np.abs(qc - one)[clear]) <= PARITY
    qn = retarget(m, q[::10], E, backend="numpy", check=False)
    assert np.max(np.abs(qc[::10] - qn)[clear[::10]]) <= PARITY


_COUNT = """
import ctypes, sys
import numpy as np
sys.path.insert(0, {tests!r})
from mtcomp import _kernel
from mtcomp.kinematics import retarget
from mtcomp.machine import load_machine
from _models import kernel_stats, random_errors
import test_kernel_stress as t
_kernel._state["lib"] = _kernel._bind(ctypes.CDLL({lib!r}))
m = load_machine("robonano-ui")
rng = np.random.default_rng(131)
E = t._errors_with(m, t._curved_tables(m, rng), rng, wp_angle=0.01)
s = np.linspace(0.0, 1.0, 2000)[:, None]
q = t._mid_commands(m, 1, rng) + s * np.array([2.0 if a.is_rotary else 1.0 for a in m.axes]) * np.sin(3.0 * s)
retarget(m, q, E, backend="c", check=False)
"""


def test_three_rotary_axes_path_poses_are_taken_on_an_earlier_jacobian(tmp_path):
    """With three rotary axes (robonano-ui) the poses of a fine path away from the pole (2,000
    poses, steps of about 1e-3 mm and deg through steep curved tables) are solved on an earlier
    pose's Jacobian too: counted in a test build (-DMTK_STATS: Jacobian passes and poses, printed
    at exit), fewer than one pass in five poses, where each pose took its own pass before."""
    stats = kernel_stats(tmp_path, _COUNT)
    assert stats["poses"] == 2000
    assert stats["jac"] < stats["poses"] / 5, stats

