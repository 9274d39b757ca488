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


_ONES = np.uint64(0xFFFFFFFFFFFFFFFF)
_POW10_U64 = np.array([10 ** k for k in range(20)], np.uint64)


def _digits8(padded: np.ndarray, end: np.ndarray, length: np.ndarray) -> np.ndarray:
    """Integer value of the digit strings of ``length`` <= 8 characters ending at ``end``
    (exclusive, indices into ``padded`` which has 8 leading pad bytes), by SWAR arithmetic on one
    uint64 per number (the classic eight-digits-at-once reduction)."""
    win = np.lib.stride_tricks.sliding_window_view(padded, 8)
    x = np.ascontiguousarray(win[end]).view("<u8").ravel()      # rows end at `end` (+8 pad)
    shift = (8 * (8 - np.minimum(length, 8))).astype(np.uint64)
    keep = np.where(length > 0, _ONES << np.minimum(shift, np.uint64(63)), np.uint64(0))
    keep = np.where(shift == 64, np.uint64(0), keep)
    x = (x & keep) & np.uint64(0x0F0F0F0F0F0F0F0F)
    x = x * np.uint64(10) + (x >> np.uint64(8))
    m = np.uint64(0x000000FF000000FF)
    x = (((x & m) * np.uint64(100 + (1000000 << 32)))
         + (((x >> np.uint64(16)) & m) * np.uint64(1 + (10000 << 32)))) >> np.uint64(32)
    return x


def parse_decimals(buf: np.ndarray, start: np.ndarray, end: np.ndarray, dot: np.ndarray,
                   first: np.ndarray | None = None, chunk: int = 1 << 16) -> np.ndarray:
    """Values of the decimal numbers ``buf[start[i]:end[i]]`` (float64, correctly rounded).

    Each run must already be validated as ``[+-]?digits[.digits]`` with at least one digit;
    ``dot`` is the position of its point (-1 if none), ``first`` may pass ``buf[start]``.
    Integer and fraction digits (up to 8 each) are converted eight at a time in uint64
    arithmetic, combined into an exact integer mantissa and divided once by 10**decimals, which
    rounds correctly -- the same value as ``float(text)``.  Longer numbers go through ``float``.
    Works in chunks so that the temporaries stay in the cache.
    """
    n = len(start)
    out = np.empty(n, np.float64)
    if n == 0:
        return out
    padded = np.concatenate([np.full(8, 32, np.uint8), buf])
    start = np.asarray(start, np.int64)
    end = np.asarray(end, np.int64)
    dot = np.asarray(dot, np.int64)
    first = buf[start] if first is None else first
    long_all = []
    for lo in range(0, n, chunk):
        hi = min(n, lo + chunk)
        s, e, d, f = start[lo:hi], end[lo:hi], dot[lo:hi], first[lo:hi]
        neg = f == 45
        istart = s + (neg | (f == 43))
        hasdot = d >= 0
        iend = np.where(hasdot, d, e)
        ilen = iend - istart
        flen = np.where(hasdot, e - d - 1, 0)
        long_ = (ilen > 8) | (flen > 8) | (ilen + flen > 15)
        if long_.any():
            long_all.append(np.flatnonzero(long_) + lo)
            flen = np.minimum(flen, 19)
        mant = _digits8(padded, iend, ilen) * _POW10_U64[flen] + _digits8(padded, e, flen)
        val = mant.astype(np.float64)
        val /= _POW10[flen]
        np.negative(val, out=val, where=neg)
        out[lo:hi] = val
    for i in (np.concatenate(long_all) if long_all else ()):
        out[i] = float(buf[start[i]:end[i]].tobytes())
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


def decimal_step(decimals: int, multiple: int) -> tuple[int, int]:
    """The step ``multiple * 10**-decimals`` with the fewest decimals (5000 * 10**-7 ->
    (4, 5)): the same number, the form `decimal_values` needs for its 2**53 bound."""
    d, m = int(decimals), int(multiple)
    while d > 0 and m % 10 == 0:
        m //= 10
        d -= 1
    return d, m


def _compiled_decimal_values(counts, steps, resolution, inplace: bool):
    """`decimal_values` by the compiled pass (two passes over the rows, none per column), or
    None (no library, counts not a C-ordered (N, n) int64/float64 array)."""
    from . import _ctok
    if not (isinstance(counts, np.ndarray) and counts.ndim == 2 and counts.flags.c_contiguous
            and counts.dtype in (np.int64, np.float64) and counts.shape[1] == len(steps)):
        return None
    n_col = counts.shape[1]
    out = None
    if inplace and counts.flags.writeable:
        out = counts.view(np.float64)
    mult = [float(m) for _, m in steps]
    p10 = [float(_POW10[d]) for d, _ in steps]
    res = [float(np.ravel(resolution)[j]) for j in range(n_col)]
    return _ctok.decimal_values(counts, mult, p10, res, out)


