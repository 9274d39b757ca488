"""Alignment with a known floor: REC compared on its own instants, a piecewise-linear SIM
interpolated exactly between its corners, steps holding a corner between SIM's samples set
aside, the resampling floor said as such."""
import numpy as np
import pytest

from mtcomp.diagnose import diagnose, synth
from mtcomp.diagnose.align import corners

CASES = {"backlash": ("backlash", {"backlash_mm": 4e-3}),
         "servo_lag": ("servo_lag", {"kv_per_s": 30.0}),
         "scale_error": ("scale_error", {"scale": 30e-6})}


@pytest.mark.parametrize("name", sorted(CASES))
def test_sim_10hz_rec_25hz_piecewise_linear_reaches_the_noise(name):
    # before: REC interpolated onto SIM's 10 Hz instants across G1 corners: every effect named,
    # the residual 1.2-1.4 µm against 20 nm of noise, "unexplained mismatch, 65x its floor"
    case = synth.polyline_case(CASES[name], seed=1)
    res = diagnose(case.sim, case.rec)
    assert res.names == [name], res.summary()
    for o in res.outputs:
        assert res.fit["holdout_rms_after"][o] <= 3 * case.noise, (o, res.summary())
    assert res.unexplained == ()
    p = res.effects[0].params
    key, val = {"backlash": ("backlash_mm", 4e-3), "servo_lag": ("kv_per_s", 30.0),
                "scale_error": ("scale", 30e-6)}[name]
    assert p[key] == pytest.approx(val, rel=0.02)


def test_corners_between_samples_set_aside_and_said():
    case = synth.polyline_case(None, seed=2, corner_dt=None)
    res = diagnose(case.sim, case.rec)
    assert res.names == [], res.summary()
    assert any("corners between its samples" in n for n in res.notes)
    for o in res.outputs:
        assert res.fit["holdout_rms_after"][o] <= 3 * case.noise


def test_corners_found_on_and_between_samples():
    t = np.arange(0.0, 2.0, 0.1)
    on = np.interp(t, [0.0, 0.5, 2.0], [0.0, 5.0, 2.0])          # corner on a sample
    between = np.interp(t, [0.0, 0.55, 2.0], [0.0, 5.5, 2.0])    # corner between 0.5 and 0.6
    lo, hi, _, err = corners(t, on)
    assert len(lo) == 0
    lo, hi, _, err = corners(t, between)
    assert lo == pytest.approx([0.5]) and hi == pytest.approx([0.6])
    # slope 10 then -2.2857: linear interpolation cuts the corner by up to 12.29 * 0.1 / 4
    assert err[0] == pytest.approx((10 + 3.5 / 1.45) * 0.1 / 4, rel=1e-6)
    # a smooth move (acceleration over many samples) is not piecewise linear
    assert corners(t, t ** 2) is None
