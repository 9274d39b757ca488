"""Uncertainties of the diagnosis: amplitudes and nonlinear parameters are inverted together,
and candidates that the sampling cannot identify are not offered (they used to crash the fit)."""
import numpy as np

from mtcomp.diagnose import diagnose
from mtcomp.diagnose import align as _align
from mtcomp.diagnose import data as _data
from mtcomp.diagnose.effects import Context, candidates
from mtcomp.diagnose.select import fit, joint_covariance


def _spindle_case(seed, dt=4.0, k=3e-7, tau=1500.0):
    rng = np.random.default_rng(seed)
    t = np.arange(0, 3600, dt)
    S = np.where(t < 600, 0.0, 10000.0)              # spindle started after 10 min, 1/min
    y = np.zeros_like(t)
    a = np.exp(-dt / tau)
    for i in range(1, len(t)):
        y[i] = a * y[i - 1] + (1 - a) * S[i]
    z = 10 * np.sin(2 * np.pi * t / 300)
    return {"t": t, "z[mm]": z}, {"t": t, "z[mm]": z + k * y + rng.normal(0, 3e-4, len(t)), "S[rpm]": S}


def test_a_recording_sampled_every_4_s_is_diagnosed():
    # the servo lag's kv range was empty at this sampling ([0.5, 0.5] 1/s) and least_squares
    # raised "Each lower bound must be strictly less than each upper bound"
    res = diagnose(*_spindle_case(0))
    assert res.names == ["thermal_drift"], res.summary()
    e = res.effects[0]
    assert abs(e.params["gain_mm_per_rpm"] - 3e-7) < 3 * e.uncertainty["gain_mm_per_rpm"]


def test_joint_covariance_is_the_schur_complement_bound():
    """With the time constant free, each amplitude's variance is at least its variance with the
    time constant held (the inverse Gram matrix): equal only if uncorrelated with it."""
    sim, rec = _spindle_case(1)
    al = _align.align(_data.load(sim, "SIM"), _data.load(rec, "REC"))
    ctx = Context(al)
    th = [c for c in candidates(al) if c.name == "thermal_drift"][0]
    f = fit(ctx, [th], [np.array([np.log(1200.0)])])
    ce, cb = joint_covariance(ctx, f)
    assert ce.shape == (1, 1) and cb.shape == (3, 3)
    assert np.all(np.diag(cb) >= np.diag(f.gram_inv) * (1 - 1e-9))
    # without nonlinear parameters it is the Gram inverse itself
    from mtcomp.diagnose.effects import ScaleError
    sc = [c for c in candidates(al) if isinstance(c, ScaleError)][0]
    f2 = fit(ctx, [sc], [np.zeros(0)])
    ce2, cb2 = joint_covariance(ctx, f2)
    assert ce2.shape == (0, 0)
    np.testing.assert_allclose(cb2, f2.gram_inv, rtol=1e-9)


def test_reported_gain_uncertainty_matches_the_scatter_over_seeds():
    g, s = [], []
    for seed in range(10):
        res = diagnose(*_spindle_case(seed))
        e = [e for e in res.effects if e.name == "thermal_drift"][0]
        g.append(e.params["gain_mm_per_rpm"])
        s.append(e.uncertainty["gain_mm_per_rpm"])
    ratio = np.std(g, ddof=1) / np.mean(s)
    assert 0.5 < ratio < 1.6, ratio
