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

from mtcomp import InputError, gcode
from mtcomp.gcode import flow
from mtcomp.gcode.rotation import to_reference

DATA = Path(__file__).parent / "data" / "nc"
#: programs; subprogram files of other programs are in data/nc/subprograms, 5-axis tool centre
#: point programs in data/nc/tcp (tests/test_gcode_tcp.py)
CORPUS = sorted(p for p in DATA.iterdir() if p.is_file())
SUBDIR = DATA / "subprograms"
AXES = ("X", "Y", "Z")
SHIFT = np.array([0.0123, -0.0071, 0.0042])
_WORD = re.compile(r"([A-Za-z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")
_OWORD = re.compile(r"^\s*[Oo]\s*(?:<([^>]*)>|(\d+))\s*(sub|endsub|call)\b", re.IGNORECASE)
_PLANES = {17: ("X", "Y", "I", "J"), 18: ("Z", "X", "K", "I"), 19: ("Y", "Z", "J", "K")}


def _subprogram_file(key):
    """The file of an O number or an o<name> subroutine in the subprogram directory."""
    for f in sorted(SUBDIR.iterdir()):
        stem = f.name.split(".")[0].lower()
        if (isinstance(key, float) and re.fullmatch(r"o?0*" + str(int(key)), stem)) or stem == key:
            return f
    raise AssertionError(f"no subprogram file for {key}")


def _execution_order(text, name="main"):
    """((file, line), text) in the order the control runs the lines.  Fanuc ``M98 P<n>``
    (repeats ``L``/``K``, or an 8-digit P: 3 digits of repeats, 4 of program number) runs
    ``O<n>`` (in the file, else the file O<n> of the subprogram directory) up to its ``M99``;
    Haas ``M97 P<n>`` (repeats ``L``) runs from block ``N<n>`` up to ``M99``; both after the
    calling block's own words.  LinuxCNC ``o<name> call`` runs ``o<name> sub`` up to its
    ``endsub`` (in the file, else name.ngc); definitions are skipped where they stand.  With
    calls, the main program ends at M30/M02 (the subprograms follow it); without, every line
    is read as before."""
    files = {name: text.split("\n")}
    code, words, label, osub = {}, {}, {}, {}

    def load(fname):
        lines = files[fname]
        code[fname] = [re.sub(r"\([^)]*\)", " ", ln).split(";")[0] for ln in lines]
        words[fname] = [[(w[0].upper(), float(w[1])) for w in _WORD.findall(c)]
                        if not _OWORD.match(c) else [] for c in code[fname]]
        for i, w in enumerate(words[fname]):
            for a, v in w:
                if a in "ON":
                    label.setdefault((a, v), (fname, i))
            m = _OWORD.match(code[fname][i])
            if m and m.group(3).lower() == "sub":
                osub.setdefault((m.group(1) or m.group(2)).lower(), (fname, i))

    load(name)
    called = any(a == "M" and v in (97, 98) for w in words[name] for a, v in w) or \
        any(_OWORD.match(c) for c in code[name])
    if not called:
        return [((name, i), ln) for i, ln in enumerate(files[name], start=1)]
    order = []

    def run(fname, i, depth):
        assert depth < 10
        lines = files[fname]
        while i < len(lines):
            w = dict(words[fname][i])
            ms = {v for a, v in words[fname][i] if a == "M"}
            m = _OWORD.match(code[fname][i])
            if m:
                key, verb = (m.group(1) or m.group(2)).lower(), m.group(3).lower()
                if verb == "call":
                    if key not in osub:
                        f = _subprogram_file(key)
                        files[f.name] = f.read_text().split("\n")
                        load(f.name)
                    run(*osub[key], depth + 1)
                elif verb == "sub" and depth == 0:       # a definition: skipped
                    while True:
                        i += 1
                        mm = _OWORD.match(code[fname][i])
                        if mm and mm.group(3).lower() == "endsub":
                            break
                elif verb == "endsub":
                    return
                i += 1
                continue
            if ms & {97, 98}:
                # the block without its call words, then the called lines
                order.append(((fname, i + 1), re.sub(r"[MmPpLlKk]\s*[-+]?[\d.]+", " ", code[fname][i])))
                prog, reps = w["P"], w.get("L", w.get("K", 1))
                if 98 in ms and ("O", prog) not in label:
                    if prog > 9999 and ("O", prog % 10000) in label:
                        reps, prog = divmod(prog, 10000)
                    else:
                        f = _subprogram_file(prog)
                        files[f.name] = f.read_text().split("\n")
                        load(f.name)
                for _ in range(int(reps)):
                    run(*label[("N" if 97 in ms else "O", prog)], depth + 1)
            else:
                order.append(((fname, i + 1), files[fname][i]))
                if 99 in ms or (depth == 0 and ms & {2, 30}):
                    return
            i += 1

    run(name, 0, 0)
    return order


