"""First-order tool-tip error models against exact models (paper 004 and mtcomp.kinematics)."""
import numpy as np
import pytest

from mtcomp.errors import AxisErrorTable, ErrorSet, GeometricErrors
from mtcomp.geometric import first_order as fo
from mtcomp.geometric import synthetic
from mtcomp.kinematics import forward, rotvec_matrix
from mtcomp.machine import load_machine

K = (250.0, 350.0, 40.0, 400.0, 150.0, 300.0, 20.0)


def _paper_exact(X, Y, Z, k, err, W, T):
    """Paper 004's vector chain (formulas 1-3) with exact rotations, written independently of
    first_order: R_T - R_W in the bed frame E1, turned into the laser frame E0."""
    k1, k2, k3, k4, k5, k6, k7 = k
    F = {key: float(np.asarray(v)) for key, v in err.f.items()}
    A = {key: float(np.asarray(v)) for key, v in err.ang.items()}

    def rot(i):
        return rotvec_matrix(np.array([[A.get(f"{i}{d}", 0.0) for d in "ABC"]]))[0]

    def fvec(g):
        return np.array([F.get(f"{d}{g}", 0.0) for d in "xyz"])
    R1, R2, R3, R4 = rot(1), rot(2), rot(3), rot(4)
    RT = (np.array([0, Y + k1 + k7, 0]) + fvec("Y")
          + R3 @ (np.array([0, 0, Z + k2 + k5 + k4]) + fvec("Z"))
          + R3 @ R4 @ np.array([k3 + T[0], -(k1 - T[1]), -(k2 - T[2])]))
    RW = (np.array([k3 - k6 + X, 0, k4]) + fvec("X")
          + R2 @ np.array([k6 + W[0], k7 + W[1], k5 + W[2]]))
    return R1 @ (RT - RW)


def _random_paper_errors(rng, scale):
    f = {f"{d}{g}": rng.uniform(-20e-3, 20e-3) * scale for d in "xyz" for g in "XYZ"}
    a = {f"{i}{d}": rng.uniform(-50e-6, 50e-6) * scale for i in "1234" for d in "ABC"}
    return fo.PaperErrors(f, a)


def test_formula4_as_printed_equals_the_derived_x_component():
    rng = np.random.default_rng(0)
    for _ in range(20):
        err = _random_paper_errors(rng, 1.0)
        X, Y, Z = rng.uniform(-300, 300, 3)
        W, T = rng.uniform(-100, 100, 3), rng.uniform(-100, 100, 3)
        derived = fo.paper_tool_tip(X, Y, Z, K, err, W, T)
        assert fo.formula4_printed(X, Y, Z, K, err, W, T) == pytest.approx(float(derived[0]), abs=1e-12)


def test_paper_first_order_differs_from_the_exact_chain_at_second_order():
    X, Y, Z = 250.0, -180.0, -220.0
    W, T = (30.0, -20.0, 10.0), (5.0, 8.0, -60.0)
    diffs = []
    for scale in (1.0, 0.5):
        r = np.random.default_rng(7)
        err = _random_paper_errors(r, scale)
        exact = _paper_exact(X, Y, Z, K, err, W, T)
        first = fo.paper_tool_tip(X, Y, Z, K, err, W, T)
        nominal = np.array([T[0] - X - W[0], Y + T[1] - W[1], Z + T[2] - W[2]])
        assert np.abs(exact - nominal).max() > 1e-2   # the errors do act (tens of µm)
        diffs.append(np.abs(exact - first).max())
    assert diffs[0] < 2e-5                            # 20 nm at full scale
    assert diffs[0] / diffs[1] == pytest.approx(4.0, rel=0.15)   # quadratic in the errors


@pytest.fixture(scope="module")
def vmc():
    return load_machine("vmc-moving-column")


@pytest.fixture(scope="module")
def syn(vmc):
    return synthetic.make_synthetic(vmc, seed=2)


