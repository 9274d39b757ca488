"""Reading a program into per-block arrays (modal state, absolute positions, arcs)."""
from __future__ import annotations

import re
from typing import Mapping

import numpy as np

from .._io import InputError
from . import _ctok
from .arcs import _arc_geometry
from .codes import ARC_WORDS, CANONICAL, INCH, LINEAR, siemens_hint
from .codes import (_CHAR_HINT, _G_ARC_DIST, _G_CYCLE, _G_DIST, _G_FEED, _G_HARMLESS, _G_MOTION, _G_NONMOVE,
                    _G_CUTTER, _G_PLANE, _G_REFUSED, _G_TOOL, _G_UNITS, _G_WCS, _M_REFUSED)
from .offsets import g10_events, offsets_per_line, tool_change_warnings
from .program import Program, resolution_formats
from .textops import parse_decimals
from .tokens import _ascii, _comment_spans, _fail, _tokenise, _word_error, _word_text


def _all_columns(a: np.ndarray) -> np.ndarray:
    """``a.all(axis=1)`` of a (rows, few columns) bool array, column by column (numpy's
    reduction along a short last axis is several times slower)."""
    out = a[:, 0].copy()
    for k in range(1, a.shape[1]):
        out &= a[:, k]
    return out


def _const(n: int, value, dtype) -> np.ndarray:
    """(n,) of one value as a read-only broadcast view (no memory): the per-line state of a
    code or letter the program never writes, so that its array costs no page faults."""
    return np.broadcast_to(np.array(value, dtype), (n,))


def _nan_to_zero(a: np.ndarray) -> np.ndarray:
    """``np.nan_to_num(a)`` (a new array): NaN -> 0 in one masked copy, numpy's own where a
    value is infinite (it replaces those by the largest floats; a check, not a pass per kind)."""
    out = a.copy()
    np.copyto(out, 0.0, where=np.isnan(out))
    if np.isinf(out).any():
        return np.nan_to_num(a)
    return out


def _take(a: np.ndarray, idx: np.ndarray, view: bool = False) -> np.ndarray:
    """``a[idx]`` (a fresh array) of a per-line array; of a `_const` view without the gather,
    and with ``view`` as a `_const` view itself."""
    if a.ndim == 1 and a.strides == (0,) and len(a) and len(idx):
        return _const(len(idx), a[0], a.dtype) if view else np.full(len(idx), a[0], a.dtype)
    return a[idx]


def _ffill(values: np.ndarray, isset: np.ndarray, default) -> np.ndarray:
    """Forward fill: the last set value at or before each index (``default`` before any).
    Nothing set: a `_const` view of the default (read-only)."""
    if values.dtype in (np.int64, np.float64, np.bool_) and not isset.any():
        return _const(len(values), default, values.dtype)
    out = _ctok.ffill(values, isset, default)            # compiled, where built: one pass
    if out is not None:
        return out
    idx = np.where(isset, np.arange(len(values)), -1)
    np.maximum.accumulate(idx, out=idx)
    out = values[np.maximum(idx, 0)]
    return np.where(idx >= 0, out, default)


