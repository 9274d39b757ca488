"""Adversarial NC programs through `compensate_program`, checked for machine safety: under zero
errors the output is the input byte for byte; under a workpiece translation and rotation every
block's written position, read back by the independent interpreter of
tests/test_gcode_corpus.py, lands (through the forward model with the errors) where the input
block meant, to a few axis increments; blocks mtcomp passes keep every byte; the numpy tokenizer
(MTCOMP_TOKENIZER=python) writes the same bytes as the compiled one.  Programs written for this
project in Fanuc, Haas, LinuxCNC and Fusion styles."""
from __future__ import annotations

import re

import numpy as np
import pytest

from mtcomp import InputError
from mtcomp.commands import compensate_program
from mtcomp.errors import ErrorSet, WorkpieceSetting
from mtcomp.kinematics import forward_position
from mtcomp.machine import load_machine

from test_gcode_compensate import corrupt_formatting
from test_gcode_corpus import AXES, interpret

PROGRAMS = {
    # Fanuc, inch with 4-decimal words, incremental mixed with absolute, G10 offsets and G43 H
    "fanuc_inch_g91": (
        "%\nO1001 (INCH G91)\nG20 G17 G40 G49 G80 G90\nG10 L2 P1 X0.1 Y-0.05 Z0.\n"
        "G10 L2 P2 X1.2500 Y0.7500 Z0.0100\nG10 L10 P3 R0.5000\nT3 M06\nG54 G00 X0.5 Y0.25\n"
        "G43 H3 Z0.1000\nG01 Z-0.0500 F10.\nG91 X0.1250 Y0.0625\nX-0.0500\nG90 X1.0000 Y0.5000\n"
        "G55 X0.2500 Y0.2500\nG91 G01 Y-.1\nG90 G02 X0.5000 Y0.1500 I0.1250 J0. F5.\n"
        "G00 Z1.0000\nG49 Z1.0\nM30\n%\n"),
    # Haas: N numbers, block delete, lowercase, words without spaces, X.5 / X-0. / X+1
    "haas_tight": (
        "%\nO02000\nN10 G21 G90 G17\nN20 G10 L2 P1 X5. Y-3. Z1.\nN30 G54\n"
        "n40 g0x1.y2.z3.\n/N50 M08\nN55 G1 X.5 F100.\nN60 g1x-0.y-.25z+1\nN70 G1X10.Y0Z-0.5F50\n"
        "/ N80 M09 (coolant off)\nN90 G3X10.Y0I-5.J0\nN100 G0 Z25.\nN110 M30\n%\n"),
    # LinuxCNC: CRLF, both comment styles, G92 shift, G92.1, ; comments after words
    "linuxcnc_crlf": (
        "(LinuxCNC style)\r\nG21 G90 G64 P0.001\r\nG0 X0 Y0 Z5 ; rapid\r\nG92 X10 Y10\r\n"
        "G1 X12 Y10 F300 (shifted)\r\nG1 X12 Y13\r\nG92.1\r\nG1 X1 Y1 ; back\r\n"
        "G2 X3 Y1 R1\r\nG0 Z10\r\nM2\r\n"),
    # Fusion post: many decimals, long lines, G43 H with the length from G10 L10
    "fusion_long": (
        "%\n(Fusion style)\nG90 G94 G17\nG21\nG10 L10 P1 R25.125\nT1 M6\nS10000 M3\nG54\n"
        "G0 X12.345678901 Y-7.000000001\nG43 Z15. H1\nG1 Z-1.23456789 F1000.\n"
        + "".join(f"G1 X{12.345678901 + 0.01 * i:.9f} Y{-7 + 0.003 * i:.9f} (step {i} "
                  + "x" * 300 + ")\n" for i in range(20))
        + "G0 Z15.\nM30\n%\n"),
    # Fanuc G16 polar coordinates, radius and angle words each omitted in turn
    "fanuc_polar": (
        "G21 G90 G17\nG0 X0 Y0 Z5.\nG1 Z-1. F100\nG16\nG1 X20. Y0\nY45.\nX25.\nX30. Y90.\n"
        "Y180. Z-2.\nG15\nG1 X0 Y0\nM30\n"),
    # G16 with negative radii (the point opposite the angle), each word omitted in turn
    "fanuc_polar_negative": (
        "G21 G90 G17\nG0 X0 Y0 Z5.\nG16\nG1 X-10. Y30. F100\nY60.\nX-12.\nX10. Y0\nY-30.\nG15\n"
        "M30\n"),
    # a BOM, tabs, trailing blanks, comments holding words and ';' in both styles, blank lines
    "comment_tricks": ("\ufeffG21 G90\t\nG0 X1 Y1 Z1 (X9 ; Y9)\n; (G0 X5)\n  \n"
                       "G1\tX2 (a) Y2 F100   \n(only) \nG1 X3;Y7\nM30\n"),
    # no spaces with M S T words; -0 in every spelling; LF and CRLF mixed
    "tight_mst": "G21G90\r\nG0X1Y1Z1M3S1000\nG1X2F100T1\r\nG1Y2.M8\nG1 X-0. Y-0 Z-0.000\nG1 X-.0\nM30\n",
    # G16 at G55 in inch; G16 under G43 with a G10 tool length
    "polar_g55_inch": ("G20 G90 G17\nG10 L2 P1 X0 Y0 Z0\nG10 L2 P2 X0.5 Y0.25 Z0\nG54 G0 X0 Y0 Z0.2\n"
                       "G55\nG16\nG0 X0.4 Y15.\nG1 Z-0.01 F5.\nX0.5\nY75.\nG15\nG54 G0 X0.1 Y0.1\nM30\n"),
    "polar_g43": ("G21 G90 G17\nG10 L10 P1 R20.\nG43 H1 G0 X0 Y0 Z5\nG16\nG1 X10 Y0 Z-1 F100\n"
                  "Y90 Z-1\nG15\nG49 G0 Z10\nM30\n"),
    # G92 then G91 increments from the shifted origin; a LinuxCNC tool table entry by G10 L1
    "g92_g91": "G21 G90\nG0 X5 Y5 Z5\nG92 X0 Y0\nG91 G1 X1 F100\nY1\nG90 X2 Y2\nG92.1\nG0 X0 Y0\nM30\n",
    "g10_l1": "G21 G90\nG10 L1 P4 Z20.5\nT4 M6\nG43 H4\nG0 X1 Y1 Z10\nG1 Z-1 F100\nG49\nG0 X2\nM30\n",
    # G68 rotation with an arc in the rotated frame
    "g68": ("G21 G90 G17\nG0 X0 Y0 Z5\nG68 X10 Y0 R30\nG1 X15 Y0 F100\nG1 X15 Y5\n"
            "G2 X10 Y10 I-5 J0\nG69\nG0 X0 Y0\nM30\n"),
    # Haas G154 P work offsets switched against G54, with the offsets given by G10 L20
    "haas_g154": (
        "G20 G90\nG54 G0 X0.1 Y0.1 Z0.5\n"
        "G1 X0.2 F20.\nG154 P7 G1 X0.1\nY0.3\nG54 X0.3\nM30\n"),
}
#: the programs the interpreter of tests/test_gcode_corpus.py reads (it has no G154)
INTERPRETED = [k for k in PROGRAMS if k != "haas_g154"]

