"""A noise floor that is tested: structure that alternates from sample to sample is not taken
as noise; the residual is checked for whiteness and for patterns locked to the position."""
import numpy as np
import pytest

from mtcomp.diagnose import diagnose
from mtcomp.diagnose.align import noise_sigma
from mtcomp.diagnose.noise import locked_share, check_residual


def _encoder(seed=0, n=200):
    # one revolution in 200 full steps: harmonics of the revolution and a pattern of period two
    # samples (a full-step error), 0.54 deg peak to peak, on 5 mdeg of noise
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.5
    a = np.arange(n) * 360.0 / n
    th = np.radians(a)
    err = (0.15 * np.sin(th + 0.3) + 0.08 * np.sin(2 * th + 1.0) + 0.04 * np.sin(4 * th)
           + 0.05 * (-1.0) ** np.arange(n))
    return {"t": t, "b[deg]": a}, {"t": t, "b[deg]": a + err + rng.normal(0, 0.005, n)}


def test_alternating_structure_is_not_noise():
    # before: the floor from second differences was 0.08 deg, most of the residual "noise"
    sim, rec = _encoder()
    res = diagnose(sim, rec)
    assert res.noise_floor["b"] == pytest.approx(0.005, rel=0.3)
    said = [n for n in res.notes if n.startswith("b: what is left is not white noise")]
    assert said or res.fit["holdout_rms_after"]["b"] < 3 * res.noise_floor["b"], res.summary()


def test_floor_of_white_noise_unchanged():
    r = np.random.default_rng(1).normal(0, 2.0, 4000)
    assert noise_sigma(r) == pytest.approx(2.0, rel=0.05)
    # an alternating pattern of 10x the noise does not raise the floor
    alt = r + 20.0 * (-1.0) ** np.arange(len(r))
    assert noise_sigma(alt) == pytest.approx(2.0, rel=0.1)


def test_whiteness_and_position_lock():
    rng = np.random.default_rng(2)
    white = rng.normal(0, 1, 3000)
    w = check_residual(white, "angle", np.linspace(0, 720, 3000))
    assert w["white"] and abs(w["lag1"]) < 0.1 and w["per_revolution"] < 0.05
    pos = np.linspace(0, 1080, 3000)
    locked = white + 3.0 * np.sin(np.radians(pos) * 5)
    w = check_residual(locked, "angle", pos)
    assert not w["white"] and w["per_revolution"] > 0.7
    assert locked_share(white, rng.uniform(0, 1, 3000)) < 0.05
