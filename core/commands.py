"""CLI commands of the core: `mtcomp compensate` and `mtcomp machines`."""
from __future__ import annotations

import argparse
import codecs
import hashlib
import math
import os
import re
import sys
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from ._io import InputError, atomic_write
from .cliargs import positive_float
from .errors import ErrorSet, TableRangeError, load_errors
from .kinematics import ConvergenceError, LimitError, deviations, forward, retarget
from .machine import list_presets, load_machine
from .progress import Progress

CHUNK = 200_000
#: Default tolerance (mm) of the output checks: feeds into the part, a cutter-compensated
#: block's correction, and a block's middle beyond the uncompensated program (mid-block check).
TOLERANCE = 5e-4

#: Default chordal tolerance for linearised arcs (mm), raised to twice the coarsest linear axis
#: resolution on machines where 0.1 µm cannot be represented.
CHORDAL_TOL = 1e-4
_LOCATION_RE = re.compile(r"^E[XYZABC]0([A-Z])$")


def default_chordal_tol(machine) -> float:
    """0.1 µm, or twice the coarsest linear axis resolution if that is larger (mm)."""
    res = [a.resolution for a in machine.axes if a.kind == "linear"] or [0.0]
    return max(CHORDAL_TOL, 2 * max(res))


def _check_chordal_tol(machine, tol):
    if tol is None:
        return default_chordal_tol(machine)
    tol = float(tol)
    if not (math.isfinite(tol) and tol > 0):
        raise InputError(f"chordal tolerance must be a positive number of µm, got {tol * 1e3:g}",
                         field="--chordal-tol")
    res = max([a.resolution for a in machine.axes if a.kind == "linear"] or [0.0])
    if tol < 2 * res:
        raise InputError(f"chordal tolerance {tol * 1e3:g} µm is below twice the linear axis "
                         f"resolution of {machine.name} ({res * 1e3:g} µm); use at least "
                         f"{2 * res * 1e3:g} µm", field="--chordal-tol")
    return tol


def check_errors_for_machine(errors: ErrorSet, machine, file=None) -> None:
    """Refuse errors that name axes the machine does not have (a table for U, EX0U, EC0W):
    they would otherwise be ignored silently."""
    names = set(machine.axis_names)
    for axis in errors.geometric.tables:
        if axis not in names:
            raise InputError(f"error table for axis {axis}, but {machine.name} has axes "
                             f"{' '.join(machine.axis_names)}", file, field=f"geometric.tables.{axis}")
    for key, value in errors.geometric.location.items():
        m = _LOCATION_RE.match(key)
        if m and m.group(1) not in names:
            raise InputError(f"location error {key} of axis {m.group(1)}, but {machine.name} has "
                             f"axes {' '.join(machine.axis_names)}", file, field=f"geometric.location.{key}")


def parse_start(spec: str | None, machine) -> dict | None:
    """``X=1.5,Y=0,Z=50`` -> {"X": 1.5, ...} (mm, deg); axes must be the machine's."""
    if spec is None:
        return None
    out = {}
    for part in spec.replace(" ", "").split(","):
        if not part:
            continue
        name, eq, val = part.partition("=")
        name = name.upper()
        try:
            v = float(val)
        except ValueError:
            v = math.nan
        if not eq or name not in machine.axis_names or not math.isfinite(v):
            raise InputError(f"expected AXIS=value with an axis of {machine.name} "
                             f"({' '.join(machine.axis_names)}) and a finite number, got {part!r}",
                             field="--start")
        out[name] = v
    return out


def parse_tool_lengths(spec: str | None) -> dict | None:
    """Tool lengths per H number (mm): ``1=50.2,2=75``, a LinuxCNC tool table (``T1 P1 Z+50.0``
    lines) or a CSV file with lines ``H,length_mm`` (a header line and ``#`` comments allowed)."""
    from .gcode.offsets import tool_lengths_from
    return tool_lengths_from(spec)


def load_offsets(path: str | None, machine) -> tuple[dict | None, dict | None]:
    """(tool lengths {H: mm}, work offsets) from an offsets TOML file: ``[H]`` tool lengths,
    ``[D]`` cutter offsets (read, unused), ``[G54]``..``[G59]``, ``["G54.1 P2"]`` tables of axis
    letters -> mm/deg (docs/gcode.md, "Offset files")."""
    if path is None:
        return None, None
    from .gcode.offsets import read_offsets
    tools, _, works = read_offsets(path, machine.axis_names)
    return tools or None, works or None


def load_work_offsets(path: str | None, machine) -> dict | None:
    """Work offsets from an offsets TOML file (see `load_offsets`)."""
    return load_offsets(path, machine)[1]


def _axis_positions(machine, prog, P):
    """Axis positions of the blocks: P itself, except for G43.4 blocks, whose words (tool tip,
    angles) the control turns into axis positions with its nominal kinematics."""
    tcp = np.asarray(prog.tcp)
    if not tcp.any():
        return np.asarray(P)
    from .gcode import tcp as gtcp
    Q = np.array(P, float)
    Q[tcp] = gtcp.nominal_axes(machine, Q[tcp], np.asarray(prog.tool_length)[tcp])
    # a tip not fully known gives no axis position (every linear axis depends on all of it)
    Q[tcp & ~np.asarray(prog.known)] = np.nan
    return Q


def _reference(prog, P):
    """`gcode.rotation.to_reference` of the positions P (N, n_axes), which is P itself (no
    copy: 40 MB at 1 M blocks) where the program has no G68 rotation; read only."""
    from .gcode.rotation import has_rotation, to_reference
    return to_reference(prog, P) if has_rotation(prog) else P


def _columns_inside(machine, P):
    """Per axis k whether every P[:, k] (N, n_axes; mm, deg) is within the axis' travel
    widened by half its resolution, no NaN: the quick test before the travel checks look for
    the first block outside (compiled: one pass over the rows; numpy: min and max per
    column).  False for every axis of an empty P."""
    from .gcode import _ctok
    n_ax = len(machine.axes)
    if not len(P):
        return [False] * n_ax
    lo = np.array([ax.limits[0] - 0.5 * ax.resolution for ax in machine.axes])
    hi = np.array([ax.limits[1] + 0.5 * ax.resolution for ax in machine.axes])
    P = np.asarray(P)
    ok = _ctok.columns_within(P[:, :n_ax], lo, hi) if P.dtype == np.float64 else None
    if ok is None:
        ok = [bool(P[:, k].min() >= lo[k] and P[:, k].max() <= hi[k]) for k in range(n_ax)]
    return [bool(x) for x in ok]


def _travel_check(machine, prog, filename, P=None):
    """Programmed positions outside an axis' travel: the control would refuse them too."""
    P = np.asarray(prog.position if P is None else P)
    inside = _columns_inside(machine, P)
    for k, ax in enumerate(machine.axes):
        lo, hi = ax.limits
        tol = 0.5 * ax.resolution
        if inside[k]:
            continue                             # (NaN anywhere: the full test)
        with np.errstate(invalid="ignore"):
            bad = np.flatnonzero(((P[:, k] < lo - tol) | (P[:, k] > hi + tol)) & prog.axis_known[:, k])
        if len(bad):
            j = int(bad[0])
            off = float(np.asarray(prog.offset)[j, k])
            # (travels are in the machine file's frame, whose origin is the program's: a G54 that
            # is not zero, or a G43 length added to Z, moves the axis position away from the word)
            u = "deg" if ax.is_rotary else "mm"
            why = (f" (programmed {P[j, k] - off:g} {u} plus {off:g} {u} of tool length and work offset "
                   "differences; the travels are those of the machine file, whose origin is the "
                   "program's origin: docs/machine-format.md)") if off else ""
            raise InputError(f"{ax.name} {P[j, k]:g} is outside the travel [{lo:g}, {hi:g}] of axis "
                             f"{ax.name} on {machine.name}{why}", filename, int(prog.line[j]))


