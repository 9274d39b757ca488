"""Direction-dependent compensation (issue: reversal was kept per direction in `geometric reversal`
but build tables, the lattice and compensate used the bidirectional mean)."""
from __future__ import annotations

import numpy as np
import pytest

from mtcomp import gcode
from mtcomp.cli import main
from mtcomp.commands import compensate_program
from mtcomp.geometric import comptables, synthetic, tables
from mtcomp.geometric.comptables import extend_tables
from mtcomp.geometric.reversal import (ReversalTable, approach_directions, direction_corrections, load_reversal,
                                       machining_order)
from mtcomp.kinematics import forward
from mtcomp.machine import load_machine

M = load_machine("vmc-moving-column")
REV = -0.005   # ISO 230-2 reversal B = x_up - x_down of -5 µm on every linear axis: 5 µm of ordinary backlash


@pytest.fixture(scope="module")
def built():
    truth = synthetic.make_synthetic(M, seed=1, run_step=5.0, min_wavelength=250.0).errors()
    mset = tables.simulate_runs(M, truth, tables.Setup.typical(1), tables.Noise(1e-7, 2e-7, 2e-10, REV),
                                step=5.0, seed=1)
    return truth, tables.build_tables(M, mset)


def _directions_by_loop(x):
    # independent of approach_directions: walk the sequence
    out, last = [], None
    for i, v in enumerate(x):
        if i and v != x[i - 1]:
            last = 1.0 if v > x[i - 1] else -1.0
        out.append(last)
    return np.array([1.0 if d is None else d for d in out])


def test_approach_directions_against_a_loop():
    rng = np.random.default_rng(0)
    for _ in range(50):
        x = np.round(rng.normal(size=30)).cumsum()     # many repeats (axis not moving)
        np.testing.assert_array_equal(approach_directions(x), _directions_by_loop(list(x)))
    assert np.all(approach_directions([3.0, 3.0, 3.0], initial=-1.0) == -1.0)


def test_machining_order_puts_a_blocks_interior_points_before_its_end():
    # rows as the rewrite hands them over: block ends (lines 10, 20, 30), then arc samples of 20, 30
    lines = np.array([10, 20, 30, 20, 20, 30])
    np.testing.assert_array_equal(machining_order(lines), [0, 3, 4, 1, 5, 2])
    np.testing.assert_array_equal(machining_order(lines, ends_first=False), [0, 1, 3, 4, 2, 5])


def test_direction_corrections_equal_the_bidirectional_tables():
    t = ReversalTable("X", np.array([0.0, 100.0, 200.0]), np.array([0.001, 0.003, 0.002]),
                      np.array([-0.002, -0.001, -0.001]))
    x = np.array([0.0, 50.0, 150.0, 120.0, 120.0, 10.0])
    q = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    got = direction_corrections(q, ("X", "Y", "Z"), {"X": t})
    d = _directions_by_loop(list(x))
    # mean table correction + this = ISO 230-2 bidirectional correction -x_up / -x_down
    np.testing.assert_allclose(got[:, 0] + t.correction(x, d, mode="mean"), t.correction(x, d), atol=1e-15)
    assert not got[:, 1:].any()


def test_reversal_csv_round_trip(tmp_path, built):
    _, res = built
    rev = res.reversal()["X"]
    (tmp_path / "X.csv").write_text(rev.to_csv())
    back = load_reversal([tmp_path / "X.csv"])["X"]
    np.testing.assert_allclose(back.half, rev.half)
    assert back.B_mean == pytest.approx(REV, abs=2e-7)


PROGRAM = "G21 G90 G94\nG00 X0 Y50 Z-20\n" + "".join(
    f"G01 X{x} Y{y} F500\n" for x, y in ((10, 50), (120, 60), (60, 60), (200, 40), (30, 45), (150, 45), (150, 80),
                                         (90, 20))) + "M30\n"


def _play(x, b):
    """The backlash (play) operator, written out: the driven slide stays put until the command has
    taken up the lost motion b (>= 0, mm) in the new direction; it starts approached upwards."""
    y = np.empty(len(x))
    prev = x[0] - b[0] / 2
    for i, (xi, bi) in enumerate(zip(x, b)):
        prev = min(max(prev, xi - bi / 2), xi + bi / 2)
        y[i] = prev
    return y


def _real_error(truth, rev, new_text, prog_text):
    """Independent: the real machine = forward model with the true tables, each axis' command
    first passed through a play of the lost motion its ISO 230-2 runs show (b = -B_i).  Tiny
    moves of an axis the program holds (the corrections of the others' errors) stay inside the
    play, as on the machine."""
    qe = np.asarray(gcode.parse(new_text, axes=M.axis_names).position)
    qp = np.asarray(gcode.parse(prog_text, axes=M.axis_names).position)
    qa = qe.copy()
    for k, ax in enumerate(M.axes):
        r = rev[ax.name]
        b = -np.interp(qe[:, k], r.position, r.up - r.down)
        # the play's centre: the bidirectional mean the tables already carry stays in forward()
        qa[:, k] = _play(qe[:, k], b)
    act = forward(M, qa, extend_tables(truth)).p
    return np.linalg.norm(act - forward(M, qp).p, axis=1), _directions_by_loop(list(qp[:, 0]))


