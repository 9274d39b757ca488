"""Pruning and refining through the model are judged on samples they did not fit: an effect the
validation samples need is put back, and a refit that does not lower the validation error is
refused (the diagnosis' values are kept)."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("fmpy")

from mtcomp.errors import ErrorSet, GeometricErrors  # noqa: E402
from mtcomp.fmu.build import MachineDynamics  # noqa: E402
from mtcomp.model.export import export_model  # noqa: E402
from mtcomp.model.simulate import OUTPUTS, _split, prune, refine, simulate  # noqa: E402

M = "vmc-moving-column"
STEP = 4e-3
# X back and forth with Y at 0, then Y moves: a squareness (x by y) shows only at the end
PROGRAM = "G90 G1 F1200\nX0 Y0 Z0\nX20\nX0\nX20\nX0\nX20\nX0\nY20\nY0\n"
G = 40e-6    # rad


@pytest.fixture(scope="module")
def rec():
    sig = simulate(PROGRAM, M, ErrorSet(geometric=GeometricErrors({}, {"EC0Y": G})),
                   MachineDynamics(noise=2e-5, seed=2), step=STEP, compiler="cc")
    return sig.t, {o: sig.p[:, k] for k, o in enumerate(OUTPUTS)}


def _export(angle_deg):
    eff = [{"name": "squareness", "output": "x", "inputs": ["y"], "params": {"angle_deg": angle_deg},
            "uncertainty": {"angle_deg": 1e-5}}]
    return export_model({"effects": eff}, M, None, step=STEP)


def test_split_leaves_the_held_out_samples_alone():
    t = np.arange(100) * 0.1
    fit, val, cut = _split(t, 6.0)
    assert cut == pytest.approx(4.2) and not np.any(fit & val)
    assert not np.any((fit | val) & (t >= 6.0))


def test_prune_puts_back_what_the_validation_samples_need(rec):
    t, r = rec
    ex = _export(-np.degrees(G))
    assert len(ex.mapped) == 1
    log: list = []
    out = prune(ex, t, r, program=PROGRAM, machine=M, step=STEP, noise_floor={o: 2e-5 for o in OUTPUTS},
                compiler="cc", log=log)
    # the first 70 % (Y at 0) cannot tell; the validation samples (Y moving) keep it
    assert any(ln.startswith("dropped squareness") for ln in log), log
    assert any(ln.startswith("put back squareness") for ln in log), log
    assert len(out.mapped) == 1


def test_refine_refused_when_the_validation_error_does_not_fall(rec):
    """The fitted part has Y at 0, so it cannot see the squareness: the refit of a wrong start
    (half the angle) does not move it, the validation error does not fall, and the refit is
    refused: the diagnosis' values and sigmas are kept (before, its sigma came from a singular
    curvature and was returned as it was)."""
    t, r = rec
    ex = _export(-0.5 * np.degrees(G))
    log: list = []
    out = refine(ex, t, r, program=PROGRAM, machine=M, step=STEP, noise_floor={o: 2e-5 for o in OUTPUTS},
                 compiler="cc", log=log, stride=2)
    assert any(ln.startswith("refine rejected") for ln in log), log
    assert out is ex