def _float_in_place(a):
    """``a`` (a writable, C-contiguous int64 or float64 array, handed over by the caller) as
    float64 over its own memory (int64 converted chunk by chunk, each chunk read before it is
    written: the values of ``a.astype(float)``), or None for other arrays."""
    if not (isinstance(a, np.ndarray) and a.flags.c_contiguous and a.flags.writeable):
        return None
    if a.dtype == np.float64:
        return a
    if a.dtype != np.int64:
        return None
    flat, out = a.reshape(-1), a.view(np.float64)
    fout = out.reshape(-1)
    step = 1 << 16
    for s in range(0, len(flat), step):
        fout[s:s + step] = flat[s:s + step].astype(np.float64)
    return out


def decimal_values(counts, decimals, multiples, resolution, inplace: bool = False) -> np.ndarray:
    """The numbers (mm, deg) that words of ``counts`` (N, n_axes; NaN where unknown) steps of
    ``multiples[k] * 10**-decimals[k]`` say, as a control reads them: the decimal value
    correctly rounded, (count * m) / 10**d, an exact integer over an exact power of ten.
    count * resolution is off by an ulp where the step is no binary fraction (3050000 * 1e-5
    is 30.500000000000004, the word C30.5 is 30.5).  Where count * m reaches 2**53 the
    division is not exact either and the product with ``resolution[k]`` (the step as a float)
    is kept.  ``inplace``: the result written over ``counts`` itself (an int64 array becomes
    the float64 array of the same bytes, converted in chunks; a float64 array is scaled where it
    is): no second (N, n_axes) array at the caller's peak; the caller must not use ``counts``
    afterwards.  Other arrays, and without ``inplace``, a new array."""
    steps = [decimal_step(d, m) for d, m in zip(decimals, multiples)]
    got = _compiled_decimal_values(counts, steps, resolution, inplace)
    if got is not None:
        return got
    out = _float_in_place(counts) if inplace else None
    if out is None:
        out = np.array(counts, float)                 # (always a new array: scaled in place)
    for j, (d, m) in enumerate(steps):
        col = out[..., j]
        if np.nanmax(np.abs(col), initial=0.0) * m >= 2.0 ** 53:
            col *= float(np.ravel(resolution)[j])
            continue
        if m != 1:
            col *= float(m)
        col /= _POW10[d]
    return out


