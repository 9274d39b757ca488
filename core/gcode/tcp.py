"""Tool centre point (G43.4) programs: compensation in tool-tip coordinates.

Under G43.4 the X Y Z words are the tool tip in the workpiece frame and the rotary words the
axis angles; the control turns them into axis positions with its *nominal* kinematics and the
active tool length.  With errors, mtcomp finds the axis positions ``q*`` that put the real tool
(errors included) at the programmed tip in the programmed orientation, then writes the words the
control must be given so that its nominal transform yields ``q*``:

    q_nom = C^-1(tip, angles)            the control's nominal inverse (what it would run)
    q*    = retarget(q_nom)              real forward(q*) = nominal forward(q_nom) (tip, orientation)
    tip'  = F_nom(q*),  angles' = rotary part of q*

so that C^-1(tip', angles') = q* (the nominal inverse of a nominal forward at the same angles is
the identity).  With zero errors q* = q_nom and the words come back unchanged.  The derivation
and its limits are in docs/gcode.md ("Tool centre point programs").

The tool length L (H) enters as a tool point ``tool_point - L * tool_axis`` (the tip is L below
the gauge point the machine file defines): on head machines it is the lever of the rotary axes.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

_MACHINES: dict = {}


def tool_machine(machine, length: float):
    """The machine with its tool point moved to the tip of a tool of ``length`` mm (along
    -tool_axis); cached so that the kinematic kernel's model cache keeps hitting."""
    key = (id(machine), float(length))
    hit = _MACHINES.get(key)
    if hit is not None and hit[0] is machine:
        return hit[1]
    if len(_MACHINES) > 64:
        _MACHINES.clear()
    tp = np.asarray(machine.tool_point, float) - float(length) * np.asarray(machine.tool_axis, float)
    m = replace(machine, tool_point=tuple(float(x) for x in tp)) if length else machine
    _MACHINES[key] = (machine, m)
    return m


def _columns(machine):
    """(linear axis columns, their workpiece coordinate index 0..2, rotary columns)."""
    lin = [i for i, a in enumerate(machine.axes) if not a.is_rotary]
    names = [machine.axes[i].name for i in lin]
    if sorted(names) != ["X", "Y", "Z"]:
        raise ValueError(f"tool centre point programs need linear axes X Y Z, {machine.name} has "
                         f"{' '.join(names)}")
    return lin, ["XYZ".index(n) for n in names], list(machine.rotary_indices)


def _by_length(lengths, n):
    lengths = np.broadcast_to(np.asarray(lengths, float), (n,))
    for L in np.unique(lengths):
        yield float(L), np.flatnonzero(lengths == L)


def nominal_axes(machine, words: np.ndarray, lengths) -> np.ndarray:
    """The control's inverse: axis positions (N, n_axes) for G43.4 words (N, n_axes: linear
    columns the tip in the workpiece frame, mm; rotary columns the angles, deg) with tool
    lengths (N,) mm.  At fixed angles the nominal tip is affine in the linear axes (they
    translate), so one solve with the unit-step Jacobian is exact."""
    from ..kinematics import forward
    w = np.asarray(words, float)
    lin, xyz, _ = _columns(machine)
    q = w.copy()
    for L, rows in _by_length(lengths, len(w)):
        m = tool_machine(machine, L)
        q0 = w[rows].copy()
        q0[:, lin] = 0.0
        p0 = forward(m, q0).p
        J = np.empty((len(rows), 3, 3))
        for k, i in enumerate(lin):
            dq = q0.copy()
            dq[:, i] = 1.0
            J[:, :, k] = forward(m, dq).p - p0
        tip = w[rows][:, lin]
        target = np.empty((len(rows), 3))
        target[:, xyz] = tip
        q[np.ix_(rows, lin)] = np.linalg.solve(J, (target - p0)[..., None])[..., 0]
    return q


def nominal_words(machine, q: np.ndarray, lengths) -> np.ndarray:
    """The control's forward: G43.4 words (N, n_axes) for axis positions q (N, n_axes)."""
    from ..kinematics import forward
    q = np.asarray(q, float)
    lin, xyz, _ = _columns(machine)
    out = q.copy()
    for L, rows in _by_length(lengths, len(q)):
        p = forward(tool_machine(machine, L), q[rows]).p
        out[np.ix_(rows, lin)] = p[:, xyz]
    return out


def compensate_words(machine, words: np.ndarray, lengths, errors, **retarget_kw) -> np.ndarray:
    """Compensated G43.4 words: the words whose nominal inverse puts the real tool (with
    ``errors``) at the tip and orientation the programmed words give on the ideal machine.
    ``retarget_kw`` go to `mtcomp.kinematics.retarget` (its LimitError / ConvergenceError
    index the rows)."""
    from ..kinematics import retarget
    w = np.asarray(words, float)
    if errors is None or errors.is_zero:
        return w.copy()
    q_nom = nominal_axes(machine, w, lengths)
    q_star = np.empty_like(q_nom)
    for L, rows in _by_length(lengths, len(w)):
        try:
            q_star[rows] = retarget(tool_machine(machine, L), q_nom[rows], errors, **retarget_kw)
        except Exception as exc:          # name the row of the whole batch
            if hasattr(exc, "index"):
                exc.index = int(rows[exc.index])
            raise
    return nominal_words(machine, q_star, lengths)


def tip_errors(machine, words: np.ndarray, written: np.ndarray, lengths, errors):
    """Tool-tip error (mm) before and after compensation of G43.4 blocks: the real tip (with
    ``errors``) where the control runs the programmed words, and where it runs the written
    words, each against the programmed tip."""
    from ..kinematics import forward
    w = np.asarray(words, float)
    lin, xyz, _ = _columns(machine)
    tip = np.empty((len(w), 3))
    tip[:, xyz] = w[:, lin]
    qa = nominal_axes(machine, w, lengths)
    qb = nominal_axes(machine, written, lengths)
    before, after = np.empty(len(w)), np.empty(len(w))
    for L, rows in _by_length(lengths, len(w)):
        m = tool_machine(machine, L)
        before[rows] = np.linalg.norm(forward(m, qa[rows], errors).p - tip[rows], axis=1)
        after[rows] = np.linalg.norm(forward(m, qb[rows], errors).p - tip[rows], axis=1)
    return before, after
