"""Rewriting axis words for transformed positions, splicing edits into the original bytes."""
from __future__ import annotations

from typing import Callable

import numpy as np

from .arcs import _arc_keep, _arc_params, _arc_samples, _n_samples, _linearisation_points, _Segments, _subset
from .._io import InputError
from .codes import ARC_WORDS, CANONICAL, INCH, LINEAR
from .program import Program, resolution_formats
from . import _ctok
from .rotation import has_rotation, to_reference, to_words
from .textops import decimal_values, format_counts, splice
from .tokens import _ascii


class _Edits:
    """Collects edits (replace orig[pos:stop] by text) as arrays of pieces of a text buffer."""

    def __init__(self):
        self.pos, self.stop, self.sub, self.off, self.len = [], [], [], [], []
        self.bufs, self.size = [], 0

    def add_buffer(self, buf: np.ndarray) -> int:
        base = self.size
        self.bufs.append(buf)
        self.size += len(buf)
        return base

    def add(self, pos, stop, sub, off, length):
        # 32-bit positions and offsets (texts under 2 GB) keep millions of edits small
        shape = np.shape(pos)
        self.pos.append(np.asarray(pos, np.int32).ravel())
        self.stop.append(np.broadcast_to(np.asarray(stop, np.int32), shape).ravel())
        self.sub.append(np.broadcast_to(np.asarray(sub, np.int16), shape).ravel())
        self.off.append(np.broadcast_to(np.asarray(off, np.int32), shape).ravel())
        self.len.append(np.broadcast_to(np.asarray(length, np.int32), shape).ravel())

    def const(self, text: bytes) -> tuple[int, int]:
        return self.add_buffer(np.frombuffer(text, np.uint8)), len(text)

    def apply(self, orig: np.ndarray, progress=None) -> bytes:
        if not self.pos:
            return orig.tobytes()
        def cat(parts):
            out = np.concatenate(parts)
            parts.clear()                     # free the pieces as soon as they are joined
            return out
        src = cat(self.bufs) if self.bufs else np.zeros(0, np.uint8)
        return splice(orig, cat(self.pos), cat(self.stop), cat(self.sub), src, cat(self.off),
                      cat(self.len), progress=progress)


# sub-order of edits at one position: G words, inserted words in canonical order, the
# linearisation comment, inserted lines, then replacements and removals
_SUB_G = 0
_SUB_INSERT = 100
_SUB_COMMENT = 500
_SUB_LINES = 600
_SUB_REPLACE = 1000


class _Ctx:
    """What the rewriting steps share: program, its bytes, edits and per-block anchors."""

    def __init__(self, program: Program):
        self.p = program
        self.data = np.frombuffer(program.data, np.uint8)
        self.edits = _Edits()
        self.blines = np.asarray(program.line) - 1
        self._anch = None
        self._spaced = None
        self._lower = None
        self.added_lines = {}            # block index -> lines inserted after it

    @property
    def anchors(self):
        """Per block: first F S T M P word position, end of the last word, first word that is
        not N or O (-1 where none)."""
        if self._anch is None:
            p = self.p
            wl, wlet = np.asarray(p.w_line), np.asarray(p.w_letter)
            wpos, wend = np.asarray(p.w_pos), np.asarray(p.w_end)

            def first_pos(mask):
                out = np.full(p.n_lines, -1, np.int64)
                uniq, idx = np.unique(wl[mask], return_index=True)
                out[uniq] = wpos[mask][idx]
                return out[self.blines]
            tail = first_pos(np.isin(wlet, [_ascii(c) for c in "FSTMP"]))
            body = first_pos(~np.isin(wlet, [_ascii(c) for c in "NO"]))
            last_end = np.full(p.n_lines, -1, np.int64)
            last_end[wl] = wend                      # the last word of a line wins
            self._anch = (tail, last_end[self.blines], body)
        return self._anch

    def letter(self, a: str) -> str:
        """An address letter in the program's case (lower case programs get lower case)."""
        if self._lower is None:
            wl = np.asarray(self.p.w_pos)
            ch = self.data[wl] if len(wl) else np.zeros(0, np.uint8)
            self._lower = bool(np.count_nonzero(ch >= 97) * 2 > len(ch))
        return a.lower() if self._lower else a

    @property
    def spaced(self):
        """Whether each block separates its words by blanks (style of inserted words)."""
        if self._spaced is None:
            p = self.p
            wl, wp = np.asarray(p.w_line), np.asarray(p.w_pos)
            first_in_line = np.ones(len(wl), bool)
            first_in_line[1:] = wl[1:] != wl[:-1]
            before = self.data[np.maximum(wp - 1, 0)]
            sp = ((before == 32) | (before == 9)) & ~first_in_line
            nsp = np.bincount(wl[sp], minlength=p.n_lines)
            nwords = np.bincount(wl, minlength=p.n_lines)
            # blocks of one word follow the program's majority
            multi = nwords[self.blines] > 1
            n_sp = np.count_nonzero(nsp[self.blines][multi] > 0)
            default = n_sp * 2 >= np.count_nonzero(multi)
            self._spaced = np.where(multi, nsp[self.blines] > 0, default)
        return self._spaced


def rewrite(program: Program, transform: Callable[[np.ndarray], np.ndarray], *,
            resolution=None, chordal_tol: float = 1e-4, progress=None, unknown: str = "defer",
            row_lines: list | None = None, info: dict | None = None) -> str:
    """Rewrite the program's axis words for new commanded positions.

    ``transform(q)`` maps absolute commanded positions (M, n_axes) in mm/deg to new ones.  It is
    called once with rows [end points of the known blocks, arc samples] and a second time only
    if some arcs must be linearised (with their segment points).  If ``row_lines`` is a list,
    the 1-based source line of every row is appended to it before each call (so a transform
    that refuses a point can name the line).
    ``resolution``: per axis letter a resolution (e.g. 1e-6, 5e-6) or a number of decimals;
    default 1e-6 mm for X Y Z (U V W), 1e-5 deg for A B C.  ``chordal_tol`` (mm): largest
    deviation of the output path from the transformed arcs.  ``progress(done, total)`` is
    called while the output is assembled (bytes).
    ``unknown``: what happens to motion blocks before every axis position is known
    (``program.known``): ``"defer"`` passes them through unchanged and compensates from the
    first block where the pose is known (that block gets words for every axis that must move;
    arcs directly after the unknown blocks pass unchanged too, an arc's start cannot move);
    ``"refuse"`` raises InputError naming the first such block.
    Everything except the axis words of known motion blocks (and, for arcs, I J K R and
    linearisation) stays byte for byte; see docs/gcode.md.
    """
    return rewrite_with_lines(program, transform, resolution=resolution, chordal_tol=chordal_tol,
                              progress=progress, unknown=unknown, row_lines=row_lines, info=info)[0]


def _control_counts(program: Program, res: np.ndarray, offc=None, words=None) -> np.ndarray:
    """Where the control stands after each block, in counts of the axis resolution, as it
    reads the words (each rounded to its input increment, G91 increments summed): (N + 1,
    n_axes) float holding integers, row 0 the start, NaN where unknown.  ``words``: (N, n_axes)
    values of the axis words of each block (NaN: no word) instead of the program's own (the
    written program read back, with the program's modal state)."""
    N, n = len(program), program.n_axes
    cw, wv = np.asarray(program.col_word), np.asarray(program.w_value)
    inc, inch = np.asarray(program.incremental), np.asarray(program.inch)
    start = np.where(program.start_known, np.rint(np.asarray(program.start) / res), np.nan)
    polar = program.polar is not None and bool(np.asarray(program.polar).any())
    # compiled: one sequential pass per axis (numpy below without it, or MTCOMP_TOKENIZER=python;
    # and for G16 polar blocks, whose X Y words are a radius and an angle)
    got = None if polar else _ctok.control_counts(N, res, inc, inch, [a in LINEAR for a in program.axes], INCH,
                               start, program.axis_known, words=words, col_word=cw,
                               w_value=wv, offc=offc)
    if got is not None:
        if got[0] is not None:
            return got[0]
        k, j = divmod(got[1], max(N, 1))
        v = (words[j, k] if words is not None else wv[cw[j, k]])
        if program.axes[k] in LINEAR and inch[j]:
            v = v * INCH
        raise InputError(f"axis word {program.axes[k]}{v:g} is too large for the axis resolution "
                         f"{res[k]:g} (more than 2**52 counts)", program.filename,
                         int(program.line[j]))
    Cc = np.empty((N + 1, n))
    Cc[0] = start
    for k, a in enumerate(program.axes):
        if words is None:
            w = cw[:, k]
            pres = w >= 0
            v = np.where(pres, wv[np.maximum(w, 0)], 0.0)
            if polar and a in "XY":
                # G16: X Y words are a radius and an angle; the control stands at their point
                v = np.where(program.polar, np.nan_to_num(program.polar_xy[:, "XY".index(a)]), v)
                pres = pres | program.polar
        else:
            pres = ~np.isnan(words[:, k])
            v = np.where(pres, words[:, k], 0.0)
        if a in LINEAR and inch.any():
            v = v * np.where(inch, INCH, 1.0)
        c = np.rint(v / res[k])
        big = np.abs(c) > 2.0 ** 52
        if big.any():
            j = int(np.argmax(big))
            raise InputError(f"axis word {a}{v[j]:g} is too large for the axis resolution "
                             f"{res[k]:g} (more than 2**52 counts)", program.filename,
                             int(program.line[j]))
        incr = np.where(pres & inc, c, 0.0)
        cum = np.cumsum(incr)
        isabs = pres & ~inc
        if offc is not None:
            c = c + offc[:, k]                    # absolute words are in the block's frame
        idx = np.where(isabs, np.arange(N), -1)
        np.maximum.accumulate(idx, out=idx)
        i0 = np.maximum(idx, 0)
        Cc[1:, k] = np.where(idx >= 0, c[i0] - cum[i0], Cc[0, k]) + cum
    Cc[1:][~np.asarray(program.axis_known)] = np.nan
    return Cc


