"""Tool lengths and work offsets as shops keep them (issue 20): LinuxCNC tool tables, an offsets
TOML file, and G10 in the program read in program order as the control executes it."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from mtcomp import InputError, gcode
from mtcomp.errors import ErrorSet, ToolSetting, save_errors
from mtcomp.gcode.offsets import read_offsets, read_tool_table, tool_lengths_from

XYZ = ("X", "Y", "Z")


def run(*args):
    return subprocess.run([sys.executable, "-m", "mtcomp", *map(str, args)], capture_output=True,
                          text=True, timeout=120)


def test_linuxcnc_tool_table(tmp_path):
    tbl = tmp_path / "tool.tbl"
    tbl.write_text("T1 P1 Z+50.0 D6.0 ;end mill 6\n\n;spare\nT2  P2 Z35.125 D3 X0 ;drill\nT7 P3 D1.\n")
    assert read_tool_table(tbl) == {1: 50.0, 2: 35.125}            # T7 has no length
    assert tool_lengths_from(str(tbl)) == {1: 50.0, 2: 35.125}
    bad = tmp_path / "bad.tbl"
    bad.write_text("T1 P1 Z50.\nT2 P2 Z=35\n")
    with pytest.raises(InputError, match=r"bad.tbl:2: expected a tool table line"):
        read_tool_table(bad)
    # G43 H2 takes tool 2's Z; G43 without H (LinuxCNC) the loaded tool's
    text = "G90 G0 X0 Y0 Z100.\nT2 M6\nG43 H2 Z10.\nG49 Z100.\nT1 M6\nG43 Z10.\n"
    p = gcode.parse(text, axes=XYZ, tool_lengths=read_tool_table(tbl))
    assert np.allclose(p.position[:, 2], [100, 45.125, 100, 60])
    assert any("loaded tool" in n for n in p.notes)


def test_offsets_toml(tmp_path):
    f = tmp_path / "offsets.toml"
    f.write_text('[H]\n1 = 80.5\nH2 = 40\n[D]\n1 = 3.0\n[G54]\nX = 0.0\n[G55]\nX = 100.0\nY = -20.0\n'
                 '["G54.1 P2"]\nX = 200.0\n')
    tools, cutters, works = read_offsets(f, XYZ)
    assert tools == {1: 80.5, 2: 40.0} and cutters == {1: 3.0}
    assert works == {"G54": {"X": 0.0}, "G55": {"X": 100.0, "Y": -20.0}, "G54.1 P2": {"X": 200.0}}
    text = "G54 G90 G0 X0 Y0 Z5.\nG55 X1.\nG54.1 P2 X1.\nG43 H1 Z5.\n"
    p = gcode.parse(text, axes=XYZ, tool_lengths=tools, work_offsets=works)
    assert np.allclose(p.position, [[0, 0, 5], [101, 0, 5], [201, 0, 5], [201, 0, 85.5]])
    # (Y not written after G55: the axis stays where it is, as on the control)
    bad = tmp_path / "bad.toml"
    bad.write_text("[G60]\nX = 1.0\n")
    with pytest.raises(InputError, match=r"bad.toml \[G60\]: expected tables \[H\], \[D\]"):
        read_offsets(bad, XYZ)
    bad.write_text("[H]\n1 = \"long\"\n")
    with pytest.raises(InputError, match=r"\[H.1\]"):
        read_offsets(bad, XYZ)


def test_offsets_files_on_the_cli(tmp_path):
    prog = tmp_path / "p.ngc"
    prog.write_text("g21 g90 g54\ng0 x0 y0 z40.\nt1 m6\ng43 h1 z-60.\ng55 x5.\ng1 z-71. f100\nm2\n")
    err = save_errors(ErrorSet(ToolSetting((0.002, 0, 0.001))), tmp_path / "e.toml")
    tbl = tmp_path / "tool.tbl"
    tbl.write_text("T1 P1 Z+50.0 D6.0 ;comment\n")
    off = tmp_path / "offsets.toml"
    off.write_text("[G54]\nX = 0.0\n[G55]\nX = 100.0\n")
    out = tmp_path / "o.ngc"
    r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", out, "--tool-table", tbl,
            "--offsets", off)
    assert r.returncode == 0, r.stderr
    assert "H1" not in r.stdout                    # no "tool length not given" note
    text = out.read_text()
    assert "g55 x4.9980\n" in text and "g43 h1 z-60.0010\n" in text and "H1=50" in text
    r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", out)
    assert r.returncode == 2 and "give the work offsets (G54, G55)" in r.stderr


# ------------------------------------------------------------------------------------- G10

def test_g10_work_offsets_read_as_the_control_does():
    # Fanuc/LinuxCNC G10 L2 P1..P6 set G54..G59; positions in the frame of the offset in
    # effect at the first motion block (G54 = (100, 0, -50) here)
    text = ("G10 L2 P1 X100. Y0 Z-50.\nG10 L2 P2 X200. Y0 Z-50.\nG54 G90 G0 X0 Y0 Z5.\nG55 X0\n"
            "G10 L2 P2 X201.5\nG90 X0\nG54 X0\n")
    p = gcode.parse(text, axes=XYZ)
    # G55 - G54 = 100, then 101.5 after the second G10
    assert np.allclose(p.position[:, 0], [0, 100, 101.5, 0])
    assert any("G10" in n for n in p.notes)
    assert gcode.rewrite(p, lambda q: q.copy()) == text
    out = gcode.rewrite(p, lambda q: q + [0.001, 0, 0])
    assert out.splitlines()[:2] == text.splitlines()[:2]       # G10 words are data, not moves
    assert out.splitlines()[3] == "G55 X0.001000"
    back = gcode.parse(out, axes=XYZ)
    assert np.allclose(back.position[:, 0], p.position[:, 0] + 0.001)


def test_g10_extended_offset_adds_in_g91():
    text = "G10 L20 P3 X50. Y0 Z0\nG91 G10 L20 P3 X1.\nG90 G54.1 P3 G0 X1. Y0 Z0\nG54 X1.\n"
    p = gcode.parse(text, axes=XYZ, work_offsets={"G54": (0, 0, 0)})
    assert np.allclose(p.position[:, 0], [1, -50])


def test_g10_changing_the_active_offset_mid_program():
    text = "G54 G90 G0 X0 Y0 Z5.\nG10 L2 P1 X5.\nX1.\n"
    # G54 before is not known: the change cannot be told
    with pytest.raises(InputError, match=r":2: from here on G54 X differs from G54 at the first "
                                         r"motion block by an amount not known"):
        gcode.parse(text, axes=XYZ)
    p = gcode.parse(text, axes=XYZ, work_offsets={"G54": (2.0, 0, 0)})
    assert np.allclose(p.position[:, 0], [0, 4])                # 1 + (5 - 2)


def test_g10_extended_offsets_only_with_g54_1():
    text = "G10 L20 P3 X50. Y0 Z0\nG54.1 P3 G90 G0 X1. Y0 Z0\nG54 X1.\n"
    p = gcode.parse(text, axes=XYZ, work_offsets={"G54": (0, 0, 0)})
    assert np.allclose(p.position[:, 0], [1, -49])
    with pytest.raises(InputError, match=r":1: G10 L20 sets the G54.1 P offsets on Fanuc"):
        gcode.parse("G10 L20 P1 X0 Y0\nG0 X1.\n", axes=XYZ)


def test_g10_l20_sets_haas_g154_offsets():
    # Haas: G10 L20 P<n> sets G154 P<n> (G110..G129 are G154 P1..P20); was read as G54.1 P<n>,
    # so the program's G154 P7 had no offset and was refused
    text = "G10 L20 P7 X50. Y0 Z0\nG154 P7 G90 G0 X1. Y0 Z0\nG54 X1.\n"
    p = gcode.parse(text, axes=XYZ, work_offsets={"G54": (0, 0, 0)})
    assert np.allclose(p.position[:, 0], [1, -49])
    text = "G10 L20 P3 X20. Y0 Z0\nG112 G90 G0 X1. Y0 Z0\nG54 X1.\n"      # G112 = G154 P3
    p = gcode.parse(text, axes=XYZ, work_offsets={"G54": (0, 0, 0)})
    assert np.allclose(p.position[:, 0], [1, -19])
    with pytest.raises(InputError, match=r":1: G10 in a program with both G54.1 P \(Fanuc\) and G154"):
        gcode.parse("G10 L20 P1 X0 Y0 Z0\nG54.1 P1 G0 X1. Y0 Z0\nG154 P1 X2.\n", axes=XYZ)


def test_work_offsets_by_haas_names_and_misspelt_names():
    # the Python API's work_offsets: G116 is G154 P7 (was ignored without a word); a name that is
    # no work offset is refused naming it
    text = "G116 G90 G0 X1. Y0 Z0\nG54 X1.\n"
    p = gcode.parse(text, axes=XYZ, work_offsets={"G54": (0, 0, 0), "G116": (30, 0, 0)})
    assert np.allclose(p.position[:, 0], [1, -29])
    with pytest.raises(InputError, match=r"work offset 'G45': expected G54..G59"):
        gcode.parse(text, axes=XYZ, work_offsets={"G45": (0, 0, 0), "G116": (30, 0, 0)})


def test_g10_tool_lengths():
    # Fanuc memory C: L10 geometry, L11 wear (G91 adds); LinuxCNC: L1 P<tool> Z
    text = ("G10 L10 P1 R50.\nG10 L11 P1 R-0.02\nG90 G0 X0 Y0 Z100.\nG43 H1 Z10.\n"
            "G49 Z100.\nG91 G10 L11 P1 R-0.01\nG90 G43 H1 Z10.\nG10 L1 P2 Z30.\nG43 H2 Z10.\n")
    p = gcode.parse(text, axes=XYZ)
    assert np.allclose(p.position[:, 2], [100, 59.98, 100, 59.97, 40])
    assert not any("not given" in n for n in p.notes)
    assert gcode.rewrite(p, lambda q: q.copy()) == text


@pytest.mark.parametrize("text,line,what", [
    ("G54 G0 X0\nG55 X1.\nG10 L2 P0 X1.\n", 3, "P0 sets the external .* uses G54, G55"),
    ("G10 L2 P7 X1.\n", 1, "G59.1-G59.3 are not"),
    ("G10 L2 P1 X1. R30.\n", 1, "with R .a rotation"),
    ("G10 L10 P1 Z5.\n", 1, "L10 with Z: not read"),
    ("G10 L20 P1 X0\n", 1, "L20 sets the G54.1"),
    ("G10 P1 R5.\n", 1, "without L or P"),
    ("G91 G10 L2 P1 X1.\n", 1, "L2 in G91: Fanuc adds"),
    ("G91 G10 L1 P1 Z1.\n", 1, "L1 in G91"),
    ("G0 X0 Y0 Z0\nG10 L1 P1 R5.\nG43 H1 Z1.\n", 3, "G10 L1 P1 R on line 2 is a tool length on Fanuc"),
    ("G10 L2 P1 G0 X1.\n", 1, "G10 in a block with motion"),
    ("G10 L10 P1 R5.\nG0 X0 Y0 Z9.\nG43 H1 Z5.\nG10 L11 P1 R-0.1\nZ4.\n", 4,
     "G10 changes the length of H1 while it is active"),
])
def test_g10_refusals_name_the_line(text, line, what):
    with pytest.raises(InputError, match=rf"^p.nc:{line}: .*{what}"):
        gcode.parse(text, axes=XYZ, filename="p.nc")


def test_g10_l1_radius_only_is_harmless_where_unused():
    # LinuxCNC G10 L1 P1 R3 (a radius) for a tool whose length is never applied: nothing refused
    p = gcode.parse("G10 L1 P1 R3.\nG90 G0 X1. Y0 Z0\n", axes=XYZ)
    assert np.allclose(p.position, [[1, 0, 0]])


def test_g10_offsets_of_axes_the_program_does_not_write():
    # a 3-axis program on a 5-axis machine: G10 sets X Y Z of G54 and G55, B and C are the
    # control's; the program reads (B C are never commanded) but a compensation that writes B
    # or C would depend on them: refused naming the block
    text = "G10 L2 P1 X0 Y0 Z0\nG10 L2 P2 X50. Y0 Z0\nG54 G90 G0 X0 Y0 Z5.\nG55 X0\nY1.\n"
    axes = ("X", "Y", "Z", "B", "C")
    p = gcode.parse(text, axes=axes)
    assert p.offset_assumed == ("B", "C") and any("taken as 0" in n for n in p.notes)
    assert np.allclose(p.position[:, 0], [0, 50, 50])
    assert gcode.rewrite(p, lambda q: q + [0.001, 0, 0, 0, 0]).splitlines()[3] == "G55 X0.001000"
    with pytest.raises(InputError, match=r":3: the compensation moves B, whose work offsets"):
        gcode.rewrite(p, lambda q: q + [0, 0, 0, 0.001, 0])


def test_tool_table_with_an_h_column(tmp_path):
    """A table whose tools carry their own length offset number: G43 H<n> takes the tool with
    H n, not tool n; a tool change loads the tool's own length; without an H column H = T, and
    the table says so (issue 20)."""
    tbl = tmp_path / "tool.tbl"
    tbl.write_text("T12 P1 H2 Z+80.0 ;face mill\nT2 P2 H12 Z+35.0 ;drill\n")
    t = read_tool_table(tbl)
    assert t == {2: 80.0, 12: 35.0} and t.by_tool == {12: 80.0, 2: 35.0}
    assert "H column" in t.note and "H = T" not in t.note
    text = "G90 G0 X0 Y0 Z100.\nT12 M6\nG43 H2 Z10.\nG49 Z100.\nT2 M6\nG43 Z10.\n"
    p = gcode.parse(text, axes=XYZ, tool_lengths=t)
    # G43 H2 -> 80 (T12's line); G43 without H after T2 M6 -> T2's own entry (H12, 35)
    assert np.allclose(p.position[:, 2], [100, 90, 100, 45])
    # after the change to T2, before its G43: its tip is T2's length (35), not H2's (80)
    q = gcode.parse("G90 G0 X0 Y0 Z100.\nT2 M6\nG0 X1.\nG43 H12 Z10.\n", axes=XYZ, tool_lengths=t)
    assert np.allclose(q.tool_tip, [0, 35, 35])
    plain = tmp_path / "plain.tbl"
    plain.write_text("T12 P1 Z+80.0\n")
    assert "no H column: H = T" in read_tool_table(plain).note
    mixed = tmp_path / "mixed.tbl"
    mixed.write_text("T1 P1 H1 Z50.\nT2 P2 Z40.\n")
    with pytest.raises(InputError, match=r"mixed.tbl:2: T2 has no H word"):
        read_tool_table(mixed)
    dup = tmp_path / "dup.tbl"
    dup.write_text("T1 P1 H5 Z50.\nT2 P2 H5 Z40.\n")
    with pytest.raises(InputError, match=r"dup.tbl:2: H5 is given two lengths"):
        read_tool_table(dup)


def test_tool_table_convention_said_on_the_cli(tmp_path):
    prog = tmp_path / "p.nc"
    prog.write_text("G21 G90 G54\nG0 X0 Y0 Z40.\nT1 M6\nG43 H1 Z-60.\nG1 Z-71. F100\nM30\n")
    err = save_errors(ErrorSet(ToolSetting((0.002, 0, 0.001))), tmp_path / "e.toml")
    tbl = tmp_path / "tool.tbl"
    tbl.write_text("T1 P1 Z+50.0\n")
    out = tmp_path / "o.nc"
    r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", out, "--tool-table", tbl)
    assert r.returncode == 0, r.stderr
    assert "no H column: H = T" in r.stdout and "H1=50 [H = T]" in out.read_text()
    tbl.write_text("T1 P1 H1 Z+50.0\n")
    r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", out, "--tool-table", tbl)
    assert r.returncode == 0, r.stderr
    assert "lengths by the H column" in r.stdout and "H = T" not in out.read_text()


def test_tool_change_under_g43_keeps_the_length_and_warns(tmp_path):
    """Fanuc/Haas: M6 under active G43 keeps the old H length until the next G43 H; a feed move
    before that new G43 H is warned with its lines (issue 20)."""
    lengths = {1: 50.0, 2: 30.0}
    text = ("G90 G0 X0 Y0 Z100.\nT1 M6\nG43 H1 Z10.\nG1 Z5. F100\n"
            "T2 M6\nG0 X10.\nG1 Z2.\nG43 H2 Z1.\nM30\n")
    p = gcode.parse(text, axes=XYZ, tool_lengths=lengths)
    # the old H1 length stays through the change: Z2 (line 7) is 2 + 50, after G43 H2 1 + 30
    assert np.allclose(p.position[:, 2], [100, 60, 55, 55, 52, 31])
    w = [n for n in p.notes if n.startswith("warning:")]
    assert len(w) == 1 and "line 5 under G43" in w[0] and "H1" in w[0] and "line 7" in w[0]
    # a new G43 H before the feed, G49, a change with its own G43 H, or rapids only: no warning
    for ok in ("T2 M6\nG0 X10.\nG43 H2 Z10.\nG1 Z2.\n", "T2 M6\nG49 Z100.\nG1 Z2.\n",
               "T2 M6 G43 H2\nG1 Z2.\n", "T2 M6\nG0 X10.\nM30\n"):
        q = gcode.parse("G90 G0 X0 Y0 Z100.\nT1 M6\nG43 H1 Z10.\n" + ok, axes=XYZ,
                        tool_lengths=lengths)
        assert not [n for n in q.notes if n.startswith("warning:")], ok
    # on the CLI the warning goes to stderr, with the lines, and the program is still written
    prog = tmp_path / "p.nc"
    prog.write_text(text.replace("Z100.", "Z40."))         # within the preset's Z travel
    err = save_errors(ErrorSet(ToolSetting((0.002, 0, 0.001))), tmp_path / "e.toml")
    r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", tmp_path / "o.nc",
            "--tool-lengths", "1=5,2=3")
    assert r.returncode == 0, r.stderr
    assert "warning: tool change on line 5 under G43" in r.stderr


def test_g10_l2_p0_in_a_program_with_one_work_offset():
    """G10 L2 P0 is Fanuc's external offset and LinuxCNC's current one: in a program that stays
    in G54 both shift G54, so it is read as G10 L2 P1 (a real program sets Z so, before its
    G54); with two work offsets it is refused (test_g10_refusals_name_the_line) (issue 20)."""
    body = "G21 G90\n{g10}\nG54\nG0 X1. Y2. Z10.\nG10 L2 P{p} Z-45.\nG1 Z5. F100\n"
    for p in (0, 1):
        q = gcode.parse(body.format(g10=f"G10 L2 P{p} Z-50.", p=p), axes=XYZ)
        # the reference frame is G54 at the first motion (Z-50); the second G10 moves it by +5
        assert np.allclose(q.position[:, 2], [10, 10]) and np.allclose(q.offset[:, 2], [0, 5])
    text = body.format(g10="G10 L2 P0 Z-50.", p=0)
    assert gcode.rewrite(gcode.parse(text, axes=XYZ), lambda x: x.copy()) == text


def test_g92_word_carries_the_correction_of_the_point_it_names():
    """G92 names the coordinates of the point where the tool stands.  In the compensated
    program the tool stands at the compensated point, so the G92 words get that point's
    correction: otherwise the control's G92 shift takes the correction in, and every later
    absolute block is corrected twice (found on a filament-winder program of the corpus)."""
    from test_gcode_corpus import interpret
    text = "G21 G90\nG0 X10 Y5 Z1\nG92 X0 Y0\nG1 X5 Y2 F100\nG1 X7\nG92.1\nG1 X4\n"
    t = np.array([0.0123, -0.0071, 0.0042])
    p = gcode.parse(text, axes=XYZ)
    out = gcode.rewrite(p, lambda q: q + t)
    assert out.split("\n")[2] == "G92 X0.012300 Y-0.007100"
    before, after = interpret(text), interpret(out)
    assert [b[0] for b in after] == [b[0] for b in before]
    for (_, p0, _, _), (_, p1, _, _) in zip(before, after):
        assert [p1[a] - p0[a] for a in "XYZ"] == pytest.approx(t, abs=1e-9)
    # a G92 where nothing is corrected stays byte for byte
    assert gcode.rewrite(p, lambda q: q.copy()) == text


def test_g92_word_correction_in_an_inch_program():
    """The G92 word of an inch program gets the correction in inch, like the axis words."""
    from test_gcode_corpus import interpret
    text = "G20 G90\nG0 X1. Y1. Z0.1\nG92 X0\nG1 X0.5 F10.\nG1 Y2.\n"
    t = np.array([0.0254, 0.0, 0.0])                     # 0.001 inch in X
    out = gcode.rewrite(gcode.parse(text, axes=XYZ), lambda q: q + t)
    assert out.split("\n")[2].startswith("G92 X0.0010")
    for (_, p0, _, _), (_, p1, _, _) in zip(interpret(text), interpret(out)):
        assert [p1[a] - p0[a] for a in "XYZ"] == pytest.approx(t, abs=1e-7)


def test_a_program_in_one_work_offset_other_than_g54_is_read():
    """A program that selects G55 (and no other offset, no G10) is read in G55's frame: it raised
    an IndexError (a traceback) before, with or without offset values given."""
    text = "G90 G55 G0 X0 Y0 Z1.\nG1 X2. F100.\n"
    for kw in ({}, {"work_offsets": {"G55": {"X": 100.0}}}):
        p = gcode.parse(text, axes=("X", "Y", "Z"), **kw)
        assert np.allclose(p.position, [[0, 0, 1], [2, 0, 1]])


def test_haas_g154_and_g110_work_offsets(tmp_path):
    """Haas' additional work offsets G154 P1-P99 (G110-G129 = G154 P1-P20) are work offsets
    like G54.1 P (they were unknown G codes): one used alone is read as it is, switching takes
    their values from the offsets file (by either name)."""
    XYZ = ("X", "Y", "Z")
    p = gcode.parse("G90 G154 P1 G0 X0 Y0 Z1.\nG1 X2. F100.\n", axes=XYZ)
    assert np.allclose(p.position[:, 0], [0, 2])
    text = "G90 G54 G0 X0 Y0 Z1.\nG154 P2 G0 X1.\nG110 X2.\nG154 P1 X3.\n"
    with pytest.raises(InputError, match=r":2: the program switches from G54 to G154 P2"):
        gcode.parse(text, axes=XYZ)
    f = tmp_path / "off.toml"
    f.write_text('[G54]\nX = 0.0\n["G154 P2"]\nX = 100.0\n[G110]\nX = 50.0\n')
    _, _, works = read_offsets(f, XYZ)
    assert set(works) == {"G54", "G154 P2", "G154 P1"}
    p = gcode.parse(text, axes=XYZ, work_offsets=works)
    assert np.allclose(p.position[:, 0], [0, 101, 52, 53])         # G110 is G154 P1
    f.write_text('[G130]\nX = 1.0\n')
    with pytest.raises(InputError, match=r"G154 P<n>"):
        read_offsets(f, XYZ)


# -- LinuxCNC G43.1 dynamic tool length (issue 20 follow-up)

G431 = "G21 G90\nG0 X0 Y0 Z10\nG43.1 Z25.5\nG0 Z5\nG1 Z-1 F100\nG43.1 Z20\nG1 Z-2\nG49\nG0 Z30\n"


def test_g43_1_reads_its_z_word_as_the_tool_length():
    """G43.1 Z<len>: the tool length is the Z word (no move), as G43 with that length until
    the next G43.1 or G49 (before: "unknown G code G43.1")."""
    p = gcode.parse(G431, axes=XYZ)
    assert p.line.tolist() == [2, 4, 5, 7, 9]                 # the G43.1 lines are no blocks
    assert np.allclose(p.position[:, 2], [10, 30.5, 24.5, 18, 30])
    assert np.allclose(p.tool_tip, [0, 25.5, 25.5, 20, 20])    # after G49: the last length
    assert any("G43.1" in n for n in p.notes)
    assert gcode.rewrite(p, lambda q: q.copy()) == G431
    out = gcode.rewrite(p, lambda q: q + [0, 0, 0.001])
    assert out.splitlines()[2] == "G43.1 Z25.5"              # a length, not rewritten
    assert out.splitlines()[3] == "G0 Z5.001000"
    # inch: the length in inch
    q = gcode.parse("G20 G90\nG0 X0 Y0 Z1.\nG43.1 Z2.\nG0 Z0.5\n", axes=XYZ)
    assert q.position[-1, 2] == pytest.approx(2.5 * 25.4)


@pytest.mark.parametrize("line, what", [
    ("G43.1", "G43.1 without Z, or with other axis words .none."),
    ("G43.1 X2. Z30.", "G43.1 without Z, or with other axis words .X."),
    ("G91 G43.1 Z30.", "G43.1 in G91: not read"),
    ("G0 G43.1 Z30.", "G43.1 in a block with a motion code"),
])
def test_g43_1_forms_not_read_are_refused(line, what):
    with pytest.raises(InputError, match=rf"d.ngc:2: {what}"):
        gcode.parse("G90 G0 X0 Y0 Z10\n" + line + "\nG0 Z5\n", axes=XYZ, filename="d.ngc")