#: haas_g154's offsets as the control holds them (mm)
G154_OFFSETS = {"G54": {"X": 12.7, "Y": 12.7, "Z": 0.0}, "G154 P7": {"X": 25.4, "Y": 25.4, "Z": 0.0}}
ERR = ErrorSet(workpiece=WorkpieceSetting((0.0123, -0.0071, 0.0042), (0.0, 0.0, 0.03)))
#: linearised under the tilt (arcs out of their plane): other line numbers
TILT_REFUSED = {"polar_g55_inch": r"r.nc:8: the compensation moves X or Y in a block under G16"}
TILT_LINEARISED = {"fanuc_inch_g91", "haas_tight", "linuxcnc_crlf", "g68"}
#: a tilt too: the 5-axis machine answers it with B, the 3-axis one with X Y Z only
TILT = ErrorSet(workpiece=WorkpieceSetting((0.0123, -0.0071, 0.0042), (0.02, -0.015, 0.03)))
MACHINES = {"3axis": ("vmc-moving-column", None), "5axis": ("robonano-a0ib", {"B": 0.0, "C": 0.0})}


def _comp(text, machine, errors, start, monkeypatch=None, tokenizer="", **kw):
    if monkeypatch is not None:
        monkeypatch.setenv("MTCOMP_TOKENIZER", tokenizer)
    try:
        return compensate_program(text, machine, errors, filename="r.nc", start=start, **kw)
    finally:
        if monkeypatch is not None:
            monkeypatch.delenv("MTCOMP_TOKENIZER")


