"""Shared pieces of the control exports: what goes to a control, quantising, limits, writing.

An export splits an `ErrorSet` (plus optional reversal tables) into

* pitch tables: the positioning error of each axis (EXX for X, ECC for C ...) per direction of
  approach (`PitchTable`), which every control compensates per axis;
* straightness tables: EYX, EZX ... (mm) of the linear axes, which some controls compensate as
  a cross-axis table (Siemens CEC, Heidenhain *.COM);
* rotary-axis location errors (EX0C, EA0C, EC0C ...), which go into the parameters of the
  control's 5-axis transformation where it has one;
* the remainder: everything the control cannot hold, written as an errors TOML for the NC rewrite.

Values are errors of the tool relative to the workpiece (ISO 230-1, mm and rad); a control's
correction is their negative (first order: the table is indexed by the commanded position, and
the error's change over one correction, about 1e-5 x 10 µm, is far below any increment).
Quantities a control holds in increments are rounded once, through integers, so that an import
gives back exactly the float an export started from (`Quantum`).
"""
from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._io import InputError, atomic_write
from ..errors import AxisErrorTable, ErrorSet, GeometricErrors, component_names
from ..machine import Machine

__all__ = ["ControlLimitError", "PitchTable", "Split", "Quantum", "split_errors", "merge_errors",
           "write_files", "equal_steps", "read_reversal_csv", "LOCATION_COMPONENTS"]

_LIN = "XYZ"
# location errors of a rotary axis K, in the order the exports use them
LOCATION_COMPONENTS = ("EX0", "EY0", "EZ0", "EA0", "EB0", "EC0")


class ControlLimitError(InputError):
    """A table or parameter does not fit the control's limits (named in the message)."""


@dataclass(frozen=True)
class Quantum:
    """An increment 10**-decimals of mm or deg, and exact conversions to and from it.

    `count(x)` rounds a value (in the control's unit) to whole increments; `value(n)` gives the
    float back as n / 10**decimals, the same float Python reads from the decimal text."""
    decimals: int

    @property
    def scale(self) -> int:
        return 10 ** self.decimals

    @property
    def step(self) -> float:
        return 1.0 / self.scale

    def count(self, x) -> np.ndarray:
        return np.rint(np.asarray(x, float) * self.scale).astype(np.int64)

    def value(self, n) -> np.ndarray:
        return np.asarray(n, np.int64) / self.scale

    def text(self, n: int) -> str:
        """Decimal text of n increments, e.g. 1234 at 4 decimals -> '0.1234'."""
        n = int(n)
        if self.decimals == 0:
            return str(n)
        sign = "-" if n < 0 else ""
        s = str(abs(n)).rjust(self.decimals + 1, "0")
        return f"{sign}{s[:-self.decimals]}.{s[-self.decimals:]}"

    @classmethod
    def of(cls, resolution: float) -> "Quantum":
        return cls(max(0, int(round(-math.log10(resolution)))))


def error_to_control(axis: str, e) -> np.ndarray:
    """Correction in the control's unit (mm, or deg for a rotary axis) of an error (mm or rad)."""
    e = np.asarray(e, float)
    return -np.degrees(e) if axis in "ABC" else -e


def control_to_error(axis: str, c) -> np.ndarray:
    """Inverse of `error_to_control`."""
    c = np.asarray(c, float)
    return -np.radians(c) if axis in "ABC" else -c


def deg_of(rad) -> np.ndarray:
    return np.degrees(np.asarray(rad, float))


def rad_of(deg) -> np.ndarray:
    return np.radians(np.asarray(deg, float))


@dataclass(frozen=True)
class PitchTable:
    """Positioning error of one axis per direction of approach, tool relative to workpiece.

    position (m,) mm or deg, strictly increasing; up / down (m,) the error (mm, or rad for a
    rotary axis) reached moving in the positive / negative direction.  Without reversal data
    up == down == the table's mean (EXX, ECC ...)."""
    axis: str
    position: np.ndarray
    up: np.ndarray
    down: np.ndarray
    counts: tuple | None = None     # (Quantum, forward, reverse corrections in increments) as read

    @property
    def mean(self) -> np.ndarray:
        if self.counts is not None:   # through the integers: the float an export started from
            q, cu, cd = self.counts
            return control_to_error(self.axis, (np.asarray(cu, np.int64) + cd) / (2 * q.scale))
        return 0.5 * (self.up + self.down)

    @property
    def half(self) -> np.ndarray:
        """Half the reversal, (up - down) / 2 (mm or rad)."""
        if self.counts is not None:
            q, cu, cd = self.counts
            return control_to_error(self.axis, (np.asarray(cu, np.int64) - cd) / (2 * q.scale))
        return 0.5 * (self.up - self.down)

    @classmethod
    def from_counts(cls, axis: str, position, q: "Quantum", cu, cd) -> "PitchTable":
        """A table read from a control: corrections in increments of q, per direction."""
        cu, cd = np.asarray(cu, np.int64), np.asarray(cd, np.int64)
        return cls(axis, np.asarray(position, float), control_to_error(axis, q.value(cu)),
                   control_to_error(axis, q.value(cd)), (q, cu, cd))

    @property
    def bidirectional(self) -> bool:
        return not np.array_equal(self.up, self.down)


