"""Compensating the diagnosed thermal drift, transport delay and friction at reversals
(`mtcomp model compensate`, docs/model-loop.md "Feeding the compensation").  Each switch: the
pure function against the Python reference of the machine FMU (an independent implementation
of the same equations), then the machine FMU co-simulated with the compensated program (part
error reduced), and the switch off gives the previous output byte for byte."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mtcomp.errors import ErrorSet, GeometricErrors
from mtcomp.fmu.build import MachineDynamics
from mtcomp.machine import load_machine
from mtcomp.model.compensate import compensate_with_model, model_dynamics

M = "vmc-moving-column"
# the feed the servo feed-forward may use (asked: the default is the program\'s fastest move)
FAST = 60000.0
STEP = 1e-3
DATA = Path(__file__).parent / "data" / "model"
SQUARE = ErrorSet(geometric=GeometricErrors({}, {"EC0Y": 1.5e-4}))
# the program of tests/test_model_compensate.py (its backlash and servo output is the golden file)
LEGACY = """G90 G1 F300
X0 Y0 Z0
X10 Y4
X-8 Y-6
G2 X-8 Y-6 I5 J0
G1 X6 Y5
X0 Y0
"""
# the spindle runs up to 8000 1/min, then 12000 (an S word alone), stops (M5) before the last move
SPINDLE = """G90 G1 F600
S8000 M3
X0 Y0 Z0
X20 Y4
X-10 Y-6
S12000
G2 X-10 Y-6 I5 J0
G1 X10 Y5
M5
X0 Y0
"""
THERMAL = {"thermal.driver": 0, "thermal.gain": 1e-3, "thermal.time_constant": 2.0, "thermal.drift.z": 0.004}


def test_spindle_profile_follows_the_program():
    from mtcomp.fmu.cosim import interpolate_program
    from mtcomp.model.thermal_comp import spindle_profile
    m = load_machine(M)
    sp = spindle_profile(SPINDLE, m, STEP)
    t, _ = interpolate_program(SPINDLE, m, STEP)
    assert len(sp) == len(t)
    # block ends: 20.396 mm at 10 mm/s; + 31.62 mm; the circle 2 pi 5; + 22.36 mm; M5 before the last
    e1 = np.hypot(20, 4) / 10
    e2 = e1 + np.hypot(30, 10) / 10
    e4 = e2 + 2 * np.pi * 5 * np.sin(np.radians(0.5)) / np.radians(0.5) / 10 + np.hypot(20, 11) / 10
    assert set(sp[t <= e2 - STEP]) == {8000.0}
    assert set(sp[(t > e2 + STEP) & (t < e4 - STEP)]) == {12000.0}
    assert set(sp[t > e4 + STEP]) == {0.0}
    # M4 runs the other way (negative), no M3 at all: stopped
    assert set(spindle_profile("G1 F600 X0 Y0 Z0\nS500 M4\nX5\n", m, STEP)[5:]) == {-500.0}
    assert not np.any(spindle_profile("G1 F600 X0 Y0 Z0 S500\nX5\n", m, STEP))


def test_thermal_correction_cancels_the_reference_drift_and_the_delay_switch():
    """The predicted temperature and the corrected commands through the Python reference of the
    machine FMU (spindle driver, drift along z and x, a delay of 3 steps): the tool edge is where
    the uncorrected commands would put it on a machine without drift, to 1e-9 mm; without the
    delay's lead the offsets are taken 3 ms early."""
    from mtcomp.fmu.cosim import interpolate_program
    from mtcomp.kinematics import forward
    from mtcomp.model.machine_ref import simulate_reference
    from mtcomp.model.thermal_comp import (ThermalModel, predicted_temperature, spindle_profile, thermal_correction,
                                           thermal_offsets)
    m = load_machine(M)
    _, w = interpolate_program(SPINDLE, m, STEP)
    sp = spindle_profile(SPINDLE, m, STEP)
    dyn = MachineDynamics(thermal_driver="spindle", thermal_gain=1e-3, thermal_time_constant=1.5,
                          drift=(0.001, 0.0, 0.004), reference=20.5, initial_excess=0.3, delay=3 * STEP)
    tm = ThermalModel.from_dynamics(dyn)
    ideal = forward(m, w, SQUARE).p
    for lead, most in ((3 * STEP, 1e-9), (0.0, None)):
        T = predicted_temperature(tm, len(w), STEP, sp, lead=lead)
        u = thermal_correction(m, w, thermal_offsets(m, w, tm, T, SQUARE), SQUARE)
        run = simulate_reference(m, u, STEP, SQUARE, dyn, spindle_speed=np.abs(sp))
        err = np.abs(run.p[3:] - ideal[:-3]).max()       # the axes act 3 steps later
        if most:
            assert err < most
        else:
            assert err > 1e-6        # the drift moves by more than 1 µm over 3 ms at the spindle steps
    before = simulate_reference(m, w, STEP, SQUARE, dyn, spindle_speed=np.abs(sp))
    assert np.abs(before.p[3:] - ideal[:-3]).max() > 0.02          # 8 K * 4 µm/K and more


