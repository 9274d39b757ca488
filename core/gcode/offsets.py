"""Tool lengths and work offsets: as the control holds them (tables the user gives, files shops
keep, G10 in the program) and what they make of the program's positions.

Files (docs/gcode.md, "Offset files"):

* a LinuxCNC tool table: ``T1 P1 Z+50.0 D6.0 ;comment`` per tool; the Z value is the tool
  length of tool (and H number) 1;
* an offsets TOML: ``[H]`` tool lengths by H number, ``[D]`` cutter radii by D number (the
  G41/G42 bound of `mtcomp compensate`), ``[G54]``..``[G59]``, ``["G54.1 P2"]`` (Haas:
  ``["G154 P2"]``, ``[G110]``..``[G129]``) work offsets as axis
  letter = mm/deg;
* CSV of ``H,length_mm`` lines (a header and ``#`` comments allowed).

G10 in the program (read in program order, as the control executes it):

* ``G10 L2 P1..P6`` (G54..G59), ``G10 L20 P<n>`` (Fanuc: G54.1 P<n>, read only where the program
  uses G54.1, since on LinuxCNC L20 sets the offset from the current position): axis words set
  those axes of the offset (L20 in G91, Fanuc only: add to them; L1/L2 in G91 are refused, the
  dialects differ);
* ``G10 L10 P<h> R`` / ``G10 L11 P<h> R`` (Fanuc geometry / wear of H), ``G10 L1 P<t> Z``
  (LinuxCNC tool table entry): tool lengths; ``G10 L12/L13`` (D values) change nothing here;
* ``G10 L2 P0`` (Fanuc: the external offset, LinuxCNC: the current one): read where the
  program uses one work offset only, where both mean the same;
* everything else (LinuxCNC G59.1-3, L10/L11/L20 relative to the current position, L1 with R
  only, rotation R in L2) is refused naming the line where it matters.
"""
from __future__ import annotations

import math
import os
import re
from typing import Mapping

import numpy as np

from .._io import InputError
from .codes import INCH, LINEAR


def _ffill(values, isset, default):
    from . import _ctok
    out = _ctok.ffill(values, isset, default)            # compiled, where built: one pass
    if out is not None:
        return out
    idx = np.where(isset, np.arange(len(values)), -1)
    np.maximum.accumulate(idx, out=idx)
    return np.where(idx >= 0, values[np.maximum(idx, 0)], default)


def _renumber(numbers, mapping):
    """Tool numbers (float array, NaN where none) -> their H numbers by ``mapping`` {T: H}."""
    out = numbers.copy()
    for t, h in mapping.items():
        out[numbers == t] = h
    return out


def wcs_name(key: int) -> str:
    if key // 1000 in (541, 154):
        return f"G{'54.1' if key // 1000 == 541 else '154'} P{key % 1000}"
    return f"G{key // 1000}"


def axis_vector(vec, axes):
    if isinstance(vec, Mapping):
        up = {str(k).upper(): float(v) for k, v in vec.items()}
        return np.array([up.get(a, 0.0) for a in axes])
    v = np.asarray(vec, float).reshape(-1)
    if len(v) != len(axes) or not np.isfinite(v).all():
        raise ValueError(f"offset vectors need {len(axes)} finite values ({' '.join(axes)})")
    return v


# --------------------------------------------------------------------------------- G10 blocks