def _read_deviation(program: Program, Cc: np.ndarray, res: np.ndarray) -> np.ndarray:
    """(N,) mm: how far the control's reading of the program as written (each word rounded to
    its count, G91 increments summed count by count) stands from the parsed positions, over
    the linear axes: the part of a block's tool-edge error the program itself carries (G91
    increments finer than a count), which no compensation removes.  NaN -> 0."""
    P = np.asarray(program.position)
    lin = [k for k, a in enumerate(program.axes) if a in LINEAR]
    out = np.zeros(len(P))
    for s in range(0, len(P), 1 << 18):
        d = Cc[1 + s:1 + s + (1 << 18), lin] * res[lin] - P[s:s + (1 << 18), lin]
        out[s:s + len(d)] = np.sqrt(np.nansum(d * d, axis=1))
    return out


def _refuse_unread_counts(program: Program, Cc: np.ndarray, kk, every: bool) -> None:
    """A compensated block must have a control reading (counts) for every axis: where the
    parser knows the position but the counts are NaN, the words would be written relative to
    0 (a retract written as no move).  Refused naming the line instead."""
    rows = Cc[1:] if every else Cc[1 + kk]
    bad = np.isnan(rows).any(axis=1)
    if not bad.any():
        return
    j = int(np.argmax(bad))
    i = j if every else int(kk[j])
    axes = " ".join(a for a, b in zip(program.axes, np.isnan(rows[j])) if b)
    raise InputError(f"where the control stands in {axes} after this block cannot be read from "
                     "the words before it (a canned cycle or an increment from a position not "
                     "known): state the start position (--start)", program.filename,
                     int(program.line[i]))


def _refuse_half_count_increments(program: Program, res: np.ndarray) -> None:
    """G91 axis words of exactly half a count of the resolution (X0.00005 at 0.0001 mm): the
    control rounds them up, to even or down depending on the control, and the difference adds
    up block after block, so the position where a compensated word is written later need not
    be one the program gives.  Up to two of them on an axis since its last absolute word (at
    most a count apart) are read as mtcomp's count model rounds them (to even); a third is
    refused naming the line (under a correction that changes nothing the program passes
    unchanged)."""
    inc = np.asarray(program.incremental)
    if not inc.any():
        return
    cw, wv, inch = np.asarray(program.col_word), np.asarray(program.w_value), np.asarray(program.inch)
    N = len(inc)
    inc_rows = np.flatnonzero(inc)               # (few blocks in most programs: index those)
    for k, a in enumerate(program.axes):
        w = cw[:, k]
        rows = inc_rows[w[inc_rows] >= 0]
        if not len(rows):
            continue
        # the increments alone first (a few rows of most programs): the same values as below
        vi = wv[w[rows]] * np.where(inch[rows] & (a in LINEAR), INCH, 1.0) / res[k]
        if not (np.abs(np.abs(vi - np.trunc(vi)) - 0.5) < 1e-6).any():
            continue
        pres = w >= 0
        v = np.where(pres, wv[np.maximum(w, 0)], 0.0)
        v = v * np.where(inch & (a in LINEAR), INCH, 1.0) / res[k]
        tie = pres & inc & (np.abs(np.abs(v - np.trunc(v)) - 0.5) < 1e-6)
        if not tie.any():
            continue
        c = np.cumsum(tie)
        last_abs = np.where(pres & ~inc, np.arange(N), -1)
        np.maximum.accumulate(last_abs, out=last_abs)
        run = c - np.where(last_abs >= 0, c[np.maximum(last_abs, 0)], 0)
        if (run > 2).any():
            j = int(np.argmax(run > 2))
            raise InputError(f"G91 increments such as {a}{wv[w[j]]:g} are half a count of the axis "
                             f"resolution {res[k]:g}: controls round them differently (up, to "
                             "even, down) and the difference adds up block after block, so the "
                             "compensated positions after them would not be ones the program "
                             "gives; write increments in whole counts", program.filename,
                             int(program.line[j]))


def read_back_counts(program: Program, info: dict, data, out_line) -> np.ndarray | None:
    """Where the control stands after each block of the *written* program, in counts of
    ``info["emitted_resolution"]`` (N, n_axes; NaN where unknown): the axis words found again
    in the output bytes `data` on each block's output line (``out_line``, 1-based, as
    `rewrite_with_lines` returns it, shifted by any header), run through the program's modal
    state (G90/G91, units, work offsets) as the control reads them.  Independent of how the
    rewrite placed and formatted its numbers, so that a wrong byte in a written word shows.
    None where this reading does not apply (the compiled reader missing; linearised arcs,
    canned cycles or G92 in the program; a block line with axis letters that are no move, such
    as G4 X) and the caller must parse the output instead; raises ValueError naming the line
    where a written word cannot be read."""
    p = program
    if not _read_back_applies(p, info):
        return None
    got = _ctok.read_words(data, np.asarray(out_line, np.int64) - 1, "".join(p.axes))
    if got is None:
        return None
    words, bad = got
    if bad >= 0:
        raise ValueError(f"line {int(out_line[bad])} of the written program: an axis word "
                         "cannot be read back")
    res = np.asarray(info["emitted_resolution"], float)
    off = np.asarray(p.offset)
    offc = np.rint(off / res).astype(np.int64) if off.any() else None
    return _control_counts(p, res, offc, words=words)[1:]


def _read_back_applies(p: Program, info: dict) -> bool:
    """Whether the written program's words can be read back block line by block line: no
    linearised arcs or canned cycles (new lines), no G92 (its words are edited too), and every
    axis-letter word on a block's line is one of its axis words (not G4 X, G10 X ...)."""
    if info.get("linearised") or np.asarray(p.cycle).any():
        return False
    fast = _ctok.read_back_applies(p.w_line, p.w_letter, p.w_value, "".join(p.axes),
                                   np.asarray(p.line) - 1, p.col_word)
    if fast is not None:
        return fast
    wl, wlet, wv = np.asarray(p.w_line), np.asarray(p.w_letter), np.asarray(p.w_value)
    G = ord("G") - 65
    if ((wlet == G) & (wv == 92.0)).any():
        return False
    axl = np.zeros(26, bool)
    axl[[ord(a) - 65 for a in p.axes]] = True
    n_axis_words = np.bincount(wl[axl[wlet]], minlength=p.n_lines)
    cw = np.asarray(p.col_word)[:, :p.n_axes]
    return bool(np.array_equal(n_axis_words[np.asarray(p.line) - 1],
                               np.count_nonzero(cw >= 0, axis=1)))


def emitted_values(info: dict, consume: bool = False) -> np.ndarray:
    """The emitted end positions ``info["emitted"]`` (counts) as the numbers the written words
    say (N, n_axes; mm, deg): (count * m) / 10**d exactly, from the decimals and multiple the
    rewrite formatted each axis with (`textops.decimal_values`).  ``consume``: the counts are
    taken out of ``info`` and the values written over their memory (one (N, n_axes) array
    fewer at the peak of `mtcomp compensate`)."""
    counts = info.pop("emitted") if consume else info["emitted"]
    return decimal_values(counts, info["emitted_decimals"], info["emitted_multiple"],
                          info["emitted_resolution"], inplace=consume)


