"""The machine FMU's dynamics (servo, backlash, transport delay, friction, thermal drift) against
the Python reference model mtcomp.model.machine_ref, and the public machine-only run."""
from __future__ import annotations

import numpy as np
import pytest

from mtcomp._io import InputError
from mtcomp.fmu.build import MachineDynamics, build_machine_fmu
from mtcomp.fmu.cosim import run_machine
from mtcomp.machine import load_machine

MACHINE = "vmc-moving-column"


@pytest.fixture(scope="module")
def machine():
    return load_machine(MACHINE)


def test_run_machine_checks_its_inputs(machine, tmp_path):
    fmu = build_machine_fmu(machine, tmp_path / "m.fmu")
    q = np.zeros((5, machine.n_axes))
    with pytest.raises(InputError, match="shape"):
        run_machine(fmu, machine, q[:, :2], 1e-3)
    with pytest.raises(InputError, match="spindle_speed"):
        run_machine(fmu, machine, q, 1e-3, spindle_speed=np.zeros(4))
    run = run_machine(fmu, machine, q, 1e-3, spindle_speed=np.linspace(0, 100, 5))
    assert run.p.shape == (5, 3) and run.actual.shape == (5, machine.n_axes)


def _path(machine, K=3000, step=1e-3):
    """Commands (K, n): X and Y on a circle of 5 mm radius (smooth reversals of each axis), a
    line out and back on Z with a sharp reversal, the other axes at rest (mm)."""
    t = np.arange(K) * step
    q = np.zeros((K, machine.n_axes))
    names = machine.axis_names
    w = 2 * np.pi / (K * step / 1.5)
    q[:, names.index("X")] = 5 * np.cos(w * t) - 5
    q[:, names.index("Y")] = 5 * np.sin(w * t)
    q[:, names.index("Z")] = -2 + np.abs(t - t[-1] / 2) * 2
    return q


CASES = {
    "held servo, backlash, friction, delay, spindle-driven thermal drift": dict(
        dyn=dict(kv=(50.0, 70.0, 0.0), backlash=(0.004, 0.0, 0.002), delay=0.0037,
                 friction_breakaway=(0.003, 0.002, 0.001), friction_coulomb=(0.0, 0.0005, 0.0),
                 friction_tau=(0.02, 0.0, 0.05), thermal_time_constant=0.7, thermal_gain=1e-3,
                 drift=(0.002, -0.001, 0.003), initial_excess=-0.5, reference=20.2),
        spindle=lambda t: 1000.0 * (t > 0.8)),
    "quadrant glitch (spike form) on a held servo with backlash and friction": dict(
        dyn=dict(kv=(50.0, 0.0, 80.0), backlash=(0.0, 0.002, 0.0), friction_breakaway=(0.0, 0.002, 0.0),
                 friction_tau=(0.0, 0.01, 0.0), glitch_height=(0.003, -0.002, 0.001), glitch_time=(0.02, 0.005, 0.0))),
    "quadrant glitch on a ramp servo with delay": dict(
        dyn=dict(kv=(40.0, 0.0, 0.0), interpolation=1, delay=0.0021, glitch_height=(0.002, 0.004, 0.003),
                 glitch_time=(0.015, 0.03, 0.01))),
    "ramp servo, delay, friction, temperature-driven drift": dict(
        dyn=dict(kv=(40.0, 90.0, 200.0), interpolation=1, delay=0.0021, backlash=(0.0, 0.003, 0.0),
                 friction_breakaway=(0.002, 0.0, 0.001), friction_tau=(0.01, 0.0, 0.0),
                 thermal_driver="temperature", thermal_time_constant=0.4, drift=(0.0, 0.0, 0.004)),
        temperature=lambda t: 21.0 + 0.5 * np.sin(t)),
    "velocity friction on a held servo with backlash, friction and glitch": dict(
        dyn=dict(kv=(50.0, 0.0, 80.0), backlash=(0.002, 0.0, 0.0), friction_breakaway=(0.0, 0.002, 0.0),
                 friction_tau=(0.0, 0.01, 0.0), glitch_height=(0.0, 0.0, 0.001), glitch_time=(0.0, 0.0, 0.01),
                 velfriction_coulomb=(0.2, 0.1, 0.05), velfriction_viscous=(0.02, 0.0, -0.01),
                 velfriction_vs=(0.5, 0.0, 1.0))),
    "negative (over-compensated) backlash alone, held servo": dict(
        dyn=dict(kv=(50.0, 70.0, 0.0), backlash=(-0.004, -0.002, -0.003))),
    "negative backlash with friction, glitch and delay, ramp servo": dict(
        dyn=dict(kv=(40.0, 0.0, 80.0), interpolation=1, delay=0.0021, backlash=(-0.003, 0.002, -0.002),
                 friction_breakaway=(0.002, 0.001, 0.003), friction_coulomb=(0.0005, 0.0, 0.001),
                 friction_tau=(0.01, 0.0, 0.02), glitch_height=(0.001, 0.0, 0.0), glitch_time=(0.01, 0.0, 0.0))),
    "encoder cyclic error after servo, backlash, glitch and velocity friction": dict(
        dyn=dict(kv=(50.0, 0.0, 80.0), backlash=(0.002, 0.0, 0.0), glitch_height=(0.0, 0.002, 0.0),
                 glitch_time=(0.0, 0.01, 0.0), velfriction_coulomb=(0.0, 0.0, 0.05), velfriction_vs=(0.0, 0.0, 1.0),
                 encoder_period=(0.02, 0.5, 0.1), encoder_a1=(0.0003, 0.002, -0.001),
                 encoder_phase1=(40.0, -120.0, 400.0), encoder_a2=(0.0001, 0.0, 0.0005),
                 encoder_phase2=(-30.0, 0.0, 90.0))),
    "ideal servo, warm-up over time": dict(
        dyn=dict(thermal_driver="time", thermal_time_constant=1.2, initial_excess=2.0, drift=(0.001, 0.0, -0.002))),
}


