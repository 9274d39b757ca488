"""Property tests of the NC reader (issue 15): mutated corpus programs and generated blocks
never raise anything but InputError, and whatever is accepted comes back byte for byte under
the identity and moves by exactly a translation.  Seeded and bounded to seconds."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

from mtcomp import InputError, gcode
from mtcomp.gcode import flow
from mtcomp.gcode.rotation import to_reference

AXES = ("X", "Y", "Z", "B", "C")
CORPUS = [gcode.read_program(p) for p in sorted((Path(__file__).parent / "data" / "nc").iterdir())
          if p.is_file()]
ALPHABET = "GXYZBCIJKRFNMSTPHQ0123456789.-+ ()%;/#[]=\n\r\t\ufeffgxyz"
SHIFT = np.array([0.0123, -0.0071, 0.0042, 0.001, -0.002])


def _check(text):
    """Accepted programs: identity exact, translation re-read exactly (known blocks)."""
    try:
        fl = flow.expand(text)                 # subprogram calls: the blocks as they run
        p = gcode.parse(fl.expanded if fl else text, axes=AXES, tcp=True, rotation=True)
        ident = gcode.rewrite(p, lambda q: q.copy())
        info = {}
        out, _ = gcode.rewrite_with_lines(p, lambda q: q + SHIFT, info=info)
    except InputError:
        return
    if fl:
        assert flow.fold(fl, ident) == ("once", text)
        mode, folded = flow.fold(fl, out)
        if mode == "once":                     # runs as the rewritten expansion
            assert flow.expand(folded).expanded == out
        else:
            assert flow.expand(folded) is None
        ident = text
    assert ident == text
    q = gcode.parse(out, axes=AXES, tcp=True, rotation=True)
    assert len(q) >= len(p)
    if len(q) == len(p) and len(p):
        res = np.array([1e-6, 1e-6, 1e-6, 1e-5, 1e-5])[:len(AXES)] * (25.4 if p.inch.any() else 1.0)
        kn = info["compensated"] & q.known      # blocks deferred by the rewrite do not move
        # in the reference frame (G68 blocks hold unrotated words)
        d = (to_reference(q, q.position) - to_reference(p, p.position))[kn]
        # a linear axis the program never writes gets no word: it does not move
        want = np.where([a in p.idle_axes and a in "XYZ" for a in AXES], 0.0, SHIFT)
        assert np.all(np.abs(d - want) <= res), (text, out)


@seed(20)
@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
@given(st.sampled_from(range(len(CORPUS))), st.lists(
    st.tuples(st.integers(0, 10_000), st.sampled_from(["ins", "del", "rep"]), st.sampled_from(ALPHABET)),
    min_size=1, max_size=4))
def test_mutated_corpus_programs(i, edits):
    text = CORPUS[i]
    for pos, kind, ch in edits:
        pos %= len(text) + 1
        if kind == "ins":
            text = text[:pos] + ch + text[pos:]
        elif kind == "del":
            text = text[:pos] + text[pos + 1:]
        else:
            text = text[:pos] + ch + text[pos + 1:]
    _check(text)


_num = st.one_of(st.integers(-999, 999).map(str),
                 st.decimals(-999, 999, places=3, allow_nan=False).map(lambda d: f"{d}"),
                 st.integers(0, 99).map(lambda v: f"{v}."), st.integers(0, 999).map(lambda v: f".{v}"))
_word = st.tuples(st.sampled_from("XYZBCxyz"), st.sampled_from(["", " "]), _num).map("".join)
_code = st.sampled_from(["G0", "G1", "G00", "G01", "G90", "G91", "G17", "G20", "G21", "G94",
                         "G43 H1", "G49", "G54", "G28 G91 Z0.", "G53 Z0", "G80", "M3", "M8", "F100",
                         "(c)", "; note", "N10", "g1", "G61.1", "G91.1"])


@seed(15)
@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
@given(st.lists(st.lists(st.one_of(_word, _code), min_size=1, max_size=5), min_size=1, max_size=12),
       st.sampled_from([" ", ""]), st.sampled_from(["\n", "\r\n"]))
def test_generated_blocks(blocks, sep, eol):
    text = eol.join(sep.join(b) for b in blocks) + eol
    _check(text)


@seed(7)
@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
@given(st.lists(st.tuples(st.floats(0.05, 50), st.floats(-np.pi, np.pi), st.floats(-2 * np.pi, 2 * np.pi),
                          st.sampled_from([2, 3, 4]), st.booleans()), min_size=1, max_size=6))
def test_generated_arcs_as_cam_systems_round_them(arcs):
    """Arcs written with 2 to 4 decimals (end points off the circle by the rounding), I J K or R:
    accepted ones are kept byte for byte and move exactly under a translation."""
    x, y = 0.0, 0.0
    lines = ["G90 G17 G1 X0 Y0 Z0 B0 C0 F100"]
    for r, a0, sweep, dec, use_r in arcs:
        cx, cy = x - r * np.cos(a0), y - r * np.sin(a0)
        ex, ey = cx + r * np.cos(a0 + sweep), cy + r * np.sin(a0 + sweep)
        g = "G3" if sweep > 0 else "G2"
        f = f"{{:.{dec}f}}".format
        if use_r and 1e-3 < abs(sweep) < 2 * np.pi - 1e-3:
            rr = r if abs(sweep) <= np.pi else -r
            lines.append(f"{g} X{f(ex)} Y{f(ey)} R{f(rr)}")
        else:
            lines.append(f"{g} X{f(ex)} Y{f(ey)} I{f(cx - x)} J{f(cy - y)}")
        x, y = float(f(ex)), float(f(ey))
    _check("\n".join(lines) + "\n")
