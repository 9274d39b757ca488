"""Volumetric error: the tool-tip error over the work volume implied by component tables.

The exact value comes from `mtcomp.kinematics.forward` (homogeneous transforms); next to it the
first-order expressions (`first_order.tool_tip_error`, and paper 004's formulas for the
moving-column machine), whose difference from the exact model is second order: products of two
angular errors with a length (ε² L ≈ (50 µrad)² · 1 m ≈ 2.5 nm) and of an angular with a
translational error (ε δ ≈ 50 µrad · 20 µm = 1 nm).
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._io import save_figure
from ..errors import ErrorSet
from ..machine import Machine, load_machine
from . import first_order

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["volume_grid", "VolumetricMap", "error_map", "plot_map", "compare"]


def volume_grid(machine: Machine, step: float | tuple = 50.0, margin: float = 0.0) -> np.ndarray:
    """Commands (N, n) on a regular grid over the travel of every axis (limits shrunk by margin).

    step: mm (one value or one per axis); the upper limit is always included.
    """
    steps = np.broadcast_to(np.asarray(step, dtype=float), (machine.n_axes,))
    axes = []
    for ax, h in zip(machine.axes, steps):
        lo, hi = ax.limits[0] + margin, ax.limits[1] - margin
        if not np.all(np.isfinite([lo, hi])):
            raise ValueError(f"axis {ax.name} has no finite travel")
        n = max(1, int(np.ceil((hi - lo) / h - 1e-9)))
        axes.append(np.linspace(lo, hi, n + 1))
    g = np.meshgrid(*axes, indexing="ij")
    return np.column_stack([x.ravel() for x in g])


@dataclass(frozen=True)
class VolumetricMap:
    """Tool-tip error vectors (N,3) in mm at commands q (N,n), exact and first order (None on
    machines with rotary axes, which the first-order model does not cover).

    paper: paper 004's formulas (x from formula 4, y and z derived likewise) evaluated at the
    workpiece point W under the tool, or None if the machine is not the moving-column type;
    paper_origin: the same with W = T = 0 as the paper prescribes for X', Y', Z'.
    """
    machine: str
    q: np.ndarray
    exact: np.ndarray
    first: np.ndarray | None = None
    paper: np.ndarray | None = None
    paper_origin: np.ndarray | None = None

    @property
    def magnitude(self) -> np.ndarray:
        return np.linalg.norm(self.exact, axis=1)

    def stats(self) -> dict:
        """Max and RMS (mm) of |e| and of each component, and of the model differences."""
        e = self.exact
        out = {"max": float(self.magnitude.max()), "rms": float(np.sqrt(np.mean(self.magnitude**2)))}
        for c, d in enumerate("xyz"):
            out[f"max_{d}"] = float(np.abs(e[:, c]).max())
            out[f"rms_{d}"] = float(np.sqrt(np.mean(e[:, c] ** 2)))
        if self.first is not None:
            out["first_order_diff_max"] = float(np.linalg.norm(self.first - e, axis=1).max())
        if self.paper is not None:
            out["paper_diff_max"] = float(np.linalg.norm(self.paper - e, axis=1).max())
            out["paper_origin_diff_max"] = float(np.linalg.norm(self.paper_origin - e, axis=1).max())
        return out

    def summary(self) -> str:
        s = self.stats()
        lines = [f"Volumetric error of {self.machine} over {len(self.q)} points",
                 f"  |e|: max {s['max'] * 1e3:.3f} µm, RMS {s['rms'] * 1e3:.3f} µm"]
        for d in "xyz":
            lines.append(f"  e{d}: max |.| {s['max_' + d] * 1e3:.3f} µm, RMS {s['rms_' + d] * 1e3:.3f} µm")
        if self.first is not None:
            lines.append(f"  first-order model vs exact: max {s['first_order_diff_max'] * 1e6:.3f} nm "
                         "(second-order terms)")
        if self.paper is not None:
            lines.append(f"  paper 004 formulas (W under the tool) vs exact: max "
                         f"{s['paper_diff_max'] * 1e6:.3f} nm")
            lines.append(f"  paper 004 formulas with W = T = 0 vs exact: max "
                         f"{s['paper_origin_diff_max'] * 1e3:.3f} µm (the workpiece frame's "
                         "rotation with the table is ignored)")
        return "\n".join(lines) + "\n"

    def to_csv(self) -> str:
        names = [f"q{i}" for i in range(self.q.shape[1])]
        first = self.first if self.first is not None else np.full_like(self.exact, np.nan)
        rows = ["# tool-tip error, exact model: commands (mm, deg) and error (mm); first order "
                "(nan where not defined)",
                ",".join(names + ["ex", "ey", "ez", "ex_first", "ey_first", "ez_first"])]
        for qi, e, f in zip(self.q, self.exact, first):
            rows.append(",".join(repr(float(v)) for v in (*qi, *e, *f)))
        return "\n".join(rows) + "\n"


def _is_moving_column(machine: Machine) -> bool:
    return (machine.axis_names == ("X", "Y", "Z")
            and [a.side for a in machine.axes] == ["workpiece", "tool", "tool"]
            and all(np.allclose(a.direction, np.eye(3)[i]) for i, a in enumerate(machine.axes)))


def error_map(machine: Machine | str, errors: ErrorSet, q=None, step: float = 50.0,
              margin: float = 0.0) -> VolumetricMap:
    """Tool-tip error over the work volume (or at commands q) by the exact and first-order models."""
    from ..kinematics import forward

    machine = load_machine(machine)
    if q is None:
        q = volume_grid(machine, step, margin)
    q = np.atleast_2d(np.asarray(q, dtype=float))
    exact = forward(machine, q, errors).p - forward(machine, q).p
    first = (first_order.tool_tip_error(machine, q, errors.geometric)
             if not machine.n_rotary else None)
    paper = paper0 = None
    if _is_moving_column(machine) and np.allclose(machine.tool_point, 0.0):
        k = first_order.paper_k(machine)
        pe = first_order.paper_errors_from_tables(machine, errors.geometric, q)
        # paper X is the table feed: −(ISO X); the workpiece point under the tool is W = (X, Y, Z)
        Xp = -q[:, 0]
        paper = first_order.paper_tool_tip(Xp, q[:, 1], q[:, 2], k, pe, W=(q[:, 0], q[:, 1], q[:, 2]))
        paper0 = first_order.paper_tool_tip(Xp, q[:, 1], q[:, 2], k, pe) - q
    return VolumetricMap(machine.name, q, exact, first, paper, paper0)


def compare(a: VolumetricMap, b: VolumetricMap) -> dict:
    """Max and RMS (mm) of the difference of two maps at the same commands."""
    if a.q.shape != b.q.shape or not np.allclose(a.q, b.q):
        raise ValueError("maps must be taken at the same commands")
    d = np.linalg.norm(a.exact - b.exact, axis=1)
    return {"max": float(d.max()), "rms": float(np.sqrt(np.mean(d**2)))}


def plot_map(vmap: VolumetricMap, path: str | os.PathLike | None = None, levels: int = 3,
             title: str | None = None) -> Figure:
    """Figure (PNG at `path` only when given) of the volumetric error: |e| and the (ex, ey) arrows in XY planes at several Z levels,
    and the exact minus first-order difference; for 3-axis maps on a regular grid."""
    from matplotlib.figure import Figure

    q = vmap.q
    if q.shape[1] != 3:
        raise ValueError("plot_map draws 3-axis maps")
    xs, ys, zs = (np.unique(q[:, i]) for i in range(3))
    if xs.size * ys.size * zs.size != len(q):
        raise ValueError("plot_map needs the map on a regular grid (volume_grid)")
    order = np.lexsort((q[:, 2], q[:, 1], q[:, 0]))
    E = vmap.exact[order].reshape(xs.size, ys.size, zs.size, 3) * 1e3  # µm
    if vmap.first is None:
        raise ValueError("plot_map draws maps of linear-axis machines")
    D = np.linalg.norm(vmap.first - vmap.exact, axis=1)[order].reshape(xs.size, ys.size, zs.size) * 1e6
    ks = np.unique(np.linspace(0, zs.size - 1, min(levels, zs.size)).round().astype(int))
    mag = np.linalg.norm(E, axis=-1)
    vmax = mag.max()
    fig = Figure(figsize=(4.0 * (len(ks) + 1) + 1.5, 3.8), dpi=110, layout="constrained")
    axs = fig.subplots(1, len(ks) + 1)
    for ax, k in zip(axs, ks):
        im = ax.pcolormesh(xs, ys, mag[:, :, k].T, shading="gouraud", vmin=0, vmax=vmax,
                           cmap="viridis")
        ax.quiver(xs, ys, E[:, :, k, 0].T, E[:, :, k, 1].T, color="w", angles="xy")
        ax.set_title(f"Z = {zs[k]:g} mm")
        ax.set_xlabel("X / mm")
        ax.set_aspect("equal")
    axs[0].set_ylabel("Y / mm")
    fig.colorbar(im, ax=axs[:len(ks)], label="|tool-tip error| / µm", shrink=0.8)
    ax = axs[-1]
    im2 = ax.pcolormesh(xs, ys, D.max(axis=2).T, shading="gouraud", cmap="magma")
    ax.set_title("exact − first order, max over Z")
    ax.set_xlabel("X / mm")
    ax.set_aspect("equal")
    fig.colorbar(im2, ax=ax, label="nm", shrink=0.8)
    s = vmap.stats()
    fig.suptitle(title or f"Volumetric error of {vmap.machine}: max {s['max'] * 1e3:.2f} µm, "
                 f"RMS {s['rms'] * 1e3:.2f} µm")
    if path is not None:
        save_figure(fig, path)
    return fig