@pytest.mark.parametrize("case", list(CASES))
def test_machine_fmu_matches_the_python_reference(machine, tmp_path, case):
    """The C model and mtcomp.model.machine_ref agree step by step (actual positions 1e-12 mm,
    tool edge 1e-9 mm, temperature 1e-9 K) on every dynamic effect."""
    from mtcomp.model.machine_ref import simulate_reference
    c = CASES[case]
    step = 1e-3
    q = _path(machine, step=step)
    t = np.arange(len(q)) * step
    dyn = MachineDynamics(**c["dyn"])
    kw = {}
    if "spindle" in c:
        kw["spindle_speed"] = c["spindle"](t)
    if "temperature" in c:
        kw["temperature"] = c["temperature"](t)
    fmu = build_machine_fmu(machine, tmp_path / "m.fmu", dynamics=dyn)
    run = run_machine(fmu, machine, q, step, **kw)
    ref = simulate_reference(machine, q, step, None, dyn, spindle_speed=kw.get("spindle_speed", 0.0),
                             temperature_input=kw.get("temperature", 20.0))
    assert np.max(np.abs(run.actual - ref.actual)) < 1e-12
    assert np.max(np.abs(run.velocity - ref.velocity)) < 1e-9
    assert np.max(np.abs(run.temperature - ref.temperature)) < 1e-9
    assert np.max(np.abs(run.p - ref.p)) < 1e-9
    # the case is not trivial: the effects moved the tool edge off the ideal machine's by > 1 µm
    from mtcomp.kinematics import forward
    assert np.max(np.abs(run.p - forward(machine, q).p)) > 1e-3


def _ramp(machine, K, v, step=1e-3, axis="X"):
    q = np.zeros((K, machine.n_axes))
    q[:, machine.axis_names.index(axis)] = v * np.arange(K) * step
    return q


