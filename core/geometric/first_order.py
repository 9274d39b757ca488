"""First-order (small-error) tool-tip error models, in mtcomp's and in paper 004's notation.

Two independent routes to the same first-order result, both checked against the exact
homogeneous-transform model of `mtcomp.kinematics` (the differences are second order: products
of two angles times a length, or an angle times a translational error):

* `tool_tip_error(machine, q, geometric)`: the linearisation of mtcomp's chain model for any
  machine with linear axes, in the tool-relative-to-workpiece sense of the error tables.
* `paper_tool_tip(...)`: paper 004's vector model of the moving-column machining centre
  (its formula 4 for x, and the y and z components derived the same way; the printed paper
  gives only x), with `paper_errors_from_tables` translating ISO 230-1 tables into the
  paper's quantities F(G) and iD.  `formula4_printed` is formula 4 exactly as printed.

The derivation and the misprints of the paper are in docs/geometric.md.  Lengths in mm, angles
in rad.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import GeometricErrors
from ..machine import Machine

__all__ = ["tool_tip_error", "PaperErrors", "paper_tool_tip", "formula4_printed",
           "paper_errors_from_tables", "paper_k", "measured_feed"]


def tool_tip_error(machine: Machine, q, geometric: GeometricErrors) -> np.ndarray:
    """First-order tool-tip error (N,3) in mm for commands q (N, n) of a machine with linear axes.

    With the chain p = G_1 ... G_n (tool point), G_i = M_i E_i on the tool side and E_i M_i on
    the workpiece side (docs/model.md: the error motion E_i about the reference point c_i belongs
    to the moving body, which for a table is the parent frame), dropping products of errors gives

        Δp = Σ_i [ δ_i(q_i) + ε_i(q_i) × ℓ_i + q_i (ε0_i × u_i) ],
        ℓ_i = t + Σ_{j>i} q_j u_j − c_i  (+ q_i u_i for a workpiece-side axis)

    with δ_i, ε_i the table values, ε0_i the location (squareness) angles, u_i the directions and t
    the tool point: the Abbe arm ℓ_i runs from the reference point where it is at the moment to
    the tool tip.  Rotary axes are not linearised here.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if machine.n_rotary:
        raise ValueError("the first-order model here covers machines with linear axes only")
    n = q.shape[0]
    out = np.zeros((n, 3))
    tp = np.asarray(machine.tool_point, dtype=float)
    U = np.array([a.direction for a in machine.axes], dtype=float)
    for i, ax in enumerate(machine.axes):
        u = U[i]
        lever = tp[None, :] + q[:, i + 1:] @ U[i + 1:] - np.asarray(ax.location)[None, :]
        if ax.side == "workpiece":
            lever = lever + q[:, [i]] * u[None, :]
        table = geometric.tables.get(ax.name)
        if table is not None:
            d, e = table.evaluate(q[:, i])
            out += d + np.cross(e, lever)
        _, e0 = geometric.location_of(ax.name)
        out += q[:, [i]] * np.cross(e0, u)[None, :]
    return out


@dataclass(frozen=True)
class PaperErrors:
    """Paper 004's error quantities at N commanded positions.

    f: positioning/straightness errors F(G) (mm) by key "xX", "yX", "zX", "xY", ... ("x(Y)" of the
    paper is f["xY"]: error in direction x while feeding Y), each (N,) or scalar, at the virtual
    points 121 (table, bed frame), 131 (column, bed frame), 141 (head, column frame).
    ang: angles iD (rad) by key "1A".."4C": 1 = laser set-up on the bed (E1 from E0), 2 = table
    (E2 from E1), 3 = column (E3 from E1), 4 = head relative to the column (E4 = E3 turned by 4).
    Missing keys are zero.
    """
    f: dict
    ang: dict

    def F(self, key):
        return np.asarray(self.f.get(key, 0.0), dtype=float)

    def A(self, key):
        return np.asarray(self.ang.get(key, 0.0), dtype=float)


