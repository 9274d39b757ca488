"""Diagnosis: each concealed effect is named and its parameters recovered; noise names nothing."""
import math

import numpy as np
import pytest
from numpy.polynomial import legendre

from mtcomp.diagnose import diagnose, synth
from mtcomp.diagnose.effects import backlash_play, direction_of_motion, first_order

SHORT = dict(duration=30.0, sim_rate=200.0, rec_rate=500.0, n_temps=3, n_junk=2)

PARAMS = {
    "thermal_drift": {"driver": "s", "amp_mm": 3e-3, "tau_frac": 0.3},
    "backlash": {"backlash_mm": 4e-3},
    "servo_lag": {"kv_per_s": 40.0},
    "periodic_pitch_error": {"lead_mm": 5.0, "amplitude_mm": 1e-3, "phase_deg": 30.0},
    "scale_error": {"scale": 30e-6},
    "squareness": {"angle_deg": math.degrees(-40e-6)},
    "straightness": {"P2_mm": 1.5e-3, "P3_mm": -0.5e-3},
    "pivot_offset": {"dx_mm": 0.012, "dz_mm": -0.020},
    "workpiece_setting": {"tx_mm": 0.010, "ty_mm": -0.004, "tz_mm": 0.006,
                          "rz_deg": math.degrees(60e-6)},
    "time_offset": {"offset_s": 0.007},
}


def _one(res, name):
    got = [e for e in res.effects if e.name == name]
    assert len(got) == 1, res.summary()
    return got[0]


@pytest.mark.parametrize("name", sorted(PARAMS))
def test_single_effect_named_and_recovered(name):
    case = synth.make_case([(name, PARAMS[name])], seed=11, **SHORT)
    res = diagnose(case.sim, case.rec)
    assert res.names == [name], res.summary()
    e = _one(res, name)
    p, truth = e.params, case.truth[0][2]
    if name == "thermal_drift":
        assert p["gain_mm_per_rpm"] == pytest.approx(truth["gain_mm_per_rpm"], rel=0.05)
        assert p["tau_s"] == pytest.approx(truth["tau_s"], rel=0.05)
    elif name == "backlash":
        assert p["backlash_mm"] == pytest.approx(4e-3, rel=0.01)
    elif name == "servo_lag":
        assert p["kv_per_s"] == pytest.approx(40.0, rel=0.01)
    elif name == "periodic_pitch_error":
        assert p["lead_mm"] == pytest.approx(5.0, rel=1e-3)
        assert p["amplitude_mm"] == pytest.approx(1e-3, rel=0.03)
    elif name == "scale_error":
        assert p["scale"] == pytest.approx(30e-6, rel=0.01)
    elif name == "squareness":
        assert p["angle_deg"] == pytest.approx(math.degrees(-40e-6), rel=0.01)
    elif name == "straightness":
        # compare the profile along the travel actually covered, about the best straight line
        lo, hi = p["range_lo_mm"], p["range_hi_mm"]
        x = np.linspace(lo, hi, 101)
        xi_true = (2 * x - sum(synth.RANGES["x"])) / np.ptp(synth.RANGES["x"])
        true = legendre.legval(xi_true, [0, 0, 1.5e-3, -0.5e-3])
        true -= np.polyval(np.polyfit(x, true, 1), x)
        assert p["peak_to_valley_mm"] == pytest.approx(np.ptp(true), rel=0.03)
    elif name == "pivot_offset":
        assert p["dx_mm"] == pytest.approx(0.012, abs=2e-4)
        assert p["dz_mm"] == pytest.approx(-0.020, abs=2e-4)
    elif name == "workpiece_setting":
        for k in ("tx_mm", "ty_mm", "tz_mm"):
            assert p[k] == pytest.approx(PARAMS[name][k], abs=1e-4)
        assert p["rz_deg"] == pytest.approx(PARAMS[name]["rz_deg"], rel=0.02)
    elif name == "time_offset":
        assert p["offset_s"] == pytest.approx(0.007, abs=2e-4)
    # the uncertainty is reported for every parameter and is finite and positive somewhere
    assert set(e.uncertainty) <= set(p)
    assert any(v and v > 0 for v in e.uncertainty.values())
    # the fit reaches the noise on data it was not fitted on
    for o in e.outputs:
        assert res.fit["holdout_rms_after"][o] < 1.5 * res.noise_floor[o]
        assert res.fit["rms_before"][o] > 3 * res.noise_floor[o]
    assert any(m.output in e.outputs for m in res.mismatch)


@pytest.mark.parametrize("seed", [0, 1])
def test_null_case_names_nothing(seed):
    case = synth.make_case([], seed=seed, **SHORT)
    res = diagnose(case.sim, case.rec)
    assert res.effects == (), res.summary()
    assert res.mismatch == ()
    for o in res.outputs:
        assert res.fit["rms_after"][o] == res.fit["rms_before"][o]
        # the noise floor is the injected 20 nm (REC interpolated onto SIM's grid lowers it a bit)
        assert 14e-6 < res.noise_floor[o] < 22e-6


