"""The compiled one-pass tokenizer (``_tok.c``) behind `mtcomp.gcode.parse`.

Built like the kinematic kernel (mtcomp._kernel): a plain shared library without Python
headers, compiled at install (setup.py, next to this module as ``libmtctok-<hash>``) or else on
first use with the C compiler ($CC, cc or gcc) into the per-user cache
(``~/.cache/mtcomp/tok/<hash>/`` or $MTCOMP_CACHE_DIR/tok), loaded through ctypes.  Without a
compiler, or with MTCOMP_TOKENIZER=python, the numpy tokenizer (``tokens._tokenise`` and
``textops.parse_decimals``) runs instead: the same results, about 3x slower.
"""
from __future__ import annotations

import ctypes
import hashlib
import os
import subprocess
import sysconfig
import tempfile
from pathlib import Path

import numpy as np

CFLAGS = ("-O3", "-std=c99", "-fPIC", "-shared")
_SRC = Path(__file__).resolve().parent / "_tok.c"
_SUFFIX = sysconfig.get_config_var("SHLIB_SUFFIX") or ".so"
_lib = None
_tried = False


def _cache() -> Path:
    from .._kernel import cache_dir
    return cache_dir().parent / "tok"


def _build(out: Path, cc: str) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tok-", suffix=_SUFFIX, dir=out.parent)
    os.close(fd)
    try:
        run = subprocess.run([cc, *CFLAGS, str(_SRC), "-o", tmp], capture_output=True, text=True)
        if run.returncode:
            raise RuntimeError(run.stderr[-1000:])
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def source_hash() -> str:
    return hashlib.sha256(_SRC.read_bytes() + " ".join(CFLAGS).encode()).hexdigest()[:16]


def packaged_name(digest: str) -> str:
    """File name of the library the install's build hook (setup.py) puts next to this module."""
    return f"libmtctok-{digest}{_SUFFIX}"


def load():
    """The ctypes library, or None (no compiler, build failed, or MTCOMP_TOKENIZER=python).

    MTCOMP_TOKENIZER=cache skips the library built at install and uses (or builds) the cached one."""
    global _lib, _tried
    mode = os.environ.get("MTCOMP_TOKENIZER", "").lower()
    if mode == "python":
        return None
    if _tried:
        return _lib
    _tried = True
    try:
        h = source_hash()
        # MTCOMP_TOKENIZER=cache: ignore the library built at install (as MTCOMP_KERNEL=cache)
        path = _SRC.parent / packaged_name(h)
        if mode == "cache" or not path.is_file():
            path = _cache() / h / f"libmtctok{_SUFFIX}"
        if not path.is_file():
            from .._kernel import find_compiler
            cc = find_compiler()
            if not cc:
                return None
            _build(path, cc)
        lib = ctypes.CDLL(str(path))
    except (OSError, RuntimeError):
        return None
    vp, i64 = ctypes.c_void_p, ctypes.c_int64
    lib.mtc_count.argtypes = [vp, i64, vp, vp]
    lib.mtc_count.restype = None
    lib.mtc_tokenise.argtypes = [vp] + [i64] + [vp] * 13
    lib.mtc_tokenise.restype = None
    lib.mtc_splice.argtypes = [vp, i64, vp, vp, vp, vp, vp, i64, vp]
    lib.mtc_splice.restype = None
    lib.mtc_splice_inplace.argtypes = [vp, i64, vp, vp, vp, vp, vp, i64]
    lib.mtc_splice_inplace.restype = i64
    lib.mtc_copy_blank_comments.argtypes = [vp, vp, i64, i64]
    lib.mtc_copy_blank_comments.restype = i64
    lib.mtc_has_flow.argtypes = [vp, i64]
    lib.mtc_add_counts.argtypes = [vp, i64, i64, vp, vp, i64, vp]
    lib.mtc_add_counts.restype = i64
    lib.mtc_has_flow.restype = i64
    lib.mtc_format_size.argtypes = [vp, i64, i64]
    lib.mtc_format_size.restype = i64
    lib.mtc_format.argtypes = [vp, i64, i64, vp, vp, vp]
    lib.mtc_format.restype = None
    lib.mtc_overwrite.argtypes = [vp, vp, vp, vp, vp, i64]
    lib.mtc_replace_edits.argtypes = [vp, i64, vp, i64, i64, i64, vp, i64, i64, vp, vp, i64, i64,
                                      vp, i64, vp, vp, vp, vp]
    lib.mtc_replace_edits.restype = i64
    lib.mtc_replace_size.argtypes = [vp, i64, vp, i64, i64, i64]
    lib.mtc_replace_size.restype = i64
    lib.mtc_overwrite.restype = None
    lib.mtc_axis_edits.argtypes = [i64, i64, i64, vp, vp, vp, vp, i64, vp, ctypes.c_double,
                                   ctypes.c_double, vp, vp, vp, vp, vp, vp, vp]
    lib.mtc_axis_edits.restype = None
    lib.mtc_overwrite_same.argtypes = [vp, i64, vp, i64, vp, vp, vp, vp, i64, vp]
    lib.mtc_overwrite_same.restype = i64
    lib.mtc_check_words.argtypes = [vp, i64, vp, i64, i64, vp, vp, vp, vp, ctypes.c_double,
                                    vp, vp, vp, vp, vp, vp, vp]
    lib.mtc_check_words.restype = i64
    lib.mtc_read_back_applies.argtypes = [vp, vp, vp, i64, vp, vp, vp, i64, i64, i64]
    lib.mtc_read_back_applies.restype = i64
    lib.mtc_read_words.argtypes = [vp, i64, vp, i64, vp, i64, vp]
    lib.mtc_read_words.restype = i64
    lib.mtc_control_counts.argtypes = [i64, i64, vp, vp, i64, vp, vp, vp, vp, ctypes.c_double,
                                       vp, vp, vp, vp, vp]
    lib.mtc_control_counts.restype = i64
    lib.mtc_count_byte.argtypes = [vp, i64, i64]
    lib.mtc_count_byte.restype = i64
    lib.mtc_line_starts.argtypes = [vp, i64, vp]
    lib.mtc_line_starts.restype = None
    lib.mtc_ffill.argtypes = [vp, vp, i64, i64, vp, vp]
    lib.mtc_ffill.restype = None
    lib.mtc_word_lines.argtypes = [vp, vp, i64, i64, vp, vp]
    lib.mtc_word_lines.restype = i64
    lib.mtc_scatter.argtypes = [vp, vp, vp, i64, vp, i64, i64, i64, vp, vp, vp]
    lib.mtc_scatter.restype = i64
    lib.mtc_absolute.argtypes = [i64, i64, vp, i64, vp, i64, vp, vp, i64, vp, vp]
    lib.mtc_absolute.restype = None
    lib.mtc_columns_within.argtypes = [vp, i64, i64, i64, vp, vp, vp]
    lib.mtc_columns_within.restype = None
    lib.mtc_decimal_values.argtypes = [vp, i64, i64, i64, vp, vp, vp, vp]
    lib.mtc_decimal_values.restype = None
    _lib = lib
    return lib


