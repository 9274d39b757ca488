"""Drift during the grooving (issue: thermal drift could not be told from the centre offsets): a
plan that repeats its first groove, the estimator fits a linear drift and reports it."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mtcomp.cli import main
from mtcomp.errors import ErrorSet, GeometricErrors, ToolSetting
from mtcomp.setting.tool import MicroscopeNoise, simulate_grooving
from mtcomp.setting.tool_design import design_plan
from mtcomp.setting.tool_estimate import DRIFT_NAMES, estimate
from mtcomp.setting.tool_plan import cutting_times, make_plan, repeated_grooves

M = "robonano-ui"
TRUTH = ErrorSet(tool=ToolSetting((0.34006, 0.24502, 0.2)),
                 geometric=GeometricErrors(location={"EX0C": 0.0393, "EY0C": -0.150}))
TV = np.array([0.34006, 0.24502, 0.2, 0.0393, -0.150, 0.0])


@pytest.fixture(scope="module")
def plans():
    base = design_plan(M).plan
    return base, make_plan(M, replace(base.options, repeat_first=True))


def test_the_repeat_is_the_first_groove_cut_last(plans):
    base, rep = plans
    assert repeated_grooves(base) == ()          # A0-1 and A0-2 share angles, not direction
    assert repeated_grooves(rep) == ("C0r",)
    g0, g1 = rep.groove("C0"), rep.groove("C0r")
    assert (g0.test, g0.face, g0.angles, g0.depth) == (g1.test, g1.face, g1.angles, g1.depth)
    assert cutting_times(rep)["C0"] == 0.0 and cutting_times(rep)["C0r"] == 1.0


@pytest.mark.parametrize("drift", [(0.002, 0, 0), (0, 0.002, 0), (0, 0, 0.002)])
def test_drift_of_2um_is_removed_when_the_plan_repeats(plans, drift):
    base, rep = plans
    # noise-free grooves, weighted with the real 1 µm noise: the bias in units of sigma
    def bias(plan, **kw):
        m = replace(simulate_grooving(M, TRUTH, MicroscopeNoise(0, 0), 0, plan=plan, drift=drift),
                    sigma_pos=0.001, sigma_depth=0.001)
        e = estimate(M, m, **kw)
        return (e._values - TV) / np.sqrt(np.diag(e._param_cov)), e
    z_rep, e = bias(rep)
    assert np.abs(z_rep).max() < 0.01
    np.testing.assert_allclose([e.nuisance[k] for k in DRIFT_NAMES], drift, atol=1e-9)
    assert "drift over the procedure" in e.summary()
    z_old, _ = bias(base)
    assert np.abs(z_old).max() > 0.2           # without the repeat the drift leaks into t


def test_estimates_within_2_sigma_with_noise(plans):
    _, rep = plans
    drift = np.array([0.0012, -0.0008, 0.0014]) / np.linalg.norm([0.0012, -0.0008, 0.0014]) * 0.002
    z = []
    for seed in range(30):
        e = estimate(M, simulate_grooving(M, TRUTH, MicroscopeNoise(0.001, 0.001), seed, plan=rep, drift=drift),
                     closed=False)
        z.append((e._values - TV) / np.sqrt(np.diag(e._param_cov)))
    z = np.array(z)
    assert np.all(np.abs(z.mean(axis=0)) < 2 / np.sqrt(len(z)) * 1.5)   # unbiased
    assert np.mean(np.abs(z) < 2) > 0.9


def test_cli_repeat_and_drift(tmp_path, capsys):
    assert main(["tool-setting", "plan", "-o", str(tmp_path), "--no-png", "--repeat-first"]) == 0
    assert main(["tool-setting", "simulate", "--plan", str(tmp_path / "plan.toml"), "--offset", "0.34006", "0.24502",
                 "0.2", "--drift", "0", "0.002", "0", "--seed", "4", "-o", str(tmp_path / "m.csv")]) == 0
    capsys.readouterr()
    assert main(["tool-setting", "estimate", str(tmp_path / "m.csv"), "--report", str(tmp_path / "r.txt")]) == 0
    assert "drift over the procedure" in capsys.readouterr().out
    # the repeat is no side of the C triangle: the predicted C distance is the closing gap's
    from mtcomp.setting.tool import load_plan, read_measurements
    from mtcomp.setting.tool_estimate import predicted_residuals
    plan = load_plan(tmp_path / "plan.toml")
    e = estimate(M, read_measurements(tmp_path / "m.csv", plan))
    base = design_plan(M).plan
    e0 = estimate(M, simulate_grooving(M, TRUTH, MicroscopeNoise(0.001, 0.001), 4, plan=base))
    assert predicted_residuals(M, plan, e)["C"] == pytest.approx(predicted_residuals(M, base, e0)["C"], rel=0.1)
    assert "C test" in (tmp_path / "r.txt").read_text()
