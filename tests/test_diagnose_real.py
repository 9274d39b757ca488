"""Diagnosis of a real recording (UMich CNC mill, command vs actual velocities) and of the
recordings the first version got wrong: every one must name the physics or say 'unexplained'."""
from pathlib import Path

import numpy as np
import pytest

from mtcomp.diagnose import diagnose, synth

HERE = Path(__file__).parent / "data" / "umich" / "exp06"


def test_real_cnc_velocities_servo_lag_on_every_axis_and_held_out_halved():
    res = diagnose(HERE / "sim.csv", HERE / "rec.csv")
    lags = {e.outputs[0]: e for e in res.effects if e.name == "servo_lag"}
    assert set(lags) == {"vx", "vy", "vz"}, res.summary()
    for o, e in lags.items():
        # through the logged commanded acceleration, a position-loop time constant of a few ms
        assert "az_cmd" in e.inputs or "ax_cmd" in e.inputs or "ay_cmd" in e.inputs
        assert 0.003 < e.params["tau_s"] < 0.015
        assert res.fit["holdout_rms_after"][o] < 0.6 * res.fit["holdout_rms_before"][o]
    total_b = sum(v ** 2 for v in res.fit["holdout_rms_before"].values())
    total_a = sum(v ** 2 for v in res.fit["holdout_rms_after"].values())
    assert total_a < 0.25 * total_b  # held-out RMS over the axes more than halved
    # columns: the kinds came from the units in the headers, not from name guesses
    cols = res.alignment["columns"]
    assert cols["vx"]["kind"] == "velocity" and cols["vx"]["kind_from"] == "unit"
    assert cols["ax_cmd"]["kind"] == "acceleration"
    # what is left is more than 3x the noise on some axis: said so, never "noise"
    text = res.summary()
    assert "explained by noise" not in text
    for u in res.unexplained:
        assert u["ratio"] > 3
        assert "unexplained mismatch" in text


def test_unexplained_is_said_when_nothing_in_the_library_fits():
    # a friction-like spike at every reversal of x is not in the library for positions: the
    # residual is many times the noise, and the answer must say so instead of "noise"
    case = synth.make_case([], seed=4, duration=20.0)
    rec = dict(case.rec)
    t = rec["t"]
    rec["x"] = rec["x"] + 2e-3 * np.sin(2 * np.pi * t / 0.7) * (t > 5)
    res = diagnose(case.sim, rec)
    rms = res.fit["holdout_rms_after"]["x"]
    if rms > 3 * res.noise_floor["x"]:
        assert [u["output"] for u in res.unexplained] == ["x"], res.summary()
        assert "unexplained mismatch" in res.summary()
        assert "explained by noise" not in res.summary()


def test_names_differing_by_case_are_two_columns(tmp_path):
    t = np.arange(200) * 0.01
    sim = {"t": t, "x": np.sin(t), "X": np.cos(t)}
    rec = {"t": t, "x": np.sin(t) + 1e-6 * np.random.default_rng(0).normal(size=200)}
    res = diagnose(sim, rec)
    assert res.outputs == ("x",)
    assert res.alignment["columns"]["X"]["role"] == "input"


def test_huge_value_in_an_auxiliary_column_is_a_clear_error(tmp_path):
    from mtcomp import InputError
    case = synth.make_case([], seed=1, duration=5.0)
    rec = dict(case.rec)
    aux = np.array(rec["aux0"], float)
    aux[7] = 1e308
    rec["aux0"] = aux
    synth.write_csv(tmp_path / "rec.csv", rec)
    synth.write_csv(tmp_path / "sim.csv", case.sim)
    with pytest.raises(InputError, match=r"rec.csv:9 \[aux0\].*out of range"):
        diagnose(tmp_path / "sim.csv", tmp_path / "rec.csv")


def test_header_error_names_the_header_line(tmp_path):
    from mtcomp import InputError
    p = tmp_path / "rec.csv"
    p.write_text("# recorder v2\n# units: mm\nt,x,x\n0,1,1\n1,2,2\n")
    with pytest.raises(InputError, match=r"rec.csv:3 \[x\].*twice"):
        diagnose(p, p)


def test_clock_offset_with_servo_lag_keeps_the_lag():
    # REC on a clock 0.3 s apart AND a servo lag: the offset must not swallow the lag
    case = synth.make_case([("time_offset", {"offset_s": 0.3}), ("servo_lag", {"kv_per_s": 30.0})],
                           seed=2, duration=30.0, sim_rate=200.0, rec_rate=200.0, rec_start=-1.0)
    res = diagnose(case.sim, case.rec)
    assert "servo_lag" in res.names, res.summary()
    assert res.alignment["clock_offset_s"] == pytest.approx(0.3, abs=2e-3)
    lag = [e for e in res.effects if e.name == "servo_lag"][0]
    assert lag.params["kv_per_s"] == pytest.approx(30.0, rel=0.05)