def add_counts(Cc, dK, kk=None):
    """The rewrite's int64 counts: ``Cc`` ((N + 1, n) float64) with the corrections ``dK``
    ((m, n) float64) added to rows ``1 + kk`` (kk ascending int64; None: rows 1..N), NaN as 0
    (numpy: ``Cc[1 + kk] += dK; nan_to_num(Cc).astype(int64)``), in one pass; Cc is not
    changed.  None without the library or where a sum is infinite or beyond int64 (the
    caller's numpy path)."""
    lib = load()
    if lib is None:
        return None
    Cc, dK = np.asarray(Cc), np.asarray(dK)
    if (Cc.dtype != np.float64 or dK.dtype != np.float64 or Cc.ndim != 2 or dK.ndim != 2
            or dK.shape[1] != Cc.shape[1]):
        return None
    Cc, dK = np.ascontiguousarray(Cc), np.ascontiguousarray(dK)
    rows, n = Cc.shape
    if kk is not None:
        kk = np.ascontiguousarray(kk, np.int64)
        if len(kk) != len(dK) or (len(kk) and (kk[0] < 0 or kk[-1] >= rows - 1)):
            return None
    out = np.empty((rows, n), np.int64)
    if not out.size:
        return out
    dummy = np.zeros(1)
    got = lib.mtc_add_counts(Cc.ctypes.data, rows, n, dK.ctypes.data if dK.size else dummy.ctypes.data,
                             None if kk is None else (kk.ctypes.data if len(kk) else dummy.ctypes.data),
                             len(dK), out.ctypes.data)
    return out if got == 0 else None


