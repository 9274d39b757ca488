"""mtcomp model export: each effect of the diagnosis JSON mapped onto the machine model is
checked against the effect's own signature through the core kinematics (an independent model),
and the files it writes load where they are meant to go."""
from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from mtcomp._io import InputError
from mtcomp.errors import load_errors
from mtcomp.kinematics import forward
from mtcomp.machine import load_machine
from mtcomp.model.dynamics import load_dynamics
from mtcomp.model.export import export_model, read_ssv

VMC = load_machine("vmc-moving-column")


def _effect(name, output, inputs, params, unc=None):
    return {"name": name, "output": output, "inputs": inputs, "params": params,
            "uncertainty": unc or {k: 1e-9 for k in params}, "evidence": {}}


def _residual(machine, effects, q):
    ex = export_model({"effects": effects}, machine)
    assert not ex.unmapped, ex.unmapped
    return forward(machine, q, ex.errors).p - forward(machine, q).p, forward(machine, q).p, ex


def _poses(machine, n=200, seed=0):
    rng = np.random.default_rng(seed)
    lo = np.array([a.limits[0] for a in machine.axes])
    hi = np.array([a.limits[1] for a in machine.axes])
    return lo + (hi - lo) * rng.random((n, machine.n_axes))


def test_squareness_signs_follow_the_signature():
    q = _poses(VMC)
    for out, drv, g_deg in (("x", "y", 1e-3), ("y", "x", -2e-3), ("z", "x", 1.5e-3), ("x", "z", 1e-3)):
        r, p, ex = _residual(VMC, [_effect("squareness", out, [drv], {"angle_deg": g_deg})], q)
        o, j = "xyz".index(out), "xyz".index(drv)
        expect = math.radians(g_deg) * p[:, j]
        assert np.allclose(r[:, o], expect, atol=1e-9 + 1e-6 * np.abs(expect).max()), (out, drv)
        others = [k for k in range(3) if k != o]
        assert np.abs(r[:, others]).max() <= math.radians(g_deg) ** 2 * np.abs(p).max() + 1e-12  # 2nd order


def test_scale_pitch_straightness_tables():
    q = _poses(VMC, seed=1)
    s = 12e-6
    r, p, _ = _residual(VMC, [_effect("scale_error", "y", ["y"], {"scale": s})], q)
    assert np.allclose(r[:, 1], s * p[:, 1], atol=1e-10)
    lead, amp, ph = 5.0, 2e-4, 30.0
    r, p, ex = _residual(VMC, [_effect("periodic_pitch_error", "x", ["x"],
                                       {"lead_mm": lead, "amplitude_mm": amp, "phase_deg": ph})], q)
    a, b = amp * math.cos(math.radians(ph)), amp * math.sin(math.radians(ph))
    w = 2 * math.pi * p[:, 0] / lead
    assert np.allclose(r[:, 0], a * np.sin(w) + b * np.cos(w), atol=2e-3 * amp)   # 64 rows per lead
    coef = {"P0_mm": 1e-4, "P1_mm": -2e-4, "P2_mm": 3e-4, "P3_mm": 0.0, "P4_mm": 5e-5}
    r, p, _ = _residual(VMC, [_effect("straightness", "z", ["x"], dict(coef, range_lo_mm=-300.0, range_hi_mm=300.0))], q)
    from numpy.polynomial import legendre
    assert np.allclose(r[:, 2], legendre.legval(p[:, 0] / 300.0, list(coef.values())), atol=5e-7)


