"""Co-simulation: NC program -> compensator FMU -> machine FMU, with fmpy as the master.

`interpolate_program` turns an NC program into axis commands sampled at the communication step,
honouring the feed rate (G1/G2/G3 at F, G0 at a rapid rate); `cosimulate` runs the chain twice,
once without and once with the compensator, and returns a `CosimResult` with the signals, the
tool-edge errors and a figure.  Units: mm, deg, s; errors reported in µm.
"""
from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._io import InputError, MtcompError, atomic_write
from ..errors import ErrorSet
from ..machine import Machine, load_machine
from . import build as _b

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["interpolate_program", "cosimulate", "CosimResult", "FmuRunner", "run_machine", "MachineRun"]

_PLANES = {17: ("X", "Y", "Z"), 18: ("Z", "X", "Y"), 19: ("Y", "Z", "X")}


def block_points(prog, b: int, prev: np.ndarray, ix: dict, max_arc_step_deg: float) -> np.ndarray:
    """Axis positions (m, n) mm/deg along block b of a parsed program, from `prev`: an arc at
    most max_arc_step_deg apart (the other axes linear in its angle), any other block its end."""
    end = np.asarray(prog.position[b], float)
    if int(prog.motion[b]) not in (2, 3) or not np.isfinite(prog.arc_sweep[b]):
        return end[None, :]
    u, v, _ = (ix[c] for c in _PLANES[int(prog.plane[b])])
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
    return seg


def interpolate_program(program, machine: Machine, step: float, *, rapid: float = 3000.0,
                        dwell: float = 0.0, max_arc_step_deg: float = 1.0, with_rapid: bool = False):
    """Sample an NC program at the communication step.

    program: path of an NC file, its text (anything with a line break), or a parsed
    `mtcomp.gcode.Program`.  Linear and
    circular blocks run at their feed F (mm/min; a block moving only rotary axes at F deg/min,
    mixed moves at F along sqrt(sum of squared axis moves), the usual control convention), G0 at
    `rapid` (mm/min).  Returns (t (K,) s, q (K, n_axes) mm/deg) with t = 0, step, 2 step, ...;
    with_rapid=True adds a (K,) bool array, True where the sample lies on a G0 move.
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
    rapids = [False]
    prev = np.asarray(prog.start, float)
    for b in range(len(prog)):
        end = prog.position[b]
        motion = int(prog.motion[b])
        feed = float(prog.feed[b])
        seg = block_points(prog, b, prev, ix, max_arc_step_deg)
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
                rapids.append(motion == 0)
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
    if not with_rapid:
        return t, q
    # a sample between nodes j-1 and j lies on the move that ends at node j
    j = np.minimum(np.searchsorted(t_nodes, t, side="left"), len(t_nodes) - 1)
    return t, q, np.asarray(rapids)[j]


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

    def raw(self):
        """(component, fmi2SetReal, fmi2GetReal, fmi2DoStep): the FMU's own C functions with
        every pointer argument typed as a plain address, for a loop that passes the addresses of
        preallocated arrays (numpy rows or ctypes arrays) instead of building new ctypes arrays
        and checking the status in Python as fmpy's methods do on every call.  The caller checks
        the returned status.  Function objects of their own: fmpy's stay as they are."""
        import ctypes
        c_int, vp = ctypes.c_int, ctypes.c_void_p
        values = ctypes.CFUNCTYPE(c_int, vp, vp, ctypes.c_size_t, vp)
        step = ctypes.CFUNCTYPE(c_int, vp, ctypes.c_double, ctypes.c_double, c_int)
        dll = self.fmu.dll

        def address(name):
            return ctypes.cast(getattr(dll, name), vp).value

        return (self.fmu.component.value if hasattr(self.fmu.component, "value") else self.fmu.component,
                values(address("fmi2SetReal")), values(address("fmi2GetReal")), step(address("fmi2DoStep")))

    def close(self) -> None:
        try:
            self.fmu.terminate()
        finally:
            self.fmu.freeInstance()
            import shutil
            shutil.rmtree(self.unzipdir, ignore_errors=True)


