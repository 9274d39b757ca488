"""The compiled block building of `mtcomp.gcode.parse` (line starts, forward fills, the words'
scatter into block columns, absolute positions: ``core/gcode/_tok.c``) against the numpy path it
stands in for: every array of the parsed program the same to the bit, and the same refusals, on
every NC program of tests/data and examples, the fuzz campaign's seed programs and mutations of
them, and a generated 5-axis program (issue 16 item 4)."""
from __future__ import annotations

import dataclasses
import random
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from mtcomp import InputError, gcode
from mtcomp.gcode import _ctok, flow

_ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(_ROOT / "benchmarks"))
import bench_gcode  # noqa: E402
import fuzz  # noqa: E402

_DATA = _ROOT / "tests" / "data" / "nc"
_SUFFIXES = {".nc", ".ngc", ".mpf", ".tap", ".gcode"}
FILES = sorted(p for root in (_DATA, _ROOT / "examples") for p in root.rglob("*")
               if p.is_file() and p.suffix.lower() in _SUFFIXES)


def _text(p: Path) -> str:
    t = gcode.read_program(p)
    try:
        f = flow.expand(t, search=[str(_DATA / "subprograms")])
    except InputError:
        return t
    return f.expanded if f else t


PROGRAMS = ([(p.relative_to(_ROOT).as_posix(), _text(p)) for p in FILES]
            + [(f"fuzz.{n}", getattr(fuzz, n)) for n in ("SMALL5", "ARCS", "G43", "G43W")]
            + [("generated", bench_gcode.generate(3000, seed=7))])
AXIS_SETS = [("X", "Y", "Z", "B", "C"), ("X", "Y", "Z"), ("X", "Y", "Z", "A", "B", "C")]
BLOCK_FUNCS = ("line_starts", "ffill", "word_lines", "scatter", "absolute")

pytestmark = pytest.mark.skipif(_ctok.load() is None, reason="no C compiler: numpy path only")


def _parse(text, axes, mode, monkeypatch):
    """mode: "c" everything compiled, "numpy-blocks" the compiled tokenizer with the numpy
    block building, "python" no compiled code at all."""
    with monkeypatch.context() as mp:
        if mode == "python":
            mp.setenv("MTCOMP_TOKENIZER", "python")
        else:
            mp.delenv("MTCOMP_TOKENIZER", raising=False)
        if mode == "numpy-blocks":
            for name in BLOCK_FUNCS:
                mp.setattr(_ctok, name, lambda *a, **k: None)
        try:
            return gcode.parse(text, axes=axes, filename="p.nc", tcp=True, rotation=True,
                               start={"Z": 50.0} if "Z" in axes else None)
        except InputError as exc:
            return f"InputError: {exc}"
        except ValueError as exc:
            return f"ValueError: {exc}"


def _bits(x: np.ndarray):
    return x.view(np.uint8) if x.dtype.kind in "fc" else x


def assert_same_program(a, b):
    if isinstance(a, str) or isinstance(b, str):
        assert a == b
        return
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert isinstance(y, np.ndarray), f.name
            assert x.dtype == y.dtype and x.shape == y.shape, f.name
            assert np.array_equal(_bits(np.ascontiguousarray(x)), _bits(np.ascontiguousarray(y))), f.name
        else:
            assert x == y, f.name


@pytest.mark.parametrize("axes", AXIS_SETS, ids=["".join(a) for a in AXIS_SETS])
@pytest.mark.parametrize("name,text", PROGRAMS, ids=[n for n, _ in PROGRAMS])
def test_every_program_same_arrays_compiled_and_numpy(name, text, axes, monkeypatch):
    c = _parse(text, axes, "c", monkeypatch)
    assert_same_program(c, _parse(text, axes, "numpy-blocks", monkeypatch))
    assert_same_program(c, _parse(text, axes, "python", monkeypatch))


