"""The shared CSV reader (mtcomp.csvtable): values written are read back exactly, line numbers
are the file's lines across comments and blank lines, units convert, and any text either
parses or is an InputError.  Seeded and derandomized, a few seconds in CI."""
import csv
import io
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mtcomp import InputError
from mtcomp.csvtable import UNITS, parse_csv, read_csv, unit_factor

FUZZ = settings(max_examples=80, derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

numbers = st.floats(min_value=-1e9, max_value=1e9, allow_nan=False, allow_infinity=False)
noise = st.sampled_from(["", "   ", "# comment", "  # indented comment, with a comma", "#"])


@FUZZ
@given(st.lists(st.lists(numbers, min_size=3, max_size=3), min_size=1, max_size=20),
       st.lists(noise, max_size=25), st.randoms(use_true_random=False), st.sampled_from(["\n", "\r\n"]))
def test_values_and_line_numbers(rows, extra, rnd, eol):
    body = [["a [mm]", "b", "c [um]"]] + [[repr(x) for x in r] for r in rows]
    lines = []
    for cells in body:
        buf = io.StringIO()
        csv.writer(buf, lineterminator="").writerow(cells)
        lines.append(buf.getvalue())
    data_idx = list(range(1, len(lines)))
    for e in extra:  # comments and blank lines anywhere after the header
        lines.insert(rnd.randint(1, len(lines)), e)
    text = eol.join(lines) + eol
    t = parse_csv(text, "x.csv", required=("a", "b", "c"))
    want_lines = [n for n, ln in enumerate(lines, 1) if ln.strip() and not ln.strip().startswith("#")][1:]
    assert list(t.lines) == want_lines and len(data_idx) == len(t)
    a = t.numbers("a", unit="mm")
    assert a.tolist() == [r[0] for r in rows]                      # exact: repr round trip
    assert t.numbers("b").tolist() == [r[1] for r in rows]
    c = t.numbers("c", unit="mm", max_abs=1e12)
    assert np.allclose(c, [r[2] * 1e-3 for r in rows], rtol=1e-15, atol=0)
    for i in range(len(t)):
        assert t.number(i, "a", unit="um", max_abs=1e15) == pytest.approx(rows[i][0] * 1e3, rel=1e-15)


TOKENS = ["a", "b", "[mm]", "(um)", "[deg]", ",", ",", ",", ";", "\t", "\n", "\n", "#", " ", '"', '""', "1",
          "-2.5", ".5", "5.", "1e3", "1e999", "nan", "+inf", "0x10", "1_0", "\u0663", "\x00", "\r", "\ufeff",
          "\u2028", "\x0c", "-", "e5", "1e", "--1"]


@FUZZ
@given(st.lists(st.sampled_from(TOKENS), max_size=50), st.sampled_from([",", None]), st.booleans())
def test_any_text_parses_or_is_an_input_error(tokens, delim, pad):
    text = "".join(tokens)
    try:
        t = parse_csv(text, "f.csv", delimiter=delim, pad=pad)
    except InputError as exc:
        assert str(exc).startswith("f.csv")
        return
    for name in t.names:
        try:
            x = t.numbers(name, max_abs=1e12)
        except InputError as exc:
            assert exc.line is not None and exc.field
            continue
        assert np.all(np.isfinite(x)) and np.all(np.abs(x) <= 1e12)
        for i, s in enumerate(r[t.col(name).index] for r in t.rows):  # strict: what float() reads the same
            assert x[i] == float(s) or (unit_factor(t.col(name).unit, None) != (1.0, 0.0))


def test_units_table_is_consistent():
    for u, (q, f, off) in UNITS.items():
        assert f > 0 and math.isfinite(f)
        base = {"length": "mm", "angle": "rad", "time": "s", "temperature": "degC", "speed": "rpm"}[q]
        assert unit_factor(u, base) == (f, off)
    assert unit_factor("deg", "rad")[0] == pytest.approx(math.pi / 180, rel=1e-15)
    assert unit_factor("K", "degC") == (1.0, -273.15)
    with pytest.raises(InputError, match="not a unit of"):
        unit_factor("mm", "rad", source="f.csv", line=1, column="x")


def test_read_csv_bom_and_line_endings(tmp_path):
    f = tmp_path / "t.csv"
    f.write_bytes(b"\xef\xbb\xbf# note\r\nx,y\r\n1,2\r\r\n3,4")
    t = read_csv(f)
    assert t.names == ("x", "y") and t.lines == (3, 5) and t.comments == ("note",)
    assert t.numbers("y").tolist() == [2.0, 4.0]