def check_written(program: Program, info: dict, data, out_line) -> bool | None:
    """Whether every compensated block (``info["compensated"]``) of the written program
    `data` reads back (`read_back_counts`) as the counts the rewrite emitted
    (``info["emitted"]``): True, or ValueError(message, block index) where it does not; None
    where the reading does not apply (see `read_back_counts`).  One compiled pass with no
    arrays of the whole program; the arrays of `read_back_counts` only to describe a
    failure."""
    p = program
    if _ctok.load() is None or not _read_back_applies(p, info):
        return None
    res = np.asarray(info["emitted_resolution"], float)
    off = np.asarray(p.offset)
    offc = np.rint(off / res).astype(np.int64) if off.any() else None
    start = np.where(p.start_known, np.rint(np.asarray(p.start) / res), np.nan)
    want = np.asarray(info["emitted"])
    got = _ctok.check_words(data, np.asarray(out_line, np.int64) - 1, "".join(p.axes), res,
                            p.incremental, p.inch, [a in LINEAR for a in p.axes], INCH, start,
                            p.axis_known, info["compensated"], want, offc)
    if got is None:
        return None
    j, kind = got
    if j < 0:
        return True
    if kind == 2:
        counts = read_back_counts(p, info, data, out_line)
        raise ValueError(f"its line {int(out_line[j])} reads back as counts "
                         f"{counts[j].tolist()}, not {want[j].tolist()}", j)
    raise ValueError(f"line {int(out_line[j])} of the written program: an axis word cannot be "
                     "read back" if kind == 1 else
                     f"line {int(out_line[j])} of the written program: a word of more than "
                     "2**52 counts", j)


def _unknown_axes(program: Program, k: int) -> str:
    return " ".join(a for a, x in zip(program.axes, program.axis_known[k]) if not x)