def _at_tip(m, length):
    """The machine with its tool point at the tip of a tool ``length`` mm long (along the
    tool axis from the gauge point)."""
    import dataclasses
    tp = np.asarray(m.tool_point) - length * np.asarray(m.tool_axis)
    return dataclasses.replace(m, tool_point=tuple(tp))


def _full(m, pos, rot):
    """The interpreter's X Y Z with the rotary axes `rot`, in the machine's order."""
    return np.array([pos[a] if a in AXES else rot[a] for a in m.axis_names], float)


def _rotary(text, blocks, start):
    """The rotary axes (absolute words, as these programs write them) after each block."""
    lines = text.split("\n")
    cur, out, at = dict(start), [], 0
    for n, *_ in blocks:
        while at < n[1]:
            code = re.sub(r"\([^)]*\)", " ", lines[at]).split(";")[0]
            for a, v in re.findall(r"([BCbc])\s*([-+]?(?:\d+\.?\d*|\.\d+))", code):
                cur[a.upper()] = float(v)
            at += 1
        out.append(dict(cur))
    return out


@pytest.mark.parametrize("mach", MACHINES)
@pytest.mark.parametrize("name", PROGRAMS)
def test_zero_errors_byte_exact_both_tokenizers(name, mach, monkeypatch):
    m = load_machine(MACHINES[mach][0])
    text = PROGRAMS[name]
    for tok in ("", "python"):
        out, rep = _comp(text, m, ErrorSet(), MACHINES[mach][1], monkeypatch, tok,
                         work_offsets=G154_OFFSETS)
        assert out == text, tok


@pytest.mark.parametrize("err", ["rotz", "tilt"])
@pytest.mark.parametrize("mach", MACHINES)
@pytest.mark.parametrize("name", INTERPRETED)
def test_written_positions_land_where_the_program_meant(name, mach, err, monkeypatch):
    m = load_machine(MACHINES[mach][0])
    start = MACHINES[mach][1] or {}
    text = PROGRAMS[name]
    ERR = {"rotz": globals()["ERR"], "tilt": TILT}[err]
    if err == "tilt" and name in TILT_REFUSED:
        # a Z move under G16 that the tilt turns into an X Y Z move
        with pytest.raises(InputError, match=TILT_REFUSED[name]):
            _comp(text, m, ERR, MACHINES[mach][1])
        return
    if err == "tilt" and name in TILT_LINEARISED:
        pytest.skip("test_linearised_arcs_stay_on_the_programmed_path")
    out, rep = _comp(text, m, ERR, MACHINES[mach][1], monkeypatch, "")
    out_py, _ = _comp(text, m, ERR, MACHINES[mach][1], monkeypatch, "python")
    assert out_py == out
    (before, tips), after = interpret(text, tips=True), interpret(out)
    assert [b[0] for b in after] == [b[0] for b in before]
    kn = rep["compensated"]
    assert len(kn) == len(before)
    rot0, rot1 = _rotary(text, before, start), _rotary(out, after, start)
    res = max(a.resolution for a in m.axes if a.kind == "linear")
    tol = 3 * 2.54 * res                          # a written increment, inch or mm, and rounding
    lines_in, lines_out = text.split("\n"), out.split("\n")
    assert len(lines_in) == len(lines_out)
    for j, ((n, p0, _, c0), (_, p1, _, c1)) in enumerate(zip(before, after)):
        for a in AXES:
            assert (p0[a] is None) == (p1[a] is None), (n, a)
        if not kn[j]:
            assert lines_out[n[1] - 1] == lines_in[n[1] - 1], n
            continue
        q0, q1 = _full(m, p0, rot0[j]), _full(m, p1, rot1[j])
        # (the axis positions, G43 length included; the tool cuts at its tip, the length below
        # the gauge point: that point must land where the program meant, under a tilt too)
        mt = _at_tip(m, tips[j])
        want = forward_position(mt, q0[None])[0]
        got = forward_position(mt, q1[None], ERR)[0]
        assert np.abs(got - want).max() <= tol, (n, got - want)
    # lines without motion keep every byte
    moved = {b[0][1] for b in before}
    for i, (a, b) in enumerate(zip(lines_in, lines_out), start=1):
        if i not in moved and "G92" not in a:       # G92's words are rewritten with the rest
            assert a == b, i


