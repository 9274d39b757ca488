"""LinuxCNC: joint compensation files (COMP_FILE, COMP_FILE_TYPE = 1) and trt kinematics pins.

Formats (docs/control.md, from the LinuxCNC sources: src/emc/motion/usrmotintf.cc
`usrmotLoadComp`, src/emc/motion/command.c `EMCMOT_SET_JOINT_COMP`, src/emc/motion/control.c
`compute_screw_comp`, src/emc/kinematics/trtfuncs.c):

* one file per joint, lines ``nominal forward_trim reverse_trim`` (blank separated, machine
  units: mm or deg); with COMP_FILE_TYPE = 1 the trims are added to the commanded joint position
  (forward trim while the joint moves up, reverse trim while it moves down), linearly
  interpolated between the nominal positions and held beyond the ends.  The reader stops at the
  first line that is not three numbers, so the file has no comment or header line.  At most
  256 lines (EMCMOT_COMP_SIZE), nominal positions strictly increasing; trims are stored as
  32-bit floats;
* ``linuxcnc-comp.ini``: the [KINS] and [JOINT_n] entries (COMP_FILE, COMP_FILE_TYPE, BACKLASH = 0)
  to merge into the machine's INI file;
* ``linuxcnc-kins.hal``: ``setp`` of the xyzbc-trt-kins / xyzac-trt-kins pins (x-rot-point,
  y-rot-point, z-rot-point, x-offset / y-offset, z-offset) for a tilting table carrying a rotary
  table: the rotary table's axis passes through (x-rot-point, y-rot-point), the tilt axis through
  x-rot-point + x-offset (xyzbc) or y-rot-point + y-offset (xyzac) and z-rot-point + z-offset.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .._io import InputError
from ..machine import Machine
from .common import ControlLimitError, PitchTable, Quantum, Split, error_to_control

NAME = "linuxcnc"
MAX_POINTS = 256          # EMCMOT_COMP_SIZE, src/emc/motion/motion.h
COMP_FILE_TYPE = 1
INI = "linuxcnc-comp.ini"
HAL = "linuxcnc-kins.hal"
_ORDER = "XYZABCUVW"      # LinuxCNC's axis letters, in the order trivkins assigns joints


def joint_letters(machine: Machine) -> str:
    """The coordinates string: the machine's axis letters in LinuxCNC order (joint i = letter i)."""
    return "".join(sorted(machine.axis_names, key=_ORDER.index))


def kinematics(machine: Machine) -> str:
    """xyzbc-trt-kins / xyzac-trt-kins for a tilting table (B or A) carrying a rotary table (C),
    trivkins otherwise."""
    rot = [a for a in machine.axes if a.is_rotary]
    names = "".join(sorted(a.name for a in rot))
    if len(rot) == 2 and all(a.side == "workpiece" for a in rot) and names in ("BC", "AC"):
        # the chain lists the workpiece side from the workpiece: C must come first (on the tilt axis)
        if machine.index("C") < machine.index(names[0]):
            return f"xyz{names.lower()}-trt-kins"
    return "trivkins"


def comp_file_name(axis: str) -> str:
    return f"{axis.lower()}.comp"


def _quantum(machine: Machine, axis: str) -> Quantum:
    return Quantum.of(machine.axis(axis).resolution)


def comp_file_text(machine: Machine, p: PitchTable) -> str:
    q = _quantum(machine, p.axis)
    if p.position.size > MAX_POINTS:
        raise ControlLimitError(f"{p.position.size} points; a LinuxCNC joint compensation table "
                                f"holds at most {MAX_POINTS} (EMCMOT_COMP_SIZE)", field=f"{p.axis} pitch")
    fwd = q.count(error_to_control(p.axis, p.up))
    rev = q.count(error_to_control(p.axis, p.down))
    return "".join(f"{float(x)!r} {q.text(f)} {q.text(r)}\n" for x, f, r in zip(p.position, fwd, rev))


