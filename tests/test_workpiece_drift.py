"""Drift during the bowl probing (issue: it could not be told from dz): the first bowl touched
again at the end, the drift fitted, removed and reported."""
from __future__ import annotations

import numpy as np
import pytest

from mtcomp.cli import main
from mtcomp.errors import WorkpieceSetting
from mtcomp.setting.bowl_design import design_bowl_plan
from mtcomp.setting.bowl_drift import apply_drift, fit_with_drift, probe_with_repeat, touch_times, visits
from mtcomp.setting.bowls import fit_bowls, virtual_probe
from mtcomp.setting.frame import frame_from_bowls

TRUTH = WorkpieceSetting((0.02, -0.01, 0.005), (0.05, -0.03, 0.1))
TV = np.r_[TRUTH.translation, TRUTH.angles]
DRIFT = np.array([0.0012, -0.0008, 0.0014]) / np.linalg.norm([0.0012, -0.0008, 0.0014]) * 0.002


@pytest.fixture(scope="module")
def plan():
    return design_bowl_plan(3).plan


def test_repeat_is_a_second_visit(plan):
    t = probe_with_repeat(TRUTH, plan, 0.0, 0)
    v = visits(t)
    assert len(v[1]) == 2 and len(v[2]) == 1 and v[1][1][-1] == len(t.bowl) - 1
    np.testing.assert_allclose(touch_times(5), [0, 0.25, 0.5, 0.75, 1])


def test_noise_free_drift_is_recovered_exactly(plan):
    t = probe_with_repeat(TRUTH, plan, 0.0, 0, DRIFT)
    _, est, dr = fit_with_drift(t, plan, 0.0005)
    np.testing.assert_allclose(dr.value, DRIFT, atol=1e-9)
    np.testing.assert_allclose(est.params, TV, atol=1e-8)


def test_drift_2um_unbiased_within_2_sigma(plan):
    z_old, z = [], []
    for seed in range(20):
        t_old = apply_drift(virtual_probe(TRUTH, plan, 0.0005, np.random.default_rng(seed)), DRIFT)
        e_old = frame_from_bowls(fit_bowls(t_old, plan.probe_radius, probe_sigma=0.0005), plan)
        _, est, _ = fit_with_drift(probe_with_repeat(TRUTH, plan, 0.0005, seed, DRIFT), plan, 0.0005)
        z_old.append((e_old.params - TV) / e_old.std)
        z.append((est.params - TV) / est.std)
    z_old, z = np.array(z_old), np.array(z)
    assert np.abs(z_old.mean(axis=0)).max() > 3          # dz 4.8 sigma off without the repeat
    assert np.abs(z.mean(axis=0)).max() < 0.5           # unbiased with it
    assert np.mean(np.abs(z) < 2) > 0.9 and z.std(axis=0).max() < 1.5


def test_cli(tmp_path, capsys):
    assert main(["workpiece-setting", "plan", "-o", str(tmp_path / "plan.toml")]) == 0
    assert main(["workpiece-setting", "probe", str(tmp_path / "plan.toml"), "--pose", "0.02,-0.01,0.005,0.05,-0.03,0.1",
                 "--noise", "0.0005", "--repeat-first", "--drift", "0,0,0.002", "-o", str(tmp_path / "t.csv")]) == 0
    capsys.readouterr()
    assert main(["workpiece-setting", "fit", str(tmp_path / "plan.toml"), str(tmp_path / "t.csv"), "--probe-sigma",
                 "0.0005", "-o", str(tmp_path / "e.toml")]) == 0
    out = capsys.readouterr().out
    assert "drift over the probing (from bowl 1 visited twice)" in out


def test_probing_program_repeats_the_first_bowl(tmp_path):
    assert main(["workpiece-setting", "plan", "-o", str(tmp_path / "p.toml"), "--repeat-first"]) == 0
    nc = (tmp_path / "p-probing.nc").read_text()
    assert nc.count("G31") == 4 * 9 and nc.count("(BOWL 1") == 2 and "(BOWL 1 AGAIN: DRIFT CHECK)" in nc
    # the repeated visit comes last, after bowls 2 and 3
    assert nc.index("(BOWL 3)") < nc.index("(BOWL 1 AGAIN")


def test_virtual_cell_with_drift():
    from mtcomp.setting.cellsim import CellConfig, simulate_cell
    kw = dict(trials=12, seed=3, probe_drift=(0.0, 0.0, 0.002))
    drifted = simulate_cell(CellConfig(**kw))
    repeated = simulate_cell(CellConfig(repeat_first=True, **kw))
    # a z drift of 2 µm over the probing reads as height and tilt; the widths move by -15 dz
    assert abs(np.mean(drifted.pose_error[:, 2])) > 0.0005
    assert abs(np.mean(repeated.pose_error[:, 2])) < 0.0003
