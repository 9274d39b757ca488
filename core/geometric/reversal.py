"""Reversal (backlash) of a linear axis from ISO 230-2 runs, and compensation by direction of approach.

ISO 230-2 keeps the two directions apart: x̄_i↑ and x̄_i↓ are the mean deviations (actual minus
target) at target i approached in the positive and the negative direction, B_i = x̄_i↑ − x̄_i↓
the reversal value at the target, B̄ = mean B_i the mean reversal value, B = max |B_i|.  The
component tables of `tables.build_tables` use the bidirectional mean x̄_i = (x̄_i↑ + x̄_i↓)/2 and
so average the reversal away; controls take it back in one of two ways:

* bidirectional pitch error compensation: one correction table per direction of approach,
  −x̄_i↑ and −x̄_i↓ (`mode="bidirectional"`);
* a unidirectional table of −x̄_i plus a backlash parameter: lost motion b = −B̄ (mm, positive for
  ordinary backlash: moving up the axis lags, x̄↑ < x̄↓), applied as ±b/2 by the direction of
  the move (`mode="backlash"`); it leaves B_i − B̄ uncorrected.

`ReversalTable.fanuc_pitch` writes the first form as a Fanuc-style bidirectional table: equally
spaced compensation points (the ISO targets need not be), incremental values per point and
direction in detection units, and the backlash parameter in the same units.  Check the control's
manual for its parameter numbers, signs and the magnification; the file states every convention
it uses.  Units: mm at the interface, detection units only in the export.
"""
from __future__ import annotations

import io
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._io import InputError, atomic_write
from .iso230_2 import Iso2302Result

__all__ = ["ReversalTable", "reversal_table", "MODES", "approach_directions", "machining_order",
           "direction_corrections", "direction_terms", "load_reversal"]

MODES = ("bidirectional", "backlash", "mean")