def _pins(machine: Machine, kins: str, location: dict) -> tuple[dict, set]:
    """HAL pin values (mm) of a trt kinematics from the rotary axes' locations, and the
    location error names they hold."""
    tilt = kins[3].upper()                      # B (xyzbc) or A (xyzac)
    pc = np.asarray(machine.axis("C").location, float).copy()
    pt = np.asarray(machine.axis(tilt).location, float).copy()
    held = set()
    for i, c in enumerate("XYZ"):
        if c != "Z" and f"E{c}0C" in location:
            pc[i] += location[f"E{c}0C"]
            held.add(f"E{c}0C")
    across = "X" if tilt == "B" else "Y"        # the tilt axis' position across the C axis
    for c in (across, "Z"):
        if f"E{c}0{tilt}" in location:
            pt["XYZ".index(c)] += location[f"E{c}0{tilt}"]
            held.add(f"E{c}0{tilt}")
    i = "XYZ".index(across)
    pins = {"x-rot-point": pc[0], "y-rot-point": pc[1], "z-rot-point": pt[2],
            f"{across.lower()}-offset": pt[i] - pc[i], "z-offset": 0.0}
    return pins, held


def export(machine: Machine, split: Split) -> tuple[dict, set, list, list, dict]:
    """(files {name: text}, location names held, what is held, notes)."""
    letters = joint_letters(machine)
    kins = kinematics(machine)
    files, held_lines, notes = {}, [], []
    ini = ["# mtcomp control export for LinuxCNC: merge into the machine's INI file",
           "[KINS]", f"KINEMATICS = {kins}{'' if kins != 'trivkins' else f' coordinates={letters}'}",
           f"JOINTS = {len(letters)}", ""]
    for j, ax in enumerate(letters):
        if ax not in split.pitch:
            continue
        p = split.pitch[ax]
        files[comp_file_name(ax)] = comp_file_text(machine, p)
        ini += [f"[JOINT_{j}]", f"COMP_FILE = {comp_file_name(ax)}", f"COMP_FILE_TYPE = {COMP_FILE_TYPE}",
                "BACKLASH = 0.0", ""]
        held_lines.append(f"joint {j} ({ax}) pitch, {'bidirectional' if p.bidirectional else 'one table for both directions'}, "
                          f"{p.position.size} points ({comp_file_name(ax)})")
    files[INI] = "\n".join(ini)
    held = set()
    if kins != "trivkins":
        pins, held = _pins(machine, kins, split.location)
        res = min(machine.axis(a).resolution for a in machine.axis_names if not machine.axis(a).is_rotary)
        q = Quantum.of(res)
        files[HAL] = ("# mtcomp control export for LinuxCNC: rotary axis locations as " + kins + " pins (mm)\n"
                      + "".join(f"setp {kins}.{k} {q.text(int(q.count(v)))}\n" for k, v in pins.items()))
        held_lines.append(f"{kins} pins: {', '.join(sorted(held)) or 'nominal locations'}")
        notes.append(f"{kins} models neither tilts of the rotary axes nor their zero errors: those stay "
                     "for the NC rewrite")
        notes.append(f"{kins} (LinuxCNC 2.9) turns {kins[3].upper()} and C opposite to the machine file's senses "
                     "unless its conventional-directions pin (later versions) is set: programs and joints "
                     "then carry the negated angles")
    elif split.location:
        notes.append("LinuxCNC ships no kinematics module with adjustable pivots for this axis chain "
                     "(trt kinematics: tilting table carrying a C table): the rotary axis location errors "
                     "stay for the NC rewrite")
    if split.straightness:
        notes.append("LinuxCNC compensates each joint along itself only: straightness stays for the NC rewrite")
    return files, held, held_lines, notes, {}