def test_the_programs_are_read():
    """The corpus is not empty and most of it parses (a parity test over refusals only would
    prove little)."""
    assert len(FILES) >= 20
    ok = sum(not isinstance(_parse(t, AXIS_SETS[0], "c", pytest.MonkeyPatch()), str)
             for _, t in PROGRAMS)
    assert ok >= len(PROGRAMS) // 2


@pytest.mark.parametrize("seed_", range(6))
def test_mutated_seed_programs_same_result(seed_, monkeypatch):
    rng = random.Random(seed_)
    pool = [t for _, t in PROGRAMS[-5:]]
    for _ in range(25):
        text = fuzz.mutate(rng.choice(pool), rng, pool)
        c = _parse(text, AXIS_SETS[0], "c", monkeypatch)
        assert_same_program(c, _parse(text, AXIS_SETS[0], "numpy-blocks", monkeypatch))


def _ffill_numpy(values, isset, default):
    idx = np.where(isset, np.arange(len(values)), -1)
    np.maximum.accumulate(idx, out=idx)
    return np.where(idx >= 0, values[np.maximum(idx, 0)], default)


@pytest.mark.parametrize("kind", ["f8", "i8", "?"])
def test_forward_fill_same_as_numpy(kind):
    rng = np.random.default_rng(3)
    n = 1000
    values = {"f8": rng.normal(size=n), "i8": rng.integers(-5, 5, n), "?": rng.random(n) > 0.5}[kind]
    if kind == "f8":
        values[::7] = np.nan
        values[::11] = -0.0
    isset = rng.random(n) > 0.8
    isset[:20] = False
    for first in (False, True):                  # nothing set at the start / the first set
        isset[0] = first
        for default in {"f8": (np.nan, 0.0, -0.0), "i8": (-1, 40), "?": (False, True)}[kind]:
            got = _ctok.ffill(values, isset, default)
            want = _ffill_numpy(values, isset, default)
            assert got.dtype == want.dtype
            assert np.array_equal(_bits(got), _bits(want))
    assert _ctok.ffill(np.zeros(n, np.int32), isset, 0) is None       # other kinds: numpy


def test_absolute_positions_same_bits_as_numpy():
    """Increments, absolute words, NaN words (axes made unknown), -0.0 increments, offsets
    and column slices of a wider array."""
    import importlib
    parse_mod = importlib.import_module("mtcomp.gcode.parse")
    rng = np.random.default_rng(5)
    n, n_ax = 2000, 5
    wide = rng.normal(0, 10, (n, n_ax + 4)).round(4)
    wide[rng.random((n, n_ax + 4)) < 0.02] = np.nan
    wide[rng.random((n, n_ax + 4)) < 0.05] = -0.0
    vals = wide[:, :n_ax]
    present = rng.random((n, n_ax)) > 0.4
    incremental = rng.random(n) > 0.7
    incremental[0] = True                        # a -0.0 first increment: cumsum keeps its sign
    present[0] = True
    wide[0] = -0.0
    for offset in (np.zeros((n, n_ax)), rng.normal(0, 1, (n, n_ax))):
        for start in (np.full(n_ax, np.nan), np.array([0.0, -0.0, 1.5, np.nan, 3.0])):
            got = _ctok.absolute(vals, present, incremental, offset, bool(offset.any()), start)
            with pytest.MonkeyPatch.context() as mp:
                mp.setattr(_ctok, "absolute", lambda *a, **k: None)
                want = parse_mod._absolute(vals, present, incremental, offset, start)
            assert np.array_equal(_bits(got), _bits(want))


