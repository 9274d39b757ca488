"""Heidenhain TNC: nonlinear axis error compensation (*.COM tables assigned in a *.CMA table)
and the rotary axes in a kinematics description table (KEY / AXIS / COORD).

Formats (docs/control.md; HEIDENHAIN technical manuals: TNC 407/415/425 "Non-linear axis error
compensation" (MP730, *.CMA/*.COM, module 9095: at most 256 entries per *.COM table),
MANUALplus 620 "Entering compensation values" (AXISPOS column, BACKLASH column for the values of
the negative direction, [axis in a *.COM column] = F(axis of the *.CMA column it is entered in),
ACTIVE column), iTNC 530 HSCI "description table" (KEY Trans / MachAxis / MachBase, AXIS, COORD)):

* ``<K>.COM``, one per input axis K: columns NR, AXISPOS (position of K, mm or deg), one column
  per compensated axis (K itself: pitch; another linear axis: its straightness as a function of
  K), BACKLASH (pitch of K moving in the negative direction); values in mm or deg with 4
  decimals (0.1 µm, 0.0001 deg);
* ``CONFIG.CMA``: NR, ACTIVE (``*``), one column per input axis naming its *.COM table;
* ``KINEMATICS.TAB``: the rotary axes as seen from the tool reference point: per rotary axis
  ``Trans X/Y/Z`` to its pivot (mm), ``Trans A/B/C`` of its tilts (deg, the component about its
  own axis excluded), ``MachAxis K``, ``Trans K`` of its zero error (deg, not undone), then the
  tilts and the pivot undone.  mm 4 decimals, deg 7 decimals.
Tables are written in the TNC's table text: a ``BEGIN <name> MM`` line, a header line of
column names, rows in the same columns, ``[END]``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .._io import InputError
from ..machine import Machine
from .common import ControlLimitError, PitchTable, Quantum, Split, error_to_control

NAME = "heidenhain"
HOLDS_STRAIGHTNESS = True
MAX_POINTS = 256
Q = Quantum(4)            # mm and deg in the *.COM tables
Q_MM = Quantum(4)         # kinematics: mm
Q_DEG = Quantum(7)        # kinematics: deg
CMA = "CONFIG.CMA"
KIN = "KINEMATICS.TAB"
_W = 14


def _table_text(name: str, cols: list[str], rows: list[list[str]]) -> str:
    widths = [max(_W, len(c) + 2) for c in cols]
    out = [f"BEGIN {name} MM", "".join(c.ljust(w) for c, w in zip(cols, widths)).rstrip()]
    out += ["".join(v.ljust(w) for v, w in zip(r, widths)).rstrip() for r in rows]
    out.append("[END]")
    return "\n".join(out) + "\n"


def _parse_table(path: Path) -> tuple[list[str], list[list[str]]]:
    if not path.exists():
        raise InputError("missing Heidenhain table", path)
    lines = [s for s in path.read_text(encoding="utf-8").splitlines() if s.strip()]
    if len(lines) < 2 or not lines[0].startswith("BEGIN") or lines[-1].strip() != "[END]":
        raise InputError("expected 'BEGIN <name> MM', a header line, rows and '[END]'", path)
    cols = lines[1].split()
    rows = []
    for k, s in enumerate(lines[2:-1], 3):
        r = s.split()
        if len(r) != len(cols):
            raise InputError(f"expected {len(cols)} columns ({' '.join(cols)}), got {len(r)}", path, k)
        rows.append(r)
    return cols, rows


def _signed(n: int, q: Quantum) -> str:
    t = q.text(n)
    return t if t.startswith("-") else "+" + t


def export(machine: Machine, split: Split) -> tuple[dict, set, list, list, dict]:
    files, held, notes = {}, [], []
    inputs = sorted({ax for ax in split.pitch} | {ax for ax, _ in split.straightness},
                    key="XYZUVWABC".index)
    for ax in inputs:
        pos = split.pitch[ax].position if ax in split.pitch else split.straightness[
            next(k for k in split.straightness if k[0] == ax)][0]
        what = f"{ax}.COM"
        if pos.size > MAX_POINTS:
            raise ControlLimitError(f"{pos.size} points; a *.COM table holds at most {MAX_POINTS}", field=what)
        cols, data = ["NR", "AXISPOS"], [[str(i), _signed(int(n), Q)] for i, n in enumerate(Q.count(pos))]
        if not np.array_equal(Q.value(Q.count(pos)), pos):
            raise ControlLimitError("positions are not whole multiples of 0.0001", field=what)
        outs = []
        p = split.pitch.get(ax)
        if p is not None:
            outs.append((ax, Q.count(error_to_control(ax, p.up))))
        for (a, d), (pos2, v) in split.straightness.items():
            if a == ax:
                if not np.array_equal(pos2, pos):
                    raise ControlLimitError(f"E{d}{a} has other positions than the pitch table", field=what)
                outs.append((d, Q.count(-v)))
        for name, v in outs:
            cols.append(name)
            for r, n in zip(data, v):
                r.append(_signed(int(n), Q))
        if p is not None and p.bidirectional:
            cols.append("BACKLASH")
            for r, n in zip(data, Q.count(error_to_control(ax, p.down))):
                r.append(_signed(int(n), Q))
        files[f"{ax}.COM"] = _table_text(f"{ax}.COM", cols, data)
        held.append(f"{ax}.COM: {', '.join(c for c in cols[2:])} as functions of {ax}")
    if inputs:
        files[CMA] = _table_text(CMA, ["NR", "ACTIVE", *inputs], [["0", "*", *[f"{a}.COM" for a in inputs]]])
    held_loc: set = set()
    rot = [a for a in machine.axes if a.is_rotary]
    if rot:
        rows = []
        for a in reversed(machine.axes):          # from the tool reference point to the table
            if a.side == "workpiece" and not any(r[0] == "MachBase" for r in rows):
                rows.append(["MachBase", "", ""])
            if not a.is_rotary:
                rows.append(["MachAxis", a.name, ""])
                continue
            own = "ABC"[int(np.argmax(np.abs(a.direction)))]
            piv = [(c, int(Q_MM.count(split.location.get(f"E{c}0{a.name}", 0.0) + a.location[k])))
                   for k, c in enumerate("XYZ")]
            tilt = [(c, int(Q_DEG.count(np.degrees(split.location.get(f"E{c}0{a.name}", 0.0)))))
                    for c in "ABC" if c != own]
            zero = int(Q_DEG.count(np.degrees(split.location.get(f"E{own}0{a.name}", 0.0))))
            rows += [["Trans", c, Q_MM.text(n)] for c, n in piv if n]
            rows += [["Trans", c, Q_DEG.text(n)] for c, n in tilt if n]
            rows.append(["MachAxis", a.name, ""])
            if zero:
                rows.append(["Trans", own, Q_DEG.text(zero)])
            rows += [["Trans", c, Q_DEG.text(-n)] for c, n in reversed(tilt) if n]
            rows += [["Trans", c, Q_MM.text(-n)] for c, n in reversed(piv) if n]
            held_loc |= {f"E{c}0{a.name}" for c in "XYZABC"} & set(split.location)
        if not any(r[0] == "MachBase" for r in rows):
            rows.append(["MachBase", "", ""])
        files[KIN] = _table_text(KIN, ["NR", "KEY", "AXIS", "COORD"],
                                 [[str(i), k, ax or "-", c or "-"] for i, (k, ax, c) in enumerate(rows)])
        held.append(f"{KIN}: pivots, tilts and zero errors of {', '.join(a.name for a in rot)}")
    return files, held_loc, held, notes, {}


def read(machine: Machine, directory: Path) -> tuple[dict, dict, dict]:
    cols, rows = _parse_table(directory / CMA)
    if not rows:
        raise InputError("no row in the assignment table", directory / CMA)
    active = next((r for r in rows if "ACTIVE" in cols and r[cols.index("ACTIVE")] == "*"), rows[0])
    pitch, straight = {}, {}
    for c, name in zip(cols, active):
        if c in ("NR", "ACTIVE") or name == "-":
            continue
        if c not in machine.axis_names:
            raise InputError(f"column {c}: machine {machine.name} has no such axis", directory / CMA)
        tc, tr = _parse_table(directory / name)
        pos = Q.value([int(Q.count(float(r[tc.index("AXISPOS")]))) for r in tr])
        for out in tc[2:]:
            if out == "BACKLASH":
                continue
            n = np.array([int(Q.count(float(r[tc.index(out)]))) for r in tr], np.int64)
            if out == c:
                nd = (np.array([int(Q.count(float(r[tc.index("BACKLASH")]))) for r in tr], np.int64)
                      if "BACKLASH" in tc else n)
                pitch[c] = PitchTable.from_counts(c, pos, Q, n, nd)
            else:
                straight[(c, out)] = (pos, -Q.value(n))
    location = {}
    kin = directory / KIN
    if kin.exists():
        location = _read_kinematics(machine, kin)
    return pitch, straight, location


def _read_kinematics(machine: Machine, path: Path) -> dict:
    """Location errors from the rows written by `export`: the Trans rows before a rotary
    MachAxis (pivot in mm, tilts in deg), a Trans about its own axis right after it (zero error),
    then as many rows undoing the set-up, which are skipped."""
    kc, kr = _parse_table(path)
    rows = [(r[kc.index("KEY")], r[kc.index("AXIS")], r[kc.index("COORD")]) for r in kr]
    location, setup, i = {}, [], 0
    while i < len(rows):
        key, ax, coord = rows[i]
        i += 1
        if key == "Trans":
            setup.append((ax, float(coord)))
            continue
        if key == "MachAxis" and ax in machine.axis_names and machine.axis(ax).is_rotary:
            a = machine.axis(ax)
            for c, v in setup:
                if c in "XYZ":
                    location[f"E{c}0{ax}"] = float(Q_MM.value(Q_MM.count(v - a.location["XYZ".index(c)])))
                else:
                    location[f"E{c}0{ax}"] = float(np.radians(v))
            if i < len(rows) and rows[i][0] == "Trans" and rows[i][1] == _own(a):
                location[f"E{rows[i][1]}0{ax}"] = float(np.radians(float(rows[i][2])))
                i += 1
            i += len(setup)            # the rows undoing the set-up
        setup = []
    return location


def _own(a) -> str:
    return "ABC"[int(np.argmax(np.abs(a.direction)))]
