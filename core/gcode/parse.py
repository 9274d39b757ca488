"""Reading a program into per-block arrays (modal state, absolute positions, arcs)."""
from __future__ import annotations

from typing import Mapping

import numpy as np

from .._io import InputError
from .arcs import _arc_geometry
from .codes import ARC_WORDS, CANONICAL, INCH, LINEAR
from .codes import _CHAR_HINT, _G_DIST, _G_HARMLESS, _G_MOTION, _G_PLANE, _G_REFUSED, _G_UNITS, _G_WCS, _M_REFUSED
from .program import Program, resolution_formats
from .textops import parse_decimals
from .tokens import _ascii, _comment_spans, _fail, _tokenise, _word_error, _word_text


def _ffill(values: np.ndarray, isset: np.ndarray, default) -> np.ndarray:
    """Forward fill: the last set value at or before each index (``default`` before any)."""
    idx = np.where(isset, np.arange(len(values)), -1)
    np.maximum.accumulate(idx, out=idx)
    out = values[np.maximum(idx, 0)]
    return np.where(idx >= 0, out, default)


def parse(text: str, *, axes=("X", "Y", "Z", "A", "B", "C"), filename: str = "<string>",
          convert_inch: bool = False, start=None, arc_tol: float | None = None,
          resolution=None) -> Program:
    """Read a Fanuc-style NC program (text) for a machine with the given axis letters.

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
    Raises ``InputError`` naming ``filename:line`` for anything it cannot read or would not
    transform correctly (docs/gcode.md lists the cases).
    """
    axes = tuple(str(a).upper() for a in axes)
    for a in axes:
        if len(a) != 1 or a not in CANONICAL:
            raise ValueError(f"axis names must be single letters out of {CANONICAL}, got {a!r}")
    n_ax = len(axes)
    data = text.encode("utf-8", "surrogateescape")
    b = np.frombuffer(data, np.uint8)
    nbytes = len(b)
    nl = np.flatnonzero(b == 10)
    line_start = np.concatenate(([0], nl + 1)).astype(np.int64)
    line_end = np.concatenate((nl, [nbytes])).astype(np.int64)
    n_lines = len(line_start)

    def line_of(pos):
        return np.searchsorted(line_start, pos, side="right") - 1

    # -- comments, % lines and block delete become blanks in a working copy; so does a UTF-8
    # byte-order mark (Windows editors write one)
    code = b.copy()
    bom = 3 if data.startswith(b"\xef\xbb\xbf") else 0
    code[:bom] = 32
    spans = _comment_spans(data, b, first=bom)
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
    slash = np.flatnonzero(code == 47)
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
    lp, rs, re_, dot_of_run, twodots, wline, sign_at, bad_at = _tokenise(code, line_start)
    if bad_at >= 0:
        ch = data[bad_at:bad_at + 1].decode("latin-1")
        hint = _CHAR_HINT.get(ch, "expected address letters, numbers, spaces and comments")
        _fail(f"unexpected character {ch!r}: {hint}", line_of(bad_at), filename)
    if len(rs) != len(lp) or np.any(rs != lp + 1):
        # blanks between a letter and its number ("X 10") are read, on the same line
        ok = len(rs) == len(lp) and bool(np.all(rs > lp)) and bool(np.all(rs[:-1] < lp[1:]))
        if ok:
            gap = np.flatnonzero(rs != lp + 1)
            ok = bool(np.all(line_of(rs[gap]) == wline[gap]))
        if not ok:
            _word_error(code, lp, rs, re_, line_of, filename)
    wlet = ((code[lp] | np.uint8(32)) - np.uint8(97)).astype(np.int8)

    # -- number syntax: sign only first, at most one point, at least one digit
    if sign_at >= 0:
        i = int(np.searchsorted(rs, sign_at, side="right") - 1)
        _fail(f"malformed number {_word_text(data, lp[i], re_[i])!r}: a sign may only "
              "lead the number", wline[i], filename)
    first_ch = code[rs]
    ndig = (re_ - rs) - (dot_of_run >= 0) - ((first_ch == 43) | (first_ch == 45))
    badnum = twodots | (ndig < 1)
    if badnum.any():
        i = int(np.argmax(badnum))
        _fail(f"malformed number in word {_word_text(data, lp[i], re_[i])!r}: expected "
              "digits with at most one decimal point", wline[i], filename)
    value = parse_decimals(code, rs, re_, dot_of_run, first=first_ch)
    if not np.isfinite(value).all():
        i = int(np.argmax(~np.isfinite(value)))
        _fail(f"number in word {_word_text(data, lp[i], min(re_[i], lp[i] + 20))!r}... is too large",
              wline[i], filename)
    w_num = rs.astype(np.int32)
    # positions fit 32 bits (programs under 2 GB); free what is no longer needed
    if nbytes >= 2**31 - 1:
        raise InputError("programs of 2 GB and more are not supported", file=filename)
    lp, re_ = lp.astype(np.int32), re_.astype(np.int32)
    del code, rs, dot_of_run, twodots, first_ch, ndig, badnum

    G, M = _ascii("G"), _ascii("M")
    # -- duplicate addresses in one block (G and M may repeat)
    # stable radix sort by letter keeps each letter's words in line order: a repeated letter in
    # a block shows as two neighbours with the same letter and line
    order = np.argsort(wlet, kind="stable")
    sl, sw = wlet[order], wline[order]
    dup = (sl[1:] == sl[:-1]) & (sw[1:] == sw[:-1]) & (sl[1:] != G) & (sl[1:] != M)
    if dup.any():
        j = int(np.argmax(dup)) + 1
        _fail(f"address {chr(65 + int(sl[j]))} appears twice in one block", int(sw[j]), filename)
    del order, sl, sw, dup

    # -- G codes
    gi = np.flatnonzero(wlet == G)
    g10 = np.rint(value[gi] * 10).astype(np.int64)
    nonint = np.abs(value[gi] * 10 - g10) > 1e-6
    cat = np.full(len(gi), -1, np.int64)   # 0 motion 1 dwell 2 plane 3 units 4 dist 5 wcs 6 harmless
    for u in np.unique(g10):
        sel = g10 == u
        u = int(u)
        if u in _G_MOTION:
            c = 0
        elif u == 40:
            c = 1
        elif u in _G_PLANE:
            c = 2
        elif u in _G_UNITS:
            c = 3
        elif u in _G_DIST:
            c = 4
        elif u in _G_WCS:
            c = 5
        elif u in _G_HARMLESS:
            c = 6
        else:
            c = -1
        cat[sel] = c
    badg = (cat < 0) | nonint
    if badg.any():
        j = int(np.argmax(badg))
        word = _word_text(data, lp[gi[j]], re_[gi[j]])
        reason = _G_REFUSED.get(int(g10[j])) if not nonint[j] else None
        what = (f"{word}: {reason}; refusing rather than guessing" if reason else
                f"unknown G code {word}: it may affect motion; refusing rather than guessing")
        _fail(what, wline[gi[j]], filename)
    gline = wline[gi]

    # -- letters
    allowed = set("GMNOFSTPIJKR") | set(axes)
    if "X" not in axes:
        allowed.add("X")                     # G4 X dwell time
    known = np.zeros(26, bool)
    known[[_ascii(c) for c in allowed]] = True
    badlet = ~known[wlet]
    if badlet.any():
        i = int(np.argmax(badlet))
        c = chr(65 + wlet[i])
        if c in CANONICAL:
            what = f"axis word {c} but the machine has axes {' '.join(axes)}"
        else:
            what = f"unknown address {_word_text(data, lp[i], re_[i])!r} (reads G M N O F S T P, " \
                   f"axes {' '.join(axes)}, arc words I J K R)"
        _fail(what, wline[i], filename)


    def per_line(catid, mapping, label):
        sel = cat == catid
        lines_, vals, words = gline[sel], g10[sel], gi[sel]
        cnt = np.bincount(lines_, minlength=n_lines)
        if np.any(cnt > 1):
            ln = int(np.argmax(cnt > 1))
            _fail(f"two {label} G codes in one block", ln, filename)
        out = np.full(n_lines, -1, np.int64)
        wout = np.full(n_lines, -1, np.int64)
        out[lines_] = _map_codes(vals, mapping)
        wout[lines_] = words
        return out, wout

    mot_l, mot_w = per_line(0, _G_MOTION, "motion (G0 G1 G2 G3)")
    pla_l, _ = per_line(2, _G_PLANE, "plane (G17 G18 G19)")
    uni_l, uni_w = per_line(3, _G_UNITS, "unit (G20 G21)")
    dis_l, _ = per_line(4, _G_DIST, "distance mode (G90 G91)")
    wcs_l, _ = per_line(5, _G_WCS, "work coordinate system")
    dwell_line = np.zeros(n_lines, bool)
    dwell_line[gline[cat == 1]] = True
    wcs_set = wcs_l >= 0
    if wcs_set.any():
        vals = np.unique(wcs_l[wcs_set])
        if len(vals) > 1:
            first = wcs_l[wcs_set][0]
            ln = int(np.flatnonzero(wcs_set & (wcs_l != first))[0])
            _fail(f"the program switches from G{first} to G{wcs_l[ln]}: the compensation is "
                  "defined in one workpiece frame", ln, filename)

    # -- M codes
    mi = np.flatnonzero(wlet == M)
    if len(mi):
        mref = np.isin(np.rint(value[mi]).astype(np.int64), list(_M_REFUSED))
        if mref.any():
            j = mi[int(np.argmax(mref))]
            _fail(_M_REFUSED[int(round(value[j]))] + "; refusing rather than guessing", wline[j], filename)

    # -- modal state per line
    inch_line = _ffill(uni_l == 20, uni_l >= 0, False)
    if inch_line.any() and not convert_inch:
        ln = int(np.flatnonzero(uni_l == 20)[0])
        _fail("inch data (G20): mtcomp works in mm; convert it with convert_inch=True "
              "(output is then written in G21)", ln, filename)
    incr_line = _ffill(dis_l == 91, dis_l >= 0, False)
    plane_line = _ffill(pla_l, pla_l >= 0, 17)
    mode_line = _ffill(mot_l, mot_l >= 0, -1)

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
    dwell_x = (wlet == _ascii("X")) & dwell_line[wline]
    if dwell_x.any():
        wcol = np.where(dwell_x, np.int8(-1), wcol)
    del dwell_x
    axis_w = np.flatnonzero((wcol >= 0) & (wcol < n_ax))
    arc_w = np.flatnonzero(wcol >= n_ax)
    if len(axis_w):
        dw = dwell_line[wline[axis_w]]
        if dw.any():
            _fail("axis word in a G4 dwell block", wline[axis_w[np.argmax(dw)]], filename)
    has_motion = np.zeros(n_lines, bool)
    has_motion[wline[axis_w]] = True
    has_arcw = np.zeros(n_lines, bool)
    has_arcw[wline[arc_w]] = True
    if len(arc_w):
        notarc = ~np.isin(mode_line[wline[arc_w]], (2, 3))
        if notarc.any():
            j = arc_w[np.argmax(notarc)]
            _fail(f"arc word {chr(65 + wlet[j])} outside G2/G3", wline[j], filename)
    block = has_motion | (has_arcw & np.isin(mode_line, (2, 3)))
    if len(bd_lines):
        bdl = bd_lines[block[bd_lines] | (np.bincount(gline, minlength=n_lines)[bd_lines] > 0)]
        if len(bdl):
            _fail("block delete '/' on a block with motion or G codes: the position after it "
                  "would depend on the operator's switch", bdl[0], filename)
    blines = np.flatnonzero(block)
    nblk = len(blines)
    blk_of_line = np.full(n_lines, -1, np.int64)
    blk_of_line[blines] = np.arange(nblk)
    col_word = np.full((nblk, n_ax + 4), -1, np.int32)
    cw = np.flatnonzero(wcol >= 0)
    col_word[blk_of_line[wline[cw]], wcol[cw]] = cw
    del cw, wcol

    motion = mode_line[blines]
    plane = plane_line[blines]
    incremental = incr_line[blines]
    inch = inch_line[blines]
    feed = feed_line[blines]
    vals = value[np.maximum(col_word, 0)]
    vals[col_word < 0] = np.nan
    if inch.any():
        lin_scale = np.where(inch, INCH, 1.0)
        for k, c in enumerate(cols):
            if c in LINEAR or c in ARC_WORDS:
                vals[:, k] *= lin_scale
    present = col_word[:, :n_ax] >= 0

    # -- absolute modal positions: last absolute value plus the increments since
    fm = resolution_formats(resolution, axes)
    res_ax = np.array([fm[a][1] * 10.0 ** -fm[a][0] for a in axes])
    if arc_tol is None:
        arc_tol = 0.002 * INCH if inch.any() else 0.02
    if not (arc_tol >= 0 and np.isfinite(arc_tol)):
        raise ValueError(f"arc_tol must be a finite number >= 0, got {arc_tol}")
    start_vec = _start_vector(start, axes)
    written = present.any(axis=0)
    idle = np.isnan(start_vec) & ~written
    start_vec[idle] = 0.0
    idle_axes = tuple(a for a, i in zip(axes, idle) if i)
    position = np.empty((nblk, n_ax))
    for k in range(n_ax):
        v = vals[:, k]
        pres = present[:, k]
        inc = np.where(pres & incremental, v, 0.0)
        cum = np.cumsum(inc)
        isabs = pres & ~incremental
        idx = np.where(isabs, np.arange(nblk), -1)
        np.maximum.accumulate(idx, out=idx)
        base = np.where(idx >= 0, v[np.maximum(idx, 0)] - cum[np.maximum(idx, 0)], start_vec[k])
        position[:, k] = base + cum

    ijk = np.nan_to_num(vals[:, n_ax:n_ax + 3])
    ijk_present = col_word[:, n_ax:n_ax + 3] >= 0
    radius = vals[:, n_ax + 3].copy()
    del vals
    arc_centre = np.full((nblk, 3), np.nan)
    arc_sweep = np.full(nblk, np.nan)
    is_arc = (motion == 2) | (motion == 3)
    if is_arc.any():
        _arc_geometry(axes, position, start_vec, motion, plane, ijk, ijk_present, radius, is_arc,
                      blines, arc_tol, filename, arc_centre, arc_sweep, res_ax)

    axis_known = np.isfinite(position)
    start_known = np.isfinite(start_vec)
    position[~axis_known] = 0.0
    start_vec = np.where(start_known, start_vec, 0.0)
    motion_word = mot_w[blines]
    g20 = uni_w[(uni_l == 20)]
    finch = fi[inch_line[wline[fi]]]
    arrays = dict(line_start=line_start, line_end=line_end, w_letter=wlet, w_value=value,
                  w_line=wline, w_pos=lp, w_num=w_num, w_end=re_, line=blines + 1, position=position,
                  start=start_vec, motion=motion.astype(np.int8), plane=plane.astype(np.int8),
                  incremental=incremental, inch=inch, feed=feed, present=present, ijk=ijk,
                  ijk_present=ijk_present, radius=radius, arc_centre=arc_centre,
                  arc_sweep=arc_sweep, col_word=col_word, motion_word=motion_word,
                  inch_g20_words=g20, inch_f_words=finch,
                  axis_known=axis_known, start_known=start_known,
                  known=axis_known.all(axis=1) if n_ax else np.ones(nblk, bool))
    for a in arrays.values():
        a.flags.writeable = False
    return Program(filename=filename, axes=axes, text=text, data=data, idle_axes=idle_axes,
                   arc_tol=float(arc_tol), **arrays)


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


def read_program(path) -> str:
    """The text of an NC program file, line endings untouched (CR LF stays CR LF, which
    ``Path.read_text`` would turn into LF).  A missing or binary file is an InputError."""
    from .._io import read_text
    return read_text(path, newline="", what="NC program")