def paper_tool_tip(X, Y, Z, k, err: PaperErrors, W=(0.0, 0.0, 0.0), T=(0.0, 0.0, 0.0)) -> np.ndarray:
    """First-order vector from workpiece point W to tool point T in the laser frame E0 (N,3), mm.

    X is the paper's table feed (the table moves +X, so the tool moves −X relative to it), Y the
    column feed, Z the head feed, mm.  k = (k1..k7) mm.  W: point on the table from the origin O,
    T: point on the head from the tool tip P (paper's Fig. 2).  Component x is formula 4; y and z
    are derived in docs/geometric.md.
    """
    X, Y, Z = (np.asarray(v, dtype=float) for v in (X, Y, Z))
    k1, k2, k3, k4, k5, k6, k7 = (float(v) for v in k)
    Wx, Wy, Wz = (np.asarray(v, dtype=float) for v in W)
    Tx, Ty, Tz = (np.asarray(v, dtype=float) for v in T)
    F, A = err.F, err.A
    A34, B34, C34 = A("3A") + A("4A"), A("3B") + A("4B"), A("3C") + A("4C")
    dx = Tx - X - Wx          # nominal components of T - W
    dy = Y + Ty - Wy
    dz = Z + Tz - Wz
    x = (-F("xX") + F("xY") + F("xZ") + dx + dz * A("1B") - dy * A("1C")
         + (Z + k4 + k5 + Tz) * A("3B") + (k1 - Ty) * A("3C") + (Tz - k2) * A("4B")
         + (k1 - Ty) * A("4C") + (k7 + Wy) * A("2C") - (k5 + Wz) * A("2B"))
    y = (-F("yX") + F("yY") + F("yZ") + dy + dx * A("1C") - dz * A("1A")
         - (Z + k4 + k5 + Tz) * A("3A") + (k3 + Tx) * C34 + (k2 - Tz) * A("4A")
         - (k6 + Wx) * A("2C") + (k5 + Wz) * A("2A"))
    z = (-F("zX") + F("zY") + F("zZ") + dz + dy * A("1A") - dx * A("1B")
         - (k3 + Tx) * B34 + (Ty - k1) * A34 + (k6 + Wx) * A("2B") - (k7 + Wy) * A("2A"))
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def formula4_printed(X, Y, Z, k, err: PaperErrors, W=(0.0, 0.0, 0.0), T=(0.0, 0.0, 0.0)):
    """Formula 4 of paper 004 term by term as printed (x component), mm."""
    k1, k2, k3, k4, k5, k6, k7 = (float(v) for v in k)
    Wx, Wy, Wz = W
    Tx, Ty, Tz = T
    F, A = err.F, err.A
    return (-F("xX") + F("xY") + F("xZ") - X - Wx + Tx + (Z + Tz - Wz) * A("1B")
            - (Y + Ty - Wy) * A("1C") + (Z + k4 + k5 + Tz) * A("3B") + (k1 - Ty) * A("3C")
            + (Tz - k2) * A("4B") + (k1 - Ty) * A("4C") + (k7 + Wy) * A("2C")
            - (k5 + Wz) * A("2B"))


def paper_k(machine: Machine) -> tuple[float, ...]:
    """Offsets k1..k7 (mm) of paper 004 from a machine's [machine] k entry or its axis locations."""
    k = machine.extra.get("k")
    if k is not None:
        return tuple(float(v) for v in k)
    cx, cy, cz = (np.asarray(machine.axis(a).location, float) for a in "XYZ")
    # 121 = -(k6, k7, k5); 131 = (-k3, k1, -(k4 + k5)); 141 = (-k3, k1, k2)
    k6, k7, k5 = -cx
    k3, k1, k2 = -cz[0], cz[1], cz[2]
    k4 = -cy[2] - k5
    return (k1, k2, k3, k4, k5, k6, k7)


def paper_errors_from_tables(machine: Machine, geometric: GeometricErrors, q) -> PaperErrors:
    """Paper 004's F(G) and iD at commands q (N,3) (ISO X, Y, Z) from mtcomp tables, first order.

    Only for the moving-column structure (X on the workpiece side, Y then Z on the tool side).
    Both act about point 121 on the table, but the tables are tool relative to workpiece while
    the paper's table errors are the table's own motion (paper X = −ISO X), so to first order
    2D = −E{D}X and x(X) = −EXX, y(X) = −EYX, z(X) = −EZX.  Column and head errors carry over,
    with the squareness tilts folded into the straightness (the paper measures straightness
    against the laser's square frame).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    names = machine.axis_names
    if names != ("X", "Y", "Z") or [a.side for a in machine.axes] != ["workpiece", "tool", "tool"]:
        raise ValueError("paper 004's model is the moving-column structure X (table), Y, Z (tool side)")
    f, ang = {}, {}
    n = q.shape[0]
    for i, ax in enumerate("XYZ"):
        t = geometric.tables.get(ax)
        d, e = t.evaluate(q[:, i]) if t is not None else (np.zeros((n, 3)), np.zeros((n, 3)))
        _, e0 = geometric.location_of(ax)
        u = np.asarray(machine.axis(ax).direction, float)
        tilt = q[:, [i]] * np.cross(e0, u)[None, :]
        if ax == "X":
            d = d + tilt
            f["xX"], f["yX"], f["zX"] = -d[:, 0], -d[:, 1], -d[:, 2]
            ang["2A"], ang["2B"], ang["2C"] = -e[:, 0], -e[:, 1], -e[:, 2]
        else:
            body = "3" if ax == "Y" else "4"
            d = d + tilt
            for c, key in enumerate("xyz"):
                f[key + ax] = d[:, c]
            for c, key in enumerate("ABC"):
                ang[body + key] = e[:, c]
    return PaperErrors(f, ang)


def measured_feed(reading, lever, angles) -> np.ndarray:
    """Remove the set-up Abbe contribution from a displacement reading (first order), mm.

    reading (N,3): displacement of the measuring point relative to its start, minus the nominal
    feed, along x, y, z (a positioning run fills one column, straightness runs the others);
    lever (N,3) or (3,): vector from the axis' reference point to the measuring point;
    angles (N,3): the axis' angular error motions (rad).  Returns the translational errors at
    the reference point: reading − ε × lever  (formula 10 of paper 004 in vector form).
    """
    return np.asarray(reading, float) - np.cross(np.asarray(angles, float),
                                                  np.broadcast_to(lever, np.shape(angles)))
