"""Fanuc polar coordinate command G16 (cancelled by G15): reading and rewriting.

Under G16 in the G17 plane the X word is a radius (mm, in) and the Y word an angle (deg,
counter-clockwise from +X); in G90 both are measured from the zero of the work coordinate
system (the block's program frame), so the point is ``(r cos a, r sin a)`` there.  Each word is
modal within the G16 section: a block writing only the angle keeps the radius of the last
polar block (the Fanuc bolt-hole idiom ``G16`` / ``G81 X100. Y30. ...`` / ``Y150.`` /
``Y270.``).  Where the section has not yet written one of them, the control would take it from
its own state (the current position or the words before G16, depending on the control): the
plane's axes are unknown there until both are written (never guessed).

Not read, refused naming the line: G16 outside G17, G91 under G16 (an incremental radius moves
the polar origin to the current position, an incremental angle adds to the last one), arcs
under G16, G16 with G68 or G43.4.

Rewriting: the compensated point of a polar block is written back as polar words (the radius
and the angle of the compensated point; an angle keeps its turn, e.g. 350 stays near 350 rather
than -10); a word whose value does not change at the resolution keeps its text, and a word the
block left modal is inserted where the compensated value differs from the one the control
holds.  The angle is written at the Y axis' resolution in deg, so its rounding moves the point
by up to ``r * res_angle / 2`` (rad) sideways; a block where the written words put the point more
than one count of the linear resolution from the compensated point is refused, naming the line.
A canned cycle under G16 that would have to be written out as moves is refused (moves under G16
would be polar words too).
"""
from __future__ import annotations

import numpy as np

from .._io import InputError
from .codes import INCH
from .tokens import _fail


def read_polar(axes, blines, on, section, col_word, value, inch, incremental, motion, plane,
               filename):
    """Polar blocks of a program (``on``: per block, G16 in effect; ``section``: per block, the
    number of the G16 that set it).  Returns (polar (N,) blocks under G16 writing X or Y,
    xy (N, 2) the point in the program frame in the program's units (NaN where a word is not
    yet known in the section, or not a polar block))."""
    n = len(blines)
    if "X" not in axes or "Y" not in axes:
        _fail("G16 polar coordinates on a machine without X and Y", int(blines[np.argmax(on)]) if on.any()
              else 0, filename)
    ix, iy = axes.index("X"), axes.index("Y")
    wr, wt = col_word[:, ix], col_word[:, iy]
    writes = on & ((wr >= 0) | (wt >= 0))
    checks = [
        (writes & (plane != 17), "G16 polar coordinates outside the G17 plane: not read"),
        (writes & incremental, "G91 under G16 polar coordinates (an incremental radius moves the "
                               "polar origin to the current position, an incremental angle adds to "
                               "the last one): not read; write absolute radius and angle"),
        (on & np.isin(motion, (2, 3)), "arc under G16 polar coordinates: not supported"),
    ]
    for bad, what in checks:
        if bad.any():
            _fail(what, int(blines[np.argmax(bad)]), filename)
    r = np.where(wr >= 0, value[np.maximum(wr, 0)], np.nan)
    a = np.where(wt >= 0, value[np.maximum(wt, 0)], np.nan)
    # modal within a section: a block that starts a section (or is outside G16) resets
    new_sec = np.r_[True, section[1:] != section[:-1]] | ~on
    r_m = _ffill(r, (wr >= 0) | new_sec)
    a_m = _ffill(a, (wt >= 0) | new_sec)
    t = np.radians(a_m)
    xy = np.full((n, 2), np.nan)
    xy[writes, 0] = (r_m * np.cos(t))[writes]
    xy[writes, 1] = (r_m * np.sin(t))[writes]
    return writes, xy


def _ffill(v, isset):
    idx = np.where(isset, np.arange(len(v)), -1)
    np.maximum.accumulate(idx, out=idx)
    return np.where(idx >= 0, v[np.maximum(idx, 0)], np.nan)


