"""Co-simulate the machine FMU with a base and an updated model; compare both with a recording.

`simulate` runs NC program -> machine FMU (no compensator in the loop: what the machine does
with the programmed commands) and returns the tool edge signals; `write_signals` writes them as
the SIM/REC CSV `mtcomp diagnose` reads, with a provenance sidecar (``<csv>.provenance.toml``:
program, machine, errors, dynamics, step) from which `resimulate` rebuilds the same run with the
fitted parameters.  `resimulate` reports RMS of REC - SIM and REC - updated SIM per output on all
samples and on held-out time blocks, with a figure.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .._io import InputError, atomic_write, dump_toml, parse_toml, read_text
from ..errors import AxisErrorTable, ErrorSet, GeometricErrors, ToolSetting, WorkpieceSetting, load_errors
from ..machine import load_machine
from .floor import INCOMPLETE, floor_of, where_incomplete

OUTPUTS = ("x", "y", "z")
DRIVER_COLUMNS = {"spindle_speed": "spindle_speed [rpm]", "temperature": "temperature [degC]"}


@dataclass(frozen=True)
class Signals:
    """Tool edge signals of one run: t (K,) s, p (K, 3) mm (x, y, z in the real workpiece frame,
    read at the end of each step), q (K, n) programmed axis commands (mm, deg)."""
    t: np.ndarray
    p: np.ndarray
    q: np.ndarray
    axes: tuple
    inputs: dict = field(default_factory=dict)   # driver inputs given per step: "spindle_speed"
                                                 # (1/min), "temperature" (degC), (K,) each
    v: np.ndarray | None = None                  # (K, n) actual axis velocities, mm/s or deg/s
                                                 # (the FMU's v.<AXIS>, over each step)

    def output(self, name: str) -> np.ndarray:
        """(K,) values of one output: x, y, z (tool edge, mm) or v<AXIS> (velocity_output)."""
        if name in OUTPUTS:
            return self.p[:, OUTPUTS.index(name)]
        ax = velocity_axis(name, self.axes)
        if ax is None or self.v is None:
            raise InputError(f"no output {name!r} in the simulation (x, y, z"
                             + (", " + ", ".join(f"v{a}" for a in self.axes) if self.v is not None else "") + ")",
                             field="outputs")
        return self.v[:, list(self.axes).index(ax)]


def velocity_output(axis: str) -> str:
    """Name of the actual-velocity output of an axis in the signal CSVs: v<AXIS> (``vX``, ``vC``),
    a velocity column to the diagnosis (unit in the header: mm/s, deg/s)."""
    return f"v{axis}"


def velocity_axis(name: str, axes) -> str | None:
    """The axis of a velocity output v<AXIS> (None for any other name)."""
    return name[1:] if len(name) > 1 and name[0] == "v" and name[1:] in tuple(axes) else None


def simulate(program, machine, errors: ErrorSet | None = None, dynamics=None, *, step: float = 1e-3,
             spindle_speed=0.0, temperature=None, workdir=None, compiler: str = "cmake") -> Signals:
    """Run the NC program (path, text, or (K, n) command array) through the machine FMU built
    with `errors` and `dynamics` (mtcomp.fmu.build.MachineDynamics) at `step` s; the machine
    gets the programmed commands (the uncompensated run of mtcomp.fmu.cosim.cosimulate).

    spindle_speed (1/min) and temperature (degC, the FMU's temperature_input): a number, an
    array with one value per step, or a callable of the step times t (K,) s; given as arrays
    (or callables) they are drivers the recording logs, kept in Signals.inputs and written as
    columns by signals_csv."""
    import tempfile

    from ..fmu.build import build_machine_fmu
    from ..fmu.cosim import interpolate_program, run_machine
    machine = load_machine(machine)
    errors = errors or ErrorSet()
    # the machine-only run of mtcomp.fmu.cosim.cosimulate (its uncompensated run, the same
    # stepping loop): cosimulate would also run the compensated loop, half the time of each of
    # the many re-simulations of prune, refine and the compensation co-simulations
    if isinstance(program, np.ndarray) or (isinstance(program, (list, tuple)) and np.ndim(program) == 2):
        q = np.asarray(program, dtype=float)
        if q.ndim != 2 or q.shape[1] != machine.n_axes or len(q) < 2 or not np.isfinite(q).all():
            raise InputError(f"axis command array must be finite with shape (K >= 2, {machine.n_axes}), "
                             f"got {q.shape}", field="program")
        t = np.arange(len(q)) * step
    else:
        t, q = interpolate_program(program, machine, step)
    with tempfile.TemporaryDirectory(prefix="mtcomp-sim-") as tmp:
        wd = Path(workdir) if workdir is not None else Path(tmp)
        # run here: the host's binary only, no win64 cross-compile
        mach = build_machine_fmu(machine, wd / "machine.fmu", errors, dynamics, compiler=compiler, windows=False)
        drivers = {}
        for name, v in (("spindle_speed", spindle_speed), ("temperature", temperature)):
            if callable(v):
                v = v(t)
            if v is not None and np.ndim(v) > 0:
                drivers[name] = np.asarray(v, float)
        run = run_machine(mach, machine, q, step, spindle_speed=drivers.get("spindle_speed", spindle_speed),
                          temperature=drivers.get("temperature", temperature))
    return Signals(t, run.p, q, tuple(machine.axis_names), drivers, run.velocity)


def signals_csv(sig: Signals, machine, velocities=()) -> str:
    """CSV text: t (s), x, y, z (mm); the programmed angles of rotary axes (deg, lower-case
    letters) as inputs for the diagnosis (pivot offsets follow them); velocities: axes whose
    actual velocity is written too, as v<AXIS> [mm/s] or [deg/s] (a velocity output)."""
    machine = load_machine(machine)
    cols = ["t"] + list(OUTPUTS)
    data = [sig.t] + [sig.p[:, k] for k in range(3)]
    for a in velocities:
        ax = machine.axes[machine.axis_names.index(a)]
        cols.append(f"{velocity_output(a)} [{'deg' if ax.is_rotary else 'mm'}/s]")
        data.append(sig.output(velocity_output(a)))
    for i, ax in enumerate(machine.axes):
        if ax.is_rotary:
            cols.append(ax.name.lower())
            data.append(sig.q[:, i])
    for name, v in sig.inputs.items():     # logged drivers of the thermal drift
        cols.append(DRIVER_COLUMNS[name])
        data.append(v)
    arr = np.column_stack(data)
    lines = [",".join(cols)] + [",".join(repr(float(v)) for v in row) for row in arr]
    return "\n".join(lines) + "\n"


def _rel(path, base: Path) -> str:
    import os
    return os.path.relpath(os.path.abspath(path), os.path.abspath(base))


def write_signals(path, sig: Signals, machine, *, program=None, errors_path=None, dynamics=None,
                  step: float, spindle_speed=0.0, velocities=()) -> Path:
    """Write the signals CSV and its provenance sidecar `<path>.provenance.toml` (paths in it
    relative to its folder; the dynamics inline).  machine: preset name, machine TOML path (kept
    as a path) or Machine (kept by name: give the path to keep a machine file)."""
    path = Path(path)
    spec = machine
    machine = load_machine(machine)
    atomic_write(path, signals_csv(sig, machine, velocities))
    is_file = isinstance(spec, (str, Path)) and Path(spec).is_file()
    prov: dict = {"machine": _rel(spec, path.parent) if is_file else machine.name, "step_s": float(step)}
    if np.ndim(spindle_speed) == 0 and not callable(spindle_speed):
        prov["spindle_speed_rpm"] = float(spindle_speed)
    if sig.inputs:   # logged drivers: columns of the CSV itself, given to the FMU step by step
        prov["driver_columns"] = [DRIVER_COLUMNS[k] for k in sig.inputs]
    if program is not None and Path(str(program)).is_file():
        prov["program"] = _rel(program, path.parent)
    if errors_path is not None:
        prov["errors"] = _rel(errors_path, path.parent)
    if dynamics is not None:
        d = asdict(dynamics)
        prov["dynamics"] = {k: (list(v) if isinstance(v, tuple) else v) for k, v in d.items() if v is not None}
    atomic_write(provenance_path(path), "# provenance of a simulated signal file (docs/model-loop.md)\n"
                 + dump_toml({"simulation": prov}))
    return path


def provenance_path(csv_path) -> Path:
    p = Path(csv_path)
    return p.with_name(p.name + ".provenance.toml")


@dataclass(frozen=True)
class Provenance:
    """How a SIM file was made: program path, machine, errors (ErrorSet), dynamics
    (MachineDynamics), step (s), spindle speed (1/min: a number, or (K,) per step from the CSV's
    driver column), temperature input ((K,) degC or None)."""
    program: Path | None
    machine: object
    errors: ErrorSet
    dynamics: object
    step: float
    spindle_speed: object
    temperature: object = None


def read_provenance(csv_path) -> Provenance:
    from ..fmu.build import MachineDynamics
    path = provenance_path(csv_path)
    if not path.is_file():
        raise InputError(f"no provenance sidecar {path.name} next to the simulation file: give --program, "
                         "--machine, --step (and --errors) instead", csv_path)
    d = parse_toml(read_text(path, what="provenance file"), path).get("simulation")
    if not isinstance(d, dict) or "machine" not in d or "step_s" not in d:
        raise InputError("expected a table [simulation] with machine and step_s", path, field="simulation")
    mpath = path.parent / str(d["machine"])
    machine = load_machine(mpath if mpath.is_file() else d["machine"])
    errors = load_errors(path.parent / d["errors"], machine=machine) if "errors" in d else ErrorSet()
    dyn = MachineDynamics(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in d.get("dynamics", {}).items()})
    prog = path.parent / d["program"] if "program" in d else None
    spindle, temp = float(d.get("spindle_speed_rpm", 0.0)), None
    if d.get("driver_columns"):
        from ..csvtable import read_csv
        tab = read_csv(csv_path, what="simulation")
        cols = [str(c) for c in d["driver_columns"]]
        if DRIVER_COLUMNS["spindle_speed"] in cols:
            spindle = tab.numbers("spindle_speed", unit="rpm")
        if DRIVER_COLUMNS["temperature"] in cols:
            temp = tab.numbers("temperature", unit="degC")
    return Provenance(prog, machine, errors, dyn, float(d["step_s"]), spindle, temp)


def read_recording(path) -> tuple:
    """(t (K,) s, {output: (K,) mm or mm/s, deg/s}) of a CSV with t and x/y/z columns (units
    from the header) and velocity outputs v<AXIS> [mm/s] or [deg/s] (signals_csv)."""
    from ..csvtable import read_csv
    tab = read_csv(path, what="recording", required=("t",))
    t = tab.numbers("t", unit="s")
    out = {}
    for o in OUTPUTS:
        try:
            out[o] = tab.numbers(o, unit="mm")
        except (InputError, KeyError):
            continue
    for c in tab.columns:
        if c.name.startswith("v") and len(c.name) > 1 and c.name[1:].isupper() and c.unit in ("mm/s", "deg/s"):
            out[c.name] = tab.numbers(c.name, unit=c.unit)
    if not out:
        raise InputError("expected tool edge columns x, y and/or z", path)
    return t, out


# ---------------------------------------------------------------- composition with a base model

def combine_errors(base: ErrorSet, fitted: ErrorSet, machine) -> ErrorSet:
    """The base errors plus the fitted ones (the diagnosis fits what the base lacked): setting
    offsets and angles add (small angles), location errors add, tables add on the fitted table's
    grid (the base table must cover it)."""
    tool = np.add(base.tool.offset, fitted.tool.offset)
    tr = np.add(base.workpiece.translation, fitted.workpiece.translation)
    ang = np.add(base.workpiece.angles, fitted.workpiece.angles)
    loc = dict(base.geometric.location)
    for k, v in fitted.geometric.location.items():
        loc[k] = loc.get(k, 0.0) + v
    tables = dict(base.geometric.tables)
    for ax, t in fitted.geometric.tables.items():
        if ax in tables:
            b = tables[ax]
            vals = {k: np.asarray(v, float).copy() for k, v in t.values.items()}
            for k, v in b.values.items():
                add = np.interp(t.position, b.position, np.asarray(v, float))
                vals[k] = vals.get(k, 0.0) + add
            tables[ax] = AxisErrorTable(ax, t.position, vals, source="base + diagnosis")
        else:
            tables[ax] = t
    return ErrorSet(ToolSetting(tuple(tool)), WorkpieceSetting(tuple(tr), tuple(ang)), GeometricErrors(tables, loc))


# ---------------------------------------------------------------- re-simulation

@dataclass(frozen=True)
class ResimResult:
    """REC against the original and the updated model.

    t (K,) s on REC's clock; rec, sim, updated: {output: (K,) mm}; blocks: the time blocks
    ((t0, t1) s); rms: {"before"|"after": {output: mm}} over all samples; heldout_rms: the same
    over the held-out samples (t >= heldout_from s, or all when None); block_rms:
    {"before"|"after": {output: [mm per block]}}."""
    t: np.ndarray
    rec: dict
    sim: dict
    updated: dict
    rms: dict
    heldout_rms: dict
    block_rms: dict
    blocks: tuple
    heldout_from: float | None
    noise_floor: dict = field(default_factory=dict)
    floor: dict = field(default_factory=dict)        # {output: floor.Floor}
    incomplete: dict = field(default_factory=dict)   # {output: where the excess is} above 3x the floor
    notes: tuple = ()                                # drivers used, effects not re-simulated

    def ratio(self, o: str) -> float:
        """Held-out RMS of REC - updated model over the floor of output o (nan without a floor)."""
        fl = self.floor.get(o)
        return self.heldout_rms["after"][o] / fl.total if fl is not None and fl.total > 0 else float("nan")

    def summary(self) -> str:
        lines = ["re-simulation with the diagnosed model: RMS of REC - model"
                 + (f" (held out: t >= {self.heldout_from:g} s)" if self.heldout_from is not None else "")]
        for o in self.rec:
            f = _um if o in OUTPUTS else _velocity_formatter(o)
            fl = self.floor.get(o)
            nfs = ""
            if fl is not None:
                nfs = (f"; floor {f(fl.total)} (noise {f(fl.noise)} from {fl.noise_source}, quantisation "
                       f"{f(fl.quantisation)}, resampling {f(fl.interpolation)}): {self.ratio(o):.2f}x")
            lines.append(f"  {o}: original {f(self.rms['before'][o])} -> updated {f(self.rms['after'][o])}; "
                         f"held out {f(self.heldout_rms['before'][o])} -> {f(self.heldout_rms['after'][o])}"
                         + nfs)
        lines += [f"  {n}" for n in self.notes]
        for o, where in self.incomplete.items():
            lines.append(f"  MODEL INCOMPLETE on {o}: the re-simulated residual is {self.ratio(o):.1f}x its floor "
                         f"(above {INCOMPLETE:g}x); {where}")
        if self.floor and not self.incomplete:
            lines.append(f"  every output within {INCOMPLETE:g}x its floor")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {"rms": self.rms, "heldout_rms": self.heldout_rms, "block_rms": self.block_rms,
                "blocks": [list(b) for b in self.blocks], "heldout_from": self.heldout_from,
                "noise_floor": self.noise_floor, "floor": {o: f.to_dict() for o, f in self.floor.items()},
                "ratio_to_floor": {o: self.ratio(o) for o in self.floor}, "incomplete": self.incomplete,
                "notes": list(self.notes)}

    def figure(self):
        """REC - original model (left) and REC - updated model (right) per output over time, in
        µm, each with its own scale and its held-out RMS (a matplotlib.figure.Figure; the
        held-out span shaded)."""
        from matplotlib.figure import Figure
        outs = list(self.rec)
        fig = Figure(figsize=(11, 2.1 * len(outs) + 0.8), layout="constrained")
        axs = fig.subplots(len(outs), 2, sharex=True, squeeze=False)
        for row, o in enumerate(outs):
            for col, (key, model, color, what) in enumerate((("before", self.sim, "tab:red", "original model"),
                                                             ("after", self.updated, "tab:blue", "updated model"))):
                ax = axs[row, col]
                # positions in µm, velocity outputs (v<AXIS>) in µm/s, or mdeg/s on a rotary axis
                ax.plot(self.t, (self.rec[o] - model[o]) * 1e3, lw=0.6, color=color)
                if self.heldout_from is not None:
                    ax.axvspan(self.heldout_from, self.t[-1], color="0.9", zorder=0)
                f = _um if o in OUTPUTS else _velocity_formatter(o)
                ax.set_title(f"{o}: REC - {what}, held-out RMS {f(self.heldout_rms[key][o])}", fontsize=9)
                ax.set_ylabel(f"{o} error [µm]" if o in OUTPUTS else
                              f"{o} error [{'mdeg/s' if _is_rotary_velocity(o) else 'µm/s'}]")
        for ax in axs[-1]:
            ax.set_xlabel("t [s]" + ("  (shaded: held out)" if self.heldout_from is not None else ""))
        return fig

    def plot(self, path):
        from .._io import atomic_path
        fig = self.figure()
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=110, format="png")
        return fig


def _um(x) -> str:
    if x is None or not math.isfinite(x):
        return "n/a"
    return f"{x * 1e6:.3g} nm" if abs(x) < 1e-4 else f"{x * 1e3:.3g} µm"


def _is_rotary_velocity(name: str) -> bool:
    """True for the velocity output of a rotary axis (vA, vB, vC: deg/s)."""
    return len(name) == 2 and name[0] == "v" and name[1].upper() in "ABC"


def _mm_s(x) -> str:
    """A linear velocity (mm/s) for the reports: µm/s below 0.1 mm/s."""
    if x is None or not math.isfinite(x):
        return "n/a"
    return f"{x * 1e3:.3g} µm/s" if abs(x) < 0.1 else f"{x:.3g} mm/s"


def _deg_s(x) -> str:
    """An angular velocity (deg/s) for the reports: mdeg/s below 0.1 deg/s."""
    if x is None or not math.isfinite(x):
        return "n/a"
    return f"{x * 1e3:.3g} mdeg/s" if abs(x) < 0.1 else f"{x:.3g} deg/s"


def _velocity_formatter(name: str):
    return _deg_s if _is_rotary_velocity(name) else _mm_s


def _rms(a) -> float:
    a = np.asarray(a, float)
    return float(np.sqrt(np.mean(a * a))) if a.size else float("nan")


def compare(t_rec, rec: dict, sim: Signals, updated: Signals, *, heldout_from: float | None = None,
            n_blocks: int = 5, noise_floor: dict | None = None, notes=()) -> ResimResult:
    """Interpolate both models onto REC's times (REC is assumed on the simulation's clock) and
    report the RMS of REC - model per output, beside each output's floor (floor.Floor: noise,
    REC's quantisation, the resampling) and, above 3x the floor, where the model falls short."""
    t_rec = np.asarray(t_rec, float)
    keep = (t_rec >= sim.t[0]) & (t_rec <= sim.t[-1])
    if keep.sum() < 2:
        raise InputError("the recording and the simulation do not overlap in time", field="t")
    t = t_rec[keep]
    r = {o: np.asarray(v, float)[keep] for o, v in rec.items()}
    s = {o: np.interp(t, sim.t, sim.output(o)) for o in r}
    u = {o: np.interp(t, updated.t, updated.output(o)) for o in r}
    edges = np.linspace(t[0], t[-1], n_blocks + 1)
    blocks = tuple((float(a), float(b)) for a, b in zip(edges[:-1], edges[1:]))
    held = np.ones(len(t), bool) if heldout_from is None else t >= heldout_from
    rms = {"before": {o: _rms(r[o] - s[o]) for o in r}, "after": {o: _rms(r[o] - u[o]) for o in r}}
    hrms = {"before": {o: _rms((r[o] - s[o])[held]) for o in r},
            "after": {o: _rms((r[o] - u[o])[held]) for o in r}}
    idx = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, n_blocks - 1)
    brms = {k: {o: [_rms((r[o] - m[o])[idx == b]) for b in range(n_blocks)] for o in r}
            for k, m in (("before", s), ("after", u))}
    nf = dict(noise_floor or {})
    floors = {o: floor_of(t, r[o], updated.t, updated.output(o), nf.get(o)) for o in r}
    incomplete = {o: where_incomplete(t[held], (r[o] - u[o])[held], floors[o].total) for o in r
                  if floors[o].total > 0 and hrms["after"][o] > INCOMPLETE * floors[o].total}
    return ResimResult(t, r, s, u, rms, hrms, brms, blocks, heldout_from, nf, floors, incomplete, tuple(notes))