def has_flow(text: str, ascii: bool = False):
    """``flow._HAS_FLOW.search(text) is not None`` in one compiled pass over the text's own
    bytes (no copy), for an ASCII str or ASCII bytes (``ascii``: bytes known to be ASCII, not
    tested again); None without the library, for other
    texts, or where the interpreter does not hand out its string data (the caller's search
    then)."""
    lib = load()
    if lib is None or not (ascii and not isinstance(text, str) or text.isascii()):
        return None
    if not isinstance(text, str):                 # bytes (ASCII): their own buffer
        buf = np.frombuffer(text, np.uint8)
        return bool(lib.mtc_has_flow(buf.ctypes.data, len(buf))) if len(buf) else False
    api = getattr(ctypes, "pythonapi", None)
    get = getattr(api, "PyUnicode_AsUTF8AndSize", None)
    if get is None:
        return None
    # a compact ASCII str is its own UTF-8: the pointer to its data, nothing allocated
    get.argtypes, get.restype = [ctypes.py_object, ctypes.POINTER(ctypes.c_ssize_t)], ctypes.c_void_p
    size = ctypes.c_ssize_t()
    ptr = get(text, ctypes.byref(size))
    if not ptr or size.value != len(text):
        return None
    return bool(lib.mtc_has_flow(ptr, size.value))


def copy_blank_comments(b: np.ndarray, first: int):
    """A copy of the program bytes `b` (uint8) with their comments blanked as
    ``tokens._comment_spans`` finds them, made in the same pass (most eight-byte groups hold no
    comment character and are copied at once); None without the compiled library."""
    lib = load()
    if lib is None:
        return None
    b = np.ascontiguousarray(b, np.uint8)
    code = np.empty(len(b), np.uint8)
    if len(b):
        lib.mtc_copy_blank_comments(b.ctypes.data, code.ctypes.data, len(b), int(first))
    return code


def tokenise(code: np.ndarray, full: bool = False):
    """Same as ``tokens._tokenise`` (int32 instead of int64 positions: letter positions, run starts and ends, point of each run,
    runs with two points, line of each letter, sign_at, bad_at) plus the value of every run
    (float64, as ``parse_decimals``; meaningful only for runs that pass the caller's checks),
    per letter A-Z the first 0-based line where it appears twice (-1: none) and two checks
    of parse's (int64): whether every run starts right after its letter (as many of each),
    the first run with two points or no digit (-1: none); then each letter's index 0..25
    (int8, A-Z in either case: parse's ``wlet``) and the number of words of each letter (26,
    int64).  Without ``full`` the points of the runs and the two-point flags are None (the two
    checks stand for them).  None if the compiled tokenizer is not available."""
    lib = load()
    if lib is None:
        return None
    code = np.ascontiguousarray(code, np.uint8)
    n = len(code)
    nl, nr = ctypes.c_int64(), ctypes.c_int64()
    ptr = code.ctypes.data
    lib.mtc_count(ptr, n, ctypes.byref(nl), ctypes.byref(nr))
    L, R = nl.value, nr.value
    if n >= 2**31 - 1:
        return None                          # int32 positions; parse refuses such programs
    lp = np.empty(L, np.int32)
    wline = np.empty(L, np.int32)
    rs, re_ = np.empty(R, np.int32), np.empty(R, np.int32)
    dot = np.empty(R, np.int32) if full else None
    two = np.zeros(R, bool) if full else None
    value = np.empty(R, np.float64)
    sign_at, bad_at = ctypes.c_int64(), ctypes.c_int64()
    dup = np.empty(26, np.int32)
    checks = np.empty(2, np.int64)
    let, let_count = np.empty(L, np.int8), np.empty(26, np.int64)
    lib.mtc_tokenise(ptr, n, lp.ctypes.data, wline.ctypes.data, rs.ctypes.data, re_.ctypes.data,
                     None if dot is None else dot.ctypes.data,
                     None if two is None else two.ctypes.data, value.ctypes.data, ctypes.byref(sign_at),
                     ctypes.byref(bad_at), dup.ctypes.data, checks.ctypes.data, let.ctypes.data,
                     let_count.ctypes.data)
    return (lp, rs, re_, dot, two, wline, sign_at.value, bad_at.value, value, dup, checks, let,
            let_count)


def splice(orig: np.ndarray, src: np.ndarray, pos, stop, src_off, src_len, total: int):
    """The bytes of `orig` with the edits applied (int64 arrays sorted by position, removed
    ranges not overlapping; ``total`` the result's size) as a bytearray, or None without the
    library."""
    lib = load()
    if lib is None:
        return None
    orig, src = np.ascontiguousarray(orig, np.uint8), np.ascontiguousarray(src, np.uint8)
    arrs = [np.ascontiguousarray(a, np.int64) for a in (pos, stop, src_off, src_len)]
    ba = bytearray(total)                    # written in place: no copy into bytes after
    out = np.frombuffer(ba, np.uint8) if total else np.zeros(1, np.uint8)
    lib.mtc_splice(orig.ctypes.data, len(orig), src.ctypes.data, *(a.ctypes.data for a in arrs),
                   len(arrs[0]), out.ctypes.data)
    del out
    return ba


