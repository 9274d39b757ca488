"""Probe calibration on a reference sphere (issue: the bowl height moved 1:1 with the probe's
radius): effective radius, lobing, `probe-calibrate`, `fit --probe`."""
from __future__ import annotations

import numpy as np
import pytest

from mtcomp._io import InputError, load_toml
from mtcomp.cli import main
from mtcomp.errors import WorkpieceSetting
from mtcomp.setting.bowl_design import design_bowl_plan
from mtcomp.setting.bowls import virtual_probe
from mtcomp.setting.probe_cal import (UNCALIBRATED_NOTE, apply_probe_model, calibrate_probe, fit_with_probe,
                                      load_calibration, save_calibration, sphere_directions, virtual_sphere_touches)

TRUTH = WorkpieceSetting((0.02, -0.01, 0.005), (0.05, -0.03, 0.1))
POSE = "0.02,-0.01,0.005,0.05,-0.03,0.1"


@pytest.fixture(scope="module")
def plan():
    return design_bowl_plan(3).plan


def test_effective_radius_is_the_same_on_sphere_and_bowl():
    # independent geometry: a probe of radius r + e on a sphere (outside) sits at Rs + r + e from
    # its centre; inside a bowl at R - r - e.  The correction p + e a restores both.
    a = np.array([[0.6, 0.0, -0.8]])
    e = 0.001
    p_sphere = -(12.5 + 0.5 + e) * a          # approach a points into the sphere
    p_bowl = (2.0 - 0.5 - e) * a              # approach a points away from the bowl centre
    for p, want in ((p_sphere, 13.0), (p_bowl, 1.5)):
        assert np.linalg.norm(p + e * a) == pytest.approx(want, abs=1e-12)


def test_calibration_recovers_radius_and_lobing_and_its_covariance():
    D = sphere_directions(49)
    vals = []
    for seed in range(40):
        P, A = virtual_sphere_touches(25.0, 0.501, D, centre=(3.0, -2.0, 40.0), noise=0.0002, rng=seed,
                                      lobe_amplitude=0.0008, lobe_phase=0.2)
        cal = calibrate_probe(P, A, 25.0, 0.5, sigma=0.0002)
        vals.append(cal.coefficients)
    vals = np.array(vals)
    names = cal.names
    truth = np.zeros(len(names))
    truth[0] = 0.001
    truth[names.index("c3")] = 0.0008 * np.cos(3 * 0.2)
    truth[names.index("s3")] = 0.0008 * np.sin(3 * 0.2)
    sd = np.sqrt(np.diag(cal.cov))
    assert np.all(np.abs(vals.mean(axis=0) - truth) < 4 * sd / np.sqrt(len(vals)))
    np.testing.assert_allclose(vals.std(axis=0, ddof=1), sd, rtol=0.35)
    assert cal.lobing_pv() == pytest.approx(0.0016, abs=0.0003)


def test_calibration_file_round_trip(tmp_path):
    P, A = virtual_sphere_touches(25.0, 0.501, sphere_directions(49), noise=0.0001, rng=1, lobe_amplitude=0.0005)
    cal = calibrate_probe(P, A, 25.0, 0.5, diameter_sigma=0.0001)
    back = load_calibration(save_calibration(cal, tmp_path / "probe.toml"))
    np.testing.assert_allclose(back.coefficients, cal.coefficients)
    a = sphere_directions(9)
    np.testing.assert_allclose(back.delta(a), cal.delta(a))
    # the certificate's diameter uncertainty is carried into the effective radius
    assert cal.effective_radius_sigma > 0.00005
    (tmp_path / "bad.toml").write_text('format = "something-else"\n')
    with pytest.raises(InputError, match="bad.toml"):
        load_calibration(tmp_path / "bad.toml")


def test_radius_error_acceptance_dz_within_0_1um(plan):
    # issue reproducer: a probe 1 µm larger than the plan's moves dz by 1.000 µm
    t = apply_probe_model(virtual_probe(TRUTH, plan, 0.0), radius_error=0.001)
    _, est0 = fit_with_probe(t, plan, None, fit_kw=dict(probe_sigma=0.0005))
    assert est0.params[2] - 0.005 == pytest.approx(0.001, abs=2e-6)
    assert UNCALIBRATED_NOTE in est0.warnings
    # after calibrating on a 25 mm sphere (49 touches, 0.1 µm noise): dz within 0.1 µm
    for seed in range(5):
        P, A = virtual_sphere_touches(25.0, 0.501, sphere_directions(49), noise=0.0001, rng=seed)
        cal = calibrate_probe(P, A, 25.0, 0.5, sigma=0.0001)
        _, est = fit_with_probe(t, plan, cal, fit_kw=dict(probe_sigma=0.0005))
        assert abs(est.params[2] - 0.005) < 0.0001, seed
        assert np.all(np.abs(est.params[:3] - TRUTH.translation) < 0.0001)
        assert UNCALIBRATED_NOTE not in est.warnings