@pytest.fixture(scope="module")
def thermal_runs():
    """Part error of the SPINDLE program on a machine with a squareness and a spindle-driven
    drift along z, stage by stage (the FMU's spindle input follows each program's S words)."""
    pytest.importorskip("fmpy")
    from mtcomp.model.compensate import compare_compensations
    dyn = model_dynamics(THERMAL, M, STEP)
    return compare_compensations(SPINDLE, M, SQUARE, dyn, compiler="cc", max_feed=FAST)


def test_thermal_compensation_in_the_cosimulation(thermal_runs):
    e = thermal_runs
    assert list(e) == ["none", "geometric", "+thermal"]
    # measured: RMS 34.0 µm -> 34.0 µm -> 0.056 µm; max 46.8 µm -> 0.19 µm (axis resolution 0.1 µm)
    assert e["none"]["rms"] > 20e-3 and e["geometric"]["rms"] > 20e-3
    assert e["+thermal"]["rms"] < 0.01 * e["geometric"]["rms"]
    assert e["+thermal"]["max"] < 0.5e-3


def test_thermal_switch_off_is_the_previous_output():
    """With thermal (and friction) off, or with the drift out of the model, the program is the one
    the backlash and servo compensation wrote before those switches existed (golden file)."""
    base = {"servo.kv.X": 80.0, "servo.kv.Y": 80.0, "backlash.X": 0.004, "backlash.Y": 0.004}
    golden = (DATA / "compensated_backlash_servo.nc").read_text()
    full = model_dynamics({**base, **THERMAL, "friction.breakaway.X": 0.003, "friction.tau.X": 0.03,
                           "delay": 0.002}, M, STEP)
    assert compensate_with_model(LEGACY, M, None, model_dynamics(base, M, STEP), max_feed=FAST)[0] == golden
    assert compensate_with_model(LEGACY, M, None, full, thermal=False, friction=False, max_feed=FAST)[0] == golden
    assert compensate_with_model(LEGACY, M, None, full, thermal=False, friction=False, delay=False, max_feed=FAST)[0] == golden
    on = compensate_with_model(LEGACY, M, None, full, max_feed=FAST)[0]
    assert on != golden and "thermal offsets" in on and "friction reversal spikes" in on


def test_time_driven_drift_from_the_program_time():
    """Driver "time": a warm machine cools down (initial excess 2 K relaxes with 1.5 s) while a
    program without S words runs; the growth follows the program time."""
    pytest.importorskip("fmpy")
    from mtcomp.model.compensate import compare_compensations
    prog = LEGACY.replace("F300", "F900")
    dyn = model_dynamics({"thermal.driver": 2, "thermal.time_constant": 1.5, "thermal.initial_excess": 2.0,
                          "thermal.drift.y": 0.003}, M, STEP)
    e = compare_compensations(prog, M, ErrorSet(), dyn, compiler="cc", max_feed=FAST)
    # measured: max 5.6 µm (2 K * 3 µm/K at the start), RMS 1.92 µm -> max 0.26 µm, RMS 0.089 µm
    # (the axis resolution is 0.1 µm)
    assert list(e) == ["none", "geometric", "+thermal"]
    assert e["none"]["max"] > 4e-3 and e["+thermal"]["max"] < 0.4e-3
    assert e["+thermal"]["rms"] < 0.1 * e["none"]["rms"]