def _updated_model(model, machine, base_err, base_dyn, combine, skipped=None):
    from .dynamics import apply_dynamics, load_dynamics
    from .identity import check_model_machine
    if hasattr(model, "dynamics_values"):
        if model.machine != machine.name:
            raise InputError(f"the model was exported for machine {model.machine}, not for {machine.name}: "
                             "the re-simulation refuses to apply one machine's model to another", field="machine")
        fit_err, fit_dyn = model.errors, model.dynamics_values
    else:
        d = Path(model)
        check_model_machine(d, machine, what="the re-simulation")
        fit_err = load_errors(d / "errors.toml", machine=machine)
        fit_dyn = load_dynamics(d / "dynamics.toml", machine)
    if skipped:
        from .drivers import without
        fit_dyn = without(fit_dyn, skipped)
    new_err = combine_errors(base_err, fit_err, machine) if combine else fit_err
    return new_err, apply_dynamics(base_dyn, fit_dyn, machine, combine=combine)


def model_dynamics_values(model, machine) -> dict:
    """{FMU parameter: value} of the model's dynamics (a ModelExport or a model folder)."""
    from .dynamics import load_dynamics
    if hasattr(model, "dynamics_values"):
        return dict(model.dynamics_values)
    p = Path(model) / "dynamics.toml"
    return load_dynamics(p, machine) if p.is_file() else {}


