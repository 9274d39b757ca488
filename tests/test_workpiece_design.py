"""Bowl plans designed for the estimate (paper 001): positions and touch rings chosen by a D/A
criterion over the workpiece setting's covariance; predicted 1-sigma; --target-sigma."""
from __future__ import annotations

import numpy as np
import pytest

from mtcomp._io import InputError
from mtcomp.cli import main
from mtcomp.errors import WorkpieceSetting
from mtcomp.setting.bowl_design import _as_mm, _score, design_bowl_plan, lever_arm, predicted_pose_covariance
from mtcomp.setting.bowls import fit_bowls, plan_bowls, virtual_probe
from mtcomp.setting.frame import frame_from_bowls


@pytest.fixture(scope="module")
def designed():
    return design_bowl_plan(3)


def test_single_sphere_centre_covariance_is_the_textbook_one():
    # independent model: a sphere of known radius probed along unit directions d_i with noise sigma
    # along d_i has cov(centre) = sigma^2 (sum d_i d_i^T)^-1
    plan = plan_bowls(3)
    t = virtual_probe(None, plan, 0.0)
    fit = fit_bowls(t, plan.probe_radius, probe_sigma=0.0005, bowl_radius=plan.tool_radius, bowls=plan.ids)
    D = plan.dirs
    np.testing.assert_allclose(fit.fits[0].centre_cov, 0.0005 ** 2 * np.linalg.inv(D.T @ D), rtol=1e-6, atol=1e-15)


def test_designed_plan_beats_the_old_default_and_fits_the_blank(designed):
    old = plan_bowls(3)
    c_old = predicted_pose_covariance(old, 0.0005)
    lev = lever_arm(old)
    assert _score(_as_mm(designed.cov, lev), "D") < _score(_as_mm(c_old, lev), "D")
    # the tilt (a, b) uncertainty drops: bowls farther apart
    assert np.all(designed.sigma[3:5] < 0.95 * np.sqrt(np.diag(c_old))[3:5])
    p = designed.plan
    rim = p.opening_radius
    for b in p.bowls:
        assert abs(b.x) + rim + 0.5 <= p.blank[0] / 2 + 1e-9 and abs(b.y) + rim + 0.5 <= p.blank[1] / 2 + 1e-9
        assert np.hypot(b.x, b.y) - rim - 0.5 >= p.keepout_radius


def test_predicted_covariance_matches_monte_carlo(designed):
    plan = designed.plan
    truth = WorkpieceSetting((0.02, -0.01, 0.005), (0.05, -0.03, 0.1))
    vals = []
    for seed in range(40):
        t = virtual_probe(truth, plan, 0.0005, np.random.default_rng(seed))
        fit = fit_bowls(t, plan.probe_radius, probe_sigma=0.0005, bowls=plan.ids)
        vals.append(frame_from_bowls(fit, plan).params)
    sd = np.std(vals, axis=0, ddof=1)
    np.testing.assert_allclose(sd, designed.sigma, rtol=0.35)


def test_target_sigma_adds_touches_or_refuses():
    d = design_bowl_plan(3, target_sigma=0.0003)
    assert d.touches > 9 and np.all(d.sigma_mm <= 0.0003)
    with pytest.raises(InputError, match="not reachable"):
        design_bowl_plan(3, target_sigma=0.00005)


def test_cli_prints_the_predicted_sigma(tmp_path, capsys):
    assert main(["workpiece-setting", "plan", "-o", str(tmp_path / "plan.toml")]) == 0
    out = capsys.readouterr().out
    assert "Predicted 1-sigma of every estimated error" in out and "arcsec" in out and "D-optimal" in out
    assert main(["workpiece-setting", "plan", "-o", str(tmp_path / "x.toml"), "--target-sigma", "0.00001"]) != 0
    assert "not reachable" in capsys.readouterr().err and not (tmp_path / "x.toml").exists()
