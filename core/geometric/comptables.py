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
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._io import InputError, atomic_write
from ..errors import AxisErrorTable, ErrorSet, GeometricErrors
from ..machine import Machine, load_machine
from .reversal import direction_terms
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
    reversal: dict = field(default_factory=dict)   # {axis: ReversalTable}: direction-dependent part

    def interpolate(self, q) -> np.ndarray:
        """Trilinear interpolation of the corrections at commands q (N,3); q outside the lattice
        is clamped to it (the controller holds the boundary values)."""
        from scipy.interpolate import RegularGridInterpolator
        q = np.atleast_2d(np.asarray(q, float))
        qc = np.column_stack([np.clip(q[:, i], n[0], n[-1]) for i, n in enumerate(self.nodes)])
        f = RegularGridInterpolator(self.nodes, self.correction, method="linear")
        return f(qc)

    def apply(self, q, directions=None) -> np.ndarray:
        """Corrected commands for q (N,3); with reversal tables, each row also corrected for the
        direction it is approached in: directions (N,3) of +1 / -1 per axis (default +1)."""
        q = np.atleast_2d(np.asarray(q, float))
        out = q + self.interpolate(q)
        return out + direction_terms(self.axes, self.reversal, q, directions, -1.0)

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
        """Read a lattice written by `to_csv` (nodes from the rows, any regular grid; format in
        docs/geometric.md, read by `mtcomp.csvtable`).  Every node appears once; all rows of one
        node index give the same position, and positions grow with the index.  Errors name the
        file, line and column."""
        from ..csvtable import read_csv
        tab = read_csv(path, what="lattice table", min_rows=1)
        names = tab.names
        if len(names) != 9 or names[:3] != ("i", "j", "k") or names[6:] != tuple(f"d{a}" for a in names[3:6]):
            raise tab.error("header must be i,j,k,<3 axes>,d<3 axes> (e.g. i,j,k,X,Y,Z,dX,dY,dZ), got "
                            + ",".join(c.header for c in tab.columns))
        axes = names[3:6]
        idx = np.column_stack([[tab.integer(r, c, lo=0, hi=10**6) for r in range(len(tab))]
                               for c in ("i", "j", "k")])
        pos = np.column_stack([tab.numbers(a, unit="mm") for a in axes])
        corr_rows = np.column_stack([tab.numbers(f"d{a}", unit="mm") for a in axes])
        shape = tuple(int(v) for v in idx.max(axis=0) + 1)
        if int(np.prod(shape)) != len(tab):
            raise InputError(f"incomplete lattice: {len(tab)} rows for {' x '.join(map(str, shape))} = "
                             f"{int(np.prod(shape))} nodes (i, j, k from 0)", tab.source)
        flat = np.ravel_multi_index(idx.T, shape)
        order = np.argsort(flat, kind="stable")
        rep = np.nonzero(np.diff(flat[order]) == 0)[0]
        if rep.size:
            r = int(order[rep[0] + 1])
            raise tab.error(f"node ({', '.join(map(str, idx[r]))}) appears twice (also line "
                            f"{tab.lines[int(order[rep[0]])]})", r, "i")
        corr = np.empty(shape + (3,))
        corr[idx[:, 0], idx[:, 1], idx[:, 2]] = corr_rows
        nodes = []
        for c, a in enumerate(axes):
            node = np.full(shape[c], np.nan)
            first = np.full(shape[c], -1)
            for r in range(len(tab)):   # every row of one index must agree on its position
                i = idx[r, c]
                if first[i] < 0:
                    node[i], first[i] = pos[r, c], r
                elif abs(pos[r, c] - node[i]) > 1e-9 * max(1.0, abs(node[i])):
                    raise tab.error(f"node {names[c]} = {i} is at {node[i]!r} mm on line "
                                    f"{tab.lines[first[i]]}, here at {pos[r, c]!r} mm", r, tab.columns[3 + c].header)
            if np.any(np.diff(node) <= 0):
                i = int(np.argmax(np.diff(node) <= 0)) + 1
                raise tab.error(f"{a} nodes must grow with {names[c]}: {names[c]} = {i} is at {node[i]!r} mm, "
                                f"{names[c]} = {i - 1} at {node[i - 1]!r} mm", int(first[i]),
                                tab.columns[3 + c].header)
            nodes.append(node)
        return cls(axes, tuple(nodes), corr)


