"""pythonfmu model of the mtcomp compensator: the baseline the native FMU is benchmarked against.

Same interface as the native compensator FMU (command.<AXIS> in, compensated.<AXIS> out), but
each step calls mtcomp.kinematics.retarget in the importer's Python interpreter, which must
have mtcomp and numpy installed.  Built by mtcomp.fmu.pyfmu.build_python_compensator_fmu.
"""
from pathlib import Path

from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Real


class MtcompPyCompensator(Fmi2Slave):
    author = "mtcomp"
    description = "mtcomp compensator in Python (pythonfmu): programmed axis commands in, compensated out"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        import numpy as np
        from mtcomp.errors import load_errors
        from mtcomp.machine import load_machine
        res = Path(self.resources)
        self._machine = load_machine(res / "machine.toml")
        self._errors = load_errors(res / "errors.toml")
        n = self._machine.n_axes
        self._cmd = np.zeros(n)
        self._out = np.zeros(n)
        self._dirty = True
        for i, a in enumerate(self._machine.axis_names):
            self.register_variable(Real(
                f"command.{a}", causality=Fmi2Causality.input, variability=Fmi2Variability.continuous,
                description=f"Commanded position of axis {a} as programmed",
                getter=lambda i=i: float(self._cmd[i]), setter=lambda v, i=i: self._set(i, v)))
        for i, a in enumerate(self._machine.axis_names):
            self.register_variable(Real(
                f"compensated.{a}", causality=Fmi2Causality.output, variability=Fmi2Variability.continuous,
                initial=Fmi2Initial.exact, description=f"Compensated command of axis {a}",
                getter=lambda i=i: self._get(i)))

    def _set(self, i, v):
        self._cmd[i] = v
        self._dirty = True

    def _get(self, i):
        if self._dirty:
            from mtcomp.kinematics import retarget
            self._out[:] = retarget(self._machine, self._cmd[None, :], self._errors)[0]
            self._dirty = False
        return float(self._out[i])

    def do_step(self, current_time, step_size):
        self._get(0)
        return True