def g10_events(lines, words, axes, inch_line, incr_line, uses_g541, filename):
    """G10 blocks as events ``(line, kind, number, values, incremental)``: kind "wcs" (number: a
    work offset key 54000..59000, or 541000 + P / 154000 + P for L20 where ``uses_g541`` is
    541 / 154: the program's G54.1 P or Haas G154 P offsets; 0: neither, L20 refused;
    values (n_axes,) NaN where not written) or
    "geo"/"wear" (number: H, values: length mm) or "amb" (G10 L1 P R: a tool length on Fanuc
    memory A, a radius on LinuxCNC; refused if that H is used).  ``words[line]`` is a list of
    (letter, value)."""
    out = []
    lin = np.array([a in LINEAR for a in axes])
    for ln in lines:
        w = dict(words[ln])
        scale = INCH if inch_line[ln] else 1.0
        inc = bool(incr_line[ln])

        def fail(what):
            raise InputError(f"G10 {what}", file=filename, line=int(ln) + 1)
        if "L" not in w or "P" not in w:
            fail("without L or P: not read")
        L, P = w["L"], w["P"]
        if L != int(L) or P != int(P) or P < 0:
            fail(f"L{L:g} P{P:g}: whole numbers expected")
        L, P = int(L), int(P)
        vals = np.array([w.get(a, np.nan) for a in axes]) * np.where(lin, scale, 1.0)
        if inc and L in (1, 2):
            fail(f"L{L} in G91: Fanuc adds the values to the offset, LinuxCNC's reading differs; "
                 "not read (write the offset in G90)")
        if L == 2 or L == 20:
            if "R" in w:
                fail(f"L{L} with R (a rotation of the coordinate system, LinuxCNC) is not supported")
            if L == 2:
                if not 0 <= P <= 6:
                    fail(f"L2 P{P}: only P0..P6 are read (G59.1-G59.3 are not)")
                # P0: Fanuc's external offset (added to every work offset), LinuxCNC's current
                # one; resolved where the program uses one work offset only (key 0 till then)
                key = (53 + P) * 1000 if P else 0
            else:
                if not uses_g541:
                    fail("L20 sets the G54.1 P offsets on Fanuc controls (G154 P on Haas) but the "
                         "offset from the current position on LinuxCNC; the program uses neither "
                         "G54.1 nor G154: not read")
                key = (154000 if uses_g541 == 154 else 541000) + P
            out.append((int(ln), "wcs", key, vals, inc))
        elif L in (10, 11) and "R" in w:
            out.append((int(ln), "geo" if L == 10 else "wear", P, w["R"] * scale, inc))
        elif L == 1 and "Z" in w:
            # LinuxCNC tool table entry: Z is the tool length of tool P (G43 H<P>)
            out.append((int(ln), "geo", P, w["Z"] * scale, inc))
        elif L == 1 and "R" in w:
            out.append((int(ln), "amb", P, w["R"] * scale, inc))
        elif L in (12, 13):
            pass                                   # D (radius) values: not read (--cutter-radius, [D])
        else:
            fail(f"L{L} with {' '.join(sorted(k for k in w if k not in 'LPG'))}: not read (L10/L11 "
                 "with axis words set offsets from the current position on LinuxCNC)")
    return out


# ------------------------------------------------------------------------ offsets per line