@dataclass(frozen=True)
class ReversalTable:
    """Per-direction mean deviations of one axis (mm): position (m,), up = x̄_i↑, down = x̄_i↓."""
    axis: str
    position: np.ndarray
    up: np.ndarray
    down: np.ndarray
    source: str | None = None

    @property
    def reversal_i(self) -> np.ndarray:
        """B_i = x̄_i↑ − x̄_i↓, mm."""
        return self.up - self.down

    @property
    def B(self) -> float:
        """Reversal value of the axis, max |B_i|, mm."""
        return float(np.max(np.abs(self.reversal_i)))

    @property
    def B_mean(self) -> float:
        """Mean reversal value B̄, mm."""
        return float(np.mean(self.reversal_i))

    @property
    def backlash(self) -> float:
        """Lost motion for a control's backlash parameter, mm: −B̄ (positive for ordinary backlash)."""
        return -self.B_mean

    @property
    def mean_bi(self) -> np.ndarray:
        return 0.5 * (self.up + self.down)

    def correction(self, x, direction, mode: str = "bidirectional") -> np.ndarray:
        """Command correction (mm) to add at commanded positions x (mm) reached moving in
        `direction` (+1 / −1 per position, or one value): linear between the targets, held
        constant beyond them (as controls do)."""
        if mode not in MODES:
            raise InputError(f"mode must be one of {', '.join(MODES)}, got {mode!r}", field="mode")
        x = np.asarray(x, float)
        d = np.broadcast_to(np.asarray(direction, float), x.shape)
        if not np.all(np.isin(d, (-1.0, 1.0))):
            raise InputError("direction must be +1 or -1", field="direction")
        if mode == "bidirectional":
            cu = -np.interp(x, self.position, self.up)
            cd = -np.interp(x, self.position, self.down)
            return np.where(d > 0, cu, cd)
        c = -np.interp(x, self.position, self.mean_bi)
        if mode == "backlash":
            c = c - d * self.B_mean / 2.0
        return c

    def compensate(self, x, direction, mode: str = "bidirectional") -> np.ndarray:
        """Compensated commands for programmed positions x (mm) approached in `direction`."""
        return np.asarray(x, float) + self.correction(x, direction, mode)

    @property
    def half(self) -> np.ndarray:
        """B_i / 2, mm: the direction-dependent part of the deviation (+ moving up, − moving down)
        about the bidirectional mean that the component tables carry."""
        return 0.5 * self.reversal_i

    @classmethod
    def from_csv(cls, path: str | os.PathLike, axis: str | None = None) -> "ReversalTable":
        """Read a table written by `to_csv` (columns position, dev_up, dev_down, more ignored;
        mm); the axis from the header comment unless given.  Errors name file, line, column."""
        from ..csvtable import read_csv
        tab = read_csv(path, what="reversal table", min_rows=2)
        need = ("position", "dev_up", "dev_down")
        missing = [c for c in need if not tab.has(c)]
        if missing:
            raise tab.error(f"header must contain {','.join(need)}; missing {','.join(missing)}")
        pos = tab.numbers("position", unit="mm")
        if np.any(np.diff(pos) <= 0):
            r = int(np.argmax(np.diff(pos) <= 0)) + 1
            raise tab.error("positions must grow from row to row", r, "position")
        up, dn = tab.numbers("dev_up", unit="mm", max_abs=1.0), tab.numbers("dev_down", unit="mm", max_abs=1.0)
        if axis is None:
            import re
            head = Path(path).read_text(errors="replace").splitlines()[:1]
            m = re.search(r"of axis (\S+):", head[0]) if head else None
            axis = m.group(1) if m and m.group(1) != "?" else ""
        return cls(axis, pos, up, dn, str(path))

    def to_csv(self) -> str:
        """position, mean deviation up / down, reversal B_i, correction up / down; mm."""
        buf = io.StringIO()
        buf.write(f"# mtcomp reversal table (ISO 230-2) of axis {self.axis or '?'}: mean deviations per "
                  "direction of approach and the corrections to add to the commands, mm\n")
        buf.write(f"# B = {self.B!r} mm, mean reversal B_mean = {self.B_mean!r} mm, backlash (lost motion) "
                  f"= {self.backlash!r} mm\n")
        buf.write("position,dev_up,dev_down,reversal,corr_up,corr_down\n")
        for p, u, d in zip(self.position, self.up, self.down):
            buf.write(",".join(repr(float(v)) for v in (p, u, d, u - d, -u, -d)) + "\n")
        return buf.getvalue()

    def fanuc_pitch(self, unit: float = 1e-6, interval: float | None = None, reference: float | None = None,
                    first_point: int = 0) -> str:
        """Fanuc-style bidirectional pitch error compensation table (CSV text).

        unit: detection unit, mm (1e-6 = 1 nm on an ultraprecision control, 1e-4 = 0.1 µm);
        interval: compensation interval, mm (default: the mean target spacing, rounded to the unit);
        reference: position of the reference point (default: the first target).  Points run from
        the reference in steps of `interval` over the targets' range.  The value of point n is the
        change of the correction from point n−1 to point n (incremental), per direction, in
        detection units, rounded so that the running sums never drift more than half a unit from
        the exact corrections.  The last lines give the backlash parameter (lost motion −B̄) and the
        correction at the reference point, both in detection units."""
        if not (np.isfinite(unit) and unit > 0):
            raise InputError(f"detection unit must be a positive mm value, got {unit!r}", field="unit")
        lo, hi = float(self.position[0]), float(self.position[-1])
        if interval is None:
            interval = float(np.round(np.mean(np.diff(self.position)) / unit) * unit)
        if not (np.isfinite(interval) and interval > 0):
            raise InputError(f"interval must be a positive mm value, got {interval!r}", field="interval")
        ref = lo if reference is None else float(reference)
        if not lo - 1e-9 <= ref <= hi + 1e-9:
            raise InputError(f"reference {ref:g} mm lies outside the measured range {lo:g} .. {hi:g} mm",
                             field="reference")
        k_lo = int(np.ceil((lo - ref) / interval - 1e-9))
        k_hi = int(np.floor((hi - ref) / interval + 1e-9))
        pts = ref + interval * np.arange(k_lo, k_hi + 1)
        cu = np.rint(-np.interp(pts, self.position, self.up) / unit).astype(np.int64)
        cd = np.rint(-np.interp(pts, self.position, self.down) / unit).astype(np.int64)
        iu, idn = np.diff(cu, prepend=cu[0]), np.diff(cd, prepend=cd[0])
        buf = io.StringIO()
        buf.write(f"# mtcomp Fanuc-style bidirectional pitch error compensation, axis {self.axis or '?'}\n")
        buf.write(f"# detection unit {float(unit)!r} mm; interval {float(interval)!r} mm; "
                  f"reference position {float(ref)!r} mm (point {first_point - k_lo}); "
                  f"points {first_point} .. {first_point + len(pts) - 1}\n")
        buf.write("# inc_up / inc_down: change of the correction from the previous point to this one, moving "
                  "in the positive / negative direction (the first point carries 0)\n")
        buf.write("# abs_up / abs_down: the correction itself at the point (add to the command)\n")
        buf.write("point,position_mm,inc_up,inc_down,abs_up,abs_down\n")
        for n, (p, a, b, u, d) in enumerate(zip(pts, iu, idn, cu, cd)):
            buf.write(f"{first_point + n},{float(p)!r},{int(a)},{int(b)},{int(u)},{int(d)}\n")
        buf.write(f"# backlash parameter (lost motion, -B_mean): {int(np.rint(self.backlash / unit))} detection units "
                  f"= {float(self.backlash)!r} mm; set it to 0 when the control applies the two tables above, which carry "
                  "the reversal themselves\n")
        return buf.getvalue()

    def write(self, directory: str | os.PathLike, unit: float = 1e-6, interval: float | None = None) -> list[Path]:
        """<axis>_reversal.csv (mm) and <axis>_pitch_bidirectional.csv (Fanuc-style), atomically."""
        d = Path(directory)
        name = self.axis or "axis"
        text = self.fanuc_pitch(unit, interval)       # computed before anything is written
        return [atomic_write(d / f"{name}_reversal.csv", self.to_csv()),
                atomic_write(d / f"{name}_pitch_bidirectional.csv", text)]