def lattice_table(machine: Machine | str, errors: ErrorSet, step: float | tuple = 50.0,
                  reversal: dict | None = None) -> LatticeTable:
    """Lattice of command corrections over the whole travel, nodes every `step` mm (the travel
    ends are nodes), from the exact model's inverse at each node.  reversal: {axis:
    ReversalTable} kept beside it (the lattice holds the bidirectional mean; controls apply the
    direction-dependent part as bidirectional pitch tables, `ReversalTable.fanuc_pitch`)."""
    machine = load_machine(machine)
    if machine.n_axes != 3 or machine.n_rotary:
        raise ValueError("the 3-D lattice table is for 3-axis machines with linear axes")
    q = volume_grid(machine, step)
    nodes = tuple(np.unique(q[:, i]) for i in range(3))
    corr = corrected_commands(machine, errors, q) - q
    shape = tuple(n.size for n in nodes)
    return LatticeTable(machine.axis_names, nodes, corr.reshape(shape + (3,)), dict(reversal or {}))


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


def residuals(machine: Machine | str, truth: ErrorSet, q_programmed, q_commanded, reversal: dict | None = None,
              directions=None) -> np.ndarray:
    """Tool-tip error (N,3) mm of the real machine (`truth`, and its reversal {axis:
    ReversalTable} with rows approached in `directions`, (N, n) of +1 / -1) at the commanded
    positions, relative to the programmed (ideal) tool position.  A linear axis' reversal moves
    the tool along the axis' direction (ISO 841: the tool's motion relative to the workpiece)."""
    from ..kinematics import forward
    machine = load_machine(machine)
    p = forward(machine, q_commanded, extend_tables(truth)).p - forward(machine, q_programmed).p
    if reversal:
        dev = direction_terms(machine.axis_names, reversal, q_commanded, directions, 1.0)
        for k, ax in enumerate(machine.axes):
            if ax.name in reversal:
                p = p + dev[:, k:k + 1] * np.asarray(ax.direction, float)[None, :]
    return p


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
                        step: float = 25.0, seed: int = 0, reversal_truth: dict | None = None,
                        reversal_model: dict | None = None) -> CompensationReport:
    """Residual error without compensation, with model-based compensation (`model` tables,
    exact inverse) and with the lattice, at the grid points (every `step` mm) plus `n_random`
    random points of the travel (between lattice nodes, where interpolation errs most).
    With reversal_truth ({axis: ReversalTable} of the real machine) every figure is given for
    every point approached in the positive and in the negative direction of all axes, and
    reversal_model (default: the lattice's) adds the direction-dependent correction."""
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
    lstep = float(np.mean(np.diff(lattice.nodes[0]))) if lattice is not None else float("nan")
    if not reversal_truth:
        figures = {"uncompensated": fig(residuals(machine, truth, q, q)),
                   "model-based (corrected commands)": fig(
                       residuals(machine, truth, q, corrected_commands(machine, model, q)))}
        if lattice is not None:
            figures["3-D lattice (trilinear)"] = fig(residuals(machine, truth, q, lattice.apply(q)))
        return CompensationReport(len(q), figures, lstep)
    rev_model = reversal_model if reversal_model is not None else (lattice.reversal if lattice is not None else {})
    figures = {}
    base = corrected_commands(machine, model, q)
    for sgn, word in ((1.0, "moving +"), (-1.0, "moving -")):
        d = np.full(q.shape, sgn)
        figures[f"uncompensated, {word}"] = fig(residuals(machine, truth, q, q, reversal_truth, d))
        figures[f"model-based, mean tables, {word}"] = fig(residuals(machine, truth, q, base, reversal_truth, d))
        if rev_model:
            qc = base + direction_terms(machine.axis_names, rev_model, q, d, -1.0)
            figures[f"model-based + reversal, {word}"] = fig(residuals(machine, truth, q, qc, reversal_truth, d))
        if lattice is not None:
            figures[f"3-D lattice{' + reversal' if rev_model else ''}, {word}"] = fig(
                residuals(machine, truth, q, lattice.apply(q, d), reversal_truth, d))
    return CompensationReport(len(q), figures, lstep)