def _rot(ang, c, u, v):
    t = math.radians(ang)
    du, dv = u - c[0], v - c[1]
    return c[0] + math.cos(t) * du - math.sin(t) * dv, c[1] + math.sin(t) * du + math.cos(t) * dv


def _plus(a, b):
    """a + b, None where either is unknown."""
    return None if a is None or b is None else a + b


def interpret(text, name="main", tips=False):
    """Blocks of a program as a control runs them, one line at a time: ((file, line), position
    per axis in the reference frame or None where the program has not fixed it, motion, arc
    centre in the plane or None).  Work offsets and tool lengths come from G10 in the program;
    positions are in the frame of the work offset in effect at the first motion block.
    ``tips``: also return, per block, how far the tool tip is below the gauge point along Z
    (mm: the length of the last G43 H, -length for G44, the G43.1 Z; kept after G49, as the
    tool stays in the spindle), as ``(blocks, tip_lengths)``."""
    pos = dict.fromkeys(AXES)                  # word frame: word + offset when written
    mode, absolute, inch, plane, centre_abs = None, True, False, 17, False
    cycle, retract, zinit, r_word, z_word = 0, 98, None, None, None
    wcs = {}                                   # G54.. -> {axis: value} set by G10 L2
    cur_wcs, ref_wcs = 54, None
    lengths, tool_mode, h, t_loaded, dyn_len = {}, 49, None, None, 0.0
    rot = None                                 # (angle, centre) under G68
    g92 = {}                                   # G92 shift per axis; None: set where unknown
    polar, pr, pa = False, None, None          # G16: radius and angle words (modal in G16)
    blocks, tip_of, tip = [], [], 0.0
    for n, raw in _execution_order(text, name):
        line = raw.lstrip("\ufeff")
        line = re.sub(r"\([^)]*\)", " ", line).split(";")[0]
        if line.strip().startswith("%"):
            continue
        words = [(w[0].upper(), float(w[1])) for w in _WORD.findall(line)]
        g = [v for a, v in words if a == "G"]
        wd = dict(words)
        s = 25.4 if (inch or 20 in g or 70 in g) and not (21 in g or 71 in g) else 1.0
        if 10 in g:                            # offsets set by the program
            if wd["L"] == 2:
                wcs[53 + int(wd["P"])] = {a: wd[a] * s for a in AXES if a in wd}
            elif wd["L"] in (10, 11):              # geometry, wear: the length is the sum
                key = (int(wd["P"]), wd["L"])
                lengths[key] = (lengths.get(key, 0.0) if 91 in g else 0.0) + wd["R"] * s
            elif wd["L"] == 1:
                lengths[(int(wd["P"]), 10)] = wd["Z"] * s
            continue
        if "T" in wd:
            t_loaded = int(wd["T"])
        if "H" in wd:
            h = int(wd["H"])
        for v in g:
            if v in (43, 44, 49):
                tool_mode = int(v)
                if v != 49 and "H" not in wd:
                    h = t_loaded                   # LinuxCNC: the loaded tool
            elif v == 43.1:                        # LinuxCNC: the length is the Z word
                tool_mode, dyn_len = 43.1, wd["Z"] * s
            if 54 <= v <= 59:
                cur_wcs = int(v)
            if v == 68:
                rot = (wd["R"], (wd[_PLANES[plane][0]] * s, wd[_PLANES[plane][1]] * s))
                pos[_PLANES[plane][0]] = pos[_PLANES[plane][1]] = None
            if v == 69 and rot is not None:
                rot = None
                pos[_PLANES[plane][0]] = pos[_PLANES[plane][1]] = None
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
            elif v == 16:                          # Fanuc polar: X radius, Y angle (G17, G90)
                polar, pr, pa = True, None, None
            elif v == 15:
                polar = False
        if tool_mode in (43, 44):
            tip = (1 if tool_mode == 43 else -1) * (lengths.get((h, 10), 0.0) + lengths.get((h, 11), 0.0))
        elif tool_mode == 43.1:
            tip = dyn_len
        if 68 in g or 43.1 in g:
            continue                               # no move (G43.1 Z: a length)

        def off(a, with92=True):
            o = wcs.get(cur_wcs, {}).get(a, 0.0) - wcs.get(ref_wcs or cur_wcs, {}).get(a, 0.0)
            if a == "Z" and tool_mode in (43, 44):
                o += (1 if tool_mode == 43 else -1) * (lengths.get((h, 10), 0.0) + lengths.get((h, 11), 0.0))
            if a == "Z" and tool_mode == 43.1:
                o += dyn_len
            if with92 and a in g92:
                o = None if g92[a] is None else o + g92[a]
            return o
        ax = {a: v for a, v in words if a in AXES}
        arcw = {a: v for a, v in words if a in "IJKR"}
        if polar and ("X" in ax or "Y" in ax) and not any(v in (4, 10, 52, 53, 92) for v in g):
            # the point at radius X and angle Y (deg, counter-clockwise from +X) from the work
            # origin; a word not written keeps its last value in the G16 section
            assert absolute and plane == 17
            pr, pa = ax.get("X", pr), ax.get("Y", pa)
            if pr is None or pa is None:
                ax["X"] = ax["Y"] = None
            else:
                ax["X"], ax["Y"] = pr * math.cos(math.radians(pa)), pr * math.sin(math.radians(pa))
        if 92.1 in g or 92.2 in g:
            g92 = {}                               # the G92 shift cancelled
            continue
        if 92 in g:
            # the current position gets the words' coordinates; the tool does not move, and
            # later absolute words are shifted by the difference (unknown where it is unknown)
            for a, v in ax.items():
                g92[a] = None if pos[a] is None else pos[a] - v * s - off(a, with92=False)
            continue
        if any(v in (28, 30, 53) for v in g):
            for a in ax:
                pos[a] = None                      # reference point / machine coordinates
            continue
        if any(v in (4, 52, 50.1) for v in g):
            continue
        if 92.4 in g:
            # Carvera's A-axis shrink (G92.4 A0 S0, its controller's Shrink button: "reset A
            # axis value to 0-360 while keeping the offset"): no move; A is not followed here
            continue
        rotary = any(a in "ABC" for a, _ in words)
        if not ax and not rotary and not (arcw and mode in (2, 3)):
            continue                           # a block that moves no axis
        if ref_wcs is None:
            ref_wcs = cur_wcs

        def ref(p):
            out = dict(p)
            if rot is not None:
                u, v_ = _PLANES[plane][:2]
                if p[u] is not None and p[v_] is not None:
                    cu, cv = rot[1][0] + off(u), rot[1][1] + off(v_)
                    out[u], out[v_] = _rot(rot[0], (cu, cv), p[u], p[v_])
            return out
        if cycle:
            # a hole: X Y as usual; Z is the depth, R the R level; the tool ends at the
            # initial level (G98) or at R (G99)
            r_word = arcw.get("R", r_word)
            z_word = ax.pop("Z", z_word)
            # repeats (Fanuc K, LinuxCNC/Haas L): the hole drilled that many times; in G91 the
            # X Y increments are taken again before each (Haas's variable peck has K with I J)
            reps = int(wd.get("L", wd.get("K", 1) if not ("I" in wd or "J" in wd) else 1))
            if reps == 0:
                continue                           # K0/L0: R and Z stored, no hole, no move
            for _ in range(reps):
                for a, v in ax.items():
                    pos[a] = (None if v is None else _plus(v * s, off(a))) if absolute else _plus(pos[a], v * s)
            r_lvl = _plus(r_word * s, off("Z")) if absolute else (None if zinit is None else zinit + r_word * s)
            pos["Z"] = zinit if retract == 98 else r_lvl
            blocks.append((n, ref(pos), cycle, None))
            tip_of.append(tip)
            continue
        start = dict(pos)
        for a, v in ax.items():
            if v is None:
                pos[a] = None                      # a polar word not yet known
            elif absolute:
                pos[a] = _plus(v * s, off(a))
            elif pos[a] is not None:
                pos[a] += v * s
        centre = None
        if mode in (2, 3):
            u, v_, iu, iv = _PLANES[plane]
            if start[u] is None or start[v_] is None:
                # from where the axes stand: the control knows the centre, the program does not
                blocks.append((n, ref(pos), mode, None))
                tip_of.append(tip)
                continue
            if "R" in arcw:
                su, sv, eu, ev, r = start[u], start[v_], pos[u], pos[v_], arcw["R"] * s
                d = math.hypot(eu - su, ev - sv)
                hh = math.sqrt(max(r * r - d * d / 4, 0.0))
                side = (1 if mode == 3 else -1) * (1 if r > 0 else -1)
                centre = ((su + eu) / 2 - side * hh * (ev - sv) / d, (sv + ev) / 2 + side * hh * (eu - su) / d)
            elif centre_abs:
                centre = (arcw.get(iu, 0.0) * s + off(u), arcw.get(iv, 0.0) * s + off(v_))
            else:
                centre = (start[u] + arcw.get(iu, 0.0) * s, start[v_] + arcw.get(iv, 0.0) * s)
            if rot is not None:
                centre = _rot(rot[0], (rot[1][0] + off(u), rot[1][1] + off(v_)), *centre)
        blocks.append((n, ref(pos), mode, centre))
        tip_of.append(tip)
    return (blocks, tip_of) if tips else blocks