def test_word_scatter_falls_back_where_a_word_has_no_block():
    wcol = np.array([0, 1, -1, 2, 6], np.int8)
    wline = np.array([0, 0, 1, 2, 2], np.int32)
    value = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    blk = np.array([0, -1, -1], np.int64)
    assert _ctok.scatter(wcol, wline, value, blk, 1, 9, 5) is None
    blk = np.array([0, -1, 1], np.int64)
    cw, v, arc = _ctok.scatter(wcol, wline, value, blk, 2, 9, 5)
    assert cw.tolist() == [[0, 1] + [-1] * 7, [-1, -1, 3, -1, -1, -1, 4, -1, -1]]
    assert v.shape == (2, 5) and arc.shape == (2, 4)
    assert v[1, 2] == 4.0 and np.isnan(v[1, 0]) and np.isnan(v[0, 2]) and v[0, 1] == 2.0
    assert arc[1, 1] == 5.0 and np.isnan(arc[0]).all() and np.isnan(arc[1, [0, 2, 3]]).all()


@pytest.mark.parametrize("mode", ["c", "python"])
def test_two_codes_of_one_group_refused_at_the_first_such_line(mode, monkeypatch):
    """The duplicate test reads neighbouring G words (text order): the first group in the
    order the parser checks them (motion before distance mode), its first such line."""
    text = "G1 X0\nG90 G91 X1\nG1 X2\nG0 G1 X3\nG2 G3 X4 R5\n"
    got = _parse(text, AXIS_SETS[0], mode, monkeypatch)
    assert got == "InputError: p.nc:4: two motion (G0 G1 G2 G3) G codes in one block"
    got = _parse("G1 X0\nG90 G91 X1\nG17 G18 G19\nG91 G90\n", AXIS_SETS[0], mode, monkeypatch)
    assert got == "InputError: p.nc:3: two plane (G17 G18 G19) G codes in one block"


def test_number_runs_of_every_length_same_tokens_and_bits_as_numpy(monkeypatch):
    """The tokenizer's eight-bytes-at-a-time path for the common run ([sign] up to 7 digits
    [. up to 7 digits]) and its byte loop for the others (8 digits and more, two points,
    inner signs, runs near the end of the text) against the numpy tokenizer: every integer
    and fraction length 0-9, signs, each ending, and the whole program's arrays."""
    from mtcomp.gcode.textops import parse_decimals
    from mtcomp.gcode.tokens import _tokenise
    rng = random.Random(11)
    words = []
    for k1 in range(10):
        for k2 in [None] + list(range(10)):
            for sign in ("", "-", "+"):
                ip = "".join(rng.choice("0123456789") for _ in range(k1))
                fp = "" if k2 is None else "." + "".join(rng.choice("0123456789") for _ in range(k2))
                words.append(sign + ip + fp)
    ends = [" ", "\n", "X", "(", "\t", ";", ""]
    text = "".join(f"X{w}{ends[i % len(ends)]}" if ends[i % len(ends)] != "" else f"X{w} "
                   for i, w in enumerate(words)) + "Y1.5\nZ-2"
    code = np.frombuffer(text.encode(), np.uint8).copy()
    ls = np.concatenate(([0], np.flatnonzero(code == 10) + 1))
    c, p = _ctok.tokenise(code, full=True), _tokenise(code, ls)
    for k in range(6):
        assert np.array_equal(c[k], p[k]), k
    assert c[6:8] == p[6:8]
    good = [i for i in range(len(c[1]))
            if re.fullmatch(rb"[+-]?(\d+\.?\d*|\.\d+)", code[c[1][i]:c[2][i]].tobytes())]
    assert len(good) > 300
    ref = parse_decimals(code, p[1][good], p[2][good], p[3][good])
    assert np.array_equal(c[8][good].view(np.int64), ref.view(np.int64))
    # a valid program of such words: every array the same on the compiled and numpy paths
    valid = "\n".join("G1 " + " ".join(f"{a}{w}" for a, w in zip("XYZBC", chunk))
                      for chunk in zip(*[iter([w for w in words if re.fullmatch(r"[+-]?(\d+\.?\d*|\.\d+)", w)])] * 5))
    a_ = _parse(valid, AXIS_SETS[0], "c", monkeypatch)
    assert not isinstance(a_, str)
    assert_same_program(a_, _parse(valid, AXIS_SETS[0], "python", monkeypatch))


