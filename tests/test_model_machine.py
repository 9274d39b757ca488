"""The machine FMU's dynamics (servo, backlash, transport delay, friction, thermal drift) against
the Python reference model mtcomp.model.machine_ref, and the public machine-only run."""
from __future__ import annotations

import numpy as np
import pytest

from mtcomp._io import InputError
from mtcomp.fmu.build import MachineDynamics, build_machine_fmu
from mtcomp.fmu.cosim import run_machine
from mtcomp.machine import load_machine

MACHINE = "vmc-moving-column"


@pytest.fixture(scope="module")
def machine():
    return load_machine(MACHINE)


def test_run_machine_checks_its_inputs(machine, tmp_path):
    fmu = build_machine_fmu(machine, tmp_path / "m.fmu")
    q = np.zeros((5, machine.n_axes))
    with pytest.raises(InputError, match="shape"):
        run_machine(fmu, machine, q[:, :2], 1e-3)
    with pytest.raises(InputError, match="spindle_speed"):
        run_machine(fmu, machine, q, 1e-3, spindle_speed=np.zeros(4))
    run = run_machine(fmu, machine, q, 1e-3, spindle_speed=np.linspace(0, 100, 5))
    assert run.p.shape == (5, 3) and run.actual.shape == (5, machine.n_axes)