def test_stop_and_measure_recording_is_diagnosed_with_effects_at_rest():
    # readings only at rest at the targets (ISO 230-2 style): a reversal error of 12 µm must be
    # named as backlash, never as servo lag or a clock offset
    rng = np.random.default_rng(3)
    targets = np.linspace(0, 100, 11)
    seq = np.concatenate([targets, targets[::-1]] * 3)
    t_sim, x_sim, t_rec, x_rec = [], [], [], []
    t = 0.0
    prev = seq[0]
    for k, p in enumerate(seq):
        move = np.linspace(prev, p, 50)
        tt = t + np.linspace(0, 1.0, 50)
        t_sim += list(tt)
        x_sim += list(move)
        dwell = t + 1.0 + np.linspace(0.01, 1.95, 20)
        t_sim += list(dwell)
        x_sim += [p] * 20
        d = np.sign(p - prev) if p != prev else (1.0 if k == 0 else d)
        t_rec.append(t + 2.0)
        x_rec.append(p - d * 6e-3 + rng.normal(0, 0.5e-3))
        prev = p
        t += 3.0
    res = diagnose({"t": np.array(t_sim), "x": np.array(x_sim)},
                   {"t": np.array(t_rec), "x": np.array(x_rec)})
    assert res.alignment["at_rest"] and res.alignment["clock_offset_s"] == 0.0
    assert res.names == ["backlash"], res.summary()
    assert res.effects[0].params["backlash_mm"] == pytest.approx(12e-3, abs=1.5e-3)


def test_plot_returns_a_figure_without_touching_the_backend(tmp_path):
    import matplotlib
    before = matplotlib.get_backend()
    case = synth.make_case(["backlash"], seed=1, duration=10.0)
    res = diagnose(case.sim, case.rec)
    fig = res.plot(tmp_path / "d.png")
    assert (tmp_path / "d.png").stat().st_size > 1000
    assert matplotlib.get_backend() == before
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert any("µm" in s for s in labels) and not any("(um)" in s for s in labels)


def test_empirical_dependence_is_reported_as_not_a_known_effect():
    # an error growing with the square of the speed (even in v: no lag, backlash or friction of
    # the library has that form) is unexplained, and the dependence on dx/dt is reported
    case = synth.make_case([], seed=6, duration=20.0)
    rec = dict(case.rec)
    t = rec["t"]
    v = np.gradient(np.interp(t, case.sim["t"], case.sim["x"]), t)
    rec["x"] = rec["x"] + 4e-6 * v ** 2
    res = diagnose(case.sim, rec)
    un = {u["output"]: u for u in res.unexplained}
    assert "x" in un, res.summary()
    emp = un["x"]["empirical"]
    assert emp is not None and emp["signal"] == "dx/dt" and emp["reduction"] > 0.5
    assert "not a known physical effect" in res.summary()


def test_text_fixes_spindle_temperature_near_zero_and_clock_sign():
    from mtcomp.diagnose.data import kind_from_name
    from mtcomp.diagnose.locate import _num
    assert kind_from_name("spindle_temp") == "temperature"
    assert _num(-3.854e-157, 10.0) == "0"
    case = synth.make_case([("time_offset", {"offset_s": -0.25})], seed=8, duration=15.0,
                           rec_start=0.5)
    text = diagnose(case.sim, case.rec).summary()
    assert "- -" not in text and "e-15" not in text
    assert "clocks aligned: REC's clock runs -0.25" in text


def test_one_velocity_output_chosen_by_option_is_not_taken_for_stop_and_measure():
    # constant-velocity stretches are not rest: with --output vz alone the lag is still named
    res = diagnose(HERE / "sim.csv", HERE / "rec.csv", outputs=["vz"])
    assert not res.alignment["at_rest"]
    assert res.names == ["servo_lag"], res.summary()
    assert res.alignment["columns"]["vx"]["role"] == "input"


def test_clock_offset_with_backlash_names_no_lag():
    # the demo's recording: a backlash on x, REC on a clock 0.25 s apart, no servo lag. A
    # backlash looks like a lag to the clock alignment; it must neither bias the clock nor be
    # explained by lags on every axis.
    rng = np.random.default_rng(0)
    pts = [np.zeros(3)]
    for _ in range(6):
        pts.append(np.clip(pts[-1] + rng.uniform(-15, 15, 3), [-50, -50, -40], [50, 50, 0]))
    q = []
    for a, b in zip(pts[:-1], pts[1:]):
        s = np.linspace(0, 1, int(np.linalg.norm(b - a) / 10.0 / 1e-3) + 2)[:, None]
        q.append(a + (3 * s ** 2 - 2 * s ** 3) * (b - a))
        q.append(np.repeat(b[None], int(rng.integers(100, 400)), axis=0))
    q = np.vstack(q)
    t = np.arange(len(q)) * 1e-3
    real = q + rng.normal(0, 2e-5, q.shape)
    cur, h = q[0, 0], 0.002
    for k in range(len(t)):  # play operator of 4 µm on x, stepped sample by sample
        cur = min(max(cur, q[k, 0] - h), q[k, 0] + h)
        real[k, 0] = cur + rng.normal(0, 2e-5)
    tr = np.arange(0.25, t[-1] - 0.1, 2.5e-3)
    sim = {"t": t, "x": q[:, 0], "y": q[:, 1], "z": q[:, 2]}
    rec = {"t": tr - 0.25, **{f"{c}[um]": np.interp(tr, t, real[:, j]) * 1e3 for j, c in enumerate("xyz")}}
    res = diagnose(sim, rec)
    assert res.names == ["backlash"], res.summary()
    assert res.alignment["clock_offset_s"] == pytest.approx(-0.25, abs=2e-4)
    assert res.effects[0].params["backlash_mm"] == pytest.approx(4e-3, rel=0.02)