def _splice_reference(orig: bytes, edits) -> bytes:
    """The edits (pos, stop, text), sorted and not overlapping, applied by joining pieces."""
    out, prev = [], 0
    for p, e, t in edits:
        out += [orig[prev:p], t]
        prev = max(prev, e)
    return b"".join(out + [orig[prev:]])


@pytest.mark.parametrize("seed_", range(4))
def test_in_place_splice_same_bytes_as_joining_pieces(seed_):
    """The compiled splice moves the kept segments inside the output buffer (towards the start
    front to back, towards the end back to front): growing, shrinking and mixed programs of
    edits, inserts at one position, removals up to the end, against joining the pieces."""
    from mtcomp.gcode.textops import splice
    rng = random.Random(seed_)
    for case in range(150):
        n = rng.choice([0, 1, 5, 40, 300, 2000])
        orig = bytes(rng.choice(b"XYZ0123456789. \n") for _ in range(n))
        bias = rng.choice(["grow", "shrink", "mixed"])
        edits, p = [], 0
        while p <= n and len(edits) < rng.choice([1, 3, 30, 200]):
            p = min(n, p + rng.randint(0, 25))
            w = rng.randint(0, 6) if bias != "grow" else rng.randint(0, 1)
            e = min(n, p + w)
            k = rng.randint(0, 2) if bias == "shrink" else rng.randint(0, 12)
            edits.append((p, e, bytes(rng.choice(b"ABC-") for _ in range(k))))
            p = e if e > p else p
            if p >= n and rng.random() < 0.5:
                break
        src = b"".join(t for _, _, t in edits)
        off = np.cumsum([0] + [len(t) for _, _, t in edits])[:-1]
        got = splice(np.frombuffer(orig, np.uint8), np.array([e[0] for e in edits]),
                     np.array([e[1] for e in edits]), np.arange(len(edits)),
                     np.frombuffer(src, np.uint8), off, np.array([len(t) for _, _, t in edits]))
        assert bytes(got) == _splice_reference(orig, edits), (seed_, case)


def test_columns_within_is_numpys_min_and_max():
    """The travel checks' quick test: per column min >= lo and max <= hi as numpy says it
    (NaN anywhere: False), values on the bounds, infinities, -0.0, column slices of a wider
    array, one row, many columns."""
    rng = np.random.default_rng(11)
    for n, n_col in ((1, 1), (7, 3), (3000, 5), (500, 70)):
        wide = rng.uniform(-2, 2, (n, n_col + 2))
        lo = rng.uniform(-2.5, -1.5, n_col)
        hi = rng.uniform(1.5, 2.5, n_col)
        for case in range(6):
            P = wide.copy()
            if case == 1:
                P[rng.integers(0, n), rng.integers(0, n_col)] = np.nan
            if case == 2:
                P[rng.integers(0, n), rng.integers(0, n_col)] = rng.choice([np.inf, -np.inf])
            if case == 3:                        # exactly on the bounds, and -0.0
                P[0, :n_col], P[-1, :n_col] = lo, hi
                P[n // 2, 0] = -0.0
            if case == 4:
                P = np.clip(P, -1.4, 1.4)        # everything inside
            if case == 5:
                P[:, :n_col] = np.where(rng.random((n, n_col)) < 0.01, np.nan, np.clip(P[:, :n_col], -1.4, 1.4))
            view = P[:, 1:n_col + 1] if case % 2 else P[:, :n_col]
            got = _ctok.columns_within(view, lo, hi)
            want = [bool(view[:, k].min() >= lo[k] and view[:, k].max() <= hi[k]) for k in range(n_col)]
            assert got.dtype == bool and got.tolist() == want, (n, n_col, case)
    assert _ctok.columns_within(np.zeros((4, 3))[:, ::2], np.zeros(2), np.ones(2)) is None
