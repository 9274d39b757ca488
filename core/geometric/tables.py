"""Component error tables from interferometer runs, with the set-up Abbe contributions removed.

A measurement set is one run per component error of each linear axis (positioning EXX,
straightness EYX and EZX, angular EAX, EBX, ECX for axis X, and so on), each in the ISO 230-2 run
format (target, cycle, direction, deviation; deviation in mm or rad), with the position of the
measuring point (reflector, straightness optic) relative to the tool tip: paper 004's set-up
coordinates P (positioning), H and V (straightness).  Squareness comes from pairs of
straightness runs made against the same optical square (paper 004's pentaprism), or is given.

The build (`build_tables`), per axis i, with every run evaluated by its mean bidirectional
deviation (ISO 230-2) and zeroed at the datum position (0):

1. angular components ε_i(s) from the angular runs;
2. translational components δ_i(s) = reading(s) − ε_i(s) × ℓ(s) (first order, formula 10 of
   paper 004 in vector form), ℓ = tool point + set-up offset + Σ_{j>i} q_j u_j − c_i (+ s u_i for
   a table axis) the lever arm from the axis' reference point c_i to the measuring point;
3. straightness: the least-squares line is removed (its slope belongs to the set-up alignment
   and the squareness); the slopes of two runs against one optical square add up to the
   squareness of the pair, independent of how the square was aligned.

The file format of a measurement set is in docs/geometric.md.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .._io import InputError, atomic_write, dump_toml, load_toml
from ..errors import AxisErrorTable, ErrorSet, GeometricErrors, component_names
from ..machine import Machine, load_machine
from . import iso230_2
from .first_order import measured_feed
from .iso230_2 import PositioningRun

__all__ = ["ComponentRun", "MeasurementSet", "Setup", "Noise", "BuildResult", "build_tables",
           "simulate_runs", "load_measurement_set", "save_measurement_set", "SQUARENESS_PAIRS"]

_LIN = "XYZ"
# Squareness names (ISO 230-1) of the axis pairs: the later axis of the pair is tilted.
SQUARENESS_PAIRS = {("X", "Y"): "EC0Y", ("X", "Z"): "EB0Z", ("Y", "Z"): "EA0Z"}


@dataclass(frozen=True)
class ComponentRun:
    """One interferometer run of one component error.

    axis: moving axis ("X"); component: ISO 230-1 name read by the run ("EXX", "EYX", "EAX"...);
    run: the readings in the tool-relative-to-workpiece sense (deviation in mm for E[XYZ]?, rad
    for E[ABC]?); mount: "tool" -- the moving optic sits on the spindle side at `offset` from the
    tool tip (tool frame) and the reference optic on the table -- or "workpiece" -- the moving
    optic sits on the table at `offset` from the workpiece origin and the reference optic on the
    bed (paper 004's arrangement for the table, formula 10; workpiece-side axes only); square:
    label shared by the two straightness runs made against one optical square (e.g. "XY"), ""
    if none; at: positions (mm) of the other axes during the run (default 0).
    """
    axis: str
    component: str
    run: PositioningRun
    offset: tuple = (0.0, 0.0, 0.0)
    square: str = ""
    at: dict = field(default_factory=dict)
    mount: str = "tool"


@dataclass(frozen=True)
class MeasurementSet:
    """All runs of one machine, plus location errors measured otherwise (ISO names, rad)."""
    machine: str
    runs: tuple
    location: dict = field(default_factory=dict)
    source: str | None = None

    def run(self, component: str) -> ComponentRun | None:
        for r in self.runs:
            if r.component == component:
                return r
        return None


@dataclass(frozen=True)
class BuildResult:
    """Tables built from a measurement set.

    errors: the ErrorSet (geometric part only); iso: ISO 230-2 results of the positioning runs
    by axis; slopes: least-squares slopes (mm/mm) removed from the Abbe-corrected straightness
    runs by component; squareness: how each squareness was obtained; notes: what was assumed;
    uncertainty: 1-sigma (mm or rad) of every table value (component -> (M,)) and squareness
    (name -> float) propagated to first order from the scatter of the cycles (the standard error
    of each mean bidirectional deviation, including the datum's, and the angular runs' through
    the Abbe arms); reversal and systematic effects of the set-up are not in it.
    """
    errors: ErrorSet
    iso: dict
    slopes: dict
    squareness: dict
    notes: tuple
    uncertainty: dict = field(default_factory=dict)

    @property
    def geometric(self) -> GeometricErrors:
        return self.errors.geometric

    def reversal(self) -> dict:
        """{axis: ReversalTable}: the per-direction mean deviations of each positioning run,
        which the (bidirectional-mean) tables leave out; see `mtcomp.geometric.reversal`."""
        from .reversal import reversal_table
        return {a: reversal_table(r) for a, r in self.iso.items()}

    def summary(self) -> str:
        g = self.geometric
        lines = ["Component error tables (tool relative to workpiece, ISO 230-1 names)"]
        for ax, t in g.tables.items():
            lines.append(f"  axis {ax}: {t.position.size} positions {t.position[0]:g} .. "
                         f"{t.position[-1]:g} mm")
            for name in component_names(ax):
                v = t.values.get(name)
                if v is None:
                    continue
                unit, scale = ("µm", 1e3) if name[1] in _LIN else ("µrad", 1e6)
                lines.append(f"    {name}: {v.min() * scale:9.3f} .. {v.max() * scale:9.3f} {unit}")
                u = self.uncertainty.get(name)
                if u is not None:
                    lines[-1] += f"   (1 sigma up to {np.max(u) * scale:.3f} {unit})"
            if ax in self.iso:
                r = self.iso[ax]
                lines.append(f"    ISO 230-2 of the positioning run: A = {r.A * 1e3:.3f} µm, "
                             f"B = {r.B * 1e3:.3f} µm (mean reversal {r.B_mean * 1e3:+.3f} µm: the table holds the "
                             f"bidirectional mean, the reversal table the rest), R = {r.R * 1e3:.3f} µm")
        for name, v in g.location.items():
            u = self.uncertainty.get(name)
            su = f" +- {u * 1e6:.3f}" if u is not None else ""
            lines.append(f"  {name} = {v * 1e6:.3f}{su} µrad ({self.squareness.get(name, 'given')})")
        for n in self.notes:
            lines.append(f"  note: {n}")
        return "\n".join(lines) + "\n"


def _lever(machine: Machine, run: ComponentRun, s: np.ndarray) -> np.ndarray:
    """Abbe arms (N,3) mm from the axis' reference point, where it is at positions s, to the
    measuring point (first order: nominal geometry).  A tool-side reference point rides with
    the tool-side chain, a table's with the table, hence the table's own travel in its arm."""
    i = machine.index(run.axis)
    ax = machine.axis(run.axis)
    if run.mount == "workpiece":
        # a point fixed on the table and the table's own reference point: a constant arm
        arm = np.asarray(run.offset, float) - np.asarray(ax.location, float)
        return np.broadcast_to(arm, (s.size, 3))
    p = np.asarray(machine.tool_point, float) + np.asarray(run.offset, float)
    for other in machine.axes[i + 1:]:
        p = p + float(run.at.get(other.name, 0.0)) * np.asarray(other.direction, float)
    lever = np.broadcast_to(p - np.asarray(ax.location, float), (s.size, 3))
    if ax.side == "workpiece":
        lever = lever + s[:, None] * np.asarray(ax.direction, float)[None, :]
    return lever


def _profile(run: ComponentRun, datum: float, where: str, grid: np.ndarray | None = None):
    """(targets, mean bidirectional deviation zeroed at the datum, its 1-sigma) of a run."""
    t = run.run.target
    if not (t[0] - 1e-9 <= datum <= t[-1] + 1e-9):
        raise InputError(f"run of {run.component} covers {t[0]:g} .. {t[-1]:g}, not the datum "
                         f"position {datum:g}", where, field=run.component)
    if grid is not None and (t[0] > grid[0] + 1e-9 or t[-1] < grid[-1] - 1e-9):
        raise InputError(f"run of {run.component} covers {t[0]:g} .. {t[-1]:g} mm, less than the "
                         f"positioning run's {grid[0]:g} .. {grid[-1]:g} mm", where,
                         field=run.component)
    res = iso230_2.evaluate(run.run)
    v = res.mean_bi
    n = run.run.n_cycles
    sig = 0.5 * np.sqrt((res.s_up**2 + res.s_down**2) / n)
    sig0 = np.interp(datum, t, sig)
    # zeroing subtracts the (independent) datum value; at the datum itself it is exact
    sig = np.sqrt(sig**2 + sig0**2) * (np.abs(t - datum) > 1e-9)
    return t, v - np.interp(datum, t, v), sig


def build_tables(machine: Machine | str, mset: MeasurementSet, datum: float = 0.0) -> BuildResult:
    """ISO 230-1 component tables and squareness of every linear axis from a measurement set.

    Positions of every table are the targets of that axis' positioning run; the other runs of
    the axis are interpolated onto them (linearly) when their targets differ.  A missing angular
    run is taken as zero and a missing straightness run too (both noted), a missing positioning
    run is an error.
    """
    machine = load_machine(machine)
    where = mset.source or "<measurement set>"
    notes: list[str] = []
    tables, iso, slopes, sq_how, unc = {}, {}, {}, {}, {}
    straight_slopes: dict[str, tuple[float, str, float]] = {}
    known = {r.component for r in mset.runs}
    for r in mset.runs:
        if r.axis not in machine.axis_names or machine.axis(r.axis).is_rotary:
            raise InputError(f"run of {r.component}: machine {machine.name} has no linear axis "
                             f"{r.axis}", where, field=r.component)
        if r.mount not in ("tool", "workpiece"):
            raise InputError(f"mount must be 'tool' or 'workpiece', got {r.mount!r}", where,
                             field=r.component)
        if r.mount == "workpiece" and machine.axis(r.axis).side != "workpiece":
            raise InputError(f"run of {r.component}: a workpiece-mounted optic moves only with a "
                             f"workpiece-side axis; {r.axis} is on the tool side", where,
                             field=r.component)
    for ax in machine.axes:
        if ax.is_rotary:
            continue
        a = ax.name
        names = component_names(a)
        pos_run = mset.run(f"E{a}{a}")
        if not any(n in known for n in names):
            continue
        if pos_run is None:
            raise InputError(f"no positioning run E{a}{a} for axis {a}", where, field=f"E{a}{a}")
        grid = pos_run.run.target
        iso[a] = iso230_2.evaluate(pos_run.run)
        eps = np.zeros((grid.size, 3))
        eps_sig = np.zeros((grid.size, 3))
        for c, d in enumerate("ABC"):
            r = mset.run(f"E{d}{a}")
            if r is None:
                notes.append(f"no run of E{d}{a}: taken as zero")
                continue
            t, v, sg = _profile(r, datum, where, grid)
            eps[:, c] = np.interp(grid, t, v)
            eps_sig[:, c] = np.interp(grid, t, sg)
            unc[f"E{d}{a}"] = eps_sig[:, c]
        values = {f"E{d}{a}": eps[:, c] for c, d in enumerate("ABC")}
        for c, d in enumerate(_LIN):
            name = f"E{d}{a}"
            r = mset.run(name)
            if r is None:
                notes.append(f"no run of {name}: taken as zero")
                values[name] = np.zeros(grid.size)
                continue
            t, v, sg = _profile(r, datum, where, grid)
            reading = np.interp(grid, t, v)
            lever = _lever(machine, r, grid)
            # the set-up's Abbe contribution ε × ℓ removed (formula 10), component d of the reading
            delta = measured_feed(reading[:, None] * np.eye(3)[c], lever, eps)[:, c]
            # its sensitivity to each angle c': (e_c' × ℓ)_d
            sens = np.stack([np.cross(np.eye(3)[k], lever)[:, c] for k in range(3)], axis=1)
            sig = np.sqrt(np.interp(grid, t, sg) ** 2 + np.sum((sens * eps_sig) ** 2, axis=1))
            if d != a:
                slope, icpt = np.polyfit(grid, delta, 1)
                delta = delta - (slope * grid + icpt)
                delta = delta - np.interp(datum, grid, delta)
                slopes[name] = float(slope)
                # standard error of a least-squares slope with independent errors sig
                xc = grid - grid.mean()
                slope_sig = float(np.sqrt(np.sum((xc / np.sum(xc**2)) ** 2 * sig**2)))
                if r.square:
                    straight_slopes[name] = (float(slope), r.square, slope_sig)
            values[name] = delta
            unc[name] = sig
        tables[a] = AxisErrorTable(a, grid, values, source=where)
    location = {}
    for (i, j), name in SQUARENESS_PAIRS.items():
        if i not in tables or j not in tables:
            continue
        a, b = f"E{j}{i}", f"E{i}{j}"  # i moving read in j, j moving read in i
        if a in straight_slopes and b in straight_slopes and \
                straight_slopes[a][1] == straight_slopes[b][1]:
            S = straight_slopes[a][0] + straight_slopes[b][0]
            k = ({"X", "Y", "Z"} - {i, j}).pop()
            ek, ui, uj = (np.eye(3)[_LIN.index(x)] for x in (k, i, j))
            # Tilt of axis j about k whose i-component of the motion slope equals S.
            location[name] = float(S / (np.cross(ek, uj) @ ui))
            unc[name] = float(np.hypot(straight_slopes[a][2], straight_slopes[b][2]))
            sq_how[name] = f"optical square {straight_slopes[a][1]!r}: runs {a} and {b}"
            if name in mset.location:
                notes.append(f"{name} is given in the set and measured with the optical square: "
                             "the measured value is used")
        elif name in mset.location:
            location[name] = float(mset.location[name])
            sq_how[name] = "given in the measurement set"
        else:
            notes.append(f"no squareness for {name} (no straightness pair against one optical "
                         f"square, none given): taken as zero")
    for name, v in mset.location.items():
        if name not in location:
            location[name] = float(v)
            sq_how[name] = "given in the measurement set"
    geo = GeometricErrors(tables, location)
    return BuildResult(ErrorSet(geometric=geo), iso, slopes, sq_how, tuple(notes), unc)


# --------------------------------------------------------------------------- simulation

@dataclass(frozen=True)
class Setup:
    """Where the optics sat: measuring point relative to the tool tip (mm, tool frame) per run.

    offsets: component name -> (3,) offset; `default` for the others.  Paper 004 calls them P
    (positioning), H and V (horizontal and vertical straightness).  mounts: component name ->
    "tool" or "workpiece" (see ComponentRun; default "tool").  square_angles: misalignment (rad)
    of the optical square used for each axis pair, about the third axis; it must drop out.
    """
    offsets: dict = field(default_factory=dict)
    default: tuple = (0.0, 0.0, 0.0)
    square_angles: dict = field(default_factory=dict)
    mounts: dict = field(default_factory=dict)

    def offset(self, component: str) -> tuple:
        return tuple(self.offsets.get(component, self.default))

    @classmethod
    def typical(cls, seed: int = 0) -> "Setup":
        """Offsets of 40..150 mm as on a real set-up, random square misalignments up to 1 mrad."""
        rng = np.random.default_rng(seed)
        offs = {}
        for a in _LIN:
            for d in _LIN:
                off = rng.uniform(-150, 150, 3)
                off[_LIN.index(a)] = 0.0  # along the motion an offset changes nothing
                offs[f"E{d}{a}"] = tuple(float(x) for x in off)
        sq = {"".join(p): float(rng.uniform(-1e-3, 1e-3)) for p in SQUARENESS_PAIRS}
        return cls(offs, (0.0, 0.0, 0.0), sq)


@dataclass(frozen=True)
class Noise:
    """Reading noise (1 sigma) per reading, and the reversal (backlash) of positioning runs.

    linear mm (positioning), straightness mm, angular rad, reversal mm (positive-direction
    readings +reversal/2, negative −reversal/2).
    """
    linear: float = 0.0
    straightness: float = 0.0
    angular: float = 0.0
    reversal: float = 0.0


def _small_rotation(R: np.ndarray) -> np.ndarray:
    """Rotation vector (N,3) of rotation matrices near the identity (exact for the skew part)."""
    return 0.5 * np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0],
                           R[:, 1, 0] - R[:, 0, 1]], axis=1)


def simulate_runs(machine: Machine | str, truth: ErrorSet, setup: Setup = Setup(),
                  noise: Noise = Noise(), step: float = 10.0, cycles: int = 5,
                  seed: int = 0) -> MeasurementSet:
    """Simulate interferometer runs of all 18 components on a machine with errors `truth`.

    Each run moves one axis (the others at 0) to the targets lo, lo + step, ..., hi, `cycles`
    times in each direction.  The reading is taken with the exact model (`kinematics.forward`)
    at the set-up's measuring point: the translation of that point relative to the workpiece
    along one machine axis, or the rotation of the tool relative to the workpiece, each relative
    to the first target (the interferometer is zeroed there), with the straightness optic's
    misalignment and the noise added.
    """
    from ..kinematics import chain, forward
    from .synthetic import run_positions

    machine = load_machine(machine)
    rng = np.random.default_rng(seed)
    runs = []
    for i, ax in enumerate(machine.axes):
        if ax.is_rotary:
            continue
        a = ax.name
        t = run_positions(ax, step)
        q = np.zeros((t.size, machine.n_axes))
        q[:, i] = t
        nominal = forward(machine, q).p
        ws = replace(machine, axes=tuple(x for x in machine.axes if x.side == "workpiece"))
        for name in component_names(a):
            d = name[1]
            off = setup.offset(name)
            mount = setup.mounts.get(name, "tool")
            if mount == "workpiece":
                if ax.side != "workpiece":
                    raise ValueError(f"{name}: a workpiece-mounted optic needs a workpiece-side axis")
                # the table point `off` seen from the bed, b = R^T (w - t), against its nominal
                # path; in the tool-relative sense the reading is minus its displacement
                qw = q[:, [k for k, x in enumerate(machine.axes) if x.side == "workpiece"]]
                Rw, tw = chain(ws, qw, truth)
                _, tn = chain(ws, qw)
                b = np.einsum("nji,nj->ni", Rw, np.asarray(off)[None, :] - tw)
                point = np.asarray(off)[None, :] - b      # tool-relative displacement, real
                point_nom = tn
                R_rel = Rw
            else:
                mach = replace(machine, tool_point=tuple(np.asarray(machine.tool_point) + off))
                pose = forward(mach, q, truth)
                point, point_nom, R_rel = pose.p, nominal + np.asarray(off)[None, :], pose.R
            square = ""
            if d in _LIN:
                c = _LIN.index(d)
                reading = point[:, c] - point_nom[:, c]
                sigma = noise.linear if d == a else noise.straightness
                if d != a:
                    pair = "".join(sorted(a + d))
                    square = pair
                    k = ({"X", "Y", "Z"} - set(pair)).pop()
                    ek = np.eye(3)[_LIN.index(k)]
                    u = np.asarray(ax.direction, float)
                    th = setup.square_angles.get(pair, 0.0)
                    # Reference line of the square turned by th about k: reading drops by the
                    # line's own slope (d-component of th ek × u) times the position.
                    reading = reading - th * np.cross(ek, u)[c] * t
            else:
                c = "ABC".index(d)
                reading = _small_rotation(R_rel)[:, c]
                sigma = noise.angular
            reading = reading - reading[0]
            up = reading[None, :] + rng.normal(0.0, 1.0, (cycles, t.size)) * sigma
            dn = reading[None, :] + rng.normal(0.0, 1.0, (cycles, t.size)) * sigma
            if d == a:
                up, dn = up + 0.5 * noise.reversal, dn - 0.5 * noise.reversal
            run = PositioningRun(t, up, dn, axis=a, source=name)
            runs.append(ComponentRun(a, name, run, tuple(float(x) for x in off), square,
                                     mount=mount))
    return MeasurementSet(machine.name, tuple(runs))


# --------------------------------------------------------------------------- files

def save_measurement_set(mset: MeasurementSet, path: str | os.PathLike) -> Path:
    """Write a measurement set: TOML index at `path` and one ISO 230-2 CSV per run next to it."""
    path = Path(path)
    data: dict = {"machine": mset.machine, "run": []}
    for r in mset.runs:
        name = f"{path.stem}_{r.component}.csv"
        atomic_write(path.parent / name, iso230_2.run_to_csv(r.run))
        entry = {"axis": r.axis, "component": r.component, "file": name,
                 "offset": [float(x) for x in r.offset]}
        if r.square:
            entry["square"] = r.square
        if r.at:
            entry["at"] = {k: float(v) for k, v in r.at.items()}
        if r.mount != "tool":
            entry["mount"] = r.mount
        data["run"].append(entry)
    if mset.location:
        data["location"] = {k: float(v) for k, v in mset.location.items()}
    head = ("# mtcomp measurement set (docs/geometric.md): one ISO 230-2 run file per component;\n"
            "# deviations in mm (E[XYZ]*) or rad (E[ABC]*), offsets in mm from the tool tip\n")
    return atomic_write(path, head + dump_toml(data))


def load_measurement_set(path: str | os.PathLike) -> MeasurementSet:
    """Read a measurement set TOML (run files are relative to its folder)."""
    path = Path(path)
    data = load_toml(path)
    unknown = set(data) - {"machine", "run", "location"}
    if unknown:
        raise InputError(f"unknown keys {sorted(unknown)}; expected machine, run, location", path)
    machine = data.get("machine")
    if not isinstance(machine, str):
        raise InputError("expected a machine preset name or file", path, field="machine")
    raw = data.get("run")
    if not isinstance(raw, list) or not raw:
        raise InputError("expected at least one [[run]] table", path, field="run")
    runs, seen = [], set()
    for k, r in enumerate(raw):
        f = f"run[{k}]"
        if not isinstance(r, dict):
            raise InputError(f"expected a [[run]] table (axis, component, file, ...), got {r!r:.40}", path,
                             field=f)
        unknown = set(r) - {"axis", "component", "file", "offset", "square", "at", "mount"}
        if unknown:
            raise InputError(f"unknown keys {sorted(unknown)}", path, field=f)
        comp = r.get("component")
        ax = r.get("axis")
        if not isinstance(ax, str) or ax not in _LIN:
            raise InputError(f"axis must be X, Y or Z, got {ax!r}", path, field=f"{f}.axis")
        if comp not in component_names(ax):
            raise InputError(f"component must be one of {', '.join(component_names(ax))}, got "
                             f"{comp!r}", path, field=f"{f}.component")
        if comp in seen:
            raise InputError(f"second run of {comp}", path, field=f"{f}.component")
        seen.add(comp)
        file = r.get("file")
        if not isinstance(file, str) or not file.strip():
            raise InputError(f"expected the run file name, got {file!r}", path, field=f"{f}.file")
        if not (path.parent / file).is_file():
            what = "a directory" if (path.parent / file).is_dir() else "not found"
            raise InputError(f"run file {file!r} is {what} (names are relative to the set's folder)", path,
                             field=f"{f}.file")
        off = r.get("offset", [0.0, 0.0, 0.0])
        try:
            if not isinstance(off, list) or any(isinstance(x, bool) for x in off):
                raise TypeError
            off = tuple(float(x) for x in off)
        except (TypeError, ValueError, OverflowError):   # OverflowError: an integer beyond float range
            off = ()
        if len(off) != 3 or not np.all(np.isfinite(off)):
            raise InputError(f"offset must be 3 numbers in mm, got {r.get('offset')!r}", path,
                             field=f"{f}.offset")
        square = r.get("square", "")
        if not isinstance(square, str):
            raise InputError("square must be a label string", path, field=f"{f}.square")
        at = r.get("at", {})
        if not isinstance(at, dict) or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                               and np.isfinite(v) for v in at.values()):
            raise InputError("at must map axis names to positions in mm", path, field=f"{f}.at")
        mount = r.get("mount", "tool")
        if mount not in ("tool", "workpiece"):
            raise InputError(f"mount must be 'tool' or 'workpiece', got {mount!r}", path,
                             field=f"{f}.mount")
        # angular components (EAX, EBX, ...) are in rad, the others in mm
        run = iso230_2.read_run_csv(path.parent / file, axis=ax,
                                    unit="rad" if comp[1] in "ABC" else "mm")
        runs.append(ComponentRun(ax, comp, run, off, square, {k: float(v) for k, v in at.items()},
                                 mount))
    loc = data.get("location", {})
    if not isinstance(loc, dict) or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                            and np.isfinite(v) for v in loc.values()):
        raise InputError("location must map ISO names (e.g. EC0Y) to values in rad", path,
                         field="location")
    return MeasurementSet(machine, tuple(runs), {k: float(v) for k, v in loc.items()}, str(path))
