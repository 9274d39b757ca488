"""Compensating a program with the closed loop's model: geometric errors through `mtcomp
compensate`, backlash on reversal and servo-lag feed-forward, each switchable.  The pure
functions are checked against independent simulations of the machine FMU's servo and play;
the whole through a co-simulation of the machine FMU: the part error drops with each switch."""
from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from mtcomp.errors import ErrorSet, GeometricErrors, save_errors
from mtcomp.machine import load_machine
from mtcomp.model.compensate import (ModelDynamics, backlash_offsets, compensate_with_model, distance_to_path,
                                     feed_forward, read_model, sampled_program)

M = "vmc-moving-column"
# the feed the servo feed-forward may use (asked: the default is the program\'s fastest move)
FAST = 60000.0
STEP = 1e-3
# lines, corners, reversals of X and Y and a full circle (G2 must be cancelled by G1)
PROGRAM = """G90 G1 F300
X0 Y0 Z0
X10 Y4
X-8 Y-6
G2 X-8 Y-6 I5 J0
G1 X6 Y5
X0 Y0
"""
TRUE_ERRORS = ErrorSet(geometric=GeometricErrors({}, {"EC0Y": 1.5e-4}))        # squareness 150 µrad
KV, BACKLASH = (80.0, 80.0, 0.0), (0.004, 0.004, 0.0)                           # 1/s, mm


def _servo(u, kv, h):
    """Independent model of the FMU's servo: first order, command held over the step, output at
    the end of the step (x_{k+1} after command u_k)."""
    a = -np.expm1(-np.asarray(kv) * h)
    x = np.empty_like(u)
    cur = u[0].copy()
    for k in range(len(u)):
        cur = cur + (u[k] - cur) * a
        x[k] = cur
    return x


def _play(x, b):
    """Centred play of width b (the FMU's backlash): the output moves only when the input is
    more than b/2 away, starting centred."""
    y = np.empty_like(x)
    cur = x[0].copy()
    for k in range(len(x)):
        cur = np.clip(cur, x[k] - b / 2, x[k] + b / 2)
        y[k] = cur
    return y


def _path(n=400, h=STEP):
    t = np.arange(n) * h
    # moves, a stop, reversals: piecewise linear with a sine on top
    w = np.column_stack([np.interp(t, [0, 0.1, 0.15, 0.3, 0.4], [0, 1.0, 1.0, -0.5, 0.2]),
                         0.3 * np.sin(2 * math.pi * 3 * t), np.zeros(n)])
    return t, w


def test_feed_forward_makes_the_fmu_servo_reach_the_command():
    _, w = _path()
    kv = np.array([40.0, 120.0, 0.0])
    lag = _servo(w, kv, STEP)
    assert np.abs(lag - w).max() > 0.1                       # uncompensated: 0.25 mm at 10 mm/s and kv 40
    x = _servo(feed_forward(w, kv, STEP), kv, STEP)
    assert np.abs(x - w).max() < 1e-12
    # at constant velocity the lead is v h / expm1(kv h) -> v / kv
    v = 10.0
    u = feed_forward(np.column_stack([v * np.arange(50) * STEP] * 3), kv, STEP)
    lead = u[-1, 0] - v * 49 * STEP
    assert lead == pytest.approx(v * STEP / math.expm1(40.0 * STEP), rel=1e-12)
    assert lead == pytest.approx(v / 40.0, rel=0.03)


def test_backlash_offsets_cancel_the_play():
    _, w = _path()
    b = np.array([0.004, 0.002, 0.0])
    assert np.abs(_play(w, b) - w).max() == pytest.approx(0.002, rel=1e-9)
    y = _play(w + backlash_offsets(w, b), b)
    assert np.abs(y - w).max() < 1e-12
    off = backlash_offsets(w, b)
    assert set(np.unique(np.round(off[:, 0] * 1e3, 9))) == {0.0, -2.0, 2.0}   # ±b/2, 0 before the first move


def test_both_together_through_servo_and_play():
    _, w = _path()
    kv, b = np.array([40.0, 60.0, 0.0]), np.array([0.004, 0.002, 0.0])
    u = feed_forward(w + backlash_offsets(w, b), kv, STEP)
    y = _play(_servo(u, kv, STEP), b)
    # the FMU applies the play to the servo output; the output of sample k is the servo at t_k + h
    assert np.abs(y - w).max() < 1e-12


def test_sampled_program_runs_the_samples():
    from mtcomp.fmu.cosim import interpolate_program
    m = load_machine(M)
    res = m.resolutions[0]
    t, w = _path()
    for u, most in ((feed_forward(w, (40.0, 60.0, 0.0), STEP), None),
                    # lines only: the samples between corners merge into a few blocks (Z moves on
                    # through X's stop: the interpolator has no dwell, a rest of every axis takes no time)
                    (feed_forward(np.column_stack([w[:, 0], 0.5 * w[:, 0], 0.05 * t]), (40.0, 40.0, 0.0), STEP), 30)):
        text = sampled_program(u, STEP, m)
        if most:
            assert len(text.splitlines()) < most
        _, q2 = interpolate_program(text, m, STEP)
        assert len(q2) == len(u)
        # rounding to the axis resolution (res/2) plus the merging tolerance (res/4)
        assert np.abs(q2 - u).max() < 0.75 * res + 1e-9