def _read(text, name="main", **kw):
    """The program as mtcomp reads it: parsed, subprogram calls expanded first (subprogram
    files from the subprogram directory); the (file, line) of each block; the flow (None
    without calls)."""
    fl = flow.expand(text, name, search=[str(SUBDIR)])
    p = gcode.parse(fl.expanded if fl else text, axes=AXES, tcp=True, rotation=True, **kw)
    if fl:
        labels = [fl.where(int(o)) for o in fl.origin[p.line - 1]]
        labels = [(Path(f).name if f != name else name, ln) for f, ln in labels]
    else:
        labels = [(name, int(ln)) for ln in p.line]
    return p, labels, fl


def _rewrite(text, transform, name="main"):
    p, _, fl = _read(text, name)
    out = gcode.rewrite(p, transform)
    if fl:
        mode, out = flow.fold(fl, out)
        # a rigid shift: every subprogram compensated once; from other files: written out
        assert mode == ("expanded" if fl.external else "once")
    return out


def _check_against_interpreter(p, blocks, labels):
    assert [b[0] for b in blocks] == labels
    P = to_reference(p, p.position)
    for j, (n, pos, mode, centre) in enumerate(blocks):
        for k, a in enumerate(AXES):
            assert p.axis_known[j, k] == (pos[a] is not None), (n, a)
            if pos[a] is not None:
                assert P[j, k] == pytest.approx(pos[a], abs=1e-9), (n, a)
        if centre is not None:
            u, v_ = (AXES.index(c) for c in _PLANES[int(p.plane[j])][:2])
            row = np.array(p.position[j], float)
            row[[u, v_]] = p.arc_centre[j, [u, v_]]
            c = to_reference(p, row[None], [j])[0]
            assert c[[u, v_]] == pytest.approx(centre, abs=1e-9), n


