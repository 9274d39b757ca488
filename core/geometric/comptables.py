"""Compensation of geometric errors: corrected commands and the tables controllers take.

Three forms, all from the same error model:

* corrected commands from `mtcomp.kinematics.retarget` (the iterative inverse of the exact model)
  -- what a rewritten NC program carries (the `mtcomp compensate` command rewrites programs with
  an errors file written by `save_errors`);
* a 3-D lattice of command corrections (like Fanuc's 3-D error compensation): at every node of
  a regular grid the correction to add to the programmed axis positions, trilinearly
  interpolated in between (`LatticeTable`);
* ISO 230-1-named component tables, one CSV per axis (position, EXX, EYX, EZX, EAX, EBX, ECX in
  mm and rad) and one of the squareness errors, as volumetric-compensation options read them
  (`write_iso_tables`).  A controller that evaluates the same kinematic model with them
  compensates like `retarget` does.

The residual error after compensation (`residuals`) is the exact model's tool position under
the *true* errors at the corrected commands, minus the programmed position.
"""
from __future__ import annotations

import io
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._io import InputError, atomic_write
from ..errors import AxisErrorTable, ErrorSet, GeometricErrors
from ..machine import Machine, load_machine
from .volumetric import volume_grid

__all__ = ["extend_tables", "corrected_commands", "LatticeTable", "lattice_table",
           "write_iso_tables", "residuals", "CompensationReport", "compensation_report"]


def extend_tables(errors: ErrorSet, by: float = 1.0) -> ErrorSet:
    """The same errors with every table held constant for `by` mm beyond both ends.

    Compensated commands at the end of the travel lie a few µm outside it, where the tables
    (and a controller's, which holds the end value) must still give a value.
    """
    g = errors.geometric
    tables = {}
    for ax, t in g.tables.items():
        pos = np.concatenate([[t.position[0] - by], t.position, [t.position[-1] + by]])
        vals = {k: np.concatenate([[v[0]], v, [v[-1]]]) for k, v in t.values.items()}
        tables[ax] = AxisErrorTable(ax, pos, vals)
    return ErrorSet(errors.tool, errors.workpiece, GeometricErrors(tables, dict(g.location)))


def corrected_commands(machine: Machine | str, errors: ErrorSet, q_programmed,
                       round_result: bool = False) -> np.ndarray:
    """Commands (N, n) that put the tool where the ideal machine would put it for q_programmed,
    under `errors` (tables extended by 1 mm at the ends; no travel check at the very limits)."""
    from ..kinematics import retarget
    machine = load_machine(machine)
    return retarget(machine, np.atleast_2d(np.asarray(q_programmed, float)), extend_tables(errors),
                    round_result=round_result, check=False)


@dataclass(frozen=True)
class LatticeTable:
    """3-D lattice compensation: command corrections (mm) at the nodes of a regular grid.

    axes: axis names; nodes: node positions per axis (mm); correction: (n1, n2, n3, 3) amounts
    to add to the programmed positions of the three axes at each node.
    """
    axes: tuple
    nodes: tuple
    correction: np.ndarray

    def interpolate(self, q) -> np.ndarray:
        """Trilinear interpolation of the corrections at commands q (N,3); q outside the lattice
        is clamped to it (the controller holds the boundary values)."""
        from scipy.interpolate import RegularGridInterpolator
        q = np.atleast_2d(np.asarray(q, float))
        qc = np.column_stack([np.clip(q[:, i], n[0], n[-1]) for i, n in enumerate(self.nodes)])
        f = RegularGridInterpolator(self.nodes, self.correction, method="linear")
        return f(qc)

    def apply(self, q) -> np.ndarray:
        q = np.atleast_2d(np.asarray(q, float))
        return q + self.interpolate(q)

    def to_csv(self) -> str:
        """CSV: header comments (axes, node counts, origin and spacing), then one row per node:
        i,j,k, node position (mm), corrections d<axis> (mm); k runs fastest."""
        buf = io.StringIO()
        a = self.axes
        buf.write("# mtcomp 3-D lattice compensation table: add d<axis> (mm) to the programmed "
                  "positions; trilinear between nodes\n")
        for name, n in zip(a, self.nodes):
            step = np.diff(n)
            buf.write(f"# axis {name}: {n.size} nodes from {float(n[0])!r} to {float(n[-1])!r} mm, spacing "
                      f"{float(step.mean())!r} mm\n")
        buf.write(",".join(["i", "j", "k", *a, *(f"d{x}" for x in a)]) + "\n")
        n1, n2, n3 = (n.size for n in self.nodes)
        for i in range(n1):
            for j in range(n2):
                for k in range(n3):
                    pos = (self.nodes[0][i], self.nodes[1][j], self.nodes[2][k])
                    c = self.correction[i, j, k]
                    buf.write(f"{i},{j},{k}," + ",".join(repr(float(v)) for v in (*pos, *c)) + "\n")
        return buf.getvalue()

    @classmethod
    def from_csv(cls, path: str | os.PathLike) -> "LatticeTable":
        """Read a lattice written by `to_csv` (nodes from the rows, any regular grid)."""
        path = Path(path)
        try:
            lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
        except FileNotFoundError:
            raise InputError("file not found", path) from None
        rows = [(n, ln) for n, ln in enumerate(lines, 1) if ln.strip() and not ln.startswith("#")]
        if len(rows) < 2:
            raise InputError("empty lattice table", path)
        hdr = rows[0][1].split(",")
        if len(hdr) != 9 or hdr[:3] != ["i", "j", "k"]:
            raise InputError("header must be i,j,k,<3 axes>,d<3 axes>", path, rows[0][0])
        axes = tuple(hdr[3:6])
        data = []
        for n, ln in rows[1:]:
            cells = ln.split(",")
            if len(cells) != 9:
                raise InputError(f"expected 9 values, got {len(cells)}", path, n)
            vals = []
            for name, x in zip(hdr, cells):
                try:
                    vals.append(float(x))
                except ValueError:
                    raise InputError(f"expected a number, got {x.strip()!r}", path, n, field=name.strip()) from None
            data.append(vals)
        d = np.array(data)
        idx = d[:, :3].astype(int)
        shape = tuple(idx.max(axis=0) + 1)
        if np.prod(shape) != len(d):
            raise InputError(f"incomplete lattice: {len(d)} rows for {shape} nodes", path)
        corr = np.full(shape + (3,), np.nan)
        corr[idx[:, 0], idx[:, 1], idx[:, 2]] = d[:, 6:9]
        nodes = []
        for c in range(3):
            pos = np.full(shape[c], np.nan)
            pos[idx[:, c]] = d[:, 3 + c]
            nodes.append(pos)
        if np.isnan(corr).any():
            raise InputError("lattice rows repeat a node and miss another", path)
        return cls(axes, tuple(nodes), corr)


