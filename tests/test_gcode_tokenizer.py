"""The compiled one-pass tokenizer (core/gcode/_tok.c) against the numpy tokenizer it stands in
for: the same program arrays to the bit and the same error messages, on the corpus, on mutated
corpus programs and on generated blocks (issue 16 item 4, issue 20)."""
from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

from mtcomp import InputError, gcode
from mtcomp.gcode import _ctok, flow
from mtcomp.gcode.textops import parse_decimals
from mtcomp.gcode.tokens import _tokenise

AXES = ("X", "Y", "Z", "B", "C")
_DATA = Path(__file__).parent / "data" / "nc"
CORPUS_FILES = sorted([p for p in _DATA.iterdir() if p.is_file()] + sorted((_DATA / "tcp").iterdir()))
# programs with subprogram calls: the expansion is what is parsed
CORPUS = [(lambda t, f: f.expanded if f else t)(t, flow.expand(t, search=[str(_DATA / "subprograms")]))
          for t in map(gcode.read_program, CORPUS_FILES)]
ALPHABET = "GXYZBCIJKRFNMSTPHQ0123456789.-+ ()%;/#[]=\n\r\t\ufeffgxyz\u00e9"

pytestmark = pytest.mark.skipif(_ctok.load() is None, reason="no C compiler: numpy tokenizer only")


def _parse(text, python: bool, monkeypatch):
    if python:
        monkeypatch.setenv("MTCOMP_TOKENIZER", "python")
    else:
        monkeypatch.delenv("MTCOMP_TOKENIZER", raising=False)
    try:
        return gcode.parse(text, axes=AXES, filename="p.nc", tcp=True, rotation=True)
    except InputError as exc:
        return str(exc)


def _same(text, monkeypatch):
    a, b = _parse(text, False, monkeypatch), _parse(text, True, monkeypatch)
    if isinstance(a, str) or isinstance(b, str):
        assert a == b
        return a
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape, f.name
            if x.dtype.kind == "f":
                assert np.array_equal(x.view(np.int64 if x.itemsize == 8 else np.int32),
                                      y.view(np.int64 if y.itemsize == 8 else np.int32)), f.name
            else:
                assert np.array_equal(x, y), f.name
        else:
            assert x == y, f.name
    return a


@pytest.mark.parametrize("i", range(len(CORPUS)), ids=[p.name for p in CORPUS_FILES])
def test_corpus_same_program_arrays(i, monkeypatch):
    assert not isinstance(_same(CORPUS[i], monkeypatch), str)


def test_tokens_and_values_bit_for_bit_with_long_and_odd_numbers():
    text = ("G1 X123456789.123456789 Y-0.000000000000001 Z+12. B.5 C-0\n"
            "X1e5 Y1..2 Z-+1 B99999999999999999999999 C0.1234567890123456789\n"
            "X12-3 N5- G-.\n").encode()
    code = np.frombuffer(text, np.uint8).copy()
    ls = np.concatenate(([0], np.flatnonzero(code == 10) + 1))
    c = _ctok.tokenise(code, full=True)
    p = _tokenise(code, ls)
    for k in range(6):
        assert np.array_equal(c[k], p[k]), k
    assert c[6:8] == p[6:8] and c[6] >= 0
    # each word's letter index (parse's wlet, either case) and the words per letter
    wlet = ((code[p[0]] | np.uint8(32)) - np.uint8(97)).astype(np.int8)
    assert c[11].dtype == np.int8 and np.array_equal(c[11], wlet)
    assert np.array_equal(c[12], np.bincount(wlet, minlength=26))
    # values of the runs that are numbers (the caller refuses the others before using them)
    good = [i for i in range(len(c[1])) if re.fullmatch(rb"[+-]?(\d+\.?\d*|\.\d+)", text[c[1][i]:c[2][i]])]
    ref = parse_decimals(code, p[1][good], p[2][good], p[3][good])
    assert np.array_equal(c[8][good].view(np.int64), ref.view(np.int64))
    assert c[8][good][1] == float("123456789.123456789") and np.signbit(c[8][good][5])


@seed(16)
@settings(max_examples=200, deadline=None, suppress_health_check=list(HealthCheck))
@given(st.sampled_from(range(len(CORPUS))), st.lists(
    st.tuples(st.integers(0, 10_000), st.sampled_from(["ins", "del", "rep"]), st.sampled_from(ALPHABET)),
    min_size=1, max_size=4))