def test_distance_to_path_is_exact_on_a_polyline():
    path = np.array([[0, 0, 0], [10, 0, 0], [10, 10, 0]], float)
    fine = np.vstack([np.linspace(path[0], path[1], 11), np.linspace(path[1], path[2], 11)[1:]])
    pts = np.array([[5, 0.003, 0], [10.002, 4, 0], [12, -2, 0], [3.3, -0.001, 0.004]])
    d = distance_to_path(pts, fine)
    assert d == pytest.approx([0.003, 0.002, math.hypot(2, 2), math.hypot(0.001, 0.004)], abs=1e-12)


@pytest.fixture(scope="module")
def errors_by_switch():
    """Part error (max, RMS in mm) of the machine with all three effects, for each switch."""
    pytest.importorskip("fmpy")
    from mtcomp.fmu.build import MachineDynamics
    from mtcomp.model.compensate import part_error
    from mtcomp.model.simulate import simulate
    dyn = MachineDynamics(kv=KV, backlash=BACKLASH)
    model = ModelDynamics(BACKLASH, KV, STEP)
    out = {}
    for name, kw in (("none", None), ("geometric", dict(backlash=False, servo=False)),
                     ("+backlash", dict(servo=False)), ("+servo", {})):
        text = PROGRAM if kw is None else compensate_with_model(PROGRAM, M, TRUE_ERRORS, model, **kw, max_feed=FAST)[0]
        sig = simulate(text, M, TRUE_ERRORS, dyn, step=STEP, compiler="cc")
        pe = part_error(PROGRAM, sig, M)
        out[name] = (pe["max"], pe["rms"])
    return out


def test_part_error_drops_with_each_switch(errors_by_switch):
    e = errors_by_switch
    rms = {k: v[1] for k, v in e.items()}
    # measured: 1.20 µm -> 1.10 -> 0.66 -> 0.048 µm RMS; max 18.6 µm (corners, circle) -> 0.39 µm
    assert rms["none"] > 1.0e-3
    assert rms["geometric"] < rms["none"] - 0.05e-3
    assert rms["+backlash"] < 0.7 * rms["geometric"]
    assert rms["+servo"] < 0.1 * rms["+backlash"]
    # the max after all switches is set by single samples at the 0.1 µm axis resolution: one
    # value on a rounding boundary (X6.00075, rounded either way by a 1e-10 mm difference between
    # the C and numpy kernels) moves it between 0.39 and 0.53 µm
    assert e["none"][0] > 10e-3 and e["+servo"][0] < 1e-3


def test_geometric_switch_alone_on_a_machine_with_geometric_errors_only():
    pytest.importorskip("fmpy")
    from mtcomp.model.compensate import part_error
    from mtcomp.model.simulate import simulate
    before = part_error(PROGRAM, simulate(PROGRAM, M, TRUE_ERRORS, None, step=STEP, compiler="cc"), M)
    text, rep = compensate_with_model(PROGRAM, M, TRUE_ERRORS, None, max_feed=FAST)
    assert rep.geometric and rep.step is None                   # no sampling without dynamics
    after = part_error(PROGRAM, simulate(text, M, TRUE_ERRORS, None, step=STEP, compiler="cc"), M)
    # squareness 150 µrad over +-10 mm: 1.3 µm max; compensated to the axis resolution (0.1 µm:
    # measured 0.41 µm max at one corner sample, RMS below 15 % of the uncompensated one)
    assert before["max"] > 1e-3 and after["max"] < 0.5e-3
    assert after["rms"] < 0.15 * before["rms"]


def _model_folder(path):
    path.mkdir()
    save_errors(TRUE_ERRORS, path / "errors.toml")
    (path / "dynamics.toml").write_text(
        'step_s = 0.001\n[parameters]\n"servo.kv.X" = 80.0\n"servo.kv.Y" = 80.0\n'
        '"backlash.X" = 0.004\n"backlash.Y" = 0.004\n')
    return path


def test_read_model(tmp_path):
    errors, dyn = read_model(_model_folder(tmp_path / "model"), M)
    assert errors.geometric.location["EC0Y"] == pytest.approx(1.5e-4)
    assert dyn == ModelDynamics((0.004, 0.004, 0.0), (80.0, 80.0, 0.0), 0.001)


def _cli(tmp_path, *a):
    return subprocess.run([sys.executable, "-m", "mtcomp", *[str(x) for x in a]], capture_output=True, text=True,
                          cwd=tmp_path)


