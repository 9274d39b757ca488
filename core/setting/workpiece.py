"""Workpiece setting errors after robot loading (paper 001): the public API and the NC transform.

Work flow (each step a function; the CLI `mtcomp workpiece-setting` is a thin layer over them):

    plan = plan_bowls(3)                                 # bowls.py: positions, depth, touches
    roughing_program(plan), probing_program(plan)        # NC text for the two machines
    touches = read_touches("touches.csv")                # or virtual_probe(true_pose, plan, ...)
    fit = fit_bowls(touches, plan.probe_radius)          # sphere per bowl, probe radius removed
    est = frame_from_bowls(fit, plan)                    # frame.py: WorkpieceSettingEstimate
    est.save("errors.toml")                              # mtcomp.errors format
    q_new = compensate_commands(machine, q, est.pose)    # this module

The NC transform comes in two modes.  "3axis" is paper 001's formula applied to the tool-point
coordinates of a program whose rotary axes stay at 0: x' = R x + t (= [ex ey ez](x - X) + X + d,
see frame.pose_from_paper); the tool keeps its direction in the machine, so relative to the real
blank it is tilted by the setting angles (harmless for a ball or a point-like edge).  "5axis"
also keeps the tool direction relative to the real blank: the core's `kinematics.compensate`
(as `retarget` does, plus restarts where Newton stalls near a singular pose) solves the axis
commands (rotary angles included) that reproduce, on the machine with the
workpiece setting error, the programmed contact point and tool direction.

Units: mm, deg.
"""
from __future__ import annotations

import numpy as np

from .._io import InputError
from ..errors import ErrorSet, WorkpieceSetting
from .bowls import (BowlFit, BowlPlan, SphereFit, Touches, fit_bowls, load_plan, plan_bowls,  # noqa: F401
                    probing_program, read_touches, roughing_program, save_plan, virtual_probe,
                    write_touches)
from .frame import (WorkpieceSettingEstimate, apply_pose, frame_from_bowls, frame_from_points,  # noqa: F401
                    paper_frame, paper_transform, pose_from_paper, pose_matrix)

__all__ = [
    "plan_bowls", "BowlPlan", "roughing_program", "probing_program", "save_plan", "load_plan",
    "Touches", "read_touches", "write_touches", "virtual_probe", "fit_bowls", "BowlFit",
    "SphereFit", "frame_from_bowls", "frame_from_points", "WorkpieceSettingEstimate",
    "paper_frame", "paper_transform", "pose_from_paper", "apply_pose", "compensate_commands",
    "is_three_axis", "compensate_text", "compensate_program",
]


def is_three_axis(machine, q) -> bool:
    """True when every rotary axis command of q (N, n_axes) is 0 (a 3-axis program)."""
    q = np.atleast_2d(np.asarray(q, float))
    rot = list(machine.rotary_indices)
    return not rot or bool(np.all(q[:, rot] == 0.0))


def _where(k: int, lines, source) -> dict:
    line = None if lines is None else int(np.asarray(lines)[k])
    return {"file": source, "line": line}


def _linear_map(machine):
    """(A, p0): tool point p = A q_lin + p0 at all rotary axes 0 (affine there; taken from the
    core's forward model, not re-derived)."""
    from ..kinematics import forward
    lin = [i for i in range(machine.n_axes) if i not in machine.rotary_indices]
    q = np.zeros((len(lin) + 1, machine.n_axes))
    for k, i in enumerate(lin):
        q[k + 1, i] = 1.0
    p = forward(machine, q).p
    return np.column_stack([p[k + 1] - p[0] for k in range(len(lin))]), p[0], lin


