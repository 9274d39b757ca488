"""Fanuc: bidirectional pitch error compensation (parameters 3605#0, 3620-3627 and the pitch
error data), as a parameter tape and a pitch-data tape.

Conventions (docs/control.md; Fanuc Series 16i/18i-MA technical report A-77810E "Bidirectional
pitch error compensation", Series 0i-PB parameter manual B-63980EN section on 3620-3625):

* compensation points are numbered 0 .. 1023 for all axes together; point n of an axis sits at
  the machine position (n - No.3620) x No.3624, the reference position (machine zero) being the
  point No.3620; No.3621 / No.3622 are the points at the negative / positive end of the table;
* the value of point n is the change of the correction from point n-1 to point n (incremental),
  in detection units times the magnification No.3623; the first point's value is 0;
* bidirectional (No.3605#0 = 1): the points No.3621 .. No.3622 hold the table for travel in the
  positive direction, a second block from No.3626 the table for the negative direction, and
  No.3627 the correction at the reference position moving in the negative direction (detection
  units); in the positive direction the correction at the reference position is 0 by definition
  of the machine zero (a constant there belongs to the reference position, parameter 1850);
* tape format: ``N<param>A<axis>P<value>...`` per parameter, ``N<10000 + point>P<value>`` per
  pitch error point, each tape between ``%`` lines.

Limits checked: points 0 .. 1023, each value within +-7 (times the magnification, 0 .. 100), the
interval a whole number of detection units, the table equally spaced and covering the reference
position.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .._io import InputError
from ..machine import Machine
from .common import (ControlLimitError, PitchTable, Quantum, Split, control_to_error, equal_steps,
                     error_to_control)

NAME = "fanuc"
N_POINTS = 1024          # compensation point numbers 0 .. 1023 (all axes together)
MAX_VALUE = 7            # per point, in units of detection unit x magnification
MAX_MAGNIFICATION = 100
PARAM_TAPE = "fanuc-params.txt"
PITCH_TAPE = "fanuc-pitch.txt"
PITCH_BASE = 10000       # tape address of pitch error point 0
_ORDER = "XYZUVWABC"


def axis_numbers(machine: Machine) -> dict:
    """Controlled axis number (1-based, No.1020 order) of every axis: X Y Z (U V W) A B C."""
    return {a: i + 1 for i, a in enumerate(sorted(machine.axis_names, key=_ORDER.index))}


def _magnify(cu: np.ndarray, cd: np.ndarray, what: str) -> tuple[int, np.ndarray, np.ndarray]:
    """Smallest magnification m with every incremental value within +-7 m: first one that divides
    every correction (nothing rounded), else the smallest after rounding the corrections to
    multiples of m: (m, cu, cd) as written."""
    for m in range(1, MAX_MAGNIFICATION + 1):
        if (np.all(cu % m == 0) and np.all(cd % m == 0)
                and max(np.max(np.abs(np.diff(cu))), np.max(np.abs(np.diff(cd)))) <= MAX_VALUE * m):
            return m, cu, cd
    for m in range(1, MAX_MAGNIFICATION + 1):
        ru, rd = np.rint(cu / m).astype(np.int64), np.rint(cd / m).astype(np.int64)
        if max(np.max(np.abs(np.diff(ru)), initial=0), np.max(np.abs(np.diff(rd)), initial=0)) <= MAX_VALUE:
            return m, ru * m, rd * m
    worst = max(np.max(np.abs(np.diff(cu)), initial=0), np.max(np.abs(np.diff(cd)), initial=0))
    raise ControlLimitError(f"the correction changes by {worst} detection units between two points; "
                            f"Fanuc holds at most {MAX_VALUE} x magnification ({MAX_MAGNIFICATION}) = "
                            f"{MAX_VALUE * MAX_MAGNIFICATION}: use a smaller interval", field=what)


def export(machine: Machine, split: Split) -> tuple[dict, set, list, list, dict]:
    """(files, location names held, what is held, notes, tables left for the program)."""
    numbers = axis_numbers(machine)
    params: dict[int, dict[int, int]] = {k: {} for k in (3605, 3620, 3621, 3622, 3623, 3624, 3626, 3627)}
    data: dict[int, int] = {}
    held, notes, left = [], [], {}
    nxt = 0
    for ax in sorted(split.pitch, key=_ORDER.index):
        p = split.pitch[ax]
        what = f"{ax} pitch"
        q = Quantum.of(machine.axis(ax).resolution)
        first, step, m = equal_steps(p.position, q, what)
        if not (first <= 0 <= first + step * (m - 1)) or first % step:
            raise ControlLimitError(f"the table ({q.text(first)} .. {q.text(first + step * (m - 1))} "
                                    f"{machine.axis(ax).unit}, interval {q.text(step)}) must have a point at the "
                                    f"reference position 0", field=what)
        r = -first // step
        cu = q.count(error_to_control(ax, p.up))
        cd = q.count(error_to_control(ax, p.down))
        if cu[r] != 0:
            notes.append(f"{ax}: the positive-direction correction at the reference position "
                         f"({q.text(cu[r])} {machine.axis(ax).unit}) belongs to the reference position "
                         f"(grid shift, parameter 1850): it is left out of the table, for the program")
            left[ax] = (p.position, {f"E{ax}{ax}": np.full(m, float(control_to_error(ax, q.value(cu[r]))))})
        cd = cd - cu[r]
        cu = cu - cu[r]
        mag, cu, cd = _magnify(cu, cd, what)
        bi = bool(np.any(cu != cd))
        need = m * (2 if bi else 1)
        if nxt + need > N_POINTS:
            raise ControlLimitError(f"needs points {nxt} .. {nxt + need - 1}; Fanuc has {N_POINTS} "
                                    f"(0 .. {N_POINTS - 1}) for all axes", field=what)
        a = numbers[ax]
        params[3605][a] = 1 if bi else 0
        params[3620][a] = nxt + r
        params[3621][a] = nxt
        params[3622][a] = nxt + m - 1
        params[3623][a] = mag
        params[3624][a] = step
        for k, v in enumerate(np.diff(cu, prepend=cu[0]) // mag):
            data[nxt + k] = int(v)
        if bi:
            params[3626][a] = nxt + m
            params[3627][a] = int(cd[r])
            for k, v in enumerate(np.diff(cd, prepend=cd[0]) // mag):
                data[nxt + m + k] = int(v)
        held.append(f"axis {a} ({ax}) pitch, {'bidirectional' if bi else 'both directions'}, points "
                    f"{nxt} .. {nxt + need - 1}, interval {q.text(step)} {machine.axis(ax).unit}, magnification {mag}")
        nxt += need
    lines = ["%"]
    for no, per_axis in params.items():
        if not per_axis:
            continue
        fmt = (lambda v: f"{v:08b}") if no == 3605 else str
        lines.append(f"N{no}" + "".join(f"A{a}P{fmt(v)}" for a, v in sorted(per_axis.items())))
    lines.append("%")
    files = {PARAM_TAPE: "\n".join(lines) + "\n",
             PITCH_TAPE: "%\n" + "".join(f"N{PITCH_BASE + n}P{v}\n" for n, v in sorted(data.items())) + "%\n"}
    if split.straightness:
        notes.append("straightness is not exported to Fanuc (its straightness compensation option is not "
                     "covered here): it stays for the NC rewrite")
    if split.location:
        notes.append("Fanuc's tool centre point machine parameters are not exported: the rotary axis location "
                     "errors stay for the NC rewrite")
    return files, set(), held, notes, left


_WORD = re.compile(r"([NAP])(-?\d+)")


def _read_tape(path: Path) -> list[list[tuple[str, int]]]:
    if not path.exists():
        raise InputError("missing Fanuc tape", path)
    out = []
    for k, line in enumerate(path.read_text(encoding="ascii", errors="replace").splitlines(), 1):
        s = line.strip()
        if not s or s == "%":
            continue
        words = _WORD.findall(s)
        if not words or "".join(f"{a}{b}" for a, b in words) != s.replace(" ", ""):
            raise InputError(f"expected N..A..P.. or N..P.. words, got {s[:40]!r}", path, k)
        out.append([(a, int(b)) for a, b in words])
    return out


def read(machine: Machine, directory: Path) -> tuple[dict, dict, dict]:
    numbers = axis_numbers(machine)
    by_number = {v: k for k, v in numbers.items()}
    params: dict[int, dict[int, int]] = {}
    tape = directory / PARAM_TAPE
    for words in _read_tape(tape):
        no = words[0][1]
        rest = words[1:]
        if no == 3605:   # bit parameter, written as 8 binary digits
            rest = [(w, int(str(v), 2) if w == "P" else v) for w, v in rest]
        params[no] = {rest[i][1]: rest[i + 1][1] for i in range(0, len(rest) - 1, 2)}
    data = {n - PITCH_BASE: v for words in _read_tape(directory / PITCH_TAPE) for (_, n), (_, v) in [words]}
    pitch = {}
    for a, ref in params.get(3620, {}).items():
        if a not in by_number:
            raise InputError(f"axis {a}, but machine {machine.name} has {len(numbers)} axes", tape, field="3620")
        ax = by_number[a]
        q = Quantum.of(machine.axis(ax).resolution)
        for no in (3621, 3622, 3623, 3624):
            if a not in params.get(no, {}):
                raise InputError(f"axis {a} ({ax}) has No.3620 but no No.{no}", tape, field=str(no))
        lo, hi = params[3621][a], params[3622][a]
        mag, step = params[3623][a], params[3624][a]
        if not (lo <= ref <= hi) or step <= 0:
            raise InputError(f"axis {a} ({ax}): expected No.3621 <= No.3620 <= No.3622 and No.3624 > 0",
                             tape, field="3620")
        m = hi - lo + 1
        r = ref - lo

        def table(start, at_ref):
            v = np.array([data.get(start + k, 0) for k in range(m)], np.int64) * mag
            c = np.cumsum(v) - v[0]
            return c - c[r] + at_ref
        cu = table(lo, 0)
        bi = params.get(3605, {}).get(a, 0) & 1
        if bi and (a not in params.get(3626, {}) or a not in params.get(3627, {})):
            raise InputError(f"axis {a} ({ax}): No.3605#0 = 1 but no No.3626 / No.3627", tape, field="3626")
        cd = table(params[3626][a], params[3627][a]) if bi else cu
        pos = q.value((np.arange(m) - r) * step)
        pitch[ax] = PitchTable.from_counts(ax, pos, q, cu, cd)
    return pitch, {}, {}