def _training_residual(model, t_rec, rec, keep_t, *, program, machine, base_err, base_dyn, step, spindle_speed,
                       nf, compiler, temperature=None):
    """Stacked (REC - re-simulation) / noise floor on the training samples."""
    e, d = _updated_model(model, machine, base_err, base_dyn, True)
    sig = simulate(program, machine, e, d, step=step, spindle_speed=spindle_speed, temperature=temperature,
                   compiler=compiler)
    keep = keep_t & (t_rec >= sig.t[0]) & (t_rec <= sig.t[-1])
    parts = []
    for o, v in rec.items():
        m = np.interp(t_rec[keep], sig.t, sig.output(o))
        parts.append((np.asarray(v, float)[keep] - m) / (nf.get(o) or 1.0))
    return np.concatenate(parts)


def _score(model, t_rec, rec, mask, *, program, machine, base_err, base_dyn, step, spindle_speed, temperature,
           nf, compiler) -> float:
    """Sum over outputs of mean square (REC - re-simulation) / noise floor^2 on the samples of
    `mask` (a (K,) bool over REC's times)."""
    e, d = _updated_model(model, machine, base_err, base_dyn, True)
    sig = simulate(program, machine, e, d, step=step, spindle_speed=spindle_speed, temperature=temperature,
                   compiler=compiler)
    keep = mask & (t_rec >= sig.t[0]) & (t_rec <= sig.t[-1])
    tot = 0.0
    for o, v in rec.items():
        m = np.interp(t_rec[keep], sig.t, sig.output(o))
        tot += float(np.mean((np.asarray(v, float)[keep] - m) ** 2)) / (nf.get(o) or 1.0) ** 2
    return tot


