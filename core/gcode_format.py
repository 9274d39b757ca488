"""Vectorised text primitives for NC programs: decimal parsing, fixed-point formatting and
byte-splicing of a text with many small edits.

These work on whole programs at once with numpy so that a million-line program costs a few
numpy passes instead of a million Python-level operations.  numpy has no fast parser for
decimal substrings scattered in a byte buffer (``np.fromstring``/``loadtxt`` cost about
0.3 us per number here) and no vectorised fixed-point formatter, so both are written here.
"""
from __future__ import annotations

import numpy as np

#: Powers of ten as exact float64 (10**22 is the largest exactly representable one).
_POW10 = 10.0 ** np.arange(23)
#: Significant digits that fit exactly into a float64 mantissa.
MAX_EXACT_DIGITS = 15


def parse_decimals(buf: np.ndarray, start: np.ndarray, end: np.ndarray,
                   chunk: int = 1 << 18) -> np.ndarray:
    """Values of the decimal numbers ``buf[start[i]:end[i]]`` (float64, correctly rounded).

    Each run must already be validated as ``[+-]?digits[.digits]`` with at least one digit and at
    most ``MAX_EXACT_DIGITS`` digits.  The run is right-aligned in a fixed-width window; the digit
    matrix times a vector of powers of ten gives the integer mantissa exactly (treating the point
    as a zero digit), from which the point is removed arithmetically, and one correctly rounded
    division by 10**decimals gives the value -- the same result as ``float(text)``.
    """
    n = len(start)
    out = np.empty(n, np.float64)
    if n == 0:
        return out
    start = np.asarray(start, np.int64)
    end = np.asarray(end, np.int64)
    length = end - start
    width = int(length.max())
    win = np.lib.stride_tricks.sliding_window_view(buf, width)
    col = np.arange(width)
    weights = _POW10[width - 1 - col]
    # digits after the point, from the positions of the points (one pass over the buffer)
    dots = np.flatnonzero(buf == 46)
    q = np.zeros(n, np.int64)
    if len(dots):
        run = np.searchsorted(end, dots, side="right")
        ok = run < n
        run, dots = run[ok], dots[ok]
        ok = start[run] <= dots
        q[run[ok]] = end[run[ok]] - dots[ok] - 1
    hasdot = np.zeros(n, bool)
    if len(dots):
        hasdot[run[ok]] = True
    first = np.maximum(end - width, 0)
    shift_short = end - width < 0                     # runs too close to the buffer start
    for lo in range(0, n, chunk):
        hi = min(n, lo + chunk)
        d = win[first[lo:hi]] - np.uint8(48)
        if shift_short[lo:hi].any():
            # only possible for the first few runs: rebuild their windows by hand
            for i in np.flatnonzero(shift_short[lo:hi]):
                row = np.full(width, 32, np.uint8)
                seg = buf[start[lo + i]:end[lo + i]]
                row[width - len(seg):] = seg
                d[i] = row - np.uint8(48)
        keep = (d < 10) & (col[None, :] >= (width - length[lo:hi])[:, None])
        d *= keep
        big = np.einsum("ij,j->i", d, weights)         # the point counts as a digit 0
        ql = q[lo:hi]
        low = np.fmod(big, _POW10[ql])                 # digits after the point
        mant = np.where(hasdot[lo:hi], (big - low) / 10.0 + low, big)
        out[lo:hi] = mant / _POW10[ql]
    neg = buf[start] == 45
    out[neg] = -out[neg]
    return out


def format_counts(counts: np.ndarray, decimals: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fixed-point text of ``counts * 10**-decimals`` without exponent and without "-0".

    Returns ``(buffer, offset, length)``: the text of value i is
    ``buffer[offset[i]:offset[i] + length[i]]`` (ASCII).  A point is always written (``12.`` for
    zero decimals) so the control never reads the number in least-input increments.
    """
    counts = np.asarray(counts, np.int64).ravel()
    d = int(decimals)
    n = len(counts)
    if n == 0:
        return np.zeros(0, np.uint8), np.zeros(0, np.int64), np.zeros(0, np.int64)
    a = np.abs(counts)
    ndig = max(len(str(int(a.max()))), d + 1)
    width = ndig + 2                                   # sign + digits + point
    rows = np.empty((n, width), np.uint8)
    r = a
    for k in range(ndig):
        r, digit = np.divmod(r, 10)
        col = width - 1 - k if k < d else width - 2 - k
        rows[:, col] = digit
    rows[:, 1:] += 48
    rows[:, width - 1 - d] = 46
    ipart = a // (10 ** d)
    nint = np.ones(n, np.int64)
    for k in range(1, ndig - d):
        nint += ipart >= 10 ** k
    neg = counts < 0
    length = d + 1 + nint + neg
    offset = np.arange(n, dtype=np.int64) * width + (width - length)
    flat = rows.ravel()
    flat[offset[neg]] = 45
    return flat, offset, length


def splice(orig: np.ndarray, pos: np.ndarray, stop: np.ndarray, sub: np.ndarray,
           src: np.ndarray, src_off: np.ndarray, src_len: np.ndarray,
           chunk_bytes: int = 1 << 24, progress=None) -> bytes:
    """Apply edits to a byte buffer in one vectorised pass.

    Edit i removes ``orig[pos[i]:stop[i]]`` (nothing if equal) and puts ``src[src_off[i]:
    src_off[i] + src_len[i]]`` there.  Edits at the same position are applied in ``sub`` order;
    removed ranges must not overlap.  The output is gathered in chunks of about
    ``chunk_bytes`` so the index arrays stay small.
    """
    pos = np.asarray(pos, np.int64)
    if len(pos) == 0:
        return orig.tobytes()
    order = np.lexsort((sub, pos))
    pos, stop = pos[order], np.asarray(stop, np.int64)[order]
    src_off, src_len = np.asarray(src_off, np.int64)[order], np.asarray(src_len, np.int64)[order]
    prev_end = np.concatenate([[0], np.maximum.accumulate(stop)[:-1]])
    if np.any(pos < prev_end):
        raise AssertionError("overlapping edits")  # a programming error, never user input
    n_orig = len(orig)
    buf = np.concatenate([orig, src])
    # pieces: original chunk before edit i, then edit i; then the tail
    p_off = np.empty(2 * len(pos) + 1, np.int64)
    p_len = np.empty(2 * len(pos) + 1, np.int64)
    p_off[0:-1:2] = prev_end
    p_len[0:-1:2] = pos - prev_end
    p_off[1::2] = src_off + n_orig
    p_len[1::2] = src_len
    tail = int(stop.max())
    p_off[-1] = tail
    p_len[-1] = n_orig - tail
    keep = p_len > 0
    p_off, p_len = p_off[keep], p_len[keep]
    out_end = np.cumsum(p_len)
    total = int(out_end[-1]) if len(out_end) else 0
    out = np.empty(total, np.uint8)
    out_start = out_end - p_len
    first = 0
    npieces = len(p_len)
    while first < npieces:
        last = int(np.searchsorted(out_end, out_start[first] + chunk_bytes, side="left")) + 1
        last = min(max(last, first + 1), npieces)
        o0 = int(out_start[first])
        o1 = int(out_end[last - 1])
        shift = np.repeat(p_off[first:last] - (out_start[first:last] - o0), p_len[first:last])
        shift += np.arange(o1 - o0)
        out[o0:o1] = buf[shift]
        first = last
        if progress is not None:
            progress(o1, total)
    return out.tobytes()