@dataclass(frozen=True)
class Split:
    """An error set split by what controls hold (see the module docstring).

    pitch: axis -> PitchTable; straightness: (axis, direction) -> (position, values mm), e.g.
    ("X", "Y") for EYX; location: rotary-axis location errors {name: value}; rest: the ErrorSet
    of everything else (angular components, squareness, linear-axis location errors, setting
    errors)."""
    pitch: dict
    straightness: dict
    location: dict
    rest: ErrorSet


def equal_steps(position: np.ndarray, q: Quantum, what: str) -> tuple[int, int, int]:
    """(first, step, count) in increments of a table with equally spaced positions on the
    increment grid; refuses by name otherwise."""
    n = q.count(position)
    if not np.array_equal(q.value(n), np.asarray(position, float)):
        i = int(np.argmax(q.value(n) != position))
        raise ControlLimitError(f"position {float(position[i])!r} is not a whole number of "
                                f"{q.text(1)} increments", field=what)
    d = np.diff(n)
    if d.size == 0 or np.any(d != d[0]):
        i = int(np.argmax(d != d[0])) + 1 if d.size else 0
        raise ControlLimitError(f"positions are not equally spaced (step {q.text(d[0])} before row "
                                f"{i + 1}, {q.text(d[i])} there): this control needs a constant "
                                f"interval; resample the table first", field=what)
    return int(n[0]), int(d[0]), int(n.size)


def read_reversal_csv(path: str | os.PathLike, axis: str | None = None):
    """A ReversalTable from the CSV `ReversalTable.to_csv` writes (position, dev_up, dev_down; mm)."""
    from ..csvtable import read_csv
    from ..geometric.reversal import ReversalTable
    t = read_csv(path, what="reversal table")
    for c in ("position", "dev_up", "dev_down"):
        if not t.has(c):
            raise t.error(f"missing column {c!r} (expected position,dev_up,dev_down,... as "
                          f"'mtcomp geometric reversal' writes)")
    pos = t.numbers("position", unit="mm")
    if np.any(np.diff(pos) <= 0):
        raise t.error("positions must increase strictly", None, "position")
    m = re.search(r"(?:^|_)([XYZUVW])_reversal\.csv$", Path(path).name, re.IGNORECASE)
    if axis is None and m is None:
        raise InputError("cannot tell the axis: name the file <axis>_reversal.csv (as 'mtcomp geometric "
                         "reversal' does)", path)
    name = axis or m.group(1).upper()
    return ReversalTable(name, pos, t.numbers("dev_up", unit="mm"), t.numbers("dev_down", unit="mm"),
                         str(path))


def _positioning_name(axis: str) -> str:
    return f"E{axis}{axis}"


def split_errors(machine: Machine, errors: ErrorSet, reversal: dict | None = None) -> Split:
    """Split an error set by what a control can hold.  `reversal`: {axis: ReversalTable} of
    linear axes; its half reversal (up - mean, at the table's positions) is added to the
    positioning error per direction."""
    reversal = dict(reversal or {})
    g = errors.geometric
    pitch, straight, rest_tables = {}, {}, {}
    for ax, t in g.tables.items():
        vals = dict(t.values)
        pname = _positioning_name(ax)
        if pname in vals or ax in reversal:
            mean = np.asarray(vals.pop(pname, np.zeros(t.position.size)), float)
            up = down = mean
            if ax in reversal:
                r = reversal.pop(ax)
                if machine.axis(ax).is_rotary:
                    raise InputError(f"reversal table for rotary axis {ax}: only linear axes", field=ax)
                half = 0.5 * (np.interp(t.position, r.position, r.up) - np.interp(t.position, r.position, r.down))
                up, down = mean + half, mean - half
            pitch[ax] = PitchTable(ax, t.position, up, down)
        if ax in _LIN:
            for d in _LIN:
                if d != ax and f"E{d}{ax}" in vals:
                    straight[(ax, d)] = (t.position, np.asarray(vals.pop(f"E{d}{ax}"), float))
        if vals:
            rest_tables[ax] = AxisErrorTable(ax, t.position, vals)
    if reversal:
        ax = next(iter(reversal))
        raise InputError(f"reversal table for axis {ax}, but the errors have no table of axis {ax} "
                         f"(the pitch table's positions come from it)", field=ax)
    rotary = {a.name for a in machine.axes if a.is_rotary}
    loc = {k: v for k, v in g.location.items() if k[-1] in rotary}
    rest_loc = {k: v for k, v in g.location.items() if k not in loc}
    rest = ErrorSet(errors.tool, errors.workpiece, GeometricErrors(rest_tables, rest_loc))
    return Split(pitch, straight, loc, rest)


