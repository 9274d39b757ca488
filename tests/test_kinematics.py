import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.spatial.transform import Rotation

from mtcomp.errors import ErrorSet, GeometricErrors, ToolSetting, WorkpieceSetting
from mtcomp.kinematics import (LimitError, check_limits, Pose, compensate, forward, retarget,
                               round_to_resolution)
from mtcomp.machine import list_presets, load_machine

from _models import independent_forward, random_commands, random_errors

PRESETS = ["robonano-ui", "robonano-a0ib", "vmc-moving-column"]


def test_presets_shipped():
    assert set(PRESETS) <= set(list_presets())
    ui = load_machine("robonano-ui")
    assert ui.axis_names == ("X", "Y", "Z", "A", "B", "C")
    assert ui.axis("X").resolution == 1e-6 and ui.axis("B").resolution == 1e-5
    assert load_machine("robonano-a0ib").axis_names == ("C", "B", "X", "Y", "Z")


def test_analytic_poses_robonano_ui():
    m = load_machine("robonano-ui")
    P = forward(m, [[1, 2, 3, 0, 0, 0]])
    assert np.allclose(P.p, [[1, 2, 3]], atol=1e-15) and np.allclose(P.R[0], np.eye(3))
    # B = +90 deg turns the tool axis (+Z) about +Y onto +X (right-hand, ISO 841).
    P = forward(m, [[0, 0, 0, 0, 90, 0]], ErrorSet(ToolSetting((0, 0, 1.0))))
    assert np.allclose(P.v, [[1, 0, 0]], atol=1e-15)
    assert np.allclose(P.p, [[1, 0, 0]], atol=1e-15)  # edge 1 mm along the tool axis
    # A = 180 deg flips an edge offset (dx, dy, dz) into (dx, -dy, -dz) about the A centre.
    P = forward(m, [[0, 0, 0, 180, 0, 0]], ErrorSet(ToolSetting((0.1, 0.2, 0.3))))
    assert np.allclose(P.p, [[0.1, -0.2, -0.3]], atol=1e-14)


def test_analytic_rotary_table():
    m = load_machine("robonano-a0ib")
    # Tool at X = 10 over a table turned by C = +90 deg: the tool sits at +Y in the workpiece frame.
    P = forward(m, [[90, 0, 10, 0, 0]])
    assert np.allclose(P.p, [[0, 10, 0]], atol=1e-14)
    # Workpiece translated by (1, 2, 3) mm: the same commands reach (x - 1, y - 2, z - 3).
    P = forward(m, [[0, 0, 10, 0, 0]], ErrorSet(workpiece=WorkpieceSetting((1, 2, 3))))
    assert np.allclose(P.p, [[9, -2, -3]], atol=1e-14)


@pytest.mark.parametrize("name", PRESETS)
def test_forward_matches_independent_model(name, rng):
    m = load_machine(name)
    E = random_errors(m, rng)
    q = random_commands(m, 50, rng)
    P = forward(m, q, E)
    for k in range(len(q)):
        p, R = independent_forward(m, q[k], E)
        assert np.allclose(P.p[k], p, atol=1e-12, rtol=0)
        assert np.allclose(P.R[k], R, atol=1e-14, rtol=0)


@pytest.mark.parametrize("name", PRESETS)
def test_zero_errors_identity(name, rng):
    m = load_machine(name)
    q = random_commands(m, 200, rng)
    assert np.array_equal(retarget(m, q, ErrorSet()), q)
    assert np.allclose(compensate(m, forward(m, q), ErrorSet(), q), q, atol=1e-12)


@settings(max_examples=25, deadline=None)
@given(name=st.sampled_from(PRESETS), seed=st.integers(0, 2**32 - 1))
def test_forward_of_compensate_reproduces_target(name, seed):
    rng = np.random.default_rng(seed)
    m = load_machine(name)
    E = random_errors(m, rng, wp_angle=2.0 if m.n_rotary else 0.5)
    q_prog = random_commands(m, 64, rng, span=0.3)
    target = forward(m, q_prog)
    q = compensate(m, target, E, q_prog)
    got = forward(m, q, E)
    assert np.max(np.abs(got.p - target.p)) <= 1e-6  # 1 nm
    if m.n_rotary == 2:
        ang = np.degrees(2 * np.arcsin(np.linalg.norm(got.v - target.v, axis=1) / 2))
        assert np.max(ang) <= 1e-7
    elif m.n_rotary == 3:
        dR = np.einsum("nji,njk->nik", target.R, got.R)
        ang = np.degrees(Rotation.from_matrix(dR).magnitude())
        assert np.max(ang) <= 1e-7


@settings(max_examples=15, deadline=None)
@given(name=st.sampled_from(PRESETS), seed=st.integers(0, 2**32 - 1))
def test_compensate_of_forward_returns_commands(name, seed):
    rng = np.random.default_rng(seed)
    m = load_machine(name)
    E = random_errors(m, rng, wp_angle=0.5)
    q = random_commands(m, 32, rng, span=0.3)
    back = compensate(m, forward(m, q, E), E, q + rng.normal(0, 1e-3, q.shape))
    assert np.max(np.abs(back - q)) <= 1e-8


def test_rounding_to_resolution_keeps_nanometre(rng):
    m = load_machine("robonano-ui")
    E = random_errors(m, rng, wp_angle=0.2)
    q_prog = random_commands(m, 100, rng, span=0.2)
    q = retarget(m, q_prog, E, round_result=True)
    assert np.allclose(q, round_to_resolution(m, q), atol=0, rtol=0)
    # Rounding to 1 nm / 1e-5 deg costs at most a couple of nm at these radii.
    assert np.max(np.abs(forward(m, q, E).p - forward(m, q_prog).p)) < 3e-6