def splice(orig: np.ndarray, pos: np.ndarray, stop: np.ndarray, sub: np.ndarray,
           src: np.ndarray, src_off: np.ndarray, src_len: np.ndarray,
           chunk_bytes: int = 1 << 24, progress=None) -> bytes | bytearray:
    """Apply edits to a byte buffer (bytes, or a bytearray from the compiled splice).

    Edit i removes ``orig[pos[i]:stop[i]]`` (nothing if equal) and puts ``src[src_off[i]:
    src_off[i] + src_len[i]]`` there.  Edits at one position are applied in ``sub`` order (then
    in the order given); removed ranges must not overlap.

    Replacements by text of the same length (the common case: a changed coordinate keeps its
    width) are written in place, grouped by length, one row copy per edit.  What remains is
    spliced by joining slices when there are few pieces, else by one vectorised gather in chunks
    of about ``chunk_bytes`` output bytes.
    """
    pos = np.asarray(pos)
    if len(pos) == 0:
        return orig.tobytes()
    stop, sub = np.asarray(stop), np.asarray(sub)
    src_off, src_len = np.asarray(src_off), np.asarray(src_len)
    # the copy lives in a bytearray, returned as it is when every edit is in place (no copy
    # into bytes: the output of a large program is tens of MB); room for the result, so that
    # the compiled splice works in place (one output buffer at the peak, not two)
    n_orig = len(orig)
    total = n_orig - int((stop - pos).sum(dtype=np.int64)) + int(src_len.sum(dtype=np.int64))
    ba = bytearray(max(n_orig, total))
    out = np.frombuffer(ba, np.uint8, count=n_orig) if n_orig else np.zeros(0, np.uint8)
    out[:] = orig
    from ._ctok import overwrite_same
    rest = overwrite_same(out, src, pos, stop, src_off, src_len)     # compiled: one pass
    if rest is not None:
        pos, stop, sub, src_off, src_len = pos[rest], stop[rest], sub[rest], src_off[rest], src_len[rest]
        same = np.zeros(0, bool)
    else:
        same = (stop - pos == src_len) & (src_len > 0)
    if same.any():
        from ._ctok import overwrite as c_overwrite
        every = bool(same.all())                 # (then no copies of the edit arrays)
        if not c_overwrite(out, src, *((pos, src_off, src_len) if every else
                                       (pos[same], src_off[same], src_len[same]))):   # compiled: memcpy each
            lens = src_len[same]
            for L in np.flatnonzero(np.bincount(lens)).tolist():
                g = np.flatnonzero(same)[lens == L]
                dst = np.lib.stride_tricks.as_strided(out, shape=(len(out) - L + 1, L), strides=(1, 1))
                srcw = np.lib.stride_tricks.sliding_window_view(src, L)
                dst[pos[g]] = srcw[src_off[g]]
        rest = ~same & ((src_len > 0) | (stop > pos))
        pos, stop, sub, src_off, src_len = pos[rest], stop[rest], sub[rest], src_off[rest], src_len[rest]
    if len(pos) == 0:
        if progress is not None:
            progress(len(out), len(out))
        del out                               # the bytearray's only view: it stays resizable
        del ba[n_orig:]                       # (room left by removals with no insertion)
        return ba
    pos, stop, sub = pos.astype(np.int64), stop.astype(np.int64), sub.astype(np.int64)
    src_off, src_len = src_off.astype(np.int64), src_len.astype(np.int64)
    # edits come in runs sorted by position (one run per kind of edit): a stable argsort on a
    # combined key merges the runs cheaply
    order = np.argsort(pos * 4096 + sub, kind="stable")
    pos, stop, src_off, src_len = pos[order], stop[order], src_off[order], src_len[order]
    prev_end = np.concatenate([[0], np.maximum.accumulate(stop)[:-1]])
    if np.any(pos < prev_end):
        raise AssertionError("overlapping edits")  # a programming error, never user input
    from ._ctok import splice_inplace
    del out
    if splice_inplace(ba, n_orig, src, pos, stop, src_off, src_len):    # compiled, in place
        del ba[total:]
        if progress is not None:
            progress(total, total)
        return ba
    out = np.frombuffer(ba, np.uint8, count=n_orig) if n_orig else np.zeros(0, np.uint8)
    tail = int(stop.max())
    npieces = 2 * len(pos) + 1
    if npieces * 64 < n_orig:
        # few pieces: join memory slices (no per-byte index arrays)
        # (into a bytearray of the final size: no joined copy)
        total = n_orig - int((stop - pos).sum()) + int(src_len.sum())
        res = bytearray(total)
        mo, ms, mr = memoryview(out), memoryview(src), memoryview(res)
        o = 0
        for p0, e0, so, sl in zip(prev_end.tolist(), pos.tolist(), src_off.tolist(), src_len.tolist()):
            mr[o:o + e0 - p0] = mo[p0:e0]
            o += e0 - p0
            mr[o:o + sl] = ms[so:so + sl]
            o += sl
        mr[o:] = mo[tail:]
        mo.release(), ms.release(), mr.release()
        if progress is not None:
            progress(len(res), len(res))
        return res
    total = n_orig - int((stop - pos).sum()) + int(src_len.sum())
    from ._ctok import splice as c_splice
    res = c_splice(out, src, pos, stop, src_off, src_len, total)
    if res is not None:                       # compiled: one pass of memcpy
        if progress is not None:
            progress(total, total)
        return res                            # a bytearray (bytes-like, no extra copy)
    buf = np.concatenate([out, src])
    p_off = np.empty(npieces, np.int64)
    p_len = np.empty(npieces, np.int64)
    p_off[0:-1:2] = prev_end
    p_len[0:-1:2] = pos - prev_end
    p_off[1::2] = src_off + n_orig
    p_len[1::2] = src_len
    p_off[-1] = tail
    p_len[-1] = n_orig - tail
    keep = p_len > 0
    p_off, p_len = p_off[keep], p_len[keep]
    out_end = np.cumsum(p_len)
    total = int(out_end[-1]) if len(out_end) else 0
    res = np.empty(total, np.uint8)
    out_start = out_end - p_len
    first = 0
    npieces = len(p_len)
    while first < npieces:
        last = int(np.searchsorted(out_end, out_start[first] + chunk_bytes, side="left")) + 1
        last = min(max(last, first + 1), npieces)
        o0 = int(out_start[first])
        o1 = int(out_end[last - 1])
        idx = np.repeat(p_off[first:last] - (out_start[first:last] - o0), p_len[first:last])
        idx += np.arange(o1 - o0)
        res[o0:o1] = buf[idx]
        first = last
        if progress is not None:
            progress(o1, total)
    return res.tobytes()