def polar_edits(ctx, program, cw, kn_edit, prev, new, res, fm, offc, expanded, column_edits):
    """Write the compensated points of the polar blocks as radius and angle words (edits into
    ``ctx`` through ``column_edits``).  ``prev``, ``new`` (N, n_axes): where the control stands
    before and after each block, compensated, in counts of ``res`` (reference frame, ``offc`` the blocks' offsets in counts).  Returns the (N, n_axes)
    mask of the cells handled here (the X and Y of the polar blocks), or None."""
    pol = program.polar
    if pol is None:
        return None
    pol = np.asarray(pol)
    line = np.asarray(program.line)
    _refuse_cartesian_moves_under_g16(program, pol, kn_edit, prev, new)
    if not pol.any():
        return None
    if len(expanded) and pol[expanded].any():
        j = int(expanded[np.argmax(pol[expanded])])
        raise InputError("this canned cycle must be written out as moves, but it stands under G16 "
                         "polar coordinates, where moves are polar words too: refusing",
                         program.filename, int(line[j]))
    axes = program.axes
    ix, iy = axes.index("X"), axes.index("Y")
    N = len(program)
    sc = np.where(np.asarray(program.inch), INCH, 1.0)
    cart = np.nan_to_num(np.asarray(program.polar_xy)) * sc[:, None]       # mm, program frame
    rxy = res[[ix, iy]]
    off = offc[:, [ix, iy]] if offc is not None else np.zeros((N, 2))
    # the correction in counts, as the rewrite rounded it: target = exact point + correction
    d = new[:, [ix, iy]] - (np.rint(cart / rxy) + off)
    tgt = cart + d * rxy
    rr = np.hypot(tgt[:, 0], tgt[:, 1])
    th = np.degrees(np.arctan2(tgt[:, 1], tgt[:, 0]))
    dY, mY = fm["Y"]
    unit = mY * 10.0 ** -dY                     # deg per count of the angle word
    wv = np.asarray(program.w_value)
    r_cnt = np.zeros(N, np.int64)
    t_cnt = np.zeros(N, np.int64)
    rep_r, ins_r, rep_t, ins_t = [], [], [], []
    r_out = t_out = None                        # what the control holds in the output
    a_in = np.nan                               # the input's modal angle (deg)
    r_neg = False                               # the input's modal radius is negative
    on16, sec = _g16_state(program)
    section_start = np.r_[True, sec[1:] != sec[:-1]]
    kn_edit = np.asarray(kn_edit)
    for j in np.flatnonzero(pol).tolist():
        wr, wt = int(cw[j, ix]), int(cw[j, iy])
        if (wr >= 0 and not abs(wv[wr] * sc[j] / rxy[0]) < 2.0**52) or \
                (wt >= 0 and not abs(wv[wt] / unit) < 2.0**52):
            raise InputError("polar words (G16) too large for the resolution (more than 2**52 "
                             "counts)", program.filename, int(line[j]))
        orig_r = int(np.rint(wv[wr] * sc[j] / rxy[0])) if wr >= 0 else None
        orig_t = int(np.rint(wv[wt] / unit)) if wt >= 0 else None
        if wt >= 0:
            a_in = float(wv[wt])
        if wr >= 0:
            r_neg = bool(wv[wr] < 0)
        elif section_start[j]:
            r_neg = False
        if not kn_edit[j]:
            r_out = orig_r if orig_r is not None else r_out
            t_out = orig_t if orig_t is not None else t_out
            continue
        # a negative radius (the point opposite the angle) stays negative, with its angle
        rj, tj = (-rr[j], th[j] + 180.0) if r_neg else (rr[j], th[j])
        ang = tj + 360.0 * np.round((a_in - tj) / 360.0)            # keep the programmed turn
        if np.rint(rj / rxy[0]) == 0 and np.isfinite(a_in):
            # at the origin (radius 0 in counts) the angle places nothing: keep the program's
            ang = a_in
        if not (abs(rj / rxy[0]) < 2.0**52 and abs(ang / unit) < 2.0**52):
            raise InputError("polar words (G16) too large for the resolution (more than 2**52 "
                             "counts)", program.filename, int(line[j]))
        rc, tc = int(np.rint(rj / rxy[0])), int(np.rint(ang / unit))
        r_cnt[j], t_cnt[j] = rc, tc
        for orig, c, rep, ins, prev in ((orig_r, rc, rep_r, ins_r, r_out),
                                        (orig_t, tc, rep_t, ins_t, t_out)):
            if orig is not None and c != orig:
                rep.append(j)
            elif orig is None and c != prev:
                ins.append(j)
        changed = (orig_r is not None and rc != orig_r) or (orig_t is not None and tc != orig_t) \
            or (orig_r is None and rc != r_out) or (orig_t is None and tc != t_out)
        if changed:
            # where the control puts the point from the written words
            rw, aw = rc * rxy[0], np.radians(tc * unit)
            err = np.hypot(rw * np.cos(aw) - tgt[j, 0], rw * np.sin(aw) - tgt[j, 1])
            if err > rxy[0] * (1 + 1e-9):
                raise InputError(f"G16 polar block: the compensated point cannot be written within "
                                 f"one count of the axis resolution by a radius and an angle at the "
                                 f"resolution ({err * 1e3:.3g} µm off at radius {rr[j]:.3f} mm, "
                                 f"angle step {unit:g} deg): refusing", program.filename,
                                 int(line[j]))
        r_out, t_out = rc, tc
    column_edits(ctx, cw, ix, ctx.letter("X").encode(), fm["X"], np.asarray(rep_r, np.int64),
                 np.asarray(ins_r, np.int64), r_cnt)
    column_edits(ctx, cw, iy, ctx.letter("Y").encode(), fm["Y"], np.asarray(rep_t, np.int64),
                 np.asarray(ins_t, np.int64), t_cnt)
    mask = np.zeros((N, len(axes)), bool)
    mask[pol, ix] = mask[pol, iy] = True
    return mask