@pytest.mark.parametrize("path", CORPUS, ids=lambda p: p.name)
def test_corpus_program_read_as_the_interpreter_reads_it(path):
    text = gcode.read_program(path)
    p, labels, _ = _read(text, path.name, filename=str(path))
    assert len(p) >= 5
    _check_against_interpreter(p, interpret(text, path.name), labels)


@pytest.mark.parametrize("path", CORPUS, ids=lambda p: p.name)
def test_corpus_identity_is_byte_exact(path):
    text = gcode.read_program(path)
    out = _rewrite(text, lambda q: q.copy(), path.name)
    p, _, fl = _read(text, path.name)
    assert out == (text if not (fl and fl.external) else flow.fold(fl, fl.expanded)[1])


@pytest.mark.parametrize("path", CORPUS, ids=lambda p: p.name)
def test_corpus_translation_moves_every_known_block_exactly(path):
    text = gcode.read_program(path)
    p, labels, fl = _read(text, path.name)
    external = bool(fl and fl.external)
    out = _rewrite(text, lambda q: q + SHIFT, path.name)
    before, after = interpret(text, path.name), interpret(out, path.name)
    if external:
        # the output holds the subprograms written out: the same blocks, in one file
        assert len(after) == len(before)
    else:
        assert [b[0] for b in after] == [b[0] for b in before]    # no line added or lost
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
    assert _rewrite(out, lambda x: x.copy(), path.name) == out
    # nothing invented: a deferred block keeps every byte
    if not external:
        lines_in, lines_out = text.split("\n"), out.split("\n")
        for j in np.flatnonzero(~p.known):
            assert lines_out[labels[j][1] - 1] == lines_in[labels[j][1] - 1]