def splice_inplace(buf: bytearray, n_orig: int, src: np.ndarray, pos, stop, src_off, src_len) -> bool:
    """`splice` within ``buf`` (its first ``n_orig`` bytes the original; room for the result):
    the result is then its first (original size - removed + inserted) bytes.  False without
    the library (or out of memory): nothing changed."""
    lib = load()
    if lib is None:
        return False
    src = np.ascontiguousarray(src, np.uint8)
    arrs = [np.ascontiguousarray(a, np.int64) for a in (pos, stop, src_off, src_len)]
    view = np.frombuffer(buf, np.uint8) if len(buf) else np.zeros(1, np.uint8)
    dummy = np.zeros(1, np.uint8)
    ok = lib.mtc_splice_inplace(view.ctypes.data, n_orig, src.ctypes.data if len(src) else dummy.ctypes.data,
                                *(a.ctypes.data for a in arrs), len(arrs[0])) == 0
    del view                                 # (the bytearray stays resizable)
    return ok


def format_counts(counts, decimals: int):
    """Same texts as ``textops.format_counts`` (``buffer[offset[i]:offset[i] + length[i]]`` is
    the text of ``counts[i] * 10**-decimals``), packed without padding; None without the
    library."""
    lib = load()
    if lib is None or not 0 <= int(decimals) <= 18:
        return None
    counts = np.ascontiguousarray(counts, np.int64).ravel()
    n, d = len(counts), int(decimals)
    size = lib.mtc_format_size(counts.ctypes.data, n, d)
    buf = np.empty(size, np.uint8)
    off, ln = np.empty(n, np.int64), np.empty(n, np.int64)
    lib.mtc_format(counts.ctypes.data, n, d, buf.ctypes.data, off.ctypes.data, ln.ctypes.data)
    return buf, off, ln


def replace_edits(counts, rows, mult: int, decimals: int, cw, col: int, w_num, w_end, base: int):
    """The replacement edits of word column ``col`` in blocks ``rows`` (rewrite._column_edits):
    (text buffer, pos, stop, off, len), the last four int32: the text of
    ``counts[rows[i]] * mult`` at ``decimals`` (as `format_counts`) at ``buf[off[i] - base:]``,
    ``len[i]`` bytes, replacing the text ``[pos[i], stop[i])`` of the block's word (``cw``
    (N, columns) int32 word indices, ``w_num`` / ``w_end`` int32 spans).  None without the
    library or where it does not apply (an offset beyond 32 bits): the caller's numpy path."""
    lib = load()
    if (lib is None or not 0 <= int(decimals) <= 18 or cw.dtype != np.int32 or cw.ndim != 2
            or np.asarray(w_num).dtype != np.int32 or np.asarray(w_end).dtype != np.int32):
        return None
    counts = np.ascontiguousarray(counts, np.int64)
    rows = np.ascontiguousarray(rows, np.int64)
    cw = np.ascontiguousarray(cw)
    w_num, w_end = np.ascontiguousarray(w_num), np.ascontiguousarray(w_end)
    if counts.ndim != 1 or len(w_num) != len(w_end) or cw.shape[0] != len(counts):
        return None
    m, d = len(rows), int(decimals)
    dummy = np.zeros(1, np.int32)
    ptr = lambda a: a.ctypes.data if a.size else dummy.ctypes.data  # noqa: E731
    size = lib.mtc_replace_size(ptr(counts), len(counts), ptr(rows), m, int(mult), d)
    if size < 0:
        raise ValueError("replace_edits: a row out of range")
    buf = np.empty(max(size, 1), np.uint8)                 # (exactly the texts)
    pos, stop, off, ln = (np.empty(m, np.int32) for _ in range(4))
    got = lib.mtc_replace_edits(ptr(counts), len(counts), ptr(rows), m, int(mult), d, ptr(cw),
                                cw.shape[1], int(col), ptr(w_num), ptr(w_end), len(w_num),
                                int(base), buf.ctypes.data, size, ptr(pos), ptr(stop), ptr(off),
                                ptr(ln))
    if got == -1 - m:
        return None
    if got < 0:
        raise ValueError(f"replace_edits: row {rows[-1 - got]} out of range or without a word")
    return buf[:got], pos, stop, off, ln