def _stats(e: np.ndarray) -> tuple[float, float]:
    """(max, RMS) of an error magnitude array; (nan, nan) when empty."""
    if e.size == 0:
        return float("nan"), float("nan")
    return float(np.max(e)), float(np.sqrt(np.mean(e ** 2)))


def _um(x_mm: float) -> str:
    """A length given in mm, printed in µm (nm when below 0.1 µm) with 3 significant digits."""
    if not np.isfinite(x_mm):
        return "n/a"
    um = x_mm * 1e3
    if abs(um) < 0.1:
        return f"{um * 1e3:.3g} nm"
    return f"{um:.3g} µm" if abs(um) < 1000 else f"{um:.0f} µm"


@dataclass(frozen=True)
class CosimResult:
    """Signals of one co-simulation (K samples at the communication step).

    t (K,) s: time at which the command row was given; the machine's outputs are read at the end
    of that step (t + step), as the machine FMU has no direct feed-through.
    q_programmed, q_compensated, q_actual (K, n) mm/deg (q_actual: axis positions of the
    compensated run after servo and backlash); target (K, 3) mm: ideal tool edge;
    p_uncompensated, p_compensated (K, 3) mm: real tool edge in the real workpiece frame;
    p_lag (K, 3) mm: the part of the compensated error due to the axes not being where they
    were commanded (servo lag, backlash), from the core model; rapid (K,) bool: True on G0
    moves (reported apart: a rapid's error does not mark the part).
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
    rapid: np.ndarray | None = None

    @property
    def is_rapid(self) -> np.ndarray:
        return np.zeros(len(self.t), bool) if self.rapid is None else np.asarray(self.rapid, bool)

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

    @property
    def error_remaining(self) -> np.ndarray:
        """Compensated error minus its servo lag / backlash part, mm (K,)."""
        return np.linalg.norm((self.p_compensated - self.target) - self.p_lag, axis=1)

    def _cut(self, e: np.ndarray) -> np.ndarray:
        return e[~self.is_rapid]

    @property
    def max_uncompensated(self) -> float:
        """Largest tool edge error without compensation while cutting (G0 rapids excluded), mm."""
        return _stats(self._cut(self.error_uncompensated))[0]

    @property
    def rms_uncompensated(self) -> float:
        return _stats(self._cut(self.error_uncompensated))[1]

    @property
    def max_compensated(self) -> float:
        """Largest tool edge error with compensation while cutting (G0 rapids excluded), mm."""
        return _stats(self._cut(self.error_compensated))[0]

    @property
    def rms_compensated(self) -> float:
        return _stats(self._cut(self.error_compensated))[1]

    def summary(self) -> str:
        rapid = self.is_rapid
        lines = [f"co-simulation of {self.machine}: {len(self.t)} steps of {self.step:g} s "
                 f"({self.t[-1] + self.step:.3f} s; {int(np.sum(~rapid))} cutting, {int(np.sum(rapid))} on G0 rapids)"]
        for label, mask in (("cutting", ~rapid), ("G0 rapids", rapid)):
            if not mask.any():
                continue
            lines.append(f"  {label}:")
            for name, e in (("tool edge error without compensation", self.error_uncompensated),
                            ("tool edge error with compensation", self.error_compensated),
                            ("  of which servo lag / backlash", self.error_lag),
                            ("  remaining (with compensation - lag)", self.error_remaining)):
                mx, rms = _stats(e[mask])
                lines.append(f"    {name + ':':<39} max {_um(mx)}, RMS {_um(rms)}")
        return "\n".join(lines)

    def default_stride(self, max_rows: int = 10_000) -> int:
        """Row stride of the default (decimated) CSV: at most `max_rows` rows."""
        return max(1, int(np.ceil(len(self.t) / max_rows)))

    def to_csv(self, path, *, full: bool = False, stride: int | None = None) -> Path:
        """The signals as CSV (docs/fmu.md lists the columns): by default every
        `default_stride()`-th step (at most 10 000 rows), every step with full=True."""
        k = 1 if full else int(stride or self.default_stride())
        if k < 1:
            raise InputError(f"CSV row stride must be >= 1, got {k}", field="stride")
        cols = ["t"]
        cols += [f"programmed.{a}" for a in self.axes] + [f"compensated.{a}" for a in self.axes]
        cols += [f"actual.{a}" for a in self.axes]
        for name in ("target", "uncompensated", "compensated", "lag"):
            cols += [f"{name}.{c}" for c in "xyz"]
        cols += ["rapid", "error_uncompensated_um", "error_compensated_um", "error_lag_um"]
        sl = slice(None, None, k)
        data = np.column_stack([self.t, self.q_programmed, self.q_compensated, self.q_actual, self.target,
                                self.p_uncompensated, self.p_compensated, self.p_lag, self.is_rapid.astype(float),
                                self.error_uncompensated * 1e3, self.error_compensated * 1e3,
                                self.error_lag * 1e3])[sl]
        import io
        buf = io.StringIO()
        buf.write(f"# mtcomp co-simulation: mm, deg, s; errors in µm; every {k}. of {len(self.t)} steps "
                  f"of {self.step:g} s\n")
        np.savetxt(buf, data, delimiter=",", header=",".join(cols), comments="", fmt="%.12g")
        return atomic_write(path, buf.getvalue())

    def figure(self) -> Figure:
        """matplotlib Figure (no pyplot, no backend change) of the tool edge error over time, µm:
        with and without compensation (G0 rapids shaded), and the compensated error beside its
        servo lag / backlash part."""
        from matplotlib.figure import Figure
        fig = Figure(figsize=(9, 6), layout="constrained")
        a1, a2 = fig.subplots(2, 1, sharex=True)
        t = self.t + self.step
        rapid = self.is_rapid
        for ax in (a1, a2):
            if rapid.any():   # shade the rapids: their error is not on the part
                edges = np.flatnonzero(np.diff(np.r_[0, rapid.astype(int), 0]))
                for lo, hi in zip(edges[::2], edges[1::2]):
                    ax.axvspan(t[lo], t[hi - 1], color="0.9", lw=0,
                               label="G0 rapid" if lo == edges[0] else None)
            ax.grid(True, alpha=0.3)
        a1.plot(t, self.error_uncompensated * 1e3, color="tab:red", label="without compensation")
        a1.plot(t, self.error_compensated * 1e3, color="tab:blue", label="with compensation")
        a1.set_ylabel("tool edge error (µm)")
        a1.set_title(f"{self.machine}: tool edge error in the workpiece frame")
        a1.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
        a2.plot(t, self.error_compensated * 1e3, color="tab:blue", label="with compensation")
        a2.plot(t, self.error_lag * 1e3, color="k", ls="--", lw=1, label="servo lag / backlash part")
        a2.plot(t, self.error_remaining * 1e3, color="tab:green", lw=1, label="remaining (compensated - lag)")
        a2.set_xlabel("time (s)")
        a2.set_ylabel("error (µm)")
        a2.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
        return fig

    def plot(self, path=None, *, dpi: int = 110) -> Figure:
        """The Figure of `figure()`, written as PNG to `path` (atomically) only when one is given."""
        from .._io import save_figure
        fig = self.figure()
        if path is not None:
            save_figure(fig, path, dpi=dpi)
        return fig


class CosimFailed(MtcompError):
    """An FMU refused a call during the co-simulation (its log message is in the text)."""


def _c_loop(mach, comp, m_in, m_out, c_in, c_out, n, step, q, qc, out):
    """(kernel library, mtk_cosim) for the stepping loop in C (fmu/c/cosim_loop.c), or None
    without the compiled library.  mach or comp may be None (the other FMU alone).  The arrays and
    value-reference arrays (ctypes c_uint arrays) must outlive the loop."""
    import ctypes
    from .. import _kernel
    lib = _kernel.load(quiet=True)
    if lib is None or not hasattr(lib, "mtk_cosim_steps"):
        return None

    def fmi(runner):
        dll = runner.fmu.dll
        comp_ = runner.fmu.component
        return ((comp_.value if hasattr(comp_, "value") else comp_),
                *(ctypes.cast(getattr(dll, f), ctypes.c_void_p).value
                  for f in ("fmi2SetReal", "fmi2GetReal", "fmi2DoStep")))

    s = _kernel.CosimLoop()
    if mach is not None:
        s.mach, s.m_set, s.m_get, s.m_step = fmi(mach)
        s.m_in, s.m_out = ctypes.addressof(m_in), ctypes.addressof(m_out)
    if comp is not None:
        s.comp, s.c_set, s.c_get, s.c_step = fmi(comp)
        s.c_in, s.c_out = ctypes.addressof(c_in), ctypes.addressof(c_out)
    s.n, s.n_out, s.step = n, len(m_out) if m_out is not None else 0, float(step)
    s.q, s.qc, s.out = q.ctypes.data, qc.ctypes.data, out.ctypes.data
    return lib, s


@dataclass(frozen=True)
class MachineRun:
    """What the machine FMU did in one run (K steps): p (K, 3) mm the tool edge in the real
    workpiece frame and actual (K, n) mm/deg the axis positions, both read at the end of step k
    (t_k + step); temperature (K,) degC the machine temperature then; q (K, n) the commands it
    was given; velocity (K, n) mm/s, deg/s the actual axis velocities over each step (the
    FMU's v.<AXIS>: the drive's less its velocity friction)."""
    q: np.ndarray
    p: np.ndarray
    actual: np.ndarray
    temperature: np.ndarray
    velocity: np.ndarray | None = None


def run_machine(machine_fmu, machine, q, step: float, *, spindle_speed=0.0, temperature=None,
                progress=None) -> MachineRun:
    """Drive a machine FMU (built by mtcomp.fmu.build.build_machine_fmu for `machine`) with the
    axis commands q (K, n_axes) mm/deg, one row per communication step of `step` s, and return
    its outputs (MachineRun).

    spindle_speed (1/min) and temperature (degC, the FMU's `temperature_input`, the driver of
    its thermal model with thermal.driver = 1): a number (held) or an array (K,) (row k given
    with the commands at t_k).  The machine-only loop of `cosimulate` (no compensator):
    mtcomp.model.simulate and the model loop run it many times.  Raises CosimFailed with the
    FMU's log message when the FMU refuses a value."""
    machine = load_machine(machine)
    q = np.asarray(q, dtype=float)
    if q.ndim != 2 or q.shape[1] != machine.n_axes or len(q) < 1 or not np.isfinite(q).all():
        raise InputError(f"axis commands must be finite with shape (K, {machine.n_axes}), got {q.shape}",
                         field="q")
    inputs = {}
    for name, v in (("spindle_speed", spindle_speed), ("temperature_input", temperature)):
        if v is None:
            continue
        a = np.asarray(v, dtype=float)
        if a.ndim == 0:
            a = np.full(len(q), float(a))
        if a.shape != (len(q),) or not np.isfinite(a).all():
            raise InputError(f"{name}: expected a finite number or {len(q)} values, got shape {a.shape}",
                             field=name)
        inputs[name] = a
    _, p, act, temp, vel = _run(machine, q, step, machine_fmu, None, inputs, progress, with_temperature=True,
                                with_velocity=True)
    return MachineRun(q, p, act, temp, vel)


