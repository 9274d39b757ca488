"""Workpiece setting (paper 001): paper formula, frames, covariance, injected-and-recovered poses."""
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from mtcomp import InputError
from mtcomp.errors import ErrorSet, WorkpieceSetting
from mtcomp.kinematics import forward
from mtcomp.machine import load_machine
from mtcomp.setting.bowls import fit_bowls, plan_bowls, virtual_probe
from mtcomp.setting.frame import (apply_pose, frame_from_bowls, frame_from_points, paper_frame,
                                  paper_rotation, paper_transform, pose_from_paper, rigid_fit)


def random_pose(rng, lin=1.0, ang=2.0):
    return WorkpieceSetting(tuple(rng.uniform(-lin, lin, 3)), tuple(rng.uniform(-ang, ang, 3)))


def pose_vec(p):
    return np.r_[p.translation, p.angles]


def test_paper_formula_is_the_pose_and_the_forward_model_agrees():
    rng = np.random.default_rng(7)
    m = load_machine("robonano-a0ib")
    for _ in range(20):
        E = Rotation.random(random_state=rng).as_matrix()
        X, d = rng.uniform(-10, 10, 3), rng.uniform(-1, 1, 3)
        x = rng.uniform(-10, 10, (50, 3))
        pose = pose_from_paper(E, X, d)
        # x' = E (x - X) + X + d  ==  R x + t with R = E, t = X + d - E X
        np.testing.assert_allclose(paper_transform(x, E, X, d), apply_pose(pose, x), atol=1e-12)
        np.testing.assert_allclose(pose.matrix, E, atol=1e-12)
        np.testing.assert_allclose(pose.translation, X + d - E @ X, atol=1e-12)
        # S1 = X goes to X + d
        np.testing.assert_allclose(paper_transform(X, E, X, d), X + d, atol=1e-12)
        # the moved program, run on the machine whose blank sits at that pose, cuts x on the blank
        q = np.zeros((len(x), 5))
        q[:, 2:] = paper_transform(x, E, X, d)
        p_real = forward(m, q, ErrorSet(workpiece=pose)).p
        np.testing.assert_allclose(p_real, x, atol=1e-9)


def test_paper_frame_orthonormal_and_axes_of_an_aligned_design():
    rng = np.random.default_rng(1)
    for _ in range(10):
        s = rng.normal(size=(3, 3)) * 10
        F = paper_frame(*s)
        np.testing.assert_allclose(F.T @ F, np.eye(3), atol=1e-12)
        assert np.linalg.det(F) == pytest.approx(1.0)
        u = (s[1] - s[0]) / np.linalg.norm(s[1] - s[0])
        np.testing.assert_allclose(F[:, 0], u, atol=1e-12)
        assert abs(F[:, 2] @ (s[2] - s[0])) < 1e-10          # ez normal to the plane
        assert F[:, 1] @ (s[2] - s[0]) > 0                    # ey on S3's side
    # design bowls on the workpiece axes: F_design = I, so R is the measured frame [ex ey ez]
    design = np.array([[0, 0, 1.0], [14, 0, 1.0], [0, 14, 1.0]])
    R = Rotation.from_euler("ZYX", [0.3, -0.2, 0.1], degrees=True).as_matrix()
    meas = design @ R.T + [0.1, 0.2, 0.3]
    np.testing.assert_allclose(paper_frame(*design), np.eye(3), atol=1e-15)
    np.testing.assert_allclose(paper_rotation(meas, design), paper_frame(*meas), atol=1e-15)
    np.testing.assert_allclose(paper_rotation(meas, design), R, atol=1e-12)


def test_rigid_fit_matches_the_batched_kabsch():
    from mtcomp.setting.frame import _estimate_batch
    rng = np.random.default_rng(3)
    d = rng.uniform(-7, 7, (6, 3))
    m = d @ Rotation.random(random_state=rng).as_matrix().T + rng.normal(size=3) \
        + rng.normal(0, 1e-3, (6, 3))
    R, t = rigid_fit(m, d)
    Rb, tb = _estimate_batch(m[None], d, "lsq")
    np.testing.assert_allclose(Rb[0], R, atol=1e-12)
    np.testing.assert_allclose(tb[0], t, atol=1e-12)


@pytest.mark.parametrize("n,method", [(3, "paper"), (3, "lsq"), (5, "lsq")])
def test_zero_noise_recovery_within_a_nanometre(n, method):
    rng = np.random.default_rng(100 + n)
    plan = plan_bowls(n)
    for _ in range(50):
        true = random_pose(rng)
        t = virtual_probe(true, plan, 0.0, rng, aim=true)
        est = frame_from_bowls(fit_bowls(t, plan.probe_radius), plan, method=method)
        e = pose_vec(est.pose) - pose_vec(true)
        assert np.abs(e[:3]).max() < 1e-6                    # 1 nm
        assert np.abs(np.radians(e[3:])).max() < 1e-7        # 1e-7 rad
        assert not est.warnings


def _coverage(n, method, trials, seed, sigma=0.0005):
    rng = np.random.default_rng(seed)
    plan = plan_bowls(n)
    lim = chi2.ppf(0.9973, 6)                                 # the 3-sigma probability in 6-D
    inside, per = 0, np.zeros(6)
    for _ in range(trials):
        true = random_pose(rng)
        t = virtual_probe(true, plan, sigma, rng, aim=true)
        est = frame_from_bowls(fit_bowls(t, plan.probe_radius, probe_sigma=sigma), plan,
                               method=method)
        e = pose_vec(est.pose) - pose_vec(true)
        inside += e @ np.linalg.solve(est.cov, e) <= lim
        per += np.abs(e) <= 3 * est.std
    return inside / trials, per / trials