def compensate_commands(machine, q, pose: WorkpieceSetting, mode: str = "auto", *, lines=None,
                        source=None, round_result: bool = False) -> np.ndarray:
    """Axis commands (N, n_axes) mm/deg for the real blank at `pose` from commands q for the nominal one.

    mode "3axis": paper 001's x' = R x + t on the tool point, rotary axes untouched (they must
    be 0 on every line); "5axis": contact point and tool direction relative to the blank, via
    kinematics.compensate of the programmed poses (`_five_axis`); "auto": 3axis when the rotary axes are all 0, else 5axis.
    lines: source line number of each row (for errors); source: program file name.
    Raises InputError naming the line when a command would leave an axis' travel (or, in 3axis
    mode, when a rotary axis is not at 0).
    """
    from ..kinematics import ConvergenceError, LimitError, check_limits, round_to_resolution
    q = np.atleast_2d(np.asarray(q, float))
    if q.shape[1] != machine.n_axes:
        raise InputError(f"commands need {machine.n_axes} columns ({' '.join(machine.axis_names)}), "
                         f"got {q.shape[1]}", source)
    if mode == "auto":
        mode = "3axis" if is_three_axis(machine, q) else "5axis"
    if mode == "3axis":
        rot = list(machine.rotary_indices)
        if rot:
            bad = np.flatnonzero(np.any(q[:, rot] != 0.0, axis=1))
            if bad.size:
                k = int(bad[0])
                names = [machine.axis_names[i] for i in rot if q[k, i] != 0.0]
                raise InputError(f"3-axis transform needs the rotary axes at 0, {names[0]} is "
                                 f"{q[k, machine.index(names[0])]:g} deg; use the 5-axis mode",
                                 **_where(k, lines, source))
        A, p0, lin = _linear_map(machine)
        if A.shape != (3, 3) or abs(np.linalg.det(A)) < 1e-9:
            raise InputError(f"the 3-axis transform needs three independent linear axes; "
                             f"machine {machine.name} has {', '.join(machine.axis_names[i] for i in lin)}",
                             field="mode")
        R, t = pose_matrix(pose)
        p = q[:, lin] @ A.T + p0                   # tool point in the nominal workpiece frame
        p_new = p @ R.T + t                        # paper 001: x' = R x + t
        out = q.copy()
        out[:, lin] = np.linalg.solve(A, (p_new - p0).T).T
        if round_result:
            out = round_to_resolution(machine, out)
        try:
            check_limits(machine, out)
        except LimitError as exc:
            raise InputError(str(exc).replace(f" (point {exc.index})", ""),
                             **_where(exc.index, lines, source)) from None
        return out
    if mode != "5axis":
        raise InputError(f"mode must be auto, 3axis or 5axis, got {mode!r}", field="mode")
    if not machine.rotary_indices:
        raise InputError(f"machine {machine.name} has no rotary axes: use the 3-axis mode",
                         field="mode")
    try:
        out = _five_axis(machine, q, ErrorSet(workpiece=pose))
        if round_result:
            out = round_to_resolution(machine, out)
        check_limits(machine, out)
        return out
    except LimitError as exc:
        what = "angles" if machine.axis(exc.axis).is_rotary else "commands"
        raise InputError(f"the compensated {what} leave the travel: "
                         f"{str(exc).replace(f' (point {exc.index})', '')}",
                         **_where(exc.index, lines, source)) from None
    except ConvergenceError as exc:
        raise InputError(f"no axis commands reach this point and tool direction on the real "
                         f"blank: {exc}", **_where(exc.index, lines, source)) from None


def _five_axis(machine, q, errors):
    """kinematics.compensate for the programmed poses.  At a singular pose of the rotary axes
    (B = 0 on a B-C table) a small tilt of the blank needs a large turn of the other rotary
    axis; compensate finds it by restarting from rotary seeds (docs/model.md)."""
    from ..kinematics import compensate, forward
    return compensate(machine, forward(machine, q), errors, q)


def _tcp_words(machine, w, lengths, pose: WorkpieceSetting, mode: str):
    """G43.4 words (N, n_axes: tool tip in the workpiece frame, rotary angles) for the real blank
    at `pose`.  The tip is a workpiece-frame point, so "3axis" is paper 001's x' = R x + t on the
    tip words themselves, angles kept (the tool keeps its direction in the machine, as the 3-axis
    mode does; the control's TCP does the kinematics); "5axis" also keeps the tool direction
    relative to the blank: the words whose nominal inverse puts the real tool (blank at `pose`)
    at the programmed tip and direction (`mtcomp.gcode.tcp.compensate_words`)."""
    from ..gcode import tcp as gtcp
    w = np.asarray(w, float)
    if mode == "5axis":
        return gtcp.compensate_words(machine, w, lengths, ErrorSet(workpiece=pose))
    lin = [i for i, a in enumerate(machine.axes) if not a.is_rotary]
    xyz = ["XYZ".index(machine.axes[i].name) for i in lin]
    tip = np.empty((len(w), 3))
    tip[:, xyz] = w[:, lin]
    R, t = pose_matrix(pose)
    out = w.copy()
    out[:, lin] = (tip @ R.T + t)[:, xyz]
    return out


def _tcp_checked(machine, w, lengths, pose, mode, lines, source):
    """`_tcp_words` with the axis positions the control derives checked against the travel
    (InputError naming the line)."""
    from ..gcode import tcp as gtcp
    from ..kinematics import ConvergenceError, LimitError, check_limits
    try:
        out = _tcp_words(machine, w, lengths, pose, mode)
        check_limits(machine, gtcp.nominal_axes(machine, out, lengths))
    except LimitError as exc:
        raise InputError("the compensated tool centre point words put an axis outside its travel: "
                         + str(exc).replace(f" (point {exc.index})", ""),
                         **_where(exc.index, lines, source)) from None
    except ConvergenceError as exc:
        raise InputError(f"no axis commands reach this tool tip and direction on the real blank: {exc}",
                         **_where(getattr(exc, "index", 0), lines, source)) from None
    return out