def test_backlash_on_a_single_axis_reversal(tmp_path):
    """A line out and back on X: the play leaves the reversal point short by b/2, on the path
    (only the part error's reach sees it); a model folder with dynamics only compensates no
    geometry, and the reversal compensation reaches the point."""
    pytest.importorskip("fmpy")
    from mtcomp.fmu.build import MachineDynamics
    from mtcomp.model.compensate import part_error
    from mtcomp.model.simulate import simulate
    d = tmp_path / "m"
    d.mkdir()
    (d / "dynamics.toml").write_text('step_s = 0.001\n[parameters]\n"backlash.X" = 0.002\n')
    errors, dyn = read_model(d, M)
    prog = "G90 G1 F600\nX0 Y0 Z0\nX5\nX-5\nX0\n"
    text, rep = compensate_with_model(prog, M, errors, dyn, max_feed=FAST)
    assert not rep.geometric and rep.backlash == (0.002, 0.0, 0.0) and rep.kv is None
    machine = MachineDynamics(backlash=(0.002, 0.0, 0.0))
    before = part_error(prog, simulate(prog, M, None, machine, step=1e-3, compiler="cc"), M)
    after = part_error(prog, simulate(text, M, None, machine, step=1e-3, compiler="cc"), M)
    assert before["max"] < 1e-9 and before["reach"] == pytest.approx(0.001, abs=1e-9)
    assert after["max"] < 1e-9 and after["reach"] < 1e-9


def test_cli_compensate_switches_and_bad_input(tmp_path):
    _model_folder(tmp_path / "model")
    (tmp_path / "p.nc").write_text(PROGRAM)
    base = ("model", "compensate", "p.nc", "--model", "model", "--machine", M)
    r = _cli(tmp_path, *base, "-o", "safe.nc")
    assert r.returncode == 0, r.stderr
    # by default no feed above the program's F300: the servo feed-forward is left out, and said so
    assert "servo feed-forward NOT applied" in r.stdout and "--max-feed" in r.stdout
    r = _cli(tmp_path, *base, "--max-feed", FAST, "-o", "all.nc")
    assert r.returncode == 0, r.stderr
    assert "geometric" in r.stdout and "backlash" in r.stdout and "feed-forward" in r.stdout
    text = (tmp_path / "all.nc").read_text()
    assert "MTCOMP COMPENSATED PROGRAM" in text and "servo feed-forward" in text
    r = _cli(tmp_path, *base, "--no-backlash", "--no-servo", "-o", "geo.nc")
    assert r.returncode == 0, r.stderr
    geo = (tmp_path / "geo.nc").read_text()
    assert "G2" in geo or "G02" in geo or len(geo.splitlines()) > 20  # the program's blocks, not samples
    assert "feed-forward" not in geo
    # the library gives the same program
    errors, dyn = read_model(tmp_path / "model", M)
    same, _ = compensate_with_model(PROGRAM, M, errors, dyn, filename="p.nc", max_feed=FAST)
    body = lambda s: [ln for ln in s.splitlines() if not ln.startswith("(")]  # noqa: E731
    assert body(same) == body(text)
    # --cosim: the part error on the model's machine, switch by switch (the model is the truth here)
    r = _cli(tmp_path, *base, "--cosim", "--max-feed", FAST, "-o", "all2.nc")
    assert r.returncode == 0, r.stderr
    pe = {ln.split()[1]: (float(ln.split()[3]), float(ln.split()[6])) for ln in r.stdout.splitlines()
          if ln.strip().startswith("compensation ")}
    assert list(pe) == ["none", "geometric", "+backlash", "+servo"]
    assert pe["none"][1] > pe["geometric"][1] > pe["+backlash"][1] > 10 * pe["+servo"][1]
    # compensating a compensated program again is refused; a missing model folder is one line
    r = _cli(tmp_path, "model", "compensate", "all.nc", "--model", "model", "--machine", M, "-o", "x.nc")
    assert r.returncode != 0 and "already compensated" in r.stderr and "Traceback" not in r.stderr
    r = _cli(tmp_path, "model", "compensate", "p.nc", "--model", "nope", "--machine", M, "-o", "x.nc")
    assert r.returncode != 0 and "nope" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x.nc").exists()


def test_simulate_is_cosimulates_uncompensated_run():
    """mtcomp.model.simulate.simulate runs only the machine: the same signals as the
    uncompensated run of mtcomp.fmu.cosim.cosimulate."""
    pytest.importorskip("fmpy")
    from mtcomp.fmu.build import MachineDynamics
    from mtcomp.fmu.cosim import cosimulate
    from mtcomp.model.simulate import simulate
    dyn = MachineDynamics(kv=KV, backlash=BACKLASH, noise=2e-5, seed=3)
    prog = PROGRAM.replace("F300", "F3000")
    sig = simulate(prog, M, TRUE_ERRORS, dyn, step=STEP, compiler="cc")
    ref = cosimulate(prog, M, TRUE_ERRORS, ErrorSet(), step=STEP, dynamics=dyn, compiler="cc")
    assert np.array_equal(sig.t, ref.t) and np.array_equal(sig.q, ref.q_programmed)
    assert np.array_equal(sig.p, ref.p_uncompensated)