@pytest.mark.slow
def test_acceptance_recovered_pose_within_3_sigma_in_99_percent_of_1000_trials():
    joint, per = _coverage(3, "paper", 1000, seed=2024)
    assert joint >= 0.99
    assert per.min() >= 0.99


def test_coverage_with_more_bowls_and_least_squares():
    joint, per = _coverage(4, "lsq", 300, seed=99)
    assert joint >= 0.99
    assert per.min() >= 0.98


@pytest.mark.slow
def test_propagated_covariance_matches_monte_carlo():
    rng = np.random.default_rng(5)
    plan = plan_bowls(3)
    true = WorkpieceSetting((0.2, -0.1, 0.05), (0.5, -0.3, 1.0))
    sigma = 0.0005
    est_all, covs = [], []
    for _ in range(1000):
        t = virtual_probe(true, plan, sigma, rng, aim=true)
        est = frame_from_bowls(fit_bowls(t, plan.probe_radius, probe_sigma=sigma), plan)
        est_all.append(pose_vec(est.pose))
        covs.append(est.cov)
    sample = np.cov(np.array(est_all).T)
    pred = np.mean(covs, axis=0)
    ratio = np.sqrt(np.diag(sample) / np.diag(pred))
    assert np.all(np.abs(ratio - 1) < 0.08), ratio            # sd of a sd estimate: 2.2 %
    # correlations too (the tilts a, b and dz are coupled through the bowl z centres)
    corr = lambda C: C / np.sqrt(np.outer(np.diag(C), np.diag(C)))  # noqa: E731
    assert np.abs(corr(sample) - corr(pred)).max() < 0.1
    # and the mean is the truth (no bias at this noise level)
    se = np.sqrt(np.diag(sample) / 1000)
    assert np.all(np.abs(np.mean(est_all, axis=0) - pose_vec(true)) < 4 * se)


def test_collinear_and_coincident_bowls_are_named():
    d = np.array([[0, 0, 1.0], [10, 0, 1.0], [5, 0.01, 1.0]])
    with pytest.raises(InputError, match=r"bowls 1, 2, 3 are \(nearly\) collinear"):
        frame_from_points(d, d)
    good = np.array([[0, 0, 1.0], [10, 0, 1.0], [0, 10, 1.0]])
    meas = good.copy()
    meas[2] = meas[1] + 1e-3
    with pytest.raises(InputError, match="measured bowls 2 and 3 coincide"):
        frame_from_points(meas, good, ids=(1, 2, 3))
    with pytest.raises(InputError, match="collinear"):
        plan_bowls(positions=[(-7, 5), (0, 5.05), (7, 5.1)], keepout_radius=0.5)
    with pytest.raises(InputError, match="at least 3"):
        frame_from_points(good[:2], good[:2])


def test_disagreeing_bowl_warns_and_gross_one_is_an_error():
    rng = np.random.default_rng(11)
    plan = plan_bowls(4)
    true = WorkpieceSetting((0.01, 0.02, -0.01), (0.02, -0.01, 0.2))
    sigma = 0.0005
    fit = fit_bowls(virtual_probe(true, plan, sigma, rng), plan.probe_radius, probe_sigma=sigma)
    est = frame_from_bowls(fit, plan)
    assert not est.warnings
    meas = est.measured.copy()
    meas[2] += [0.008, 0.0, 0.0]                              # bowl 3 milled 8 um off
    est = frame_from_points(meas, plan.centres, fit.centre_covs, plan.ids)
    assert len(est.warnings) == 1 and est.warnings[0].startswith("bowl 3 disagrees")
    meas[2] += [0.3, 0.0, 0.0]
    with pytest.raises(InputError, match="bowl 3 is .* away"):
        frame_from_points(meas, plan.centres, fit.centre_covs, plan.ids)


def test_bowl_bottom_moves_with_tilt_by_r_alpha_but_the_centre_does_not():
    # docs: the lowest point of a bowl of radius R is a different material point after a tilt
    # alpha; it moves by 2 R sin(alpha/2) ~ R alpha: 8.73 um for R = 5 mm, alpha = 0.1 deg
    R, alpha = 5.0, 0.1
    pose = WorkpieceSetting((0.0, 0.0, 0.0), (alpha, 0.0, 0.0))
    c = np.array([3.0, -2.0, R - 1.0])
    c_machine = apply_pose(pose, c)
    low_machine = c_machine - [0, 0, R]
    low_material = pose.matrix.T @ (low_machine - np.asarray(pose.translation))
    shift = np.linalg.norm(low_material - (c - [0, 0, R]))
    assert shift * 1e3 == pytest.approx(2 * R * math.sin(math.radians(alpha) / 2) * 1e3, rel=1e-9)
    assert shift * 1e3 == pytest.approx(8.727, abs=1e-3)


def test_three_bowls_that_do_not_form_the_planned_triangle_warn():
    rng = np.random.default_rng(12)
    plan = plan_bowls(3)
    sigma = 0.0005
    true = WorkpieceSetting((0.01, 0.02, -0.01), (0.02, -0.01, 0.2))
    n_warn = 0
    for _ in range(200):
        fit = fit_bowls(virtual_probe(true, plan, sigma, rng), plan.probe_radius, probe_sigma=sigma)
        n_warn += bool(frame_from_bowls(fit, plan).warnings)
    assert n_warn <= 3                                         # false alarm rate 0.1 %
    meas = fit.centres.copy()
    meas[1] += [0.010, 0.0, 0.0]                              # S1S2 10 um longer than planned
    est = frame_from_points(meas, plan.centres, fit.centre_covs, plan.ids)
    assert len(est.warnings) == 1 and "do not form the planned triangle" in est.warnings[0]