def _split(t_rec, train_until):
    """(fit mask, validation mask, cut): the samples before train_until (all without it) split
    at 70 % of their span: the fit sees the first part, the later part judges it.  The samples
    from train_until on stay unseen by both, so the reported held-out error stays honest."""
    t_rec = np.asarray(t_rec, float)
    end = float(t_rec[-1]) + 1.0 if train_until is None else float(train_until)
    cut = float(t_rec[0]) + 0.7 * (min(end, float(t_rec[-1])) - float(t_rec[0]))
    return t_rec < cut, (t_rec >= cut) & (t_rec < end), cut


def refine(ex, t_rec, rec: dict, *, program, machine, errors=None, dynamics=None, step: float,
           spindle_speed=0.0, train_until: float | None = None, noise_floor: dict | None = None,
           compiler: str = "cmake", stride: int = 1, log: list | None = None, temperature=None):
    """Refit the exported scalar parameters (kv, backlash, location and setting errors) through
    the machine model itself: nonlinear least squares of REC - re-simulation on the training
    samples (t < train_until), each evaluation a co-simulation of the FMU, started from the
    diagnosis' values and scaled by their sigmas.  Tables keep the diagnosis' values.

    Why: the diagnosis fits its own effect models; where they differ from the FMU's physics
    (a servo lag seen with a latency the model has no home for) its values are biased for the
    model.  The refitted sigmas are the least-squares covariance scaled by the residual
    variance.  stride: use every n-th training sample (speed).  The fit uses the first 70 %
    of the training span; the refit is returned only when it lowers the error on the rest
    (`_split`), else `ex` itself (logged: "refine rejected")."""
    from dataclasses import replace

    from scipy.optimize import least_squares

    from ..fmu.build import MachineDynamics
    machine = load_machine(machine)
    # thermal.driver is a choice, not a number; thermal.gain is the scale the drift is written in
    # (only gain * drift enters a spindle-driven drift);
    # velfriction.vs is the diagnosis' convention (2 % of SIM's peak speed), not a fitted value
    params = [p for p in ex.params if p.type == "Real" and p.name != "thermal.gain"
              and not p.name.startswith("velfriction.vs.")]
    if not params:
        return ex
    base_err = errors or ErrorSet()
    base_dyn = replace(dynamics or MachineDynamics(), noise=0.0)
    t_rec = np.asarray(t_rec, float)
    train, held, cut = _split(t_rec, train_until)
    keep_t = np.zeros(len(t_rec), bool)
    keep_t[::max(1, int(stride))] = True
    keep_t &= train
    nf = dict(noise_floor or {})
    x0 = np.array([p.value for p in params])
    scale = np.array([p.sigma if p.sigma and math.isfinite(p.sigma) and p.sigma > 0 else max(abs(p.value), 1e-9) * 1e-3
                      for p in params])
    nonneg = ("servo.kv.", "backlash.", "friction.", "glitch.time.", "delay", "thermal.gain", "encoder.period.")
    # a negative backlash (over-compensated: the FMU's mirrored play) keeps the FMU's range
    lo = np.array([1e-3 if p.name == "thermal.time_constant" else -1.0 if p.name.startswith("backlash.") and p.value < 0
                   else 0.0 if p.name.startswith(nonneg) else -np.inf for p in params])

    def model_at(z):
        return ex.with_values({p.name: float(v) for p, v in zip(params, x0 + z * scale)})

    def fun(z):
        return _training_residual(model_at(z), t_rec, rec, keep_t, program=program, machine=machine,
                                  base_err=base_err, base_dyn=base_dyn, step=step, spindle_speed=spindle_speed,
                                  nf=nf, compiler=compiler, temperature=temperature)
    zlo = np.where(np.isfinite(lo), (lo - x0) / scale, -np.inf)
    sol = least_squares(fun, np.zeros(len(params)), bounds=(zlo, np.inf), diff_step=1e-3, x_scale=1.0,
                        max_nfev=20 * (len(params) + 1))
    J = sol.jac
    dof = max(1, len(sol.fun) - len(params))
    s2 = float(sol.fun @ sol.fun) / dof
    try:
        cov = np.linalg.inv(J.T @ J) * s2
        sig = np.sqrt(np.clip(np.diag(cov), 0, None)) * scale
    except np.linalg.LinAlgError:
        sig = np.full(len(params), np.nan)
    vals = x0 + sol.x * scale
    out = ex.with_values({p.name: float(v) for p, v in zip(params, vals)},
                         {p.name: float(s) for p, s in zip(params, sig)})
    # accepted only when it lowers the error on samples the fit did not see: a refit that
    # chases the training noise or a structural mismatch (backlash 2.67 -> 14.2 µm) is refused
    kw = dict(program=program, machine=machine, base_err=base_err, base_dyn=base_dyn, step=step,
              spindle_speed=spindle_speed, temperature=temperature, nf=nf, compiler=compiler)
    before, after = _score(ex, t_rec, rec, held, **kw), _score(out, t_rec, rec, held, **kw)
    if not after < before:
        if log is not None:
            log.append(f"refine rejected: the validation error (t >= {cut:g} s, not fitted) would rise from {before:.4g} "
                       f"to {after:.4g}; the diagnosis' values kept")
        return ex
    if log is not None:
        for p, v, s in zip(params, vals, sig):
            log.append(f"refined {p.name}: {p.value:.6g} -> {v:.6g} +/- {s:.2g} {p.unit}")
        log.append(f"refine accepted: validation error (t >= {cut:g} s, not fitted) {before:.4g} -> {after:.4g}")
    return out