def test_temperature_driver_goes_to_the_control(tmp_path):
    """A drift driven by a logged temperature: the program is not changed for it (the future
    temperature is unknown); the control's parameters follow the model, and their law, applied
    online (causally) to the logged sensor, cancels the machine FMU's drift."""
    pytest.importorskip("fmpy")
    from mtcomp.fmu.cosim import interpolate_program
    from mtcomp.kinematics import forward
    from mtcomp.model.simulate import simulate
    from mtcomp.model.thermal_comp import control_offsets, thermal_correction
    params = {"thermal.driver": 1, "thermal.time_constant": 0.8, "thermal.drift.z": 0.005,
              "thermal.initial_excess": 0.4, "thermal.reference": 20.2}
    dyn = model_dynamics(params, M, STEP)
    text, rep = compensate_with_model(LEGACY, M, SQUARE, dyn, max_feed=FAST)
    assert text == compensate_with_model(LEGACY, M, SQUARE, dyn, thermal=False, max_feed=FAST)[0]
    assert rep.thermal == "temperature" and rep.step is None
    ctl = rep.thermal_control["thermal_compensation"]
    assert ctl["gain_mm_per_K"] == [0.0, 0.0, 0.005] and ctl["time_constant_s"] == 0.8
    assert ctl["reference_K"] == pytest.approx(0.2) and ctl["initial_excess_K"] == 0.4
    m = load_machine(M)
    t, w = interpolate_program(LEGACY, m, STEP)
    sensor = 21.3 + 1.5 * np.sin(2 * np.pi * t / 3.0) + 0.8 * (t > 2.0)        # the logged temperature
    growth = -control_offsets(rep.thermal_control, sensor, STEP)               # tool frame = workpiece frame here
    u = thermal_correction(m, w, growth, SQUARE)
    truth = dyn.machine_dynamics(m)
    before = simulate(w, M, SQUARE, truth, step=STEP, temperature=sensor, compiler="cc")
    after = simulate(u, M, SQUARE, truth, step=STEP, temperature=sensor, compiler="cc")
    ideal = forward(m, w, SQUARE).p
    assert np.abs(before.p - ideal).max() > 5e-3
    assert np.abs(after.p - ideal).max() < 1e-9


def _cli(tmp_path, *a):
    return subprocess.run([sys.executable, "-m", "mtcomp", *[str(x) for x in a]], capture_output=True, text=True,
                          cwd=tmp_path)


