"""A corpus of NC programs in the dialects shops run (Fanuc, Haas, LinuxCNC, Fusion and FreeCAD
post output, Siemens; written for this project in each dialect's style), checked against an
independent block-by-block interpreter written here from the controls' rules, not from
mtcomp's parser: every program is read, comes back byte for byte under the identity, and a
translation moves every known block by exactly the translation (issue 20)."""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from mtcomp import gcode
from mtcomp.gcode import flow

CORPUS = sorted((Path(__file__).parent / "data" / "nc").iterdir())
AXES = ("X", "Y", "Z")
SHIFT = np.array([0.0123, -0.0071, 0.0042])
_WORD = re.compile(r"([A-Za-z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")
_PLANES = {17: ("X", "Y", "I", "J"), 18: ("Z", "X", "K", "I"), 19: ("Y", "Z", "J", "K")}


def _execution_order(text):
    """(line number, text) in the order the control runs the lines.  Fanuc ``M98 P<n>``
    (repeats ``L``/``K``, or an 8-digit P: 3 digits of repeats, 4 of program number) runs
    ``O<n>`` up to its ``M99``; Haas ``M97 P<n>`` (repeats ``L``) runs from block ``N<n>`` up
    to ``M99``; both after the calling block's own words.  With calls, the main program ends at
    M30/M02 (the subprograms follow it); without, every line is read as before."""
    lines = text.split("\n")
    code = [re.sub(r"\([^)]*\)", " ", ln).split(";")[0] for ln in lines]
    words = [[(w[0].upper(), float(w[1])) for w in _WORD.findall(c)] for c in code]
    called = any(a == "M" and v in (97, 98) for w in words for a, v in w)
    if not called:
        return list(enumerate(lines, start=1))
    label = {}
    for i, w in enumerate(words):
        for a, v in w:
            if a in "ON":
                label.setdefault((a, v), i)
    order = []

    def run(i, depth):
        assert depth < 10
        while i < len(lines):
            w = dict(words[i])
            ms = {v for a, v in words[i] if a == "M"}
            if ms & {97, 98}:
                # the block without its call words, then the called lines
                order.append((i + 1, re.sub(r"[MmPpLlKk]\s*[-+]?[\d.]+", " ", code[i])))
                prog, reps = w["P"], w.get("L", w.get("K", 1))
                if 98 in ms and ("O", prog) not in label:
                    reps, prog = divmod(prog, 10000)
                for _ in range(int(reps)):
                    run(label[("N" if 97 in ms else "O", prog)], depth + 1)
            else:
                order.append((i + 1, lines[i]))
                if 99 in ms or (depth == 0 and ms & {2, 30}):
                    return
            i += 1

    run(0, 0)
    return order


def interpret(text):
    """Blocks of a program as a control runs them, one line at a time: (line, position per
    axis or None where the program has not fixed it, motion, arc centre in the plane or None)."""
    pos = dict.fromkeys(AXES)
    mode, absolute, inch, plane, centre_abs = None, True, False, 17, False
    cycle, retract, zinit, r_word, z_word = 0, 98, None, None, None
    blocks = []
    for n, raw in _execution_order(text):
        line = raw.lstrip("\ufeff")
        line = re.sub(r"\([^)]*\)", " ", line).split(";")[0]
        if line.strip().startswith("%"):
            continue
        words = [(w[0].upper(), float(w[1])) for w in _WORD.findall(line)]
        g = [v for a, v in words if a == "G"]
        for v in g:
            if v in (73, 74, 76) or 81 <= v <= 89:
                if not cycle:
                    zinit = pos["Z"]
                cycle = int(v)
            elif v == 80:
                cycle = 0
            elif v in (98, 99):
                retract = int(v)
            if v in (0, 1, 2, 3):
                mode, cycle = int(v), 0
            elif v in (90, 91):
                absolute = v == 90
            elif v in (20, 70):
                inch = True
            elif v in (21, 71):
                inch = False
            elif v in (17, 18, 19):
                plane = int(v)
            elif v in (90.1, 91.1):
                centre_abs = v == 90.1
        ax = {a: v for a, v in words if a in AXES}
        arcw = {a: v for a, v in words if a in "IJKR"}
        if any(v in (28, 30, 53) for v in g):
            for a in ax:
                pos[a] = None                      # reference point / machine coordinates
            continue
        if any(v in (4, 52, 50.1) for v in g):
            continue
        if not ax and not (arcw and mode in (2, 3)):
            continue
        s = 25.4 if inch else 1.0
        if cycle:
            # a hole: X Y as usual; Z is the depth, R the R level; the tool ends at the
            # initial level (G98) or at R (G99)
            r_word = arcw.get("R", r_word)
            z_word = ax.pop("Z", z_word)
            for a, v in ax.items():
                pos[a] = v * s if absolute else (None if pos[a] is None else pos[a] + v * s)
            r_lvl = r_word * s if absolute else (None if zinit is None else zinit + r_word * s)
            pos["Z"] = zinit if retract == 98 else r_lvl
            blocks.append((n, dict(pos), cycle, None))
            continue
        start = dict(pos)
        for a, v in ax.items():
            if absolute:
                pos[a] = v * s
            elif pos[a] is not None:
                pos[a] += v * s
        centre = None
        if mode in (2, 3):
            u, v_, iu, iv = _PLANES[plane]
            if "R" in arcw:
                su, sv, eu, ev, r = start[u], start[v_], pos[u], pos[v_], arcw["R"] * s
                d = math.hypot(eu - su, ev - sv)
                h = math.sqrt(max(r * r - d * d / 4, 0.0))
                side = (1 if mode == 3 else -1) * (1 if r > 0 else -1)
                centre = ((su + eu) / 2 - side * h * (ev - sv) / d, (sv + ev) / 2 + side * h * (eu - su) / d)
            elif centre_abs:
                centre = (arcw.get(iu, 0.0) * s, arcw.get(iv, 0.0) * s)
            else:
                centre = (start[u] + arcw.get(iu, 0.0) * s, start[v_] + arcw.get(iv, 0.0) * s)
        blocks.append((n, dict(pos), mode, centre))
    return blocks


