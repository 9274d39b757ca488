"""Where the control stands after canned cycle blocks, in the rewrite's control counts.

`rewrite._control_counts` reads every axis word once, and a cycle block's Z is no axis word
(it is the depth).  Here the cycle blocks get the Z level the control leaves them at (G98: the
initial level, G99: the R level, as `Program.position`), carried into later blocks until Z is
written absolutely, and the repeats below their further steps.

Repeated canned cycle holes (Fanuc ``K``, LinuxCNC and Haas ``L``) in G91: a cycle block with a repeat count n in G91 drills n holes, stepping by its X Y increments
before each: the control runs the one block n times.  `Program.position` holds its last hole;
the rewrite's control counts (`rewrite._control_counts`, which read each word once) get the
n - 1 further steps here, so that later blocks start where the control stands.  The block's
words can only stay one increment if the correction is the same at every hole and at the
block before (then the step is unchanged and only where the run starts moves with the
correction, which the block before carries); otherwise the block is refused naming its line.
In G90 the n holes are one place drilled n times, which the cycle code handles as one hole.
"""
from __future__ import annotations

import numpy as np

from .._io import InputError
from .codes import INCH, LINEAR
from .program import Program


def stepped_rows(program: Program) -> np.ndarray:
    """Blocks that repeat in G91 with an X or Y increment (their holes step)."""
    rep = program.cycle_repeat
    if rep is None or not (np.asarray(rep) > 1).any():
        return np.zeros(0, np.int64)
    cw = np.asarray(program.col_word)[:, :program.n_axes]
    sel = (np.asarray(rep) > 1) & np.asarray(program.incremental) & (cw >= 0).any(axis=1)
    return np.flatnonzero(sel)


def _steps(program: Program, rows) -> np.ndarray:
    """(len(rows), n_axes) the increment of one step (mm, deg; 0 where no word)."""
    cw = np.asarray(program.col_word)[rows, :program.n_axes]
    wv = np.asarray(program.w_value)
    v = np.where(cw >= 0, wv[np.maximum(cw, 0)], 0.0)
    inch = np.asarray(program.inch)[rows]
    lin = np.array([a in LINEAR for a in program.axes])
    return v * np.where(inch[:, None] & lin[None, :], INCH, 1.0)


def control_counts(program: Program, Cc: np.ndarray, res: np.ndarray, rows,
                   offc=None) -> np.ndarray:
    """``Cc`` ((N + 1, n_axes) control counts, each word read once) with the cycle blocks'
    return levels in Z and the n - 1 further steps of the repeated G91 blocks ``rows``, both
    carried into every later block until the axis gets an absolute word."""
    N, n_ax = len(program), program.n_axes
    cw = np.asarray(program.col_word)[:, :n_ax]
    isabs = (cw >= 0) & ~np.asarray(program.incremental)[:, None]
    out = _return_levels(program, Cc, res, isabs, offc)
    if not len(rows):
        return out
    rep = np.asarray(program.cycle_repeat)
    ex = np.zeros((N, n_ax))
    ex[rows] = np.rint(_steps(program, rows) / res) * (rep[rows, None] - 1)
    for k in range(n_ax):
        if not ex[:, k].any():
            continue
        cum = np.cumsum(ex[:, k])
        idx = np.where(isabs[:, k], np.arange(N), -1)
        np.maximum.accumulate(idx, out=idx)
        out[1:, k] += cum - np.where(idx >= 0, cum[np.maximum(idx, 0)], 0.0)
    return out