def test_synthetic_errors_are_canonical_and_within_bounds(vmc, syn):
    for ax in vmc.axes:
        s = synthetic.run_positions(ax, 10.0)
        for name in ("E" + d + ax.name for d in "XYZABC"):
            v = syn.value(name, s)
            bound = 20e-3 if name[1] in "XYZ" else 50e-6
            assert np.abs(v).max() <= bound * (1 + 1e-12) and np.abs(v).max() >= 0.5 * bound * 0.999
            assert syn.value(name, 0.0) == pytest.approx(0.0, abs=1e-15)
            if name[1] in "XYZ" and name[1] != name[2]:
                assert abs(np.polyfit(s, v, 1)[0]) < 1e-12
    assert set(syn.squareness) == {"EC0Y", "EB0Z", "EA0Z"}


def _scaled(errors: ErrorSet, k: float) -> ErrorSet:
    g = errors.geometric
    tables = {a: AxisErrorTable(a, t.position, {n: v * k for n, v in t.values.items()})
              for a, t in g.tables.items()}
    return ErrorSet(geometric=GeometricErrors(tables, {n: v * k for n, v in g.location.items()}))


def test_first_order_model_matches_exact_forward_to_second_order(vmc, syn):
    rng = np.random.default_rng(3)
    q = np.column_stack([rng.uniform(*a.limits, 3000) for a in vmc.axes])
    diffs = []
    for k in (1.0, 0.5):
        err = _scaled(syn.errors(), k)
        exact = forward(vmc, q, err).p - forward(vmc, q).p
        first = fo.tool_tip_error(vmc, q, err.geometric)
        assert np.abs(exact).max() > 0.03 * k
        diffs.append(np.abs(exact - first).max())
    assert diffs[0] < 1e-5
    assert diffs[0] / diffs[1] == pytest.approx(4.0, rel=0.1)


def test_paper_formulas_on_mtcomp_tables_match_exact_forward(vmc, syn):
    """Paper 004's formulas with the tables translated into F(G), iD and W under the tool agree
    with mtcomp's exact model to second order; with W = T = 0 (the paper's X', Y', Z') they miss
    the rotation of the table-borne workpiece frame, a first-order term."""
    err = syn.errors()
    rng = np.random.default_rng(4)
    q = np.column_stack([rng.uniform(*a.limits, 2000) for a in vmc.axes])
    exact = forward(vmc, q, err).p - forward(vmc, q).p
    k = fo.paper_k(vmc)
    assert k == tuple(vmc.extra["k"])
    pe = fo.paper_errors_from_tables(vmc, err.geometric, q)
    paper = fo.paper_tool_tip(-q[:, 0], q[:, 1], q[:, 2], k, pe, W=(q[:, 0], q[:, 1], q[:, 2]))
    assert np.abs(paper - exact).max() < 1e-5
    origin = fo.paper_tool_tip(-q[:, 0], q[:, 1], q[:, 2], k, pe) - q
    # the missing term is the table's rotation times the tool's distance from O: ε2 × p
    eps2 = np.column_stack([pe.A("2A"), pe.A("2B"), pe.A("2C")])
    np.testing.assert_allclose(origin - exact, np.cross(eps2, q), atol=1e-5)
    assert np.abs(origin - exact).max() > 5e-3


def test_abbe_correction_is_formula_10():
    """reading − ε × ℓ removes the set-up offset's contribution (paper 004 formula 10)."""
    rng = np.random.default_rng(5)
    eps = rng.uniform(-50e-6, 50e-6, (10, 3))
    lever = np.array([0.0, 120.0, -80.0])
    delta = rng.uniform(-0.02, 0.02, (10, 3))
    reading = delta + np.cross(eps, lever)
    np.testing.assert_allclose(fo.measured_feed(reading, lever, eps), delta, atol=1e-15)
    # x component by hand: (ε × ℓ)_x = B ℓz − C ℓy = −80 B − 120 C (formula 10's 2B, 2C terms)
    np.testing.assert_allclose(fo.measured_feed(reading, lever, eps)[:, 0],
                               reading[:, 0] + 80.0 * eps[:, 1] + 120.0 * eps[:, 2], atol=1e-15)
