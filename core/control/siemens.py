"""Siemens SINUMERIK 840D sl: interpolatory compensation tables (CEC, $AN_CEC...) and the
generic 5-axis transformation's machine data (TRAORI, swivel table type 40).

Formats (docs/control.md; SINUMERIK 840D sl function manual Extended Functions, K3
"Interpolatory compensation"; commissioning manual SINUMERIK Operate, "Swiveling", the table of
TOOLCARRIER vectors against the 5-axis transformation machine data):

* ``siemens-cec.ini``: an NC initialisation program ``%_N_NC_CEC_INI`` ... ``M17`` of
  assignments: per table t the values ``$AN_CEC[t,N]`` (output axis unit: mm or deg), the basic
  axis ``$AN_CEC_INPUT_AXIS[t]``, the compensated axis ``$AN_CEC_OUTPUT_AXIS[t]`` (machine axis
  names X1, Y1, Z1, A1, B1, C1, the defaults of MD10000), ``$AN_CEC_STEP[t]``,
  ``$AN_CEC_MIN[t]``, ``$AN_CEC_MAX[t]`` (number of points = (MAX - MIN) / STEP + 1, at most
  MD18342 $MN_MM_CEC_MAX_POINTS), ``$AN_CEC_DIRECTION[t]`` (0 both directions, 1 only moving
  positive, -1 only moving negative: the bidirectional pitch is two tables),
  ``$AN_CEC_MULT_BY_TABLE[t] = 0``, ``$AN_CEC_IS_MODULO[t] = 0``.  Pitch: input = output axis;
  straightness EYX: input X1, output Y1 (the sag compensation of the manual);
* ``siemens-traori.ini``: channel machine data (``CHANDATA(1)``) of transformation 1 for a
  machine whose two rotary axes both carry the workpiece: ``$MC_TRAFO_TYPE_1 = 40``,
  ``$MC_TRAFO5_AXIS1_1[0..2]`` / ``AXIS2_1`` the directions of the rotary axes (1st = the one
  nearer the machine base), ``$MC_TRAFO5_BASE_TOOL_1`` = I2 (machine zero to the 1st rotary
  axis), ``$MC_TRAFO5_JOINT_OFFSET_1`` = I3 (1st to 2nd rotary axis), ``$MC_TRAFO5_PART_OFFSET_1``
  = I4 = -(I2 + I3).
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .._io import InputError
from ..machine import Machine
from .common import ControlLimitError, PitchTable, Quantum, Split, equal_steps, error_to_control

NAME = "siemens"
HOLDS_STRAIGHTNESS = True
MAX_POINTS = 2000          # MD18342 $MN_MM_CEC_MAX_POINTS, upper limit
MAX_TABLES = 62            # table index 0 .. 2 x 31 axes - 1
MAX_SUM = 1.0              # MD32720 $MA_CEC_MAX_SUM default, mm: the summed compensation of an axis
CEC = "siemens-cec.ini"
TRAORI = "siemens-traori.ini"


def machine_axis(axis: str) -> str:
    return f"{axis}1"


def _table(lines: list, t: int, inp: str, out: str, first: int, step: int, qi: Quantum,
           values: np.ndarray, qo: Quantum, direction: int) -> None:
    lines += [f"$AN_CEC[{t},{i}]={qo.text(v)}" for i, v in enumerate(values)]
    lines += [f'$AN_CEC_INPUT_AXIS[{t}]="{machine_axis(inp)}"', f'$AN_CEC_OUTPUT_AXIS[{t}]="{machine_axis(out)}"',
              f"$AN_CEC_STEP[{t}]={qi.text(step)}", f"$AN_CEC_MIN[{t}]={qi.text(first)}",
              f"$AN_CEC_MAX[{t}]={qi.text(first + step * (len(values) - 1))}",
              f"$AN_CEC_DIRECTION[{t}]={direction}", f"$AN_CEC_MULT_BY_TABLE[{t}]=0",
              f"$AN_CEC_IS_MODULO[{t}]=0"]


def _linear_quantum(machine: Machine) -> Quantum:
    return Quantum.of(min(a.resolution for a in machine.axes if not a.is_rotary))


def _traori_axes(machine: Machine):
    """The two workpiece-side rotary axes (1st = nearer the base), or None."""
    rot = [a for a in machine.axes if a.is_rotary]
    if len(rot) != 2 or any(a.side != "workpiece" for a in rot):
        return None
    return rot[1], rot[0]        # the chain lists the workpiece side from the workpiece


def _pivot(axis, location: dict) -> np.ndarray:
    return np.asarray(axis.location, float) + [location.get(f"E{c}0{axis.name}", 0.0) for c in "XYZ"]


def _direction(axis, location: dict) -> np.ndarray:
    """Nominal direction tilted by the axis' tilts (first order): d + e x d, e without its
    component along d (that one is the zero error)."""
    d = np.asarray(axis.direction, float)
    e = np.array([location.get(f"E{c}0{axis.name}", 0.0) for c in "ABC"])
    e = e - d * (e @ d)
    return d + np.cross(e, d)


def export(machine: Machine, split: Split) -> tuple[dict, set, list, list, dict]:
    lines = ["%_N_NC_CEC_INI"]
    held, notes, t = [], [], 0
    out_sum: dict[str, float] = {}

    def add(inp, out, pos, corr, direction, what):
        nonlocal t
        qi, qo = Quantum.of(machine.axis(inp).resolution), Quantum.of(machine.axis(out).resolution)
        first, step, m = equal_steps(pos, qi, what)
        if m > MAX_POINTS:
            raise ControlLimitError(f"{m} points; a CEC table holds at most {MAX_POINTS} (MD18342)", field=what)
        if t >= MAX_TABLES:
            raise ControlLimitError(f"more than {MAX_TABLES} CEC tables", field=what)
        vals = qo.count(corr)
        _table(lines, t, inp, out, first, step, qi, vals, qo, direction)
        out_sum[out] = out_sum.get(out, 0.0) + float(np.max(np.abs(qo.value(vals)))) / (2 if direction else 1)
        t += 1
    order = "XYZUVWABC".index
    for ax in sorted(split.pitch, key=order):      # a fixed order: the same files for the same errors
        p = split.pitch[ax]
        if p.bidirectional:
            add(ax, ax, p.position, error_to_control(ax, p.up), 1, f"{ax} pitch")
            add(ax, ax, p.position, error_to_control(ax, p.down), -1, f"{ax} pitch")
        else:
            add(ax, ax, p.position, error_to_control(ax, p.up), 0, f"{ax} pitch")
        held.append(f"{ax} pitch: CEC {'two tables, $AN_CEC_DIRECTION 1 and -1' if p.bidirectional else 'one table'}")
    for ax, d in sorted(split.straightness, key=lambda k: (order(k[0]), order(k[1]))):
        pos, v = split.straightness[(ax, d)]
        add(ax, d, pos, -v, 0, f"E{d}{ax} straightness")
        held.append(f"E{d}{ax}: CEC input {machine_axis(ax)} output {machine_axis(d)}")
    for out, s in out_sum.items():
        if s > MAX_SUM and machine.axis(out).unit == "mm":
            notes.append(f"axis {out}: the tables add up to {s:.4f} mm, above MD32720 $MA_CEC_MAX_SUM's "
                         f"default {MAX_SUM} mm: raise it (up to 10 mm)")
    lines.append("M17")
    files = {CEC: "\n".join(lines) + "\n"}
    held_loc: set = set()
    pair = _traori_axes(machine)
    if pair:
        a1, a2 = pair
        q = _linear_quantum(machine)
        p1, p2 = (q.value(q.count(_pivot(a, split.location))) for a in (a1, a2))
        md = ["%_N_TRAORI_INI", "CHANDATA(1)", "$MC_TRAFO_TYPE_1=40"]
        for name, v in (("AXIS1", _direction(a1, split.location)), ("AXIS2", _direction(a2, split.location))):
            md += [f"$MC_TRAFO5_{name}_1[{k}]={float(x)!r}" for k, x in enumerate(v)]
        # the offsets on the linear increment: I2 = p1, I3 = p2 - p1, I4 = -(I2 + I3) = -p2
        for name, v in (("BASE_TOOL", q.count(p1)), ("JOINT_OFFSET", q.count(p2) - q.count(p1)),
                        ("PART_OFFSET", -q.count(p2))):
            md += [f"$MC_TRAFO5_{name}_1[{k}]={q.text(int(n))}" for k, n in enumerate(v)]
        md.append("M17")
        files[TRAORI] = "\n".join(md) + "\n"
        for a in (a1, a2):
            own = "ABC"[int(np.argmax(np.abs(a.direction)))]
            held_loc |= {f"E{c}0{a.name}" for c in "XYZABC" if c != own} & set(split.location)
        held.append(f"TRAORI type 40 ({a1.name} then {a2.name}): pivots and tilts "
                    f"({', '.join(sorted(held_loc)) or 'nominal'})")
        notes.append("the zero errors of the rotary axes (rotation about their own axis) are not written "
                     "(no offset machine data covered here): they stay for the NC rewrite")
    elif split.location:
        notes.append("TRAORI is exported for a swivel table (two rotary axes carrying the workpiece) only: "
                     "the rotary axis location errors stay for the NC rewrite")
    return files, held_loc, held, notes, {}


_ASSIGN = re.compile(r"^\$(AN_CEC\w*|MC_TRAFO\w*?)(?:\[([^\]]*)\])?\s*=\s*(.+)$")


def _assignments(path: Path) -> dict:
    out = {}
    for k, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        s = line.strip()
        if not s.startswith("$"):
            continue
        m = _ASSIGN.match(s)
        if not m:
            raise InputError(f"expected $NAME[index]=value, got {s[:40]!r}", path, k)
        v = m.group(3).strip()
        out[(m.group(1), (m.group(2) or "").replace(" ", ""))] = v.strip('"')
    return out


def read(machine: Machine, directory: Path) -> tuple[dict, dict, dict]:
    path = directory / CEC
    if not path.exists():
        raise InputError(f"no {CEC}", directory)
    a = _assignments(path)
    names = {machine_axis(x): x for x in machine.axis_names}
    tables = sorted({int(k[1]) for k in a if k[0] == "AN_CEC_INPUT_AXIS"})
    pitch_parts: dict = {}
    straight = {}
    def get(name, index):
        if (name, index) not in a:
            raise InputError(f"missing ${name}[{index}]", path, field=f"{name}[{index}]")
        return a[(name, index)]

    def number(name, index):
        v = get(name, index)
        try:
            return float(v)
        except ValueError:
            raise InputError(f"expected a number, got {v!r}", path, field=f"{name}[{index}]") from None
    for t in tables:
        ti, to = get("AN_CEC_INPUT_AXIS", str(t)), get("AN_CEC_OUTPUT_AXIS", str(t))
        if ti not in names or to not in names:
            bad = ti if ti not in names else to
            raise InputError(f"table {t}: axis {bad!r} is not one of {', '.join(names)}", path)
        inp, out = names[ti], names[to]
        qi, qo = Quantum.of(machine.axis(inp).resolution), Quantum.of(machine.axis(out).resolution)
        lo, hi, step = (int(qi.count(number(f"AN_CEC_{k}", str(t)))) for k in ("MIN", "MAX", "STEP"))
        if step <= 0 or hi <= lo or (hi - lo) % step:
            raise InputError(f"table {t}: MAX - MIN must be a positive multiple of STEP", path,
                             field=f"AN_CEC_STEP[{t}]")
        m = (hi - lo) // step + 1
        vals = np.array([int(qo.count(number("AN_CEC", f"{t},{i}"))) for i in range(m)], np.int64)
        pos = qi.value(lo + step * np.arange(m))
        direction = int(a.get(("AN_CEC_DIRECTION", str(t)), "0"))
        if inp == out:
            pitch_parts.setdefault(inp, {})[direction] = (pos, qo, vals)
        else:
            straight[(inp, out)] = (pos, -qo.value(vals))
    pitch = {}
    for ax, parts in pitch_parts.items():
        if 0 in parts:
            pos, q, v = parts[0]
            pitch[ax] = PitchTable.from_counts(ax, pos, q, v, v)
        else:
            pos, q, up = parts[1]
            pitch[ax] = PitchTable.from_counts(ax, pos, q, up, parts[-1][2])
    location = {}
    pair = _traori_axes(machine)
    md_path = directory / TRAORI
    if pair and md_path.exists():
        md = _assignments(md_path)

        def vec(name):
            return np.array([float(md[(f"MC_TRAFO5_{name}_1", str(k))]) for k in range(3)])
        a1, a2 = pair
        q = _linear_quantum(machine)      # the pivots were written on the linear increment
        p1 = q.value(q.count(vec("BASE_TOOL")))
        p2 = q.value(q.count(vec("BASE_TOOL") + vec("JOINT_OFFSET")))
        for ax, p, d in ((a1, p1, vec("AXIS1")), (a2, p2, vec("AXIS2"))):
            own = int(np.argmax(np.abs(ax.direction)))
            dn = np.asarray(ax.direction, float)
            e = np.cross(dn, d - dn)          # d - dn = e x dn, and dn x (e x dn) = e (e _|_ dn)
            for k, c in enumerate("XYZ"):
                v = float(q.value(q.count(p[k] - ax.location[k])))
                if k != own and v != 0:
                    location[f"E{c}0{ax.name}"] = float(v)
            for k, c in enumerate("ABC"):
                if k != own and e[k] != 0:
                    location[f"E{c}0{ax.name}"] = float(e[k])
    return pitch, straight, location