def prune(ex, t_rec, rec: dict, *, program, machine, errors=None, dynamics=None, step: float,
          spindle_speed=0.0, train_until: float | None = None, noise_floor: dict | None = None,
          compiler: str = "cmake", log: list | None = None, temperature=None):
    """Backward elimination through the machine model itself: drop each exported effect (last
    first) whose removal does not raise the error of the re-simulation on the first 70 % of the
    training samples (t < train_until; all when None), sum over outputs of mean square / noise
    floor^2; then put back each dropped effect that lowers the error on the other 30 %.

    Why: the diagnosis fits its own effect models to REC - SIM; where they differ from the
    machine model's physics (e.g. the FMU's servo holds the command over each step), it can add
    small compensating effects (a scale or pitch error riding on a servo lag) that the machine
    model, which now has the real physics, does not need and is hurt by.  Returns the pruned
    ModelExport; `log` (a list) receives one line per decision."""
    from dataclasses import replace

    from ..fmu.build import MachineDynamics
    machine = load_machine(machine)
    base_err = errors or ErrorSet()
    base_dyn = replace(dynamics or MachineDynamics(), noise=0.0)
    t_rec = np.asarray(t_rec, float)
    nf = dict(noise_floor or {})
    train, held, _ = _split(t_rec, train_until)
    kw = dict(program=program, machine=machine, base_err=base_err, base_dyn=base_dyn, step=step,
              spindle_speed=spindle_speed, temperature=temperature, nf=nf, compiler=compiler)

    def score(model, mask=train):
        return _score(model, t_rec, rec, mask, **kw)

    keep = list(range(len(ex.mapped)))
    current = score(ex)
    for i in reversed(range(len(ex.mapped))):
        trial = [k for k in keep if k != i]
        sc = score(ex.subset(trial))
        m = ex.mapped[i]
        if sc <= current:
            keep, current = trial, sc
            if log is not None:
                log.append(f"dropped {m.effect} on {m.output}: training error {sc:.4g} without it (was higher with it)")
        elif log is not None:
            log.append(f"kept {m.effect} on {m.output}: training error rises to {sc:.4g} without it (from {current:.4g})")
    if len(keep) < len(ex.mapped) and held.any():
        # never drop an effect the samples the elimination did not see keep: each dropped one
        # is put back when it lowers the validation error (a real 4 µm backlash was dropped on
        # the fitted samples alone)
        h_cur = score(ex.subset(keep), held)
        for i in range(len(ex.mapped)):
            if i in keep:
                continue
            trial = sorted(keep + [i])
            h = score(ex.subset(trial), held)
            if h < h_cur:
                keep, h_cur = trial, h
                if log is not None:
                    m = ex.mapped[i]
                    log.append(f"put back {m.effect} on {m.output}: the validation error falls to {h:.4g} with it")
    return ex.subset(keep) if len(keep) < len(ex.mapped) else ex