def test_mutated_corpus_programs_same_result(i, edits):
    text = CORPUS[i]
    for pos, kind, ch in edits:
        pos %= len(text) + 1
        if kind == "ins":
            text = text[:pos] + ch + text[pos:]
        elif kind == "del":
            text = text[:pos] + text[pos + 1:]
        else:
            text = text[:pos] + ch + text[pos + 1:]
    with pytest.MonkeyPatch.context() as mp:
        _same(text, mp)


_num = st.one_of(st.integers(-10**12, 10**12).map(str),
                 st.decimals(-999, 999, places=3, allow_nan=False).map(lambda d: f"{d}"),
                 st.floats(-1e6, 1e6).map(lambda v: f"{v:.12f}"),
                 st.integers(0, 99).map(lambda v: f"{v}."), st.integers(0, 999).map(lambda v: f".{v}"),
                 st.text("0123456789.-+", min_size=1, max_size=20))
_word = st.tuples(st.sampled_from("XYZBCxyzGFI"), st.sampled_from(["", " "]), _num).map("".join)


@seed(17)
@settings(max_examples=200, deadline=None, suppress_health_check=list(HealthCheck))
@given(st.lists(st.lists(st.one_of(_word, st.sampled_from(["G1", "G91", "(c)", "; x", "/", "%"])),
                         min_size=1, max_size=6), min_size=1, max_size=10),
       st.sampled_from(["\n", "\r\n"]))
def test_generated_blocks_same_result(blocks, eol):
    with pytest.MonkeyPatch.context() as mp:
        _same(eol.join(" ".join(b) for b in blocks) + eol, mp)


@pytest.mark.parametrize("text", [
    "(a)G1 X1(b) ; c (d)\n%x\n G1 (unclosed\n((nested) X2)\n; (\n(a\n)\n%\n",
    "\ufeff%\nG1 X1 % not a line start\n(x(y)z)\n(;)X3;(\n",
    "", "(", ";", "%", "G1 X1 (no newline at the end)"])
def test_comment_blanking_same_spans(text):
    from mtcomp.gcode.tokens import _comment_spans
    data = text.encode("utf-8")
    b = np.frombuffer(data, np.uint8)
    bom = 3 if data.startswith(b"\xef\xbb\xbf") else 0
    ref = b.copy()
    for s, e in _comment_spans(data, b, first=bom):
        ref[s:e] = 32
    assert _ctok.copy_blank_comments(b, bom).tobytes() == ref.tobytes()
    # comment bytes at every offset of its eight-byte steps
    for lead in range(1, 9):
        pre = b" " * lead
        data2 = data[:bom] + pre + data[bom:]
        b2 = np.frombuffer(data2, np.uint8)
        ref2 = b2.copy()
        for s, e in _comment_spans(data2, b2, first=bom):
            ref2[s:e] = 32
        got2 = _ctok.copy_blank_comments(b2, bom)
        assert got2.tobytes() == ref2.tobytes()


@seed(5)
@settings(max_examples=300, deadline=None, suppress_health_check=list(HealthCheck))
@given(st.text("G1X2.(;)%\n \t/", max_size=80), st.booleans())
def test_comment_blanking_copy_same_as_spans(text, bom):
    from mtcomp.gcode.tokens import _comment_spans
    data = (b"\xef\xbb\xbf" if bom else b"") + text.encode("utf-8")
    b = np.frombuffer(data, np.uint8)
    first = 3 if bom else 0
    ref = b.copy()
    for s, e in _comment_spans(data, b, first=first):
        ref[s:e] = 32
    assert _ctok.copy_blank_comments(b, first).tobytes() == ref.tobytes()


@pytest.mark.parametrize("text", ["G1 X1 Y2 Y3\nX1 X2\n", "X1 X2\nG1 Y1 Y2\n", "G1 G90 M3 M8 X1\nB1 b2\n",
                                  "x1 X2\n", "G1 X1\nY1 Z1\nZ2 Z3 Y4 Y5\n"])
def test_duplicate_address_same_message(text, monkeypatch):
    msg = _same(text, monkeypatch)
    if "G90 M3 M8 X1" in text:
        assert msg.endswith("address B appears twice in one block")
    else:
        assert "appears twice in one block" in msg