def offsets_per_line(axes, wcs_l, p_line, tool_l, h_line, t_line, work_offsets, tool_lengths,
                     events, first_motion, n_lines, filename, notes, written=None,
                     change_line=None, dyn_len=None):
    """Per line (n_lines, n_axes) the offset from program coordinates to the reference frame
    (the work offset in effect at the first motion block, ``first_motion``): work offset minus
    the reference one, plus +/- the tool length along Z for G43/G44; and per line the tool
    length of G43.4 blocks.  Also returned, last: the reference work offset's own value
    (n_axes,), where the program origin lies in machine coordinates (NaN: not given; zeros
    where the program names no work offset and no G54 is given).  Offsets not given are unknown: where only one is used and no G10
    changes it, the difference is 0; otherwise the program is refused naming the line.
    Tool lengths not given are taken as 0 and noted.  ``written`` (n_axes,): the axes the
    program writes; an unknown offset of an axis it never writes is harmless (the control does
    not move an axis that is not commanded).

    ``change_line`` (n_lines,) bool: the tool changes (M6 lines; default: the T words); the tool
    loaded is the last T word. Also returned: per line the tool tip (mm along -tool axis from
    the gauge point) and whether the tool in the spindle has an unknown length there (after a
    change, before its G43: its tip taken at the gauge point).  ``dyn_len`` (n_lines,): the
    length (mm) LinuxCNC's G43.1 Z sets on its lines (tool_l 431), NaN elsewhere: G43 with it."""
    n_ax = len(axes)
    # (n_lines, n_ax) zeros, allocated where an offset is added: without offsets a read-only
    # zero view is returned (no memory: 40 MB at 1 M lines of five axes)
    off = None

    def offsets():
        nonlocal off
        if off is None:
            off = np.zeros((n_lines, n_ax))
        return off
    assumed = []
    frame = np.full(n_ax, np.nan)         # the reference work offset's own value (machine frame)
    wev = [e for e in events if e[1] == "wcs"]
    tev = [e for e in events if e[1] != "wcs"]
    # -- work offsets
    wset = wcs_l >= 0
    keys = wcs_l * 1000
    with_p = (wcs_l == 541) | (wcs_l == 154)
    if with_p.any():                      # (P numbers read only where a code takes one)
        pnum = np.clip(np.nan_to_num(p_line, nan=1), 0, 999).astype(np.int64)
        keys = keys + np.where(with_p, pnum, 0)
    # Haas G110..G129 are G154 P1..P20
    haas = (wcs_l >= 110) & (wcs_l <= 129)
    if haas.any():
        keys = np.where(haas, 154000 + wcs_l - 109, keys)
    table = {}
    for key, vec in dict(work_offsets or {}).items():
        name = str(key).upper().replace(" ", "")
        m = re.fullmatch(r"G(\d+)", name)
        if m and 110 <= int(m.group(1)) <= 129:
            name = f"G154P{int(m.group(1)) - 109}"             # Haas: G110..G129 = G154 P1..P20
        elif not re.fullmatch(r"G5[4-9]|G54\.1P\d+|G154P\d+", name):
            # (a misspelt name would otherwise leave its offset unused without a word)
            raise InputError(f"work offset {str(key)!r}: expected G54..G59, 'G54.1 P<n>', "
                             "'G154 P<n>' or G110..G129", field="work_offsets")
        table[name] = axis_vector(vec, axes)
    if wset.any() or wev:
        used = list(dict.fromkeys(keys[wset].tolist())) or [54000]
        p0 = [e for e in wev if e[2] == 0]
        if p0:
            # the external offset (Fanuc) and the current one (LinuxCNC) are the same change
            # only in a program that stays in one work offset
            first_sel = int(np.argmax(wset)) if wset.any() else n_lines
            if len(used) > 1 or (used[0] != 54000 and p0[0][0] < first_sel):
                raise InputError(f"G10 L2 P0 sets the external work offset (Fanuc, added to every "
                                 f"work offset) or the current one (LinuxCNC), and the program "
                                 f"uses {', '.join(wcs_name(k) for k in used)}, where the two "
                                 "differ: write G10 L2 P<n> for the offset meant",
                                 file=filename, line=p0[0][0] + 1)
            wev = [(e[0], e[1], used[0] if e[2] == 0 else e[2], e[3], e[4]) for e in wev]
        if not wev:
            cur0 = _ffill(keys, wset, used[0])
            fm = min(max(int(first_motion), 0), n_lines - 1) if n_lines else 0
            given = table.get(wcs_name(int(cur0[fm]) if n_lines else used[0]).replace(" ", ""))
            if given is not None:
                frame = np.asarray(given, float)
            if len(used) > 1:
                missing = [wcs_name(k) for k in used if wcs_name(k).replace(" ", "") not in table]
                if missing:
                    ln = int(np.flatnonzero(wset & (keys != used[0]))[0])
                    raise InputError(f"the program switches from {wcs_name(used[0])} to "
                                     f"{wcs_name(keys[ln])}: give the work offsets "
                                     f"({', '.join(wcs_name(k) for k in used)}) to compensate in "
                                     "one workpiece frame", file=filename, line=ln + 1)
                vec = {k: np.nan_to_num(table[wcs_name(k).replace(" ", "")]) for k in used}
                ref = vec[used[0]]
                cur = _ffill(keys, wset, used[0])
                for k in used:
                    offsets()[cur == k] += vec[k] - ref
        else:
            cur = _ffill(keys, wset, used[0])
            assumed, frame = _offsets_with_g10(axes, offsets(), cur, table, wev, first_motion,
                                               filename, np.ones(n_ax, bool) if written is None
                                               else np.asarray(written, bool))
            if assumed:
                notes.append(f"work offsets of {' '.join(assumed)} (axes the program does not "
                             "write) are not all set: their differences taken as 0; a "
                             "compensation that writes them is refused")
    # -- tool length (G43 +, G44 -, G49 cancel) along Z; G43.4: in the TCP transform
    tset = tool_l >= 0
    tlen = tip = np.broadcast_to(np.float64(0.0), (n_lines,))     # (read-only, no memory)
    active = np.zeros(n_lines, bool)
    lengths = {int(k): float(v) for k, v in dict(tool_lengths or {}).items()}
    # a tool table with an H column: tool T's own length and offset number (else H = T)
    by_tool = getattr(tool_lengths, "by_tool", None)
    h_of_tool = getattr(tool_lengths, "h_of_tool", None) or {}
    if tset.any():
        # G43/G44/G43.4 without H: the loaded tool T (LinuxCNC)
        h_line = h_line.copy()
        noh = tset & (tool_l != 49) & (tool_l != 431) & np.isnan(h_line)
        if noh.any():
            tmod = _ffill(t_line, ~np.isnan(t_line), np.nan)
            tmod = _renumber(tmod, h_of_tool)
            h_line[noh] = tmod[noh]
            if np.isfinite(tmod[noh]).any():
                notes.append("G43 without H: the tool length of the loaded tool (T word) is used, as "
                             "on LinuxCNC")
        hmodal = _ffill(h_line, ~np.isnan(h_line), np.nan)
        mode = _ffill(tool_l, tset, 49)
        active = mode != 49
        L, unknown = _lengths_per_line(hmodal, active & (mode != 431), lengths, tev, filename)
        if (mode == 431).any():
            # G43.1 Z<len>: the length its block gives, until G43/G44/G49 or the next G43.1
            dl = _ffill(np.where(tool_l == 431, dyn_len, np.nan), tset, np.nan)
            L = np.where(mode == 431, dl, L)
            mode = np.where(mode == 431, 43, mode)
        if unknown:
            notes.append(f"tool length offsets H{', H'.join(map(str, unknown))} not given: taken as "
                         "0 mm (the compensation then evaluates the errors at the programmed tool "
                         "tip position; give the tool lengths where errors depend on Z)")
        if "Z" in axes:
            sign = np.where(mode == 43, 1.0, np.where(mode == 44, -1.0, 0.0))
            offsets()[:, axes.index("Z")] += sign * L
        tlen = np.where(mode == 434, L, 0.0)
        # where the tool tip is: L along -tool axis from the gauge point (G44 subtracts: -L)
        tip = np.where(mode == 434, L, sign * L if "Z" in axes else 0.0)
    # G49 cancels the compensation, not the tool: its tip stays that far down the axis until
    # another tool is loaded. From a tool change (M6; without any M6 in the program, the T word)
    # to its G43 the axes do not carry the new tool's length, so its tip is that length below
    # the gauge point: the length of the number of its T word (tool table; --tool-lengths and
    # [H] by the same number, as shops number H after T; G10 before the change as for G43 H);
    # not known: the gauge point, flagged.
    change = ~np.isnan(t_line) if change_line is None else np.asarray(change_line, bool)
    newtool = change & ~active
    gauge = np.zeros(n_lines, bool)
    if newtool.any():
        tool = _ffill(t_line, ~np.isnan(t_line), np.nan)
        hm = np.where(newtool, tool, np.nan)
        try:      # the lengths the G10 blocks before the change have set, as for G43 H
            hm = _renumber(hm, h_of_tool)     # a table's H column: the tool's own entry
            Lnew, unk_h = _lengths_per_line(hm, newtool, lengths, tev, filename)
        except InputError:     # an ambiguous G10 entry of that number: its length is not known
            Lnew, unk_h = np.zeros(n_lines), np.unique(hm[newtool & np.isfinite(hm)]).tolist()
        newlen = np.where(np.isfinite(hm[newtool]) & ~np.isin(hm[newtool], list(unk_h)),
                          Lnew[newtool], np.nan)
        start = np.zeros(n_lines)
        start[newtool] = np.nan_to_num(newlen)
        unk = np.zeros(n_lines, bool)
        unk[newtool] = ~np.isfinite(newlen)
        tip = _ffill(np.where(active, tip, start), active | newtool, 0.0)
        # flagged only where a G43/G44/G43.4 follows (the program compensates lengths, so the
        # machine file's tool point is the gauge point); a tool never compensated is taken as
        # the program was written for it, at the machine file's tool point
        ev = np.flatnonzero(active | newtool)
        for i in np.flatnonzero(unk).tolist():
            k = int(np.searchsorted(ev, i, side="right"))     # the next change or G43 line
            if k < len(ev) and active[ev[k]]:
                gauge[i:ev[k]] = True
    elif tset.any():
        tip = _ffill(np.where(active, tip, 0.0), active, 0.0)
    if off is None:
        off = np.broadcast_to(np.zeros(n_ax), (n_lines, n_ax))
    if not (wset.any() or wev):
        # no work offset named: G54 if given, else the machine file's origin is the program's
        given = table.get("G54")
        frame = np.asarray(given, float) if given is not None else np.zeros(n_ax)
    return off, tlen, tuple(assumed), tip, gauge, frame