def overwrite(out: np.ndarray, src: np.ndarray, pos, src_off, length) -> bool:
    """Write ``src[src_off[i]:src_off[i] + length[i]]`` at ``out[pos[i]:]`` for every i (ranges
    inside ``out``, not overlapping; `out` a writable C-contiguous uint8 array).  False without
    the library (nothing done)."""
    lib = load()
    if lib is None or not out.flags.c_contiguous or not out.flags.writeable:
        return False
    src = np.ascontiguousarray(src, np.uint8)
    pos, src_off, length = (np.ascontiguousarray(a, np.int64) for a in (pos, src_off, length))
    if len(pos) and (pos.min() < 0 or int((pos + length).max()) > len(out)
                     or src_off.min() < 0 or int((src_off + length).max()) > len(src)):
        raise ValueError("overwrite outside the buffers")
    lib.mtc_overwrite(out.ctypes.data, src.ctypes.data, pos.ctypes.data, src_off.ctypes.data,
                      length.ctypes.data, len(pos))
    return True


def read_words(data, lines, letters: str):
    """The written words of ``lines`` (0-based, ascending int64) of the program bytes `data`:
    (len(lines), len(letters)) float64, the value of the word of each letter (upper case; read
    in either case), NaN where the line has none; and the index into ``lines`` of the first line
    that cannot be read (a letter without a well-formed number, twice, or a line past the end),
    -1 if none.  None without the library."""
    lib = load()
    if lib is None:
        return None
    b = np.frombuffer(data, np.uint8) if not isinstance(data, np.ndarray) else data
    b = np.ascontiguousarray(b, np.uint8)
    lines = np.ascontiguousarray(lines, np.int64)
    if len(lines) > 1 and (np.diff(lines) <= 0).any():
        raise ValueError("lines must be ascending")
    col = np.full(26, -1, np.int8)
    for k, a in enumerate(letters):
        col[ord(a.upper()) - 65] = k
    val = np.empty((len(lines), len(letters)), np.float64)
    ptr = b.ctypes.data if len(b) else np.zeros(1, np.uint8).ctypes.data
    bad = lib.mtc_read_words(ptr, len(b), lines.ctypes.data, len(lines), col.ctypes.data,
                             len(letters), val.ctypes.data)
    return val, int(bad)


def control_counts(N: int, res, inc, inch, lin, inch_mm: float, start, known, *, words=None,
                   col_word=None, w_value=None, offc=None):
    """Same as ``rewrite._control_counts`` (the (N + 1, n) counts, float) from ``words`` (N, n)
    values (NaN: no word) or from the program's ``col_word`` / ``w_value``; ``offc`` (N, n)
    int64 or None; ``lin`` per axis whether it is linear (inch conversion).  Returns (counts,
    -1) or (None, k * N + i) for the first count above 2**52 (axis k, block i); None without the
    library."""
    lib = load()
    if lib is None:
        return None
    res = np.ascontiguousarray(res, np.float64)
    n = len(res)
    if n > 64:                                   # the C pass keeps at most 64 axes' state
        return None
    u8 = lambda a: np.ascontiguousarray(a, np.bool_).view(np.uint8)  # noqa: E731
    inc, inch, lin, known = u8(inc), u8(inch), u8(lin), u8(known)
    start = np.ascontiguousarray(start, np.float64)
    if words is not None:
        words = np.ascontiguousarray(words, np.float64)
        vals, cw, stride, wv = words.ctypes.data, None, 0, None
    else:
        col_word = np.ascontiguousarray(col_word, np.int32)
        w_value = np.ascontiguousarray(w_value, np.float64)
        vals, cw, stride = None, col_word.ctypes.data, col_word.shape[1]
        wv = w_value.ctypes.data if len(w_value) else None
    if offc is not None:
        offc = np.ascontiguousarray(offc, np.int64)
    out = np.empty((N + 1, n), np.float64)
    bad = lib.mtc_control_counts(N, n, vals, cw, stride, wv, inc.ctypes.data, inch.ctypes.data,
                                 lin.ctypes.data, float(inch_mm), res.ctypes.data,
                                 None if offc is None else offc.ctypes.data, start.ctypes.data,
                                 known.ctypes.data, out.ctypes.data)
    return (None, int(bad)) if bad >= 0 else (out, -1)