def _g16_state(program):
    """Per block: G16 in effect after its line's G15/G16 words, and the number of the G16 that
    set it (the sections of `read_polar`), from the program's words."""
    wl, wlet, wv = (np.asarray(x) for x in (program.w_line, program.w_letter, program.w_value))
    sel = (wlet == ord("G") - 65) & np.isin(wv, (15.0, 16.0))
    ev = np.full(program.n_lines, -1, np.int64)
    ev[wl[sel & (wv == 15.0)]] = 0
    ev[wl[sel & (wv == 16.0)]] = 1
    bl = np.asarray(program.line) - 1
    on16 = _ffill(ev.astype(float), ev >= 0)[bl] == 1
    return on16, np.cumsum(ev == 1)[bl]


def _refuse_cartesian_moves_under_g16(program, pol, kn_edit, prev, new):
    """A block under G16 that writes neither X nor Y, where the compensated point moves in X or
    Y (a tilt turning a Z move into an XYZ move): its X Y words would be a radius and an angle,
    not coordinates.  Refused, naming the line (writing polar words there would also fix the
    section's modal radius and angle where the program had not)."""
    axes = program.axes
    ix, iy = axes.index("X"), axes.index("Y")
    on16, _ = _g16_state(program)
    moves = (new[:, ix] != prev[:, ix]) | (new[:, iy] != prev[:, iy])
    bad = on16 & ~pol & np.asarray(kn_edit) & moves
    if bad.any():
        j = int(np.argmax(bad))
        raise InputError("the compensation moves X or Y in a block under G16 polar coordinates "
                         "that writes neither (a tilt of the workpiece or a correction that is not "
                         "rigid): its X Y words would be a radius and an angle; refusing (write "
                         "the block's radius and angle, or the section without G16)",
                         program.filename, int(np.asarray(program.line)[j]))