def _offsets_with_g10(axes, off, cur, table, wev, first_motion, filename, written):
    """Work offsets that G10 changes: each offset's value per axis is a known number or "its
    value before the program" (unknown, a symbol) plus a known change; the offset of a line is
    its work offset minus the reference one, defined where both are known or share the symbol."""
    n_ax = len(axes)
    state = {}                     # key -> (sym (n_ax,) object: None known or key, val (n_ax,))

    def value(key):
        if key not in state:
            v = table.get(wcs_name(key).replace(" ", ""))
            v = np.full(n_ax, np.nan) if v is None else np.asarray(v, float)
            sym = np.array([None if np.isfinite(x) else key for x in v], object)
            state[key] = (sym, np.nan_to_num(v))
        return state[key]

    n_lines = len(cur)
    ev_lines = sorted({e[0] for e in wev})
    change = sorted(set(ev_lines) | set(np.flatnonzero(np.r_[True, cur[1:] != cur[:-1]]).tolist())
                    | {first_motion})
    # pass 1: the state at every change point (events apply from their own line on)
    snaps = []
    by_line = {}
    for e in wev:
        by_line.setdefault(e[0], []).append(e)
    for c in change:
        for _, _, key, vals, inc in by_line.get(c, ()):
            sym, val = value(key)
            sym, val = sym.copy(), val.copy()
            w = np.isfinite(vals)
            if inc:
                val[w] += vals[w]
            else:
                val[w] = vals[w]
                sym[w] = None
            state[key] = (sym, val)
        k = int(cur[c])
        sym, val = value(k)
        snaps.append((c, k, sym.copy(), val.copy()))
    ref = next(s for s in snaps if s[0] == first_motion)
    assumed = set()
    for i, (c, k, sym, val) in enumerate(snaps):
        end = snaps[i + 1][0] if i + 1 < len(snaps) else n_lines
        same = np.array([a == b for a, b in zip(sym, ref[2])])
        if not (same | ~written).all() and c > first_motion - 1:
            bad = [a for a, s, w in zip(axes, same, written) if w and not s]
            raise InputError(f"from here on {wcs_name(k)} {' '.join(bad)} differs from "
                             f"{wcs_name(ref[1])} at the first motion block by an amount not known "
                             "(G10 or the offsets file gives one of them, not the other): give the "
                             "work offsets",
                             file=filename, line=c + 1)
        if c >= first_motion:
            assumed |= {a for a, s in zip(axes, same) if not s}
        off[c:end] += np.where(same, val - ref[3], 0.0)
    frame = np.array([v if sy is None else np.nan for sy, v in zip(ref[2], ref[3])], float)
    return [a for a in axes if a in assumed], frame