def test_workpiece_setting_and_pivot_offset():
    q = _poses(VMC, seed=2)
    par = {"tx_mm": 0.01, "ty_mm": -0.02, "tz_mm": 0.005, "rz_deg": 2e-3}
    r, p, _ = _residual(VMC, [_effect("workpiece_setting", "x,y,z", ["x", "y", "z"], par)], q)
    w = np.array([0.0, 0.0, math.radians(2e-3)])
    expect = -(np.array([0.01, -0.02, 0.005]) + np.cross(w, p))
    assert np.allclose(r, expect, atol=1.5 * w[2] * 0.023 + 1e-12)   # second order: w x T
    m = load_machine("robonano-a0ib")
    qr = _poses(m, seed=3)
    qr[:, 1] = 0.0                                     # B at zero: the effect is about C alone
    r, p, ex = _residual(m, [_effect("pivot_offset", "x,y", ["c"], {"dx_mm": 0.003, "dy_mm": -0.002})], qr)
    th = np.radians(qr[:, 0])
    d = np.array([0.003, -0.002])
    ex_x = (np.cos(th) - 1) * d[0] - np.sin(th) * d[1]
    ex_y = np.sin(th) * d[0] + (np.cos(th) - 1) * d[1]
    assert np.allclose(r[:, 0], ex_x, atol=1e-9) and np.allclose(r[:, 1], ex_y, atol=1e-9)


def test_no_home_effects_are_listed_not_dropped(tmp_path):
    effects = [_effect("backlash", "x", ["x"], {"backlash_mm": 0.002}),
               _effect("time_offset", "x,y", ["t"], {"offset_s": -1e-3}),          # REC leads: no delay
               _effect("thermal_drift", "z", ["hum"], {"gain_mm_per_pct": 1e-7, "tau_s": 600.0}),
               _effect("friction", "vx", ["vx"], {"coulomb_mm_per_s": 0.1}),
               _effect("pivot_offset", "x,z", ["b"], {"dx_mm": 0.001}),         # no rotary axis on the VMC
               _effect("quadrant_glitch", "y", ["y"], {"peak_mm": 2.0, "tau_s": 0.01})]   # beyond the FMU's range
    ex = export_model({"effects": effects}, VMC, tmp_path / "m", step=1e-3)
    assert [m.effect for m in ex.mapped] == ["backlash"]
    names = ["time_offset", "thermal_drift", "friction", "pivot_offset", "quadrant_glitch"]
    assert [e["name"] for e, _ in ex.unmapped] == names
    manifest = (tmp_path / "m" / "model.toml").read_text()
    for name in names:
        assert f'name = "{name}"' in manifest
    assert manifest.count('status = "no home"') == 5
    assert "NOT IN THE MODEL" in ex.summary()


def test_dynamic_effects_have_a_home(tmp_path):
    """A transport delay, stick-slip friction and a thermal drift go into dynamics.toml and the
    .ssv under the FMU's parameter names (thermal.driver as an ssv:Integer), and load back."""
    from mtcomp.model.dynamics import load_dynamics
    from mtcomp.model.export import read_ssv
    effects = [_effect("time_offset", "x,y,z", ["t"], {"offset_s": 2e-3}, {"offset_s": 1e-6}),
               _effect("quadrant_glitch", "y", ["y"], {"breakaway_mm": 0.003, "tau_s": 0.02},
                       {"breakaway_mm": 1e-5, "tau_s": 1e-4}),
               _effect("quadrant_glitch", "x", ["x"], {"peak_mm": -0.0025, "tau_s": 0.015},      # the spike form
                       {"peak_mm": 2e-6, "tau_s": 3e-5}),
               _effect("thermal_drift", "z", ["spindle_speed"], {"gain_mm_per_rpm": 4e-6, "tau_s": 3.0,
                                                                 "initial_mm": 1e-3, "offset_mm": -2e-3}),
               _effect("thermal_drift", "x", ["spindle_speed"], {"gain_mm_per_rpm": -1e-6, "tau_s": 2.0})]
    ex = export_model({"effects": effects}, VMC, tmp_path / "m", step=1e-3, drivers={"spindle_speed": 1000.0})
    dyn = load_dynamics(tmp_path / "m" / "dynamics.toml", load_machine(VMC))
    ssv = read_ssv(tmp_path / "m" / "machine.ssv")
    want = {"delay": 2e-3, "friction.breakaway.Y": 0.003, "friction.tau.Y": 0.02, "glitch.height.X": -0.0025,
            "glitch.time.X": 0.015, "thermal.driver": 0,
            "thermal.gain": 1e-3, "thermal.time_constant": 3.0, "thermal.drift.z": 4e-3, "thermal.drift.x": -1e-3,
            # excess = r0/drift + G S0 = 0.25 + 1; reference = 20 + G S0 - c/drift = 20 + 1 + 0.5
            "thermal.initial_excess": 1.25, "thermal.reference": 21.5}
    for k, v in want.items():
        assert dyn[k] == pytest.approx(v, rel=1e-12) and ssv[k] == pytest.approx(v, rel=1e-12), k
    assert isinstance(ssv["thermal.driver"], int)
    assert "one thermal state" in ex.summary()