def lattice_table(machine: Machine | str, errors: ErrorSet, step: float | tuple = 50.0) -> LatticeTable:
    """Lattice of command corrections over the whole travel, nodes every `step` mm (the travel
    ends are nodes), from the exact model's inverse at each node."""
    machine = load_machine(machine)
    if machine.n_axes != 3 or machine.n_rotary:
        raise ValueError("the 3-D lattice table is for 3-axis machines with linear axes")
    q = volume_grid(machine, step)
    nodes = tuple(np.unique(q[:, i]) for i in range(3))
    corr = corrected_commands(machine, errors, q) - q
    shape = tuple(n.size for n in nodes)
    return LatticeTable(machine.axis_names, nodes, corr.reshape(shape + (3,)))


def write_iso_tables(geometric: GeometricErrors, directory: str | os.PathLike,
                     prefix: str = "comp") -> list[Path]:
    """One CSV per axis (<prefix>_<axis>.csv: position, E?<axis> columns in mm and rad) and
    <prefix>_location.csv (name,value: squareness and other location errors in rad or mm)."""
    d = Path(directory)
    out = [atomic_write(d / f"{prefix}_{ax}.csv", t.to_csv()) for ax, t in geometric.tables.items()]
    text = ("# ISO 230-1 location errors (squareness in rad, positions in mm)\nname,value\n"
            + "".join(f"{k},{v!r}\n" for k, v in geometric.location.items()))
    out.append(atomic_write(d / f"{prefix}_location.csv", text))
    return out


def residuals(machine: Machine | str, truth: ErrorSet, q_programmed, q_commanded) -> np.ndarray:
    """Tool-tip error (N,3) mm of the real machine (`truth`) at the commanded positions, relative
    to the programmed (ideal) tool position."""
    from ..kinematics import forward
    machine = load_machine(machine)
    return (forward(machine, q_commanded, extend_tables(truth)).p
            - forward(machine, q_programmed).p)


@dataclass(frozen=True)
class CompensationReport:
    """Max and RMS (mm) of |tool-tip error| over the evaluation points for each method."""
    n_points: int
    figures: dict       # method -> (max, rms)
    lattice_step: float

    def summary(self) -> str:
        lines = [f"Tool-tip error over {self.n_points} points of the work volume"]
        for k, (mx, rms) in self.figures.items():
            lines.append(f"  {k:<34s} max {mx * 1e3:9.4f} µm   RMS {rms * 1e3:9.4f} µm")
        return "\n".join(lines) + "\n"


def compensation_report(machine: Machine | str, truth: ErrorSet, model: ErrorSet,
                        lattice: LatticeTable | None = None, q=None, n_random: int = 5000,
                        step: float = 25.0, seed: int = 0) -> CompensationReport:
    """Residual error without compensation, with model-based compensation (`model` tables,
    exact inverse) and with the lattice, at the grid points (every `step` mm) plus `n_random`
    random points of the travel (between lattice nodes, where interpolation errs most)."""
    machine = load_machine(machine)
    if q is None:
        rng = np.random.default_rng(seed)
        lo = np.array([a.limits[0] for a in machine.axes])
        hi = np.array([a.limits[1] for a in machine.axes])
        q = np.vstack([volume_grid(machine, step), lo + (hi - lo) * rng.random((n_random, machine.n_axes))])
    q = np.atleast_2d(np.asarray(q, float))

    def fig(r):
        m = np.linalg.norm(r, axis=1)
        return float(m.max()), float(np.sqrt(np.mean(m**2)))
    figures = {"uncompensated": fig(residuals(machine, truth, q, q)),
               "model-based (corrected commands)": fig(
                   residuals(machine, truth, q, corrected_commands(machine, model, q)))}
    lstep = float("nan")
    if lattice is not None:
        figures["3-D lattice (trilinear)"] = fig(residuals(machine, truth, q, lattice.apply(q)))
        lstep = float(np.mean(np.diff(lattice.nodes[0])))
    return CompensationReport(len(q), figures, lstep)