def reversal_table(result: Iso2302Result) -> ReversalTable:
    """The per-direction mean deviations of an ISO 230-2 evaluation."""
    r = result.run
    return ReversalTable(r.axis, np.asarray(r.target, float).copy(), np.asarray(result.mean_up).copy(),
                         np.asarray(result.mean_down).copy(), r.source)


# ---------------------------------------------------------------------------------------------
# Direction of approach of programmed positions, and the direction-dependent correction

def machining_order(lines, ends_first: bool = True) -> np.ndarray:
    """Order (N,) in which the rows handed to a compensation transform are reached: by program
    line; within one line its interior points (arc samples, cycle points) in the order given,
    and, when the block's end point is among the rows (``ends_first``: every line's first row is
    its end, as `gcode.rewrite_with_lines` hands them over), that end last."""
    lines = np.asarray(lines)
    n = len(lines)
    is_end = np.zeros(n, bool)
    if ends_first and n:
        _, first = np.unique(lines, return_index=True)
        is_end[first] = True
    return np.lexsort((np.arange(n), is_end, lines))


def approach_directions(x, initial: float = 1.0) -> np.ndarray:
    """+1 / −1 (N,): the direction each position of the sequence x (mm) is approached in: the
    sign of the move into it; a row the axis does not move to keeps the direction before it (the
    lost motion stays taken up that way); rows before the axis' first move take `initial`, the
    direction the slide is assumed to have last moved in before the sequence (+1: as after a
    reference run or a positive approach; the state before a program is not in the program)."""
    x = np.asarray(x, float)
    s = np.sign(np.diff(x, prepend=x[:1] if x.size else x))
    moved = np.flatnonzero(s)
    if not moved.size:
        return np.full(x.shape, float(initial))
    idx = np.where(s != 0, np.arange(s.size), 0)
    np.maximum.accumulate(idx, out=idx)
    d = s[idx]
    d[:moved[0]] = initial
    return d