def test_lobing_is_corrected(plan):
    # 3-lobe pre-travel of 1 µm amplitude: the correction brings every translation within 0.1 µm
    t = apply_probe_model(virtual_probe(TRUTH, plan, 0.0), radius_error=0.0005, lobe_amplitude=0.001, lobe_phase=0.4)
    P, A = virtual_sphere_touches(25.0, 0.5005, sphere_directions(49), noise=0.0001, rng=3,
                                  lobe_amplitude=0.001, lobe_phase=0.4)
    cal = calibrate_probe(P, A, 25.0, 0.5, sigma=0.0001)
    _, raw = fit_with_probe(t, plan, None, fit_kw=dict(probe_sigma=0.0005))
    _, est = fit_with_probe(t, plan, cal, fit_kw=dict(probe_sigma=0.0005))
    err_raw = np.abs(raw.params[:3] - TRUTH.translation)
    err = np.abs(est.params[:3] - TRUTH.translation)
    assert err_raw.max() > 0.0004 and err.max() < 0.0001


def test_calibration_uncertainty_reaches_dz(plan):
    t = virtual_probe(TRUTH, plan, 0.0)
    P, A = virtual_sphere_touches(25.0, 0.5, sphere_directions(49), noise=0.0005, rng=0)
    coarse = calibrate_probe(P, A, 25.0, 0.5, sigma=0.0005, diameter_sigma=0.0004)
    _, plain = fit_with_probe(t, plan, None, fit_kw=dict(probe_sigma=0.0005))
    _, est = fit_with_probe(t, plan, coarse, fit_kw=dict(probe_sigma=0.0005))
    # dz moves 1:1 with the effective radius: its variance grows by about sigma(d0)^2
    assert est.std[2] ** 2 - plain.std[2] ** 2 == pytest.approx(coarse.cov[0, 0], rel=0.15)


def test_cli_probe_calibrate_and_fit(tmp_path, capsys):
    d = tmp_path
    assert main(["workpiece-setting", "plan", "-o", str(d / "nominal.toml")]) == 0
    assert main(["workpiece-setting", "plan", "-o", str(d / "real.toml"), "--probe-radius", "0.501"]) == 0
    assert main(["workpiece-setting", "probe", str(d / "real.toml"), "--pose", POSE, "-o", str(d / "t.csv")]) == 0
    capsys.readouterr()
    assert main(["workpiece-setting", "fit", str(d / "nominal.toml"), str(d / "t.csv"), "--probe-sigma", "0.0005",
                 "-o", str(d / "e0.toml")]) == 0
    assert "carries the probe's effective radius error" in capsys.readouterr().err
    e0 = load_toml(d / "e0.toml")["workpiece_setting"]["translation"]
    assert e0[2] - 0.005 == pytest.approx(0.001, abs=2e-6)
    assert main(["workpiece-setting", "probe-sphere", "--probe-radius", "0.501", "--noise", "0.0001", "--seed", "2",
                 "-o", str(d / "sphere.csv")]) == 0
    assert main(["workpiece-setting", "probe-calibrate", str(d / "sphere.csv"), "--sphere-diameter", "25",
                 "--probe-radius", "0.5", "-o", str(d / "probe.toml"), "--png", str(d / "cal.png")]) == 0
    out = capsys.readouterr().out
    assert "effective radius 0.5010" in out and (d / "cal.png").read_bytes()[:4] == b"\x89PNG"
    assert main(["workpiece-setting", "fit", str(d / "nominal.toml"), str(d / "t.csv"), "--probe-sigma", "0.0005",
                 "--probe", str(d / "probe.toml"), "-o", str(d / "e1.toml")]) == 0
    assert "carries the probe" not in capsys.readouterr().err
    e1 = load_toml(d / "e1.toml")["workpiece_setting"]["translation"]
    assert abs(e1[2] - 0.005) < 0.0001
    # a file that is not a calibration: named, non-zero, nothing written
    assert main(["workpiece-setting", "fit", str(d / "nominal.toml"), str(d / "t.csv"), "--probe",
                 str(d / "e1.toml"), "-o", str(d / "e2.toml")]) != 0
    assert "e1.toml" in capsys.readouterr().err and not (d / "e2.toml").exists()
