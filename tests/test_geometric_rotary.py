"""ISO 230-7 location errors of rotary tables from a sphere probed at several angles."""
import numpy as np
import pytest

from mtcomp import InputError
from mtcomp.errors import ErrorSet, GeometricErrors
from mtcomp.geometric.rotary import (default_parameters, estimate_rotary, plan_sphere, simulate_readings)
from mtcomp.machine import load_machine

M = load_machine("robonano-a0ib")


def _truth(axis, rng):
    names = default_parameters(M, axis)
    vals = np.r_[rng.uniform(-0.01, 0.01, 2), rng.uniform(-100e-6, 100e-6, 2)]
    return names, vals, ErrorSet(geometric=GeometricErrors(location=dict(zip(names, vals))))


@pytest.mark.parametrize("axis,names", [("C", ("EX0C", "EY0C", "EA0C", "EB0C")),
                                        ("B", ("EX0B", "EZ0B", "EA0B", "EC0B"))])
def test_noise_free_location_errors_are_recovered_exactly(axis, names):
    assert default_parameters(M, axis) == names
    plan = plan_sphere(M, axis)
    _, vals, truth = _truth(axis, np.random.default_rng(7))
    sphere = np.array(plan.sphere) + [0.03, -0.02, 0.01]           # placed off its nominal spot
    est = estimate_rotary(M, plan, simulate_readings(M, plan, truth, 0.0, sphere=sphere), sigma=0.0005)
    np.testing.assert_allclose(est.values, vals, atol=1e-9)
    np.testing.assert_allclose(est.sphere, sphere, atol=1e-8)
    assert est.chi2 < 1e-6
    assert "µrad" in est.summary() and axis in est.summary()


def test_injected_location_errors_within_3_sigma_in_95_percent():
    rng = np.random.default_rng(2307)
    inside, d2 = [], []
    for k in range(40):
        axis = "C" if k % 2 else "B"
        plan = plan_sphere(M, axis)
        _, vals, truth = _truth(axis, rng)
        est = estimate_rotary(M, plan, simulate_readings(M, plan, truth, 0.0005, seed=k), sigma=0.0005)
        z = (est.values - vals) / est.sigma
        inside.append(np.all(np.abs(z) <= 3))
        dv = est.values - vals
        d2.append(dv @ np.linalg.solve(est.cov, dv))
    assert np.mean(inside) >= 0.95
    assert np.mean(d2) == pytest.approx(4.0, rel=0.35)


def test_compensating_the_estimate_puts_the_sphere_back_on_its_circle():
    """With the estimated C axis errors in the model, readings are predicted to the noise."""
    from mtcomp.geometric.rotary import centre_readings
    plan = plan_sphere(M, "C")
    _, vals, truth = _truth("C", np.random.default_rng(3))
    r = simulate_readings(M, plan, truth, 0.0002, seed=5)
    est = estimate_rotary(M, plan, r, sigma=0.0002)
    pred = centre_readings(M, plan, est.errors(), est.sphere)
    nominal = centre_readings(M, plan, None, est.sphere)
    assert np.max(np.abs(pred - r)) < 5 * 0.0002
    assert np.max(np.abs(nominal - r)) > 0.002                    # without them: µm off


def test_bad_rotary_inputs():
    with pytest.raises(InputError, match="carries the tool"):
        plan_sphere("robonano-ui", "C")
    with pytest.raises(InputError, match="not a rotary"):
        plan_sphere(M, "X")
    plan = plan_sphere(M, "C", n=3)
    with pytest.raises(InputError, match="readings"):
        estimate_rotary(M, plan, np.zeros((2, 3)))
    with pytest.raises(InputError, match="location errors of axis C"):
        estimate_rotary(M, plan, np.zeros((3, 3)), names=("EX0B",))


def test_rotary_cli_round_trip(tmp_path, capsys):
    from mtcomp.cli import main
    from mtcomp.errors import load_errors
    plan = plan_sphere(M, "C")
    _, vals, truth = _truth("C", np.random.default_rng(11))
    r = simulate_readings(M, plan, truth, 0.0, sphere=np.array(plan.sphere) + [0.1, 0.05, -0.02])
    p = tmp_path / "c.csv"
    p.write_text("# sphere centres\nangle_deg,x,y,z\n" + "".join(
        f"{a!r},{float(x)!r},{float(y)!r},{float(z)!r}\n" for a, (x, y, z) in zip(plan.angles, r)))
    assert main(["geometric", "rotary", str(p), "--axis", "C", "-o", str(tmp_path / "e.toml")]) == 0
    assert "EX0C" in capsys.readouterr().out
    loc = load_errors(tmp_path / "e.toml").geometric.location
    np.testing.assert_allclose([loc[n] for n in ("EX0C", "EY0C", "EA0C", "EB0C")], vals, atol=1e-8)
    p.write_text("angle_deg,x,y,z\n0,1,2,3\n0,1,2,3\n90,1,2,nan\n")
    assert main(["geometric", "rotary", str(p), "--axis", "C"]) != 0
    assert main(["geometric", "rotary", str(p), "--axis", "X"]) != 0