def rewrite_with_lines(program: Program, transform: Callable[[np.ndarray], np.ndarray], *,
                       resolution=None, chordal_tol: float = 1e-4, progress=None,
                       unknown: str = "defer", row_lines: list | None = None,
                       info: dict | None = None, as_bytes: bool = False,
                       arc_tol: float | None = None):
    """`rewrite`, also returning for every motion block the 1-based line of the output where
    the block ends (after a linearised arc: its last segment line), so that the output can be
    compared block by block with the input.  ``info``, if a dict, receives what was done:
    ``deferred`` blocks, ``linearised`` arcs, canned cycle holes ``cycles_kept`` and
    ``cycles_expanded``, ``compensated`` blocks, and the counts the written words say:
    ``emitted`` (N, n_axes) end positions in steps of ``emitted_resolution`` (mm, deg; float),
    each step exactly ``emitted_multiple * 10**-emitted_decimals`` (per axis;
    `emitted_values`).  ``as_bytes``: the output as a bytes-like object (a bytearray where
    the compiled splice made it; the program's encoding, UTF-8 with its undecodable bytes
    kept) instead of str, so that a caller that edits it further or writes it saves a copy of
    the whole text.  ``arc_tol`` (mm): how far the compensated path may leave the circle the
    control runs for an arc to stay an arc (default: ``chordal_tol``; `mtcomp compensate`
    gives its ``--tolerance``)."""
    axes = program.axes
    n_ax = len(axes)
    if unknown not in ("defer", "refuse"):
        raise ValueError(f"unknown must be 'defer' or 'refuse', got {unknown!r}")
    fm = resolution_formats(resolution, axes)
    inch_prog = bool(np.asarray(program.inch).any())
    if inch_prog:
        # an inch program is written in inch, one decimal more than the mm resolution has
        fm = {a: ((d + 1, 1) if a in LINEAR else (d, m)) for a, (d, m) in fm.items()}
    d_ax = np.array([fm[a][0] for a in axes])
    m_ax = np.array([fm[a][1] for a in axes])
    res = m_ax * 10.0 ** -d_ax.astype(float)
    if inch_prog:
        res = np.where([a in LINEAR for a in axes], res * INCH, res)
    if not chordal_tol > 0:
        raise ValueError("chordal_tol must be positive")
    idle = [k for k, a in enumerate(axes) if a in program.idle_axes and a in LINEAR]
    if idle:
        # a linear axis the program never writes stands where the operator set it (Z of a 2D
        # program): it is taken at 0 to evaluate the transform, but gets no word (a word would
        # move it to a position the program never stated), so its correction is not applied.
        # Rotary axes never written stand at 0 by the convention 3-axis programs are run with
        # on a 5-axis machine, and are compensated (docs/gcode.md, "Unknown positions")
        transform = _KeepIdle(transform, idle)
    ctx = _Ctx(program)
    N = len(program)
    P = np.asarray(program.position)
    line = np.asarray(program.line)
    kn = np.asarray(program.known)
    if unknown == "refuse" and not kn.all():
        j = int(np.argmax(~kn))
        raise InputError(f"position of {_unknown_axes(program, j)} not known at this block (the "
                         "program has not written it yet): state the start position or let "
                         "such blocks pass uncompensated", program.filename, int(line[j]))
    kprev = np.concatenate([[bool(np.all(program.start_known))], kn[:-1]])
    cyc = np.asarray(program.cycle)
    if cyc.any():
        # a cycle run starting where the pose is not yet known is left as it is: its initial
        # level (the G98 return, the first hole's arrival) was set uncompensated
        cb0 = np.flatnonzero(cyc > 0)
        first = np.asarray(program.cycle_data)[cb0, 6].astype(np.int64)
        late = ~kprev[first]
        if late.any():
            kn = kn.copy()
            kn[cb0[late]] = False
    is_arc = np.asarray(program.is_arc)
    ak = np.flatnonzero(is_arc & kn)
    first_arc = ak[~kprev[ak]]
    if len(first_arc) and unknown == "defer":
        # an arc cannot be the first compensated block (its start was not compensated): arcs
        # that directly follow the blocks before the pose is known pass uncompensated too, and
        # the first line after them brings every axis onto the compensated path
        idx = np.arange(N)
        lu = np.where(~kn, idx, -1 if not kprev[0] else -2)
        lu = np.maximum.accumulate(np.r_[-1 if not kprev[0] else -2, lu[:-1]])
        nonarc = np.cumsum(~is_arc)
        before = np.where(lu >= 0, nonarc[np.maximum(lu, 0)], 0)
        chain = kn & is_arc & (lu >= -1) & (nonarc - before == 0)
        kn = kn.copy()
        kn[chain] = False
        ak = np.flatnonzero(is_arc & kn)
        first_arc = ak[:0]
    if len(first_arc):
        j = int(first_arc[0])
        raise InputError(f"the first block where every axis position is known is an arc "
                         f"(G{program.motion[j]}); its start ({_unknown_axes(program, j - 1) if j else ''} "
                         "unknown) cannot be compensated: state the start position or move "
                         "to the arc start first", program.filename, int(line[j]))
    geo = _arc_params(program, ak) if len(ak) else None
    if geo is not None:
        lin_res = max(res[geo.u.max()], res[geo.v.max()], res[geo.u.min()], res[geo.v.min()])
        if chordal_tol < 2 * lin_res:
            raise InputError(f"chordal tolerance {chordal_tol * 1e3:g} µm is below twice the axis "
                             f"resolution ({lin_res * 1e3:g} µm): arcs could not be written within it",
                             program.filename, field="chordal_tol")
    samp = _arc_samples(geo) if geo is not None else np.zeros((0, n_ax))
    kk = np.flatnonzero(kn)
    nk = len(kk)
    cb, cyc_pts = _cycle_points(program, kn)
    # (filled in place: no gathered copy of the positions when every block is compensated)
    Q = np.empty((nk + len(samp) + len(cyc_pts), n_ax))
    if nk == N:
        Q[:nk] = P
    else:
        np.take(P, kk, axis=0, out=Q[:nk])
    Q[nk:nk + len(samp)] = samp
    Q[nk + len(samp):] = cyc_pts
    rotated = has_rotation(program)
    if row_lines is not None or rotated:
        rl = np.concatenate([line[kk], np.repeat(line[ak], 4 * _n_samples(geo) - 1)
                             if geo is not None else np.zeros(0, np.int64), np.repeat(line[cb], 3)])
        if row_lines is not None:
            row_lines.append(rl)
    if rotated:
        # G68: positions are in the (unrotated) word frame, the transform in the reference frame
        transform = _Conjugated(program, transform)
        transform.blocks = np.searchsorted(line, rl)
    ns = len(samp)
    del samp
    cyc_q = Q[nk + ns:].copy()                                  # (the transform gets Q itself)
    Qt = _call_transform(transform, Q, own=True) if len(Q) else Q
    del Q
    St = Qt[nk:nk + ns].copy()                                    # arc samples
    cyc_delta = np.rint((Qt[nk + ns:] - cyc_q) / res)           # cycle points: A, R, bottom
    # new position = where the control reads the program + the rounded correction, so that a
    # transform that changes nothing changes no count (G91 increments finer than the resolution
    # included); rows not known stay where the program puts them
    off = np.asarray(program.offset)
    offc = np.rint(off / res).astype(np.int64) if off.any() else None
    Cc = _control_counts(program, res, offc)
    from . import cycle_counts                 # canned cycles: return levels, K/L repeats
    rep_rows = cycle_counts.stepped_rows(program)
    if cyc.any():
        Cc = cycle_counts.control_counts(program, Cc, res, rep_rows, offc)
    _refuse_unread_counts(program, Cc, kk, nk == N)
    if info is not None:
        info["read_deviation"] = _read_deviation(program, Cc, res)
    dK = np.subtract(Qt[:nk], P if nk == N else P[kk])         # (in place: no temporaries)
    np.divide(dK, res, out=dK)
    np.rint(dK, out=dK)
    if dK.any():
        _refuse_half_count_increments(program, res)
    if rotated:
        _check_rotation_centres(program, kk, dK)
    del Qt
    # C = Cc with the corrections, NaN (rows not known) 0, as int64: compiled in one pass
    C = _ctok.add_counts(Cc, dK, None if nk == N else kk)
    if C is None:
        if nk == N:
            Cc[1:] += dK
        else:
            Cc[1 + kk] += dK
        C = np.nan_to_num(Cc, copy=False, nan=0.0).astype(np.int64)    # (Cc is this function's own)
    del Cc
    prev, new = C[:N], C[1:]
    no_z = np.zeros(N, bool)
    kn_edit = kn
    if len(cb):
        no_z[cb] = True                           # a cycle's Z word is its depth
        dE = dK[np.searchsorted(kk, cb)].astype(np.int64)
        # the correction the initial level got (the block before the run; the start: none)
        before = np.asarray(program.cycle_data)[cb, 6].astype(np.int64) - 1
        dz0 = np.zeros(len(cb), np.int64)
        sel_ = before >= 0
        dz0[sel_] = dK[np.searchsorted(kk, before[sel_]), program.axes.index("Z")]
        expanded = _cycle_edits(ctx, program, cb, cyc_delta, dE, new, res, fm,
                                inc_=np.asarray(program.incremental), dz0=dz0)
        if program.cutter is not None and len(expanded) and (np.asarray(program.cutter)[expanded] > 0).any():
            j = int(expanded[np.argmax(np.asarray(program.cutter)[expanded] > 0)])
            raise InputError("this canned cycle must be written out as moves, but cutter radius "
                             "compensation (G41/G42) is active: refusing", program.filename,
                             int(line[j]))
        kn_edit = kn.copy()
        kn_edit[expanded] = False                 # written out as new lines instead
        if len(rep_rows):                         # their words stay (or the program is refused)
            kn_edit[cycle_counts.check(program, transform, rep_rows, kn, kk, dK, res, row_lines)] = False

    keep = np.ones(len(ak), bool)
    arc_cols = None
    if geo is not None:
        # an arc stays an arc where the compensated path is one within ``arc_tol`` (default:
        # the chordal tolerance); the others are linearised at the chordal tolerance
        keep, arc_cols = _arc_keep(program, geo, St, prev, new, res, fm,
                                   max(chordal_tol, arc_tol or 0.0), program.arc_tol, offc)
    del St
    lin = ak[~keep]
    cutter = program.cutter
    if cutter is not None and len(lin) and (np.asarray(cutter)[lin] > 0).any():
        j = int(lin[np.argmax(np.asarray(cutter)[lin] > 0)])
        # segments would change the control's offset path at every joint (and tiny ones raise
        # gouge alarms): an arc under G41/G42 is kept as an arc or refused
        raise InputError(f"the corrected arc is not an arc in the plane within the chordal "
                         f"tolerance (a tilt or a correction that is not rigid), so it would be "
                         f"written as line segments, but cutter radius compensation "
                         f"G{int(cutter[j])} is active: segments would change the offset path "
                         "the control computes; refusing (a larger --chordal-tol keeps arcs "
                         "that stay within it)", program.filename, int(line[j]))
    seg = None
    inner_rows = inner_pts = None
    if len(lin):
        seg = _linearisation_points(_subset(geo, ~keep), n_ax, chordal_tol)
        if len(seg.points):
            if row_lines is not None:
                row_lines.append(np.repeat(line[lin], seg.count))
            if rotated:
                transform.blocks = np.repeat(lin, seg.count)
            seg.counts = np.rint(_call_transform(transform, seg.points) / res).astype(np.int64)
        else:
            seg.counts = np.zeros((0, n_ax), np.int64)
        inner = seg.count > 0
        # the block itself goes to its first segment point; later points become new lines
        inner_rows, inner_pts = lin[inner], seg.counts[seg.first[inner]]

    inc = np.asarray(program.incremental)
    cw = np.asarray(program.col_word)
    if len(lin):
        cw = cw.copy()
        cw[lin, n_ax:] = -1          # removed arc words are no anchors for inserted words
    wv = np.asarray(program.w_value)
    # G16 polar blocks: their X Y are written as radius and angle (gcode.polar)
    from .polar import polar_edits
    pmask = polar_edits(ctx, program, cw, kn_edit, prev, new, res, fm, offc,
                        expanded if len(cb) else np.zeros(0, np.int64), _column_edits)
    nz_any = bool(no_z.any())
    for k, a in enumerate(axes):
        kn_edit_k = kn_edit if pmask is None else kn_edit & ~pmask[:, k]
        # compiled: one pass per axis (not for linearised arcs' first points or axes with
        # assumed work offsets: numpy below, as without the library)
        got = None
        if inner_rows is None and a not in program.offset_assumed:
            got = _ctok.axis_edits(C, k, inc, offc, cw, wv, INCH if inch_prog and a in LINEAR else 1.0,
                                   res[k], kn_edit_k, no_z if nz_any and a == "Z" else None)
        if got is not None:
            target, rep, ins = got
            _column_edits(ctx, cw, k, ctx.letter(a).encode(), fm[a], rep, ins, target)
            continue
        v = new[:, k]
        if inner_rows is not None:
            v = v.copy()
            v[inner_rows] = inner_pts[:, k]
        pv = prev[:, k]
        target = np.where(inc, v - pv, v if offc is None else v - offc[:, k])
        wk = cw[:, k]
        pres = wk >= 0
        ov = wv[np.maximum(wk, 0)]
        if inch_prog and a in LINEAR:
            ov = ov * INCH
        oc = np.rint(ov / res[k]).astype(np.int64)
        differs = target != oc
        if a in program.offset_assumed and ((pres & differs & kn_edit_k).any()
                                            or (~pres & (v != pv) & kn_edit_k).any()):
            j = int(np.argmax((pres & differs | ~pres & (v != pv)) & kn_edit_k))
            raise InputError(f"the compensation moves {a}, whose work offsets the program does not "
                             "all set (G10): give the work offsets", program.filename,
                             int(line[j]))
        _column_edits(ctx, cw, k, ctx.letter(a).encode(), fm[a], np.flatnonzero(pres & differs & kn_edit_k),
                      np.flatnonzero(~pres & (v != pv) & kn_edit_k & ~(no_z & (a == "Z"))), target)

    _g92_edits(ctx, program, kk, dK, res, fm, inch_prog)
    # the corrections, the compensated rows and the last axis' edit arrays are spent (80 MB at
    # 1 M blocks, held through the arc words' edits otherwise)
    dK = kk = got = target = rep = ins = None

    if arc_cols is not None:
        a_rep, a_ins, a_counts, a_fmt = arc_cols
        for j, letter in enumerate(ARC_WORDS):
            _column_edits(ctx, cw, n_ax + j, ctx.letter(letter).encode(), a_fmt[j],
                          np.flatnonzero(a_rep[:, j]), np.flatnonzero(a_ins[:, j]), a_counts[:, j])
    if len(lin):
        inv = np.asarray(program.inverse_time)[lin]
        if inv.any():
            raise InputError("this arc must be linearised under the transform, but the block is "
                             "in G93 inverse time feed: its segments would need new F words",
                             program.filename, int(line[lin[np.argmax(inv)]]))
        _linearise_edits(ctx, lin, seg, new, d_ax, m_ax, chordal_tol, offc)
    _restore_modal_arcs(ctx, lin)

    if info is not None:
        rep = getattr(ctx, "cycle_report", {"kept": 0, "expanded": 0})
        # the emitted end position of every block (counts of ``resolution``, reference frame):
        # what the control reads back from the written words (a linearised arc's last segment
        # ends at its end point); the caller can verify from these without re-reading the text
        # the step of each axis as decimals and multiple (mm, deg): inch programs' linear
        # words are steps of m * 10**-d inch, 254 * m * 10**-(d + 1) mm
        dec_e = [int(d) + (1 if inch_prog and a in LINEAR else 0) for a, d in zip(axes, d_ax)]
        mul_e = [int(m) * (254 if inch_prog and a in LINEAR else 1) for a, m in zip(axes, m_ax)]
        info.update(deferred=int(N - kn.sum()), linearised=int(len(lin)), compensated=kn,
                    cycles_kept=rep["kept"], cycles_expanded=rep["expanded"],
                    emitted=new, emitted_resolution=res, emitted_decimals=dec_e,
                    emitted_multiple=mul_e)
    ed = ctx.edits
    # the splice holds the output twice at its peak: free what the edits no longer need
    del C
    v = pv = target = wk = pres = ov = oc = differs = None      # the axis loop's last columns
    # and the arc words' (N, 4) columns, the last axis' edits, the compensated rows: their
    # edits are made (40-60 MB at 1 M blocks)
    arc_cols = a_rep = a_ins = a_counts = got = rep = ins = kk = seg = inner_pts = None
    ctx._anch = ctx._spaced = None
    text = ed.apply(ctx.data, progress=progress)
    if not as_bytes:
        text = text.decode("utf-8", "surrogateescape")
    added = np.zeros(N, np.int64)
    for k, n_add in ctx.added_lines.items():
        added[k] = n_add
    out_line = np.asarray(program.line) + np.cumsum(added)
    return text, out_line