def _at_tool_tip(machine, length: float):
    """The machine with its tool point moved ``length`` mm (G43 H length, the block's
    `Program.tool_tip`) from the gauge point along the tool axis to the tool tip: NC words
    under G43 are the axes' positions, and the errors' rotations (a tilted workpiece, the
    axes' angular errors) must be corrected where the tool cuts, at the tip, not at the gauge
    point (length x angle apart: 8.7 µm for 25 mm and 0.02 deg)."""
    if not length:
        return machine
    import dataclasses
    tp = np.asarray(machine.tool_point, float) - float(length) * np.asarray(machine.tool_axis, float)
    return dataclasses.replace(machine, tool_point=tuple(float(v) for v in tp))


def _by_tool(tip, rows):
    """Split ``rows`` (slice or index array into the blocks of the chunk) by the tool tip
    length of each: (length, sub-selection) pairs; one pair without G43 lengths."""
    t = tip[rows]
    if not len(t) or (t == t[0]).all():
        return [(float(t[0]) if len(t) else 0.0, rows)]
    idx = np.arange(len(t)) if isinstance(rows, slice) else np.asarray(rows)
    if isinstance(rows, slice):
        idx = idx + rows.start
    return [(float(v), idx[t == v]) for v in np.unique(t)]


def _midblock_check(machine, prog, P, emitted, kn, kk, before_end, errors, tip, at_tip, tolerance,
                    filename):
    """Refuse a compensated program whose tool path leaves the programmed one between the end
    points of a block by more than the uncompensated program does there plus the errors it
    corrects at the block's ends (before_end: the uncompensated error of the blocks kk, mm) plus
    ``tolerance`` mm.

    The check of the end points cannot see it: the control interpolates a G0/G1 block's axes
    linearly (no tool centre point control), so where the correction of a rotary axis changes
    much from one block to the next (at the end of a pole axis' hold, or where the solution
    changes branch) the tool sweeps an arc between two correct end points.  Tested at the middle
    of every linear block whose rotary axes move (programmed or emitted) and whose block before
    it is compensated too, with the same tool and no tool centre point control: the real machine
    at the mean of the emitted commands against the ideal machine at the mean of the programmed
    ones.  Blocks whose rotary axes stand still keep their rotary correction, and the model is
    then affine in the linear axes up to the tables' curvature (second order, nm), so they are
    not evaluated.  Arcs are solved point by point by the compensation itself.
      The allowance: the corrections at the two ends are each about as large as the error they
    remove there, and between the ends the control moves them linearly, so the tool can be off
    by up to about that much more than uncompensated where the rotary axes turn much (a 325 deg
    turn of C in one block of setting errors of 20 µm: 1.2 µm more), without anything wrong in
    the solution; a correction that changes its rotary branch or leaves a pole axis' hold within
    one block puts the tool off by the sagitta of the turn (1.8 mm for 70 deg at 10 mm from the
    axis), far beyond it."""
    rot = list(machine.rotary_indices)
    n = len(kn)
    if not rot or n < 2:
        return
    # (masks over the pairs (i-1, i) from slices of the columns: no gathered copies of the
    # positions, which are 40 MB at 1 M blocks)
    tcp = np.asarray(prog.tcp, bool)
    ok = kn[1:] & kn[:-1] & (np.asarray(prog.motion)[1:] <= 1) & (np.asarray(prog.cycle)[1:] == 0)
    if tcp.any():
        ok &= ~tcp[1:] & ~tcp[:-1]
    if tip is not None:
        ok &= tip[1:] == tip[:-1]
    moving = np.zeros(n - 1, bool)
    for k in rot:
        moving |= P[1:, k] != P[:-1, k]
        moving |= emitted[1:, k] != emitted[:-1, k]
    ok &= moving
    b = np.flatnonzero(ok) + 1
    every = len(kk) == n                         # every block compensated: kk is the identity
    for s in range(0, len(b), CHUNK):
        rows = b[s:s + CHUNK]
        run = len(rows) and rows[-1] - rows[0] == len(rows) - 1     # consecutive: slices
        sl = slice(int(rows[0]), int(rows[-1]) + 1) if run else rows
        sl0 = slice(sl.start - 1, sl.stop - 1) if run else rows - 1
        qp = np.add(P[sl0], P[sl])
        qp *= 0.5
        qe = np.add(emitted[sl0], emitted[sl])
        qe *= 0.5
        before = np.empty(len(rows))
        after = np.empty(len(rows))
        groups = _by_tool(tip, rows) if tip is not None else [(0.0, None)]
        for length, sub in groups:
            if sub is None:
                before[:], after[:] = deviations(at_tip(length), qp, qe, errors)
            else:
                k = np.searchsorted(rows, sub)
                before[k], after[k] = deviations(at_tip(length), qp[k], qe[k], errors)
        pos = rows if every else np.searchsorted(kk, rows)
        ends = np.maximum(before_end[pos - 1], before_end[pos])
        bad = np.flatnonzero(~(after <= before + ends + tolerance))
        if not len(bad):
            continue
        j = int(bad[0])
        i = int(rows[j])
        turn = np.abs((emitted[i, rot] - emitted[i - 1, rot]) - (P[i, rot] - P[i - 1, rot]))
        r = int(np.argmax(turn))
        ax = machine.axes[rot[r]].name
        raise InputError(
            f"mid-block the compensated tool path would leave the programmed one by "
            f"{_length_text(after[j])} (the uncompensated program: {_length_text(before[j])} there, "
            f"{_length_text(ends[j])} at the block's ends; accepted: the sum of the two plus "
            f"{_length_text(tolerance)}): the correction turns {ax} "
            f"by {turn[r]:.4f} deg within this block ({ax} {emitted[i - 1, rot[r]]:.4f} -> "
            f"{emitted[i, rot[r]]:.4f} deg as compensated, {P[i - 1, rot[r]]:.4f} -> {P[i, rot[r]]:.4f} "
            "as programmed), and the control turns it linearly between the end points; near a "
            "pole of the real machine the exact solution swings the pole axis (docs/gcode.md, "
            "'Mid-block check'). Refusing; alternatives: position-only compensation with the "
            "rotary axes as programmed (`mtcomp workpiece-setting compensate --mode 3axis`), or a "
            "program that passes the pole in one held stretch", filename, int(prog.line[i]))


def _length_text(mm: float) -> str:
    """A length for a message: mm from 0.1 mm, else µm."""
    return f"{mm:.3f} mm" if mm >= 0.1 else f"{mm * 1e3:.3f} µm"


def _three_axis_hint(machine, prog) -> str:
    rot = [machine.axis_names[i] for i in machine.rotary_indices]
    if rot and not np.asarray(prog.present)[:, list(machine.rotary_indices)].any():
        return (f"; the program does not move {' '.join(rot)}: for a 3-axis program, "
                "`mtcomp workpiece-setting compensate --mode 3axis` corrects the setting "
                "errors with X Y Z only")
    return ""


