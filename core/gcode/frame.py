"""The machine frame: where a program's blocks are in machine coordinates.

A control places a block at ``word + work offset (+ tool length along Z under G43)``, with the
work offset measured from the machine's reference point (Fanuc, Haas, LinuxCNC: the machine
zero).  `Program.position` holds blocks in the frame of the work offset in effect at the first
motion block (tool lengths and the differences of other work offsets included); that offset's
own value, `Program.frame`, is where the program origin lies in machine coordinates.

Geometric errors (component tables, squareness and other location errors, docs/errors-format.md)
are in machine coordinates: a table of X is read at the machine's X, not the word's.  Setting
errors are not: the workpiece setting is the pose of the real blank in the program's frame
(paper 001), the tool setting the edge in the tool frame.  `MachineFrame` evaluates the
model with the commands shifted by the frame and the workpiece setting's translation moved so
that its rotation still turns about the program origin:

    x_nominal = R x_real + t          (program frame, errors.WorkpieceSetting)
    x' = x + d  (d: the nominal tool point's shift for commands shifted by the frame)
    x'_nominal = R x'_real + t + (I - R) d

so the tool point in the shifted model is the program-frame one plus ``d`` for every error
that is not geometric, and only the geometric errors see machine positions.  ``d`` is exact for
machines whose rotary axes are all on the tool side (or none); with workpiece-side rotary axes
it depends on their angles, and a rotated blank under a work offset that is not zero is refused.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .._io import InputError


@dataclass(frozen=True)
class MachineFrame:
    """Commands shift ``base`` (n_axes,: mm, deg) and the errors to evaluate there."""
    base: np.ndarray
    errors: object                      # ErrorSet with the workpiece translation moved

    def to_machine(self, q: np.ndarray) -> np.ndarray:
        """Program-frame commands (N, n_axes) -> machine coordinates (a new array)."""
        return np.add(q, self.base)

    def from_machine(self, q: np.ndarray) -> np.ndarray:
        """Machine coordinates (N, n_axes) -> program-frame commands, in place."""
        q -= self.base
        return q


def wcs_text(prog) -> str:
    """The name of the work offset in effect at the first motion block, for messages."""
    line = int(getattr(prog, "frame_line", 0) or 0)
    if not line:
        return "G54"
    import re
    text = prog.lines[line - 1] if line - 1 < len(prog.lines) else ""
    m = re.search(r"G\s*(5[4-9](?:\.1\s*P\s*\d+)?|154\s*P\s*\d+|1[12]\d)(?!\d)",
                  text.split("(")[0].upper())
    return f"G{m.group(1)}" if m else "the work offset"


def machine_frame(machine, prog, errors, filename: str = "<string>") -> MachineFrame | None:
    """The machine frame of `prog` for `errors`, or None where nothing depends on it (no
    geometric errors, or the program origin at the machine zero).  Refused (InputError naming
    the line of the work offset code) where error tables are given and the program names a
    work offset whose value is not given for an axis it moves.  With location errors only, an
    offset not given is taken as 0 (the machine file's origin is the program's: location
    errors such as squareness change with the origin only by a constant, as before)."""
    if errors is None or errors.geometric.is_zero:
        return None
    frame = getattr(prog, "frame", None)
    n = len(machine.axis_names)
    base = np.zeros(n) if frame is None else np.asarray(frame, float)[:n].copy()
    written = np.asarray(prog.present).any(axis=0) if len(prog) else np.zeros(n, bool)
    missing = [a for a, v, w in zip(machine.axis_names, base, written) if w and not np.isfinite(v)]
    if missing and errors.geometric.tables:
        name = wcs_text(prog)
        raise InputError(f"the geometric errors are in machine coordinates, and the value of "
                         f"{name} ({' '.join(missing)}), where this program's origin lies on the "
                         f"machine, is not given: give it (--offsets FILE with [{name}], or "
                         "G10 L2/L20 in the program); docs/gcode.md \"The machine frame\"",
                         filename, int(prog.frame_line) or None)
    base = np.nan_to_num(base)
    if not base.any():
        return None
    if np.asarray(prog.tcp).any():
        raise InputError("G43.4 tool centre point blocks under a work offset that is not zero, "
                         "with geometric errors: not supported (the tip words are in the "
                         "workpiece frame; give the program in the machine frame)", filename,
                         int(prog.line[int(np.argmax(prog.tcp))]))
    from ..kinematics import forward
    zero = np.zeros((1, n))
    d = (forward(machine, base[None, :]).p - forward(machine, zero).p)[0]
    wp = errors.workpiece
    if any(wp.angles):
        work_rot = [a.name for a in machine.axes if a.is_rotary and a.side == "workpiece"]
        if work_rot:
            raise InputError(f"a rotated blank (workpiece setting angles) under a work offset that "
                             f"is not zero on {machine.name}, whose {' '.join(work_rot)} carry the "
                             "workpiece: the pivot of the rotation in machine coordinates "
                             "depends on their angles; not supported", filename,
                             int(prog.frame_line) or None)
        R = wp.matrix
        t = np.asarray(wp.translation) + (np.eye(3) - R) @ d
        errors = replace(errors, workpiece=replace(wp, translation=tuple(float(x) for x in t)))
    return MachineFrame(base, errors)