def _check_rotation_centres(program, kk, dK):
    """A G68 without centre words turns about where the tool is: a correction of that block
    would move the centre the control uses, which the words cannot follow."""
    from .rotation import PLANE_AXES
    rot = program.rotation
    for j in np.unique(rot[:, 4][rot[:, 4] >= 0]).astype(int):
        b = int(np.argmax(rot[:, 4] == j))
        r = np.searchsorted(kk, j)
        if r < len(kk) and kk[r] == j:
            cols = [program.axes.index(a) for a in PLANE_AXES[int(program.plane[b])]]
            if dK[r, cols].any():
                raise InputError("G68 without a centre turns about the current position, which the "
                                 "compensation moves: write the centre on the G68 block",
                                 program.filename, int(rot[b, 3]))


class _Conjugated:
    """A reference-frame transform applied to word-frame rows of ``blocks`` (G68)."""

    def __init__(self, program, transform):
        self.program, self.transform, self.blocks = program, transform, None

    def __call__(self, q):
        return to_words(self.program, self.transform(to_reference(self.program, q, self.blocks)),
                        self.blocks)


class _KeepIdle:
    """A transform whose output keeps the input in the columns ``idle``."""

    def __init__(self, transform, idle):
        self.transform, self.idle = transform, idle

    def __call__(self, q):
        out = np.array(self.transform(q.copy()), dtype=float)
        if out.shape == q.shape:
            out[:, self.idle] = q[:, self.idle]
        return out


def _call_transform(transform, q, own: bool = False):
    """``transform(q)`` checked (shape, finite); ``own``: the caller does not read ``q`` again,
    so the transform gets it itself (which it may change) instead of a copy."""
    q = np.ascontiguousarray(q, dtype=float)
    out = np.asarray(transform(q if own else q.copy()), dtype=float)
    if out.shape != q.shape:
        raise ValueError(f"transform returned shape {out.shape}, expected {q.shape}")
    if not np.isfinite(out).all():
        i = int(np.argmax(~np.isfinite(out).all(axis=1)))
        raise ValueError(f"transform returned a non-finite value for point {i}: {q[i]}")
    return out


def _column_edits(ctx, cw, col, letter: bytes, fmt: tuple, rep_rows, ins_rows, counts):
    """Replace the number of word column ``col`` in blocks ``rep_rows`` and insert the word
    into blocks ``ins_rows``; ``counts`` (N,) in resolution units."""
    p = ctx.p
    decimals, mult = fmt
    if len(rep_rows):
        # compiled: texts, offsets and word spans of the replacements in one pass (no gathered
        # copies); the numpy path below without the library, and for the insertions
        got = _ctok.replace_edits(counts, rep_rows, mult, decimals, cw, col, p.w_num, p.w_end,
                                  ctx.edits.size)
        if got is not None:
            buf, pos, stop, off, ln = got
            ctx.edits.add_buffer(buf)
            ctx.edits.add(pos, stop, _SUB_REPLACE, off, ln)
            rep_rows = rep_rows[:0]
    rows = np.concatenate([rep_rows, ins_rows])
    if not len(rows):
        return
    # compiled formatter (same bytes), the numpy one without it or with MTCOMP_TOKENIZER=python
    buf, off, ln = _ctok.format_counts(counts[rows] * mult, decimals) or format_counts(counts[rows] * mult, decimals)
    off = off + ctx.edits.add_buffer(buf)
    nr = len(rep_rows)
    if nr:
        w = cw[rep_rows, col]
        ctx.edits.add(np.asarray(p.w_num)[w], np.asarray(p.w_end)[w], _SUB_REPLACE, off[:nr], ln[:nr])
    if len(ins_rows):
        _insert_words(ctx, cw, ins_rows, col, letter, off[nr:], ln[nr:])


def _insert_words(ctx, cw, rows, gcol, letter: bytes, off, ln):
    """Insert word ``letter``+number into blocks ``rows`` at its canonical place: before the
    next present axis/arc word, else after the previous one, else before the first F S T M P
    word, else after the last word of the block."""
    p = ctx.p
    wpos, wend = np.asarray(p.w_pos), np.asarray(p.w_end)
    # columns in canonical word order (X Y Z U V W A B C, then I J K R), whatever the machine's
    # chain order of the axes is
    n_ax = len(p.axes)
    perm = sorted(range(n_ax), key=lambda c: CANONICAL.index(p.axes[c])) + list(range(n_ax, n_ax + 4))
    allc = cw[rows][:, perm]
    gcol_sorted = perm.index(gcol)
    m = len(rows)
    r_ = np.arange(m)
    after, before = allc[:, gcol_sorted + 1:], allc[:, :gcol_sorted]
    has_next = (after >= 0).any(axis=1) if after.shape[1] else np.zeros(m, bool)
    nxt = after[r_, np.argmax(after >= 0, axis=1)] if after.shape[1] else np.full(m, -1)
    has_prev = (before >= 0).any(axis=1) if before.shape[1] else np.zeros(m, bool)
    rev = before[:, ::-1]
    prv = rev[r_, np.argmax(rev >= 0, axis=1)] if before.shape[1] else np.full(m, -1)
    tail, last_end, _ = ctx.anchors
    ft, le = tail[rows], last_end[rows]
    mode = np.where(has_next, 0, np.where(has_prev, 1, np.where(ft >= 0, 2, 3)))
    pos = np.select([mode == 0, mode == 1, mode == 2],
                    [wpos[np.maximum(nxt, 0)], wend[np.maximum(prv, 0)], ft], le)
    spl = ctx.spaced[rows].astype(np.int64)
    sp_off, _ = ctx.edits.const(b" ")
    let_off, _ = ctx.edits.const(letter)
    sub = _SUB_INSERT + 3 * gcol_sorted
    lead = (mode == 1) | (mode == 3)             # after a word: " X1.0"; before one: "X1.0 "
    ed = ctx.edits
    ed.add(pos[lead], pos[lead], sub, sp_off, spl[lead])
    ed.add(pos, pos, sub + 1, let_off, 1)
    ed.add(pos, pos, sub + 2, off, ln)
    ed.add(pos[~lead], pos[~lead], sub + 2, sp_off, spl[~lead])   # stable: after the number



def _fmt(c: int, d: int) -> str:
    s = str(abs(int(c))).rjust(d + 1, "0")
    s = f"{s[:len(s) - d]}.{s[len(s) - d:]}"
    return "-" + s if c < 0 else s