def compensate_program(text: str | bytes, machine, errors: ErrorSet, *, filename: str = "<string>",
                       chordal_tol: float | None = None, start=None, unknown: str = "defer",
                       provenance: list | None = None, force: bool = False, progress=None,
                       convert_inch: bool = False, tool_lengths=None, work_offsets=None,
                       arc_tol: float | None = None, stock=None, part=None, clearance: float = 0.2,
                       tolerance: float = TOLERANCE, warn_only: bool = False, search_path=None,
                       cutter_radius: float | None = None, cutter_offsets: dict | None = None,
                       encoding: str = "utf-8", reversal: dict | None = None,
                       arc_keep_tol: float | None = None):
    """Rewrite an NC program written for the ideal machine so that the real machine with
    `errors` cuts what the program meant.

    text: the program's text, or its bytes as read from the file (`gcode.read_program_bytes`)
    in ``encoding`` ("ascii", "utf-8", or "latin-1" for 8-bit comments): the output is then
    bytes too (a bytes-like object, written as it is), nothing decoded or encoded on the way;
    the output of a text is text.

    chordal_tol (mm): tolerance for arcs that must be linearised (default 0.1 µm, at least twice
    the linear resolution).  start: known axis positions before the first block ({"X": ..}).
    unknown: "defer" (blocks before every axis position is known pass uncompensated) or
    "refuse".  provenance: (key, value) items for the header comment (None: no header).
    force: compensate a program that carries mtcomp's provenance header anyway.
    stock / part (objects of mtcomp.verify: Box, HalfSpace, ShapeStock; workpiece frame, mm):
    the written program is run through the forward model with the errors (rapids included, axes
    interpolated as the control does, docs/verify.md) and its rapids must keep ``clearance``
    (mm) from the stock, its feeds stay within ``tolerance`` (mm) of the part; a violation
    raises VerifyError naming the block, unless ``warn_only`` (then it is in the report).
    Every emitted end position is checked against the travel of its axis (arcs: their interior
    points are solved for and checked by the compensation itself).  A linear block whose middle
    (axes interpolated linearly) leaves the programmed path by more than the uncompensated
    program does there, plus ``tolerance``, is refused (InputError naming its line: a rotary
    correction that turns much within one block, at the end of a pole axis' hold).
    cutter_radius (mm) / cutter_offsets ({D number: radius mm}): the tool radius of blocks
    under G41/G42 (the option wins; default gcode.cutter.DEFAULT_RADIUS, noted): their
    correction is evaluated at the programmed contour, and a block where that differs from the
    correction at the tool centre by more than ``tolerance`` is refused (docs/gcode.md).
    arc_keep_tol (mm): an arc stays G2/G3 where its corrected path is a circle within this
    (default: the chordal tolerance, so that kept arcs are as accurate as linearised ones; a
    larger value, up to ``tolerance``, keeps more arcs at that accuracy: issue 31).
    search_path: directories where subprograms called but not in the program are looked for
    (M98 P1234: O1234[.ext]; o<name> call: name.ngc); they are written out in the output.
    reversal: {axis: mtcomp.geometric.reversal.ReversalTable}: also correct each position for the
    direction it is approached in (docs/geometric.md, reversal); the checks and the report's
    errors after compensation run the machine with that lost motion (the before errors without it).
    Returns (new program (text or bytes, as given), report dict: blocks, lines, deferred
    blocks, idle axes, max/RMS tool-edge errors in mm before and after over the compensated blocks, from the forward model,
    ``verify``: the VerifyResult or None)."""
    from . import gcode
    from .gcode import flow
    from .gcode import tcp as gtcp
    from .gcode.provenance import check_nc_write, header_lines, insert_header_bytes

    opts = dict(filename=filename, chordal_tol=chordal_tol, start=start, unknown=unknown,
                arc_keep_tol=arc_keep_tol,
                provenance=provenance, progress=progress, convert_inch=convert_inch,
                tool_lengths=tool_lengths, work_offsets=work_offsets, arc_tol=arc_tol,
                stock=stock, part=part, clearance=clearance, tolerance=tolerance,
                warn_only=warn_only, cutter_radius=cutter_radius, cutter_offsets=cutter_offsets)
    as_text = isinstance(text, str)
    codec = None if as_text else codecs.lookup(encoding).name
    ascii = codec == "ascii"
    if codec not in (None, "ascii", "utf-8"):
        # 8-bit comments (Latin-1): read as their text, every byte one character, and written
        # back in the encoding, byte for byte
        new, report = compensate_program(bytes(text).decode(encoding), machine, errors,
                                         force=force, search_path=search_path, **opts)
        return new.encode(encoding), report
    tol = _check_chordal_tol(machine, chordal_tol)
    check_errors_for_machine(errors, machine)
    check_nc_write(text, filename=filename, force=force)
    fl = flow.expand(text, filename, search=search_path, ascii=ascii)
    if fl is not None and reversal:
        raise InputError("direction-dependent (reversal) compensation of programs with subprogram calls is "
                         "not supported", filename)
    if fl is not None:
        # (subprogram calls: the expansion is text)
        new, report = _compensate_flow(fl, machine, errors, **opts)
        return (new if as_text else new.encode("utf-8", "surrogateescape")), report
    res = {a.name: a.resolution for a in machine.axes}
    prog = gcode.parse(text, axes=machine.axis_names, filename=filename, start=start,
                       convert_inch=convert_inch, resolution=res, tool_lengths=tool_lengths,
                       work_offsets=work_offsets, arc_tol=arc_tol, tcp=True, rotation=True)
    n_blocks = len(prog)
    if chordal_tol is None and np.asarray(prog.inch).any():
        # inch programs are written one decimal finer in inch: 2.54 times the mm resolution
        res_lin = max([a.resolution for a in machine.axes if a.kind == "linear"] or [0.0])
        tol = max(tol, 2 * 2.54 * res_lin)
    tcp = np.asarray(prog.tcp)
    # G43/G44 lengths: the model's tool point is the tip of the block's tool (_at_tool_tip)
    tip = np.where(tcp, 0.0, np.nan_to_num(np.asarray(prog.tool_tip, float)))
    lengths = bool(tip.any())
    if not lengths:
        tip = None                               # (read only with lengths: 8 MB at 1 M blocks)
    tools = {}

    def at_tip(length):
        if length not in tools:
            tools[length] = _at_tool_tip(machine, length)
        return tools[length]
    _travel_check(machine, prog, filename,
                  _axis_positions(machine, prog, _reference(prog, prog.position)))
    from .gcode.frame import machine_frame
    mf = machine_frame(machine, prog, errors, filename)

    def solve(m, qq):                  # retarget, in the machine frame (docs/gcode.md)
        if mf is None:
            return retarget(m, qq, errors)
        return mf.from_machine(retarget(m, mf.to_machine(qq), mf.errors))

    def dev(m, a, b):                  # deviations, in the machine frame
        if mf is None:
            return deviations(m, a, b, errors)
        return deviations(m, mf.to_machine(a), mf.to_machine(b), mf.errors)
    hint = _three_axis_hint(machine, prog)
    calls = []

    def transform(q):
        lines = calls[-1]
        out = np.empty_like(q)
        # rows of G43.4 blocks are tool-tip words: compensated through the TCP transform
        if tcp.any() or lengths:
            blk = np.clip(np.searchsorted(prog.line, lines), 0, max(len(prog) - 1, 0))
        if tcp.any():
            on = tcp[blk] & (prog.line[blk] == lines)
            sels = (np.flatnonzero(~on), np.flatnonzero(on))
        else:                                   # (slices: no index arrays, no gathered copies)
            on, sels = None, (range(len(q)),)
        done = 0
        for sel in sels:
            for s in range(0, len(sel), CHUNK):
                rows = sel[s:s + CHUNK]
                if isinstance(rows, range):
                    rows = slice(rows.start, rows.stop)
                try:
                    if on is not None and on[rows[0]]:
                        out[rows] = gtcp.compensate_words(machine, q[rows],
                                                          prog.tool_length[blk[rows]], errors)
                    elif lengths:
                        # (an arc's interior points take the tool of the block they belong to)
                        rr = np.arange(len(q))[rows]
                        for length, sub in _by_tool(tip[blk], rr):
                            out[sub] = solve(at_tip(length), q[sub])
                    else:
                        out[rows] = solve(machine, q[rows])
                except (LimitError, ConvergenceError, TableRangeError) as exc:
                    i = int(np.arange(len(q))[rows][getattr(exc, "index", 0)])
                    line = int(lines[i]) if 0 <= i < len(lines) else None
                    is_end = line is not None and i < int(np.count_nonzero(prog.known))
                    where = "" if is_end else " an interior point of the arc ending here"
                    raise InputError(f"cannot compensate{where}: {exc}{hint}", filename, line) from None
                done += rows.stop - rows.start if isinstance(rows, slice) else len(rows)
                if progress:
                    progress(done, len(q))
        if reversal:   # direction of approach: mtcomp.geometric.reversal
            from .geometric.reversal import direction_corrections
            out += direction_corrections(out, machine.axis_names, reversal, lines, ends_first=len(calls) == 1)
        return out

    info = {}
    # the output as bytes: the header goes in place and the check reads these bytes, with one
    # decoding to text at the end (a 1 M-line program is 57 MB: each copy counts at the peak)
    raw, out_line = gcode.rewrite_with_lines(prog, transform, resolution=res, chordal_tol=tol,
                                             unknown=unknown, row_lines=calls, info=info,
                                             as_bytes=True, arc_tol=arc_keep_tol)
    raw = raw if isinstance(raw, bytearray) else bytearray(raw)
    kn = np.asarray(info["compensated"])
    cut = _cutter_check(machine, prog, errors, kn, cutter_radius, cutter_offsets, tolerance,
                        filename)
    added = 0
    if provenance is not None:
        at, added = insert_header_bytes(raw, header_lines(provenance + _cutter_items(cut)))
        out_line = np.where(out_line > at, out_line + added, out_line)
    # Check the result as the machine will run it: the emitted positions (rounded numbers, the
    # end of linearised arcs) through the forward model with the errors, in chunks.
    kn = np.asarray(info["compensated"])
    kk = np.flatnonzero(kn)
    P = _reference(prog, prog.position)              # G68: the positions the axes take
    emitted = _reference(prog, emitted_positions(prog, info, raw, filename=filename,
                                                 start=start, res=res, tool_lengths=tool_lengths,
                                                 work_offsets=work_offsets, arc_tol=arc_tol,
                                                 out_line=out_line, consume=True))
    info.pop("emitted", None)
    _travel_check_emitted(machine, _axis_positions(machine, prog, emitted), kn, prog, filename)
    if reversal:
        # the checks run the machine as it is, lost motion included: a command corrected for
        # its direction of approach is meant to be half a reversal off, the slide is not
        from .geometric.reversal import played_positions
        emitted = played_positions(emitted, machine.axis_names, reversal)
    before, after = _edge_errors(machine, prog, P, emitted, kk, kn, tcp, tip, at_tip, dev,
                                 errors)
    _output_checks(machine, prog, P, emitted, kn, kk, before, after, errors, mf, tip, at_tip,
                   tolerance, filename, info.get("read_deviation"))
    verified = None
    if stock is not None or part is not None:
        verified = verify_output(machine, raw, errors, filename=filename, stock=stock,
                                 part=part, clearance=clearance, tolerance=tolerance,
                                 warn_only=warn_only, start=start, resolution=res,
                                 tool_lengths=tool_lengths, work_offsets=work_offsets, arc_tol=arc_tol)
    n_lines, idle_axes, notes = prog.n_lines, prog.idle_axes, prog.notes
    new_text = raw
    if as_text:
        # the text last, with the program's arrays and bytes freed: its 57 MB (1 M lines) then
        # reuse their memory instead of raising the peak
        del P, emitted, prog, calls, tcp
        new_text = raw.decode("utf-8", "surrogateescape")
        del raw
    rms = lambda e: float(np.sqrt(np.mean(e**2))) if e.size else 0.0  # noqa: E731
    report = {"blocks": n_blocks, "lines": n_lines, "deferred": int(n_blocks - kn.sum()),
              "idle_axes": idle_axes, "chordal_tol": tol, "header_lines": added,
              "notes": notes, "linearised": info["linearised"],
              "cycles_kept": info["cycles_kept"], "cycles_expanded": info["cycles_expanded"],
              "before_max": float(before.max(initial=0)), "before_rms": rms(before),
              "after_max": float(after.max(initial=0)), "after_rms": rms(after),
              "verify": verified, "flow": None, "compensated": kn, "cutter": cut}
    return new_text, report