def test_thermal_mapping_reproduces_the_diagnosed_drift():
    """The FMU's thermal model with the mapped parameters (Python reference) moves the tool edge
    by the diagnosis' k (F_tau[u] - u0) + r0 exp(-t/tau) + c, for a spindle speed (starting at
    800 1/min) and for a logged temperature; the FMU holds the driver over each 1 ms step, the
    diagnosis' filter is ramp invariant: equal to 1e-3 of the drift."""
    from mtcomp.diagnose.effects import first_order
    from mtcomp.fmu.build import MachineDynamics
    from mtcomp.model.dynamics import apply_dynamics
    from mtcomp.model.machine_ref import temperature
    m = load_machine(VMC)
    h, K = 1e-3, 8000
    t = np.arange(K) * h
    k, tau, r0, c = 3e-6, 1.5, 2e-3, -1e-3
    for col, unit, u in (("spindle_speed", "rpm", 800.0 + 2000.0 * (t > 2.0) + 500.0 * np.sin(t)),
                         ("temp", "degC", 21.0 + 0.8 * np.sin(t / 2.0))):
        kk = k if unit == "rpm" else 4e-3
        e = _effect("thermal_drift", "z", [col], {f"gain_mm_per_{unit}": kk, "tau_s": tau,
                                                  "initial_mm": r0, "offset_mm": c})
        ex = export_model({"effects": [e]}, m, None, step=h, drivers={col: float(u[0])})
        dyn = apply_dynamics(MachineDynamics(), ex.dynamics_values, m, combine=False)
        T = temperature(K, h, dyn, spindle_speed=u if unit == "rpm" else 0.0,
                        temperature_input=u if unit == "degC" else 20.0)
        fmu = dyn.drift[2] * (T - dyn.reference_temperature)
        te = t + h                       # the FMU's output k is its state at the end of step k
        want = kk * (first_order(u, h, tau) - u[0]) + r0 * np.exp(-te / tau) + c
        assert np.max(np.abs(fmu - want)) < 1e-3 * np.max(np.abs(want)), unit


def test_files_load_where_they_go(tmp_path):
    effects = [_effect("backlash", "x", ["x"], {"backlash_mm": 0.002}, {"backlash_mm": 1e-6}),
               _effect("servo_lag", "y", ["y"], {"kv_per_s": 30.0}, {"kv_per_s": 0.01}),
               _effect("squareness", "x", ["y"], {"angle_deg": 1e-3}, {"angle_deg": 1e-5}),
               _effect("scale_error", "x", ["x"], {"scale": 1e-5}, {"scale": 1e-7})]
    ex = export_model({"effects": effects}, VMC, tmp_path / "m", step=1e-3)
    errors = load_errors(tmp_path / "m" / "errors.toml", machine=VMC)       # what `compensate --errors` reads
    assert errors.geometric.location["EC0Y"] == pytest.approx(-math.radians(1e-3))
    assert set(errors.geometric.tables) == {"X"}
    dyn = load_dynamics(tmp_path / "m" / "dynamics.toml", VMC)
    assert dyn["backlash.X"] == 0.002
    assert dyn["servo.kv.Y"] == pytest.approx(math.log1p(30.0 * 1e-3) / 1e-3)
    ssv = read_ssv(tmp_path / "m" / "machine.ssv")
    assert ssv == {p.name: pytest.approx(p.value) for p in ex.params}
    assert set(ssv) == {"backlash.X", "servo.kv.Y", "location.EC0Y"}
    text = (tmp_path / "m" / "machine.ssv").read_text()
    assert 'xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues"' in text
    assert "org.mtcomp.uncertainty" in text
    toml = (tmp_path / "m" / "errors.toml").read_text()
    assert "[uncertainty]" in toml and "X.EXX.scale" in toml