def _run(machine: Machine, q: np.ndarray, step: float, mach_path, comp_path, spindle_speed,
         progress=None, with_temperature: bool = False, with_velocity: bool = False):
    """One run; comp_path None: the machine gets the programmed commands.

    spindle_speed: a number (1/min, held), or a dict {machine input name: (K,) array} of
    further machine inputs given row by row with the commands.
    Per step k: set the compensator's inputs to q[k], read its outputs, give them to the machine,
    step both from t_k to t_k + step, then read the machine (no feed-through: its outputs are
    its state at t_k + step).  The loop runs in C (the kernel library's mtk_cosim_steps: the
    FMUs' C functions called through their addresses on the rows of preallocated numpy arrays,
    one ctypes call per progress report) when the machine has no inputs given row by row;
    otherwise, and without the library, the same loop runs in Python with six ctypes calls
    per step (seven with row inputs).
    Returns (commands given to the machine, tool edge, actual positions[, temperature, velocities]);
    with_velocity needs with_temperature."""
    import ctypes
    names = machine.axis_names
    logs: list = []
    K, n = q.shape
    extra = dict(spindle_speed) if isinstance(spindle_speed, dict) else {"spindle_speed": float(spindle_speed)}
    held = {k: float(v) for k, v in extra.items() if np.ndim(v) == 0}
    varying = {k: np.asarray(v, float) for k, v in extra.items() if np.ndim(v) > 0}
    qc = np.empty((K, n))
    p = np.empty((K, 3))
    act = np.empty((K, n))
    mach = comp = None

    def refs(runner, names_):
        return (ctypes.c_uint * len(names_))(*runner.refs(names_))

    def fail(what, k):
        msgs = "; ".join(m for s, _, m in logs if s >= 3)
        raise CosimFailed(f"co-simulation failed at step {k} (t = {k * step:g} s): {what}"
                          + (f" (FMU log: {msgs})" if msgs else ""))

    try:
        mach = FmuRunner(mach_path, "machine", logs)
        comp = FmuRunner(comp_path, "compensator", logs) if comp_path else None
        m_in = refs(mach, [f"command.{a}" for a in names])
        m_out = refs(mach, ["tool.x", "tool.y", "tool.z"] + [f"actual.{a}" for a in names]
                     + (["temperature"] if with_temperature else [])
                     + ([f"v.{a}" for a in names] if with_velocity else []))
        c_in = refs(comp, [f"command.{a}" for a in names]) if comp else None
        c_out = refs(comp, [f"compensated.{a}" for a in names]) if comp else None
        for f in (mach, comp):
            if f:
                f.fmu.enterInitializationMode()
        if comp:
            comp.fmu.setReal(list(c_in), list(q[0]))
            comp.fmu.exitInitializationMode()
        first = comp.fmu.getReal(list(c_out)) if comp else list(q[0])
        mach.fmu.setReal(list(m_in), first)
        mach.set(held)
        mach.set({k: v[0] for k, v in varying.items()})
        mach.fmu.exitInitializationMode()
        n_in = len(varying)
        if n_in:
            m_vin = refs(mach, list(varying))
            vin = np.ascontiguousarray(np.column_stack(list(varying.values())), dtype=np.float64)
            a_vinref, a_vin, vrow = ctypes.addressof(m_vin), vin.ctypes.data, n_in * 8
        # The FMUs read and write the rows of these C-contiguous arrays in place: no copies.
        qin = np.ascontiguousarray(q, dtype=np.float64)
        if comp is None:
            qc[:] = qin
        nout = 3 + n + int(with_temperature) + (n if with_velocity else 0)
        out = np.empty((K, nout))
        row, orow = n * 8, nout * 8
        a_q, a_qc, a_out = qin.ctypes.data, qc.ctypes.data, out.ctypes.data
        a_min, a_mout = ctypes.addressof(m_in), ctypes.addressof(m_out)
        mc, m_set, m_get, m_step = mach.raw()
        if comp:
            cc, c_set, c_get, c_step = comp.raw()
            a_cin, a_cout = ctypes.addressof(c_in), ctypes.addressof(c_out)
        report = max(1, K // 200)
        # the C loop has no row inputs: with them the Python loop runs
        loop = None if n_in else _c_loop(mach, comp, m_in, m_out, c_in, c_out, n, step, qin, qc, out)
        if loop is not None:
            # the same calls in the same order from C, `report` steps per ctypes call
            lib, s = loop
            for k0 in range(0, K, report):
                k1 = min(K, k0 + report)
                bad = lib.mtk_cosim_steps(ctypes.byref(s), k0, k1)
                if bad >= 0:
                    from .._kernel import COSIM_FAILED
                    fail(COSIM_FAILED[bad % 8], bad // 8)
                if progress is not None:
                    progress(k1, K)
        else:  # without the kernel library, or with row inputs: the same loop in Python
            for k in range(K):
                t = k * step
                if comp:
                    if c_set(cc, a_cin, n, a_q + k * row) > 1 or c_get(cc, a_cout, n, a_qc + k * row) > 1:
                        fail("compensator", k)
                if m_set(mc, a_min, n, a_qc + k * row) > 1:
                    fail("machine command", k)
                if n_in and m_set(mc, a_vinref, n_in, a_vin + k * vrow) > 1:
                    fail("machine input", k)
                if comp and c_step(cc, t, step, 1) > 1:
                    fail("compensator step", k)
                if m_step(mc, t, step, 1) > 1 or m_get(mc, a_mout, nout, a_out + k * orow) > 1:
                    fail("machine step", k)
                if progress is not None and (k % report == 0 or k == K - 1):
                    progress(k + 1, K)
        p[:] = out[:, :3]
        act[:] = out[:, 3:3 + n]
        if with_velocity:
            return qc, p, act, out[:, 3 + n].copy(), out[:, 4 + n:4 + 2 * n].copy()
        return (qc, p, act, out[:, 3 + n].copy()) if with_temperature else (qc, p, act)
    except CosimFailed:
        raise
    except Exception as exc:
        msgs = "; ".join(m for s, _, m in logs if s >= 3)
        raise CosimFailed(f"co-simulation failed: {exc}" + (f" (FMU log: {msgs})" if msgs else "")) from None
    finally:
        for f in (comp, mach):
            if f:
                f.close()


def cosimulate(program, machine, true_errors: ErrorSet, identified_errors: ErrorSet | None = None, *,
               step: float = 1e-3, dynamics: _b.MachineDynamics | None = None, rapid: float = 3000.0,
               spindle_speed: float = 0.0, workdir=None, compiler: str = "cmake", progress=None) -> CosimResult:
    """Run NC -> compensator FMU -> machine FMU and, for comparison, NC -> machine FMU.

    program: NC file path or text (interpolated at `step` s honouring the feed), or an array of
    axis commands (K, n_axes) already sampled at `step` (no rapids then).  true_errors: the
    machine's errors (the machine FMU); identified_errors: what the compensator believes
    (default: the true ones).  dynamics: servo/backlash/thermal/noise of the machine FMU
    (default: ideal).  The FMUs are built into `workdir` (default: a temporary folder) with
    `compiler` ("cmake" or "cc"); compiled binaries come from the cache (mtcomp.fmu.build).
    progress: optional callable (done, total) over both runs.
    """
    from ..kinematics import forward
    machine = load_machine(machine)
    identified = true_errors if identified_errors is None else identified_errors
    if isinstance(program, np.ndarray) or (isinstance(program, (list, tuple)) and np.ndim(program) == 2):
        q = np.asarray(program, dtype=float)
        if q.ndim != 2 or q.shape[1] != machine.n_axes or len(q) < 2:
            raise InputError(f"axis command array must have shape (K >= 2, {machine.n_axes}), got {q.shape}",
                             field="program")
        if not np.isfinite(q).all():
            raise InputError("axis command array must be finite", field="program")
        t = np.arange(len(q)) * step
        is_rapid = np.zeros(len(q), bool)
    else:
        t, q, is_rapid = interpolate_program(program, machine, step, rapid=rapid, with_rapid=True)
    K = len(q)

    def part(offset):
        return None if progress is None else (lambda done, total: progress(offset + done, 2 * total))

    tmp = None
    if workdir is None:
        tmp = tempfile.TemporaryDirectory(prefix="mtcomp-cosim-")
        workdir = tmp.name
    workdir = Path(workdir)
    try:
        # built to run here: the host's binary only (a win64 cross-compile, when mingw-w64 is
        # installed, would double the build for a DLL this process cannot load)
        mach_path = _b.build_machine_fmu(machine, workdir / "machine.fmu", true_errors, dynamics, compiler=compiler,
                                         windows=False)
        comp_path = _b.build_compensator_fmu(machine, workdir / "compensator.fmu", identified, compiler=compiler,
                                             windows=False)
        _, p_unc, _ = _run(machine, q, step, mach_path, None, spindle_speed, part(0))
        qc, p_cmp, act = _run(machine, q, step, mach_path, comp_path, spindle_speed, part(K))
    finally:
        if tmp is not None:
            tmp.cleanup()
    target = forward(machine, q).p
    # Error due to the axes not being where commanded: real machine at the actual positions
    # minus real machine at the commanded ones (the core model, thermal drift excluded).
    p_lag = forward(machine, act, true_errors, strict=False).p - forward(machine, qc, true_errors, strict=False).p
    return CosimResult(machine.name, machine.axis_names, t, q, qc, act, target, p_unc, p_cmp, p_lag, step,
                       rapid=is_rapid)