def test_g16_negative_radius_keeps_its_words():
    """A G16 block with a negative radius (the point opposite the angle): under zero errors it
    keeps its bytes, and a correction writes a negative radius near the programmed angle (the
    old rewrite wrote X10. Y-150. for X-10. Y30.)."""
    m = load_machine("vmc-moving-column")
    text = PROGRAMS["fanuc_polar_negative"]
    assert compensate_program(text, m, ErrorSet(), filename="r.nc")[0] == text
    out, _ = compensate_program(text, m, ERR, filename="r.nc")
    assert out.split("\n")[3].startswith("G1 X-9.99") and " Y30.1" in out.split("\n")[3]


def test_a_z_move_under_g16_that_would_need_x_y_words_is_refused():
    """Under a tilt a Z-only block moves X and Y too; under G16 its inserted X Y words would be
    read as a radius and an angle (the old rewrite wrote "G0 X5.0092 Y4.9948 Z2.0073" for
    "G0 Z2" there: the tool went 4.6 mm from the programmed point)."""
    m = load_machine("vmc-moving-column")
    text = ("G21 G90 G17\nG0 X5 Y5 Z5\nG16\nG0 Z2\nG1 X10 F100\nY30\nX-10 Y30.\nG15\n"
            "X1 Y1\nM30\n")
    with pytest.raises(InputError, match=r"r.nc:4: the compensation moves X or Y in a block under G16"):
        compensate_program(text, m, TILT, filename="r.nc")
    # with X Y written in every block under G16 the tilt is compensated
    ok = text.replace("G16\nG0 Z2\n", "G0 Z2\nG16\n")
    out, rep = compensate_program(ok, m, TILT, filename="r.nc")
    assert rep["after_max"] < 1e-3


@pytest.mark.parametrize("tok", ["", "python"])
def test_a_corrupted_polar_word_is_caught(tok, monkeypatch):
    """Polar programs (and every program on the numpy tokenizer) are read back by parsing the
    output whole; what that reading gives must be what was computed, else nothing is written
    (before, a wrong digit there went to the machine with only the report's error figures
    showing it)."""
    import importlib
    from mtcomp.gcode import _ctok
    rewrite = importlib.import_module("mtcomp.gcode.rewrite")
    m = load_machine("vmc-moving-column")
    text = PROGRAMS["fanuc_polar_negative"]
    monkeypatch.setenv("MTCOMP_TOKENIZER", tok)
    compensate_program(text, m, ERR, filename="r.nc")
    mod = rewrite if tok == "python" or _ctok.load() is None else _ctok
    # the next-to-last digit of the first word
    calls = corrupt_formatting(monkeypatch, mod, 0, back=2)
    with pytest.raises(InputError, match="not what was computed"):
        compensate_program(text, m, ERR, filename="r.nc")
    assert calls


def test_g91_half_count_increments_are_refused_under_a_correction():
    """Z0.00005 at 0.0001 mm is half a count: rounded up by one control, to even (here: 0) by
    mtcomp's count model; after 150 such blocks the absolute Z inserted into the G90 block was
    7.5 µm from where the interpreter (and a control summing the words) stands."""
    m = load_machine("vmc-moving-column")
    text = ("G21 G90 G17\nG0 X0 Y0 Z1\nG1 Z0 F100\nG91\n"
            + "G1 X0.00037 Y-0.00011 Z0.00005\n" * 150 + "G90 X0.5 Y0.5\nM30\n")
    assert compensate_program(text, m, ErrorSet(), filename="r.nc")[0] == text
    with pytest.raises(InputError, match=r"r.nc:7: G91 increments such as Z5e-05 are half a count"):
        compensate_program(text, m, TILT, filename="r.nc")
    # increments finer than a count but not at a half: rounded as the control rounds them;
    # two halves on an axis (at most a count apart) are read too
    for t in (text.replace("Z0.00005", "Z0.00004"),
              text.replace("G1 X0.00037 Y-0.00011 Z0.00005\n" * 148, "G1 X0.00037\n" * 148)):
        out, rep = compensate_program(t, m, TILT, filename="r.nc")
        assert rep["compensated"].all() and out != t