def test_cli_thermal_switches(tmp_path):
    d = tmp_path / "model"
    d.mkdir()
    (d / "dynamics.toml").write_text('step_s = 0.001\n[parameters]\n"thermal.driver" = 1\n"thermal.drift.z" = 0.004\n'
                                     '"thermal.time_constant" = 60.0\n')
    (tmp_path / "p.nc").write_text(SPINDLE)
    r = _cli(tmp_path, "model", "compensate", "p.nc", "--model", "model", "--machine", M, "-o", "out.nc")
    assert r.returncode == 0, r.stderr
    from mtcomp._io import parse_toml
    ctl = parse_toml((tmp_path / "out.nc.thermal.toml").read_text(), "x")["thermal_compensation"]
    assert ctl["gain_mm_per_K"] == [0.0, 0.0, 0.004] and ctl["time_constant_s"] == 60.0
    assert "left to the control" in r.stdout
    r = _cli(tmp_path, "model", "compensate", "p.nc", "--model", "model", "--machine", M, "--no-thermal",
             "-o", "off.nc")
    assert r.returncode == 0, r.stderr
    assert not (tmp_path / "off.nc.thermal.toml").exists()
    # spindle driver: sampled, the S words carried to the samples where the speed changes
    (d / "dynamics.toml").write_text('step_s = 0.001\n[parameters]\n"thermal.driver" = 0\n"thermal.gain" = 0.001\n'
                                     '"thermal.drift.z" = 0.004\n"thermal.time_constant" = 2.0\n')
    r = _cli(tmp_path, "model", "compensate", "p.nc", "--model", "model", "--machine", M, "-o", "sp.nc")
    assert r.returncode == 0, r.stderr
    from mtcomp.model.thermal_comp import spindle_profile
    out = (tmp_path / "sp.nc").read_text()
    assert "thermal offsets [spindle_speed]" in out      # the header writes brackets
    assert np.array_equal(spindle_profile(out, M, STEP), spindle_profile(SPINDLE, M, STEP))


# ---------------------------------------------------------------- friction at reversals

CIRCLE = """G90 G1 F600
X5 Y0 Z0
G2 X5 Y0 I-5 J0
G2 X5 Y0 I-5 J0
"""
FRICTION = {"friction.breakaway.X": 0.003, "friction.tau.X": 0.03, "friction.breakaway.Y": 0.003,
            "friction.tau.Y": 0.03}


def test_reversal_spikes_invert_the_reference_friction():
    """friction_commands, backlash offsets and feed-forward together, through the Python
    reference of the FMU's servo, play and friction (with a Coulomb lag too): the slide follows
    the target to 1e-12 mm; the spike at a reversal is the breakaway, decaying with tau."""
    from mtcomp.model.compensate import backlash_offsets, feed_forward
    from mtcomp.model.friction_comp import friction_commands
    from mtcomp.model.machine_ref import axis_response
    t = np.arange(3000) * STEP
    w = np.column_stack([5 * np.cos(2 * np.pi * t / 1.5), 5 * np.sin(2 * np.pi * t / 1.5),
                         np.interp(t, [0, 0.5, 1.0, 3.0], [0, 2.0, 2.0, -1.0])])
    brk, cou, tau = (0.003, 0.002, 0.004), (0.0, 0.0005, 0.001), (0.03, 0.02, 0.05)
    kv, bl = (60.0, 90.0, 0.0), (0.002, 0.0, 0.003)
    dyn = MachineDynamics(kv=kv, backlash=bl, friction_breakaway=brk, friction_coulomb=cou, friction_tau=tau)
    assert np.abs(axis_response(w, STEP, dyn) - w).max() > 0.1        # servo lag, play, lost motion
    s = friction_commands(w, STEP, brk, cou, tau)
    u = feed_forward(s + backlash_offsets(s, bl), kv, STEP)
    assert np.abs(axis_response(u, STEP, dyn) - w).max() < 1e-12
    # X reverses at t = 0.75 s (x = -5): the drive jumps by the breakaway, then the spike decays by tau
    k = int(np.argmin(w[:, 0])) + 1
    spike = (s - w)[k:k + 60, 0]
    assert spike[0] == pytest.approx(0.003, rel=0.05)
    assert spike[30] / spike[0] == pytest.approx(np.exp(-30 * STEP / 0.03), rel=0.05)