def test_ssv_parameters_apply_in_the_fmu(tmp_path):
    """The .ssv names are the machine FMU's parameter names: set them into a built FMU through
    fmpy and read them back."""
    pytest.importorskip("fmpy")
    from fmpy import simulate_fmu

    from mtcomp.fmu.build import build_machine_fmu
    ex = export_model({"effects": [_effect("backlash", "x", ["x"], {"backlash_mm": 0.002}),
                                   _effect("squareness", "x", ["y"], {"angle_deg": 1e-3})]},
                      VMC, tmp_path / "m", step=1e-3)
    fmu = build_machine_fmu(VMC, tmp_path / "machine.fmu", compiler="cc")
    vals = read_ssv(tmp_path / "m" / "machine.ssv")
    res = simulate_fmu(str(fmu), stop_time=0.01, step_size=1e-3, start_values=vals,
                       output=["actual.X"], fmi_type="CoSimulation")
    assert len(res) > 1
    from fmpy import read_model_description
    names = {v.name for v in read_model_description(str(fmu)).modelVariables}
    assert set(vals) <= names


def test_cli_export_and_bad_input(tmp_path):
    diag = tmp_path / "d.json"
    diag.write_text(json.dumps({"effects": [_effect("backlash", "x", ["x"], {"backlash_mm": 0.002})]}))
    cmd = [sys.executable, "-m", "mtcomp", "model", "export", str(diag), "--machine", "vmc-moving-column",
           "--step", "0.001", "-o", str(tmp_path / "out")]
    r = subprocess.run(cmd, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "backlash.X" in r.stdout and (tmp_path / "out" / "machine.ssv").is_file()
    diag.write_text('{"effects": 3}')
    r = subprocess.run(cmd, capture_output=True, text=True)
    assert r.returncode != 0 and "effects" in r.stderr and "Traceback" not in r.stderr
    with pytest.raises(InputError):
        export_model(str(diag), VMC)


def test_exported_errors_drive_compensate(tmp_path):
    """The exported errors.toml is what `mtcomp compensate --errors` takes: a squareness and a
    scale error diagnosed on the VMC compensate a program (by hand: X100 Y150 becomes X99.9928)."""
    effects = [_effect("squareness", "x", ["y"], {"angle_deg": 2e-3}),
               _effect("scale_error", "x", ["x"], {"scale": 2e-5})]
    export_model({"effects": effects}, VMC, tmp_path / "m", step=1e-3)
    prog = tmp_path / "p.nc"
    prog.write_text("G90 G1 F600\nX0 Y0 Z0\nX100 Y150\nX-100 Y-150\n")
    out = tmp_path / "pc.nc"
    r = subprocess.run([sys.executable, "-m", "mtcomp", "compensate", str(prog), "--machine", "vmc-moving-column",
                        "--errors", str(tmp_path / "m" / "errors.toml"), "-o", str(out)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    # x error at (100, 150): scale 2e-5 * 100 + squareness radians(2e-3) * 150 = 7.24 µm, commanded away
    assert "X99.9928 Y150" in out.read_text()


def test_bad_dynamics_and_missing_provenance_are_named(tmp_path):
    from mtcomp.model.simulate import read_provenance
    bad = tmp_path / "dyn.toml"
    bad.write_text('[parameters]\n"servo.kv.Q" = 30.0\n')
    with pytest.raises(InputError, match="axis Q"):
        load_dynamics(bad, VMC)
    bad.write_text('[parameters]\n"backlash.X" = -2.0\n')     # negative is an over-compensated backlash, to -1
    with pytest.raises(InputError, match="within"):
        load_dynamics(bad, VMC)
    bad.write_text('[parameters]\n"friction.breakaway.X" = -0.001\n')
    with pytest.raises(InputError, match=">= 0"):
        load_dynamics(bad, VMC)
    bad.write_text('[parameters]\n"friction.X" = 1.0\n')
    with pytest.raises(InputError, match="unknown dynamics parameter"):
        load_dynamics(bad, VMC)
    bad.write_text('[parameters]\n"thermal.driver" = 3\n')
    with pytest.raises(InputError, match="thermal.driver"):
        load_dynamics(bad, VMC)
    bad.write_text('[parameters]\n"delay" = 2.0\n')
    with pytest.raises(InputError, match="delay"):
        load_dynamics(bad, VMC)
    bad.write_text('[parameters]\n"thermal.drift.z" = -0.004\n"thermal.reference" = 21.5\n')
    assert load_dynamics(bad, VMC) == {"thermal.drift.z": -0.004, "thermal.reference": 21.5}   # signed: fine
    with pytest.raises(InputError, match="provenance"):
        read_provenance(tmp_path / "nothing.csv")
    # a drivers file without a driver column, through the CLI: one line naming the file, no traceback
    (tmp_path / "p.nc").write_text("G90 G1 F600\nX0 Y0 Z0\nX1\n")
    (tmp_path / "drv.csv").write_text("t,humidity\n0,1\n1,2\n")
    r = subprocess.run([sys.executable, "-m", "mtcomp", "model", "simulate", "p.nc", "--machine", "vmc-moving-column",
                        "--drivers", "drv.csv", "-o", "s.csv"], capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode != 0 and "drv.csv" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "s.csv").exists()
    # a leading (negative, over-compensated) backlash maps to a negative backlash.X, sigma along
    # (the FMU mirrors its play: issue 18, every effect of the diagnosis has a home)
    ex = export_model({"effects": [_effect("backlash", "x", ["x"], {"backlash_mm": -0.001},
                                           {"backlash_mm": 2e-5})]}, VMC)
    assert not ex.unmapped
    (p,) = ex.params
    assert (p.name, p.value, p.sigma) == ("backlash.X", -0.001, 2e-5)


def test_output_names_with_prefixes_and_suffixes():
    from mtcomp.model.axes import NoHome, coordinate_letter
    assert [coordinate_letter(n) for n in ("x", "tool.y", "z_act", "pos_x", "y1", "x[um]")] == list("xyzxyx")
    for bad in ("temp", "xy", "spindle"):
        with pytest.raises(NoHome):
            coordinate_letter(bad)
    ex = export_model({"effects": [_effect("squareness", "tool.x", ["tool.y"], {"angle_deg": 1e-3}),
                                   _effect("backlash", "y_act", ["y_act"], {"backlash_mm": 1e-3})]}, VMC)
    assert {p.name for p in ex.params} == {"location.EC0Y", "backlash.Y"}


def test_provenance_round_trip_with_a_machine_file(tmp_path):
    """The sidecar keeps a machine TOML as a path (relative to itself), the program and the
    dynamics; read_provenance gives them back."""
    import shutil
    from pathlib import Path

    import mtcomp.presets
    from mtcomp.fmu.build import MachineDynamics
    from mtcomp.model.simulate import Signals, read_provenance, write_signals
    mfile = tmp_path / "mine.toml"
    shutil.copy(Path(mtcomp.presets.__file__).parent / "vmc-moving-column.toml", mfile)
    (tmp_path / "p.nc").write_text("G1 X1\n")
    sig = Signals(np.array([0.0, 0.1]), np.zeros((2, 3)), np.zeros((2, 3)), ("X", "Y", "Z"))
    out = tmp_path / "sub"
    out.mkdir()
    dyn = MachineDynamics(kv=(30.0, 0.0, 0.0), backlash=0.001, noise=2e-5, seed=4)
    write_signals(out / "sim.csv", sig, str(mfile), program=tmp_path / "p.nc", dynamics=dyn, step=1e-3)
    prov = read_provenance(out / "sim.csv")
    assert prov.machine.axis_names == ("X", "Y", "Z") and prov.step == 1e-3
    assert prov.program.resolve() == (tmp_path / "p.nc").resolve()
    assert prov.dynamics == dyn
    assert 'machine = "../mine.toml"' in (out / "sim.csv.provenance.toml").read_text()


def test_package_exports():
    import mtcomp.model as mm
    from mtcomp.model import ModelExport, ResimResult, close_loop, export_model, load_dynamics, resimulate  # noqa: F401
    assert mm.export_model is export_model
    with pytest.raises(AttributeError):
        mm.nothing_here  # noqa: B018


def _element_truth(P, par, unit="mm"):
    """The encoder element's harmonics 1 and 2 for the diagnosis' r_d(y) (y the recorded
    position): per axis position q the recorded y solves y - r_d(y) = q (brentq, independent of
    the mapping's fixed-point iteration), r(q) = y - q, fitted by least squares with harmonics
    0..4 over one period; returns [(A_1, phi_1 deg), (A_2, phi_2 deg)]."""
    from scipy.optimize import brentq

    def r_d(y):
        return sum(par[f"amplitude_h{h}_{unit}"] * np.sin(2 * np.pi * h * y / P + math.radians(par[f"phase_h{h}_deg"]))
                   for h in (1, 2))
    q = np.arange(512) / 512 * P
    amp = sum(par[f"amplitude_h{h}_{unit}"] for h in (1, 2))
    r = np.array([brentq(lambda y: y - r_d(y) - qi, qi - 2 * amp - 1e-12, qi + 2 * amp + 1e-12, xtol=1e-16)
                  for qi in q]) - q
    w = 2 * np.pi * q / P
    cols = [np.ones_like(w)] + [f(h * w) for h in range(1, 5) for f in (np.sin, np.cos)]
    c = np.linalg.lstsq(np.stack(cols, axis=1), r, rcond=None)[0]
    return [(math.hypot(c[2 * h - 1], c[2 * h]), math.degrees(math.atan2(c[2 * h], c[2 * h - 1]))) for h in (1, 2)]


def test_encoder_cyclic_error_of_a_rotary_axis_is_its_encoder_element():
    """On the angle output of a rotary axis (C of the robonano-ui, a 0.5 deg signal period,
    amplitudes in deg) the effect maps to the element of C as it is: the axis reads its angle."""
    from mtcomp.model.machine_ref import encoder_cyclic
    m = load_machine("robonano-ui")
    par = {"period_deg": 0.5, "amplitude_h1_deg": 2e-4, "phase_h1_deg": 200.0, "amplitude_h2_deg": 5e-5,
           "phase_h2_deg": -10.0}
    ex = export_model({"effects": [_effect("encoder_cyclic_error", "c", ["c"], par)]}, m)
    assert not ex.unmapped and not ex.errors.geometric.tables
    v = ex.dynamics_values
    assert v["encoder.period.C"] == 0.5
    # the element acts on the axis' angle before the error, the diagnosis' r_d on the read one
    (a1, f1), (a2, f2) = _element_truth(0.5, par, "deg")
    c = np.linspace(-360.0, 360.0, 7001)
    got = encoder_cyclic(c, 0.5, v["encoder.a1.C"], v["encoder.phase1.C"], v["encoder.a2.C"], v["encoder.phase2.C"])
    assert np.max(np.abs(got - encoder_cyclic(c, 0.5, a1, f1, a2, f2))) < 1e-12
    # and the angle it gives reproduces the diagnosis' r_d at the angle read better than a copy
    # of r_d's harmonics does (what is left: harmonics 3 and up, order 2 pi A_1 A_2/P)

    def r_d(y):
        w = 2 * np.pi * y / 0.5
        return 2e-4 * np.sin(w + math.radians(200.0)) + 5e-5 * np.sin(2 * w + math.radians(-10.0))
    copy = encoder_cyclic(c, 0.5, 2e-4, 200.0, 5e-5, -10.0)
    assert np.max(np.abs(got - r_d(c + got))) < 0.5 * np.max(np.abs(copy - r_d(c + copy)))
    assert {p.unit for p in ex.dynamics if not p.name.startswith("encoder.phase")} == {"deg"}


def test_encoder_cyclic_error_as_a_table_or_the_encoder_element():
    """Harmonics 1 and 2 of a scale's signal period: a positioning table when 64 rows per period
    fit the travel, else the machine FMU's encoder element of the axis (controls correct it in the
    encoder interface): on each output of the VMC (axis signs and offsets of the tool edge at
    zero), the element on the axis reproduces the diagnosis' r(p) on the output coordinate."""
    from mtcomp.fmu.build import MachineDynamics
    from mtcomp.model.dynamics import apply_dynamics
    from mtcomp.model.machine_ref import encoder_cyclic
    q = _poses(VMC, seed=4)
    P = 2.0   # mm: 64 rows per period over the travel stays below the row limit
    par = {"period_mm": P, "amplitude_h1_mm": 3e-4, "phase_h1_deg": 40.0,
           "amplitude_h2_mm": 1e-4, "phase_h2_deg": -70.0}
    r, p, ex = _residual(VMC, [_effect("encoder_cyclic_error", "y", ["y"], par)], q)
    # the table is a function of the axis position before the error: the harmonics of r(q) =
    # y - q with y - r_d(y) = q, to the table's linear interpolation (0.12 % of the amplitude)
    (a1, f1), (a2, f2) = _element_truth(P, par)
    w = 2 * math.pi * p[:, 1] / P
    expect = a1 * np.sin(w + math.radians(f1)) + a2 * np.sin(2 * w + math.radians(f2))
    assert np.allclose(r[:, 1], expect, atol=2e-3 * 4e-4)
    P = 0.02    # mm: 20 µm over 600 mm would need 1.9 million rows
    for out in "xyz":
        ex = export_model({"effects": [_effect("encoder_cyclic_error", out, [out], dict(par, period_mm=P))]}, VMC)
        assert not ex.unmapped and not ex.errors.geometric.tables
        names = {p.name for p in ex.dynamics}
        (axis,) = {n.rsplit(".", 1)[1] for n in names}
        assert names == {f"encoder.{k}.{axis}" for k in ("period", "a1", "phase1", "a2", "phase2")}
        dyn = apply_dynamics(MachineDynamics(), ex.dynamics_values, VMC)
        i = VMC.axis_names.index(axis)
        act = q.copy()
        act[:, i] += encoder_cyclic(q[:, i], *(dyn.per_axis(getattr(dyn, f"encoder_{k}"), 3, k)[i]
                                               for k in ("period", "a1", "phase1", "a2", "phase2")))
        p = forward(VMC, q).p
        r = forward(VMC, act).p - p
        o = "xyz".index(out)
        # the element's harmonics are those of r(q) = y - q with y - r_d(y) = q (the diagnosis
        # reads r_d at the recorded position y): on the output coordinate, with the axis' sign
        # and offset, exactly those
        (a1, f1), (a2, f2) = _element_truth(P, dict(par, period_mm=P))
        w = 2 * math.pi * p[:, o] / P
        expect = a1 * np.sin(w + math.radians(f1)) + a2 * np.sin(2 * w + math.radians(f2))
        assert np.max(np.abs(r[:, o] - expect)) < 1e-9
        assert np.max(np.abs(np.delete(r, o, axis=1))) < 1e-9
