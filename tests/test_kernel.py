"""The compiled kernel (fmu/c/mtk.c through ctypes) against the numpy reference, its build and
fallback, and the rotary solutions that follow the path (issue 14 item 2)."""
import os
import subprocess
import sys

import numpy as np
import pytest

from mtcomp import _kernel
from mtcomp.errors import (ErrorSet, GeometricErrors, ToolSetting, WorkpieceSetting, load_errors)
from mtcomp.kinematics import SwingError, compensate, forward, forward_position, retarget
from mtcomp.machine import load_machine

from _models import random_commands, random_errors

PRESETS = ["robonano-ui", "robonano-a0ib", "vmc-moving-column"]
KINDS = ["tool", "wp_translation", "wp_rotation", "location", "tables", "all"]
EXAMPLES = os.path.join(os.path.dirname(__file__), "..", "examples", "errors")

pytestmark = pytest.mark.skipif(not _kernel.available(), reason="no C compiler: the numpy reference runs alone")


def _errors(machine, kind, rng):
    full = random_errors(machine, rng, wp_angle=2.0 if machine.n_rotary else 0.5)
    if kind == "all":
        return full
    if kind == "tool":
        return ErrorSet(full.tool)
    if kind == "wp_translation":
        return ErrorSet(workpiece=WorkpieceSetting(full.workpiece.translation))
    if kind == "wp_rotation":
        return ErrorSet(workpiece=full.workpiece)
    if kind == "location":
        return ErrorSet(geometric=GeometricErrors(location=full.geometric.location))
    return ErrorSet(geometric=GeometricErrors(tables=full.geometric.tables))


@pytest.mark.parametrize("name", PRESETS)
@pytest.mark.parametrize("kind", KINDS)
def test_c_and_numpy_agree_on_every_preset_and_error_kind(name, kind, rng):
    m = load_machine(name)
    E = _errors(m, kind, rng)
    assert not E.is_zero
    q = random_commands(m, 200, rng, span=0.3)
    Pc, Pn = forward(m, q, E, backend="c"), forward(m, q, E, backend="numpy")
    assert np.max(np.abs(Pc.p - Pn.p)) <= 1e-12 and np.max(np.abs(Pc.R - Pn.R)) <= 1e-14
    # the positions-only forward (no orientations written) gives the same bits as the full one
    assert np.array_equal(forward_position(m, q, E, backend="c"), Pc.p)
    assert np.array_equal(forward_position(m, q, E, backend="numpy"), Pn.p)
    target = forward(m, q)
    qc = compensate(m, target, E, q, backend="c")
    qn = compensate(m, target, E, q, backend="numpy")
    # commands within 1e-9 mm / deg, and both reach the target within 1e-9 mm
    assert np.max(np.abs(qc - qn)) <= 1e-9
    for qq in (qc, qn):
        assert np.max(np.abs(forward(m, qq, E, backend="numpy").p - target.p)) <= 1e-9
    rc = retarget(m, q, E, backend="c", check=False)
    rn = retarget(m, q, E, backend="numpy", check=False)
    assert np.max(np.abs(rc - rn)) <= 1e-9


def test_table_range_error_is_the_references(rng):
    m = load_machine("vmc-moving-column")
    E = random_errors(m, rng)
    lo, hi = E.geometric.tables["X"].range
    q = random_commands(m, 5, rng, span=0.3)
    q[3, 0] = hi + 1.0
    from mtcomp.errors import TableRangeError
    for be in ("c", "numpy"):
        for fn in (forward, forward_position):
            with pytest.raises(TableRangeError) as exc:
                fn(m, q, E, backend=be)
            assert exc.value.axis == "X" and exc.value.index == 3


