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

__all__ = ["ReversalTable", "reversal_table", "MODES"]

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