def axis_edits(C, k: int, inc, offc, col_word, w_value, scale: float, res: float, edit, no_z):
    """The rewrite's decisions for axis column ``k`` (see ``mtc_axis_edits``): (target counts
    (N,) int64, blocks whose word is replaced, blocks that get a new word), or None without the
    library.  C: (N + 1, n) int64 counts; offc (N, n) int64 or None; no_z (N,) bool or None."""
    lib = load()
    if lib is None:
        return None
    C = np.ascontiguousarray(C, np.int64)
    N, n = C.shape[0] - 1, C.shape[1]
    u8 = lambda a: np.ascontiguousarray(a, np.bool_).view(np.uint8)  # noqa: E731
    inc, edit = u8(inc), u8(edit)
    no_z = None if no_z is None else u8(no_z)
    cw = np.ascontiguousarray(col_word, np.int32)
    wv = np.ascontiguousarray(w_value, np.float64)
    if offc is not None:
        offc = np.ascontiguousarray(offc, np.int64)
    target = np.empty(N, np.int64)
    rep, ins = np.empty(N, np.int64), np.empty(N, np.int64)
    nr, ni = ctypes.c_int64(), ctypes.c_int64()
    lib.mtc_axis_edits(N, n, int(k), C.ctypes.data, inc.ctypes.data,
                       None if offc is None else offc.ctypes.data, cw.ctypes.data, cw.shape[1],
                       wv.ctypes.data if len(wv) else None, float(scale), float(res),
                       edit.ctypes.data, None if no_z is None else no_z.ctypes.data,
                       target.ctypes.data, rep.ctypes.data, ins.ctypes.data, ctypes.byref(nr),
                       ctypes.byref(ni))
    return target, rep[:nr.value], ins[:ni.value]


def overwrite_same(out: np.ndarray, src: np.ndarray, pos, stop, src_off, src_len):
    """The in-place step of ``textops.splice``: edits whose text has the length of the range it
    replaces are written into `out` (writable C-contiguous uint8); returns the indices (int64)
    of the other edits that do something.  None without the library or unless the four edit
    arrays are int32 (nothing done)."""
    lib = load()
    arrs = [np.asarray(a) for a in (pos, stop, src_off, src_len)]
    if (lib is None or not out.flags.c_contiguous or not out.flags.writeable
            or any(a.dtype != np.int32 for a in arrs)):
        return None
    arrs = [np.ascontiguousarray(a) for a in arrs]
    src = np.ascontiguousarray(src, np.uint8)
    m = len(arrs[0])
    rest = np.empty(m, np.int64)
    if not m:
        return rest
    dummy = np.zeros(1, np.uint8)
    k = lib.mtc_overwrite_same(out.ctypes.data if len(out) else dummy.ctypes.data, len(out),
                               src.ctypes.data if len(src) else dummy.ctypes.data, len(src),
                               *(a.ctypes.data for a in arrs), m, rest.ctypes.data)
    if k < 0:
        raise ValueError("overwrite outside the buffers")
    return rest[:k]


def check_words(data, lines, letters: str, res, inc, inch, lin, inch_mm: float, start, known,
                check, want, offc=None):
    """``read_words`` of the block ``lines`` run through ``control_counts`` (same arguments)
    and compared with ``want`` ((N, n) int64 counts) on the blocks with ``check``, in one
    compiled pass: (-1, 0) if every checked block reads back as ``want``, else (block, kind:
    1 unreadable word or line, 2 other counts, 3 a count above 2**52).  None without the
    library."""
    lib = load()
    if lib is None or len(letters) > 64:
        return None
    b = np.frombuffer(data, np.uint8) if not isinstance(data, np.ndarray) else data
    b = np.ascontiguousarray(b, np.uint8)
    lines = np.ascontiguousarray(lines, np.int64)
    col = np.full(26, -1, np.int8)
    for k, a in enumerate(letters):
        col[ord(a.upper()) - 65] = k
    u8 = lambda a: np.ascontiguousarray(a, np.bool_).view(np.uint8)  # noqa: E731
    inc, inch, lin, known, check = u8(inc), u8(inch), u8(lin), u8(known), u8(check)
    res = np.ascontiguousarray(res, np.float64)
    start = np.ascontiguousarray(start, np.float64)
    want = np.ascontiguousarray(want, np.int64)
    if offc is not None:
        offc = np.ascontiguousarray(offc, np.int64)
    kind = ctypes.c_int64()
    ptr = b.ctypes.data if len(b) else np.zeros(1, np.uint8).ctypes.data
    j = lib.mtc_check_words(ptr, len(b), lines.ctypes.data, len(lines), len(letters),
                            col.ctypes.data, inc.ctypes.data, inch.ctypes.data, lin.ctypes.data,
                            float(inch_mm), res.ctypes.data,
                            None if offc is None else offc.ctypes.data, start.ctypes.data,
                            known.ctypes.data, check.ctypes.data, want.ctypes.data,
                            ctypes.byref(kind))
    return int(j), int(kind.value)