def test_without_a_compiler_the_numpy_tokenizer_reads_the_program(tmp_path):
    import subprocess
    import sys
    code = ("from mtcomp import gcode; from mtcomp.gcode import _ctok; "
            "p = gcode.parse('G1 X1.5 Y-2 (c) Z3\\n', axes=('X', 'Y', 'Z')); "
            "print(_ctok.load() is None, p.position.tolist())")
    # MTCOMP_TOKENIZER=cache: the library a non-editable install built is not there either
    env = {**__import__("os").environ, "MTCOMP_CACHE_DIR": str(tmp_path), "CC": str(tmp_path / "no-cc"),
           "MTCOMP_TOKENIZER": "cache"}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split("\n")[0] == "True [[1.5, -2.0, 3.0]]"


@seed(18)
@settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck))
@given(st.binary(min_size=0, max_size=3000), st.lists(
    st.tuples(st.integers(0, 3000), st.integers(0, 4), st.integers(0, 3), st.binary(max_size=6)),
    min_size=1, max_size=400))
def test_splice_same_bytes(orig, raw):
    """Many edits (so that splice takes its gather branch): compiled and numpy give the same."""
    from mtcomp.gcode.textops import splice
    o = np.frombuffer(orig, np.uint8)
    # non-overlapping removals: sort the starts, clip each range before the next start
    raw = sorted((min(p, len(orig)), w, s, t) for p, w, s, t in raw)
    pos, stop, sub, off, ln, src = [], [], [], [], [], b""
    for k, (p, w, s, t) in enumerate(raw):
        nxt = raw[k + 1][0] if k + 1 < len(raw) else len(orig)
        pos.append(p)
        stop.append(min(p + w, nxt) if w else p)
        sub.append(s)
        off.append(len(src))
        ln.append(len(t))
        src += t
    args = (o, np.array(pos), np.array(stop), np.array(sub), np.frombuffer(src, np.uint8),
            np.array(off), np.array(ln))
    # the rewrite's edit arrays are 32-bit: the compiled in-place step (mtc_overwrite_same)
    args32 = args[:4] + (args[4],) + tuple(np.asarray(a, np.int32) for a in args[5:])
    args32 = (args[0],) + tuple(np.asarray(a, np.int32) for a in args[1:3]) + args32[3:]
    with pytest.MonkeyPatch.context() as mp:
        mp.delenv("MTCOMP_TOKENIZER", raising=False)
        a = splice(*args)
        a32 = splice(*args32)
        mp.setenv("MTCOMP_TOKENIZER", "python")
        b = splice(*args)
    assert a == b and a32 == b


@seed(19)
@settings(max_examples=200, deadline=None, suppress_health_check=list(HealthCheck))
@given(st.lists(st.one_of(st.integers(-10**18, 10**18), st.integers(-1000, 1000), st.sampled_from([0, -1, 1, 9, -10])),
                min_size=1, max_size=50), st.integers(0, 12))
def test_compiled_number_formatter_same_texts(counts, decimals):
    from mtcomp.gcode.textops import format_counts
    c = np.array(counts, np.int64)
    buf, off, ln = _ctok.format_counts(c, decimals)
    rbuf, roff, rln = format_counts(c, decimals)
    got = [buf[o:o + n].tobytes() for o, n in zip(off, ln)]
    ref = [rbuf[o:o + n].tobytes() for o, n in zip(roff, rln)]
    assert got == ref
    # and the text means the value: counts * 10**-decimals, a point always, no "-0"
    for v, t in zip(counts, got):
        assert t.count(b".") == 1 and len(t) - t.index(b".") - 1 == decimals
        assert (t[:1] == b"-") == (v < 0) and int(t.replace(b".", b"")) == v


def _on_both_paths(fn):
    """[fn() on the compiled path, fn() on the numpy path]; an InputError gives its message."""
    out = []
    for python in (False, True):
        with pytest.MonkeyPatch.context() as mp:
            if python:
                mp.setenv("MTCOMP_TOKENIZER", "python")
            else:
                mp.delenv("MTCOMP_TOKENIZER", raising=False)
            try:
                out.append(fn())
            except InputError as exc:
                out.append(str(exc))
    return out


def _control_counts_both(prog, res, offc=None, words=None):
    rw = __import__("importlib").import_module("mtcomp.gcode.rewrite")
    return _on_both_paths(lambda: rw._control_counts(prog, res, offc, words=words))