def tool_change_warnings(tool_l, h_line, change, feed_lines, limit=5) -> list:
    """Warnings for tool changes made while G43/G44/G43.4 is active and not followed by a new
    length (G43 H, an H word, G49) before the next feed move.  Fanuc and Haas controls keep the
    old H length then (it changes only at the next G43 H), and so does mtcomp; but a program that
    cuts with the new tool on the old tool's length is usually a post-processor or hand-editing
    slip.  tool_l (n_lines,): tool length code per line (43, 44, 49, 434, -1 none); h_line: H
    word per line (NaN none); change: the tool change lines (bool, or T values with NaN where
    none); feed_lines: sorted line indices of the feed blocks (G1-G3, cycles)."""
    change = np.asarray(change)
    ch = np.flatnonzero(~np.isnan(change) if change.dtype.kind == "f" else change)
    if not len(ch) or not len(feed_lines):
        return []
    mode = _ffill(tool_l, tool_l >= 0, 49)
    length_set = np.flatnonzero((tool_l >= 0) | ~np.isnan(h_line))
    hmodal = None
    out = []
    for c in ch.tolist():
        if mode[c] == 49 or tool_l[c] >= 0 or not np.isnan(h_line[c]):
            continue            # no length active, or the change block sets the new one itself
        k = int(np.searchsorted(feed_lines, c, side="right"))
        if k == len(feed_lines):
            continue
        f = int(feed_lines[k])
        e = int(np.searchsorted(length_set, c, side="right"))
        if e < len(length_set) and length_set[e] < f:
            continue
        if hmodal is None:
            hmodal = _ffill(h_line, ~np.isnan(h_line), np.nan)
        h = hmodal[c]
        hs = f"H{int(h)}" if np.isfinite(h) else "the old length"
        code = {43: "G43", 44: "G44", 434: "G43.4"}.get(int(mode[c]), "G43")
        out.append(f"warning: tool change on line {c + 1} under {code}: the tool length stays "
                   f"{hs} (as Fanuc and Haas controls keep it until the next G43 H), and the "
                   f"feed move on line {f + 1} comes before any new G43 H; check that the new "
                   "tool is meant to cut on the old tool's length")
        if len(out) == limit:
            out.append("warning: more tool changes under G43 without a new G43 H follow")
            break
    return out