def read_back_applies(w_line, w_letter, w_value, axes: str, block_line, col_word):
    """``rewrite._read_back_applies`` in one compiled pass (no G92 word; every axis-letter word
    on a block's line one of its axis words), or None without the library or if the words are
    not in text order."""
    lib = load()
    if lib is None:
        return None
    wl = np.ascontiguousarray(w_line, np.int32)
    wlet = np.ascontiguousarray(w_letter, np.int8)
    wv = np.ascontiguousarray(w_value, np.float64)
    axis = np.zeros(26, np.uint8)
    axis[[ord(a) - 65 for a in axes]] = 1
    bl = np.ascontiguousarray(block_line, np.int64)
    cw = np.ascontiguousarray(col_word, np.int32)
    dummy = np.zeros(1, np.float64)
    got = int(lib.mtc_read_back_applies(
        wl.ctypes.data if len(wl) else dummy.ctypes.data, wlet.ctypes.data if len(wl) else dummy.ctypes.data,
        wv.ctypes.data if len(wl) else dummy.ctypes.data, len(wl), axis.ctypes.data,
        bl.ctypes.data if len(bl) else dummy.ctypes.data, cw.ctypes.data if cw.size else dummy.ctypes.data,
        cw.shape[1] if cw.ndim == 2 else 0, len(axes), len(bl)))
    return None if got < 0 else bool(got)


# ---- block building of parse: the twins of numpy passes in parse.py (same values, same bits;
# tests/test_gcode_blocks.py holds every array of the parsed program to the numpy path's)

def line_starts(b: np.ndarray):
    """int64 start of every line of the bytes `b` (0 and every byte after a line feed), or
    None."""
    lib = load()
    if lib is None or not b.flags.c_contiguous or b.dtype != np.uint8:
        return None
    out = np.empty(lib.mtc_count_byte(b.ctypes.data, len(b), 10) + 1, np.int64)
    lib.mtc_line_starts(b.ctypes.data, len(b), out.ctypes.data)
    return out


def ffill(values: np.ndarray, isset: np.ndarray, default):
    """``parse._ffill`` for int64, float64 and bool values (a default of the same kind), or
    None (another kind, or no library)."""
    lib = load()
    if lib is None or values.ndim != 1 or len(isset) != len(values):
        return None
    dt = values.dtype
    if dt == np.float64 and isinstance(default, (float, int, np.floating)) and not isinstance(default, bool):
        d = np.array([default], np.float64)
    elif dt == np.int64 and isinstance(default, (int, np.integer)) and not isinstance(default, bool):
        d = np.array([default], np.int64)
    elif dt == np.bool_ and isinstance(default, (bool, np.bool_)):
        d = np.array([default], np.bool_)
    else:
        return None
    values = np.ascontiguousarray(values)
    isset = np.ascontiguousarray(isset, np.bool_)
    out = np.empty(len(values), dt)
    lib.mtc_ffill(values.ctypes.data, isset.ctypes.data, len(values), dt.itemsize,
                  d.ctypes.data, out.ctypes.data)
    return out


def word_lines(wcol: np.ndarray, wline: np.ndarray, n_ax: int, n_lines: int):
    """(has_motion, has_arc, number of arc words): per line whether it holds an axis word
    (column < n_ax) or an arc word, or None."""
    lib = load()
    if lib is None or wcol.dtype != np.int8 or wline.dtype != np.int32:
        return None
    wcol, wline = np.ascontiguousarray(wcol), np.ascontiguousarray(wline)
    hm, ha = np.zeros(n_lines, bool), np.zeros(n_lines, bool)
    n_arc = lib.mtc_word_lines(wcol.ctypes.data, wline.ctypes.data, len(wcol), n_ax,
                               hm.ctypes.data, ha.ctypes.data)
    return hm, ha, int(n_arc)