def test_travel_limit_named(rng):
    m = load_machine("robonano-ui")
    q = np.zeros((3, 6))
    q[2, 0] = 149.9995
    with pytest.raises(LimitError) as exc:
        retarget(m, q, ErrorSet(ToolSetting((-0.001, 0, 0))))  # X must go 1 um further
    assert exc.value.axis == "X" and exc.value.index == 2 and "outside its travel" in str(exc.value)


def test_tool_pointing_up_needs_b_beyond_travel():
    m = load_machine("robonano-a0ib")
    flipped = np.diag([1.0, -1.0, -1.0])[None]  # tool axis along -Z of the workpiece: B = 180 deg
    q = compensate(m, Pose(np.zeros((1, 3)), flipped), ErrorSet(), np.array([[0, 30.0, 0, 0, 0]]))
    assert abs(abs(q[0, 1]) - 180.0) < 1e-7
    with pytest.raises(LimitError) as exc:
        check_limits(m, q)
    assert exc.value.axis == "B"


def first_order_linear_machine(m, q, E):
    """First-order tool-edge position of a machine with linear axes only: the sum of the
    translational errors plus each angular error times its Abbe arm (written independently
    from docs/model.md: arm from the axis' reference point, where it is, to the tool edge)."""
    p = np.asarray(q, float) @ np.array([a.direction for a in m.axes]) + np.array(m.tool_point) + E.tool.offset
    out = p.copy()
    for i, ax in enumerate(m.axes):
        tab = E.geometric.tables[ax.name]
        d, e = tab.evaluate(q[:, i])
        u = np.array(ax.direction)
        # moving body: its reference point has travelled with the axis on the tool side; on the
        # workpiece side the arm to the tool includes the table's own travel.
        after = np.zeros_like(p)
        for j in range(i + 1, m.n_axes):
            after += q[:, [j]] * np.array(m.axes[j].direction)
        if ax.side == "workpiece":
            after += q[:, [i]] * u
        arm = np.array(m.tool_point) + after - np.array(ax.location)
        out += d + np.cross(e, arm)
    return out


def test_first_order_model_differs_to_second_order(rng):
    """Paper 004's style of model (first order in the errors) and the exact model differ by
    terms of second order: halving every error divides the difference by 4."""
    m = load_machine("vmc-moving-column")
    base = random_errors(m, rng, setting=0.0, trans=0.02, ang=50e-6, wp_angle=0.0, location=False)
    q = random_commands(m, 400, rng, span=0.9)

    def scaled(s):
        from mtcomp.errors import AxisErrorTable
        tabs = {k: AxisErrorTable(k, t.position, {n: s * v for n, v in t.values.items()})
                for k, t in base.geometric.tables.items()}
        return ErrorSet(geometric=GeometricErrors(tabs))

    diffs = []
    for s in (1.0, 0.5, 0.25):
        E = scaled(s)
        diffs.append(np.max(np.abs(forward(m, q, E).p - first_order_linear_machine(m, q, E))))
    assert diffs[0] > 1e-9  # the difference is real (second-order terms of ~ 1e-8 mm)...
    assert 3.5 < diffs[0] / diffs[1] < 4.5 and 3.5 < diffs[1] / diffs[2] < 4.5  # ...and quadratic


@pytest.mark.parametrize("name", PRESETS)
def test_rigid_closed_form_equals_iteration(name, rng):
    """The closed form for rigid setting errors and the general Gauss-Newton agree."""
    from mtcomp._solver import retarget_rigid as _retarget_rigid
    m = load_machine(name)
    E = ErrorSet(ToolSetting(tuple(rng.uniform(-1, 1, 3))),
                 WorkpieceSetting(tuple(rng.uniform(-1, 1, 3)), (0.3, -0.2, 0.5) if m.n_rotary == 0 else (0, 0, 0)))
    q = random_commands(m, 300, rng)
    closed = _retarget_rigid(m, q, E)
    assert closed is not None
    iterated = compensate(m, forward(m, q), E, q)
    assert np.max(np.abs(closed - iterated)) < 1e-9
    assert np.max(np.abs(forward(m, closed, E).p - forward(m, q).p)) < 1e-9


def test_tilted_blank_at_the_singularity_turns_c():
    """A 3-axis program (B = C = 0) on a B-C table with the blank tilted about X: the tool
    direction can only be matched by turning C by 90 deg and tilting B; compensate finds it."""
    m = load_machine("robonano-a0ib")
    q = np.zeros((4, 5))
    q[:, 2:] = [[0, 0, 1], [5, 0, 0], [5, 3, 0], [0, 3, -0.5]]
    E = ErrorSet(workpiece=WorkpieceSetting((0.01, 0.02, 0.0), (0.5, 0.0, 0.0)))
    qc = retarget(m, q, E)
    assert np.allclose(np.abs(qc[:, 0]), 90.0, atol=1e-6) and np.allclose(np.abs(qc[:, 1]), 0.5, atol=1e-6)
    # equivalent branches are ties: every point of the path takes the same one
    assert np.ptp(qc[:, 0]) < 1e-6 and np.ptp(qc[:, 1]) < 1e-6
    got = forward(m, qc, E)
    want = forward(m, q)
    assert np.max(np.abs(got.p - want.p)) < 1e-6 and np.max(np.abs(got.v - want.v)) < 1e-9