def test_delay_and_ramp_servo_are_exact_on_a_ramp(machine, tmp_path):
    """On a ramp at v = 10 mm/s: a delay of 3.7 steps lags the ideal axis by v d exactly; the
    ramp-invariant servo (servo.interpolation = 1) lags by v/kv exactly in steady state (the
    held command gives v h / expm1(kv h) instead, half a step less)."""
    step, v, kv, d = 1e-3, 10.0, 50.0, 0.0037
    q = _ramp(machine, 600, v)
    ix = machine.axis_names.index("X")
    for dyn, lag in ((MachineDynamics(delay=d), v * d),
                     (MachineDynamics(kv=kv, interpolation=1), v / kv),
                     (MachineDynamics(kv=kv), v * step / np.expm1(kv * step))):
        run = run_machine(build_machine_fmu(machine, tmp_path / "m.fmu", dynamics=dyn), machine, q, step)
        err = q[:, ix] - run.actual[:, ix]
        assert err[-1] == pytest.approx(lag, rel=1e-9, abs=1e-12)


def test_velocity_friction_is_the_diagnosis_friction_on_the_velocity_output(machine, tmp_path):
    """A velocity-mode axis: on a ramp out at 10 mm/s and back (ideal servo), v.X is the drive's
    velocity less c tanh(v/vs) + b v, exactly; the position integrates the deficit (it falls
    behind by (c tanh(v/vs) + b v) t); the FMU without velocity friction gives v.X = the
    command's backward difference, at rest 0."""
    step, v, c, b, vs = 1e-3, 10.0, 0.3, 0.02, 0.2
    K = 400
    ix = machine.axis_names.index("X")
    t = np.arange(K) * step
    q = np.zeros((K, machine.n_axes))
    q[:, ix] = v * np.minimum(t, 0.2) - v * np.maximum(t - 0.2, 0.0)
    base = run_machine(build_machine_fmu(machine, tmp_path / "m0.fmu"), machine, q, step)
    vd = np.diff(np.r_[q[0, ix], q[:, ix]]) / step
    assert np.max(np.abs(base.velocity[:, ix] - vd)) < 1e-9 and base.velocity[0, ix] == 0.0
    dyn = MachineDynamics(velfriction_coulomb=c, velfriction_viscous=b, velfriction_vs=vs)
    run = run_machine(build_machine_fmu(machine, tmp_path / "m.fmu", dynamics=dyn), machine, q, step)
    loss = c * np.tanh(vd / vs) + b * vd
    assert np.max(np.abs(run.velocity[:, ix] - (vd - loss))) < 1e-9
    assert np.max(np.abs(run.actual[:, ix] - (q[:, ix] - np.cumsum(loss) * step))) < 1e-9
    # the other axes are untouched
    others = [i for i in range(machine.n_axes) if i != ix]
    assert np.max(np.abs(run.actual[:, others] - q[:, others])) == 0.0


def test_friction_sticks_for_the_breakaway_then_catches_up_exponentially(machine, tmp_path):
    """Out at 10 mm/s and back (a sharp reversal at a sample): the slide stays at the reversal
    point until the command has come back by the breakaway distance (4 µm = 0.4 steps), then its
    lag decays as breakaway * exp(-(t - t_b)/tau); with Coulomb friction it settles at the
    Coulomb distance."""
    step, v, brk, tau = 1e-3, 10.0, 0.004, 0.02
    K = 400
    ix = machine.axis_names.index("X")
    t = np.arange(K) * step
    q = np.zeros((K, machine.n_axes))
    q[:, ix] = v * np.minimum(t, 0.2) - v * np.maximum(t - 0.2, 0.0)       # reversal at k = 200
    fmu = build_machine_fmu(machine, tmp_path / "m.fmu",
                            dynamics=MachineDynamics(friction_breakaway=brk, friction_tau=tau))
    lag = run_machine(fmu, machine, q, step).actual[:, ix] - q[:, ix]      # > 0: behind on the way back
    assert np.max(np.abs(lag[:201])) < 1e-12
    # the step 200 -> 201 takes the command 10 µm back: the breakaway after 0.4 of it
    tb = 201 * step + 0.4 * step
    k = np.arange(201, K)
    assert np.max(np.abs(lag[201:] - brk * np.exp(-((k + 1) * step - tb) / tau))) < 1e-12
    # Coulomb friction: a lag of 1 µm against the motion once the slide slides
    fmu = build_machine_fmu(machine, tmp_path / "m.fmu", dynamics=MachineDynamics(
        friction_breakaway=brk, friction_coulomb=0.001, friction_tau=tau))
    lag = run_machine(fmu, machine, q, step).actual[:, ix] - q[:, ix]
    assert lag[199] == pytest.approx(-0.001, abs=1e-7) and lag[-1] == pytest.approx(0.001, abs=3e-7)
    assert lag[202] > 0.002                                              # the glitch after the reversal