def test_interpreter_g92_and_rotary_only_blocks_as_the_controls_run_them():
    """G92 sets the coordinates of the current point (no move; later absolute words shift by
    the difference, G92.1 cancels); a block writing only a rotary axis is a block; both read
    by mtcomp as by the interpreter (the corpus programs of filament winders use both)."""
    text = "G21 G90\nG0 X10 Y5 Z1\nG92 X0 A25\nG1 X5 F100\nG0 A90\nG92.1\nG1 X5\n"
    blocks = interpret(text)
    assert [b[0][1] for b in blocks] == [2, 4, 5, 7]
    assert [b[1]["X"] for b in blocks] == [10.0, 15.0, 15.0, 5.0]
    p = gcode.parse(text, axes=("A", "X", "Y", "Z"))
    assert [int(x) for x in p.line] == [2, 4, 5, 7]
    assert np.allclose(to_reference(p, p.position)[:, 1], [10.0, 15.0, 15.0, 5.0])
    # G92 where the position is not known: unknown until G92.1
    blocks = interpret("G90\nG92 X3\nG1 X5 Y1\nG92.1\nG1 X4\n")
    assert [b[1]["X"] for b in blocks] == [None, 4.0]


def test_interpreter_unknown_arc_start_and_carvera_shrink():
    """An arc from a start the program has not fixed runs from where the axes stand (its end
    is known, its centre is not); Carvera's G92.4 A0 S0 is no move.  mtcomp reads both as the
    interpreter does, and a translation moves every block it compensates (issue 20: a
    LinuxCNC sample and two Carvera 4-axis programs were refused for them)."""
    text = ("g0 z2\ng1 z-1.6 f50\ng2 x-10 y10 i0 j10 f100\ng0 z2 a0\nG0 X5 Y1 Z3 A370\n"
            "G92.4A0S0\nG1 X6\nG0 A10\nG2 X4 Y1 I-1 J0\n")
    blocks = interpret(text)
    assert [b[0][1] for b in blocks] == [1, 2, 3, 4, 5, 7, 8, 9]
    assert blocks[2][1] == {"X": -10.0, "Y": 10.0, "Z": -1.6} and blocks[2][3] is None
    p = gcode.parse(text, axes=AXES + ("A",))        # X Y Z first: the interpreter's columns
    assert p.notes and "G92.4" in p.notes[-1]
    _check_against_interpreter(p, blocks, [("main", int(x)) for x in p.line])
    info = {}
    out, _ = gcode.rewrite_with_lines(p, lambda x: x + np.r_[SHIFT, 0.0], info=info)
    comp = info["compensated"]
    # the arc from the unknown start passes; A is unknown from the shrink to its next word
    assert comp.tolist() == [False, False, False, True, True, False, True, True]
    after = interpret(out)
    for (n, p0, _, c0), (_, p1, _, c1), c in zip(blocks, after, comp):
        for k, a in enumerate(AXES):
            assert (p0[a] is None) == (p1[a] is None)
            if p0[a] is not None and c:
                assert abs(p1[a] - p0[a] - SHIFT[k]) < 1e-9, (n, a)
    # the blocks passed keep every byte
    assert out.split("\n")[:3] == text.split("\n")[:3]
    assert out.split("\n")[5:7] == ["G92.4A0S0", "G1 X6"]
    assert gcode.rewrite(p, lambda x: x.copy()) == text


@pytest.mark.parametrize("line", ["G92.4 X0", "G92.4 A10 R0", "G92.4 A0", "G92.4 A0 S1",
                                  "G0 G92.4 A0 S0"])
def test_other_g92_4_forms_are_refused(line):
    """Smoothieware's G92.4 X.. sets the machine position, Carvera's G92.4 A.. R0 moves A
    rapidly: neither is read; only the shrink G92.4 A0 S0 is."""
    with pytest.raises(InputError, match=r"c.nc:2: G92.4 \(Smoothieware/Carvera\): only"):
        gcode.parse("G0 X1 A5\n" + line + "\n", axes=AXES + ("A",), filename="c.nc")