def _edge_errors(machine, prog, P, emitted, kk, kn, tcp, tip, at_tip, dev, errors):
    """Tool-edge error (mm) of every compensated block ``kk`` before (the programmed positions
    P on the machine with the errors) and after (the written ones, ``emitted``), from the
    forward model, in chunks: at the tip of each block's tool (G43 lengths, ``tip``), G43.4
    blocks at their tool tip (gcode.tcp).  ``dev``: `deviations` in the machine frame."""
    from .gcode import tcp as gtcp
    before = np.empty(len(kk))
    after = np.empty(len(kk))
    every = len(kk) == len(kn)                   # every block compensated: slices, no gathers
    for s in range(0, len(kk), CHUNK):
        rows = kk[s:s + CHUNK]
        on = tcp[rows] if tcp.any() else np.zeros(len(rows), bool)
        r = slice(s, s + len(rows)) if every and not on.any() else rows[~on]
        if len(rows[~on]) and tip is None:
            before[s:s + CHUNK][~on], after[s:s + CHUNK][~on] = dev(machine, P[r], emitted[r])
        elif len(rows[~on]):
            # at the tip of each block's tool, where the transform put it
            b_out, a_out = before[s:s + CHUNK], after[s:s + CHUNK]
            pos = np.flatnonzero(~on)
            for length, sub in _by_tool(tip, rows[~on]):
                mt = at_tip(length)
                k = pos[np.isin(rows[~on], sub)]
                b_out[k], a_out[k] = dev(mt, P[sub], emitted[sub])
        if on.any():
            r = rows[on]
            b, a = gtcp.tip_errors(machine, P[r], emitted[r], prog.tool_length[r], errors)
            before[s:s + CHUNK][on], after[s:s + CHUNK][on] = b, a
    return before, after


def _output_checks(machine, prog, P, emitted, kn, kk, before, after, errors, mf, tip, at_tip,
                   tolerance, filename, carried):
    """The checks of the written program that refuse it (nothing written): every block's
    tool edge within the tolerance (`_refuse_residuals`), and every block's middle
    (`_midblock_check`, in the machine frame ``mf`` where there is one)."""
    _refuse_residuals(machine, prog, kk, after, tolerance, filename, carried)
    if mf is None:
        _midblock_check(machine, prog, P, emitted, kn, kk, before, errors, tip, at_tip, tolerance,
                        filename)
    else:
        _midblock_check(machine, prog, mf.to_machine(P), mf.to_machine(emitted), kn, kk, before,
                        mf.errors, tip, at_tip, tolerance, filename)