def direction_terms(axes, reversal: dict, q, directions, sign: float) -> np.ndarray:
    """(N, n) mm: sign * d B_i(x)/2 on every axis with a reversal table (`ReversalTable`), d the
    direction of approach per row and axis ((N, n) of +1 / -1, default +1).  sign = +1 gives the
    deviation a machine with that reversal adds, -1 the command correction that removes it."""
    q = np.atleast_2d(np.asarray(q, float))
    out = np.zeros_like(q)
    d = np.ones_like(q) if directions is None else np.broadcast_to(np.asarray(directions, float), q.shape)
    names = list(axes)
    for ax, tab in (reversal or {}).items():
        if ax not in names:
            raise InputError(f"reversal table of axis {ax}, but the axes are {' '.join(names)}", field="reversal")
        k = names.index(ax)
        out[:, k] = sign * d[:, k] * np.interp(q[:, k], tab.position, tab.half)
    return out


def direction_corrections(q, axis_names, reversal: dict, lines=None, ends_first: bool = True,
                          initial: float = 1.0) -> np.ndarray:
    """Command corrections (N, n_axes) mm for the direction of approach: −d B_i(x)/2 on every axis
    with a reversal table (`ReversalTable`, by axis name), B_i interpolated linearly and held
    beyond the ends.  q: the commands after the bidirectional-mean correction, i.e. where each
    slide must go; d: the direction each row is reached in, from q in machining order
    (`machining_order` of the rows' program lines, or as given).

    Why q and not the programmed positions: an axis the program holds still still moves by the
    mean correction of the others' errors (straightness: tens of µm), and each such move is a
    reversal for the play.  This is the exact inverse of a play (backlash) of lost motion −B_i:
    to bring the slide up to y the command goes to y + b/2, down to y − b/2, and it stays where
    it was while y stays (tested against a play operator written out).  Added to the mean
    correction it equals ISO 230-2's bidirectional correction (`ReversalTable.correction`)."""
    q = np.atleast_2d(np.asarray(q, float))
    if not len(q):
        return np.zeros_like(q)
    order = machining_order(lines, ends_first) if lines is not None else np.arange(len(q))
    d = np.ones_like(q)
    names = list(axis_names)
    for ax in reversal:
        k = names.index(ax) if ax in names else None
        if k is not None:      # (an unknown axis is refused by direction_terms)
            d[order, k] = approach_directions(q[order, k], initial)
    return direction_terms(axis_names, reversal, q, d, -1.0)


def played_positions(q, axis_names, reversal: dict, initial: float = 1.0) -> np.ndarray:
    """Where the slides of a machine with these reversals stand (N, n_axes) mm for the commands q
    reached in row order: q + d B_i(x)/2 on every axis with a table, d the direction each row is
    approached in (the play model whose inverse is `direction_corrections`).  What the checks of
    a compensated program run through the forward model: a command corrected for the direction
    of approach is meant to be half a reversal off, the slide is not."""
    q = np.atleast_2d(np.asarray(q, float))
    if not len(q) or not reversal:
        return q
    d = np.ones_like(q)
    names = list(axis_names)
    for ax in reversal:
        if ax in names:
            k = names.index(ax)
            d[:, k] = approach_directions(q[:, k], initial)
    return q + direction_terms(axis_names, reversal, q, d, 1.0)


def load_reversal(paths) -> dict:
    """{axis: ReversalTable} from reversal CSVs (`ReversalTable.to_csv`); an axis twice is an error."""
    out = {}
    for p in paths:
        t = ReversalTable.from_csv(p)
        if not t.axis:
            raise InputError("the reversal table names no axis (header '... of axis X: ...')", p)
        if t.axis in out:
            raise InputError(f"a second reversal table for axis {t.axis} (first: {out[t.axis].source})", p)
        out[t.axis] = t
    return out