def _tilted_blank_program(n):
    q = np.zeros((n, 5))
    s = np.linspace(0.0, 1.0, n)
    q[:, 2] = 30.0 * np.cos(40 * s)  # X
    q[:, 3] = 30.0 * np.sin(40 * s)  # Y
    q[:, 4] = -0.01 * s              # Z
    return q


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_three_axis_program_on_a_tilted_blank_keeps_c(backend):
    """Issue 14: a 3-axis program (B = C = 0) on robonano-a0ib with the blank tilted 0.03 deg
    commanded C = 33.8 deg (the tilt's direction) in every block.  Within the pole tolerance C
    is held at its programmed value, B takes the part of the tilt it can, the position is exact."""
    m = load_machine("robonano-a0ib")
    E = ErrorSet(workpiece=WorkpieceSetting((0.01, 0.02, 0.0), (0.025, -0.0167, 0.0)))
    assert np.hypot(0.025, 0.0167) < 0.031
    q = _tilted_blank_program(20_000 if backend == "c" else 2000)
    out = retarget(m, q, E, backend=backend)
    assert np.all(out[:, 0] == 0.0)                      # C never turns
    assert np.max(np.abs(out[:, 1])) < 0.031             # B by the tilt at most
    assert np.ptp(out[:, 1]) < 1e-6                      # ... the same in every block
    P, ideal = forward(m, out, E), forward(m, q)
    assert np.max(np.abs(P.p - ideal.p)) <= 1e-9
    ang = np.degrees(np.arccos(np.clip(np.sum(P.v * ideal.v, axis=1), -1, 1)))
    assert np.max(ang) <= 0.031                          # the tool direction left, below the tilt
    # the exact tool direction is still there on request: C follows the tilt direction
    exact = retarget(m, q[:50], E, backend=backend, pole_tolerance=0.0)
    assert np.allclose(np.abs(exact[:, 0]), np.degrees(np.arctan2(0.025, 0.0167)) + 0.0, atol=1.0) or \
        np.allclose(np.abs(exact[:, 0]), 180 - np.degrees(np.arctan2(0.025, 0.0167)), atol=1.0) or \
        np.all(np.abs(exact[:, 0]) > 10.0)


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_head_at_b90_does_not_swing_a_and_c(backend):
    """Issue 14: robonano-ui at B = 90 with the example setting errors gave A -78.69 and
    C +78.71 deg for a 0.15 deg correction (A and C are parallel there)."""
    m = load_machine("robonano-ui")
    E = load_errors(os.path.join(EXAMPLES, "setting-example.toml"))
    q = np.array([[1.0, 2.0, 3.0, 0.0, 90.0, 0.0], [5.0, -2.0, 1.0, 0.0, 90.0, 0.0]])
    out = retarget(m, q, E, backend=backend)
    assert np.max(np.abs(out[:, 3:] - q[:, 3:])) < 0.2
    P, ideal = forward(m, out, E), forward(m, q)
    assert np.max(np.abs(P.p - ideal.p)) <= 1e-9
    M = np.einsum("nji,njk->nik", ideal.R, P.R)
    ang = np.degrees(np.arccos(np.clip((np.trace(M, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert np.max(ang) <= 0.2


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_bounded_swing_names_the_block_and_the_alternatives(backend):
    m = load_machine("robonano-a0ib")
    E = ErrorSet(workpiece=WorkpieceSetting((0.0, 0.0, 0.0), (0.5, 0.0, 0.0)))  # beyond the pole tolerance
    q = _tilted_blank_program(10)
    out = retarget(m, q, E, backend=backend)
    assert np.allclose(np.abs(out[:, 0]), 90.0, atol=1e-6)  # exact: C a quarter turn
    assert np.ptp(out[:, 0]) < 1e-6                          # once, not per block
    with pytest.raises(SwingError) as exc:
        retarget(m, q, E, backend=backend, max_swing=5.0)
    assert exc.value.index == 0 and exc.value.axis == "C"
    assert "3-axis" in str(exc.value) and "pole_tolerance" in str(exc.value)


def test_continuation_keeps_the_branch_along_a_path():
    """Along a path the kernel starts each block from the previous block's correction; with it
    and without it the same solution where the solution is unique."""
    m = load_machine("robonano-a0ib")
    E = ErrorSet(ToolSetting((0.1, -0.05, 0.2)), WorkpieceSetting((0.01, 0.02, 0.0), (0.3, -0.2, 0.5)))
    q = np.zeros((500, 5))
    s = np.linspace(0, 1, 500)
    q[:, 0], q[:, 1], q[:, 2], q[:, 3] = 90 * s, 10 + 20 * s, 20 * np.cos(6 * s), 20 * np.sin(6 * s)
    a = retarget(m, q, E, backend="c")
    b = retarget(m, q, E, backend="c", continuation=False)
    assert np.max(np.abs(a - b)) <= 1e-9
    assert np.max(np.abs(np.diff(a[:, :2] - q[:, :2], axis=0))) < 0.05  # smooth rotary correction (no jump of a branch)


def test_kernel_builds_into_a_cache_keyed_by_the_source_hash(tmp_path):
    out = tmp_path / _kernel.library_name(_kernel.source_hash())
    _kernel.compile_library(out)
    assert out.is_file() and _kernel.source_hash() in out.name
    lib = _kernel._bind(__import__("ctypes").CDLL(str(out)))
    m = load_machine("robonano-a0ib")
    q = random_commands(m, 10, np.random.default_rng(1))
    p, R, bad = _kernel.forward(lib, m, q, None, True)
    assert bad == -1 and np.allclose(p, forward(m, q, backend="numpy").p, atol=1e-12)


def test_without_a_compiler_the_numpy_kernel_runs_with_a_one_line_notice(tmp_path):
    code = ("import numpy as np; from mtcomp.machine import load_machine; from mtcomp.errors import "
            "ErrorSet, ToolSetting; from mtcomp.kinematics import retarget; from mtcomp import _kernel; "
            "m = load_machine('robonano-a0ib'); q = np.zeros((3, 5)); "
            "print(retarget(m, q, ErrorSet(ToolSetting((0.1, 0, 0))))[0, 2], _kernel.available())")
    env = dict(os.environ, CC=str(tmp_path / "no-such-cc"), MTCOMP_CACHE_DIR=str(tmp_path / "cache"),
               MTCOMP_KERNEL="cache")  # also where the install built the library
    run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == ["-0.1", "False"]
    notice = [ln for ln in run.stderr.splitlines() if ln.strip()]
    assert len(notice) == 1 and "numpy" in notice[0] and "kernel" in notice[0]


def test_a_fresh_install_with_gcc_builds_the_kernel():
    """A non-editable install (setup.py's build hook, as CI and the README install) puts the
    library the loader looks for next to mtcomp._kernel; an editable checkout compiles on first
    use instead (its own test above)."""
    from pathlib import Path
    here = Path(_kernel.__file__).resolve().parent
    if (here.parent / "pyproject.toml").is_file():
        pytest.skip("editable install: the library is compiled into the cache on first use")
    assert (here / _kernel.library_name(_kernel.source_hash())).is_file()


def test_batches_on_threads_are_bit_identical_to_one_thread(monkeypatch):
    """Long batches run in chunks on threads started in C; the chunks do not depend on the number
    of threads (each takes up the path from RUN_IN poses before its start), so one thread and
    several give the same bits, here across pole regions, with tables and without; and the
    chunked result is the unchunked sequential one to the solver's tolerance."""
    m = load_machine("robonano-a0ib")
    rng = np.random.default_rng(5)
    E = ErrorSet(ToolSetting((0.1, -0.05, 0.2)), WorkpieceSetting((0.01, 0.02, 0.0), (0.02, -0.01, 0.3)))
    n = 3 * _kernel.CHUNK + 1234
    q = _tilted_blank_program(n)
    q[:, 1] = np.where(np.arange(n) % 7000 < 3500, 0.0, 15.0)  # B = 0 (pole) and tilted stretches
    qr = random_commands(m, n, rng, span=0.3)
    Eg = random_errors(m, rng, wp_angle=0.05)
    out = {}
    for t in ("1", "2", "5"):
        monkeypatch.setenv("MTCOMP_THREADS", t)
        out[t] = (retarget(m, q, E, backend="c"), forward(m, qr, Eg, backend="c"),
                  retarget(m, qr, Eg, backend="c", check=False), retarget(m, qr, RIGID_A0IB, backend="c"))
    for t in ("2", "5"):
        a, b = out["1"], out[t]
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[2], b[2]) and np.array_equal(a[3], b[3])
        assert np.array_equal(a[1].p, b[1].p) and np.array_equal(a[1].R, b[1].R)
    lib = _kernel.load()
    assert lib.mtk_threads(n, 2) == 2 and lib.mtk_threads(_kernel.CHUNK, 2) == 1 and lib.mtk_threads(n, 9) == 4
    # the chunk boundaries (run-in) against one uninterrupted sequential pass
    seq = _sequential_retarget(lib, m, q, E)
    assert np.max(np.abs(out["1"][0] - seq)) <= 1e-9


RIGID_A0IB = ErrorSet(ToolSetting((0.35, -0.2, 0.15)), WorkpieceSetting((0.03, -0.02, 0.01)))


def _sequential_retarget(lib, machine, q, errors):
    """The kernel's single-pass batch entry (no chunks) on the whole program."""
    import ctypes
    q = np.ascontiguousarray(q, dtype=float)
    n = q.shape[0]
    out, res = np.empty_like(q), np.empty(n)
    status, info = np.empty(n, dtype=np.intc), np.empty(n, dtype=np.intc)
    mm = _kernel.model(lib, machine, errors)
    e = _kernel.c_errors(machine, errors)
    opt = _kernel._Options(1e-10, 60, 0.2, 1, 0)
    lib.mtk_retarget_batch(mm.ptr, ctypes.byref(e), n, _kernel._p(q), _kernel._p(out), ctypes.byref(opt),
                           _kernel._p(res), status.ctypes.data_as(_kernel._I), info.ctypes.data_as(_kernel._I))
    assert not status.any()
    return out


@pytest.mark.parametrize("name", ["robonano-ui", "robonano-a0ib"])
def test_c_and_numpy_agree_at_poles_and_restarts(name):
    """Rotary angles at multiples of 90 deg (B = 0 on the B-C table, B = 90 on the A-B-C head) and
    blank rotations inside and beyond the pole tolerance: held axes, exact solutions and seeded
    restarts agree pose by pose (the kernel's warm start off, as the reference has none)."""
    from mtcomp._io import MtcompError
    m = load_machine(name)
    rot = list(m.rotary_indices)
    for seed in range(6):
        rng = np.random.default_rng(1000 + seed)
        E = random_errors(m, rng, wp_angle=[0.01, 0.3, 2.0][seed % 3])
        q = random_commands(m, 40, rng, span=0.35, avoid_singular=False)
        q[:, rot] = np.round(q[:, rot] / 90.0) * 90.0
        out = []
        for be in ("c", "numpy"):
            try:
                out.append(retarget(m, q, E, backend=be, check=False, continuation=False))
            except MtcompError as exc:
                out.append(type(exc))
        if isinstance(out[0], type) or isinstance(out[1], type):
            assert out[0] == out[1]
        else:
            assert np.max(np.abs(out[0] - out[1])) <= 1e-9


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_a_command_that_is_not_a_number_is_named(backend):
    from mtcomp._io import InputError
    m = load_machine("robonano-a0ib")
    q = np.zeros((3, 5))
    q[1, 2] = np.nan
    with pytest.raises(InputError, match="point 1: the X command is nan"):
        retarget(m, q, ErrorSet(ToolSetting((0.1, 0, 0))), backend=backend)
    with pytest.raises(InputError, match="point 1"):
        compensate(m, forward(m, np.zeros((3, 5))), ErrorSet(ToolSetting((0.1, 0, 0))), q, backend=backend)


@pytest.mark.parametrize("name", ["robonano-a0ib", "robonano-ui", "vmc-moving-column"])
def test_c_and_numpy_agree_along_a_fine_path_with_tables(name):
    """A program-like path in steps of a few µm with tables, location and setting errors: the
    kernel starts each pose from the previous correction and takes the Newton step of the full
    model's Jacobian (table slopes in it) without evaluating the model after it where the model is
    linear over the step; the commands stay within 1e-9 of the numpy reference's."""
    m = load_machine(name)
    rng = np.random.default_rng(7)
    E = random_errors(m, rng, wp_angle=0.05 if m.n_rotary else 0.5)
    s = np.linspace(0.0, 1.0, 400)
    q = np.empty((s.size, m.n_axes))
    for k, a in enumerate(m.axes):
        lo, hi = a.limits
        mid, amp = 0.5 * (lo + hi), 0.2 * (hi - lo)
        if a.is_rotary:
            mid, amp = (25.0, 10.0) if name == "robonano-a0ib" and a.name == "B" else (10.0, min(amp, 20.0))
        q[:, k] = mid + amp * np.sin(0.02 * (k + 1) * s)
    qc = retarget(m, q, E, backend="c", check=False)
    qn = retarget(m, q, E, backend="numpy", check=False)
    assert np.max(np.abs(qc - qn)) <= 1e-9
    # the errors act: the compensation moves the axes by far more than the agreement
    assert np.max(np.abs(qc - q)) > 1e-3


@pytest.mark.parametrize("name", ["robonano-ui", "robonano-a0ib"])
def test_rigid_errors_with_a_workpiece_rotation_closed_form_is_the_iterative_solution(name):
    """Setting errors with a workpiece rotation: the kernel solves the rotary angles in closed form
    (Paden-Kahan subproblems on the rigid chain) and then the linear axes (affine in them); it
    agrees with the numpy reference's Gauss-Newton iteration to 1e-9, also where it hands poses
    back to the iteration: near the poles (B = 0 on the table, B = 90 on the head), for blank
    rotations up to 5 deg, and for given targets (compensate)."""
    m = load_machine(name)
    b = [k for k, a in enumerate(m.axes) if a.name == "B"][0]
    pole = 0.0 if name == "robonano-a0ib" else 90.0
    for seed, ang in enumerate([0.05, 0.3, 2.0, 5.0]):
        rng = np.random.default_rng(50 + seed)
        full = random_errors(m, rng, wp_angle=ang)
        E = ErrorSet(full.tool, full.workpiece)
        assert any(E.workpiece.angles) and E.geometric.is_zero
        q = random_commands(m, 600, rng, span=0.3, avoid_singular=False)
        q[:200, b] = pole + rng.uniform(-4.0, 4.0, 200)   # at and around the pole
        qc = retarget(m, q, E, backend="c", check=False, continuation=False)
        qn = retarget(m, q, E, backend="numpy", check=False)
        assert np.max(np.abs(qc - qn)) <= 1e-9
        # the real machine puts the tool where the ideal one would (away from the pole, exactly)
        t = forward(m, q)
        away = np.abs(q[:, b] - pole) > 2.0
        assert np.max(np.abs(forward(m, qc, E).p - t.p)[away]) <= 1e-9
        tc = compensate(m, t, E, q, backend="c", continuation=False)
        assert np.max(np.abs(tc - compensate(m, t, E, q, backend="numpy"))) <= 1e-9
    # along a path (warm start from the previous pose) the same commands as pose by pose
    qp = random_commands(m, 50, np.random.default_rng(9), span=0.3)
    qp = np.repeat(qp, 20, axis=0) + np.linspace(0, 1e-3, 20)[None, :].repeat(50, 0).reshape(-1, 1)
    assert np.max(np.abs(retarget(m, qp, E, backend="c") - retarget(m, qp, E, backend="c", continuation=False))) <= 1e-9


@pytest.mark.parametrize("name", PRESETS)
def test_steps_taken_without_an_evaluation_put_the_tool_on_the_ideal_pose(name):
    """With tables the kernel corrects the first Newton step by the model's second-order term
    and takes a step without evaluating the model after it where a bound on the second
    derivatives (the axes' angular velocities and the Jacobian's column lengths) keeps the linear
    prediction within 1e-11 mm.  Checked against the model itself, not the numpy iteration: the
    real machine at the compensated commands puts the tool where the ideal machine puts it at the
    programmed ones, on random poses (the corrected step and the bound after it) and on a path of
    0.01 deg and 0.1 mm steps (a warm start from the previous pose), and the poses agree with numpy."""
    m = load_machine(name)
    rng = np.random.default_rng(11)
    E = random_errors(m, rng, wp_angle=0.05 if m.n_rotary else 0.5)
    q = random_commands(m, 300, rng, span=0.3)
    start = q[0]
    path = start + np.outer(np.arange(300), [0.01 if a.is_rotary else 0.1 for a in m.axes])
    for cmds in (q, path):
        qc = retarget(m, cmds, E, backend="c", check=False)
        ideal, real = forward(m, cmds), forward(m, qc, E)
        # (the iteration stops at steps below 1e-10 mm or deg: its own residual is about 1e-10 mm)
        assert np.max(np.abs(real.p - ideal.p)) <= 5e-10
        a = np.asarray(m.tool_axis, dtype=float)
        if m.n_rotary:   # (three linear axes cannot turn the tool)
            assert np.max(np.abs(real.R @ a - ideal.R @ a)) <= 1e-11
        assert np.max(np.abs(qc - retarget(m, cmds, E, backend="numpy", check=False))) <= 1e-9
        assert np.max(np.abs(qc - cmds)) > 1e-3


@pytest.mark.parametrize("name", ["robonano-a0ib", "vmc-moving-column"])
def test_unevenly_spaced_tables_agree_with_numpy(name):
    """The kernel finds a table interval from the previous one (the hint), then by one
    multiplication on an evenly spaced grid, then by bisection: with knots spaced unevenly (the
    grid guess mostly wrong) the forward model and the compensation still agree with numpy."""
    from mtcomp.errors import AxisErrorTable, component_names
    m = load_machine(name)
    rng = np.random.default_rng(21)
    base = random_errors(m, rng, wp_angle=0.05 if m.n_rotary else 0.5)
    tables = {}
    for a in m.axes:
        lo, hi = a.limits
        pos = np.sort(np.concatenate([[lo, hi], rng.uniform(lo, hi, 13)]))
        pos = lo + (hi - lo) * ((pos - lo) / (hi - lo)) ** 2   # crowded at the low end
        vals = {c: rng.uniform(-50e-6 if j > 2 else -0.05, 50e-6 if j > 2 else 0.05, pos.size)
                for j, c in enumerate(component_names(a.name))}
        tables[a.name] = AxisErrorTable(a.name, pos, vals)
    E = ErrorSet(base.tool, base.workpiece, GeometricErrors(tables, base.geometric.location))
    q = random_commands(m, 400, rng, span=0.3)
    assert np.max(np.abs(forward(m, q, E, backend="c").p - forward(m, q, E, backend="numpy").p)) <= 1e-12
    qc = retarget(m, q, E, backend="c", check=False)
    assert np.max(np.abs(qc - retarget(m, q, E, backend="numpy", check=False))) <= 1e-9
    assert np.max(np.abs(forward(m, qc, E).p - forward(m, q).p)) <= 5e-10


@pytest.mark.parametrize("name", PRESETS)
def test_extrapolated_start_along_uneven_paths_with_corners(name):
    """Along a path the kernel starts a pose from the previous correction plus the previous
    segment's change of it, scaled by this segment's projection on that segment.  Where that
    prediction is poor (a corner, a stop, a reversal, the step length changing tenfold, a table
    knot) the Newton step is larger and the model is evaluated: the real machine at the commands
    still puts the tool on the ideal pose, and the commands agree with numpy's pose-by-pose
    solution and with the kernel's own solution without a path."""
    m = load_machine(name)
    rng = np.random.default_rng(23)
    E = random_errors(m, rng, wp_angle=0.05 if m.n_rotary else 0.5)
    q0 = random_commands(m, 1, rng, span=0.2)[0]
    unit = np.array([0.01 if a.is_rotary else 0.1 for a in m.axes])
    turn = np.roll(unit, 1) * np.where(np.arange(m.n_axes) % 2, 1.0, -1.0)   # a corner's new direction
    steps = [unit] * 40 + [0.1 * unit] * 20 + [3.0 * unit] * 20 + [np.zeros_like(unit)] * 5 + \
            [turn] * 40 + [-turn] * 30 + [unit * rng.uniform(0.0, 2.0)] * 1 + \
            [unit * f for f in rng.uniform(0.05, 2.0, 60)]
    q = q0 + np.cumsum(np.array(steps), axis=0)
    qc = retarget(m, q, E, backend="c", check=False)
    ideal, real = forward(m, q), forward(m, qc, E)
    assert np.max(np.abs(real.p - ideal.p)) <= 5e-10
    if m.n_rotary:
        a = np.asarray(m.tool_axis, dtype=float)
        assert np.max(np.abs(real.R @ a - ideal.R @ a)) <= 1e-11
    assert np.max(np.abs(qc - retarget(m, q, E, backend="numpy", check=False))) <= 1e-9
    assert np.max(np.abs(qc - retarget(m, q, E, backend="c", check=False, continuation=False))) <= 1e-9
    assert np.max(np.abs(qc - q)) > 1e-3


@pytest.mark.parametrize("name", ["robonano-a0ib", "robonano-ui"])
def test_rotary_commands_held_over_a_pass_stay_the_same_bits(name):
    """A pass at fixed rotary angles (the targets of the ideal machine, solved from a start that
    is off in the linear axes only): the kernel extrapolates each pose's start from the poses
    before it and may take the step on an earlier pose's Jacobian, yet a rotary axis the
    solution does not move keeps the same bits from pose to pose (downstream code finds the
    rotary moves of a program by exact comparison)."""
    m = load_machine(name)
    n = 300
    q = np.zeros((n, m.n_axes))
    lin = [k for k, a in enumerate(m.axes) if not a.is_rotary]
    rot = [k for k, a in enumerate(m.axes) if a.is_rotary]
    q[:, rot] = np.linspace(15.0, 35.0, len(rot))
    s = np.linspace(0.0, 1.0, n)
    for j, k in enumerate(lin):
        q[:, k] = 5.0 * np.sin((j + 1) * 2.0 * s) + j
    t = forward(m, q)
    q0 = q.copy()
    q0[:, lin] += 0.3
    qc = compensate(m, t, None, q0, backend="c")
    assert np.max(np.abs(qc - q)) <= 1e-9
    assert np.all(np.diff(qc[:, rot], axis=0) == 0.0)