def test_two_effects_on_quantised_um_recording():
    case = synth.make_case(["backlash", "thermal_drift"], seed=5, um_headers=True,
                           quantum=5e-5, **SHORT)
    res = diagnose(case.sim, case.rec)
    assert sorted(res.names) == ["backlash", "thermal_drift"], res.summary()
    # 50 nm resolution: the noise floor cannot be below q/sqrt(12) = 14 nm
    assert res.noise_floor["z"] >= 5e-5 / math.sqrt(12) * 0.999
    b = _one(res, "backlash").params["backlash_mm"]
    assert b == pytest.approx(case.truth[0][2]["backlash_mm"], rel=0.03)
    # located and said in words: x depends on its direction of motion, z drifts with an input
    # (which one correlates most is not a test of cause: the logged temperatures are smooth)
    wx = " ".join(m.where for m in res.mismatch if m.output == "x")
    wz = " ".join(m.where for m in res.mismatch if m.output == "z")
    assert "direction of motion of x" in wx
    assert "z residual correlates most with" in wz
    assert not [m for m in res.mismatch if m.output == "y"]


def test_large_clock_offset_and_other_rates():
    # REC starts 2 s earlier on a clock 0.35 s behind, at 3x SIM's rate: the clocks are aligned
    # (not an effect), and a backlash is still found where the play switches
    case = synth.make_case([("time_offset", {"offset_s": 0.35}), ("backlash", {"backlash_mm": 3e-3})],
                           seed=3, duration=30.0, sim_rate=100.0, rec_rate=300.0, rec_start=-2.0)
    res = diagnose(case.sim, case.rec)
    assert res.names == ["backlash"], res.summary()
    assert res.alignment["clock_offset_s"] == pytest.approx(0.35, abs=1e-3)
    assert _one(res, "backlash").params["backlash_mm"] == pytest.approx(3e-3, rel=0.02)
    assert res.fit["holdout_rms_after"]["x"] < 1.5 * res.noise_floor["x"]


def test_result_json_keys_follow_the_contract():
    import json
    case = synth.make_case(["scale_error"], seed=2, **SHORT)
    d = json.loads(diagnose(case.sim, case.rec).to_json())
    assert list(d) == ["outputs", "noise_floor", "mismatch", "effects", "unexplained", "local",
                       "fit", "alignment", "notes"]
    assert d["unexplained"] == []
    assert d["outputs"] == ["x", "y", "z"]
    assert set(d["fit"]) == {"rms_before", "rms_after", "holdout_rms_before", "holdout_rms_after",
                             "whiteness"}
    (e,) = d["effects"]
    assert set(e) == {"name", "output", "inputs", "params", "uncertainty", "evidence"}
    assert e["name"] == "scale_error" and e["output"] == "y"
    m = d["mismatch"][0]
    assert set(m) == {"output", "t_start", "t_end", "where", "rms"}
    assert m["output"] == "y" and m["t_start"] < m["t_end"]


def test_first_order_filter_is_exact_for_a_ramp():
    dt, tau = 0.01, 0.037
    t = np.arange(0, 1, dt)
    u = np.where(t > 0.2, 5.0 * (t - 0.2), 0.0)  # ramp starting on a sample
    y = first_order(u, dt, tau)
    s = np.clip(t - 0.2, 0, None)
    exact = 5.0 * (s - tau * (1 - np.exp(-s / tau)))
    assert np.max(np.abs(y - exact)) < 1e-12


def test_vectorised_backlash_matches_sequential_play_operator():
    rng = np.random.default_rng(4)
    tr = synth.Trajectory(rng, 0.0, 50.0, 20.0, vmax=10.0, acc=100.0)
    p = tr(np.arange(0, 20, 0.002))
    b = 0.003
    first = np.sign(tr.seg[0][2] - tr.seg[0][1])
    ref = synth._play(p, b, first) - p
    got = backlash_play(p, b, direction_of_motion(p))
    assert np.max(np.abs(got - ref)) < 1e-12


def test_sparse_recording_of_a_few_hundred_samples():
    # REC at 5 Hz (200 samples) against a dense SIM: two effects still named and recovered
    case = synth.make_case([("squareness", PARAMS["squareness"]), ("backlash", PARAMS["backlash"])],
                           seed=8, duration=40.0, sim_rate=200.0, rec_rate=5.0, n_temps=3, n_junk=3)
    res = diagnose(case.sim, case.rec)
    assert res.alignment["samples"] < 210
    assert sorted(res.names) == ["backlash", "squareness"], res.summary()
    assert _one(res, "backlash").params["backlash_mm"] == pytest.approx(4e-3, rel=0.02)
    assert _one(res, "squareness").params["angle_deg"] == pytest.approx(math.degrees(-40e-6), rel=0.02)