def _read_comp(machine: Machine, path: Path, axis: str) -> PitchTable:
    nom, fwd, rev = [], [], []
    for k, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        parts = line.split()
        if len(parts) != 3:
            break          # as LinuxCNC: the table ends at the first line that is not a triple
        try:
            a, b, c = (float(x) for x in parts)
        except ValueError:
            break
        nom.append(a), fwd.append(b), rev.append(c)
    if len(nom) < 2:
        raise InputError("expected at least two lines 'nominal forward reverse'", path)
    pos = np.asarray(nom)
    if np.any(np.diff(pos) <= 0):
        raise InputError("nominal positions must increase strictly (LinuxCNC refuses the rest)", path)
    if len(nom) > MAX_POINTS:
        raise ControlLimitError(f"{len(nom)} points; LinuxCNC holds at most {MAX_POINTS}", path)
    q = _quantum(machine, axis)
    return PitchTable.from_counts(axis, pos, q, q.count(fwd), q.count(rev))


def _ini_joints(text: str) -> dict:
    """{joint: (COMP_FILE, COMP_FILE_TYPE)} from an INI text."""
    out, sect = {}, None
    for line in text.splitlines():
        s = line.strip()
        m = re.match(r"^\[JOINT_(\d+)\]$", s)
        if m:
            sect = int(m.group(1))
            out.setdefault(sect, [None, 0])
            continue
        if s.startswith("["):
            sect = None
        if sect is None or "=" not in s or s.startswith(("#", ";")):
            continue
        k, v = (x.strip() for x in s.split("=", 1))
        if k == "COMP_FILE":
            out[sect][0] = v
        elif k == "COMP_FILE_TYPE":
            out[sect][1] = int(v)
    return {j: tuple(v) for j, v in out.items() if v[0]}


def read(machine: Machine, directory: Path) -> tuple[dict, dict, dict]:
    """(pitch, straightness, location) from an export folder (INI fragment, comp files, HAL pins)."""
    letters = joint_letters(machine)
    ini = directory / INI
    if not ini.exists():
        raise InputError(f"no {INI} (the [JOINT_n] COMP_FILE entries)", directory)
    pitch = {}
    for j, (name, typ) in _ini_joints(ini.read_text(encoding="utf-8")).items():
        if j >= len(letters):
            raise InputError(f"[JOINT_{j}] but machine {machine.name} has {len(letters)} joints", ini)
        ax = letters[j]
        p = _read_comp(machine, directory / name, ax)
        if typ == 0:   # nominal, actual forward, actual reverse: the trims are nominal - actual
            q, fwd, rev = p.counts
            n = q.count(p.position)
            p = PitchTable.from_counts(ax, p.position, q, n - fwd, n - rev)
        pitch[ax] = p
    location = {}
    kins = kinematics(machine)
    hal = directory / HAL
    if kins != "trivkins" and hal.exists():
        pins = {}
        for line in hal.read_text(encoding="utf-8").splitlines():
            m = re.match(rf"^setp\s+{re.escape(kins)}\.([a-z-]+)\s+(\S+)\s*$", line.strip())
            if m:
                pins[m.group(1)] = float(m.group(2))
        location = _location_from_pins(machine, kins, pins)
    return pitch, {}, location


def _location_from_pins(machine: Machine, kins: str, pins: dict) -> dict:
    tilt = kins[3].upper()
    across = "X" if tilt == "B" else "Y"
    res = min(machine.axis(a).resolution for a in machine.axis_names if not machine.axis(a).is_rotary)
    q = Quantum.of(res)
    pc = np.asarray(machine.axis("C").location, float)
    pt = np.asarray(machine.axis(tilt).location, float)
    i = "XYZ".index(across)
    found = {"EX0C": pins.get("x-rot-point", pc[0]) - pc[0], "EY0C": pins.get("y-rot-point", pc[1]) - pc[1],
             f"E{across}0{tilt}": pins.get(f"{across.lower()}-rot-point", pc[i])
             + pins.get(f"{across.lower()}-offset", 0.0) - pt[i],
             f"EZ0{tilt}": pins.get("z-rot-point", pt[2]) + pins.get("z-offset", 0.0) - pt[2]}
    # the pins are written to the linear increment: round the differences back onto it
    return {k: float(q.value(q.count(v))) for k, v in found.items() if q.count(v) != 0}