def scatter(wcol, wline, value, blk_of_line, nblk: int, ncol: int, n_ax: int):
    """(col_word int32 (nblk, ncol), values float64 (nblk, n_ax) of the columns below n_ax,
    values (nblk, ncol - n_ax) of the others): the words in block columns (-1 and NaN where
    none), or None (no library, or a word on a line that is no block)."""
    lib = load()
    if (lib is None or wcol.dtype != np.int8 or wline.dtype != np.int32
            or value.dtype != np.float64 or blk_of_line.dtype != np.int64):
        return None
    wcol, wline = np.ascontiguousarray(wcol), np.ascontiguousarray(wline)
    value, blk_of_line = np.ascontiguousarray(value), np.ascontiguousarray(blk_of_line)
    col_word = np.empty((nblk, ncol), np.int32)
    vax, varc = np.empty((nblk, n_ax)), np.empty((nblk, ncol - n_ax))
    bad = lib.mtc_scatter(wcol.ctypes.data, wline.ctypes.data, value.ctypes.data, len(wcol),
                          blk_of_line.ctypes.data, nblk, ncol, n_ax, col_word.ctypes.data,
                          vax.ctypes.data, varc.ctypes.data)
    return None if bad >= 0 else (col_word, vax, varc)


def _row_stride(a: np.ndarray, dtype):
    """Row stride in elements of a 2-D array whose rows are contiguous, else None."""
    if a.dtype != dtype or a.ndim != 2 or (a.shape[1] > 1 and a.strides[1] != a.itemsize):
        return None
    if a.shape[0] > 1 and (a.strides[0] % a.itemsize or a.strides[0] <= 0):
        return None
    return a.strides[0] // a.itemsize if a.shape[0] > 1 else a.shape[1]


def absolute(vals, present, incremental, offset, use_off: bool, start_vec):
    """``parse._absolute`` (positions, (n, n_axes) float64), or None."""
    lib = load()
    if lib is None:
        return None
    n, n_ax = present.shape
    vs, ps = _row_stride(vals, np.float64), _row_stride(present, np.bool_)
    if vs is None or ps is None or vals.shape != (n, n_ax):
        return None
    incremental = np.ascontiguousarray(incremental, np.bool_)
    if offset.shape != (n, n_ax):
        return None
    # (without offsets they are not read: a zero view is not copied into a full array)
    offset = np.ascontiguousarray(offset, np.float64) if use_off else np.zeros((1, n_ax))
    start_vec = np.ascontiguousarray(start_vec, np.float64)
    if incremental.shape != (n,) or start_vec.shape != (n_ax,):
        return None
    position = np.empty((n, n_ax))
    if n and n_ax:
        lib.mtc_absolute(n, n_ax, vals.ctypes.data, vs, present.ctypes.data, ps,
                         incremental.ctypes.data, offset.ctypes.data, int(bool(use_off)),
                         start_vec.ctypes.data, position.ctypes.data)
    return position


def columns_within(P, lo, hi):
    """Per column k of P (rows, n_col) float64: whether ``P[:, k].min() >= lo[k] and
    P[:, k].max() <= hi[k]`` (False where the column holds a NaN), in one pass over the rows;
    None without the library or for arrays whose rows are not contiguous."""
    lib = load()
    if lib is None or not isinstance(P, np.ndarray) or P.ndim != 2:
        return None
    stride = _row_stride(P, np.float64)
    if stride is None:
        return None
    n, n_col = P.shape
    lo = np.ascontiguousarray(lo, np.float64).reshape(-1)
    hi = np.ascontiguousarray(hi, np.float64).reshape(-1)
    if lo.shape != (n_col,) or hi.shape != (n_col,):
        return None
    ok = np.zeros(n_col, bool)
    if n_col:
        lib.mtc_columns_within(P.ctypes.data, n, n_col, stride, lo.ctypes.data, hi.ctypes.data,
                               ok.ctypes.data)
    return ok


def decimal_values(counts, mult, p10, res, out=None):
    """``textops.decimal_values`` of counts (n, n_col) int64 or float64, C order, with the
    columns' multiples ``mult``, powers of ten ``p10`` and steps ``res`` (floats, as the numpy
    path uses them) into ``out`` (float64 (n, n_col), C order; may be the memory of counts
    itself; None: a new array); out, or None without the library or for other arrays."""
    lib = load()
    if (lib is None or not isinstance(counts, np.ndarray) or counts.ndim != 2
            or counts.dtype not in (np.int64, np.float64) or not counts.flags.c_contiguous):
        return None
    n, n_col = counts.shape
    if n_col > 64:
        return None
    if out is None:
        out = np.empty((n, n_col))
    if out.shape != (n, n_col) or out.dtype != np.float64 or not out.flags.c_contiguous:
        return None
    cols = [np.ascontiguousarray(v, np.float64).reshape(-1) for v in (mult, p10, res)]
    if any(c.shape != (n_col,) for c in cols):
        return None
    if n and n_col:
        lib.mtc_decimal_values(counts.ctypes.data, int(counts.dtype == np.int64), n, n_col,
                               *(c.ctypes.data for c in cols), out.ctypes.data)
    return out