def _lengths_per_line(hmodal, active, lengths, tev, filename):
    """Tool length (geometry + wear, mm) per line of the active H, with G10 tool events applied
    in program order; H numbers used whose length is not known (taken as 0)."""
    n = len(hmodal)
    L = np.zeros(n)
    geo = {h: v for h, v in lengths.items()}
    wear: dict = {}
    amb: dict = {}
    unknown = []
    evl = sorted({e[0] for e in tev})
    bounds = [0] + [x for x in evl if x > 0] + [n]
    by_line: dict = {}
    for e in tev:
        by_line.setdefault(e[0], []).append(e)
    for s, e_ in zip(bounds[:-1], bounds[1:]):
        for _, kind, h, v, inc in by_line.get(s, ()):
            if active[s] and hmodal[s] == h:
                raise InputError(f"G10 changes the length of H{h} while it is active (G43/G44 H{h}): "
                                 "controls differ on when that takes effect; set it before G43 "
                                 "or cancel with G49 first", file=filename, line=s + 1)
            if kind == "amb":
                amb[h] = s
                continue
            d = geo if kind == "geo" else wear
            if kind == "geo":
                amb.pop(h, None)
            if inc:
                if d is geo and h not in geo:
                    continue                      # unknown plus a change: still unknown
                d[h] = d.get(h, 0.0) + v
            else:
                d[h] = v
        seg = slice(s, e_)
        hs = hmodal[seg]
        act = active[seg] & np.isfinite(hs)
        if not act.any():
            continue
        for h in np.unique(hs[act]).astype(int).tolist():
            rows = np.flatnonzero(act & (hs == h)) + s
            if h in amb:
                raise InputError(f"H{h}: G10 L1 P{h} R on line {amb[h] + 1} is a tool length on "
                                 "Fanuc (memory A) but a radius on LinuxCNC: write G10 L10 (Fanuc) "
                                 "or G10 L1 Z (LinuxCNC)", file=filename, line=int(rows[0]) + 1)
            if h not in geo and h != 0 and h not in unknown:
                unknown.append(h)
            L[rows] = geo.get(h, 0.0) + wear.get(h, 0.0)
    return L, unknown


# ------------------------------------------------------------------------------------- files

_TBL_WORD = re.compile(r"([A-Za-z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")


class ToolTable(dict):
    """Tool lengths (mm) by H number read from a tool table, with what the table says about tools:
    ``by_tool`` {T: mm} (the length of the tool a T word loads), ``h_of_tool`` {T: H} and
    ``note``, the convention used (said in the output of the commands)."""

    def __init__(self, by_h=(), *, by_tool=None, h_of_tool=None, note="", radius_of_tool=None):
        super().__init__(by_h)
        self.radius_of_tool = dict(radius_of_tool or {})   # {T: mm}, half the D (diameter) column
        self.by_tool = dict(by_tool or {})
        self.h_of_tool = dict(h_of_tool or {})
        self.note = note