def test_g52_local_shift_under_a_rotation():
    """G52 X10 Y5 (the interpreter of the corpus has no G52): the written words are the rotated
    and translated point (11, 6) less the shift, to the resolution."""
    m = load_machine("vmc-moving-column")
    text = "G21 G90\nG0 X0 Y0 Z5\nG52 X10 Y5\nG1 X1 Y1 F100\nG52 X0 Y0\nG1 X1 Y1\nM30\n"
    out, _ = compensate_program(text, m, ERR, filename="r.nc")
    t = np.radians(0.03)
    R = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    tr = np.array(ERR.workpiece.translation[:2])
    for line, point, shift in ((3, (11.0, 6.0), (10.0, 5.0)), (5, (1.0, 1.0), (0.0, 0.0))):
        want = R @ point + tr - shift
        words = dict(re.findall(r"([XY])([-\d.]+)", out.split("\n")[line]))
        assert abs(float(words["X"]) - want[0]) <= 0.5e-4 + 1e-12
        assert abs(float(words["Y"]) - want[1]) <= 0.5e-4 + 1e-12


def test_g154_and_g116_work_offsets_under_a_rotation():
    """Haas G154 P7 (and its other name G116) against G54, offsets given: every block's point,
    followed in the G54 frame through the offset switches (a word not written keeps the
    axis where it stands, so in the other frame it reads differently), is the rotated and
    translated programmed point, to the inch increment."""
    m = load_machine("vmc-moving-column")
    t = np.radians(0.03)
    R = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    tr = np.array(ERR.workpiece.translation[:2])
    g116 = {"G54": G154_OFFSETS["G54"], "G154 P7": G154_OFFSETS["G154 P7"]}
    for text in (PROGRAMS["haas_g154"], PROGRAMS["haas_g154"].replace("G154 P7", "G116")):
        out, rep = compensate_program(text, m, ERR, filename="r.nc", work_offsets=g116)
        assert rep["compensated"].all()
        pos_in, pos_out, off = {}, {}, np.zeros(2)
        for a, b in zip(text.split("\n"), out.split("\n")):
            if "G154" in a or "G116" in a:
                off = np.array([12.7, 12.7])          # G154 P7 less G54, mm
            elif "G54" in a:
                off = np.zeros(2)
            for pos, line in ((pos_in, a), (pos_out, b)):
                for k, v in re.findall(r"([XY])([-\d.]+)", line):
                    pos[k] = float(v) * 25.4 + off["XY".index(k)]
            if re.search(r"[XY]", a):
                want = R @ np.array([pos_in["X"], pos_in["Y"]]) + tr
                got = np.array([pos_out["X"], pos_out["Y"]])
                assert np.abs(got - want).max() <= 0.5 * 2.54e-4 + 1e-9, (a, b, got - want)


_PLANE_AXES = {17: (0, 1, 2), 18: (2, 0, 1), 19: (1, 2, 0)}


def _path_distance(points, blocks, planes):
    """Distance (mm) of each point (M, 3) from the programmed path of the interpreter's
    `blocks`: straight segments between end points, arcs about their centres (planar)."""
    d = np.full(len(points), np.inf)
    prev = None
    for (n, pos, mode, centre), plane in zip(blocks, planes):
        end = np.array([pos[a] if pos[a] is not None else np.nan for a in AXES])
        if prev is not None and not np.isnan(prev).any() and not np.isnan(end).any():
            if mode in (2, 3) and centre is not None:
                u, v, w = _PLANE_AXES[plane]
                c = np.array(centre)
                r = np.hypot(*(prev[[u, v]] - c))
                a0 = np.arctan2(*(prev[[v, u]] - c[::-1]))
                a1 = np.arctan2(*(end[[v, u]] - c[::-1]))
                sgn = 1.0 if mode == 3 else -1.0
                sweep = (sgn * (a1 - a0)) % (2 * np.pi) or 2 * np.pi
                ang = np.arctan2(points[:, v] - c[1], points[:, u] - c[0])
                t = (sgn * (ang - a0)) % (2 * np.pi)
                rho = np.hypot(points[:, u] - c[0], points[:, v] - c[1])
                on = np.sqrt((rho - r) ** 2 + (points[:, w] - end[w]) ** 2)
                ends = np.minimum(np.linalg.norm(points - prev, axis=1),
                                  np.linalg.norm(points - end, axis=1))
                d = np.minimum(d, np.where(t <= sweep + 1e-9, on, ends))
            else:
                seg = end - prev
                L2 = float(seg @ seg)
                s_ = np.clip((points - prev) @ seg / L2, 0, 1) if L2 > 0 else np.zeros(len(points))
                d = np.minimum(d, np.linalg.norm(points - (prev + s_[:, None] * seg), axis=1))
        prev = end
    return d