def test_acceptance_bidirectional_program_within_half_a_micrometre(built):
    truth, res = built
    rev = res.reversal()
    old, _ = compensate_program(PROGRAM, M, extend_tables(res.errors))
    err_old, d = _real_error(truth, rev, old, PROGRAM)
    assert err_old.min() > 0.002          # mean tables only: about B/2 = 2.5 µm left
    new, _ = compensate_program(PROGRAM, M, extend_tables(res.errors), reversal=rev)
    err, d = _real_error(truth, rev, new, PROGRAM)
    assert (d > 0).any() and (d < 0).any()
    assert err[d > 0].max() < 0.0005 and err[d < 0].max() < 0.0005


def test_arcs_with_a_reversal_inside(built):
    # X turns round inside each half circle: the arcs are written as segments, each point
    # corrected for the direction it is reached in; the block ends land within 0.5 µm
    truth, res = built
    rev = res.reversal()
    prog = "G21 G90 G17\nG00 X-20 Y0 Z-20\nG01 X-20 Y0 F300\nG02 X20 Y0 I20 J0\nG02 X-20 Y0 I-20 J0\nM30\n"
    new, rep = compensate_program(prog, M, extend_tables(res.errors), reversal=rev)
    assert rep["linearised"] >= 1
    p_new = gcode.parse(new, axes=M.axis_names)
    qe = np.asarray(p_new.position)
    # every emitted point through the play, against the programmed circle (radius 20 mm)
    qa = qe.copy()
    for k, ax in enumerate(M.axes):
        r = rev[ax.name]
        qa[:, k] = _play(qe[:, k], -np.interp(qe[:, k], r.position, r.up - r.down))
    p = forward(M, qa, extend_tables(truth)).p - forward(M, np.zeros((1, 3))).p
    on = np.abs(qe[:, 1]) > 1.0                 # points on the arcs, away from the joints
    assert np.abs(np.hypot(p[on, 0], p[on, 1]) - 20.0).max() < 0.0005


def test_lattice_and_report_per_direction(built):
    truth, res = built
    rev = res.reversal()
    lat = comptables.lattice_table(M, res.errors, 100.0, reversal=rev)
    rep = comptables.compensation_report(M, truth, res.errors, lat, n_random=300, step=100.0, reversal_truth=rev)
    f = rep.figures
    for w in ("moving +", "moving -"):
        assert f[f"model-based, mean tables, {w}"][0] > 0.004          # |B|/2 on three axes
        assert f[f"model-based + reversal, {w}"][0] < 0.0005
        assert f"3-D lattice + reversal, {w}" in f
    # at the lattice's nodes (no interpolation error) the directional lattice leaves < 0.5 µm
    q = np.stack(np.meshgrid(*lat.nodes, indexing="ij"), -1).reshape(-1, 3)
    mean_only = comptables.LatticeTable(lat.axes, lat.nodes, lat.correction)
    for sgn in (1.0, -1.0):
        d = np.full(q.shape, sgn)
        with_rev = np.linalg.norm(comptables.residuals(M, truth, q, lat.apply(q, d), rev, d), axis=1)
        without = np.linalg.norm(comptables.residuals(M, truth, q, mean_only.apply(q, d), rev, d), axis=1)
        assert with_rev.max() < 0.0005 and without.min() > 0.004


def test_cli_build_writes_reversal_and_compensate_uses_it(tmp_path, capsys):
    d = tmp_path
    assert main(["geometric", "simulate", "-o", str(d / "set.toml"), "--reversal", "-5", "--seed", "2"]) == 0
    assert main(["geometric", "build", str(d / "set.toml"), "-o", str(d / "errors.toml")]) == 0
    assert (d / "errors_X_reversal.csv").exists() and "errors_X_reversal.csv" in capsys.readouterr().out
    (d / "p.nc").write_text(PROGRAM)
    assert main(["compensate", str(d / "p.nc"), "-m", "vmc-moving-column", "-e", str(d / "errors.toml"),
                 "--reversal", str(d / "errors_X_reversal.csv"), str(d / "errors_Y_reversal.csv"),
                 str(d / "errors_Z_reversal.csv"), "-o", str(d / "p_comp.nc")]) == 0
    from mtcomp.errors import load_errors
    truth = load_errors(d / "set_truth.toml")
    rev = load_reversal([d / f"errors_{a}_reversal.csv" for a in "XYZ"])
    err, dd = _real_error(truth, rev, (d / "p_comp.nc").read_text(), PROGRAM)
    assert err.max() < 0.0005
    capsys.readouterr()
    assert main(["geometric", "table", str(d / "errors.toml"), "--truth", str(d / "set_truth.toml"),
                 "--lattice-step", "100", "--reversal", str(d / "errors_X_reversal.csv"), "-o", str(d / "t")]) == 0
    out = capsys.readouterr().out
    assert "model-based + reversal, moving -" in out
    # a reversal table of an axis the machine lacks: named, non-zero
    bad = d / "errors_X_reversal.csv"
    bad.write_text(bad.read_text().replace("of axis X:", "of axis U:"))
    assert main(["compensate", str(d / "p.nc"), "-m", "vmc-moving-column", "-e", str(d / "errors.toml"),
                 "--reversal", str(bad), "-o", str(d / "q.nc")]) != 0
    assert "reversal table of axis U" in capsys.readouterr().err and not (d / "q.nc").exists()