def test_circle_test_with_reversal_spikes():
    """Two turns of a circle test (r = 5 mm, F600) on a machine with stick-slip friction on X
    and Y: the quadrant glitches at the four reversals go, co-simulated in the machine FMU."""
    pytest.importorskip("fmpy")
    from mtcomp.model.compensate import compare_compensations
    from mtcomp.model.simulate import simulate
    dyn = model_dynamics(FRICTION, M, STEP)
    e = compare_compensations(CIRCLE, M, ErrorSet(), dyn, compiler="cc", max_feed=FAST)
    assert list(e) == ["none", "geometric", "+friction"]
    # measured: max 3.00 µm (the breakaway at each quadrant), RMS 0.43 µm -> max 0.26 µm, RMS 0.14 µm;
    # the floor is the interpolator's 1 deg chords (sagitta 0.19 µm on r = 5 mm), which the
    # programmed path does not have
    assert e["none"]["max"] > 2.5e-3
    assert e["+friction"]["max"] < 0.35e-3 and e["+friction"]["rms"] < 0.4 * e["none"]["rms"]
    # against the ideal machine's run of the same chords: 3.0 µm -> 0.075 µm (the 0.1 µm resolution)
    ideal = simulate(CIRCLE, M, None, None, step=STEP, compiler="cc").p
    text, _ = compensate_with_model(CIRCLE, M, None, dyn, max_feed=FAST)
    before = simulate(CIRCLE, M, None, dyn.machine_dynamics(M), step=STEP, compiler="cc").p
    after = simulate(text, M, None, dyn.machine_dynamics(M), step=STEP, compiler="cc").p
    assert np.abs(before - ideal).max() > 2.5e-3
    assert np.abs(after - ideal).max() < 0.12e-3


def test_friction_inversion_steps_the_reference_element():
    """The inversion's own step of the friction element (tuples, no object per trial) is the
    Python reference's friction_step bit for bit, on random states and drive moves: stuck or
    sliding, reversals, breakaways inside the step, tau = 0."""
    import random

    from mtcomp.model.friction_comp import _stepper
    from mtcomp.model.machine_ref import FrictionState, friction_step
    rng = random.Random(5)
    for _ in range(3000):
        h, brk, cou = rng.choice([1e-3, 2e-3]), rng.choice([0.0, 0.003]), rng.choice([0.0, 0.0005])
        tau = rng.choice([0.0, 0.01, 0.03])
        st = FrictionState(rng.uniform(-1, 1), rng.uniform(-0.004, 0.004), rng.choice([-1.0, 0.0, 1.0]),
                           rng.random() < 0.5)
        s0 = st.slide + rng.uniform(-0.005, 0.005)
        s1 = s0 + rng.choice([0.0, 1e-13, rng.uniform(-0.01, 0.01)])
        got = _stepper(h, brk, cou, tau)((st.slide, st.err, st.direction, st.stuck), s0, s1)
        friction_step(st, s0, s1, h, brk, cou, tau)
        assert got == (st.slide, st.err, st.direction, st.stuck)


def test_glitch_lead_inverts_the_reference_glitch():
    """glitch_commands with friction, backlash and feed-forward, through the Python reference of
    the FMU (servo, play, friction, quadrant glitch in the spike form on every axis): the axes
    follow the targets to 1e-12 mm (on Y the friction compensation holds the drive at each
    reversal, so the glitch's clock comes from the drive); the lead after X's reversal is the
    glitch itself."""
    from mtcomp.model.compensate import backlash_offsets, feed_forward
    from mtcomp.model.compensate import _glitch_and_friction
    from mtcomp.model.friction_comp import glitch_commands
    from mtcomp.model.machine_ref import axis_response
    t = np.arange(3000) * STEP
    w = np.column_stack([5 * np.cos(2 * np.pi * t / 1.5), 5 * np.sin(2 * np.pi * t / 1.5),
                         np.interp(t, [0, 0.5, 1.0, 3.0], [0, 2.0, 2.0, -1.0])])
    gh, gt = (0.003, 0.001, 0.002), (0.03, 0.01, 0.02)
    kv, bl, brk, ftau = (60.0, 0.0, 80.0), (0.002, 0.0, 0.0), (0.0, 0.002, 0.0), (0.0, 0.02, 0.0)
    dyn = MachineDynamics(kv=kv, backlash=bl, friction_breakaway=brk, friction_tau=ftau, glitch_height=gh,
                          glitch_time=gt)
    s = _glitch_and_friction(w, STEP, (gh, gt), (brk, (0.0, 0.0, 0.0), ftau), bl)
    u = feed_forward(s + backlash_offsets(s, bl), kv, STEP)
    assert np.abs(axis_response(u, STEP, dyn) - w).max() < 1e-12
    k = int(np.argmin(w[:, 0]))                       # X reverses at its minimum (t = 0.75 s)
    lead = (glitch_commands(w, STEP, gh, gt) - w)[:, 0]
    assert np.abs(lead[:k + 1]).max() == 0.0
    assert lead.max() == pytest.approx(0.003, rel=1e-9) and np.argmax(lead) == k + 30   # tau = 30 steps