def compensate_text(machine, text: str, pose: WorkpieceSetting, *, mode: str = "auto",
                    filename: str = "<program>", chordal_tol: float = 1e-4,
                    tool_lengths=None) -> tuple[str, int]:
    """Rewrite NC program text for the real blank at `pose`: (new text, motion blocks).

    mtcomp.gcode reads the program and splices the new axis words in (every other byte is
    kept); every block end point and arc sample goes through `compensate_commands`; axis words
    are written at the machine's resolutions.  The whole program is checked first, so an axis
    leaving its travel is an InputError naming `filename` and the line.
    G68 rotation is followed (the setting error applies in the reference frame, the words are
    written in the rotated one, as `mtcomp compensate` does); G43.4 blocks are tool-tip words
    transformed in the workpiece frame (`_tcp_words`; ``tool_lengths`` {H: mm} for the 5-axis
    mode, where the tool length is the lever of head axes).
    """
    from .. import gcode
    from ..gcode import tcp as gtcp
    from ..gcode.rotation import to_reference
    prog = gcode.parse(text, axes=machine.axis_names, filename=filename, tcp=True, rotation=True,
                       tool_lengths=tool_lengths)
    # blocks before every axis position is known pass uncompensated (gcode.rewrite)
    known = np.asarray(prog.known)
    tcp = np.asarray(prog.tcp, bool)
    tlen = np.asarray(prog.tool_length, float)
    words = to_reference(prog, prog.position)           # G68: the positions the axes take
    q_all = words.copy()
    if tcp.any():
        q_all[tcp & known] = gtcp.nominal_axes(machine, words[tcp & known], tlen[tcp & known])
    if mode == "auto":
        mode = "3axis" if is_three_axis(machine, q_all[known]) else "5axis"
    # (in 3axis mode the rotary axes must be at 0 outside G43.4 only: under it the control's
    # tool centre point does the kinematics)
    # validate every block with its line number before any text is produced
    lines = np.asarray(prog.line)
    if (known & ~tcp).any():
        sel = known & ~tcp
        q_out = compensate_commands(machine, q_all[sel], pose, mode, lines=lines[sel], source=filename)
        if mode == "5axis":
            _midblock(machine, prog, q_all, q_out, sel, pose, filename)
    if (tcp & known).any():
        _tcp_checked(machine, words[tcp & known], tlen[tcp & known], pose, mode,
                     lines[tcp & known], filename)
    res = {a.name: a.resolution for a in machine.axes}
    calls = []

    def transform(q):
        if not tcp.any():
            return compensate_commands(machine, q, pose, mode, source=filename)
        rl = np.asarray(calls[-1])
        blk = np.clip(np.searchsorted(lines, rl), 0, len(lines) - 1)
        on = tcp[blk] & (lines[blk] == rl)
        out = np.empty_like(q)
        if (~on).any():
            out[~on] = compensate_commands(machine, q[~on], pose, mode, source=filename)
        if on.any():
            out[on] = _tcp_checked(machine, q[on], tlen[blk[on]], pose, mode, rl[on], filename)
        return out

    new = gcode.rewrite(prog, transform, resolution=res, chordal_tol=chordal_tol, row_lines=calls)
    return new, len(prog)


def _midblock(machine, prog, q_all, q_out, sel, pose, filename):
    """The mid-block check of `mtcomp compensate` (docs/gcode.md) on the 5-axis mode's commands:
    a linear block whose middle, axes interpolated linearly, leaves the programmed path by more
    than the uncompensated program there plus the error corrected at its ends is refused
    (InputError naming its line).  q_out: the compensated commands of the blocks `sel`."""
    from ..commands import TOLERANCE, _midblock_check
    from ..errors import ErrorSet
    from ..kinematics import deviations
    errors = ErrorSet(workpiece=pose)
    emitted = q_all.copy()
    emitted[sel] = q_out
    kk = np.flatnonzero(sel)
    before_end = deviations(machine, q_all[kk], emitted[kk], errors)[0]
    _midblock_check(machine, prog, q_all, emitted, sel, kk, before_end, errors, None,
                    lambda length: machine, TOLERANCE, filename)


def compensate_program(machine, path, pose: WorkpieceSetting, out, *, mode: str = "auto",
                       chordal_tol: float = 1e-4) -> int:
    """Rewrite the NC program file `path` into `out` (atomically; nothing written on error).

    Returns the number of motion blocks.  See `compensate_text`.
    """
    from pathlib import Path

    from .. import gcode
    from .._io import atomic_write
    path = Path(path)
    text = gcode.read_program(path)
    new, n = compensate_text(machine, text, pose, mode=mode, filename=str(path),
                             chordal_tol=chordal_tol)
    atomic_write(out, new)
    return n