def merge_errors(pitch: dict, straightness: dict, location: dict, remainder: ErrorSet | None):
    """Inverse of `split_errors`: (ErrorSet, {axis: ReversalTable} of the bidirectional tables)."""
    from ..geometric.reversal import ReversalTable
    remainder = remainder or ErrorSet()
    g = remainder.geometric
    tables: dict[str, tuple[np.ndarray, dict]] = {ax: (t.position, dict(t.values)) for ax, t in g.tables.items()}

    def add(ax, pos, name, v):
        if ax not in tables:
            tables[ax] = (pos, {})
        p0, vals = tables[ax]
        if not np.array_equal(p0, pos):
            raise InputError(f"the control's table of axis {ax} has other positions than the "
                             f"remainder's ({pos.size} vs {p0.size} points)", field=name)
        vals[name] = vals[name] + v if name in vals else v
    rev = {}
    for ax, p in pitch.items():
        name = _positioning_name(ax)
        prior = tables.get(ax, (None, {}))[1].get(name)
        if prior is not None and p.counts is not None:
            # a part the control left to the program (Fanuc's constant at the reference): add it in
            # the control's increments, so that the sum is the float the export started from
            q, cu, cd = p.counts
            k = np.rint(error_to_control(ax, prior) * 2 * q.scale).astype(np.int64)
            if np.array_equal(control_to_error(ax, k / (2 * q.scale)), prior):
                tables[ax][1][name] = control_to_error(ax, (cu + cd + k) / (2 * q.scale))
                if p.bidirectional:
                    rev[ax] = ReversalTable(ax, p.position, p.half, -p.half)
                continue
        add(ax, p.position, name, p.mean)
        if p.bidirectional:
            h = p.half
            rev[ax] = ReversalTable(ax, p.position, h, -h)
    for (ax, d), (pos, v) in straightness.items():
        add(ax, pos, f"E{d}{ax}", v)
    names = {ax: set(component_names(ax)) for ax in tables}
    built = {ax: AxisErrorTable(ax, pos, {k: v for k, v in vals.items() if k in names[ax]})
             for ax, (pos, vals) in tables.items()}
    loc = dict(g.location)
    loc.update(location)
    return ErrorSet(remainder.tool, remainder.workpiece, GeometricErrors(built, loc)), rev


@dataclass(frozen=True)
class ExportResult:
    """Files written, what the control holds, and what stays for the NC rewrite."""
    control: str
    files: tuple
    held: tuple            # lines: what the control's files hold
    remainder: ErrorSet    # what stays for the program
    notes: tuple = ()
    figures: dict = field(default_factory=dict)

    def summary(self) -> str:
        lines = [f"{self.control}: {len(self.files)} files"]
        lines += [f"  holds: {h}" for h in self.held]
        g = self.remainder.geometric
        left = [f"{ax} table ({', '.join(sorted(t.values))})" for ax, t in g.tables.items()]
        left += sorted(g.location)
        if not self.remainder.tool.is_zero:
            left.append("tool setting")
        if not self.remainder.workpiece.is_zero:
            left.append("workpiece setting")
        lines.append("  stays for the NC rewrite (remainder.toml): " + (", ".join(left) if left else "nothing"))
        for k, v in self.figures.items():
            lines.append(f"  {k}: {v}")
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines) + "\n"


def write_files(directory: str | os.PathLike, texts: dict) -> tuple:
    """Write every {name: text} atomically into `directory` (all texts are computed before the
    first is written, so a refusal leaves nothing behind)."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    return tuple(atomic_write(d / name, text) for name, text in texts.items())