def _linearise_edits(ctx, lin, seg: _Segments, new, d_ax, m_ax, tol, offc=None):
    """Blocks of linearised arcs: G2/G3 -> G1, arc words out, a comment with the tolerance,
    and the remaining segment points as new lines after the block."""
    p, ed, data = ctx.p, ctx.edits, ctx.data
    axes = p.axes
    wpos, wend = np.asarray(p.w_pos), np.asarray(p.w_end)
    n_ax = len(axes)
    _, last_end, body = ctx.anchors
    spaced = ctx.spaced
    mw = np.asarray(p.motion_word)
    inc = np.asarray(p.incremental)
    motion = np.asarray(p.motion)
    cw = np.asarray(p.col_word)
    line_start, line_end = np.asarray(p.line_start), np.asarray(p.line_end)
    dtol = max(int(d_ax[axes.index(a)]) for a in "XYZ" if a in axes)
    pieces = []                      # (pos, stop, sub, bytes)
    at_line = []                     # per arc: (end of its line, line ending, word separator)
    for j, k in enumerate(lin):
        sp = " " if spaced[k] else ""
        g = int(motion[k])
        w = mw[k]
        if w >= 0:
            wn = int(p.w_num[w])
            old = p.data[wn:wend[w]]
            pieces.append((wn, wend[w], _SUB_REPLACE, b"01" if old in (b"02", b"03") else b"1"))
        else:
            pieces.append((body[k], body[k], _SUB_G, (ctx.letter("G") + "1" + sp).encode()))
        for c in range(4):
            wi = cw[k, n_ax + c]
            if wi >= 0:
                s = wpos[wi]
                ls = line_start[p.w_line[wi]]
                if s - 1 >= ls and data[s - 1] in (32, 9):
                    s -= 1
                pieces.append((s, wend[wi], _SUB_REPLACE, b""))
        pieces.append((last_end[k], last_end[k], _SUB_COMMENT,
                       f"{sp}(G{g} LINEARISED, CHORDAL TOLERANCE {tol:.{dtol}f} MM)".encode()))
        # later segment points as new lines: placed after the loop, formatted for all arcs at
        # once (_segment_lines; the per-word Python formatting was 86-89 % of a run with tables)
        le = line_end[p.line[k] - 1]
        eol = "\n"
        if le > line_start[p.line[k] - 1] and data[le - 1] == 13:
            le -= 1
            eol = "\r\n"
        at_line.append((le, eol, sp))
    texts, n_lines = _segment_lines(ctx, lin, seg, new, d_ax, m_ax, inc, offc, at_line)
    for j, k in enumerate(lin):
        if n_lines[j]:
            pieces.append((at_line[j][0], at_line[j][0], _SUB_LINES, texts[j]))
            ctx.added_lines[k] = int(n_lines[j])
    if pieces:
        buf = b"".join(pc[3] for pc in pieces)
        base = ed.add_buffer(np.frombuffer(buf, np.uint8))
        lens = np.array([len(pc[3]) for pc in pieces], np.int64)
        offs = base + np.cumsum(lens) - lens
        ed.add(np.array([pc[0] for pc in pieces]), np.array([pc[1] for pc in pieces]),
               np.array([pc[2] for pc in pieces]), offs, lens)


def _segment_lines(ctx, lin, seg: _Segments, new, d_ax, m_ax, inc, offc, at_line,
                   chunk: int = 100_000):
    """The new lines of every linearised arc: per arc the text (bytes: each line preceded by
    its line ending) and the number of lines, formatted for groups of arcs of about ``chunk``
    lines at once (the group's arrays are a few dozen bytes per line: bounded memory)."""
    lin = np.asarray(lin)
    lines = np.asarray(seg.count, np.int64) + 1
    group = np.cumsum(lines) // max(int(chunk), 1)
    cuts = np.flatnonzero(np.r_[True, group[1:] != group[:-1], True])
    texts, counts = [], []
    for a, b in zip(cuts[:-1], cuts[1:]):
        sub = _Segments(None, np.asarray(seg.first)[a:b], np.asarray(seg.count)[a:b], seg.counts)
        t, n = _segment_lines_group(ctx, lin[a:b], sub, new, d_ax, m_ax, inc, offc,
                                    at_line[a:b])
        texts += t
        counts.append(n)
    return texts, (np.concatenate(counts) if counts else np.zeros(0, np.int64))


def _segment_lines_group(ctx, lin, seg: _Segments, new, d_ax, m_ax, inc, offc, at_line):
    """`_segment_lines` of a group of arcs at once.  A line per segment point after the
    first, with the words of the axes that move (G91: the increments; else the positions in
    the block's frame), each number through the compiled formatter where built."""
    p = ctx.p
    n_ax = len(p.axes)
    m = len(lin)
    npts = np.asarray(seg.count, np.int64) + 1             # interior points and the end
    if not m or not npts.sum():
        return [b""] * m, np.zeros(m, np.int64)
    owner = np.repeat(np.arange(m), npts)
    start = np.cumsum(npts) - npts
    idx = np.arange(len(owner)) - np.repeat(start, npts)   # 0 .. npts-1 within the arc
    pts = np.empty((len(owner), n_ax), np.int64)
    inner = idx < np.repeat(npts - 1, npts)
    pts[inner] = seg.counts[np.repeat(seg.first, npts)[inner] + idx[inner]]
    pts[~inner] = new[np.asarray(lin)]
    # lines: points 1.. of each arc against the point before (a point equal to it is no line)
    li = np.flatnonzero(idx > 0)
    diff = pts[li] - pts[li - 1]
    moves = diff != 0
    keep = moves.any(axis=1)
    li, diff, moves = li[keep], diff[keep], moves[keep]
    arc = owner[li]
    k_of = np.asarray(lin)[arc]
    incr = np.asarray(inc)[k_of]
    vals = np.where(incr[:, None], diff, pts[li] if offc is None else pts[li] - offc[k_of])
    n_lines = np.bincount(arc, minlength=m)
    # the pieces of the text, in order: per line its ending, then per moving axis the separator
    # (not before the first word), the letter and the number
    chunks = []                          # byte buffers; pieces index into their concatenation
    base = 0

    def buffer(b: bytes | np.ndarray) -> int:
        nonlocal base
        b = np.frombuffer(b, np.uint8) if isinstance(b, bytes) else b
        chunks.append(b)
        base += len(b)
        return base - len(b)
    eols = [at_line[j][1].encode() for j in range(m)]
    seps = [at_line[j][2].encode() for j in range(m)]
    eol_off = {e: buffer(e) for e in set(eols)}
    sep_off = {sp: buffer(sp) for sp in set(seps)}
    line_eol = np.array([eol_off[eols[j]] for j in range(m)], np.int64)[arc]
    line_eol_len = np.array([len(eols[j]) for j in range(m)], np.int64)[arc]
    line_sep = np.array([sep_off[seps[j]] for j in range(m)], np.int64)[arc]
    line_sep_len = np.array([len(seps[j]) for j in range(m)], np.int64)[arc]
    L = len(li)
    # per (line, axis): letter, number; order within a line: axes in program order
    word_off = np.zeros((L, n_ax), np.int64)
    word_len = np.zeros((L, n_ax), np.int64)
    let_off = np.zeros((L, n_ax), np.int64)
    for a in range(n_ax):
        rows = np.flatnonzero(moves[:, a])
        if not len(rows):
            continue
        d = int(d_ax[a])
        got = _ctok.format_counts(vals[rows, a] * int(m_ax[a]), d) or \
            format_counts(vals[rows, a] * int(m_ax[a]), d)
        buf, off, ln = got
        b0 = buffer(np.asarray(buf, np.uint8))
        word_off[rows, a] = b0 + off
        word_len[rows, a] = ln
        let_off[rows, a] = buffer(ctx.letter(p.axes[a]).encode())
    # the pieces: (line, slot) with slot 0 the line ending, then 3 per axis (sep, letter, number)
    first_word = np.argmax(moves, axis=1)
    src = np.zeros((L, 1 + 3 * n_ax), np.int64)
    ln_ = np.zeros((L, 1 + 3 * n_ax), np.int64)
    src[:, 0], ln_[:, 0] = line_eol, line_eol_len
    for a in range(n_ax):
        mv = moves[:, a]
        sep = mv & (first_word != a)
        src[:, 1 + 3 * a] = line_sep
        ln_[:, 1 + 3 * a] = np.where(sep, line_sep_len, 0)
        src[:, 2 + 3 * a] = let_off[:, a]
        ln_[:, 2 + 3 * a] = np.where(mv, 1, 0)
        src[:, 3 + 3 * a] = word_off[:, a]
        ln_[:, 3 + 3 * a] = np.where(mv, word_len[:, a], 0)
    src, ln_ = src.ravel(), ln_.ravel()
    pool = np.concatenate(chunks)
    # the byte indices into the pool: runs of consecutive indices, one per piece, by a
    # cumulative sum of steps (np.repeat with varying counts costs twice as much)
    nz = ln_ > 0
    s_, l_ = src[nz], ln_[nz]
    total = int(l_.sum())
    gather = np.ones(total, np.int64)
    st = np.cumsum(l_) - l_
    gather[st[0]] = s_[0]
    gather[st[1:]] = s_[1:] - (s_[:-1] + l_[:-1] - 1)
    np.cumsum(gather, out=gather)
    text = pool[gather].tobytes()
    # per arc: its lines' bytes
    line_bytes = ln_.reshape(L, -1).sum(axis=1)
    arc_bytes = np.bincount(arc, weights=line_bytes, minlength=m).astype(np.int64)
    cut = np.concatenate([[0], np.cumsum(arc_bytes)])
    return [text[cut[j]:cut[j + 1]] for j in range(m)], n_lines