def _finite_number(v) -> bool:
    """True for an int or float (not a bool) that is finite as a float.  An integer of hundreds
    of digits (TOML and Python read it exactly) does not fit a float: that is not finite either,
    where math.isfinite would raise OverflowError."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    try:
        return math.isfinite(float(v))
    except OverflowError:
        return False


def read_tool_table(path) -> ToolTable:
    """Tool lengths (mm) by H number from a tool table: LinuxCNC's ``T1 P1 Z+50.0 D6.0 ;comment``
    lines, optionally with an ``H`` word, the length offset number of the tool (``T12 P3 H2
    Z+80.0``: G43 H2 takes 80).  Without any H word the offset number is the tool number (H = T,
    as Fanuc and Haas shops number them), and the returned table says so in ``note``."""
    from .._io import read_text
    by_h, by_t, h_of_t, rows = {}, {}, {}, []
    for n, raw in enumerate(read_text(path, what="tool table").splitlines(), start=1):
        ln = raw.split(";")[0].strip()
        if not ln:
            continue
        pos, words = 0, {}
        for m in _TBL_WORD.finditer(ln):
            if ln[pos:m.start()].strip():
                break
            words[m.group(1).upper()] = float(m.group(2))
            pos = m.end()
        # float() of a number of hundreds of digits is inf: not finite, never int()-converted
        bad = [k for k in ("T", "H", "P") if k in words and not math.isfinite(words[k])]
        if bad:
            raise InputError(f"{bad[0]} number too large in {raw.strip()[:60]!r}", file=path, line=n,
                             field=bad[0])
        if ln[pos:].strip() or "T" not in words or words["T"] != int(words["T"]) or words["T"] < 0:
            raise InputError(f"expected a tool table line like 'T1 P1 Z+50.0 D6.0 ;comment', got "
                             f"{raw.strip()!r}", file=path, line=n)
        if "H" in words and not (words["H"] == int(words["H"]) and words["H"] >= 0):
            raise InputError(f"expected an H offset number (an integer >= 0), got H{words['H']:g}",
                             file=path, line=n, field="H")
        if "Z" in words and not math.isfinite(words["Z"]):
            raise InputError("tool length Z is not finite", file=path, line=n)
        if "D" in words and not (math.isfinite(words["D"]) and words["D"] >= 0):
            raise InputError(f"tool diameter D must be a finite number >= 0 mm, got {words['D']:g}",
                             file=path, line=n, field="D")
        rows.append((n, words))
    has_h = any("H" in w for _, w in rows)
    for n, w in rows:
        t = int(w["T"])
        if has_h and "H" not in w:
            raise InputError(f"T{t} has no H word while other tools have one: give every tool its "
                             "length offset number, or none (then H = T)", file=path, line=n)
        h = int(w["H"]) if has_h else t
        if "Z" in w:
            if h in by_h and by_h[h] != w["Z"]:
                raise InputError(f"H{h} is given two lengths ({by_h[h]:g} and {w['Z']:g} mm)",
                                 file=path, line=n)
            by_h[h] = w["Z"]
            by_t[t] = w["Z"]
        h_of_t[t] = h
    note = (f"tool table {os.path.basename(str(path))}: lengths by the H column" if has_h else
            f"tool table {os.path.basename(str(path))} has no H column: H = T (offset number = tool "
            "number, the Fanuc/Haas convention)")
    # D is the diameter (LinuxCNC); G41/G42 D<n> takes tool n's radius
    radii = {int(w["T"]): 0.5 * w["D"] for _, w in rows if "D" in w}
    return ToolTable(by_h, by_tool=by_t, h_of_tool=h_of_t, note=note, radius_of_tool=radii)


def is_tool_table(path) -> bool:
    """Whether a file looks like a LinuxCNC tool table (its first entry starts with T)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096).decode("utf-8", "replace")
    except OSError:
        return False
    for ln in head.splitlines():
        ln = ln.split(";")[0].strip()
        if ln:
            return bool(re.match(r"[Tt]\s*\d", ln))
    return False


def read_offsets(path, axes) -> tuple[dict, dict, dict]:
    """(tool lengths {H: mm}, cutter offsets {D: mm}, work offsets {"G54": {axis: value}, ...})
    from an offsets TOML file: ``[H]`` / ``[D]`` tables of number = mm, ``[G54]``..``[G59]`` and
    ``["G54.1 P<n>"]`` tables of axis letter = mm/deg."""
    from .._io import load_toml
    data = load_toml(path)
    tools, cutters, works = {}, {}, {}
    for key, vec in data.items():
        name = str(key).upper().strip()
        if name in ("H", "D"):
            if not isinstance(vec, dict):
                raise InputError(f"expected a table [{name}] of number = mm", path, field=str(key))
            for k, v in vec.items():
                try:
                    num = int(str(k).lstrip("HDhd"))
                except ValueError:
                    num = -1
                if num < 0 or not _finite_number(v):
                    raise InputError(f"expected an {name} number and a finite length in mm", path,
                                     field=f"{key}.{k}")
                (tools if name == "H" else cutters)[num] = float(v)
            continue
        name = re.sub(r"\s+", " ", name)
        if not isinstance(vec, dict) or not re.fullmatch(r"G5[4-9]|G54\.1 ?P\d+|G154 ?P\d+|"
                                                         r"G1[12]\d", name) or \
                re.fullmatch(r"G1[12]\d", name) and not 110 <= int(name[1:]) <= 129:
            raise InputError("expected tables [H], [D], [G54]..[G59], [\"G54.1 P<n>\"], "
                             "[\"G154 P<n>\"] or [G110]..[G129] (axis letters = mm/deg)", path,
                             field=str(key))
        if re.fullmatch(r"G1[12]\d", name):
            name = f"G154 P{int(name[1:]) - 109}"             # Haas: G110..G129 = G154 P1..P20
        for a, v in vec.items():
            if a.upper() not in axes or not _finite_number(v):
                raise InputError(f"expected an axis of the machine ({' '.join(axes)}) and a finite "
                                 "number", path, field=f"{key}.{a}")
        works[name] = {a.upper(): float(v) for a, v in vec.items()}
    return tools, cutters, works


