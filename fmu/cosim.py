"""Co-simulation: NC program -> compensator FMU -> machine FMU, with fmpy as the master.

`interpolate_program` turns an NC program into axis commands sampled at the communication step,
honouring the feed rate (G1/G2/G3 at F, G0 at a rapid rate); `cosimulate` runs the chain twice,
once without and once with the compensator, and returns a `CosimResult` with the signals, the
tool-edge errors and a plot.  Units: mm, deg, s; errors reported in um.
"""
from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._io import InputError, MtcompError, atomic_write, save_figure
from ..errors import ErrorSet
from ..machine import Machine, load_machine
from . import build as _b

__all__ = ["interpolate_program", "cosimulate", "CosimResult", "FmuRunner"]

_PLANES = {17: ("X", "Y", "Z"), 18: ("Z", "X", "Y"), 19: ("Y", "Z", "X")}


def interpolate_program(program, machine: Machine, step: float, *, rapid: float = 3000.0,
                        dwell: float = 0.0, max_arc_step_deg: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Sample an NC program at the communication step.

    program: path of an NC file, its text (anything with a line break), or a parsed
    `mtcomp.gcode.Program`.  Linear and
    circular blocks run at their feed F (mm/min; a block moving only rotary axes at F deg/min,
    mixed moves at F along sqrt(sum of squared axis moves), the usual control convention), G0 at
    `rapid` (mm/min).  Returns (t (K,) s, q (K, n_axes) mm/deg) with t = 0, step, 2 step, ...
    """
    from .. import gcode
    if not (step > 0 and np.isfinite(step)):
        raise InputError(f"communication step must be a positive number of seconds, got {step!r}", field="step")
    if isinstance(program, gcode.Program):
        prog = program
    else:
        text, name = program, "<string>"
        if isinstance(program, os.PathLike) or (isinstance(program, str) and "\n" not in program):
            name = str(program)  # a path: program text always has a line break
            try:
                text = Path(program).read_text(encoding="utf-8")
            except FileNotFoundError:
                raise InputError("NC program not found", program) from None
        prog = gcode.parse(text, axes=machine.axis_names, filename=name)
    n = machine.n_axes
    if len(prog) == 0:
        raise InputError("the program has no motion blocks", prog.filename)
    ix = {a: k for k, a in enumerate(machine.axis_names)}
    points = [np.asarray(prog.start, float)]
    times = [0.0]
    prev = np.asarray(prog.start, float)
    for b in range(len(prog)):
        end = prog.position[b]
        motion = int(prog.motion[b])
        feed = float(prog.feed[b])
        if motion in (2, 3) and np.isfinite(prog.arc_sweep[b]):
            u, v, w = (ix[c] for c in _PLANES[int(prog.plane[b])])
            iu, iv = ("XYZ".index(c) for c in _PLANES[int(prog.plane[b])][:2])
            cu, cv = prog.arc_centre[b, iu], prog.arc_centre[b, iv]
            sweep = float(prog.arc_sweep[b])
            r = np.hypot(prev[u] - cu, prev[v] - cv)
            a0 = np.arctan2(prev[v] - cv, prev[u] - cu)
            m = max(1, int(np.ceil(abs(np.degrees(sweep)) / max_arc_step_deg)))
            s = np.arange(1, m + 1) / m
            seg = prev + s[:, None] * (end - prev)
            seg[:, u] = cu + r * np.cos(a0 + s * sweep)
            seg[:, v] = cv + r * np.sin(a0 + s * sweep)
            seg[-1] = end
        else:
            seg = end[None, :]
        rate = rapid if motion == 0 else feed
        if motion != 0 and not (rate > 0):
            raise InputError("feed motion without a positive feed rate F", prog.filename, int(prog.line[b]))
        last = prev
        for pnt in seg:
            d = pnt - last
            length = float(np.sqrt(np.sum(d ** 2)))  # mm and deg together, as a control does
            if motion == 0:
                length = float(np.max(np.abs(d))) if length else 0.0
            if length > 0:
                times.append(times[-1] + length / rate * 60.0)
                points.append(pnt)
            last = pnt
        prev = end
    t_nodes = np.asarray(times)
    q_nodes = np.asarray(points)
    t_end = t_nodes[-1] + dwell
    k = int(np.floor(t_end / step + 1e-9)) + 1
    t = np.arange(k) * step
    q = np.empty((k, n))
    for j in range(n):
        q[:, j] = np.interp(t, t_nodes, q_nodes[:, j])
    return t, q


class FmuRunner:
    """One FMI 2.0 co-simulation FMU instance driven through fmpy (the master's view of it)."""

    def __init__(self, path, name: str, logs: list | None = None):
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave
        self.path = Path(path)
        self.md = read_model_description(str(self.path))
        self.unzipdir = extract(str(self.path))
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.types = {v.name: v.type for v in self.md.modelVariables}
        self.logs = logs if logs is not None else []
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=self.unzipdir,
                             modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=name)
        self.fmu.instantiate(callbacks=self._callbacks())
        self.fmu.setupExperiment(startTime=0.0)

    def _callbacks(self):
        from fmpy.fmi2 import (fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                               fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
        from fmpy import calloc, free
        logs = self.logs

        def logger(env, instance, status, category, message):
            logs.append((int(status), (category or b"").decode(), (message or b"").decode()))

        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(logger)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self._cb = cb  # keep the ctypes callbacks alive as long as the instance
        return cb

    def refs(self, names) -> list[int]:
        return [self.vr[n] for n in names]

    def set(self, values: dict) -> None:
        reals = {k: v for k, v in values.items() if self.types[k] == "Real"}
        ints = {k: v for k, v in values.items() if self.types[k] == "Integer"}
        strs = {k: v for k, v in values.items() if self.types[k] == "String"}
        if reals:
            self.fmu.setReal(self.refs(reals), [float(x) for x in reals.values()])
        if ints:
            self.fmu.setInteger(self.refs(ints), [int(x) for x in ints.values()])
        if strs:
            self.fmu.setString(self.refs(strs), [str(x) for x in strs.values()])

    def close(self) -> None:
        try:
            self.fmu.terminate()
        finally:
            self.fmu.freeInstance()
            import shutil
            shutil.rmtree(self.unzipdir, ignore_errors=True)


@dataclass(frozen=True)
class CosimResult:
    """Signals of one co-simulation (K samples at the communication step).

    t (K,) s; q_programmed, q_compensated, q_actual (K, n) mm/deg (q_actual: axis positions of
    the compensated run after servo and backlash); target (K, 3) mm: ideal tool edge;
    p_uncompensated, p_compensated (K, 3) mm: real tool edge in the real workpiece frame;
    p_lag (K, 3) mm: the part of the compensated error due to the axes not being where they
    were commanded (servo lag, backlash), from the core model.
    """
    machine: str
    axes: tuple
    t: np.ndarray
    q_programmed: np.ndarray
    q_compensated: np.ndarray
    q_actual: np.ndarray
    target: np.ndarray
    p_uncompensated: np.ndarray
    p_compensated: np.ndarray
    p_lag: np.ndarray
    step: float
    notes: dict = field(default_factory=dict)

    @property
    def error_uncompensated(self) -> np.ndarray:
        """Tool edge error magnitude without compensation, mm (K,)."""
        return np.linalg.norm(self.p_uncompensated - self.target, axis=1)

    @property
    def error_compensated(self) -> np.ndarray:
        return np.linalg.norm(self.p_compensated - self.target, axis=1)

    @property
    def error_lag(self) -> np.ndarray:
        return np.linalg.norm(self.p_lag, axis=1)

    @staticmethod
    def _stats(e: np.ndarray) -> tuple[float, float]:
        return float(np.max(e)), float(np.sqrt(np.mean(e ** 2)))

    @property
    def max_uncompensated(self) -> float:
        return self._stats(self.error_uncompensated)[0]

    @property
    def rms_uncompensated(self) -> float:
        return self._stats(self.error_uncompensated)[1]

    @property
    def max_compensated(self) -> float:
        return self._stats(self.error_compensated)[0]

    @property
    def rms_compensated(self) -> float:
        return self._stats(self.error_compensated)[1]

    def summary(self) -> str:
        u, c = self._stats(self.error_uncompensated), self._stats(self.error_compensated)
        lag = self._stats(self.error_lag)
        res = (self.p_compensated - self.target) - self.p_lag
        rmax = float(np.max(np.linalg.norm(res, axis=1)))
        return (f"co-simulation of {self.machine}: {len(self.t)} steps of {self.step:g} s "
                f"({self.t[-1]:.3f} s)\n"
                f"  tool edge error without compensation: max {u[0] * 1e3:.3f} um, RMS {u[1] * 1e3:.3f} um\n"
                f"  tool edge error with compensation:    max {c[0] * 1e3:.4f} um, RMS {c[1] * 1e3:.4f} um\n"
                f"  of which servo lag / backlash:        max {lag[0] * 1e3:.4f} um, RMS {lag[1] * 1e3:.4f} um\n"
                f"  compensated error minus lag part:     max {rmax * 1e3:.4f} um")

    def to_csv(self, path) -> Path:
        """All signals, one row per step (docs/fmu.md lists the columns)."""
        cols = ["t"]
        cols += [f"programmed.{a}" for a in self.axes] + [f"compensated.{a}" for a in self.axes]
        cols += [f"actual.{a}" for a in self.axes]
        for name in ("target", "uncompensated", "compensated", "lag"):
            cols += [f"{name}.{c}" for c in "xyz"]
        cols += ["error_uncompensated_um", "error_compensated_um", "error_lag_um"]
        data = np.column_stack([self.t, self.q_programmed, self.q_compensated, self.q_actual, self.target,
                                self.p_uncompensated, self.p_compensated, self.p_lag,
                                self.error_uncompensated * 1e3, self.error_compensated * 1e3, self.error_lag * 1e3])
        import io
        buf = io.StringIO()
        buf.write("# mtcomp co-simulation: mm, deg, s; errors in um\n")
        np.savetxt(buf, data, delimiter=",", header=",".join(cols), comments="", fmt="%.12g")
        return atomic_write(path, buf.getvalue())

    def plot(self, path) -> Path:
        """PNG of the tool edge error over time (um): without and with compensation, and the
        part of the compensated error that is servo lag / backlash."""
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
        a1.plot(self.t, self.error_uncompensated * 1e3, color="tab:red", label="without compensation")
        a1.plot(self.t, self.error_compensated * 1e3, color="tab:blue", label="with compensation")
        a1.set_ylabel("tool edge error (um)")
        a1.set_title(f"{self.machine}: tool edge error in the workpiece frame")
        a1.legend(loc="best")
        a1.grid(True, alpha=0.3)
        a2.plot(self.t, self.error_compensated * 1e3, color="tab:blue", label="with compensation")
        a2.plot(self.t, self.error_lag * 1e3, color="k", ls="--", lw=1, label="servo lag / backlash part")
        res = np.linalg.norm((self.p_compensated - self.target) - self.p_lag, axis=1)
        a2.plot(self.t, res * 1e3, color="tab:green", lw=1, label="remaining (compensated - lag)")
        a2.set_xlabel("time (s)")
        a2.set_ylabel("error (um)")
        a2.legend(loc="best")
        a2.grid(True, alpha=0.3)
        fig.tight_layout()
        save_figure(fig, path, dpi=110)
        return Path(path)


def _run(machine: Machine, q: np.ndarray, step: float, mach_path, comp_path, spindle_speed: float):
    """One run; comp_path None: the machine gets the programmed commands."""
    names = machine.axis_names
    logs: list = []
    mach = FmuRunner(mach_path, "machine", logs)
    comp = FmuRunner(comp_path, "compensator", logs) if comp_path else None
    try:
        cin = mach.refs([f"command.{a}" for a in names])
        outs = mach.refs(["tool.x", "tool.y", "tool.z"] + [f"actual.{a}" for a in names])
        cmp_in = comp.refs([f"command.{a}" for a in names]) if comp else None
        cmp_out = comp.refs([f"compensated.{a}" for a in names]) if comp else None
        K, n = q.shape
        qc = np.empty_like(q)
        p = np.empty((K, 3))
        act = np.empty_like(q)
        for f in (mach, comp):
            if f:
                f.fmu.enterInitializationMode()
        if comp:
            comp.fmu.setReal(cmp_in, list(q[0]))
            comp.fmu.exitInitializationMode()
        first = comp.fmu.getReal(cmp_out) if comp else list(q[0])
        mach.fmu.setReal(cin, first)
        mach.set({"spindle_speed": spindle_speed})
        mach.fmu.exitInitializationMode()
        t = 0.0
        for k in range(K):
            if comp:
                comp.fmu.setReal(cmp_in, list(q[k]))
                cmd = comp.fmu.getReal(cmp_out)
            else:
                cmd = list(q[k])
            qc[k] = cmd
            mach.fmu.setReal(cin, cmd)
            o = mach.fmu.getReal(outs)
            p[k] = o[:3]
            act[k] = o[3:]
            if k + 1 < K:
                if comp:
                    comp.fmu.doStep(t, step)
                mach.fmu.doStep(t, step)
                t = (k + 1) * step
        return qc, p, act
    except Exception as exc:
        msgs = "; ".join(m for s, _, m in logs if s >= 3)
        raise MtcompError(f"co-simulation failed: {exc}" + (f" (FMU log: {msgs})" if msgs else "")) from None
    finally:
        for f in (comp, mach):
            if f:
                f.close()


def cosimulate(program, machine, true_errors: ErrorSet, identified_errors: ErrorSet | None = None, *,
               step: float = 1e-3, dynamics: _b.MachineDynamics | None = None, rapid: float = 3000.0,
               spindle_speed: float = 0.0, workdir=None, compiler: str = "cmake") -> CosimResult:
    """Run NC -> compensator FMU -> machine FMU and, for comparison, NC -> machine FMU.

    program: NC file path or text (interpolated at `step` s honouring the feed), or an array of
    axis commands (K, n_axes) already sampled at `step`.  true_errors: the machine's errors (the
    machine FMU); identified_errors: what the compensator believes (default: the true ones).
    dynamics: servo/backlash/thermal/noise of the machine FMU (default: ideal).  The FMUs are
    built into `workdir` (default: a temporary folder) with `compiler` ("cmake" or "cc").
    """
    from ..kinematics import forward
    machine = load_machine(machine)
    identified = true_errors if identified_errors is None else identified_errors
    if isinstance(program, np.ndarray) or (isinstance(program, (list, tuple)) and np.ndim(program) == 2):
        q = np.asarray(program, dtype=float)
        if q.ndim != 2 or q.shape[1] != machine.n_axes or len(q) < 2:
            raise InputError(f"axis command array must have shape (K >= 2, {machine.n_axes}), got {q.shape}",
                             field="program")
        t = np.arange(len(q)) * step
    else:
        t, q = interpolate_program(program, machine, step, rapid=rapid)
    tmp = None
    if workdir is None:
        tmp = tempfile.TemporaryDirectory(prefix="mtcomp-cosim-")
        workdir = tmp.name
    workdir = Path(workdir)
    try:
        mach_path = _b.build_machine_fmu(machine, workdir / "machine.fmu", true_errors, dynamics, compiler=compiler)
        comp_path = _b.build_compensator_fmu(machine, workdir / "compensator.fmu", identified, compiler=compiler)
        _, p_unc, _ = _run(machine, q, step, mach_path, None, spindle_speed)
        qc, p_cmp, act = _run(machine, q, step, mach_path, comp_path, spindle_speed)
    finally:
        if tmp is not None:
            tmp.cleanup()
    target = forward(machine, q).p
    # Error due to the axes not being where commanded: real machine at the actual positions
    # minus real machine at the commanded ones (the core model, thermal drift excluded).
    p_lag = forward(machine, act, true_errors, strict=False).p - forward(machine, qc, true_errors, strict=False).p
    return CosimResult(machine.name, machine.axis_names, t, q, qc, act, target, p_unc, p_cmp, p_lag, step)