def _restore_modal_arcs(ctx, lin):
    """An arc block that relies on a modal G2/G3 after a linearised arc (now G1) gets its
    G2/G3 word written out."""
    p = ctx.p
    motion = np.asarray(p.motion)
    mw = np.asarray(p.motion_word)
    if not len(lin):
        return
    modal_arc = np.flatnonzero(((motion == 2) | (motion == 3)) & (mw < 0))
    if not len(modal_arc):
        return
    linflag = np.zeros(len(p), bool)
    linflag[lin] = True
    modal_arc = modal_arc[~linflag[modal_arc]]
    # lines with an explicit motion word
    wl, wlet, wv = np.asarray(p.w_line), np.asarray(p.w_letter), np.asarray(p.w_value)
    gm = (wlet == _ascii("G")) & np.isin(wv, (0, 1, 2, 3))
    glines = np.unique(wl[gm])
    blines = ctx.blines
    bl = blines[modal_arc]
    set_line = glines[np.maximum(np.searchsorted(glines, bl, side="right") - 1, 0)]
    lo = np.searchsorted(blines, set_line, side="left")
    cum = np.concatenate([[0], np.cumsum(linflag)])
    need = cum[modal_arc] - cum[lo] > 0
    rows = modal_arc[need]
    if not len(rows):
        return
    _, _, body = ctx.anchors
    sp = ctx.spaced[rows]
    for g in (2, 3):
        for s in (True, False):
            sel = (motion[rows] == g) & (sp == s)
            if sel.any():
                off, ln = ctx.edits.const(f"{ctx.letter('G')}{g}{' ' if s else ''}".encode())
                ctx.edits.add(body[rows[sel]], body[rows[sel]], _SUB_G, off, ln)


# ---------------------------------------------------------------------------------------------
# canned cycles

#: cycles that can be written out as moves: (feed out instead of rapid, dwell at the bottom)
_EXPANDABLE = {81: (False, False), 82: (False, True), 85: (True, False), 89: (True, True),
               73: (False, True), 83: (False, True)}
#: pecking cycles written out: the G73 chip-breaking retract and the G83 re-approach above the
#: last depth (mm), which controls take from a parameter (Fanuc 5114/5115, Haas setting 22) the
#: program does not carry; at most half the peck Q so that a retract never reaches the last
#: depth minus Q and a re-approach always stops in the hole already drilled
PECK_CLEARANCE = 0.5
#: most pecks written out for one hole
MAX_PECKS = 10000


def _peck_levels(r_lvl, bottom, q, code, *, filename, line):
    """The moves of one pecking hole below the R level (mm, reference frame) as (rapid?, Z):
    G83 back to R after each peck and rapid down to the clearance above the last depth, G73 a
    short retract of the clearance; each peck Q deeper until the bottom."""
    if not (np.isfinite(q) and q > 0):
        raise InputError(f"canned cycle G{code} without a peck depth Q > 0: cannot be written out "
                         "as moves", filename, line)
    n = int(np.ceil((r_lvl - bottom) / q - 1e-9))
    if n > MAX_PECKS:
        raise InputError(f"canned cycle G{code}: {n} pecks of Q{q:g} mm in one hole: more than "
                         f"{MAX_PECKS} written out", filename, line)
    c = min(PECK_CLEARANCE, q / 2)
    levels = [max(r_lvl - (i + 1) * q, bottom) for i in range(max(n, 1))]
    moves = []
    for i, z in enumerate(levels):
        if i:
            moves.append((True, levels[i - 1] + c))       # G83: down to the clearance; G73: up
        moves.append((False, z))
        if code == 83 and i < len(levels) - 1:
            moves.append((True, r_lvl))
    return moves


def _cycle_points(program: Program, kn):
    """Known cycle blocks and their points to transform: the hole at the level the tool
    arrives at (A), the R level and the bottom, 3 rows per block."""
    cyc = np.asarray(program.cycle)
    cb = np.flatnonzero((cyc > 0) & kn)
    n_ax = program.n_axes
    if not len(cb):
        return cb, np.zeros((0, n_ax))
    zk = program.axes.index("Z")
    P = np.asarray(program.position)
    data = np.asarray(program.cycle_data)
    pts = np.repeat(P[cb], 3, axis=0)
    za = np.where(cb > 0, P[np.maximum(cb - 1, 0), zk], data[cb, 0])
    za = np.where(np.isfinite(za) & kn[np.maximum(cb - 1, 0)], za, data[cb, 1])
    pts[0::3, zk] = za
    pts[1::3, zk] = data[cb, 1]
    pts[2::3, zk] = data[cb, 2]
    return cb, pts


def _cycle_edits(ctx, program, cb, delta, dE, new, res, fm, inc_, dz0=None):
    """Canned cycles under the transform.  Where the correction is the same at the hole's
    levels (a rigid shift there) the cycle stays: X Y as for any block, R and the depth Z shifted
    by the correction (G90) or kept (G91, relative).  Elsewhere the holes of the run are written
    out as moves (G81 G82 G85 G89) or refused (tapping, boring, peck cycles).  What was done is
    recorded in ``ctx.cycle_report``."""
    p = ctx.p
    zk = p.axes.index("Z")
    data = np.asarray(p.cycle_data)
    cyc = np.asarray(p.cycle)
    d = delta.reshape(len(cb), 3, -1)
    rigid = np.all(d == dE[:, None, :], axis=(1, 2))
    # runs: consecutive cycle blocks (G80 or another block ends a run)
    run_id = np.cumsum(np.r_[True, (np.diff(cb) > 1) | (data[cb[1:], 0] != data[cb[:-1], 0])])
    report = ctx.cycle_report = {"kept": 0, "expanded": 0}
    expanded = []
    letter_z, letter_r = ctx.letter("Z").encode(), ctx.letter("R").encode()
    dz, mz = fm["Z"]
    for r in np.unique(run_id):
        sel = np.flatnonzero(run_id == r)
        rows = cb[sel]
        if rigid[sel].all():
            # holes: a block repeated by K/L drills that many
            report["kept"] += int(np.asarray(p.cycle_repeat)[rows].sum()) if p.cycle_repeat is not None else len(rows)
            d0 = dz0[sel] if dz0 is not None else np.zeros(len(sel), np.int64)
            _cycle_shift(ctx, p, rows, dE[sel, zk], res[zk], (dz, mz), letter_z, letter_r, inc_, d0)
            # G98 returns to the initial level the control has (its block's correction)
            g98 = data[rows, 5] == 98
            new[rows[g98], zk] -= dE[sel[g98], zk] - d0[g98]
            continue
        code = int(cyc[rows[0]])
        rep = p.cycle_repeat
        if rep is not None and (np.asarray(rep)[rows] > 1).any():
            bad = rows[np.argmax(np.asarray(rep)[rows] > 1)]
            raise InputError(f"canned cycle G{int(cyc[bad])} with repeat count {int(rep[bad])}: the "
                             "correction is not the same at the hole's levels (not a rigid shift), "
                             "and repeated holes are not written out as moves", p.filename,
                             int(p.line[bad]))
        if any(int(cyc[k]) not in _EXPANDABLE for k in rows):
            bad = next(k for k in rows if int(cyc[k]) not in _EXPANDABLE)
            raise InputError(f"canned cycle G{int(cyc[bad])}: the correction is not the same at the "
                             "hole's levels (not a rigid shift), and this cycle (tapping, boring or "
                             "pecking) cannot be written out as moves without the control's "
                             "parameters", p.filename, int(p.line[bad]))
        report["expanded"] += len(rows)
        expanded.extend(rows.tolist())
        _cycle_expand(ctx, p, rows, sel, d, new, res, fm, code)
    return np.asarray(expanded, np.int64)