def test_circle_test_with_the_glitch_lead():
    """The quadrant glitch in the spike form (3 µm, 30 ms on X; 2 µm, 20 ms on Y) on a circle
    in the machine FMU: the deviation from the ideal machine's run drops from 3 µm to the axis
    resolution's floor (0.1 µm), with --no-friction it stays."""
    pytest.importorskip("fmpy")
    from mtcomp.model.simulate import simulate
    dyn = model_dynamics({"glitch.height.X": 0.003, "glitch.time.X": 0.03, "glitch.height.Y": 0.002,
                          "glitch.time.Y": 0.02}, M, STEP)
    ideal = simulate(CIRCLE, M, None, None, step=STEP, compiler="cc").p
    text, rep = compensate_with_model(CIRCLE, M, None, dyn, max_feed=FAST)
    assert rep.glitch == ((0.003, 0.002, 0.0), (0.03, 0.02, 0.0)) and "quadrant glitch lead" in rep.summary()
    before = simulate(CIRCLE, M, None, dyn.machine_dynamics(M), step=STEP, compiler="cc").p
    after = simulate(text, M, None, dyn.machine_dynamics(M), step=STEP, compiler="cc").p
    assert np.abs(before - ideal).max() > 2.5e-3
    assert np.abs(after - ideal).max() < 0.12e-3
    text, rep = compensate_with_model(CIRCLE, M, None, dyn, friction=False, max_feed=FAST)
    assert text == CIRCLE and rep.glitch is None


def test_feed_forward_for_the_ramp_invariant_servo():
    """servo.interpolation = 1 (the command linear from the previous step's): the recursion of
    feed_forward(..., 1) makes the Python reference's servo reach the targets at every step end
    to 1e-12 mm (the held-command feed-forward leaves about 10 µm on it).  Through `model
    compensate` and the FMU on a circle the 0.1 mm lag goes to under 0.5 µm: the written program
    carries the recursion's alternating transient after the stop of the approach move (0.38 µm
    measured there, a few nm elsewhere; docs/model-loop.md, Limits)."""
    pytest.importorskip("fmpy")
    from mtcomp.model.compensate import feed_forward
    from mtcomp.model.machine_ref import axis_response
    from mtcomp.model.simulate import simulate
    t = np.arange(3000) * STEP
    w = np.column_stack([5 * np.cos(2 * np.pi * t / 1.5), 5 * np.sin(2 * np.pi * t / 1.5),
                         np.interp(t, [0, 0.5, 1.0, 3.0], [0, 2.0, 2.0, -1.0])])
    kv = (40.0, 90.0, 300.0)
    dyn = MachineDynamics(kv=kv, interpolation=1)
    assert np.abs(axis_response(w, STEP, dyn) - w).max() > 0.5
    assert np.abs(axis_response(feed_forward(w, kv, STEP, 1), STEP, dyn) - w).max() < 1e-12
    assert np.abs(axis_response(feed_forward(w, kv, STEP, 0), STEP, dyn) - w).max() > 5e-3
    model = model_dynamics({"servo.kv.X": 40.0, "servo.kv.Y": 90.0, "servo.interpolation": 1}, M, STEP)
    ideal = simulate(CIRCLE, M, None, None, step=STEP, compiler="cc").p
    text, _ = compensate_with_model(CIRCLE, M, None, model, max_feed=FAST)
    before = simulate(CIRCLE, M, None, model.machine_dynamics(M), step=STEP, compiler="cc").p
    after = simulate(text, M, None, model.machine_dynamics(M), step=STEP, compiler="cc").p[:len(ideal)]
    assert np.abs(before - ideal).max() > 0.05
    assert np.abs(after - ideal).max() < 0.5e-3