def residual_limit(machine, tolerance: float) -> float:
    """Largest tool-edge error (mm) a compensated block may keep at its end: ``tolerance``, or
    the error the written numbers' rounding alone can leave (half a resolution step on every
    linear axis) if that is larger."""
    half = [a.resolution / 2 for a in machine.axes if a.kind == "linear"]
    return max(float(tolerance), math.sqrt(sum(h * h for h in half)) * (1 + 1e-9))


def _refuse_residuals(machine, prog, kk, after, tolerance, filename, carried=None):
    """Nothing over tolerance leaves the command: a compensated block whose tool edge, with the
    numbers as written run through the forward model, misses the programmed one by more than
    `residual_limit` is refused by line (whatever produced it: a canned cycle or an increment
    taken from a position that was not known, a table, a solver that stopped short)."""
    limit = residual_limit(machine, tolerance)
    # (plus what the program itself carries where the control reads its words: G91 increments
    # finer than a count drift from the exact sum whether compensated or not)
    lim = limit if carried is None else limit + np.asarray(carried)[kk]
    bad = np.flatnonzero(~(after <= lim))                 # (NaN is over, too)
    if not len(bad):
        return
    i = int(bad[np.argmax(np.nan_to_num(after[bad], nan=np.inf))])
    first = int(bad[0])
    line = int(prog.line[kk[first]])
    worst = "" if i == first else (f"; worst {after[i] * 1e3:.4g} µm at line "
                                   f"{int(prog.line[kk[i]])}")
    idle = [a for a in (prog.idle_axes or ()) if a in "XYZUVW"]
    hint = (f" (the program never writes {' '.join(idle)}, so no correction can be written "
            "for it: give --start to state where it stands)" if idle else "")
    raise InputError(f"the compensated block misses the programmed tool edge by "
                     f"{after[first] * 1e3:.4g} µm, more than the tolerance "
                     f"{limit * 1e3:.4g} µm ({len(bad)} block(s){worst}){hint}; nothing written",
                     filename, line)


def _cutter_check(machine, prog, errors, kn, radius, offsets, tolerance, filename):
    """Blocks under G41/G42: the bound on correcting the programmed contour instead of the
    tool centre (gcode.cutter) at each compensated block's end point, refused above
    ``tolerance`` (mm).  Returns None without such blocks, else a dict: blocks, worst bound
    (mm) and its line, the radius used and where it came from."""
    from .gcode import cutter as gcut
    from .gcode.rotation import to_reference
    if prog.cutter is None:
        return None
    rows = np.flatnonzero((np.asarray(prog.cutter) > 0) & kn)
    if not len(rows):
        return None
    line = np.asarray(prog.line)
    tcp = np.asarray(prog.tcp)
    if tcp.any() and tcp[rows].any():
        raise InputError("cutter radius compensation G41/G42 with G43.4 tool centre point is "
                         "not supported", filename, int(line[rows[np.argmax(tcp[rows])]]))
    if radius is not None:
        r = np.full(len(rows), float(radius))
        source = "--cutter-radius"
    else:
        d = np.asarray(prog.cutter_d)[rows]
        table = {int(k): float(v) for k, v in (offsets or {}).items()}
        r = np.array([table.get(int(x), np.nan) if np.isfinite(x) else np.nan for x in d])
        given = np.isfinite(r)
        r[~given] = gcut.DEFAULT_RADIUS
        source = ("D table" if given.all() else
                  "assumed (no --cutter-radius"
                  + (", D value not in the offsets file or tool table" if table else "") + ")"
                  + ("; D table where given" if given.any() else ""))
    if prog.cutter_radius is not None:
        # G41.1/G42.1 D<diameter> (LinuxCNC): the program gives the radius the control uses
        dyn = np.isfinite(np.asarray(prog.cutter_radius)[rows])
        if dyn.any():
            r = r.copy()
            r[dyn] = np.asarray(prog.cutter_radius)[rows][dyn]
            source = "G41.1/G42.1 D" if dyn.all() else source + "; G41.1/G42.1 D where given"
    if not (np.all(np.isfinite(r)) and np.all(r >= 0)):
        raise InputError(f"cutter radius must be a finite number >= 0 mm, got {r[~(r >= 0)][0]}",
                         field="--cutter-radius")
    P = to_reference(prog, prog.position)[rows]

    blk = [rows]                                     # the block of each row of q, repeated

    def correct(q):
        try:
            return retarget(machine, q, errors)
        except (LimitError, ConvergenceError, TableRangeError) as exc:
            i = int(blk[0][int(getattr(exc, "index", 0)) % len(blk[0])])
            raise InputError(f"cannot evaluate the correction one cutter radius from the "
                             f"programmed point (G41/G42): {exc}", filename, int(line[i])) from None

    axes = tuple(a.name for a in machine.axes)
    rot = [k for k, a in enumerate(machine.axes) if a.is_rotary]
    if rot:
        turn = np.abs(correct(P)[:, rot] - P[:, rot])
        res_rot = np.array([machine.axes[k].resolution for k in rot])
        bad = (turn > 0.5 * res_rot).any(axis=1)
        if bad.any():
            raise InputError("the correction turns a rotary axis on a block under cutter radius "
                             "compensation G41/G42: the plane the control offsets in would turn "
                             "with it; refusing", filename, int(line[rows[np.argmax(bad)]]))
    # end points, and the middle of every arc (the correction may vary along a long arc)
    arcs, mid = gcut.arc_midpoints(prog, rows)
    at = np.searchsorted(rows, arcs)
    pts = np.vstack([P, to_reference(prog, mid, arcs)]) if len(arcs) else P
    which = np.concatenate([np.arange(len(rows)), at])
    blk[0] = rows[which]
    try:
        b = gcut.offset_error_bound(correct, pts, np.asarray(prog.plane)[rows][which], r[which], axes)
    except ValueError as exc:
        raise InputError(f"G41/G42: {exc}", filename, int(line[rows[0]])) from None
    bound = np.zeros(len(rows))
    np.maximum.at(bound, which, b)
    over = bound > tolerance
    if over.any():
        j = int(np.argmax(over))
        src = source.replace("assumed (", "assumed: ").rstrip(")")
        raise InputError(f"under cutter radius compensation G{int(prog.cutter[rows[j]])} the "
                         f"correction is evaluated at the programmed contour, not at the tool "
                         f"centre {r[j]:g} mm away ({src}); the difference may reach "
                         f"{bound[j] * 1e3:.3g} µm, above the tolerance {tolerance * 1e3:g} µm "
                         "(the correction tilts or stretches the plane: table slopes, workpiece "
                         "tilt); refusing", filename, int(line[rows[j]]))
    j = int(np.argmax(bound))
    return {"blocks": int(len(rows)), "bound": float(bound[j]), "line": int(line[rows[j]]),
            "radius": float(r[j]), "source": source, "tolerance": float(tolerance)}


def _cutter_items(cut) -> list:
    """Provenance items for the G41/G42 check (none without cutter compensation)."""
    if cut is None:
        return []
    return [("CUTTER-COMP", f"G41/G42 on {cut['blocks']} blocks: correction at the programmed "
             f"contour; radius {cut['radius']:g} mm [{cut['source']}]; worst bound "
             f"{cut['bound']:.2e} mm at line {cut['line']}, tolerance {cut['tolerance']:g} mm")]