def resimulate(model, rec, *, program, machine, errors: ErrorSet | None = None, dynamics=None,
               step: float, spindle_speed=0.0, heldout_from: float | None = None,
               combine: bool = True, workdir=None, compiler: str = "cmake", noise_floor: dict | None = None,
               temperature=None, rec_drivers: dict | None = None):
    """Rebuild the machine FMU with the fitted parameters and re-run the co-simulation.

    model: a ModelExport or the folder `mtcomp model export` wrote.  rec: REC CSV path or
    (t, {output: values}).  program/machine/errors/dynamics/step: what made the original SIM
    (errors and dynamics the base model).  The recording's sensor noise is not re-simulated:
    both runs use the base dynamics with noise 0.  Drivers (spindle speed, temperature): REC's
    columns (a REC path; or rec_drivers {driver: (column, t, values)} with an in-memory REC)
    before SIM's (spindle_speed, temperature); a thermal drift whose driver is in neither is
    left out and named in the result's notes (mtcomp.model.drivers).  Returns (ResimResult, original Signals,
    updated Signals)."""
    from dataclasses import replace

    from ..fmu.build import MachineDynamics
    from .drivers import resolve
    machine = load_machine(machine)
    base_err = errors or ErrorSet()
    base_dyn = replace(dynamics or MachineDynamics(), noise=0.0)
    _updated_model(model, machine, base_err, base_dyn, combine)     # refuses another machine's model first
    t_rec, rec_v = read_recording(rec) if isinstance(rec, (str, Path)) else rec
    drv = resolve(model_dynamics_values(model, machine), sim_spindle=spindle_speed, sim_temperature=temperature,
                  rec=rec if isinstance(rec, (str, Path)) else rec_drivers)
    new_err, new_dyn = _updated_model(model, machine, base_err, base_dyn, combine, drv.skipped)
    kw = dict(step=step, spindle_speed=drv.spindle_speed, temperature=drv.temperature, compiler=compiler)
    sim = simulate(program, machine, base_err, base_dyn, workdir=None if workdir is None else Path(workdir) / "base", **kw)
    upd = simulate(program, machine, new_err, new_dyn,
                   workdir=None if workdir is None else Path(workdir) / "updated", **kw)
    notes = drv.notes + tuple(not_in_model(model))
    return compare(t_rec, rec_v, sim, upd, heldout_from=heldout_from, noise_floor=noise_floor, notes=notes), sim, upd


def not_in_model(model) -> list:
    """Report lines for the diagnosed effects the model has no home for (not re-simulated)."""
    if hasattr(model, "unmapped"):
        return [f"{e.get('name')} on {e.get('output')}: NOT re-simulated ({why})" for e, why in model.unmapped]
    p = Path(model) / "model.toml"
    if not p.is_file():
        return []
    data = parse_toml(read_text(p, what="model manifest"), p)
    return [f"{e.get('name')} on {e.get('output')}: NOT re-simulated ({e.get('reason', e.get('status'))})"
            for e in data.get("effect", []) if isinstance(e, dict) and e.get("status") != "in the model"]