def _return_levels(program: Program, Cc, res, isabs, offc):
    """Z counts after each cycle block: the initial level (G98, where Z stood before the run)
    or the R level (G99: the R word in G90, in the block's frame; in G91 the initial level
    plus R), and after it as the later words move Z from there."""
    zk = program.axes.index("Z")
    cyc = np.asarray(program.cycle)
    data = np.asarray(program.cycle_data)
    inc = np.asarray(program.incremental)
    rz = res[zk]
    N = len(program)
    col = Cc[:, zk]                           # the words' reading (row 0: the start)
    last_abs = np.where(isabs[:, zk], np.arange(N), -1)
    np.maximum.accumulate(last_abs, out=last_abs)
    cb = np.flatnonzero(cyc > 0)
    # the G91 Z increments read since each block: a level the cycle sets (G99 with R in G90)
    # is where Z stands whatever came before, so later blocks are that level plus the
    # increments since (col + dl is NaN where Z was not known before the cycle; a NaN here
    # once read as 0 and wrote a 50 mm retract as no move, issue 31)
    wz = np.asarray(program.col_word)[:, zk]
    wv = np.asarray(program.w_value)
    incz = np.where((wz >= 0) & inc, wv[np.maximum(wz, 0)], 0.0)
    if zk < len(program.axes) and program.axes[zk] in LINEAR:
        incz = incz * np.where(np.asarray(program.inch), INCH, 1.0)
    cum = np.cumsum(np.rint(incz / rz))
    end_at = np.zeros(len(cb))                # per cycle block: the level it leaves Z at

    def z_after(j):                           # the control's Z after block j (-1: the start)
        if j < 0:
            return col[0]
        i = int(np.searchsorted(cb, j, side="right")) - 1
        if i >= 0 and cb[i] > last_abs[j]:
            return end_at[i] + cum[j] - cum[cb[i]]
        return col[1 + j]
    for i, k in enumerate(cb.tolist()):
        zinit = z_after(int(data[k, 6]) - 1)
        if data[k, 5] == 98:
            end = zinit
        elif inc[k]:
            end = zinit + np.rint(data[k, 3] / rz)
        else:
            end = np.rint(data[k, 3] / rz) + (offc[k, zk] if offc is not None else 0)
        end_at[i] = end
    ci = np.searchsorted(cb, np.arange(N), side="right") - 1
    after = (ci >= 0) & (cb[np.maximum(ci, 0)] > last_abs)
    out = Cc.copy()
    c0 = np.maximum(ci, 0)
    out[1:, zk] = np.where(after, end_at[c0] + cum - cum[cb[c0]], col[1:])
    out[1:, zk][~np.asarray(program.axis_known)[:, zk]] = np.nan
    return out


def check(program: Program, transform, rows, kn, kk, dK, res, row_lines=None) -> np.ndarray:
    """The known repeated G91 blocks among ``rows`` whose correction (counts) is the same at
    every hole, at its arrival level, R level and bottom, as at the block before: their words
    stay as written (returned, to be left out of the word edits).  Any other is refused naming
    its line.  ``transform`` is called once with all the holes' points."""
    from .rewrite import _call_transform
    rows = np.asarray([k for k in rows.tolist() if kn[k]], np.int64)
    if not len(rows):
        return rows
    P = np.asarray(program.position)
    data = np.asarray(program.cycle_data)
    rep = np.asarray(program.cycle_repeat)
    zk = program.axes.index("Z")
    steps = _steps(program, rows)
    line = np.asarray(program.line)
    for k in rows.tolist():
        if k == 0 or not kn[k - 1]:
            raise InputError(f"canned cycle repeat count {rep[k]} in G91 where the position "
                             "before the block is not known: the holes cannot be placed",
                             program.filename, int(line[k]))
    pts, owner = [], []
    for i, k in enumerate(rows.tolist()):
        n = int(rep[k])
        end_lvl = data[k, 0] if data[k, 5] == 98 else data[k, 1]
        first_lvl = P[k - 1, zk] if np.isfinite(P[k - 1, zk]) else data[k, 1]
        for h in range(1, n + 1):
            hole = P[k] - (n - h) * steps[i]
            for z in (first_lvl if h == 1 else end_lvl, data[k, 1], data[k, 2]):
                q = hole.copy()
                q[zk] = z
                pts.append(q)
                owner.append(k)
    Q = np.asarray(pts)
    owner = np.asarray(owner, np.int64)
    if row_lines is not None:
        row_lines.append(line[owner])
    if hasattr(transform, "blocks"):
        transform.blocks = owner
    d = np.rint((_call_transform(transform, Q) - Q) / res)
    pos = {int(k): j for j, k in enumerate(kk.tolist())}
    for k in rows.tolist():
        want = dK[pos[k - 1]]
        if not (np.all(d[owner == k] == want) and np.all(dK[pos[k]] == want)):
            raise InputError(f"canned cycle repeat count {rep[k]} in G91: the correction is not "
                             "the same at every hole and at the block before, so the step cannot "
                             "stay one increment; not supported (write the holes out, or in G90)",
                             program.filename, int(line[k]))
    return rows