def tool_lengths_from(spec: str | None) -> dict | None:
    """Tool lengths by H number (mm) from an option value: ``1=50.2,2=75``, a LinuxCNC tool
    table, or a CSV file of ``H,length_mm`` lines (a header line and ``#`` comments allowed)."""
    if spec is None:
        return None
    if os.path.exists(spec) and is_tool_table(spec):
        return read_tool_table(spec)
    items, where = [], "--tool-lengths"
    if os.path.exists(spec):
        from .._io import read_text
        for n, ln in enumerate(read_text(spec, what="tool length table").splitlines(), start=1):
            ln = ln.split("#")[0].strip()
            if not ln or (n == 1 and not ln[0].isdigit()):
                continue
            items.append((ln.replace(";", ","), (spec, n)))
    else:
        items = [(part, (None, None)) for part in spec.split(",") if part.strip()]
        items = [(it.replace("=", ","), w) for it, w in items]
    out = {}
    for text, (file, line) in items:
        h, _, v = text.partition(",")
        try:
            hn, val = int(h.strip().lstrip("Hh")), float(v)
        except ValueError:
            hn, val = -1, math.nan
        if hn < 0 or not math.isfinite(val):
            raise InputError(f"expected H number and tool length in mm (1=50.2 or a CSV line 1,50.2), "
                             f"got {text!r}", file, line, field=None if file else where)
        out[hn] = val
    return out


def add_tool_length_options(parser) -> None:
    """The tool-length and offset options of the CLI commands that read G43/G44/G43.4 programs
    (`mtcomp compensate`, `mtcomp verify`): --tool-lengths, --tool-table, --offsets; read them
    with :func:`tool_lengths_of_options`."""
    parser.add_argument("--tool-lengths", metavar="H=MM,..|CSV",
                        help="tool lengths for G43/G44/G43.4 H (and of the tool a T word loads): "
                             "1=50.2,2=75, a CSV file of lines H,length_mm or a LinuxCNC tool "
                             "table (default: taken as 0 and noted)")
    parser.add_argument("--tool-table", dest="tool_lengths", metavar="TBL",
                        help="a LinuxCNC tool table (T1 P1 Z+50.0 D6.0 lines): tool lengths by tool "
                             "number (same as --tool-lengths with the file)")
    parser.add_argument("--work-offsets", "--offsets", metavar="TOML",
                        help="offsets file: [G54]..[G59], [\"G54.1 P1\"] tables of axis = mm, [H] "
                             "tool lengths and [D] cutter offsets by number = mm (docs/gcode.md)")


def tool_lengths_of_options(args, axes) -> tuple[dict | None, dict | None]:
    """(tool lengths {number: mm}, work offsets) from the options of
    :func:`add_tool_length_options`: the offsets file's [H] table, overridden by --tool-lengths."""
    tools = tool_lengths_from(args.tool_lengths)
    if args.work_offsets is None:
        return tools, None
    file_tools, _, works = read_offsets(args.work_offsets, axes)
    if file_tools:
        merged = {**file_tools, **(tools or {})}          # --tool-lengths wins
        tools = ToolTable(merged, by_tool=tools.by_tool, h_of_tool=tools.h_of_tool,
                          note=tools.note, radius_of_tool=tools.radius_of_tool) if isinstance(tools, ToolTable) else merged
    return tools, works or None