def _compensate_flow(fl, machine, errors, *, filename, provenance, **kw):
    """`compensate_program` of a program with subprogram calls: the expansion (the blocks in
    the order they run) is compensated and checked, then folded back: subprograms compensated
    once where every run of each block came out the same, else the calls written out."""
    from .gcode import flow
    from .gcode.provenance import header_lines, insert_header
    try:
        new, report = compensate_program(fl.expanded, machine, errors, filename=filename,
                                         provenance=None, force=True, **kw)
    except InputError as exc:
        raise flow.remap_error(fl, exc, filename) from None
    mode, new = flow.fold(fl, new, filename)
    note = (f"subprograms: {fl.calls} run(s) followed; each subprogram compensated once (the "
            "correction is the same on every run)" if mode == "once" else
            f"subprograms: {fl.calls} run(s) followed and written out as the blocks they run "
            + ("(subprograms from other files: "
               + ", ".join(Path(f).name for _, f in fl.segments[1:])
               + "; the control's own copies would run uncompensated)" if fl.external else
               "(the correction differs between runs)") + "; the calls are left as comments")
    if fl.loop_len:
        note = ((note + "; ") if fl.calls else "") + (
            f"M99 on line {fl.loop_line + 1} repeats the main program: a second run was "
            "compensated from the state the first leaves and came out the same; M99 kept")
    src_line = lambda m: ", ".join(dict.fromkeys(  # noqa: E731
        str(int(fl.origin[int(x) - 1]) + 1) for x in m.group(1).split(", ")))
    notes = tuple(re.sub(r"(?<=line\(s\) )(\d+(?:, \d+)*)", src_line, n) for n in report["notes"])
    report = dict(report, notes=notes + (note,), flow=mode,
                  lines=fl.main_lines or len(flow._lines(fl.text)))
    if report.get("cutter") is not None:
        # the worst G41/G42 block by its source line (a subprogram file: named)
        f, ln = fl.where(int(fl.origin[report["cutter"]["line"] - 1]))
        report["cutter"] = dict(report["cutter"], line=ln if f == filename else f"{Path(f).name}:{ln}")
    if provenance is not None:
        new, _, added = insert_header(new, header_lines(provenance + _cutter_items(report["cutter"])))
        report["header_lines"] = added
    return new, report


def _travel_check_emitted(machine, emitted, kn, prog, filename):
    """The written end positions inside the travel (compensation can push a block that was
    just inside its axis' travel out of it)."""
    inside = _columns_inside(machine, emitted)
    for k, ax in enumerate(machine.axes):
        lo, hi = ax.limits
        tol = 0.5 * ax.resolution
        if inside[k]:
            continue                             # (NaN anywhere: the full test)
        with np.errstate(invalid="ignore"):
            bad = np.flatnonzero(((emitted[:, k] < lo - tol) | (emitted[:, k] > hi + tol)) & kn)
        if len(bad):
            j = int(bad[0])
            raise InputError(f"the compensated {ax.name} {emitted[j, k]:g} is outside the travel "
                             f"[{lo:g}, {hi:g}] of axis {ax.name} on {machine.name}", filename,
                             int(prog.line[j]))


def verify_output(machine, text, errors, *, filename="<string>", stock=None, part=None,
                  clearance=0.2, tolerance=TOLERANCE, warn_only=False, **parse_kw):
    """Run the written program `text` (str, or its bytes: UTF-8) through the forward model
    with `errors` (the real machine) and check it against stock (rapids, ``clearance``) and
    part (feeds, ``tolerance``) with mtcomp.verify, block by block.  Blocks where the program has not fixed every axis yet
    (deferred) are not checked; canned cycle blocks and the moves into them neither (their holes
    go into the stock by design).  Returns the VerifyResult; raises VerifyError naming the first
    failing block unless warn_only."""
    from dataclasses import replace

    from . import gcode
    from .verify import FEED, PROBE, RAPID, VerifyError, verify_commands
    from .gcode.rotation import to_reference
    from .verify import program_arcs
    back = gcode.parse(text, axes=machine.axis_names, filename=f"{filename} (compensated output)",
                       tcp=True, rotation=True, **parse_kw)
    motion = np.asarray(back.motion, int).copy()
    motion[motion < 0] = RAPID
    motion[motion == 1] = FEED
    motion[(motion == 2) | (motion == 3)] = 3
    motion[np.asarray(back.cycle) > 0] = PROBE         # not checked
    arcs_all = program_arcs(machine, back, motion)
    position = to_reference(back, back.position)       # G68: where the axes go
    tcp, tlen = np.asarray(back.tcp, bool), np.asarray(back.tool_tip, float)
    if isinstance(text, str):
        src = text.split("\n")
        line_text = src.__getitem__
    else:                                              # bytes: the lines named decoded alone
        src = bytes(text).split(b"\n")
        line_text = lambda i: src[i].decode("utf-8", "surrogateescape")  # noqa: E731
    lines = np.asarray(back.line, int)
    kn = np.asarray(back.known)
    # runs of consecutive blocks with every axis known
    edges = np.flatnonzero(np.diff(np.concatenate([[0], kn.astype(np.int8), [0]])))
    results = []
    for a, b in zip(edges[::2], edges[1::2]):
        sl = slice(int(a), int(b))
        res = verify_commands(machine, position[sl], motion[sl], stock=stock, part=part,
                              tcp=tcp[sl], tool_length=tlen[sl],
                              clearance=clearance, tolerance=tolerance, errors=errors,
                              lines=lines[sl], texts=[line_text(ln - 1) if 0 < ln <= len(src) else ""
                                                      for ln in lines[sl]],
                              arcs=tuple(x[sl] for x in arcs_all), name=filename,
                              raise_on_violation=False)
        results.append(res)
    if not results:
        return None
    best = min(results, key=lambda r: r.min_clearance)
    out = replace(best, n_blocks=sum(r.n_blocks for r in results),
                  n_samples=sum(r.n_samples for r in results),
                  min_part=min(r.min_part for r in results),
                  violations=tuple(v for r in results for v in r.violations))
    from .verify import gauge_point_warning
    warning = gauge_point_warning(lines, back.tool_unknown)    # tool change before its G43
    if warning:
        out = replace(out, warnings=out.warnings + (warning,))
    if out.violations and not warn_only:
        v = out.violations
        raise VerifyError(f"{filename}: the compensated program fails the verification (lines "
                          "of the written program): "
                          + v[0].describe(clearance, tolerance)
                          + (f" (and {len(v) - 1} more blocks)" if len(v) > 1 else ""), out)
    return out