@pytest.mark.parametrize("mach", MACHINES)
@pytest.mark.parametrize("name", sorted(TILT_LINEARISED))
def test_linearised_arcs_stay_on_the_programmed_path(name, mach):
    """Under a tilt an arc is written as line segments: every written point, read back by the
    interpreter and run through the forward model with the errors, lies on the programmed path
    (within the chordal tolerance and a few increments), and every programmed end point is
    reached."""
    m = load_machine(MACHINES[mach][0])
    start = MACHINES[mach][1] or {}
    text = PROGRAMS[name]
    if name == "fanuc_inch_g91" and mach == "5axis":
        # its G10 set X Y Z of G54 and G55, not B: the tilt moves B, refused
        with pytest.raises(InputError, match="moves B, whose work offsets the program does not"):
            _comp(text, m, TILT, MACHINES[mach][1])
        return
    out, rep = _comp(text, m, TILT, MACHINES[mach][1])
    assert rep["linearised"] > 0
    (before, tips0), (after, tips1) = interpret(text, tips=True), interpret(out, tips=True)
    rot1 = _rotary(out, after, start)
    # the plane of each input block, as the interpreter's modal G17/G18/G19 (these programs: 17,
    # but for the G18 arc of none of them)
    planes = [17] * len(before)
    known = [i for i, b in enumerate(after) if all(b[1][a] is not None for a in AXES)]
    # at the tool tip (the G43 length below the gauge point), where the tool cuts
    pts = np.array([forward_position(_at_tip(m, tips1[i]),
                                     _full(m, after[i][1], rot1[i])[None], TILT)[0] for i in known])
    res = max(a.resolution for a in m.axes if a.kind == "linear")
    tol = rep["chordal_tol"] + 4 * 2.54 * res
    # the forward model's tool point is in the workpiece frame: the nominal point of the same
    # axis positions with no errors is the programmed point
    nominal = [b for b in before if all(b[1][a] is not None for a in AXES)]
    pn = np.array([forward_position(_at_tip(m, tips0[i]), _full(m, b[1], start)[None])[0]
                   for i, b in enumerate(before) if all(b[1][a] is not None for a in AXES)])
    nb = [(n, dict(zip(AXES, p)), mode, c) for (n, _, mode, c), p in zip(nominal, pn)]
    d = _path_distance(pts, nb, planes)
    assert d.max() <= tol, (d.max(), tol)
    # every programmed end point is among the written points
    for p in pn:
        assert np.linalg.norm(pts - p, axis=1).min() <= tol


def test_tool_tip_lands_on_the_programmed_point_under_a_tilt_with_g43():
    """On a 3-axis machine the tool stays along Z: its tip is the axis position less the G43
    length.  Under a workpiece tilt the tip must land on the programmed point."""
    m = load_machine("vmc-moving-column")
    text = "G21 G90\nG10 L10 P1 R25.\nG43 H1 G0 X10 Y5 Z5\nG1 Z-1 F100\nX20\nM30\n"
    out, rep = compensate_program(text, m, TILT, filename="r.nc")
    before, after = interpret(text), interpret(out)
    for (n, p0, _, _), (_, p1, _, _) in zip(before, after):
        tip0 = np.array([p0["X"], p0["Y"], p0["Z"] - 25.0])
        tip1 = np.array([p1["X"], p1["Y"], p1["Z"] - 25.0])
        got = forward_position(m, tip1[None], TILT)[0]
        want = forward_position(m, tip0[None])[0]
        assert np.abs(got - want).max() <= 3e-4, (n, got - want)
