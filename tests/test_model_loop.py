"""The closed loop: inject an effect into the machine FMU, co-simulate it as the recording (with
noise), diagnose it against the nominal model, export the fitted effect into the model, re-run
the co-simulation with it, and check that the re-simulation matches the recording to the noise
on time the diagnosis never saw, with the parameter recovered within its reported 3 sigma."""
from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("fmpy")

from mtcomp.diagnose import diagnose  # noqa: E402
from mtcomp.errors import ErrorSet, GeometricErrors  # noqa: E402
from mtcomp.fmu.build import MachineDynamics  # noqa: E402
from mtcomp.machine import load_machine  # noqa: E402
from mtcomp.model.dynamics import apply_dynamics  # noqa: E402
from mtcomp.model.export import export_model  # noqa: E402
from mtcomp.model.simulate import combine_errors, compare, signals_csv, simulate  # noqa: E402

M = "vmc-moving-column"
STEP = 2e-3
NOISE = 2e-5          # mm (20 nm)
# zig-zag in X and Y: reversals for backlash, both axes for squareness
PROGRAM = """G90 G1 F1200
X0 Y0 Z0
X20 Y5
X-20 Y-10
X15 Y10
X-15 Y-5
X0 Y0
"""
TRAIN = 0.6           # the diagnosis sees the first 60 % of the recording; the rest is held out


@pytest.fixture(scope="module")
def nominal():
    return simulate(PROGRAM, M, None, None, step=STEP, compiler="cc")


def _loop(tmp_path, nominal, errors=None, dynamics=None):
    rec = simulate(PROGRAM, M, errors, dynamics, step=STEP, compiler="cc")
    n_train = int(TRAIN * len(rec.t))
    sim_csv, rec_csv = tmp_path / "sim.csv", tmp_path / "rec.csv"
    sim_csv.write_text(signals_csv(nominal, M))
    lines = signals_csv(rec, M).splitlines()
    rec_csv.write_text("\n".join(lines[:1 + n_train]) + "\n")       # header + training rows only
    diag = diagnose(str(sim_csv), str(rec_csv))
    ex = export_model(diag, M, tmp_path / "model", step=STEP)
    # re-simulate through the FMU with the exported parameters (noise-free), compare on held-out time
    m_err = combine_errors(ErrorSet(), ex.errors, load_machine(M))
    m_dyn = apply_dynamics(MachineDynamics(), ex.dynamics_values, load_machine(M))
    upd = simulate(PROGRAM, M, m_err, m_dyn, step=STEP, compiler="cc")
    rec_out = {o: rec.p[:, k] for k, o in enumerate("xyz")}
    res = compare(rec.t, rec_out, nominal, upd, heldout_from=float(rec.t[n_train]))
    return diag, ex, res


def _assert_matches_noise(res):
    for o in "xyz":
        assert res.heldout_rms["after"][o] <= 1.5 * NOISE, (o, res.summary())


def _within_3sigma(value, sigma, truth):
    assert sigma is not None and sigma > 0
    assert abs(value - truth) <= 3 * sigma, (value, sigma, truth)


def test_backlash_loop(tmp_path, nominal):
    b = 0.003
    diag, ex, res = _loop(tmp_path, nominal, dynamics=MachineDynamics(backlash=(b, 0.0, 0.0), noise=NOISE, seed=5))
    assert diag.names == ["backlash"]
    p = {q.name: q for q in ex.params}["backlash.X"]
    _within_3sigma(p.value, p.sigma, b)
    assert res.heldout_rms["before"]["x"] > 20 * NOISE
    _assert_matches_noise(res)
    assert (tmp_path / "model" / "machine.ssv").is_file()


def test_squareness_loop(tmp_path, nominal):
    ec0y = 20e-6    # rad: Y tilted about Z
    diag, ex, res = _loop(tmp_path, nominal, errors=ErrorSet(geometric=GeometricErrors({}, {"EC0Y": ec0y})),
                          dynamics=MachineDynamics(noise=NOISE, seed=6))
    assert diag.names == ["squareness"]
    p = {q.name: q for q in ex.params}["location.EC0Y"]
    _within_3sigma(p.value, p.sigma, ec0y)
    assert res.heldout_rms["before"]["x"] > 3 * NOISE
    _assert_matches_noise(res)