def test_friction_switch_off_is_the_previous_output():
    dyn = model_dynamics(FRICTION, M, STEP)
    text, rep = compensate_with_model(CIRCLE, M, None, dyn, friction=False, max_feed=FAST)
    assert text == CIRCLE and rep.friction is None and rep.step is None        # nothing else to compensate
    text, rep = compensate_with_model(CIRCLE, M, None, dyn, max_feed=FAST)
    assert rep.friction == ((0.003, 0.003, 0.0), (0.0, 0.0, 0.0), (0.03, 0.03, 0.0))
    assert "friction reversal spikes" in text and "breakaway 3, 3, 0 µm" in rep.summary()


# ---------------------------------------------------------------- transport delay

def test_a_delay_leaves_the_contour_and_the_switch_times_the_thermal_offsets():
    """A transport delay of all axes runs the same path later: with a whole number of steps the
    compensated part error is the one without delay (nothing for a rewritten program to
    advance).  What it shifts is the axes against the clock-driven drift: with the `delay`
    switch the thermal offsets are taken when the axes act (a fast drift, tau = 0.5 s, 10 ms)."""
    pytest.importorskip("fmpy")
    from mtcomp.model.compensate import part_error
    from mtcomp.model.simulate import simulate
    from mtcomp.model.thermal_comp import spindle_profile
    base = {"servo.kv.X": 80.0, "servo.kv.Y": 80.0, "backlash.X": 0.004, "backlash.Y": 0.004}
    plain, delayed = model_dynamics(base, M, STEP), model_dynamics({**base, "delay": 3 * STEP}, M, STEP)
    text = compensate_with_model(LEGACY, M, SQUARE, plain, max_feed=FAST)[0]
    assert compensate_with_model(LEGACY, M, SQUARE, delayed, max_feed=FAST)[0] == text
    p0 = simulate(text, M, SQUARE, plain.machine_dynamics(M), step=STEP, compiler="cc").p
    p1 = simulate(text, M, SQUARE, delayed.machine_dynamics(M), step=STEP, compiler="cc").p
    assert np.abs(p1[3:] - p0[:-3]).max() < 1e-12          # the same tool edge, 3 steps later
    assert part_error(LEGACY, simulate(text, M, SQUARE, plain.machine_dynamics(M), step=STEP, compiler="cc"),
                      M)["max"] < 1e-3
    dyn = model_dynamics({**THERMAL, "thermal.time_constant": 0.5, "delay": 10 * STEP}, M, STEP)
    rms = {}
    for on in (True, False):
        text, rep = compensate_with_model(SPINDLE, M, None, dyn, delay=on, max_feed=FAST)
        assert rep.delay == (10 * STEP if on else None)
        sp = spindle_profile(text, M, STEP)
        sig = simulate(text, M, None, dyn.machine_dynamics(M), step=STEP, spindle_speed=np.abs(sp), compiler="cc")
        rms[on] = part_error(SPINDLE, sig, M)["rms"]
    # measured (uncompensated 38 µm RMS): RMS 0.196 µm with the offsets at the command's time, 0.081 µm
    # at the axes' time; max 0.95 -> 0.70 µm (the first 10 ms: no command has reached the axes yet)
    assert rms[True] < 0.6 * rms[False]