def _read(text, **kw):
    """The program as mtcomp reads it: parsed, subprogram calls expanded first; the source
    line of each block; the flow (None without calls)."""
    fl = flow.expand(text)
    p = gcode.parse(fl.expanded if fl else text, axes=AXES, **kw)
    lines = fl.origin[p.line - 1] + 1 if fl else np.asarray(p.line)
    return p, lines, fl


def _rewrite(text, transform):
    p, lines, fl = _read(text)
    out = gcode.rewrite(p, transform)
    if fl:
        mode, out = flow.fold(fl, out)
        assert mode == "once"                 # a rigid shift: every subprogram compensated once
    return out


def _check_against_interpreter(p, blocks, lines=None):
    assert [b[0] for b in blocks] == list(p.line if lines is None else lines)
    for j, (n, pos, mode, centre) in enumerate(blocks):
        for k, a in enumerate(AXES):
            assert p.axis_known[j, k] == (pos[a] is not None), (n, a)
            if pos[a] is not None:
                assert p.position[j, k] == pytest.approx(pos[a], abs=1e-9), (n, a)
        if centre is not None:
            u, v_ = (AXES.index(c) for c in _PLANES[int(p.plane[j])][:2])
            assert p.arc_centre[j, [u, v_]] == pytest.approx(centre, abs=1e-9), n


@pytest.mark.parametrize("path", CORPUS, ids=lambda p: p.name)
def test_corpus_program_read_as_the_interpreter_reads_it(path):
    text = gcode.read_program(path)
    p, lines, _ = _read(text, filename=str(path))
    assert len(p) >= 5
    _check_against_interpreter(p, interpret(text), lines)


@pytest.mark.parametrize("path", CORPUS, ids=lambda p: p.name)
def test_corpus_identity_is_byte_exact(path):
    text = gcode.read_program(path)
    assert _rewrite(text, lambda q: q.copy()) == text


@pytest.mark.parametrize("path", CORPUS, ids=lambda p: p.name)
def test_corpus_translation_moves_every_known_block_exactly(path):
    text = gcode.read_program(path)
    p, lines, _ = _read(text)
    out = _rewrite(text, lambda q: q + SHIFT)
    before, after = interpret(text), interpret(out)
    assert [b[0] for b in after] == [b[0] for b in before]        # no line added or lost
    inch = bool(p.inch.any())
    tol = 2.54e-7 * 5 if inch else 1e-6                           # half a written increment
    for j, ((n, p0, _, c0), (_, p1, _, c1)) in enumerate(zip(before, after)):
        for k, a in enumerate(AXES):
            assert (p0[a] is None) == (p1[a] is None), (n, a)
            if p0[a] is None:
                continue
            want = p0[a] + (SHIFT[k] if p.known[j] else 0.0)       # deferred blocks stay
            assert abs(p1[a] - want) <= tol, (n, a, p1[a], want)
        if c0 is not None and p.known[j]:
            u, v_ = (AXES.index(c) for c in _PLANES[int(p.plane[j])][:2])
            assert np.allclose(np.subtract(c1, c0), SHIFT[[u, v_]], atol=2 * tol), n
    # the output reads back, and is itself an identity fixed point
    assert _rewrite(out, lambda x: x.copy()) == out
    # nothing invented: a deferred block keeps every byte
    lines_in, lines_out = text.split("\n"), out.split("\n")
    for j in np.flatnonzero(~p.known):
        assert lines_out[lines[j] - 1] == lines_in[lines[j] - 1]