def test_quadrant_glitch_is_the_diagnosis_spike_after_each_reversal(machine, tmp_path):
    """Out at 10 mm/s and back, the command peaking at row 200 (t = 0.2 s): the drive reaches
    it at the end of that step and turns, so output row k (the end of step k) is t_k - 0.2 s
    after the reversal, on the recording's clock the time since the peak sample, as the
    diagnosis counts it.  The actual position lags against the new direction by A s exp(1 - s),
    s = (t_k - 0.2)/tau, peak A at tau after it (the diagnosis' quadrant_glitch); none before
    the reversal; a second reversal (row 400) restarts it with the other sign."""
    step, v, A, tau = 1e-3, 10.0, 0.003, 0.02
    K = 600
    ix = machine.axis_names.index("X")
    t = np.arange(K) * step
    q = np.zeros((K, machine.n_axes))
    q[:, ix] = v * np.minimum(t, 0.2) - v * np.clip(t - 0.2, 0.0, 0.2) + v * np.maximum(t - 0.4, 0.0)
    fmu = build_machine_fmu(machine, tmp_path / "m.fmu", dynamics=MachineDynamics(glitch_height=(A, 0, 0),
                                                                                   glitch_time=(tau, 0, 0)))
    err = run_machine(fmu, machine, q, step).actual[:, ix] - q[:, ix]
    assert np.max(np.abs(err[:200])) == 0.0
    s1 = (t - 0.2) / tau
    s2 = (t - 0.4) / tau
    want = np.where(t <= 0.4 + 1e-12, A * s1 * np.exp(1 - s1), -A * s2 * np.exp(1 - s2))
    want[:201] = 0.0
    assert np.max(np.abs(err - want)) < 1e-12
    k_peak = int(np.argmax(err))
    assert t[k_peak] == pytest.approx(0.2 + tau) and err[k_peak] == pytest.approx(A, rel=1e-12)