@pytest.mark.parametrize("name", ["robonano-a0ib", "robonano-ui"])
def test_thermal_correction_with_rotary_axes(name):
    """Drift along the tool frame while rotary axes turn it (driver time, 2 K cooling): the
    linear axes take the whole growth, the orientation stays; through the Python reference of
    the FMU, 8 µm -> 1e-12 mm."""
    from mtcomp.kinematics import forward
    from mtcomp.model.machine_ref import simulate_reference
    from mtcomp.model.thermal_comp import ThermalModel, predicted_temperature, thermal_correction, thermal_offsets
    m = load_machine(name)
    t = np.arange(2000) * STEP
    w = np.column_stack([(20.0 if a.is_rotary else 5.0) * np.sin(t * (j + 1)) for j, a in enumerate(m.axes)])
    dyn = MachineDynamics(thermal_driver="time", thermal_time_constant=1.0, initial_excess=2.0,
                          drift=(0.001, 0.002, 0.004))
    tm = ThermalModel.from_dynamics(dyn)
    u = thermal_correction(m, w, thermal_offsets(m, w, tm, predicted_temperature(tm, len(w), STEP)))
    ideal = forward(m, w).p
    assert np.abs(simulate_reference(m, w, STEP, None, dyn).p - ideal).max() > 5e-3
    assert np.abs(simulate_reference(m, u, STEP, None, dyn).p - ideal).max() < 1e-12


def test_friction_compensated_with_the_diagnosed_model():
    """The loop end to end for friction: a circle test recorded with 20 nm noise, diagnosed on
    its first 60 %, exported; the program compensated with the *diagnosed* model runs on the true
    machine (FMU) as close to the ideal machine's run as with the true model."""
    pytest.importorskip("fmpy")
    from mtcomp.model.loop import close_loop
    from mtcomp.model.simulate import simulate
    prog = "G90 G1 F1200\nX0 Y0 Z0\nG3 X0 Y0 I0 J10\nG3 X0 Y0 I0 J10\n"
    h = 2e-3
    truth = MachineDynamics(friction_breakaway=(0.003, 0, 0), friction_tau=(0.025, 0, 0))
    nominal = simulate(prog, M, None, None, step=h, compiler="cc")
    rec = simulate(prog, M, None, MachineDynamics(noise=2e-5, seed=5, friction_breakaway=(0.003, 0, 0),
                                                  friction_tau=(0.025, 0, 0)), step=h, compiler="cc")
    lr = close_loop(rec, nominal, program=prog, machine=M, step=h, compiler="cc")
    learned = model_dynamics(lr.export.dynamics_values, M, h)
    assert learned.friction(M) is not None
    text, rep = compensate_with_model(prog, M, lr.export.errors, learned, max_feed=FAST)
    assert rep.friction is not None
    before = simulate(prog, M, None, truth, step=h, compiler="cc").p
    after = simulate(text, M, None, truth, step=h, compiler="cc").p
    # measured: 3.3 µm -> 0.07 µm (the 0.1 µm axis resolution)
    assert np.abs(before - nominal.p).max() > 2.5e-3
    assert np.abs(after - nominal.p).max() < 0.15e-3


def test_cli_encoder_switch(tmp_path):
    """`--no-encoder` leaves the encoder cyclic error to the control: the program comes back with
    its positions; without it the X targets move by -r(w)."""
    d = tmp_path / "model"
    d.mkdir()
    (d / "dynamics.toml").write_text('step_s = 0.001\n[parameters]\n"encoder.period.X" = 0.1\n'
                                     '"encoder.a1.X" = 0.001\n"encoder.phase1.X" = 30.0\n')
    prog = "G90 G1 F60\nX0 Y0 Z0\nX1.525 Y0.5\n"
    (tmp_path / "p.nc").write_text(prog)
    r = _cli(tmp_path, "model", "compensate", "p.nc", "--model", "model", "--machine", M, "--no-encoder",
             "-o", "off.nc")
    assert r.returncode == 0, r.stderr
    assert "X1.525 Y0.5" in (tmp_path / "off.nc").read_text()
    r = _cli(tmp_path, "model", "compensate", "p.nc", "--model", "model", "--machine", M, "-o", "on.nc")
    assert r.returncode == 0, r.stderr
    assert "X1.525 Y0.5" not in (tmp_path / "on.nc").read_text()