@pytest.mark.parametrize("i", range(len(CORPUS)), ids=[p.name for p in CORPUS_FILES])
def test_control_counts_same_bits_compiled_and_numpy(i):
    """The control's position in counts (G90/G91, inch, work offsets, unknown start): the C
    pass and the numpy reference give the same float bits, from the program's words and from
    words given as values."""
    try:
        prog = gcode.parse(CORPUS[i], axes=AXES, filename="p.nc", tcp=True, rotation=True)
    except InputError:
        pytest.skip("not a program for these axes")
    rng = np.random.default_rng(i)
    res = np.array([1e-4, 1e-6, 5e-6, 1e-5, 1e-3])
    offc = rng.integers(-10**6, 10**6, (len(prog), len(AXES)))
    cw = np.asarray(prog.col_word)[:, :len(AXES)]
    words = np.where(cw >= 0, np.asarray(prog.w_value)[np.maximum(cw, 0)], np.nan)
    for o in (None, offc):
        a, b = _control_counts_both(prog, res, o)
        assert np.array_equal(a.view(np.int64), b.view(np.int64))
        c, d = _control_counts_both(prog, res, o, words=words)
        assert np.array_equal(c.view(np.int64), d.view(np.int64))
        if prog.polar is None or not np.asarray(prog.polar).any():
            # (G16 blocks: the program's X Y words are a radius and an angle, the values given
            # here Cartesian, so the two differ there by design)
            assert np.array_equal(a.view(np.int64), c.view(np.int64))
    # a word of more than 2**52 counts: the same message
    big = words.copy()
    big[np.isfinite(big)] *= 1e12
    a, b = _control_counts_both(prog, np.full(len(AXES), 1e-9), None, words=big)
    assert isinstance(a, str) and a == b


@pytest.mark.parametrize("i", range(len(CORPUS)), ids=[p.name for p in CORPUS_FILES])
def test_read_back_words_are_the_parsed_words(i):
    """The read-back of the check (mtc_read_words) finds on every block's line the axis words
    the parser found there, to the bit."""
    try:
        prog = gcode.parse(CORPUS[i], axes=AXES, filename="p.nc", tcp=True, rotation=True)
    except InputError:
        pytest.skip("not a program for these axes")
    cw = np.asarray(prog.col_word)[:, :len(AXES)]
    words = np.where(cw >= 0, np.asarray(prog.w_value)[np.maximum(cw, 0)], np.nan)
    got, bad = _ctok.read_words(prog.data, np.asarray(prog.line) - 1, "".join(AXES))
    assert bad == -1 and len(prog) > 0
    # lines where an axis letter is no move (G4 X, G10 X, G92 X) are left to the full parse
    lines = np.asarray(prog.line) - 1
    wl, wlet = np.asarray(prog.w_line), np.asarray(prog.w_letter)
    axl = np.isin(wlet, [ord(a) - 65 for a in AXES])
    simple = np.bincount(wl[axl], minlength=prog.n_lines)[lines] == (cw >= 0).sum(axis=1)
    assert simple.mean() > 0.5
    a, b = got[simple], words[simple]
    assert np.array_equal(np.isnan(a), np.isnan(b))
    assert np.array_equal(np.nan_to_num(a).view(np.int64), np.nan_to_num(b).view(np.int64))


@pytest.mark.parametrize("i", range(len(CORPUS)), ids=[p.name for p in CORPUS_FILES])
def test_read_back_applies_same_compiled_and_numpy(i):
    """Whether compensate's read-back applies (no G92; no axis letter that is no move on a
    block's line): the compiled pass and the numpy reference agree, and a G92 or a G4 X line
    made into a block's line turns it off."""
    rw = __import__("importlib").import_module("mtcomp.gcode.rewrite")
    texts = [CORPUS[i]]
    lines = CORPUS[i].split("\n")
    k = next((j for j, ln in enumerate(lines) if re.match(r"\s*[Gg]0*1\b.*[Xx]", ln)), None)
    if k is not None:
        texts += ["\n".join(lines[:k + 1] + ["G92 X0"] + lines[k + 1:]),
                  "\n".join(lines[:k] + [lines[k] + " G4 P1"] + lines[k + 1:])]
    for n, text in enumerate(texts):
        try:
            prog = gcode.parse(text, axes=AXES, filename="p.nc", tcp=True, rotation=True)
        except InputError:
            continue
        got = []
        for python in (False, True):
            with pytest.MonkeyPatch.context() as mp:
                if python:
                    mp.setenv("MTCOMP_TOKENIZER", "python")
                got.append(rw._read_back_applies(prog, {"linearised": 0}))
        assert got[0] == got[1]
        if n == 1:
            assert got[0] is False                  # G92 in the program


