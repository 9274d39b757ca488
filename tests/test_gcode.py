"""NC program reader/rewriter: byte-exact round trips, refusals with file:line, arcs, G91, inch."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mtcomp import InputError
from mtcomp import gcode
from mtcomp.gcode.textops import format_counts, parse_decimals

ROOT = Path(__file__).resolve().parent.parent
PROGRAMS = sorted((ROOT / "examples" / "programs").glob("*.nc"))
XYZBC = ("X", "Y", "Z", "B", "C")


def shift(d):
    d = np.asarray(d, float)
    return lambda q: q + d


def rot_x(deg):
    """Rotation of X Y Z about the X axis (tilts G17 arcs out of their plane)."""
    a = np.radians(deg)

    def f(q):
        q = q.copy()
        y, z = q[:, 1].copy(), q[:, 2].copy()
        q[:, 1] = np.cos(a) * y - np.sin(a) * z
        q[:, 2] = np.sin(a) * y + np.cos(a) * z
        return q
    return f


def rot_z(deg, centre=(0.0, 0.0)):
    """Rotation of X Y about Z (keeps G17 arcs in their plane)."""
    a = np.radians(deg)

    def f(q):
        q = q.copy()
        x, y = q[:, 0] - centre[0], q[:, 1] - centre[1]
        q[:, 0] = centre[0] + np.cos(a) * x - np.sin(a) * y
        q[:, 1] = centre[1] + np.sin(a) * x + np.cos(a) * y
        return q
    return f


# ----------------------------------------------------------------------------------- numbers

def test_parse_decimals_matches_float():
    words = ["1", "-.5", "+2.", "0.1", "12345678.12345678", "-0", ".000001", "123456789.5",
             "1.123456789", "99999999.99999999", "0.30000000000000004", "7", "-123.456789"]
    rng = np.random.default_rng(3)
    words += [f"{v:.{d}f}" for v, d in zip(rng.normal(0, 1e3, 2000), rng.integers(0, 9, 2000))]
    text = " ".join("X" + w for w in words).encode()
    b = np.frombuffer(text, np.uint8)
    starts = np.array([m.start() + 1 for m in re.finditer(rb"X", text)])
    ends = np.array([m.end() for m in re.finditer(rb"X[-+.0-9]+", text)])
    dots = np.array([text.find(b".", s, e) for s, e in zip(starts, ends)])
    got = parse_decimals(b, starts, ends, dots)
    assert np.array_equal(got, np.array([float(w) for w in words]))


@pytest.mark.parametrize("decimals", [0, 1, 3, 5, 6, 9])
def test_format_counts_fixed_point(decimals):
    rng = np.random.default_rng(decimals)
    c = np.concatenate([[0, 1, -1, 10 ** decimals, -(10 ** decimals)], rng.integers(-10**11, 10**11, 500)])
    buf, off, ln = format_counts(c, decimals)
    texts = [buf[o:o + n].tobytes().decode() for o, n in zip(off, ln)]
    for ci, t in zip(c, texts):
        assert "e" not in t and t != "-" + "0." + "0" * decimals
        assert t.count(".") == 1 and len(t.split(".")[1]) == decimals
        assert round(float(t) * 10 ** decimals) == ci
    assert texts[0] == "0." + "0" * decimals


# ------------------------------------------------------------------------------- round trips

def test_example_programs_exist():
    names = {p.name for p in PROGRAMS}
    assert "groove5x.nc" in names
    text = (ROOT / "examples" / "programs" / "groove5x.nc").read_text()
    p = gcode.parse(text, axes=XYZBC)
    assert 50 <= p.n_lines <= 200
    assert p.is_arc.any() and p.incremental.any()
    assert {0, 1, 2, 3} <= set(np.asarray(p.motion).tolist())


@pytest.mark.parametrize("path", PROGRAMS, ids=lambda p: p.name)
def test_examples_round_trip_byte_exact(path):
    text = path.read_text()
    p = gcode.parse(text, axes=XYZBC, filename=path.name)
    assert gcode.write(p) == text
    assert gcode.rewrite(p, lambda q: q) == text
    # a change below half the resolution also reproduces the input
    assert gcode.rewrite(p, shift([3e-7, -3e-7, 2e-7, 3e-6, -3e-6])) == text


STYLES = [
    "N10 G90 G1 X1. Y2. F100.\r\nN20 X3.5 (CRLF)\r\nN30 G91 Y-1.\r\n",
    "G1X1.Y2.Z3.\nX4.;compact\n",
    "%\nO0042\n  N1 G0 X0 Y0\t\t(tabs)\n/M01\n\nG1 X1.000 Y-.5 Z+2.\n%",   # no final newline
    "g1 x1.5 y2.5 f10.\n",                                                 # lower case
    "G1 X1. (A;B) Y2. ; (C) ...\n",
]


@pytest.mark.parametrize("text", STYLES)
def test_style_round_trip(text):
    p = gcode.parse(text, axes=XYZBC)
    assert gcode.rewrite(p, lambda q: q) == text


def test_crlf_kept_and_words_changed():
    text = "N10 G90 G1 X1. Y2. F100.\r\nN20 X3.5 (CRLF)\r\n"
    out = gcode.rewrite(gcode.parse(text, axes=XYZBC), shift([0.25, 0, 0, 0, 0]))
    assert out == "N10 G90 G1 X1.250000 Y2. F100.\r\nN20 X3.750000 (CRLF)\r\n"


def test_insertion_in_canonical_order_and_style():
    p = gcode.parse("N1 G90 G1 Z1. F10\nN2 Y2. C3.\n", axes=("C", "B", "X", "Y", "Z"), start=[0] * 5)
    out = gcode.rewrite(p, shift([0.1, 0.2, 0.3, 0.4, 0.5]))
    assert out == ("N1 G90 G1 X0.300000 Y0.400000 Z1.500000 B0.20000 C0.10000 F10\n"
                   "N2 Y2.400000 C3.10000\n")
    p = gcode.parse("G1X1.Y2.\nZ3.\n", axes=("X", "Y", "Z"), start={"Z": 0})
    assert gcode.rewrite(p, lambda q: q + 0.5) == "G1X1.500000Y2.500000Z0.500000\nZ3.500000\n"


def test_number_format_follows_resolution():
    p = gcode.parse("G1 X1. B2.\n", axes=XYZBC)
    out = gcode.rewrite(p, shift([-1.0000004, 0, 0, 1e-3, 0]))
    assert out == "G1 X0.000000 B2.00100\n"           # -4e-7 gives no "-0.000000"; B: 5 decimals
    out = gcode.rewrite(p, shift([0.123456789, 0, 0, 0, 0]), resolution={"X": 3})
    assert out == "G1 X1.123 B2.\n"
    out = gcode.rewrite(p, shift([0.123456789, 0, 0, 0, 0]), resolution={"X": 1e-4})
    assert out == "G1 X1.1235 B2.\n"
    # a resolution that is not a power of ten (issue 15: 5e-6 crashed): multiples of it
    out = gcode.rewrite(p, shift([0.123456789, 0, 0, 0, 0]), resolution={"X": 5e-6})
    assert out == "G1 X1.123455 B2.\n"
    with pytest.raises(ValueError):
        gcode.rewrite(p, shift([0, 0, 0, 0, 0]), resolution={"X": 1e-6 / 3})


_num = st.integers(-10**7, 10**7)


@st.composite
def programs(draw):
    """Random programs of linear moves in G90/G91 with assorted spacing, comments, N words."""
    lines = [draw(st.sampled_from(["%", "O1234", "(HEADER)", "G21 G17"]))]
    n = draw(st.integers(1, 25))
    for i in range(n):
        sep = draw(st.sampled_from([" ", "", "  ", "\t"]))
        words = []
        if draw(st.booleans()):
            words.append(f"N{i + 1}")
        if draw(st.integers(0, 4)) == 0:
            words.append(draw(st.sampled_from(["G90", "G91"])))
        if draw(st.integers(0, 3)) == 0:
            words.append(draw(st.sampled_from(["G0", "G1", "G01", "G00"])))
        for a in XYZBC:
            if draw(st.integers(0, 2)) == 0:
                d = 6 if a in "XYZ" else 5
                c = draw(_num)
                style = draw(st.integers(0, 2))
                if style == 0:
                    v = f"{c / 10**d:.{d}f}"
                elif style == 1:
                    v = f"{c // 10**d}" if c % 10**d == 0 else f"{c / 10**d:.{d}f}".rstrip("0")
                else:
                    v = f"{c / 10**d:.{d}f}".rstrip("0")
                words.append(a + v)
        if draw(st.integers(0, 5)) == 0:
            words.append("F" + str(draw(st.integers(1, 2000))) + ".")
        line = sep.join(words)
        tail = draw(st.sampled_from(["", " (C)", ";note", " ; x (y)"]))
        lines.append(line + tail)
    eol = draw(st.sampled_from(["\n", "\r\n"]))
    return eol.join(lines) + draw(st.sampled_from([eol, ""]))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(programs())
def test_hypothesis_round_trip(text):
    p = gcode.parse(text, axes=XYZBC)
    assert gcode.write(p) == text
    assert gcode.rewrite(p, lambda q: q) == text


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(programs(), st.lists(st.integers(-2000, 2000), min_size=5, max_size=5))
def test_hypothesis_translation_reparses(text, d):
    """Output re-read gives exactly the transformed positions (at the resolution), G90 and G91."""
    p = gcode.parse(text, axes=XYZBC, start=np.zeros(5))
    d = np.array(d) * np.array([1e-4, 1e-4, 1e-4, 1e-3, 1e-3])
    out = gcode.rewrite(p, shift(d))
    q = gcode.parse(out, axes=XYZBC, start=np.zeros(5))
    assert np.array_equal(q.line, p.line)
    res = np.array([1e-6, 1e-6, 1e-6, 1e-5, 1e-5])
    expect = np.rint((p.position + d) / res)
    # axes never written stay where the control starts, unless the transform moved them
    assert np.array_equal(np.rint(q.position / res), expect)


# ------------------------------------------------------------------------------------ G91

def test_g91_increments_are_differences_of_transformed_positions():
    text = ("G90 G1 X1. Y1. Z0\nG91\n" + "X0.1 Y0.05\n" * 50 + "G90 X10. Y0\n")
    p = gcode.parse(text, axes=("X", "Y", "Z"))
    tf = rot_z(7.0, centre=(0.3, -0.2))
    out = gcode.rewrite(p, tf)
    q = gcode.parse(out, axes=("X", "Y", "Z"))
    res = 1e-6
    # the control sums the written increments exactly: positions equal rounded transformed ones
    assert np.array_equal(np.rint(q.position / res), np.rint(tf(p.position) / res))
    assert q.incremental.sum() == p.incremental.sum()


# ------------------------------------------------------------------------------------- arcs

ARCS = """G90 G17 G1 X10. Y0 Z0 F100.
G3 X0 Y10. I-10. J0
G2 X-10. Y0 R10.
G3 X0 Y-10. R-10.
G2 J10. (full circle)
G3 X10. Y0 Z2. J10. (helix)
"""


def test_arc_geometry_read():
    p = gcode.parse(ARCS, axes=("X", "Y", "Z"))
    sw = np.asarray(p.arc_sweep)
    assert np.isnan(sw[0])
    assert sw[1] == pytest.approx(np.pi / 2) and sw[2] == pytest.approx(-np.pi / 2)
    assert sw[3] == pytest.approx(1.5 * np.pi)  # R negative: the long way round
    assert sw[4] == pytest.approx(-2 * np.pi) and sw[5] == pytest.approx(np.pi / 2)
    assert np.allclose(p.arc_centre[1:6, :2], [[0, 0], [-10, 10], [-10, -10], [0, 0], [0, 0]],
                       atol=1e-12)
    assert p.arc_centre[5, 2] == 0 and p.position[5, 2] == 2


def test_r_negative_long_arc():
    p = gcode.parse("G90 G1 X10. Y0\nG3 X0 Y-10. R-10.\n", axes=("X", "Y", "Z"))
    assert p.arc_sweep[1] == pytest.approx(1.5 * np.pi)
    assert np.allclose(p.arc_centre[1, :2], [0, 0], atol=1e-12)


def test_arcs_kept_under_translation():
    p = gcode.parse(ARCS, axes=("X", "Y", "Z"))
    out = gcode.rewrite(p, shift([0.5, -0.25, 0.125]))
    assert "LINEARISED" not in out
    assert out.splitlines()[1:] == ["G3 X0.500000 Y9.750000 I-10. J0",
                                    "G2 X-9.500000 Y-0.250000 R10.",
                                    "G3 X0.500000 Y-10.250000 R-10.",
                                    "G2 J10. (full circle)",
                                    "G3 X10.500000 Y-0.250000 Z2.125000 J10. (helix)"]


def test_arcs_kept_under_rotation_in_plane():
    p = gcode.parse(ARCS, axes=("X", "Y", "Z"))
    tf = rot_z(30.0, centre=(1.0, 2.0))
    out = gcode.rewrite(p, tf)
    assert "LINEARISED" not in out
    q = gcode.parse(out, axes=("X", "Y", "Z"))
    assert np.allclose(q.position, tf(p.position), atol=1e-6)
    k = np.flatnonzero(p.is_arc)
    centre = tf(np.asarray(p.arc_centre)[k])
    assert np.allclose(q.arc_centre[k, :2], centre[:, :2], atol=2e-6)
    assert np.allclose(q.arc_sweep[k], p.arc_sweep[k], atol=1e-6)


def test_half_circle_in_r_format_linearised_under_rotation():
    # the control computes an R-format centre from the chord: with a rounded chord just below
    # the diameter, the centre moves by up to sqrt(2 R res) (4.5 um here), so keeping R is unsafe
    p = gcode.parse("G90 G1 X-10. Y0\nG3 X10. Y0 R-10.\n", axes=("X", "Y", "Z"))
    assert "R-10." in gcode.rewrite(p, shift([0.5, 0.25, 0]))
    out = gcode.rewrite(p, rot_z(30.0, centre=(1.0, 2.0)))
    assert "G1" in out.splitlines()[1] and "LINEARISED" in out


@pytest.mark.parametrize("tol", [1e-4, 1e-3])
def test_arcs_linearised_under_tilt_stay_on_the_transformed_arc(tol):
    p = gcode.parse(ARCS, axes=("X", "Y", "Z"), start=np.zeros(3))
    tf = rot_x(0.5)
    out = gcode.rewrite(p, tf, chordal_tol=tol)
    assert out.count("LINEARISED") == 5
    assert f"CHORDAL TOLERANCE {tol:.6f} MM" in out
    q = gcode.parse(out, axes=("X", "Y", "Z"), start=np.zeros(3))
    assert not q.is_arc.any()
    # every output point and every chord midpoint lies on a transformed block within tol:
    # measured in the untransformed frame (the tilt is a rotation)
    pts = np.vstack([q.start[None], q.position])
    back = rot_x(-0.5)
    for a, b in zip(pts[:-1], pts[1:]):
        x = back(np.array([a, (a + b) / 2, b]))
        d = _distance_to_program(p, x)
        assert np.all(d <= tol + 2e-6), (a, b, d)
    # ends of the arcs are the transformed ends exactly
    ends = np.rint(tf(p.position) / 1e-6)
    got = np.rint(q.position / 1e-6)
    for row in ends:
        assert (got == row).all(axis=1).any()


def _distance_to_program(p, x):
    """Distance of points x (m, 3) to the nearest block path of program p (X Y Z, G17)."""
    prev = np.vstack([p.start[None], p.position])
    best = np.full(len(x), np.inf)
    for i in range(len(p)):
        s, e = prev[i], p.position[i]
        if not p.is_arc[i]:
            se = e - s
            t = np.clip(((x - s) @ se) / max(se @ se, 1e-300), 0, 1)
            d = np.linalg.norm(x - (s + t[:, None] * se), axis=1)
        else:
            c, sw = p.arc_centre[i], p.arc_sweep[i]
            r = np.hypot(*(s[:2] - c[:2]))
            a0 = np.arctan2(s[1] - c[1], s[0] - c[0])
            phi = np.arctan2(x[:, 1] - c[1], x[:, 0] - c[0])
            f = np.mod(np.sign(sw) * (phi - a0), 2 * np.pi) / abs(sw)
            f = np.where(f > 1 + 1e-9, np.where(f - 1 < (2 * np.pi / abs(sw) - f), 1.0, 0.0), f)
            z = s[2] + (e[2] - s[2]) * f
            ang = a0 + sw * f
            on = np.column_stack([c[0] + r * np.cos(ang), c[1] + r * np.sin(ang), z])
            d = np.linalg.norm(x - on, axis=1)
        best = np.minimum(best, d)
    return best


def test_modal_arcs_linearised_or_kept_together():
    text = "G90 G17 G1 X10. Y0 Z0\nG3 X0 Y10. I-10. J0\nX-10. Y0 I0 J-10.\n"
    p = gcode.parse(text, axes=("X", "Y", "Z"))
    out = gcode.rewrite(p, rot_x(1.0), chordal_tol=1e-3)
    lines = out.splitlines()
    assert lines[1].startswith("G1 ") and "LINEARISED" in lines[1]
    q = gcode.parse(out, axes=("X", "Y", "Z"))
    assert not q.is_arc.any()
    assert gcode.rewrite(p, shift([0.1, 0, 0])).splitlines()[2] == "X-9.900000 Y0 I0 J-10."


def test_modal_arc_gets_its_g_word_when_the_previous_arc_is_linearised():
    # a transform that bends Z only where X > 5 distorts the first arc (X from 10 to 0) and
    # leaves the second one (X from 0 to -10) alone
    text = "G90 G17 G1 X10. Y30. Z0\nG3 X0 Y40. I-10. J0\nX-10. Y30. I0 J-10.\nG1 X10. Y0\n"
    p = gcode.parse(text, axes=("X", "Y", "Z"))

    def tf(q):
        q = q.copy()
        bend = q[:, 0] > 5.0
        q[bend, 2] += 1e-3 * (q[bend, 0] - 5.0) ** 2
        return q
    out = gcode.rewrite(p, tf, chordal_tol=1e-4)
    lines = out.splitlines()
    assert lines[1].startswith("G1 ") and "LINEARISED" in lines[1]
    third = [ln for ln in lines if ln.startswith("G3 X-10.") or ln.startswith("X-10.")]
    assert third == ["G3 X-10. Y30. I0 J-10."]
    q = gcode.parse(out, axes=("X", "Y", "Z"))
    assert q.motion[-2] == 3 and np.allclose(q.arc_centre[-2, :2], [0, 30], atol=1e-9)


def test_arc_in_g18_and_g19_kept_under_translation():
    text = "G90 G18 G1 X-5. Y0 Z0\nG2 X5. Z0 R50.\nG19 G1 X0 Y-5. Z0\nG3 Y5. Z0 J5. K0\n"
    p = gcode.parse(text, axes=("X", "Y", "Z"))
    assert p.arc_centre[1, 2] == pytest.approx(np.sqrt(2500 - 25))
    out = gcode.rewrite(p, shift([0.1, 0.2, 0.3]))
    assert "LINEARISED" not in out
    q = gcode.parse(out, axes=("X", "Y", "Z"))
    assert np.allclose(q.arc_centre[[1, 3]], p.arc_centre[[1, 3]] + [0.1, 0.2, 0.3], atol=1e-6)


# ------------------------------------------------------------------------------------- inch

INCH = "G20 G90 G1 X1. Y-0.5 F10.\nG91 X0.1\nG2 X1. Y0 I0.5 J0\n"


def test_inch_read_and_written_in_inch():
    p = gcode.parse(INCH, axes=("X", "Y", "Z"), filename="prog.nc", start=np.zeros(3))
    assert np.allclose(p.position[0, :2], [25.4, -12.7])
    assert np.allclose(p.position[1, 0], 27.94)
    assert p.feed[0] == pytest.approx(254.0)
    assert gcode.rewrite(p, lambda q: q) == INCH          # no flag, no conversion
    out = gcode.rewrite(p, shift([0.0254, 0, 0]))          # 0.001 in
    assert out == "G20 G90 G1 X1.0010000 Y-0.5 F10.\nG91 X0.1\nG2 X1. Y0 I0.5 J0\n"   # G91: same increments
    q = gcode.parse(out, axes=("X", "Y", "Z"), start=np.zeros(3))
    assert np.allclose(q.position[:, 0], p.position[:, 0] + 0.0254, atol=1e-9)
    with pytest.raises(InputError, match=r":3: the program switches between inch"):
        gcode.parse("G20 G0 X1.\nG21\nX1.\n", axes=("X", "Y", "Z"))


# ----------------------------------------------------------------------------------- refusals

REFUSALS = [
    ("G1 X1.\nG68 X0 Y0 R30.\n", 2, "G68 coordinate rotation changes"),
    ("G1 X1.\n\nG43.4 H1\n", 3, "G43.4 tool centre point: X Y Z are the tool tip"),
    ("G1 X1.\nG68.2 X0 Y0 Z0 I0 J30. K0\n", 2, "G68.2 tilted working plane"),
    ("G1 X1.\n\nG43.5 H1\n", 3, "G43.5 tool centre point with a tool vector"),
    ("G51 X0 Y0 P2\n", 1, "G51 scaling"),
    ("G10 L2 P0 X0\nG55 G0 X1.\n", 1, "G10 L2 P0 sets the external work offset"),
    ("G18 G7\nG0 X20. Z1.\n", 1, "G7 diameter mode (LinuxCNC lathe): X words are diameters"),
    ("G91 G81 R.1 Z-.5 ^60 L6 F10\n", 1, "LinuxCNC polar coordinates (@ distance, ^ angle)"),
    ("G5.1 Q3\n", 1, "G5.1 without Q1/Q0 (Fanuc smooth interpolation Q2, nano smoothing Q3)"),
    ("G0 X1.\nG5.1 Q2 X2.\n", 2, "G5.1 without Q1/Q0"),
    ("G6.2 Q1\n", 1, "unknown"),
    ("G1 X1.\nG12 X2.\n", 2, "unknown G code G12"),
    ("G1 X1.2.3\n", 1, "malformed number"),
    ("G1 X--1\n", 1, "malformed number"),
    ("G1 X-\n", 1, "malformed number"),
    ("G1 X\n", 1, "address X without a number"),
    ("G1 XNAN\n", 1, "unknown word"),
    ("G1 Xinf\n", 1, "unknown word"),
    ("G1 X1e5\n", 1, None),
    ("G1 X1.\nE5.\n", 2, "unknown address"),
    ("G1 A5.\n", 1, "axis word A"),
    ("#100=1.\n", 1, "macro variables (#)"),
    ("G1 X[1+2]\n", 1, "macro expressions"),
    ("G1 X1. (open comment\n", 1, "unbalanced"),
    ("G1 X1. ((nested))\n", 1, "unbalanced"),
    ("G1 X1. X2.\n", 1, "appears twice"),
    ("G0 G1 X1.\n", 1, "two motion"),
    ("G1 X1.\nG54\nX2.\nG55 X3.\n", 4, "switches from G54 to G55"),
    ("M98 P100\n", 1, "subprogram"),
    ("G1 X1.\n/G1 X2.\n", 2, "block delete"),
    ("12.5\n", 1, "without an address letter"),
    ("G1 X1. Y1.\nG3 X2. Y1. I0.3 J0\n", 2, "not on the circle"),
    ("G1 X1. Y0\nG2 X1. Y0 R1.\n", 2, "R-format arc with equal start and end"),
    ("G1 X0 Y0\nG2 X10. Y0 R2.\n", 2, "chord"),
    ("G1 X1. Y0 B0\nG2 X-1. Y0 I-1. J0 B5.\n", 2, "axis B moves during circular"),
    ("G1 X1. Y0\nG2 X-1. Y0 I-1. J0 K1.\n", 2, "does not belong to plane"),
    ("G1 X1.\nI5.\n", 2, "outside G2/G3"),
    ("G4 X1. Y2.\n", 1, "dwell"),
    ("G1 X1.\nM97 P100\n", 2, "M97 calls a local subprogram"),
    ("G1 X1.\nM99\n", 2, "M99"),
    ("M71\n", 1, "M71"),
    ("G65 P9010 A1.\n", 1, "G65 macro call"),
    ("o100 sub\nG1 X1.\no100 endsub\n", 1, "o-word program flow"),
    ("G50 X30. Z20.\n", 1, "G50 with axis words"),
    ("G1 X1. R2. I1.\nG3 X1. Y1. R1. I1.\n", 1, "outside G2/G3"),
]


@pytest.mark.parametrize("text,line,what", REFUSALS)
def test_refusals_name_file_and_line(text, line, what):
    with pytest.raises(InputError) as exc:
        gcode.parse(text, axes=XYZBC, filename="part.nc")
    msg = str(exc.value)
    assert msg.startswith(f"part.nc:{line}: "), msg
    assert exc.value.line == line
    if what:
        assert what in msg, msg


def test_dwell_x_is_time_not_axis():
    text = "G1 X1. Y1.\nG4 X2.5\nG4 P500\nX3.\n"
    p = gcode.parse(text, axes=XYZBC)
    assert len(p) == 2
    out = gcode.rewrite(p, shift([1.0, 0, 0, 0, 0]))
    assert out == "G1 X2.000000 Y1.\nG4 X2.5\nG4 P500\nX4.000000\n"


def test_transform_output_checked():
    p = gcode.parse("G1 X1.\n", axes=XYZBC)
    with pytest.raises(ValueError, match="shape"):
        gcode.rewrite(p, lambda q: q[:, :2])
    with pytest.raises(ValueError, match="non-finite"):
        gcode.rewrite(p, lambda q: q * np.nan)


def test_start_position_used_for_unwritten_axes():
    p = gcode.parse("G91 G1 X1.\n", axes=("X", "Y", "Z"), start={"X": 5.0})
    assert p.position[0, 0] == 6.0
    # the control starts at the (untransformed) start: the increment carries the shift
    assert gcode.rewrite(p, shift([0.5, 0, 0])) == "G91 G1 X1.500000\n"


# ------------------------------------------------------------------- with the machine model

def test_groove5x_compensated_with_setting_errors_reaches_the_programmed_edge_positions():
    from mtcomp.errors import ErrorSet, ToolSetting, WorkpieceSetting
    from mtcomp.kinematics import forward, retarget
    from mtcomp.machine import load_machine
    m = load_machine("robonano-a0ib")
    text = (ROOT / "examples" / "programs" / "groove5x.nc").read_text()
    p = gcode.parse(text, axes=m.axis_names, filename="groove5x.nc")
    err = ErrorSet(tool=ToolSetting((0.012, -0.004, 0.020)),
                   workpiece=WorkpieceSetting((0.010, 0.005, -0.003), (0.0, 0.0, 0.0)))
    out = gcode.rewrite(p, lambda q: retarget(m, q, err, check=False),
                        resolution=dict(zip(m.axis_names, m.resolutions)))
    assert out != text
    q = gcode.parse(out, axes=m.axis_names)
    # a rigid shift while the rotary axes stand still keeps every arc: one output block per input block
    assert np.array_equal(q.line, p.line)
    # every original block end is reached: edge with errors at the new commands equals the
    # ideal edge at the programmed commands (within the 1 nm / 1e-5 deg rounding)
    blocks = np.flatnonzero(np.isin(q.line, p.line))
    real = forward(m, q.position[blocks], err).p
    ideal = forward(m, p.position).p
    assert np.max(np.abs(real - ideal)) < 5e-6
    # everything that is not an axis word is unchanged: strip numbers after axis letters
    strip = lambda s: re.sub(r" ?[XYZBCIJKR][-+.0-9]+", "", s)
    assert [strip(a) for a in out.splitlines() if "LINEARISED" not in a][:40] == \
        [strip(a) for a in text.splitlines()][:40]


@pytest.mark.parametrize("text", ["", "\n", "(only a comment)\n", "%\n%", "M30"])
def test_programs_without_motion(text):
    p = gcode.parse(text, axes=XYZBC)
    assert len(p) == 0
    assert gcode.rewrite(p, shift([1, 1, 1, 1, 1])) == text


def test_lines_and_progress():
    text = "G1 X1.\r\n(A)\nY2."
    p = gcode.parse(text, axes=XYZBC, start=np.zeros(5))
    assert p.lines == ["G1 X1.\r\n", "(A)\n", "Y2."]
    seen = []
    out = gcode.rewrite(p, shift([0, 0, 0, 0, 0.5]), progress=lambda done, total: seen.append((done, total)))
    assert out == "G1 X1. C0.50000\r\n(A)\nY2."
    assert seen and seen[-1][0] == seen[-1][1] == len(out.encode())


def test_rewrite_with_lines_maps_blocks_to_output_lines():
    p = gcode.parse(ARCS, axes=("X", "Y", "Z"))
    out, lines = gcode.rewrite_with_lines(p, rot_x(0.5), chordal_tol=1e-3)
    q = gcode.parse(out, axes=("X", "Y", "Z"))
    tf = rot_x(0.5)
    at = {int(ln): i for i, ln in enumerate(q.line)}
    got = q.position[[at[int(ln)] for ln in lines]]
    assert np.allclose(got, tf(p.position), atol=1e-6)
    out2, lines2 = gcode.rewrite_with_lines(p, shift([1, 0, 0]))
    assert np.array_equal(lines2, p.line)


def test_g8_radius_mode_reads_x_as_the_axis_position():
    """LinuxCNC lathe programs start with G18 G8 (radius mode, the default): X words are the
    axis positions, so the program reads as without it (a public LinuxCNC sample, issue 20)."""
    text = "G21\nG18 G8\nG00 X13.5 Z1.0 S1000 M3\nG01 X10. Z-5. F100\n"
    p = gcode.parse(text, axes=("X", "Y", "Z"))
    assert np.allclose(p.position[:, [0, 2]], [[13.5, 1.0], [10.0, -5.0]])
    assert gcode.rewrite(p, lambda q: q.copy()) == text