def parse(text: str | bytes, *, axes=("X", "Y", "Z", "A", "B", "C"), filename: str = "<string>",
          convert_inch: bool = False, start=None, arc_tol: float | None = None,
          resolution=None, tool_lengths=None, work_offsets=None, tcp: bool = False,
          rotation: bool = False) -> Program:
    """Read a Fanuc-style NC program (text, or its bytes: UTF-8, undecodable bytes kept) for a
    machine with the given axis letters.

    ``start``: position of the axes before the first block, where the user knows it (mapping
    letter -> value, or a sequence over ``axes`` with NaN for unknown).  An axis the program
    writes but ``start`` does not give is *unknown* until its first word: ``axis_known`` is
    False there, blocks before that are not ``known`` and `rewrite` writes nothing for them
    (``position`` holds 0 there only so that simulations have a number; do not compensate it).  An axis the
    program never writes stays where it is; it is taken at 0 (the program origin, as a 3-axis
    program assumes of the rotary axes of a 5-axis machine) and listed in ``idle_axes``.  ``arc_tol`` (mm): largest
    accepted difference between an arc's radius at its start and at its end (default 0.02 mm,
    0.002 in in inch programs, in the style of LinuxCNC; an end point within it is read as a
    spiral, as controls run it).  ``resolution`` (as for `rewrite`): the axis resolutions; an
    arc whose end equals its start at the resolution is a full circle, and a radius below the
    resolution is refused.
    ``tcp``: read G43.4 tool centre point blocks (their X Y Z are the tool tip: ``Program.tcp``
    marks them, `mtcomp.gcode.tcp` turns them into axis positions); ``rotation``: read G68
    (``position`` is then in the unrotated word frame, `mtcomp.gcode.rotation`).  Both are
    refused by default, so that a caller taking ``position`` as axis positions cannot misread
    them; `rewrite` and `mtcomp compensate` handle both.
    Raises ``InputError`` naming ``filename:line`` for anything it cannot read or would not
    transform correctly (docs/gcode.md lists the cases).
    """
    axes = tuple(str(a).upper() for a in axes)
    notes: list[str] = []
    for a in axes:
        if len(a) != 1 or a not in CANONICAL:
            raise ValueError(f"axis names must be single letters out of {CANONICAL}, got {a!r}")
    n_ax = len(axes)
    # a str is worked on as its UTF-8 bytes (undecodable bytes it carries kept); bytes as they are
    data = bytes(text) if isinstance(text, (bytearray, memoryview)) else (
        text if isinstance(text, bytes) else text.encode("utf-8", "surrogateescape"))
    b = np.frombuffer(data, np.uint8)
    nbytes = len(b)
    line_start = _ctok.line_starts(b)
    if line_start is None:
        nl = np.flatnonzero(b == 10)
        line_start = np.concatenate(([0], nl + 1)).astype(np.int64)
        del nl
    line_end = np.empty_like(line_start)
    line_end[:-1] = line_start[1:] - 1
    line_end[-1] = nbytes
    n_lines = len(line_start)

    def line_of(pos):
        return np.searchsorted(line_start, pos, side="right") - 1

    # -- comments, % lines and block delete become blanks in a working copy; so does a UTF-8
    # byte-order mark (Windows editors write one)
    bom = 3 if data.startswith(b"\xef\xbb\xbf") else 0
    code = _ctok.copy_blank_comments(b, bom)       # compiled: the copy and the blanking, one pass
    spans = []
    if code is None:
        code = b.copy()
        spans = _comment_spans(data, b, first=bom)
    code[:bom] = 32
    if spans:
        if len(spans) < 1 << 18:                  # slice assignments: cheap per comment
            for s, e in spans:
                code[s:e] = 32
        else:
            sp = np.asarray(spans, np.int64)
            mark = np.zeros(nbytes + 1, np.int8)
            np.add.at(mark, sp[:, 0], 1)
            np.add.at(mark, sp[:, 1], -1)
            code[np.cumsum(mark[:-1], dtype=np.int8).view(bool)] = 32
    bd_lines = np.zeros(0, np.int64)
    slash = np.flatnonzero(code == 47) if b"/" in data else ()
    if len(slash):
        # block delete: '/' as the first non-blank character of a line
        ls = line_start[line_of(slash)]
        bd = [int(q) for q, l0 in zip(slash, ls) if not bytes(code[l0:q]).strip(b" \t")]
        if bd:
            bd = np.asarray(bd, np.int64)
            code[bd] = 32
            bd_lines = line_of(bd)

    # -- character classes and words: a letter immediately followed by a run of number
    # characters (in chunks that fit the cache; chunks end at line breaks so no word is split)
    tok = _ctok.tokenise(code)               # compiled one-pass tokenizer, where built
    if tok is None:
        tok = _tokenise(code, line_start) + (None, None, None, None, None)
    lp, rs, re_, dot_of_run, twodots, wline, sign_at, bad_at, value, dup_line, checks, wlet, lcount = tok
    del tok
    if bad_at >= 0:
        ch = data[bad_at:bad_at + 1].decode("latin-1")
        hint = _CHAR_HINT.get(ch, "expected address letters, numbers, spaces and comments")
        ln = int(line_of(bad_at))
        siemens = siemens_hint(data[line_start[ln]:line_end[ln]].decode("latin-1"))
        if siemens and ch in "=(,)":
            _fail(siemens, ln, filename)
        _fail(f"unexpected character {ch!r}: {hint}", ln, filename)
    # (checks: the compiled tokenizer's answers to the two tests below, made on the way)
    if (not checks[0]) if checks is not None else (len(rs) != len(lp) or np.any(rs != lp + 1)):
        # blanks between a letter and its number ("X 10") are read, on the same line
        ok = len(rs) == len(lp) and bool(np.all(rs > lp)) and bool(np.all(rs[:-1] < lp[1:]))
        if ok:
            gap = np.flatnonzero(rs != lp + 1)
            ok = bool(np.all(line_of(rs[gap]) == wline[gap]))
        if not ok:
            _word_error(code, lp, rs, re_, line_of, filename)
    if wlet is None:                         # (the compiled tokenizer gives both)
        wlet = ((code[lp] | np.uint8(32)) - np.uint8(97)).astype(np.int8)
        lcount = np.bincount(wlet, minlength=26)

    # -- number syntax: sign only first, at most one point, at least one digit
    if sign_at >= 0:
        i = int(np.searchsorted(rs, sign_at, side="right") - 1)
        _fail(f"malformed number {_word_text(data, lp[i], re_[i])!r}: a sign may only "
              "lead the number", wline[i], filename)
    first_ch = code[rs] if value is None else None
    if checks is None:
        ndig = (re_ - rs) - (dot_of_run >= 0) - ((first_ch == 43) | (first_ch == 45))
        badnum = twodots | (ndig < 1)
        first_bad = int(np.argmax(badnum)) if badnum.any() else -1
        del ndig, badnum
    else:
        first_bad = int(checks[1])
    if first_bad >= 0:
        i = first_bad
        _fail(f"malformed number in word {_word_text(data, lp[i], re_[i])!r}: expected "
              "digits with at most one decimal point", wline[i], filename)
    if value is None:
        value = parse_decimals(code, rs, re_, dot_of_run, first=first_ch)
    if not np.isfinite(value).all():
        i = int(np.argmax(~np.isfinite(value)))
        _fail(f"number in word {_word_text(data, lp[i], min(re_[i], lp[i] + 20))!r}... is too large",
              wline[i], filename)
    w_num = rs.astype(np.int32, copy=False)
    # positions fit 32 bits (programs under 2 GB); free what is no longer needed
    if nbytes >= 2**31 - 1:
        raise InputError("programs of 2 GB and more are not supported", file=filename)
    lp, re_ = lp.astype(np.int32, copy=False), re_.astype(np.int32, copy=False)
    del code, rs, dot_of_run, twodots, first_ch

    G, M = _ascii("G"), _ascii("M")
    # -- duplicate addresses in one block (G and M may repeat)
    # stable radix sort by letter keeps each letter's words in line order: a repeated letter in
    # a block shows as two neighbours with the same letter and line
    if dup_line is not None:
        # the compiled tokenizer found, per letter, the first line with it twice: the same
        # answer as the sort below (the smallest letter, its first such line)
        dup_line[[G, M]] = -1
        if (dup_line >= 0).any():
            j = int(np.argmax(dup_line >= 0))
            _fail(f"address {chr(65 + j)} appears twice in one block", int(dup_line[j]), filename)
    else:
        order = np.argsort(wlet, kind="stable")
        sl, sw = wlet[order], wline[order]
        dup = (sl[1:] == sl[:-1]) & (sw[1:] == sw[:-1]) & (sl[1:] != G) & (sl[1:] != M)
        if dup.any():
            j = int(np.argmax(dup)) + 1
            _fail(f"address {chr(65 + int(sl[j]))} appears twice in one block", int(sw[j]), filename)
        del order, sl, sw, dup

    _refuse_huge_whole_numbers(wlet, value, wline, data, lp, re_, filename)

    # -- G codes
    gi = np.flatnonzero(wlet == G)
    # (clipped: a G code of 300 digits is a finite float but no int64; any code that large is
    # refused below as unknown, by its text)
    g10 = np.rint(np.clip(value[gi], -1e9, 1e9) * 10).astype(np.int64)
    nonint = np.abs(value[gi] * 10 - g10) > 1e-6
    # 0 motion 1 dwell 2 plane 3 units 4 dist 5 wcs 6 harmless 7 arc centre mode 8 tool length
    # 9 axis words that are not moves 10 feed mode
    cat = np.full(len(gi), -1, np.int64)
    tables = [(_G_MOTION, 0), ({40: 4}, 1), (_G_PLANE, 2), (_G_UNITS, 3), (_G_DIST, 4), (_G_WCS, 5),
              (_G_ARC_DIST, 7), (_G_TOOL, 8), (_G_NONMOVE, 9), (_G_FEED, 10), (_G_CYCLE, 11),
              (_G_HARMLESS, 6), ({100: 10}, 12), ({680: 68}, 13), (_G_CUTTER, 14), ({160: 16}, 15)]
    for u in np.unique(g10):
        sel = g10 == u
        u = int(u)
        cat[sel] = next((c for table, c in tables if u in table), -1)
    badg = (cat < 0) | nonint
    if badg.any():
        j = int(np.argmax(badg))
        word = _word_text(data, lp[gi[j]], re_[gi[j]])
        reason = _G_REFUSED.get(int(g10[j])) if not nonint[j] else None
        what = (f"{word}: {reason}; refusing rather than guessing" if reason else
                f"unknown G code {word}: it may affect motion; refusing rather than guessing")
        _fail(what, wline[gi[j]], filename)
    gline = wline[gi]
    g7071 = gline[np.isin(g10, (700, 710))]
    if len(g7071):
        # Haas mills: G70 bolt hole circle, G71 bolt hole arc (I radius, J angle, K step, L
        # count, run with the active cycle), not inch/mm as elsewhere
        # Fanuc lathes: G71 stock removal (U R / P Q U W), G70 finishing (P Q)
        ijkl = np.isin(wlet, [_ascii(c) for c in "IJKLPQRUW"]) & np.isin(wline, g7071)
        if ijkl.any():
            L = int(wline[np.argmax(ijkl)])
            g = 70 if L in gline[g10 == 700] else 71
            if np.isin(wlet[ijkl & (wline == L)], [_ascii(c) for c in "IJKL"]).any():
                _fail(f"G{g} with I J K L words: a Haas bolt hole pattern (G70 circle, G71 arc), "
                      "not inch/mm; not supported (post the holes as X Y positions)", L, filename)
            _fail(f"G{g} with P Q U W R words: a Fanuc lathe {'finishing' if g == 70 else 'stock removal'} "
                  "cycle, not inch/mm; not supported (its passes are generated by the control)",
                  L, filename)
    if (g10 == 150).any():
        # G15 H<n> on Okuma controls selects work coordinate system n (elsewhere G15 cancels
        # polar coordinates): one is read as it is; switching between them is not read
        hi = np.flatnonzero(wlet == _ascii("H"))
        hi = hi[np.isin(wline[hi], gline[g10 == 150])]
        if len(np.unique(value[hi])) > 1:
            j = hi[np.flatnonzero(value[hi] != value[hi[0]])[0]]
            _fail("G15 H<n> (Okuma work coordinate system selection) switches between work "
                  "coordinate systems: not read (their offsets are the control's)", wline[j],
                  filename)
    cc_line = _contour_control_lines(g10, gline, wlet, wline, value, n_lines, filename)

    # -- letters
    # H tool length offset number, D cutter compensation number, Q peck/shift amounts: values
    # that move nothing by themselves (the codes that use them are followed or refused)
    allowed = set("GMNOFSTPIJKRHDQ") | set(axes)
    if "X" not in axes:
        allowed.add("X")                     # G4 X dwell time
    known = np.zeros(26, bool)
    known[[_ascii(c) for c in allowed]] = True
    # (the letters' counts: no pass over the words where every letter is known)
    badlet = ~known[wlet] if lcount[~known].any() else np.zeros(1, bool)
    if badlet.any():
        # E is the tolerance of Haas G187 (smoothness), nowhere else
        g187 = np.zeros(n_lines, bool)
        g187[gline[g10 == 1870]] = True
        badlet &= ~((wlet == _ascii("E")) & g187[wline])
    g10_line = np.zeros(n_lines, bool)
    g10_line[gline[cat == 12]] = True
    if badlet.any() and g10_line.any():
        badlet &= ~((wlet == _ascii("L")) & g10_line[wline])      # G10 L: the data kind
    if badlet.any() and (cat == 11).any():
        # L in a canned cycle block: the repeat count (LinuxCNC, Haas), read with the cycles
        cev = np.full(n_lines, -1, np.int64)
        cev[gline[np.isin(cat, (0,))]] = 0
        cev[gline[g10 == 800]] = 0
        cev[gline[cat == 11]] = 1
        in_cycle = _ffill(cev, cev >= 0, 0) == 1
        badlet &= ~((wlet == _ascii("L")) & in_cycle[wline])
    if badlet.any():
        i = int(np.argmax(badlet))
        c = chr(65 + wlet[i])
        if c in CANONICAL:
            what = f"axis word {c} but the machine has axes {' '.join(axes)}"
        elif (gline[g10 == 760] == wline[i]).any():
            what = (f"{_word_text(data, lp[i], re_[i])} in a G76 block: the LinuxCNC lathe "
                    "threading cycle (P pitch, I J K depths, R Q H E L) is not supported: its "
                    "passes are generated by the control (mtcomp reads G76 as Fanuc's fine "
                    "boring cycle, with X Y Z R words only)")
        elif c == "L":
            what = (f"{_word_text(data, lp[i], re_[i])}: a Siemens subprogram call L<n> (or a "
                    "repeat count L where none is read) is not followed")
        else:
            what = f"unknown address {_word_text(data, lp[i], re_[i])!r} (reads G M N O F S T P H D Q, " \
                   f"axes {' '.join(axes)}, arc words I J K R)"
        _fail(what, wline[i], filename)


    def per_line(catid, mapping, label, words=False):
        """Per line the category's code (-1: none) and, if ``words``, its word index."""
        sel = cat == catid
        lines_, vals = gline[sel], g10[sel]
        # the words are in text order: a line with two codes shows as equal neighbours, the
        # first such pair at the smallest such line
        twice = np.flatnonzero(lines_[1:] == lines_[:-1])
        if len(twice):
            _fail(f"two {label} G codes in one block", int(lines_[twice[0]]), filename)
        if not len(lines_):                   # a group the program never writes
            return _const(n_lines, -1, np.int64), _const(n_lines, -1, np.int64) if words else None
        out = np.full(n_lines, -1, np.int64)
        out[lines_] = _map_codes(vals, mapping)
        if not words:
            return out, None
        wout = np.full(n_lines, -1, np.int64)
        wout[lines_] = gi[sel]
        return out, wout

    mot_l, mot_w = per_line(0, _G_MOTION, "motion (G0 G1 G2 G3)", words=True)
    pla_l, _ = per_line(2, _G_PLANE, "plane (G17 G18 G19)")
    uni_l, uni_w = per_line(3, _G_UNITS, "unit (G20 G21)", words=True)
    dis_l, _ = per_line(4, _G_DIST, "distance mode (G90 G91)")
    wcs_l, _ = per_line(5, _G_WCS, "work coordinate system")
    acm_l, _ = per_line(7, _G_ARC_DIST, "arc centre mode (G90.1 G91.1)")
    tool_l, _ = per_line(8, _G_TOOL, "tool length (G43 G44 G49)")
    nonmove_l, _ = per_line(9, _G_NONMOVE, "non-modal positioning (G28 G30 G52 G53)")
    if (nonmove_l == 924).any():
        _carvera_shrink(np.flatnonzero(nonmove_l == 924), mot_l, wline, wlet, value, filename)
    feedm_l, _ = per_line(10, _G_FEED, "feed mode (G93 G94 G95)")
    cut_l, _ = per_line(14, _G_CUTTER, "cutter compensation (G40 G41 G42)")
    # G41/G42 per line, modal until G40: the block's end point is offset by the control
    cutter_line = _ffill(cut_l, cut_l >= 0, 40)
    dwell_line = np.zeros(n_lines, bool)
    dwell_line[gline[cat == 1]] = True
    g50_line = np.zeros(n_lines, bool)
    g50_line[gline[g10 == 500]] = True
    # per-line word values of P and H (NaN where absent)
    def letter_value(c):
        i = np.flatnonzero(wlet == _ascii(c)) if lcount[_ascii(c)] else ()
        if not len(i):
            return _const(n_lines, np.nan, np.float64)
        out = np.full(n_lines, np.nan)
        out[wline[i]] = value[i]
        return out
    p_line, h_line, t_line = letter_value("P"), letter_value("H"), letter_value("T")
    inch_line = _ffill(uni_l == 20, uni_l >= 0, False)
    incr_line = _ffill(dis_l == 91, dis_l >= 0, False)
    first_motion, events, written = 0, [], None
    if g10_line.any():
        # the first line with an axis word (outside G10): the reference work offset's block
        axis_let = np.zeros(26, bool)
        axis_let[[_ascii(a) for a in axes]] = True
        ax_lines = wline[axis_let[wlet]]
        ax_lines = ax_lines[~g10_line[ax_lines]]
        first_motion = int(ax_lines.min()) if len(ax_lines) else 0
        moved = np.zeros(26, bool)              # axes the program writes (outside G10 blocks)
        moved[wlet[~g10_line[wline]]] = True
        written = [bool(moved[_ascii(a)]) for a in axes]
        both = g10_line & ((mot_l >= 0) | (np.bincount(gline[np.isin(cat, (9, 11))],
                                                        minlength=n_lines) > 0))
        if both.any():
            _fail("G10 in a block with motion or positioning codes", int(np.argmax(both)), filename)
        gl = np.flatnonzero(g10_line)
        sel = np.flatnonzero(g10_line[wline] & (wlet != G))
        words = {int(ln): [] for ln in gl}
        for i in sel.tolist():
            words[int(wline[i])].append((chr(65 + int(wlet[i])), float(value[i])))
        # G10 L20 P<n>: G54.1 P<n> on Fanuc, G154 P<n> on Haas (the program's own work offset
        # codes tell which; Haas G110..G129 are G154 P1..P20)
        haas = bool(((wcs_l == 154) | ((wcs_l >= 110) & (wcs_l <= 129))).any())
        fanuc = bool((wcs_l == 541).any())
        if haas and fanuc and g10_line.any():
            _fail("G10 in a program with both G54.1 P (Fanuc) and G154 P (Haas) work offsets: "
                  "which of them G10 L20 sets depends on the control", int(np.argmax(g10_line)),
                  filename)
        events = g10_events(gl, words, axes, inch_line, incr_line,
                            541 if fanuc else 154 if haas else 0, filename)
        notes.append(f"G10 on line(s) {', '.join(str(int(x) + 1) for x in gl[:5])}"
                     + (" ..." if len(gl) > 5 else "") + ": offsets set as the control does")
    # tool changes: the M6 lines (T only preselects); a program without M6 changes at its T words
    m_words = np.flatnonzero(wlet == M) if lcount[M] else np.zeros(0, np.int64)   # (read again below)
    mi6 = m_words[np.rint(value[m_words]) == 6]
    change_line = None
    if len(mi6):
        change_line = np.zeros(n_lines, bool)
        change_line[wline[mi6]] = True
    dyn_len = None
    if (tool_l == 431).any():
        dyn_len = _g43_1_lengths(tool_l, mot_l, inch_line, incr_line, axes, wline, wlet, value,
                                 n_lines, filename)
        notes.append("G43.1 (LinuxCNC dynamic tool length) on line(s) "
                     f"{', '.join(str(int(x) + 1) for x in np.flatnonzero(tool_l == 431)[:5])}: "
                     "its Z word is the tool length (not a move), read as G43 with it")
    frame_line = int(np.argmax(wcs_l >= 0)) + 1 if (wcs_l >= 0).any() else 0
    offsets_line, tlen_line, offset_assumed, tip_line, gauge_line, frame = offsets_per_line(
        axes, wcs_l, p_line, tool_l, h_line, t_line, work_offsets, tool_lengths, events,
        first_motion, n_lines, filename, notes, written, change_line, dyn_len)
    # G43.4 tool centre point mode per line (modal until G43/G44/G49)
    if (tool_l == 434).any() and not tcp:
        _fail("G43.4: G43.4 tool centre point: X Y Z are the tool tip, not axis positions; "
              "refusing rather than guessing (mtcomp compensate compensates it in tool-tip "
              "coordinates: parse(..., tcp=True))", int(np.argmax(tool_l == 434)), filename)
    tcp_line = (_ffill(tool_l == 434, tool_l >= 0, False) if (tool_l == 434).any()
                else np.zeros(n_lines, bool))

    # -- M codes
    mi = m_words
    if len(mi):
        mref = np.isin(np.rint(np.clip(value[mi], -1e9, 1e9)).astype(np.int64), list(_M_REFUSED))
        if mref.any():
            j = mi[int(np.argmax(mref))]
            _fail(_M_REFUSED[int(round(value[j]))] + "; refusing rather than guessing", wline[j], filename)

    # -- modal state per line
    plane_line = _ffill(pla_l, pla_l >= 0, 17)
    mode_line = _ffill(mot_l, mot_l >= 0, -1)
    # canned cycles: set by G73..G89, cancelled by G80 or a G0-G3 code (the G0/G1 mode from
    # before the cycle then continues, as on Fanuc controls)
    cyc_l, _ = per_line(11, _G_CYCLE, "canned cycle")
    both = (cyc_l >= 0) & (mot_l >= 0)
    if both.any():
        _fail("a motion code and a canned cycle in one block", int(np.argmax(both)), filename)
    ev = rl = None
    if (cyc_l >= 0).any():
        ev = np.full(n_lines, -1, np.int64)
        ev[mot_l >= 0] = 0
        ev[gline[g10 == 800]] = 0
        ev[cyc_l >= 0] = cyc_l[cyc_l >= 0]
        cycle_line = _ffill(ev, ev >= 0, 0)
        mode_line = np.where(cycle_line > 0, cycle_line, mode_line)
    else:                                      # no cycle: the events would all be 0
        cycle_line = _const(n_lines, 0, np.int64)
    if ((g10 == 980) | (g10 == 990)).any():
        rl = np.full(n_lines, -1, np.int64)
        rl[gline[g10 == 980]] = 98
        rl[gline[g10 == 990]] = 99
        retract_line = _ffill(rl, rl >= 0, 98)
    else:
        retract_line = _const(n_lines, 98, np.int64)

    # -- feed (modal), converted in inch blocks
    fi = np.flatnonzero(wlet == _ascii("F"))
    fval = np.full(n_lines, np.nan)
    fval[wline[fi]] = value[fi] * np.where(inch_line[wline[fi]], INCH, 1.0)
    fset = np.zeros(n_lines, bool)
    fset[wline[fi]] = True
    feed_line = _ffill(fval, fset, np.nan)

    # -- axis and arc words -> block columns
    cols = list(axes) + list(ARC_WORDS)
    col_of_letter = np.full(26, -1, np.int8)
    for k, c in enumerate(cols):
        col_of_letter[_ascii(c)] = k
    wcol = col_of_letter[wlet]
    # X in a dwell block is the dwell time, not an axis
    if dwell_line.any():
        dwell_x = (wlet == _ascii("X")) & dwell_line[wline]
        wcol = np.where(dwell_x, np.int8(-1), wcol)
        del dwell_x
    # axis words of G28 G30 G52 G53 G50.1 are not moves; after G28 G30 G53 the axes they name
    # are somewhere the program does not say (machine coordinates, reference point)
    any_nm = bool((nonmove_l >= 0).any())
    nm_w = np.flatnonzero((wcol >= 0) & (wcol < n_ax) & (nonmove_l[wline] >= 0)) if any_nm else []
    g50_w = np.flatnonzero((wcol >= 0) & (wcol < n_ax) & g50_line[wline]) if g50_line.any() else []
    if len(g50_w):
        _fail("G50 with axis words sets the coordinate system (lathe controls) or scaling: "
              "not supported", wline[g50_w[0]], filename)
    reset_lines = np.zeros(0, np.int64)
    reset_cols = np.zeros(0, np.int64)
    shift_l = None
    g92_w = np.zeros(0, np.int64)
    if len(nm_w):
        code_w = nonmove_l[wline[nm_w]]
        rs_ = np.isin(code_w, (28, 30, 53, 924))
        reset_lines, reset_cols = wline[nm_w[rs_]].astype(np.int64), wcol[nm_w[rs_]].astype(np.int64)
        for c in sorted(set(code_w.tolist())):
            ln = wline[nm_w[code_w == c]]
            notes.append(f"G{ {501: '50.1', 924: '92.4'}.get(c, c)} on line(s) "
                         f"{', '.join(str(x + 1) for x in np.unique(ln)[:5])}"
                         + (" ..." if len(np.unique(ln)) > 5 else "")
                         + (": passed through uncompensated; the axes it names are unknown "
                            "until written again" if c in (28, 30, 53) else
                            ": Carvera A-axis shrink (A reduced to 0-360 deg, no move); A is "
                            "unknown until written again" if c == 924 else
                            ": its axis words are not moves" if c == 501 else
                            ": the coordinates of the current position set (later positions "
                            "shifted; unknown where the position is)" if c == 92 else
                            ": local shift applied to later positions"))
        g92_w = nm_w[code_w == 92]
        g52 = nm_w[code_w == 52]
        if len(g52):
            shift_l = np.full((n_lines, n_ax), np.nan)
            shift_l[wline[g52], wcol[g52]] = value[g52] * np.where(inch_line[wline[g52]] &
                                                                  np.isin(wcol[g52], [k for k, a in enumerate(axes) if a in LINEAR]), INCH, 1.0)
        wcol_all = wcol.copy()
        wcol = np.where((nonmove_l[wline] >= 0) & (wcol < n_ax), np.int8(-1), wcol)
    if tcp_line.any():
        # switching into or out of G43.4 changes what the linear words mean (tool tip / axis
        # positions): the linear axes are unknown until the program writes them again
        sw = np.flatnonzero(tcp_line != np.r_[False, tcp_line[:-1]])
        lin_cols = [k for k, a in enumerate(axes) if a in LINEAR]
        if not {"X", "Y", "Z"} <= set(axes):
            _fail("G43.4 tool centre point on a machine without X Y Z", int(sw[0]), filename)
        reset_lines = np.r_[reset_lines, np.repeat(sw, len(lin_cols))].astype(np.int64)
        reset_cols = np.r_[reset_cols, np.tile(lin_cols, len(sw))].astype(np.int64)
        o = np.lexsort((reset_cols, reset_lines))
        reset_lines, reset_cols = reset_lines[o], reset_cols[o]
        notes.append(f"G43.4 tool centre point on line(s) "
                     f"{', '.join(str(int(x) + 1) for x in sw[::2][:5])}"
                     + (" ..." if len(sw) > 10 else "")
                     + ": its X Y Z words are the tool tip, compensated in tool-tip coordinates")
    if shift_l is not None:
        offsets_line = np.array(offsets_line)          # (writable: no offsets is a zero view)
        for k in range(n_ax):
            col = shift_l[:, k]
            offsets_line[:, k] += _ffill(col, ~np.isnan(col), 0.0)
    g68_line = np.zeros(n_lines, bool)
    g68_line[gline[cat == 13]] = True
    if g68_line.any() and not rotation:
        _fail("G68: G68 coordinate rotation changes the commanded positions in the control; "
              "refusing rather than guessing (mtcomp compensate follows it: parse(..., "
              "rotation=True))", int(np.argmax(g68_line)), filename)
    rot_events = []
    if g68_line.any():
        rot_events = _rotation_events(axes, g68_line, gline[g10 == 690], plane_line, inch_line,
                                      incr_line, mot_l, wline, wlet, value, filename)
        for L, (u, v), *_ in rot_events:
            reset_lines = np.r_[reset_lines, [L, L]].astype(np.int64)
            reset_cols = np.r_[reset_cols, [axes.index(u), axes.index(v)]].astype(np.int64)
        o = np.lexsort((reset_cols, reset_lines))
        reset_lines, reset_cols = reset_lines[o], reset_cols[o]
        on_lines = [str(e[0] + 1) for e in rot_events if e[2] is not None][:5]
        notes.append(f"G68 coordinate rotation on line(s) {', '.join(on_lines)}: "
                     "positions rotated as the control does; the plane's axes are unknown after "
                     "G68/G69 until written")
        wcol = np.where(g68_line[wline], np.int8(-1), wcol)      # centre and angle, not moves
    if g10_line.any():
        wcol = np.where(g10_line[wline], np.int8(-1), wcol)      # G10 words are data
    if dyn_len is not None:
        wcol = np.where(~np.isnan(dyn_len)[wline], np.int8(-1), wcol)   # G43.1 Z: a length
    if (g10 == 160).any() and (len(nm_w) or g10_line.any()) and {"X", "Y"} <= set(axes):
        # under G16 the X Y words of G10/G28/G30/G52/G53/G92 would be polar too, or not,
        # depending on the control: not read
        ev16 = np.full(n_lines, -1, np.int64)
        ev16[gline[g10 == 150]] = 0
        ev16[gline[g10 == 160]] = 1
        on16 = _ffill(ev16, ev16 >= 0, 0) == 1
        xy = np.isin(wlet, (_ascii("X"), _ascii("Y")))
        bad = xy & on16[wline] & (g10_line[wline] | (nonmove_l[wline] >= 0))
        if bad.any():
            _fail("X Y words of G10/G28/G30/G52/G53/G92 under G16 polar coordinates: not read "
                  "(controls differ on whether they are polar); cancel G16 with G15 first",
                  wline[int(np.argmax(bad))], filename)
    # in a canned cycle Z is the hole depth and R the R level, not a move and not a radius
    cyc_zw = cyc_rw = _const(n_lines, -1, np.int64)
    repeat_line = None
    if (cycle_line > 0).any():
        cyc_zw = np.full(n_lines, -1, np.int64)
        cyc_rw = np.full(n_lines, -1, np.int64)
        in_cyc = cycle_line[wline] > 0
        if g10_line.any() or g68_line.any():
            in_cyc &= ~(g10_line | g68_line)[wline]
        if "Z" not in axes:
            _fail("canned cycle on a machine without Z", int(np.argmax(cycle_line > 0)), filename)
        zc = axes.index("Z")
        zi = np.flatnonzero(in_cyc & (wcol == zc))
        ri = np.flatnonzero(in_cyc & (wlet == _ascii("R")))
        # repeat counts: Fanuc K, LinuxCNC and Haas L (a K beside I or J is Haas's variable
        # peck, refused with the I J words below)
        ij_line = np.zeros(n_lines, bool)
        ij_line[wline[np.isin(wlet, (_ascii("I"), _ascii("J")))]] = True
        ki = np.flatnonzero(in_cyc & (((wlet == _ascii("K")) & ~ij_line[wline]) |
                                      (wlet == _ascii("L"))))
        if len(ki):
            repeat_line = _cycle_repeats(ki, wline, wlet, value, wcol, axes, n_lines,
                                         incr_line, filename)
            wcol = wcol.copy()
            wcol[ki] = -1
        cyc_zw[wline[zi]], cyc_rw[wline[ri]] = zi, ri
        wcol = np.where(in_cyc & ((wcol == zc) | (wlet == _ascii("R"))), np.int8(-1), wcol)
    if cc_line is not None:
        # G5.1 Q1 R<n>: R selects the control's machining condition (precision level), no radius
        wcol = np.where(cc_line[wline] & (wlet == _ascii("R")), np.int8(-1), wcol)
    wl = _ctok.word_lines(wcol, wline, n_ax, n_lines)    # compiled: one pass, no index arrays
    if wl is not None:
        has_motion, has_arcw, n_arc = wl
        arc_w = np.flatnonzero(wcol >= n_ax) if n_arc else ()
    else:
        axis_w = np.flatnonzero((wcol >= 0) & (wcol < n_ax))
        arc_w = np.flatnonzero(wcol >= n_ax)
        has_motion = np.zeros(n_lines, bool)
        has_motion[wline[axis_w]] = True
        has_arcw = np.zeros(n_lines, bool)
        has_arcw[wline[arc_w]] = True
        del axis_w
    if dwell_line.any() and (has_motion & dwell_line).any():
        axis_w = np.flatnonzero((wcol >= 0) & (wcol < n_ax))
        dw = dwell_line[wline[axis_w]]
        _fail("axis word in a G4 dwell block", wline[axis_w[np.argmax(dw)]], filename)
    if len(arc_w):
        notarc = ~np.isin(mode_line[wline[arc_w]], (2, 3))
        if notarc.any():
            j = arc_w[np.argmax(notarc)]
            if cycle_line[wline[j]] > 0:
                _fail(f"{chr(65 + wlet[j])} word in canned cycle G{cycle_line[wline[j]]} (Haas "
                      "variable peck I J K, boring shift I J): not supported", wline[j], filename)
            _fail(f"arc word {chr(65 + wlet[j])} outside G2/G3", wline[j], filename)
    block = has_motion | (has_arcw & np.isin(mode_line, (2, 3))) | (cyc_zw >= 0) | (cyc_rw >= 0)
    k0_lines = np.zeros(0, np.int64)
    if repeat_line is not None and (repeat_line == 0).any():
        # K0/L0: the cycle's R and Z stored for the next holes, no hole and no move here
        k0_lines = np.flatnonzero(repeat_line == 0)
        block[k0_lines] = False
        k0_cancel = np.zeros(n_lines, np.int64)          # G80 and G0-G3 lines, counted
        k0_cancel[gline[(g10 == 800) | (cat == 0)]] = 1
        k0_cancel = np.cumsum(k0_cancel)
    if len(bd_lines):
        bdl = bd_lines[block[bd_lines] | (np.bincount(gline, minlength=n_lines)[bd_lines] > 0)]
        if len(bdl):
            _fail("block delete '/' on a block with motion or G codes: the position after it "
                  "would depend on the operator's switch", bdl[0], filename)
    blines = np.flatnonzero(block)
    nblk = len(blines)
    blk_of_line = np.full(n_lines, -1, np.int64)
    blk_of_line[blines] = np.arange(nblk)

    motion = mode_line[blines]
    tcp = tcp_line[blines]
    if tcp.any():
        bad = tcp & ((motion == 2) | (motion == 3) | (_take(cycle_line, blines) > 0))
        if bad.any():
            j = int(np.argmax(bad))
            _fail(("canned cycle" if cycle_line[blines[j]] > 0 else f"arc G{motion[j]}")
                  + " under G43.4 tool centre point: not supported (CAM systems write linear "
                  "moves under TCP)", blines[j], filename)
    # (no tool lengths, the common case: read-only views of 0, no memory, as offset below)
    tool_length = _take(tlen_line, blines, view=True)
    tool_tip = _take(tip_line, blines, view=True)
    tool_unknown = gauge_line[blines]
    mb = mode_line[blines]
    feed_blk = (mb >= 1) & (mb <= 3) | (_take(cycle_line, blines) > 0)     # G1 G2 G3 or a cycle
    del mb
    notes.extend(tool_change_warnings(tool_l, h_line, t_line if change_line is None else change_line,
                                      blines[feed_blk]))
    motion_word = mot_w[blines]
    g20 = uni_w[(uni_l == 20)]
    del tlen_line, tip_line, gauge_line, t_line, feed_blk, mot_w, uni_w, uni_l   # (peak memory)
    if inch_line[blines].any() and not inch_line[blines].all():
        j = int(np.flatnonzero(inch_line[blines] != inch_line[blines][0])[0])
        _fail("the program switches between inch (G20) and mm (G21) data between motion "
              "blocks: not supported", blines[j], filename)
    ijk_absolute = _take(_ffill(acm_l == 90, acm_l >= 0, False), blines)
    cl = _take(cutter_line, blines)
    cutter = np.where(cl == 40, 0, np.where(cl > 100, cl // 10, cl)).astype(np.int8)
    # constant columns are read-only broadcast views (no memory: 8 MB each at 1 M blocks)
    cutter_radius = np.broadcast_to(np.float64(np.nan), (nblk,))
    if (cl > 100).any():
        # G41.1/G42.1 D<diameter>: the radius is the D word of the line that switched it on
        d_val = letter_value("D")
        dyn = np.isin(cut_l, (411, 421))
        if np.isnan(d_val[dyn]).any():
            _fail("G41.1/G42.1 without D (the tool diameter)", int(np.flatnonzero(dyn & np.isnan(d_val))[0]),
                  filename)
        dia = _ffill(np.where(dyn, d_val * np.where(inch_line, INCH, 1.0), np.nan), cut_l >= 0, np.nan)
        cutter_radius = 0.5 * dia[blines]
    if (cutter > 0).any():
        on = np.flatnonzero(np.isin(cut_l, (41, 42, 411, 421))) + 1
        notes.append(f"G41/G42 cutter radius compensation on line(s) "  # (also G41.1/G42.1)
                     f"{', '.join(str(int(x)) for x in on[:5])}{' ...' if len(on) > 5 else ''}: the "
                     "positions are the programmed contour; the control offsets the tool by the "
                     "D radius in the plane")
        d_val = letter_value("D")
        cutter_d = _ffill(d_val, ~np.isnan(d_val), np.nan)[blines]
    else:
        cutter_d = np.broadcast_to(np.float64(np.nan), (nblk,))
    inverse_time = _take(_ffill(feedm_l == 93, feedm_l >= 0, False), blines)
    plane = plane_line[blines]
    incremental = incr_line[blines]
    inch = inch_line[blines]
    feed = feed_line[blines]
    # the per-line state is in the block arrays now: free it before the positions (peak memory)
    del (mot_l, pla_l, dis_l, wcs_l, acm_l, tool_l, nonmove_l, feedm_l, dwell_line, g50_line,
         p_line, h_line, incr_line, plane_line, mode_line, cyc_l, ev, rl, fval, fset,
         feed_line, block, has_motion, has_arcw, gi, cat, cut_l, cutter_line)
    # the words into block columns (after the per-line state is freed: peak memory)
    # vax: the axis words' values per block (NaN: none), varc: I J K R (compiled: two arrays,
    # neither above the allocator's heap reuse size at 1 M blocks)
    sc = _ctok.scatter(wcol, wline, value, blk_of_line, nblk, n_ax + 4, n_ax)   # one pass
    if sc is not None:
        col_word, vax, varc = sc
    else:
        col_word = np.full((nblk, n_ax + 4), -1, np.int32)
        cw = np.flatnonzero(wcol >= 0)
        col_word[blk_of_line[wline[cw]], wcol[cw]] = cw
        del cw
        vals = value[np.maximum(col_word, 0)]
        vals[col_word < 0] = np.nan
        vax, varc = vals[:, :n_ax], vals[:, n_ax:]
        del vals
    del sc, wcol, blk_of_line
    if inch.any():
        lin_scale = np.where(inch, INCH, 1.0)
        for k, c in enumerate(cols):
            if c in LINEAR or c in ARC_WORDS:
                col = vax[:, k] if k < n_ax else varc[:, k - n_ax]
                col *= lin_scale                   # (a view: in place)
    present = col_word[:, :n_ax] >= 0
    cycle_repeat = np.ones(nblk, np.int32)
    if repeat_line is not None:
        cycle_repeat = repeat_line[blines].astype(np.int32)
        # G91: the hole steps by the increment at each repeat, the block ends at the last
        step = (cycle_repeat > 1) & incremental
        if step.any():
            vax[step] *= cycle_repeat[step, None]
    polar = polar_xy = None
    pres_pos = present
    if (g10 == 160).any():
        # G16 polar coordinates (modal until G15): X radius, Y angle in G17 (gcode.polar)
        from .polar import read_polar
        ev16 = np.full(n_lines, -1, np.int64)
        ev16[gline[g10 == 150]] = 0
        ev16[gline[g10 == 160]] = 1
        on16 = _ffill(ev16, ev16 >= 0, 0)[blines] == 1
        sec16 = np.cumsum(ev16 == 1)[blines]
        if on16.any() and (tcp[on16].any() or g68_line.any()):
            _fail("G16 polar coordinates together with G43.4 or G68: not supported",
                  int(blines[np.argmax(on16)]), filename)
        polar, polar_xy = read_polar(axes, blines, on16, sec16, col_word, value, inch,
                                     incremental, motion, plane, filename)
        if polar.any():
            # the positions see the point (NaN where a word is not known yet: unknown)
            ix, iy = axes.index("X"), axes.index("Y")
            sc = np.where(inch, INCH, 1.0)
            vax[polar, ix] = polar_xy[polar, 0] * sc[polar]
            vax[polar, iy] = polar_xy[polar, 1] * sc[polar]
            pres_pos = present.copy()
            pres_pos[polar, ix] = pres_pos[polar, iy] = True
            notes.append(f"G16 polar coordinates on line(s) "
                         f"{', '.join(str(int(x)) for x in blines[polar][:5] + 1)}"
                         + (" ..." if polar.sum() > 5 else "")
                         + ": X radius and Y angle from the work origin, compensated as polar words")

    # -- absolute modal positions: last absolute value plus the increments since
    fm = resolution_formats(resolution, axes)
    res_ax = np.array([fm[a][1] * 10.0 ** -fm[a][0] for a in axes])
    if arc_tol is None:
        arc_tol = 0.002 * INCH if inch.any() else 0.02
    if not (arc_tol >= 0 and np.isfinite(arc_tol)):
        raise ValueError(f"arc_tol must be a finite number >= 0, got {arc_tol}")
    start_vec = _start_vector(start, axes)
    written = present.any(axis=0)
    written |= np.isin(np.arange(n_ax), reset_cols)
    idle = np.isnan(start_vec) & ~written
    start_vec[idle] = 0.0
    idle_axes = tuple(a for a, i in zip(axes, idle) if i)
    # no offsets (the common case): a read-only view of zeros, no (N, n_axes) array
    zero_offset = np.broadcast_to(np.zeros(n_ax), (nblk, n_ax))
    offset = (offsets_line[blines] if offsets_line.strides[0] and offsets_line.any()
              else zero_offset)
    position = _positions(blines, reset_lines, reset_cols, vax, pres_pos, incremental,
                          offset, start_vec)
    cancel92 = gline[np.isin(g10, (921, 922))]
    if len(g92_w):
        # G92 in program order: the current position (reference frame) gets the words'
        # coordinates, which shifts every later absolute word; G92.1/.2 cancel
        lin_ = np.array([a in LINEAR for a in axes])
        events = sorted(set(wline[g92_w].tolist()) | set(cancel92.tolist()))
        g92 = np.zeros(n_ax)
        offsets_line = np.array(offsets_line)          # (writable: no offsets is a zero view)
        base_off = offsets_line.copy()
        for L in events:
            delta = np.zeros(n_ax)
            if L in set(cancel92.tolist()):
                offsets_line[L:] = base_off[L:]
                g92 = np.zeros(n_ax)
            else:
                j = int(np.searchsorted(blines, L)) - 1
                cur = position[j] if j >= 0 else start_vec
                sel = g92_w[wline[g92_w] == L]
                for w in sel:
                    k = int(wcol_all[w])
                    v = value[w] * (INCH if inch_line[L] and lin_[k] else 1.0)
                    new92 = cur[k] - (offsets_line[L, k] - g92[k]) - v
                    delta[k] = new92 - g92[k]
                    g92[k] = new92
            offsets_line[L:] += delta
            offset = offsets_line[blines]
            position = _positions(blines, reset_lines, reset_cols, vax, pres_pos,
                                  incremental, offset, start_vec)

    del offsets_line
    if rot_events:
        reset_lines, reset_cols, position = _rotation_known(
            axes, rot_events, blines, position, offset, res_ax, reset_lines, reset_cols,
            lambda rl, rc: _positions(blines, rl, rc, vax, pres_pos, incremental,
                                      offset, start_vec))
    rotation = None
    if rot_events:
        rotation = _rotation_per_block(axes, rot_events, blines, position, offset, plane, tcp,
                                       cycle_line[blines], filename)
    cycle = _take(cycle_line, blines)
    cyc_data = None
    if (cycle > 0).any():
        g80n = np.cumsum(np.isin(np.arange(n_lines), gline[g10 == 800]))[blines]
        cut = np.r_[True, np.diff(g80n) > 0]          # a G80 between two blocks ends a run
        seeds = None
        if len(k0_lines):
            # a K0 line's words count for the next block if no G80 or G0-G3 comes between
            cancel = k0_cancel
            seeds = np.full((nblk, 2), np.nan)
            nxt = np.searchsorted(blines, k0_lines)
            for L, j in zip(k0_lines.tolist(), nxt.tolist()):
                if j < nblk and cancel[blines[j]] == cancel[L] and cycle[j] > 0:
                    sc = INCH if inch_line[L] else 1.0
                    for col_, w in ((0, cyc_rw[L]), (1, cyc_zw[L])):
                        if w >= 0:
                            seeds[j, col_] = value[w] * sc
        position, cyc_data = _cycles(axes, blines, cycle, cut, retract_line[blines], cyc_zw[blines],
                                     cyc_rw[blines], value, inch, incremental, vax,
                                     present, offset, start_vec, position, filename, seeds)
    del cycle_line, retract_line, cyc_zw, cyc_rw
    ijk = _nan_to_zero(varc[:, :3])
    ijk_present = col_word[:, n_ax:n_ax + 3] >= 0
    radius = varc[:, 3].copy()
    del vax, varc
    arc_centre = np.full((nblk, 3), np.nan)
    arc_sweep = np.full(nblk, np.nan)
    is_arc = (motion == 2) | (motion == 3)
    if is_arc.any():
        _arc_geometry(axes, position, start_vec, motion, plane, ijk, ijk_present, radius, is_arc,
                      blines, arc_tol, filename, arc_centre, arc_sweep, res_ax,
                      ijk_absolute=ijk_absolute, offset=offset)

    axis_known = np.isfinite(position)
    start_known = np.isfinite(start_vec)
    position[~axis_known] = 0.0
    start_vec = np.where(start_known, start_vec, 0.0)
    finch = fi[inch_line[wline[fi]]]
    arrays = dict(line_start=line_start, line_end=line_end, w_letter=wlet, w_value=value,
                  w_line=wline, w_pos=lp, w_num=w_num, w_end=re_, line=blines + 1, position=position,
                  start=start_vec, motion=motion.astype(np.int8), plane=plane.astype(np.int8),
                  incremental=incremental, inch=inch, feed=feed, present=present, ijk=ijk,
                  ijk_present=ijk_present, radius=radius, arc_centre=arc_centre,
                  arc_sweep=arc_sweep, col_word=col_word, motion_word=motion_word,
                  inch_g20_words=g20, inch_f_words=finch,
                  axis_known=axis_known, start_known=start_known, offset=offset if offset is zero_offset else np.nan_to_num(offset),
                  ijk_absolute=ijk_absolute, inverse_time=inverse_time, cycle=cycle.astype(np.int8),
                  cycle_repeat=cycle_repeat,
                  cycle_data=cyc_data if cyc_data is not None else np.zeros((nblk, 0)),
                  known=_all_columns(axis_known) if n_ax else np.ones(nblk, bool),
                  tcp=tcp, tool_length=tool_length, rotation=rotation, tool_tip=tool_tip,
                  tool_unknown=tool_unknown, cutter=cutter, cutter_d=cutter_d,
                  cutter_radius=cutter_radius, polar=polar, polar_xy=polar_xy)
    for a in arrays.values():
        if a is not None:
            a.flags.writeable = False
    prog = Program(filename=filename, axes=axes, data=data, idle_axes=idle_axes,
                   offset_assumed=offset_assumed, frame=frame, frame_line=frame_line,
                   arc_tol=float(arc_tol), notes=tuple(notes), **arrays)
    if isinstance(text, str):
        prog.__dict__["text"] = text            # (Program.text: the str given, not decoded again)
    return prog


#: addresses of whole numbers (tool, length and radius offsets, program and sequence numbers,
#: M codes, repeat counts): A=0 ... Z=25
_WHOLE_ADDRESSES = np.array([ord(c) - 65 for c in "DHLMNOT"])


def _contour_control_lines(g10, gline, wlet, wline, value, n_lines, filename):
    """Check the Fanuc look-ahead / contour control codes read as settings (docs/gcode.md,
    "Control settings codes"): G5.1 only as Q1/Q0 (AI contour control, R the machining
    condition level), G5 only as P10000/P0 (AI high-precision contour control), alone in its
    block.  The other forms move the tool along a path the control computes: refused.
    Returns (n_lines,) bool, the G5.1 lines (their R words are not arc radii), or None."""
    g51, g5 = gline[g10 == 51], gline[g10 == 50]
    if not len(g51) and not len(g5):
        return None
    q_at, p_at = np.full(n_lines, np.nan), np.full(n_lines, np.nan)
    qi, pi = np.flatnonzero(wlet == _ascii("Q")), np.flatnonzero(wlet == _ascii("P"))
    q_at[wline[qi]], p_at[wline[pi]] = value[qi], value[pi]
    for L in np.unique(g51).tolist():
        if q_at[L] not in (0.0, 1.0):
            _fail("G5.1 without Q1/Q0 (Fanuc smooth interpolation Q2, nano smoothing Q3): the "
                  "control replaces the programmed path by a curve it computes; refusing "
                  "rather than guessing (G5.1 Q1, AI contour control, is read)", L, filename)
    if len(g5):
        # any letter beside G N P (axis words, I J, R, L) makes G5 a motion: LinuxCNC's cubic
        # spline, Haas fine spindle control, Fanuc high-speed cycle machining
        other = ~np.isin(wlet, [_ascii(c) for c in "GNP"]) & np.isin(wline, g5)
        for L in np.unique(g5).tolist():
            if p_at[L] not in (0.0, 10000.0) or (other & (wline == L)).any():
                _fail("G5 other than a block of its own G05 P10000 / G05 P0 (Fanuc AI "
                      "high-precision contour control on/off, which is read): a cubic spline "
                      "(LinuxCNC), fine spindle control (Haas) or high-speed cycle machining "
                      "(Fanuc G05 P1..): the control computes the motion; refusing rather than "
                      "guessing", L, filename)
    out = np.zeros(n_lines, bool)
    out[g51] = True
    return out


def _refuse_huge_whole_numbers(wlet, value, wline, data, lp, re_, filename):
    """A whole-number address beyond 2**31 is no register of any control (and overflowed the
    integer conversions further on with a RuntimeWarning): refused naming the word."""
    big = np.flatnonzero(np.abs(value) >= 2.0 ** 31)
    if not len(big):
        return
    big = big[np.isin(wlet[big], _WHOLE_ADDRESSES)]
    if len(big):
        i = int(big[0])
        _fail(f"number in word {_word_text(data, lp[i], min(re_[i], lp[i] + 20))!r}... is too "
              "large for an address of whole numbers (at most 2**31 - 1)", wline[i], filename)


def _carvera_shrink(lines, mot_l, wline, wlet, value, filename):
    """Check that the G92.4 blocks are Carvera's A-axis shrink ``G92.4 A0 S0``, the one form
    whose meaning is documented (the controller's Shrink button: the A value reduced to 0-360
    deg keeping the work offset, no move).  Smoothieware's G92.4 with X Y Z sets the machine
    position (a frame change by an amount the program does not carry) and Carvera's
    ``G92.4 A.. R0`` is a rapid A move: both refused naming the line."""
    for L in lines.tolist():
        i = np.flatnonzero(wline == L)
        words = {chr(65 + int(wlet[j])): float(value[j]) for j in i if chr(65 + int(wlet[j])) != "G"}
        words.pop("N", None)
        if mot_l[L] >= 0 or set(words) != {"A", "S"} or words["A"] != 0 or words["S"] != 0:
            _fail("G92.4 (Smoothieware/Carvera): only the Carvera A-axis shrink 'G92.4 A0 S0' is "
                  "read (A reduced to 0-360 deg, no move); other forms set the machine position "
                  "or move the A axis by rules the program does not carry; refusing rather than "
                  "guessing", L, filename)


def _rotation_events(axes, g68_line, g69_lines, plane_line, inch_line, incr_line, mot_l, wline,
                     wlet, value, filename):
    """G68 / G69 in program order: (line, plane axes (u, v), angle deg or None for G69, centre
    (u, v) in program coordinates with NaN for "the current position")."""
    from .rotation import PLANE_AXES
    sel = np.flatnonzero(g68_line[wline])
    words: dict = {}
    for i in sel.tolist():
        c = chr(65 + int(wlet[i]))
        if c != "G":
            words.setdefault(int(wline[i]), {})[c] = float(value[i])
    events, angle = [], 0.0
    for L in sorted(set(np.flatnonzero(g68_line).tolist()) | set(np.asarray(g69_lines).tolist())):
        pl = int(plane_line[L])
        u, v = PLANE_AXES[pl]
        if not g68_line[L]:
            if angle:
                events.append((L, (u, v), None, None))
            angle = 0.0
            continue
        w = words.get(L, {})
        if mot_l[L] >= 0:
            _fail("G68 in a block with a motion code", L, filename)
        if u not in axes or v not in axes:
            _fail(f"G68 in the plane G{pl}: the machine has no axis {u if u not in axes else v}", L, filename)
        other = sorted(set(w) - {u, v, "R", "N"})
        if set(other) & set("IJK"):
            _fail("G68 with I J K (three-dimensional coordinate rotation): not supported", L, filename)
        if other:
            _fail(f"G68 with {' '.join(other)}: expected the centre {u} {v} and the angle R", L, filename)
        if "R" not in w:
            _fail("G68 without R: the angle would be a control parameter; not read", L, filename)
        sc = INCH if inch_line[L] else 1.0
        angle = (angle if incr_line[L] else 0.0) + w["R"]
        centre = (w.get(u, np.nan) * sc, w.get(v, np.nan) * sc)
        if incr_line[L] and (u in w or v in w):
            _fail("G68 in G91 with a centre: incremental centres are not read", L, filename)
        events.append((L, (u, v), angle, centre))
    return events


def _rotation_known(axes, events, blines, position, offset, res_ax, reset_lines, reset_cols,
                    positions):
    """Keep the plane's axes known across a G68/G69 where the tool's place does not depend on
    how the control reads the words there: if the current point maps to the same axis positions
    under the rotation before and after the event (G68 about the current point, G69 with the
    tool at the centre, an angle change of 360 deg), the modal words and the re-expressed
    position agree, so the axes stay known (their resets are dropped).  Returns the reset
    arrays and the positions recomputed."""
    active = None                                  # (angle deg, centre u, v program coords)
    for L, (u, v), angle, centre in events:
        iu, iv = axes.index(u), axes.index(v)
        j = int(np.searchsorted(blines, L)) - 1     # the last block before the event
        w = position[j, [iu, iv]] if j >= 0 else np.array([np.nan, np.nan])
        off = offset[j, [iu, iv]] if j >= 0 else np.zeros(2)
        new_c = None
        if angle is not None:
            new_c = np.where(np.isnan(centre), w - off, np.asarray(centre, float))
        if np.isfinite(w).all():
            def ref(a, c):
                c = np.asarray(c, float) + off
                t = np.radians(a)
                d = w - c
                return c + np.array([np.cos(t) * d[0] - np.sin(t) * d[1],
                                     np.sin(t) * d[0] + np.cos(t) * d[1]])
            before = ref(*active) if active is not None else w
            after = ref(angle, new_c) if angle is not None else w
            if np.abs(before - after).max() <= 0.5 * min(res_ax[iu], res_ax[iv]):
                keep = ~((reset_lines == L) & np.isin(reset_cols, (iu, iv)))
                reset_lines, reset_cols = reset_lines[keep], reset_cols[keep]
                position = positions(reset_lines, reset_cols)
        active = None if angle is None else (angle, new_c)
    return reset_lines, reset_cols, position


def _rotation_per_block(axes, events, blines, position, offset, plane, tcp, cycle, filename):
    """(N, 5) per block: G68 angle (deg, 0 where none), centre (program coordinates), the G68
    line (1-based) and the block whose end is the centre (G68 without centre words; -1)."""
    from .rotation import PLANE_AXES
    n = len(blines)
    rot = np.zeros((n, 5))
    rot[:, 4] = -1
    for k, (L, (u, v), angle, centre) in enumerate(events):
        b0 = int(np.searchsorted(blines, L, side="right"))
        b1 = int(np.searchsorted(blines, events[k + 1][0], side="right")) if k + 1 < len(events) else n
        if angle is None or b0 >= b1:
            continue
        iu, iv = axes.index(u), axes.index(v)
        c = np.array(centre, float)
        implicit = -1
        if np.isnan(c).any():
            implicit = b0 - 1
            # no centre word: the current position (program coordinates) is the centre
            j = b0 - 1
            cur = (position[j, [iu, iv]] - offset[j, [iu, iv]]) if j >= 0 else np.array([np.nan, np.nan])
            c = np.where(np.isnan(c), cur, c)
            if np.isnan(c).any():
                _fail("G68 without a centre where the current position is not known", L, filename)
        seg = slice(b0, b1)
        pl = PLANE_AXES[int(plane[b0])] if b1 > b0 else (u, v)
        bad = np.flatnonzero((plane[seg] != plane[b0]) | ((u, v) != pl))
        if len(bad):
            _fail("plane change under G68 coordinate rotation: not supported", blines[b0 + bad[0]],
                  filename)
        bad = np.flatnonzero(tcp[seg] | ((cycle[seg] > 0) & (plane[seg] != 17)))
        if len(bad):
            _fail("G43.4 tool centre point or a canned cycle outside G17 under G68: not supported",
                  blines[b0 + bad[0]], filename)
        rot[seg] = (angle, c[0], c[1], L + 1, implicit)
    return rot


def _positions(blines, reset_lines, reset_cols, vals, present, incremental, offset, start_vec):
    """Absolute positions of the blocks; the rows of G28/G30/G53 lines join them as absolute
    "words" NaN for the axes they name (unknown until written again)."""
    n_ax = present.shape[1]
    if not len(reset_lines):
        return _absolute(vals, present, incremental, offset, start_vec)
    ev = np.union1d(blines, reset_lines)
    rows_b = np.flatnonzero(np.isin(ev, blines))
    vals_e = np.full((len(ev), n_ax), np.nan)
    pres_e = np.zeros((len(ev), n_ax), bool)
    incr_e = np.zeros(len(ev), bool)
    off_e = np.zeros((len(ev), n_ax))
    vals_e[rows_b], pres_e[rows_b] = vals, present
    incr_e[rows_b], off_e[rows_b] = incremental, offset
    pres_e[np.searchsorted(ev, reset_lines), reset_cols] = True
    return _absolute(vals_e, pres_e, incr_e, off_e, start_vec)[rows_b]


def _absolute(vals, present, incremental, offset, start_vec):
    """Absolute positions (rows, n_axes): an absolute word is its value plus the row's offset
    (work offset, local shift, tool length); an increment adds to the position before; an axis
    not written stays.  An absolute NaN makes the axis unknown until its next absolute word."""
    n, n_ax = present.shape
    # (a broadcast view of one row, the usual zero offset: that row only)
    use_off = bool((offset[:1] if offset.ndim == 2 and offset.strides[0] == 0 else offset).any())
    position = _ctok.absolute(vals, present, incremental, offset, use_off, start_vec)
    if position is not None:                  # compiled, where built: one pass per axis
        return position
    position = np.empty((n, n_ax))
    rows = np.arange(n)
    for k in range(n_ax):
        pres = present[:, k]
        v = vals[:, k]
        inc = np.where(pres & incremental, v, 0.0)
        cum = np.cumsum(inc)
        idx = np.where(pres & ~incremental, rows, -1)
        np.maximum.accumulate(idx, out=idx)
        i0 = np.maximum(idx, 0)
        a = v[i0] - cum[i0]
        if use_off:
            a += offset[i0, k]
        position[:, k] = np.where(idx >= 0, a, start_vec[k]) + cum
    return position


def _cycles(axes, blines, cycle, cut, retract, zw, rw, value, inch, incremental, vals, present, offset,
            start_vec, position, filename, seeds=None):
    """Canned cycle blocks: per block the initial level, R level and depth (reference frame,
    mm; NaN where unknown) and the block's end Z (initial level for G98, R level for G99).
    Runs of holes are taken in order, since each run's initial level is where the last left Z.
    Returns (positions with the cycles' end Z, (N, 7) array: initial, R, depth, R word, Z word,
    retract, first block of the run)."""
    zk = axes.index("Z")
    n = len(blines)
    data = np.full((n, 7), np.nan)
    cb = np.flatnonzero(cycle > 0)
    starts = cb[(cb == 0) | (cycle[np.maximum(cb - 1, 0)] == 0) | cut[cb]]
    scale = np.where(inch, 25.4, 1.0)
    zvals = np.where(present[:, zk], vals[:, zk], np.nan)
    zpres = present[:, zk].copy()
    zinc = incremental.copy()
    for s in starts:
        e = s
        while e + 1 < n and cycle[e + 1] > 0 and not cut[e + 1]:
            e += 1
        zinit = position[s - 1, zk] if s > 0 else start_vec[zk]
        r_word = z_word = np.nan
        for j in range(s, e + 1):
            if seeds is not None:                  # R Z stored by K0/L0 lines before it (mm)
                r_word = seeds[j, 0] if np.isfinite(seeds[j, 0]) else r_word
                z_word = seeds[j, 1] if np.isfinite(seeds[j, 1]) else z_word
            if rw[j] >= 0:
                r_word = value[rw[j]] * scale[j]
            if zw[j] >= 0:
                z_word = value[zw[j]] * scale[j]
            if np.isnan(r_word) or np.isnan(z_word):
                _fail(f"canned cycle G{cycle[j]} without {'an R level' if np.isnan(r_word) else 'a depth Z'}",
                      blines[j], filename)
            if incremental[j]:                     # R from the initial level, Z from R
                r_lvl = zinit + r_word
                depth = r_lvl + z_word
            else:
                r_lvl = r_word + offset[j, zk]
                depth = z_word + offset[j, zk]
            end = zinit if retract[j] == 98 else r_lvl
            data[j] = (zinit, r_lvl, depth, r_word, z_word, retract[j], s)
            # the block's Z: an absolute "word" at its end level (NaN stays unknown)
            zvals[j] = end - offset[j, zk]
            zpres[j] = True
            zinc[j] = False
        col = _absolute(zvals[:, None], zpres[:, None], zinc, offset[:, zk:zk + 1],
                        start_vec[zk:zk + 1])[:, 0]
        position[:, zk] = col
    return position, data


def _g43_1_lengths(tool_l, mot_l, inch_line, incr_line, axes, wline, wlet, value, n_lines,
                   filename):
    """Per line the tool length (mm) set by LinuxCNC's ``G43.1 Z<len>``, NaN elsewhere.  Only
    Z is read (X and other axes are lathe or special offsets), in G90 (LinuxCNC takes the
    value as it is; whether every control does so in G91 is not established, so it is
    refused), not in a block with a motion code (its axis words would be claimed twice)."""
    out = np.full(n_lines, np.nan)
    for L in np.flatnonzero(tool_l == 431).tolist():
        i = np.flatnonzero(wline == L)
        ax = {chr(65 + int(wlet[j])): float(value[j]) for j in i
              if chr(65 + int(wlet[j])) in axes or chr(65 + int(wlet[j])) in "XYZUVWABC"}
        if mot_l[L] >= 0:
            _fail("G43.1 in a block with a motion code: its axis words are the tool offsets, "
                  "not a move; write G43.1 in a block of its own", L, filename)
        if set(ax) != {"Z"}:
            _fail("G43.1 without Z, or with other axis words "
                  f"({' '.join(sorted(set(ax) - {'Z'})) or 'none'}): only the Z tool length "
                  "(G43.1 Z<length>) is read", L, filename)
        if incr_line[L]:
            _fail("G43.1 in G91: not read (the length is read as an absolute value only in "
                  "G90); write it in G90", L, filename)
        out[L] = ax["Z"] * (INCH if inch_line[L] else 1.0)
    return out


#: largest canned cycle repeat count read (Fanuc K: 1-9999)
MAX_REPEATS = 9999


def _cycle_repeats(ki, wline, wlet, value, wcol, axes, n_lines, incr_line, filename):
    """Repeat count per line (1 where none) from the K (Fanuc) or L (LinuxCNC, Haas) words
    ``ki`` of canned cycle blocks: the hole is drilled that many times, in G91 stepping by the
    block's X Y increments each time.  K0/L0 (Fanuc: the cycle data stored without drilling;
    Haas: no hole at that block) is refused: whether the tool still moves to the block's X Y
    differs between controls and manuals, and no position is guessed."""
    rep = np.ones(n_lines, np.int64)
    seen = {}
    for i in ki.tolist():
        ln, c, v = int(wline[i]), chr(65 + int(wlet[i])), float(value[i])
        if ln in seen:
            _fail(f"two repeat counts ({seen[ln]} and {c}) in one canned cycle block", ln, filename)
        seen[ln] = c
        if v == 0:
            # the cycle data stored, no hole: read where the block names no position (X Y)
            # nor a peck or dwell (which the written-out moves would need from this line)
            i = np.flatnonzero(wline == ln)
            other = [chr(65 + int(wlet[j])) for j in i
                     if (0 <= wcol[j] < len(axes) and axes[int(wcol[j])] != "Z")
                     or chr(65 + int(wlet[j])) in "PQ"]
            if other:
                _fail(f"repeat count {c}0 in a canned cycle (the cycle data stored without a "
                      f"hole) with {' '.join(other)}: not read, since controls differ on whether "
                      "the tool moves to the block's X Y (and a stored P or Q is not carried "
                      "into written-out moves); write the cycle at its first hole", ln, filename)
            rep[ln] = 0
            continue
        if v != int(v) or not 1 <= v <= MAX_REPEATS:
            _fail(f"repeat count {c}{v:g} in a canned cycle: a whole number 1-{MAX_REPEATS} "
                  "expected", ln, filename)
        rep[ln] = int(v)
    if (rep > 1).any():
        # in G91 the X Y words step at each repeat; other axes in such a block are not read
        other = [k for k, a in enumerate(axes) if a not in "XYZ"]
        sel = (rep[wline] > 1) & incr_line[wline] & np.isin(wcol, other)
        if sel.any():
            j = int(np.argmax(sel))
            _fail(f"axis word {axes[int(wcol[j])]} in a repeated canned cycle block in G91: "
                  "only X Y step at each repeat; not read", wline[j], filename)
    return rep


def _map_codes(vals, mapping):
    out = np.empty(len(vals), np.int64)
    for u in np.unique(vals):
        out[vals == u] = mapping[int(u)]
    return out


def _start_vector(start, axes):
    n = len(axes)
    if start is None:
        return np.full(n, np.nan)
    if isinstance(start, Mapping):
        unknown = set(k.upper() for k in start) - set(axes)
        if unknown:
            raise ValueError(f"start names axes {sorted(unknown)} not in {axes}")
        up = {k.upper(): float(v) for k, v in start.items()}
        v = np.array([up.get(a, np.nan) for a in axes])
        if np.isinf(v).any():
            raise ValueError("start values must be finite")
        return v
    v = np.array(start, float).reshape(-1)
    if len(v) != n or np.isinf(v).any():
        raise ValueError(f"start must give {n} values (finite, or NaN for unknown)")
    return v



def write(program: Program) -> str:
    """The program's text, exactly as read."""
    return program.text


#: Largest program read (bytes); positions are 32-bit internally.
MAX_PROGRAM_BYTES = 2**31 - 2


def read_program(path) -> str:
    """The text of an NC program file, line endings untouched (CR LF stays CR LF, which
    ``Path.read_text`` would turn into LF).  A missing, binary (a NUL byte, not UTF-8), device
    (/dev/zero never ends) or directory path is an InputError naming it; nothing beyond 2 GB is
    read.  The one reader of the package's text files, `mtcomp._io.read_text`, does the work."""
    from .._io import read_text
    return read_text(path, newline="", what="NC program", max_bytes=MAX_PROGRAM_BYTES)


_COMMENTS = re.compile(r"\([^)\n]*\)|;[^\n]*")


def read_program_bytes(path) -> tuple[bytes, str]:
    """(bytes, encoding) of an NC program file, the bytes as they are on disk (nothing decoded:
    `parse` and `mtcomp compensate` work on them): encoding "ascii" where every byte is below
    128 (also UTF-8: passed on, the readers of the bytes need not test it again), "utf-8"
    where the file is UTF-8, else "latin-1" for a program that carries 8-bit
    characters in its comments only (``(FRÄSER Ø6)`` written by Windows CAM systems in Latin-1
    / cp1252); an 8-bit byte outside a comment is an InputError naming the line.  Otherwise
    as `read_program`."""
    from .._io import decode_text, read_bytes
    data = read_bytes(path, what="NC program", max_bytes=MAX_PROGRAM_BYTES)
    if data.isascii():
        return data, "ascii"
    try:
        decode_text(data, path)
        return data, "utf-8"
    except InputError as exc:
        code = _COMMENTS.sub("", data.decode("latin-1"))
        bad = re.search(r"[^\x00-\x7f]", code)
        if bad is None:
            return data, "latin-1"
        # the line of the first 8-bit byte outside a comment (comments keep the line count)
        raise InputError(f"{str(exc).split(': ', 1)[-1]}; an 8-bit character outside a comment "
                         f"({bad.group()!r})", path, code.count("\n", 0, bad.start()) + 1) from None


def read_program_8bit(path) -> tuple[str, str]:
    """(text, encoding) of an NC program file that may carry 8-bit characters in its comments
    (`read_program_bytes`): UTF-8 where it is, else Latin-1, every byte one character,
    provided no byte above 127 stands outside a comment (the program's words stay ASCII);
    write the output back with the same encoding to keep those bytes."""
    data, encoding = read_program_bytes(path)
    encoding = "utf-8" if encoding == "ascii" else encoding
    return data.decode(encoding), encoding