@seed(20)
@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
@given(st.lists(st.text(alphabet="XYZxyGg0123456789.-+ ()%;\t", max_size=30), min_size=1, max_size=12))
def test_read_back_words_against_a_python_reader(lines):
    """mtc_read_words on arbitrary lines against a small reader written here: comments skipped,
    blanks between letter and number read, a bad or repeated word reported."""
    _read_words_as_the_reader(lines, "")


@seed(21)
@settings(max_examples=300, deadline=None, suppress_health_check=list(HealthCheck))
@given(st.lists(st.lists(st.tuples(st.sampled_from("XYZxy"), st.sampled_from(["", "-", "+", " "]),
                                   st.text("0123456789", max_size=9), st.sampled_from(["", ".", ".."]),
                                   st.text("0123456789", max_size=9), st.sampled_from(["", " ", "-", "("]))
                         .map("".join), max_size=4).map("".join), min_size=1, max_size=8))
def test_read_back_numbers_eight_bytes_at_a_time_against_a_python_reader(lines):
    """The same with numbers of 0-9 digits on either side of the point, followed by at least 17
    bytes (a padding line), so that the eight-byte reading of the common number runs and
    hands every other number to the byte loop at the same place."""
    _read_words_as_the_reader(lines, " " * 24 + "\n")


def _read_words_as_the_reader(lines, pad):
    text = "\n".join(lines) + "\n" + pad
    want = np.arange(len(lines))
    got, bad = _ctok.read_words(text.encode(), want, "XYZ")
    ref_bad, ref = -1, np.full((len(lines), 3), np.nan)
    for q, ln in enumerate(lines):
        code = "" if ln.startswith("%") else re.sub(r"\([^()]*\)", lambda m: " " * len(m.group()), ln).split(";")[0]
        ok = True
        for m in re.finditer(r"([XYZxyz])[ \t\r]*", code):
            num = re.match(r"[-+]?(\d*)(\.?)(\d*)", code[m.end():])
            rest = code[m.end() + num.end():m.end() + num.end() + 1]
            k = "XYZ".index(m.group(1).upper())
            if not (num.group(1) or num.group(3)) or (rest and rest in "0123456789.+-") or not np.isnan(ref[q, k]):
                ok = False
                break
            ref[q, k] = float(num.group())
        if not ok:
            ref_bad = q
            break
    assert bad == ref_bad
    n = len(lines) if bad < 0 else bad
    np.testing.assert_array_equal(got[:n], ref[:n])


def _rewrite_both(text, machine_axes=AXES):
    """Parse and rewrite (translation + small rotation) with the compiled and the numpy paths."""
    shift = np.array([0.0123456, -0.0045, 0.002, 0.0, 0.001])[:len(machine_axes)]
    return _on_both_paths(lambda: gcode.rewrite(gcode.parse(text, axes=machine_axes, filename="p.nc"),
                                                lambda q: q + shift))


@pytest.mark.parametrize("i", range(len(CORPUS)), ids=[p.name for p in CORPUS_FILES])
def test_corpus_rewrite_same_bytes_compiled_and_numpy(i):
    a, b = _rewrite_both(CORPUS[i])
    assert a == b