def _fmu_refuses(fmu, bad, good):
    """Through fmpy: fmi2SetReal of each (name, value) in ``bad`` fails (fmi2Error), and the
    in-range ``good`` (name, value) is accepted."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    slave = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(fmu)), modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName="m")
    slave.instantiate(loggingOn=True, callbacks=None)
    try:
        for name, value in bad:
            with pytest.raises(Exception):
                slave.setReal([vr[name]], [value])
        slave.setReal([vr[good[0]]], [good[1]])
    finally:
        slave.freeInstance()


def test_encoder_cyclic_error_is_the_diagnosis_form_on_the_actual_position(machine, tmp_path):
    """Ideal servo, X at 5 mm/s: the actual position is the command plus a1 sin(2 pi q/P +
    phi1) + a2 sin(4 pi q/P + phi2) (the diagnosis' encoder_cyclic_error, phases in deg) with
    no other element, q the command; Y and Z untouched; out-of-range amplitudes and negative
    periods are refused by name (build, FMU, dynamics file)."""
    from mtcomp._io import MtcompError
    from mtcomp.model.dynamics import load_dynamics
    step, P, a1, p1, a2, p2 = 1e-3, 0.02, 3e-4, 40.0, 1e-4, -75.0
    q = _ramp(machine, 500, 5.0, step)
    dyn = MachineDynamics(encoder_period=(P, 0, 0), encoder_a1=(a1, 0, 0), encoder_phase1=(p1, 0, 0),
                          encoder_a2=(a2, 0, 0), encoder_phase2=(p2, 0, 0))
    act = run_machine(build_machine_fmu(machine, tmp_path / "m.fmu", dynamics=dyn), machine, q, step).actual
    x = q[:, 0]
    want = a1 * np.sin(2 * np.pi * x / P + np.radians(p1)) + a2 * np.sin(4 * np.pi * x / P + np.radians(p2))
    assert np.max(np.abs(act[:, 0] - x - want)) < 1e-12
    assert np.max(np.abs(want)) > 3e-4
    assert np.max(np.abs(act[:, 1:] - q[:, 1:])) == 0.0
    with pytest.raises(MtcompError, match=r"encoder\.a1\.X"):
        build_machine_fmu(machine, tmp_path / "bad.fmu", dynamics=MachineDynamics(encoder_a1=(1.5, 0, 0)))
    with pytest.raises(MtcompError, match=r"encoder\.period\.Y"):
        build_machine_fmu(machine, tmp_path / "bad.fmu", dynamics=MachineDynamics(encoder_period=(0, -1.0, 0)))
    _fmu_refuses(tmp_path / "m.fmu", (("encoder.period.X", -0.02), ("encoder.a2.Y", 2.0),
                                       ("encoder.phase1.Z", 800.0)), ("encoder.phase2.Z", -700.0))
    (tmp_path / "d.toml").write_text('[parameters]\n"encoder.period.X" = -0.02\n')
    with pytest.raises(InputError, match="encoder.period.X"):
        load_dynamics(tmp_path / "d.toml", machine)
    (tmp_path / "d.toml").write_text('[parameters]\n"encoder.a2.Z" = 0.0003\n"encoder.phase2.Z" = -90.0\n')
    assert load_dynamics(tmp_path / "d.toml", machine) == {"encoder.a2.Z": 0.0003, "encoder.phase2.Z": -90.0}


def test_thermal_drift_over_time_and_driver_checks(machine, tmp_path):
    """thermal.driver = time: T = ambient + excess exp(-t/tau), the tool edge moves by
    drift (T - reference); an unknown driver and a delay beyond the command history are
    refused with the parameter named."""
    from mtcomp.fmu.cosim import CosimFailed, FmuRunner
    step, tau, ex = 1e-3, 0.3, 1.5
    dyn = MachineDynamics(thermal_driver="time", thermal_time_constant=tau, initial_excess=ex, drift=(0, 0, 2e-3),
                          reference=20.5)
    q = np.zeros((500, machine.n_axes))
    run = run_machine(build_machine_fmu(machine, tmp_path / "m.fmu", dynamics=dyn), machine, q, step)
    t_end = (np.arange(500) + 1) * step
    assert np.allclose(run.temperature, 20.0 + ex * np.exp(-t_end / tau), rtol=0, atol=1e-12)
    p0 = run_machine(build_machine_fmu(machine, tmp_path / "n.fmu"), machine, q, step).p
    assert np.allclose(run.p[:, 2] - p0[:, 2], 2e-3 * (run.temperature - 20.5), rtol=0, atol=1e-12)
    with pytest.raises(Exception, match="thermal_driver"):
        MachineDynamics(thermal_driver="humidity").driver_code
    r = FmuRunner(build_machine_fmu(machine, tmp_path / "m.fmu"), "bad")
    try:
        with pytest.raises(Exception):
            r.set({"thermal.driver": 3})
        assert any("thermal.driver = 3" in m for _, _, m in r.logs)
    finally:
        r.close()
    with pytest.raises(CosimFailed, match="delay"):
        run_machine(build_machine_fmu(machine, tmp_path / "m.fmu", dynamics=MachineDynamics(delay=0.5)), machine,
                    _ramp(machine, 600, 1.0), step)


def test_velocity_friction_out_of_range_is_refused_by_name(machine, tmp_path):
    """The FMU refuses (fmi2Error) a viscous loss beyond +-1 (the axis would run backwards) and a
    negative smoothing speed set through fmpy; the build refuses such start values naming the
    parameter, and so does the dynamics file."""
    from mtcomp._io import MtcompError
    from mtcomp.model.dynamics import load_dynamics
    with pytest.raises(MtcompError, match=r"velfriction\.viscous\.X"):
        build_machine_fmu(machine, tmp_path / "bad.fmu", dynamics=MachineDynamics(velfriction_viscous=(1.5, 0, 0)))
    _fmu_refuses(build_machine_fmu(machine, tmp_path / "m.fmu"),
                 (("velfriction.viscous.X", 1.5), ("velfriction.vs.Y", -1.0)), ("velfriction.coulomb.Z", 0.5))
    (tmp_path / "d.toml").write_text('[parameters]\n"velfriction.viscous.X" = 1.5\n')
    with pytest.raises(InputError, match="velfriction.viscous.X"):
        load_dynamics(tmp_path / "d.toml", machine)
    (tmp_path / "d.toml").write_text('[parameters]\n"velfriction.vs.X" = -1.0\n')
    with pytest.raises(InputError, match="velfriction.vs.X"):
        load_dynamics(tmp_path / "d.toml", machine)


def test_negative_backlash_is_the_mirror_of_the_play_about_the_servo(machine, tmp_path):
    """backlash.<AXIS> = -|b| (an over-compensated backlash, ISO 230-2 reversal value negative):
    the FMU's axis is the play of width |b| mirrored about the servo position, x = 2 servo - play,
    the form of the diagnosis' Backlash with sign -1; on an ideal servo it leads the command by
    |b|/2 in the direction of motion."""
    step, b = 1e-3, 0.004
    q = _path(machine, K=1500, step=step)
    runs = {}
    for name, bl in (("servo", 0.0), ("play", b), ("mirror", -b)):
        dyn = MachineDynamics(kv=(50.0, 0.0, 0.0), backlash=(bl, bl, bl))
        runs[name] = run_machine(build_machine_fmu(machine, tmp_path / f"{name}.fmu", dynamics=dyn),
                                 machine, q, step).actual
    assert np.max(np.abs(runs["mirror"] - (2 * runs["servo"] - runs["play"]))) < 1e-12
    # Z (ideal servo): out at 2 mm/s, back from the middle; at constant speed the axis leads by b/2
    z = machine.axis_names.index("Z")
    e = runs["mirror"][:, z] - q[:, z]
    k = len(q) // 2
    assert np.allclose(e[k - 300:k - 10], -0.5 * b, atol=1e-12)    # moving in -Z: leads in -Z
    assert np.allclose(e[k + 10 + int(b / 2e-3 / step):k + 300], 0.5 * b, atol=1e-12)


def test_compensation_of_a_negative_backlash_is_exact_through_the_fmu(machine, tmp_path):
    """mtcomp.model.compensate.backlash_offsets inverts the mirrored play (b < 0) exactly: the
    FMU's axes, fed the compensated and feed-forwarded commands, are at the targets at every
    step; the opposite reversal step (-|b|/2 by direction) leaves a spike of |b| after each
    reversal (inside the band the mirror moves twice as fast as the drive)."""
    from mtcomp.model.compensate import backlash_offsets, feed_forward
    step, b = 1e-3, -0.004
    w = _path(machine, K=1500, step=step)
    bl, kv = (b, b, b), (50.0, 80.0, 0.0)
    fmu = build_machine_fmu(machine, tmp_path / "m.fmu", dynamics=MachineDynamics(kv=kv, backlash=bl))
    act = run_machine(fmu, machine, feed_forward(w + backlash_offsets(w, bl), kv, step), step).actual
    assert np.max(np.abs(act - w)) < 1e-9
    # uncompensated: the axis leads by |b|/2; the naive opposite step: spikes of |b|
    z = machine.axis_names.index("Z")
    raw = run_machine(fmu, machine, feed_forward(w, kv, step), step).actual
    assert abs(np.max(np.abs(raw[:, z] - w[:, z])) - 0.5 * abs(b)) < 1e-9
    naive = run_machine(fmu, machine, feed_forward(w - backlash_offsets(w, [abs(b)] * 3), kv, step), step).actual
    assert np.max(np.abs(naive[:, z] - w[:, z])) > 0.9 * abs(b)


def test_backlash_range_is_plus_minus_one(machine, tmp_path):
    """backlash.<AXIS> spans -1..1 mm or deg (negative: the mirrored play); beyond, refused by name."""
    from mtcomp._io import MtcompError
    with pytest.raises(MtcompError, match=r"backlash.X = -1.5 is outside \[-1.0, 1.0\]"):
        build_machine_fmu(machine, tmp_path / "a.fmu", dynamics=MachineDynamics(backlash=(-1.5, 0.0, 0.0)))
    assert build_machine_fmu(machine, tmp_path / "b.fmu", dynamics=MachineDynamics(backlash=(-1.0, 0.0, 0.0))).is_file()
