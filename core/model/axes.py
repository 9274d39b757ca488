"""Which machine axis a diagnosed output follows, and in which sense.

The diagnosis names outputs by the workpiece-frame coordinate they hold (x, y, z for the tool
edge; a, b, c for angles).  An effect acting on "the output's own axis" belongs to the linear
axis whose direction is along that coordinate (ISO 841: every axis motion is the tool relative
to the workpiece, so with direction +e the coordinate is q + c, with -e it is -q + c).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..machine import Machine

XYZ = "xyz"


class NoHome(Exception):
    """The effect has no place in the machine model (the reason is the message)."""


@dataclass(frozen=True)
class LinearAxisOf:
    """The machine's linear axis along output coordinate `output`.

    sign: +1 when the axis moves the tool along +output, -1 along -output.  offset: the output
    coordinate (mm) of the tool edge with every axis at zero, so output = sign q + offset.
    lo, hi: the axis travel (mm)."""
    output: str
    axis: str
    sign: float
    offset: float
    lo: float
    hi: float

    def coordinate(self, q):
        """Output coordinate (mm) of the tool for axis position q (mm)."""
        return self.sign * np.asarray(q, float) + self.offset


def coordinate_letter(name: str) -> str:
    """'x', 'y' or 'z' of an output name as the diagnosis writes it: x, tool.x, x_act, pos_z,
    y1 (a unit in brackets is ignored); NoHome when the name holds no one coordinate."""
    import re
    n = re.sub(r"[\[(].*$", "", str(name)).strip().lower()
    toks = [t for t in re.split(r"[^a-z]+", n) if t in ("x", "y", "z")]
    if len(toks) == 1:
        return toks[0]
    raise NoHome(f"output {name!r} is not a tool edge coordinate (x, y, z)")


def linear_axis(machine: Machine, output: str) -> LinearAxisOf:
    """The linear axis that moves the tool along output `output` (x, y or z; also tool.x,
    x_act, pos_z)."""
    o = coordinate_letter(output)
    k = XYZ.index(o)
    for ax in machine.axes:
        if ax.is_rotary:
            continue
        d = np.asarray(ax.direction, float)
        if abs(abs(d[k]) - 1.0) < 1e-9:
            lo, hi = (float(v) for v in ax.limits)
            return LinearAxisOf(o, ax.name, float(np.sign(d[k])), _zero_pose(machine)[k], lo, hi)
    raise NoHome(f"machine {machine.name!r} has no linear axis along {o}")


def rotary_axis(machine: Machine, letter: str):
    """(index, Axis) of rotary axis `letter` (A, B, C; also c_cmd, b1), or NoHome."""
    import re
    toks = [t for t in re.split(r"[^a-z]+", re.sub(r"[\[(].*$", "", str(letter)).strip().lower())
            if t in ("a", "b", "c")]
    L = toks[0].upper() if len(toks) == 1 else str(letter).strip().upper()
    for i, ax in enumerate(machine.axes):
        if ax.name == L and ax.is_rotary:
            return i, ax
    raise NoHome(f"machine {machine.name!r} has no rotary axis {L}")


def _zero_pose(machine: Machine) -> np.ndarray:
    from ..kinematics import forward
    return forward(machine, np.zeros((1, machine.n_axes)), strict=False).p[0]