@pytest.mark.parametrize("seed_", [1, 2, 3])
def test_generated_program_rewrite_same_bytes_compiled_and_numpy(seed_):
    import importlib.util
    spec = importlib.util.spec_from_file_location(
        "bench_gcode", Path(__file__).resolve().parents[1] / "benchmarks" / "bench_gcode.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    a, b = _rewrite_both(bench.generate(3000, seed=seed_))
    assert isinstance(a, str) and a == b and a.count("\n") > 2900


def test_install_hook_builds_the_tokenizer_the_loader_looks_for():
    """setup.py compiles _tok.c at install under the name (source and flags hashed) that _ctok
    looks for first: a non-editable install has the file next to _ctok; in an editable checkout
    the hook's name is checked against the loader's."""
    root = Path(_ctok.__file__).resolve().parents[2]
    setup_py = root / "setup.py"
    if setup_py.is_file():
        # setup.py calls setup() at import: run its definitions before the build class alone
        ns: dict = {"__file__": str(setup_py)}
        exec(compile(setup_py.read_text().split("class BuildWithKernel")[0], str(setup_py), "exec"), ns)
        assert ns["TOK_CFLAGS"] == _ctok.CFLAGS
        assert ns["tok_name"]() == _ctok.packaged_name(_ctok.source_hash())
    else:
        assert (Path(_ctok.__file__).parent / _ctok.packaged_name(_ctok.source_hash())).is_file()


@seed(22)
@settings(max_examples=200, deadline=None, suppress_health_check=list(HealthCheck))
@given(st.lists(st.integers(-2**52, 2**52), min_size=1, max_size=40), st.integers(0, 9),
       st.sampled_from([1, 2, 5, 10]), st.integers(0, 1000), st.randoms(use_true_random=False))
def test_replace_edits_same_as_the_formatter_and_the_gathers(counts, decimals, mult, base, rnd):
    """mtc_replace_edits: the texts of the numpy formatter (textops.format_counts of the
    products), the word spans gathered as rewrite._column_edits gathers them, offsets after
    ``base``, on random rows of a word-column table with gaps."""
    from mtcomp.gcode.textops import format_counts
    n = len(counts)
    counts = np.array(counts, np.int64)
    cw = np.full((n, 3), -1, np.int32)
    words = rnd.sample(range(3 * n), n)
    cw[:, 1] = words
    cw[::3, 1] = -1                                   # blocks without the word: not replaced
    w_num = np.arange(3 * n, dtype=np.int32) * 7 + 1
    w_end = w_num + np.array([rnd.randint(1, 6) for _ in range(3 * n)], np.int32)
    rows = np.flatnonzero(cw[:, 1] >= 0)
    rows = np.array(sorted(rnd.sample(list(rows), len(rows) // 2 + 1 if len(rows) else 0)), np.int64)
    got = _ctok.replace_edits(counts, rows, mult, decimals, cw, 1, w_num, w_end, base)
    buf, pos, stop, off, ln = got
    rb, ro, rl = format_counts(counts[rows] * mult, decimals)
    for i in range(len(rows)):
        assert buf[off[i] - base:off[i] - base + ln[i]].tobytes() == rb[ro[i]:ro[i] + rl[i]].tobytes()
    assert [d.dtype for d in (pos, stop, off, ln)] == [np.int32] * 4
    np.testing.assert_array_equal(pos, w_num[cw[rows, 1]])
    np.testing.assert_array_equal(stop, w_end[cw[rows, 1]])
    assert len(buf) == int(rl.sum()) and (np.diff(off) == ln[:-1]).all()
    if n >= 1 and (cw[:, 1] < 0).any():
        with pytest.raises(ValueError):              # a row without a word is refused
            _ctok.replace_edits(counts, np.flatnonzero(cw[:, 1] < 0), mult, decimals, cw, 1, w_num,
                                w_end, base)
    with pytest.raises(ValueError):                  # a row out of range too
        _ctok.replace_edits(counts, np.array([n], np.int64), mult, decimals, cw, 1, w_num, w_end, base)


@seed(24)
@settings(max_examples=200, deadline=None, suppress_health_check=list(HealthCheck))
@given(st.integers(0, 30), st.integers(1, 6), st.randoms(use_true_random=False), st.booleans())
def test_add_counts_same_as_numpy(N, n, rnd, every):
    """mtc_add_counts: the rewrite's ``Cc[1 + kk] += dK; nan_to_num(Cc).astype(int64)`` to the
    bit, with NaN cells (rows not known), all rows or a subset corrected; a sum that numpy
    converts differently between platforms (infinite, beyond int64) is left to numpy (None)."""
    Cc = np.array([[rnd.choice([np.nan, float(rnd.randint(-2**52, 2**52)), -0.0])
                    for _ in range(n)] for _ in range(N + 1)])
    kk = np.arange(N) if every else np.array(sorted(rnd.sample(range(N), rnd.randint(0, N))), np.int64)
    dK = np.array([[float(rnd.randint(-1000, 1000)) for _ in range(n)] for _ in kk]).reshape(len(kk), n)
    ref = Cc.copy()
    ref[1 + kk] += dK
    ref = np.nan_to_num(ref, nan=0.0).astype(np.int64)
    before = Cc.copy()
    got = _ctok.add_counts(Cc, dK, None if every else kk)
    np.testing.assert_array_equal(got, ref)
    assert got.dtype == np.int64 and np.array_equal(np.isnan(Cc), np.isnan(before))
    if N:
        for bad in (np.inf, -np.inf, 2.0**64, -2.0**65):
            C2 = Cc.copy()
            C2[1, 0] = bad
            assert _ctok.add_counts(C2, dK, None if every else kk) is None