def _cycle_shift(ctx, p, rows, dzc, rz, fmt, letter_z, letter_r, inc_, dz0=None):
    """Rigid case: R and depth words shifted by the Z correction in G90 (inserted where the
    block relies on the modal value and the correction changed)."""
    wv = np.asarray(p.w_value)
    data = np.asarray(p.cycle_data)
    cz, cr = _cycle_words(p, rows)
    scale = 25.4 if np.asarray(p.inch).any() else 1.0
    modal = {}
    _, last_end, _ = ctx.anchors
    for i, k in enumerate(rows):
        for w, col, letter, val in ((cr[i], 3, letter_r, data[k, 3]), (cz[i], 4, letter_z, data[k, 4])):
            # G90: shifted by the correction; G91: R from the initial level, shifted by the
            # difference of the corrections there and at the hole; Z (from R) as written
            shift = dzc[i] if not inc_[k] else (dzc[i] - dz0[i] if col == 3 and dz0 is not None else 0)
            want = int(np.rint(val / rz) + shift)
            if w >= 0:
                if want != int(np.rint(wv[w] * scale / rz)):
                    _replace_number(ctx, w, want, fmt)
            elif modal.get(col, int(np.rint(val / rz))) != want:
                # the modal value in the control: the last one written in this run, or the
                # program's own where it came from a block left as it was
                _insert_text(ctx, last_end[k], b" " + letter + _number(want, fmt))
            modal[col] = want


def _cycle_words(p, rows):
    """Word indices of the cycle's Z (depth) and R words per block (-1 where absent)."""
    wl, wlet = np.asarray(p.w_line), np.asarray(p.w_letter)
    lines = np.asarray(p.line)[rows] - 1
    out_z, out_r = np.full(len(rows), -1), np.full(len(rows), -1)
    for i, ln in enumerate(lines):
        lo, hi = np.searchsorted(wl, ln), np.searchsorted(wl, ln, side="right")
        for w in range(lo, hi):
            if wlet[w] == 25:
                out_z[i] = w
            elif wlet[w] == 17:
                out_r[i] = w
    return out_z, out_r


def _number(count: int, fmt) -> bytes:
    d, m = fmt
    buf, off, ln = format_counts(np.array([count * m]), d)
    return buf[off[0]:off[0] + ln[0]].tobytes()


def _replace_number(ctx, w, count, fmt):
    t = _number(count, fmt)
    off, ln = ctx.edits.const(t)
    ctx.edits.add([int(ctx.p.w_num[w])], [int(ctx.p.w_end[w])], _SUB_REPLACE, off, ln)


def _insert_text(ctx, pos, text: bytes, sub=_SUB_COMMENT - 1):
    off, ln = ctx.edits.const(text)
    ctx.edits.add([int(pos)], [int(pos)], sub, off, ln)


def _cycle_expand(ctx, p, rows, sel, d, new, res, fm, code):
    """Write the holes of a run out as moves: the cycle's words come out of each block, and
    after it lines G0 to the hole, G0 to R, G1 to the bottom (G4 dwell), out to R (G0, or G1
    for G85 G89) and, for G98, G0 to the initial level; all compensated points."""
    P = np.asarray(p.position)
    data = np.asarray(p.cycle_data)
    wl, wlet = np.asarray(p.w_line), np.asarray(p.w_letter)
    wv = np.asarray(p.w_value)
    axes = p.axes
    zk = axes.index("Z")
    n_ax = len(axes)
    spaced = ctx.spaced
    _, last_end, _ = ctx.anchors
    line_start, line_end = np.asarray(p.line_start), np.asarray(p.line_end)
    data_b = ctx.data
    inch = 25.4 if np.asarray(p.inch).any() else 1.0
    feed = np.asarray(p.feed)
    pre_mode = int(np.asarray(p.motion)[rows[0] - 1]) if rows[0] > 0 else -1
    q_modal = np.nan
    for i, k in enumerate(rows):
        ln = int(p.line[k]) - 1
        lo, hi = np.searchsorted(wl, ln), np.searchsorted(wl, ln, side="right")
        dwell = b""
        for w in range(lo, hi):
            c = chr(65 + int(wlet[w]))
            gcyc = c == "G" and int(round(wv[w] * 10)) in range(730, 900)
            if c in "XYZRPFQ" or c in axes or gcyc:
                if c == "Q":
                    q_modal = float(wv[w]) * inch       # Q is modal in the cycle
                if c == "P":
                    dwell = bytes(data_b[p.w_pos[w]:p.w_end[w]])
                s0 = int(p.w_pos[w])
                if s0 - 1 >= line_start[ln] and data_b[s0 - 1] in (32, 9):
                    s0 -= 1
                ctx.edits.add([s0], [int(p.w_end[w])], _SUB_REPLACE, 0, 0)
        sp = " " if spaced[k] else ""
        j = sel[i]
        pts = np.repeat(P[k][None], 3, axis=0)
        pts[:, zk] = [P[k - 1, zk] if k > 0 and np.isfinite(P[k - 1, zk]) else data[k, 1], data[k, 1], data[k, 2]]
        cnt = np.rint(pts / res).astype(np.int64) + d[j].astype(np.int64)
        end = new[k]
        feed_out, has_dwell = _EXPANDABLE[int(p.cycle[k])]

        def words(c):
            return sp.join(ctx.letter(axes[a]) + _number(int(c[a]), fm[axes[a]]).decode()
                           for a in range(n_ax))
        g = lambda n: ctx.letter("G") + str(n)  # noqa: E731
        f = f"{sp}{ctx.letter('F')}{feed[k] / inch:g}" if np.isfinite(feed[k]) else ""
        out = [f"{g(90)}{sp}{g(0)}{sp}{words(cnt[0])}", f"{g(0)}{sp}{words(cnt[1])}"]
        code_k = int(p.cycle[k])
        if code_k in (73, 83):
            # pecks: points on the compensated line from R to the bottom, at the fraction of
            # the programmed depth (the straight feed of a G81 passes the same points)
            r_lvl, bottom = data[k, 1], data[k, 2]
            last = ""
            for rapid, z in _peck_levels(r_lvl, bottom, q_modal, code_k, filename=p.filename,
                                         line=ln + 1):
                t = (r_lvl - z) / (r_lvl - bottom) if r_lvl != bottom else 1.0
                c_z = np.rint(cnt[1] + t * (cnt[2] - cnt[1])).astype(np.int64)
                mode_ = g(0) if rapid else g(1)
                out.append(f"{mode_}{sp}{words(c_z)}" + ("" if rapid or last == "f" else f))
                last = "f" if not rapid else last
        else:
            out.append(f"{g(1)}{sp}{words(cnt[2])}{f}")
        if has_dwell and dwell:
            out.append(f"{g(4)}{sp}{dwell.decode()}")
        out.append(f"{g(1 if feed_out else 0)}{sp}{words(cnt[1])}")
        if data[k, 5] == 98:
            out.append(f"{g(0)}{sp}{words(end)}")
        if np.asarray(p.incremental)[k]:
            out.append(g(91))
        if i == len(rows) - 1 and pre_mode in (0, 1):
            out.append(g(pre_mode))
        if i == 0:
            _insert_text(ctx, last_end[k], f"{sp}(G{code} WRITTEN OUT AS MOVES: THE CORRECTION IS NOT "
                         "A RIGID SHIFT AT THE HOLES)".encode())
        le = int(line_end[ln])
        eol = "\n"
        if le > line_start[ln] and data_b[le - 1] == 13:
            le -= 1
            eol = "\r\n"
        _insert_text(ctx, le, "".join(eol + o for o in out).encode(), sub=_SUB_LINES)
        ctx.added_lines[k] = ctx.added_lines.get(k, 0) + len(out)


def _g92_edits(ctx, program, kk, dK, res, fm, inch_prog):
    """G92 names the coordinates of the point where the tool stands.  In the output the tool
    stands at the compensated point, so each G92 axis word gets that point's correction (the
    last block before it; none before the first block or after a deferred one): the G92 shift
    the control then sets is the program's own, and later absolute words, compensated against
    the program's shift, are not corrected a second time."""
    p = program
    wl, wv = np.asarray(p.w_letter), np.asarray(p.w_value)
    g92_lines = np.unique(np.asarray(p.w_line)[(wl == ord("G") - 65) & (wv == 92.0)])
    if not len(g92_lines) or not len(kk):
        return
    line = np.asarray(p.line)
    delta = np.zeros((len(line), len(p.axes)), np.int64)
    delta[kk] = dK.astype(np.int64)
    col = {ord(a) - 65: k for k, a in enumerate(p.axes) if len(a) == 1}
    for L in g92_lines.tolist():
        j = int(np.searchsorted(line, L + 1)) - 1          # the block the tool stands at
        if j < 0 or not delta[j].any():
            continue
        if has_rotation(p):
            raise InputError("G92 under a coordinate rotation with a correction at its point: "
                             "not supported, refusing", p.filename, L + 1)
        for w in np.flatnonzero((np.asarray(p.w_line) == L) & np.isin(wl, list(col))).tolist():
            k = col[int(wl[w])]
            if delta[j, k] == 0:
                continue
            v = wv[w] * (INCH if inch_prog and p.axes[k] in LINEAR else 1.0)
            _replace_number(ctx, w, int(np.rint(v / res[k])) + int(delta[j, k]), fm[p.axes[k]])
