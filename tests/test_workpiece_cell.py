"""Virtual cell of paper 001: analytic pyramid, Monte Carlo with and without compensation."""
import math

import numpy as np
import pytest

from mtcomp.errors import ErrorSet, WorkpieceSetting
from mtcomp.kinematics import forward
from mtcomp.machine import load_machine
from mtcomp.setting.cellsim import (CellConfig, Pyramid, RobotPlacement, finishing_commands,
                                    measure_pyramid, simulate_cell)

M = load_machine("robonano-a0ib")


def test_nominal_pyramid_has_the_paper_target_size():
    pyr = Pyramid()
    assert pyr.height == pytest.approx(1.725 * math.tan(math.radians(7.595)), rel=1e-12)
    q, face = finishing_commands(M, pyr)
    r = measure_pyramid(forward(M, q).p, face)
    for k in range(1, 5):
        assert r[f"W{k}"] == pytest.approx(3450.0, abs=1e-9)
    assert r["S1&S2"] == pytest.approx(164.81, abs=1e-12)
    assert r["S3&S4"] == pytest.approx(164.81, abs=1e-12)


def test_uncompensated_height_error_narrows_the_pyramid_by_2dz_over_tan_beta():
    pyr = Pyramid()
    q, face = finishing_commands(M, pyr)
    dz = 0.010
    r = measure_pyramid(forward(M, q, ErrorSet(workpiece=WorkpieceSetting((0, 0, dz)))).p, face)
    expect = 3450.0 - 2 * dz * 1e3 / math.tan(pyr.beta)
    for k in range(1, 5):
        assert r[f"W{k}"] == pytest.approx(expect, abs=1e-9)
    # a rigid displacement never changes the angle between two cut faces
    r = measure_pyramid(forward(M, q, ErrorSet(workpiece=WorkpieceSetting((0.01, 0.02, 0.03),
                                                                            (0.1, -0.2, 0.3)))).p, face)
    assert r["S1&S2"] == pytest.approx(164.81, abs=1e-9)
    # a shift in x moves the pyramid on the blank by -dx
    r = measure_pyramid(forward(M, q, ErrorSet(workpiece=WorkpieceSetting((0.004, 0, 0)))).p, face)
    assert r["centre_x"] == pytest.approx(-4.0, abs=1e-9)


def test_robot_repeatability_maps_to_iso9283_rp():
    rng = np.random.default_rng(0)
    robot = RobotPlacement(repeatability=0.030, rotation_sigma=0.0)
    t = np.array([robot.sample(rng).translation for _ in range(20000)])
    dist = np.linalg.norm(t - t.mean(axis=0), axis=1)
    assert dist.mean() + 3 * dist.std() == pytest.approx(0.030, rel=0.02)


@pytest.mark.parametrize("kw,field", [({"repeatability": -0.03}, "repeatability"),
                                      ({"rotation_sigma": -1.0}, "rotation_sigma")])
def test_negative_robot_scatter_is_refused(kw, field):
    from mtcomp import InputError
    with pytest.raises(InputError, match=rf"\[{field}\]: .* must be >= 0"):
        RobotPlacement(**kw)


def test_noise_free_cell_gives_the_exact_pyramid_and_compensation_matters():
    cfg = CellConfig(trials=20, probe_sigma=0.0, seed=3,
                     robot=RobotPlacement(offset=(0.05, -0.03, 0.02), rotation=(0.05, -0.05, 0.3)))
    res = simulate_cell(cfg)
    for k in range(1, 5):
        np.testing.assert_allclose(res.compensated[f"W{k}"], 3450.0, atol=1e-5)   # 0.01 nm
        assert np.abs(res.uncompensated[f"W{k}"] - 3450).mean() > 100              # ~15 x dz
    assert np.abs(res.pose_error).max() < 1e-9


def test_cell_monte_carlo_figures_and_outputs(tmp_path):
    res = simulate_cell(CellConfig(trials=40, seed=2))
    rows = {r[0]: r for r in res.table_rows()}
    for k in range(1, 5):
        _, target, paper, mean, sd, *_ , umean, usd = rows[f"W{k}"]
        assert abs(mean - 3450) < 4 * sd / math.sqrt(40)
        assert sd < usd / 3                                    # compensation shrinks the scatter
    # width scatter follows the height uncertainty: sd(W) = 2 sd(dz) / tan(beta) to first order
    # (the tilts add up to about a tenth now that the height comes from the bowls' bottom points
    # and its own error is small)
    sd_dz = res.pose_error[:, 2].std(ddof=1) * 1e3
    for k in range(1, 5):
        assert rows[f"W{k}"][4] == pytest.approx(2 * sd_dz / math.tan(Pyramid().beta), rel=0.12)
    text = res.table()
    assert "| W1 um | 3450 | 3449.5 |" in text and "| S3&S4 deg | 164.81 | 164.9 |" in text
    res.plot(tmp_path / "cell.png")
    assert (tmp_path / "cell.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
