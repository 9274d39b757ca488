"""`kinematics.deviations`: the check of a compensated program in one compiled pass (three tool
edge positions per pose) against three passes of the numpy reference."""
import numpy as np
import pytest

from mtcomp import _kernel
from mtcomp.errors import ErrorSet, GeometricErrors, TableRangeError, WorkpieceSetting
from mtcomp.kinematics import deviations, forward, retarget
from mtcomp.machine import load_machine

from _models import random_commands, random_errors

pytestmark = pytest.mark.skipif(not _kernel.available(), reason="no C compiler: the numpy reference runs alone")

PRESETS = ["robonano-ui", "robonano-a0ib", "vmc-moving-column"]


def _kinds(machine, rng):
    full = random_errors(machine, rng, wp_angle=2.0 if machine.n_rotary else 0.5)
    return {"all": full, "tool": ErrorSet(full.tool),
            "wp_rotation": ErrorSet(workpiece=full.workpiece),
            "location": ErrorSet(geometric=GeometricErrors(location=full.geometric.location)),
            "tables": ErrorSet(geometric=GeometricErrors(tables=full.geometric.tables))}


def _distance(a, b):
    return np.sqrt(np.sum((a - b) ** 2, axis=1))


@pytest.mark.parametrize("name", PRESETS)
def test_one_pass_is_the_reference_three_forwards(name, rng):
    m = load_machine(name)
    for kind, E in _kinds(m, rng).items():
        q = random_commands(m, 300, rng, span=0.3)
        # emitted commands as a compensation leaves them: micrometres and micro-degrees away,
        # which the rotary sines and cosines take by the angle sum
        qe = q + rng.uniform(-2e-3, 2e-3, q.shape)
        target = forward(m, q, backend="numpy").p
        b_ref = _distance(forward(m, q, E, backend="numpy").p, target)
        a_ref = _distance(forward(m, qe, E, backend="numpy").p, target)
        b, a = deviations(m, q, qe, E, backend="c")
        assert np.max(np.abs(b - b_ref)) <= 1e-12, kind
        assert np.max(np.abs(a - a_ref)) <= 1e-12, kind
        bn, an = deviations(m, q, qe, E, backend="numpy")
        assert np.max(np.abs(bn - b_ref)) <= 1e-15 and np.max(np.abs(an - a_ref)) <= 1e-15, kind
        assert np.all(b > 1e-4), kind        # every kind moves the tool edge


@pytest.mark.parametrize("name", PRESETS)
def test_compensated_commands_check_to_the_solver_tolerance(name, rng):
    """The retargeted commands put the real tool edge on the ideal one: after ~ 0, before the
    size of the errors (the error map's norm, computed independently)."""
    m = load_machine(name)
    E = random_errors(m, rng)
    q = random_commands(m, 500, rng, span=0.3)
    qc = retarget(m, q, E)
    b, a = deviations(m, q, qc, E)
    assert np.max(a) <= 1e-9
    assert np.allclose(b, _distance(forward(m, q, E).p, forward(m, q).p), rtol=0, atol=1e-12)


def test_the_same_on_one_thread_and_two(monkeypatch, rng):
    m = load_machine("robonano-a0ib")
    E = random_errors(m, rng)
    q = random_commands(m, 3 * 4096 + 17, rng, span=0.3)
    qe = q + 1e-4
    monkeypatch.setenv("MTCOMP_THREADS", "1")
    one = deviations(m, q, qe, E)
    monkeypatch.setenv("MTCOMP_THREADS", "2")
    two = deviations(m, q, qe, E)
    assert np.array_equal(one[0], two[0]) and np.array_equal(one[1], two[1])


@pytest.mark.parametrize("backend", ["c", "numpy"])
@pytest.mark.parametrize("which", ["programmed", "emitted"])
def test_a_command_outside_a_table_is_named(backend, which, rng):
    m = load_machine("vmc-moving-column")
    E = random_errors(m, rng)
    lo, hi = E.geometric.tables["Y"].range
    q = random_commands(m, 9000, rng, span=0.3)
    qe = q.copy()
    (q if which == "programmed" else qe)[5000, 1] = hi + 0.5
    with pytest.raises(TableRangeError) as exc:
        deviations(m, q, qe, E, backend=backend)
    assert exc.value.axis == "Y" and exc.value.index == 5000


def test_shapes_must_agree():
    m = load_machine("robonano-a0ib")
    with pytest.raises(ValueError, match="differ in shape"):
        deviations(m, np.zeros((3, 5)), np.zeros((2, 5)), ErrorSet(workpiece=WorkpieceSetting((0.01, 0, 0))))