def emitted_positions(prog, info, new_text, *, filename="<string>", start=None, res=None,
                      tool_lengths=None, work_offsets=None, arc_tol=None, out_line=None,
                      consume: bool = False):
    """End position of every motion block of the rewritten program `new_text` (str, or its
    bytes; N, n_axes; mm, deg), as the control reads it back.  The axis words are found again
    in the written bytes on each block's output line and run through the input's modal state
    (`gcode.rewrite.check_written`, one compiled pass); they must give the counts `rewrite`
    meant to emit
    (``info["emitted"]``), else the output is refused (InputError: a wrong byte in a written
    number would otherwise go to the machine unseen).  Programs where that reading does not
    apply (canned cycles, whose holes may be written out as new lines; linearised arcs; G92;
    G16 polar blocks, whose radius and angle words put the point up to a count from the
    emitted one; no compiled reader) are parsed back whole instead.  ``consume``: the caller
    gives up ``info["emitted"]`` (taken out of ``info``; where read back, the positions are
    written over its memory: one (N, n_axes) array fewer at the peak)."""
    from .gcode.rewrite import check_written, emitted_values
    if not isinstance(new_text, str):                 # the written bytes (compensate_program)
        data, new_text = new_text, None
    else:
        data = None
    polar = prog.polar is not None and bool(np.asarray(prog.polar).any())
    if out_line is not None and not polar:
        try:
            if data is None:
                data = new_text.encode("utf-8", "surrogateescape")
            ok = check_written(prog, info, data, out_line)
        except ValueError as exc:
            j = exc.args[1] if len(exc.args) > 1 else None
            raise InputError(f"internal error, the written program is not what was computed: "
                             f"{exc.args[0]}; refusing to write it", filename,
                             None if j is None else int(prog.line[j])) from None
        if ok:
            return emitted_values(info, consume=consume)
    from . import gcode
    if new_text is None:
        new_text = bytes(data)                        # (a copy: the caller may edit its bytes)
    after_prog = gcode.parse(new_text, axes=prog.axes, start=start, resolution=res,
                             tool_lengths=tool_lengths, work_offsets=work_offsets, arc_tol=arc_tol,
                             tcp=True, rotation=True,
                             filename=f"{filename} (compensated output)")
    # the output block that ends each input block (linearised arcs add lines after their block)
    idx = np.searchsorted(after_prog.line, out_line, side="right") - 1
    got = np.asarray(after_prog.position)[idx]
    # what the control reads must be what was computed: the output's words rounded to their
    # counts and G91 increments summed count by count, as the control does (and as the emitted
    # counts are); within a count, as a G16 angle rounded to its increment moves the point by
    # up to one count (gcode.polar)
    if "emitted" in info and out_line is not None:
        from .gcode.rewrite import _control_counts
        r = np.asarray(info["emitted_resolution"], float)
        off = np.asarray(after_prog.offset)
        offc = np.rint(off / r).astype(np.int64) if off.any() else None
        from .gcode import cycle_counts

        def counts(p, offc):
            c = _control_counts(p, r, offc)
            if np.asarray(p.cycle).any():
                # the cycles' return levels and the further holes of K/L repeats, as the
                # rewrite counts them (gcode.cycle_counts)
                c = cycle_counts.control_counts(p, c, r, cycle_counts.stepped_rows(p), offc)
            return c[1:]
        back = counts(after_prog, offc)[idx]
        want = np.asarray(info["emitted"], float)
        # (canned cycle blocks: their emitted row is the cycle's own end level, not the
        # position the parser gives the block)
        kn = np.asarray(info["compensated"], bool) & (np.asarray(prog.cycle) == 0)
        with np.errstate(invalid="ignore"):
            ok = np.abs(back - want) <= 1.0
        # an axis the written program leaves unknown at a block is compared only where the
        # input fixed it there (an axis neither fixes got no word: nothing to read back)
        unk = np.isnan(back) & kn[:, None]
        if unk.any():
            off_in = np.asarray(prog.offset)
            unk &= np.isnan(counts(prog, np.rint(off_in / r).astype(np.int64)
                                   if off_in.any() else None))
            ok |= unk
        bad = kn & ~ok.all(axis=1)
        if bad.any():
            j = int(np.argmax(bad))
            raise InputError(f"internal error, the written program is not what was computed: "
                             f"its block reads back as counts {back[j].tolist()}, not "
                             f"{want[j].tolist()}; refusing to write it", filename,
                             int(prog.line[j]))
    return got


def _sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _cmd_compensate(args) -> int:
    from . import __version__
    from .gcode import read_program_bytes
    machine = load_machine(args.machine)
    errors = load_errors(args.errors, machine=machine)
    src = Path(args.program)
    # the bytes, compensated and written as bytes: CR LF and 8-bit comments stay byte for byte
    data, encoding = read_program_bytes(src)
    out = Path(args.output) if args.output else src.with_name(src.stem + "_comp" + src.suffix)
    if out.is_dir():
        raise InputError("the output is a directory; give a file name", str(out), field="-o")
    from .gcode.provenance import check_nc_write
    # (the header itself is checked by compensate_program)
    check_nc_write(None, output=out, inputs=(src, args.errors))
    tol = None if args.chordal_tol is None else args.chordal_tol * 1e-3
    arc_tol = None
    if args.arc_tol is not None:
        if not (math.isfinite(args.arc_tol) and args.arc_tol >= 0):
            raise InputError(f"expected a finite number of µm >= 0, got {args.arc_tol}", field="--arc-tol")
        arc_tol = args.arc_tol * 1e-3
    search = [str(src.parent)] + [d for d in (args.subprogram_path or "").split(os.pathsep) if d]
    for d in search[1:]:
        if not os.path.isdir(d):
            raise InputError("not a directory", d, field="--subprogram-path")
    start = parse_start(args.start, machine)
    from .gcode.offsets import tool_lengths_of_options
    tools, offsets = tool_lengths_of_options(args, machine.axis_names)
    options = [f"unknown-start {args.unknown}"]
    if tools:
        options.append("tool lengths " + ",".join(f"H{k}={v:g}" for k, v in tools.items())
                       + (" (H = T)" if "H = T" in getattr(tools, "note", "") else ""))
    if offsets:
        options.append(f"work offsets {Path(args.work_offsets).name}")
    if tol is not None:
        options.append(f"chordal-tol {tol:g} mm")          # ASCII: controls read the comment
    if arc_tol is not None:
        options.append(f"arc-tol {arc_tol:g} mm")
    if start:
        options.append("start " + ",".join(f"{k}={v:g}" for k, v in start.items()))
    if args.subprogram_path:
        options.append("subprogram-path " + args.subprogram_path)
    if args.force:
        options.append("force")
    keep = None if args.arc_keep_tol is None else args.arc_keep_tol * 1e-3
    if keep is not None:
        if keep > args.tolerance:
            raise InputError(f"expected at most --tolerance ({args.tolerance * 1e3:g} µm), got "
                             f"{args.arc_keep_tol:g} µm", field="--arc-keep-tol")
        options.append(f"arc-keep-tol {keep:g} mm")
    cutter_radius = args.cutter_radius
    if cutter_radius is not None:
        if not (math.isfinite(cutter_radius) and cutter_radius >= 0):
            raise InputError(f"expected a cutter radius >= 0 mm, got {cutter_radius}",
                             field="--cutter-radius")
        options.append(f"cutter-radius {cutter_radius:g} mm")
    # G41/G42 D<n> radii: the offsets file's [D] (radius), else the tool table's D column
    # (diameter of tool n, LinuxCNC)
    cutter_offsets = dict(getattr(tools, "radius_of_tool", {}) or {})
    if args.work_offsets is not None:
        from .gcode.offsets import read_offsets
        cutter_offsets.update(read_offsets(args.work_offsets, machine.axis_names)[1])
    cutter_offsets = cutter_offsets or None
    provenance = [("VERSION", f"mtcomp {__version__}"),
                  ("ERRORS", f"{Path(args.errors).name} SHA256 {_sha256(args.errors)}"),
                  ("MACHINE", machine.name),
                  ("DATE", datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")),
                  ("SOURCE", src.name), ("OPTIONS", "; ".join(options))]
    stock = part = None
    if args.stock or args.part:
        from .verify import ShapeStock, parse_stock
        stock = parse_stock(args.stock) if args.stock else None
        part = ShapeStock.from_step(args.part) if args.part else None
        if not (math.isfinite(args.clearance) and args.clearance >= 0):
            raise InputError(f"expected a clearance >= 0 mm, got {args.clearance}", field="--clearance")
        if not (math.isfinite(args.tolerance) and args.tolerance >= 0):
            raise InputError(f"expected a tolerance >= 0 mm, got {args.tolerance}", field="--tolerance")
        options.append(f"verified clearance {args.clearance:g} mm" + (" warn-only" if args.warn_only else ""))
    from .geometric.reversal import load_reversal
    new_data, rep = compensate_program(data, machine, errors, filename=str(src), chordal_tol=tol,
                                       start=start, unknown=args.unknown, provenance=provenance,
                                       force=args.force, progress=Progress("compensating", args.progress),
                                       tool_lengths=tools, work_offsets=offsets, arc_tol=arc_tol,
                                       stock=stock, part=part, clearance=args.clearance,
                                       tolerance=args.tolerance, warn_only=args.warn_only,
                                       search_path=search, cutter_radius=cutter_radius,
                                       cutter_offsets=cutter_offsets, encoding=encoding,
                                       reversal=load_reversal(args.reversal or ()) or None,
                                       arc_keep_tol=keep)
    del data
    atomic_write(out, new_data)
    print(f"{src}: {rep['lines']} lines, {rep['blocks']} motion blocks on {machine.name} -> {out}")
    if encoding not in ("ascii", "utf-8"):
        print("note: the program is not UTF-8: its 8-bit comment characters were read as Latin-1 "
              "and written back byte for byte")
    if rep["deferred"]:
        print(f"{rep['deferred']} blocks before every axis position is known passed uncompensated "
              "(give --start to compensate them)")
    if rep["idle_axes"]:
        lin = [a for a in rep["idle_axes"] if a in "XYZUVW"]
        print(f"axes the program never writes, taken at 0: {' '.join(rep['idle_axes'])}"
              + (f" (no word is written for {' '.join(lin)}, so its correction is not applied: "
                 "give --start to state where it stands)" if lin else ""))
    for note in ([tools.note] if getattr(tools, "note", "") else []) + list(rep["notes"]):
        if note.startswith("warning: "):
            print(note, file=sys.stderr)
        else:
            print(f"note: {note}")
    if rep["linearised"]:
        print(f"{rep['linearised']} arcs written as lines (chordal tolerance {rep['chordal_tol'] * 1e3:g} µm)")
    if rep["cycles_kept"] or rep["cycles_expanded"]:
        print(f"canned cycle holes: {rep['cycles_kept']} kept (rigid shift: positions and R/Z levels "
              f"compensated), {rep['cycles_expanded']} written out as moves")
    cut = rep.get("cutter")
    if cut is not None:
        print(f"cutter radius compensation G41/G42 on {cut['blocks']} blocks: corrected at the "
              f"programmed contour; radius {cut['radius']:g} mm "
              + (cut["source"] if cut["source"].startswith("assumed") else f"({cut['source']})")
              + "; worst "
              f"difference from the correction at the tool centre {cut['bound'] * 1e3:.3g} µm "
              f"(line {cut['line']}), within the tolerance {cut['tolerance'] * 1e3:g} µm")
    print(f"tool-edge error before compensation: max {rep['before_max'] * 1e3:10.3f} µm   "
          f"RMS {rep['before_rms'] * 1e3:10.3f} µm")
    print(f"tool-edge error after  compensation: max {rep['after_max'] * 1e6:10.3f} nm   "
          f"RMS {rep['after_rms'] * 1e6:10.3f} nm")
    ver = rep["verify"]
    if ver is not None:
        print(ver.summary(max_listed=20).replace("verify ", "verification of the output, ", 1))
        if ver.violations:
            print(f"warning: {len(ver.violations)} block(s) fail the verification (--warn-only): "
                  "the program was written anyway", file=sys.stderr)
    elif stock is not None or part is not None:
        print("verification: no block with every axis position known, nothing checked")
    return 0


def _cmd_machines(args) -> int:
    if args.name:
        m = load_machine(args.name)
        from ._io import dump_toml
        sys.stdout.write(dump_toml(m.to_dict()))
        return 0
    for name in list_presets():
        m = load_machine(name)
        chain = " ".join(f"{a.name}{'*' if a.side == 'workpiece' else ''}" for a in m.axes)
        print(f"{name:20s} {chain:16s} {m.description}")
    print("(* = axis on the workpiece side)")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("compensate", help="rewrite an NC program for setting and geometric errors",
                       description="Rewrite an NC program so that the real machine with the given "
                                   "errors cuts what the program meant; prints the tool-edge error "
                                   "before and after (forward model). The output starts with a "
                                   "provenance comment; such a program is not compensated again.")
    p.add_argument("program", help="NC program (G-code)")
    p.add_argument("--machine", "-m", required=True, help=f"preset ({', '.join(list_presets())}) or TOML file")
    p.add_argument("--errors", "-e", required=True, help="errors TOML (docs/errors-format.md)")
    p.add_argument("-o", "--output", help="output program (default: PROGRAM_comp.nc)")
    p.add_argument("--chordal-tol", type=positive_float, default=None, metavar="UM",
                   help="chordal tolerance for linearised arcs in µm (default 0.1, at least twice "
                        "the linear axis resolution)")
    p.add_argument("--arc-keep-tol", type=positive_float, default=None, metavar="UM",
                   help="keep an arc as G2/G3 where its corrected path is a circle within this, "
                        "µm (default: the chordal tolerance; at most --tolerance)")
    p.add_argument("--arc-tol", type=float, default=None, metavar="UM",
                   help="largest accepted difference of an arc's radius at its start and end, in "
                        "µm (default 20, 50.8 in inch programs, as LinuxCNC); within it the arc is "
                        "read as a spiral, as controls run it")
    p.add_argument("--start", metavar="X=..,Y=..",
                   help="axis positions before the first block (mm, deg), where known")
    p.add_argument("--unknown", choices=("defer", "refuse"), default="defer",
                   help="blocks before every axis position is known: pass them uncompensated "
                        "(defer, default) or refuse the program naming the line")
    from .gcode.offsets import add_tool_length_options
    add_tool_length_options(p)
    p.add_argument("--cutter-radius", type=float, default=None, metavar="MM",
                   help="tool radius under G41/G42, mm (default: the [D] value of the offsets "
                        "file, else 10 mm assumed and said so): bounds the error of correcting "
                        "the programmed contour instead of the tool centre")
    p.add_argument("--subprogram-path", metavar="DIR[%sDIR]" % os.pathsep.replace("%", "%%"),
                   help="directories searched, after the program's own, for subprograms in other "
                        "files (M98 P1234: O1234[.ext]; o<name> call: name.ngc); they are written "
                        "out in the output")
    p.add_argument("--reversal", nargs="+", metavar="CSV",
                   help="reversal tables (<axis>_reversal.csv of 'geometric build' or 'geometric reversal'): "
                        "each position is also corrected for the direction it is approached in")
    p.add_argument("--force", action="store_true",
                   help="compensate a program that mtcomp has already compensated")
    p.add_argument("--stock", help="verify the output against this stock (workpiece frame): "
                                   "box:x0,y0,z0,x1,y1,z1 (mm), plane:Z or a STEP file; rapids "
                                   "must keep --clearance from it")
    p.add_argument("--part", help="STEP of the finished part: feed moves of the output must not "
                                  "gouge it by more than --tolerance")
    p.add_argument("--clearance", type=float, default=0.2, help="rapid clearance, mm (default 0.2)")
    p.add_argument("--tolerance", type=float, default=TOLERANCE,
                   help="allowed depth of feed moves into the part, and how much further than "
                        "the uncompensated program a block's middle may leave the programmed path, "
                        "mm (default 0.0005)")
    p.add_argument("--warn-only", action="store_true",
                   help="write the program even if the verification fails (report the blocks)")
    p.add_argument("--progress", action="store_true", default=None, help="show a progress bar")
    p.set_defaults(func=_cmd_compensate)

    p = sub.add_parser("machines", help="list machine presets, or print one as TOML")
    p.add_argument("name", nargs="?", help="preset name or machine file")
    p.set_defaults(func=_cmd_machines)
