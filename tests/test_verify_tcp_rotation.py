"""Verification of G43.4 tool centre point and G68 rotated programs (issue 20, what goes to a
machine must be safe: issue 14).  Under G43.4 the verifier runs what the machine does: the
control's nominal inverse of the written tip and angles gives the axis positions, the forward
model with the errors the real tool tip; G43.4 rapids are checked along the tip-straight path and
the axis-linear path (controls differ).  Under G68 the rotation is applied, arcs included."""
from __future__ import annotations

import numpy as np
import pytest

from mtcomp.commands import compensate_program
from mtcomp.errors import ErrorSet, GeometricErrors, ToolSetting, WorkpieceSetting
from mtcomp.gcode import parse
from mtcomp.gcode.tcp import nominal_axes, tool_machine
from mtcomp.kinematics import forward
from mtcomp.machine import load_machine
from mtcomp.verify import Box, HalfSpace, VerifyError, verify_program

PLATE = Box((-10.0, -10.0, -3.0), (10.0, 10.0, 0.0))
ERRORS = ErrorSet(ToolSetting((0.002, -0.001, 0.003)),
                  WorkpieceSetting((0.01, -0.02, 0.005), (0.001, -0.002, 0.003)),
                  GeometricErrors(location={"EB0Z": 2e-5, "EC0Y": -1e-5}))


def tcp_program(body):
    return f"G21 G90\nG43.4 H1\n{body}G49\nM30\n"


def dense_min_z(machine, w0, w1, length, n=4001):
    """Lowest tool tip along the move w0 -> w1 (G43.4 words) with the axes interpolated
    linearly: the nominal inverse of both ends (mtcomp.gcode.tcp, not the verifier's own), then
    a dense uniform sampling through the forward model."""
    q = nominal_axes(machine, np.array([w0, w1], float), [length, length])
    s = np.linspace(0, 1, n)[:, None]
    return forward(tool_machine(machine, length), q[0] + s * (q[1] - q[0])).p[:, 2].min()


@pytest.mark.parametrize("length", [0.0, 40.0])
def test_tcp_rapid_that_swings_into_the_stock_in_axis_space_is_caught(length):
    # G00 B-30 under G43.4 from the tip (-5, 0, 1) to (5, 0, 1): straight, the tip keeps 1 mm;
    # a control that moves every axis linearly (many do in G00 under TCP) dips into the plate
    m = load_machine("robonano-a0ib")
    text = tcp_program("G00 C0. B0. X-5. Y0. Z1.\nG00 B-30. X5. Z1.\n")
    tip = verify_program(m, text, stock=PLATE, clearance=0.2, tcp_rapids="tip",
                         tool_lengths={1: length})
    assert tip.ok and tip.min_clearance == pytest.approx(1.0, abs=tip.step / 2)
    with pytest.raises(VerifyError, match=r"line 4 \(G00 B-30\. X5\. Z1\.\) \[G43\.4 rapid, axes "
                                          r"interpolated linearly\]: rapid move: the tool enters") as e:
        verify_program(m, text, stock=PLATE, clearance=0.2, tool_lengths={1: length})
    v = e.value.result.violations[0]
    expect = dense_min_z(m, [0, 0, -5, 0, 1], [0, -30, 5, 0, 1], length)
    assert expect < -0.3 and v.value == pytest.approx(expect, abs=e.value.result.step / 2)
    # turning the other way the axis-linear path rises: both paths pass
    ok = verify_program(m, tcp_program("G00 C0. B0. X-5. Y0. Z1.\nG00 B30. X5. Z1.\n"),
                        stock=PLATE, clearance=0.2, tool_lengths={1: length})
    assert ok.ok and ok.min_clearance == pytest.approx(1.0, abs=ok.step / 2)


FEED = ("G00 C0. B20. X-5. Y0. Z1.\nG01 Z{z} F100.\nG01 X5. Z{z} B25. C10.\n"
        "G01 X5. Y3. Z{z} B20. C20.\nG00 Z5.\n")


def test_tcp_program_on_the_real_machine_gouges_and_its_compensation_does_not():
    m = load_machine("robonano-a0ib")
    part = HalfSpace(0.0)
    text = tcp_program(FEED.format(z="0."))
    ideal = verify_program(m, text, part=part, tool_lengths={1: 40.0})
    assert ideal.ok and abs(ideal.min_part) < 1e-9                 # on the surface, nominally
    # the same words on the machine with the errors: the tip goes into the part by the errors
    real = verify_program(m, text, part=part, tool_lengths={1: 40.0}, errors=ERRORS,
                          raise_on_violation=False)
    assert [v.line for v in real.violations] == [4, 5, 6] and real.min_part < -0.003
    # at least as deep as the real tip at the block ends (nominal inverse, forward with errors)
    p = parse(text, axes=m.axis_names, tool_lengths={1: 40.0}, tcp=True)
    q = nominal_axes(m, p.position[1:4], [40.0] * 3)
    ends = forward(tool_machine(m, 40.0), q, ERRORS).p[:, 2]
    assert real.min_part <= ends.min() + 1e-12
    # compensated, the real tip is on the surface to the resolution (sqrt(3) nm)
    out, rep = compensate_program(text, m, ERRORS, tool_lengths={1: 40.0}, part=part)
    assert out != text and rep["verify"].ok and abs(rep["verify"].min_part) < 1.8e-6
    # a program that cuts 3 µm below the surface is caught in its compensated output, named
    bad = tcp_program(FEED.format(z="-0.003"))
    with pytest.raises(VerifyError, match=r"line 4 \(G01 X-4\.99\d+ Y-0\.0\d+ Z-0\.00\d+ F100\.\): feed "
                                          r"move gouges the part by 3\.00 µm") as e:
        compensate_program(bad, m, ERRORS, tool_lengths={1: 40.0}, part=part)
    assert [v.line for v in e.value.result.violations] == [4, 5, 6]
    assert all(v.value == pytest.approx(-0.003, abs=1.8e-6) for v in e.value.result.violations)


def test_a_program_switching_into_and_out_of_tcp_is_verified_in_each_mode():
    # axis moves before G43.4, tip words after: each block in its own meaning; the block right
    # after the switch is checked at its end (where its move starts, the tip, is not fixed yet)
    m = load_machine("robonano-a0ib")
    text = ("G21 G90\nG00 C0. B0. X0. Y0. Z5.\nG43.4 H1\nG00 X-5. Y0. Z1. B0. C0.\n"
            "G00 B-30. X5. Z1.\nG49\nG00 X0. Y0. Z5. B0. C0.\nM30\n")
    r = verify_program(m, text, stock=PLATE, clearance=0.2, raise_on_violation=False)
    assert [v.line for v in r.violations] == [5]
    assert parse(text, axes=m.axis_names, tcp=True).known.tolist() == [True, True, True, True]


# G68 R180 about the origin turns the half circle (5, 0) -> (0, 5) -> (-5, 0) into
# (-5, 0) -> (0, -5) -> (5, 0): its middle enters a part at y < -4.9 by 0.1 mm; the words alone
# (and the chord) stay clear of it
ROT = "G21 G90 G17\nG00 X0. Y0. Z5.\nG68 X0. Y0. R{r}\nG00 X5. Y0. Z5.\nG01 Z1. F100.\n" \
      "G03 X-5. Y0. I-5. J0.\nG00 Z5.\nG69\nG00 X0. Y0.\nM30\n"
BAR = Box((-1.0, -10.0, -3.0), (1.0, -4.9, 2.0))


def test_g68_rotation_is_applied_to_lines_and_arcs():
    m = load_machine("robonano-a0ib")
    with pytest.raises(VerifyError, match=r"line 6 \(G03 X-5\. Y0\. I-5\. J0\.\): feed move gouges "
                                          r"the part by 100(\.00)? µm") as e:
        verify_program(m, ROT.format(r="180."), part=BAR)
    v = e.value.result.violations[0]
    assert v.point[0] == pytest.approx(0.0, abs=0.01) and v.point[1] == pytest.approx(-5.0, abs=1e-3)
    # R0 (and no G68 at all) runs the words as written: clear of the bar
    assert verify_program(m, ROT.format(r="0."), part=BAR).ok
    # a rapid rotated into the stock: (25, 0) turned by 90 deg is (0, 25)
    stock = Box((-10.0, 20.0, -3.0), (10.0, 40.0, 0.0))
    rapid = "G21 G90\nG00 X0. Y0. Z5.\nG68 X0. Y0. R90.\nG00 X{x}. Y0.\nG00 Z-1.\nG00 Z5.\nG69\nM30\n"
    with pytest.raises(VerifyError, match=r"line 5 \(G00 Z-1\.\): rapid move: the tool enters"):
        verify_program(m, rapid.format(x=25), stock=stock)
    assert verify_program(m, rapid.format(x=-25), stock=stock).ok


def test_compensate_verifies_g68_programs_against_the_stock():
    m = load_machine("robonano-a0ib")
    errors = ErrorSet(workpiece=WorkpieceSetting((0.01, -0.02, 0.005), (0.0, 0.0, 0.0)))
    with pytest.raises(VerifyError, match=r"line 6 \(G03 X-5\.0.*feed move gouges the part"):
        compensate_program(ROT.format(r="180."), m, errors, part=BAR)
    out, rep = compensate_program(ROT.format(r="0."), m, errors, part=BAR)
    assert rep["verify"].ok


def test_tool_length_compensation_checks_the_tool_tip_not_the_gauge_point():
    # G43 H1 with a 20 mm tool: the axes stand 20 mm higher than the words, the tip where the
    # words say; a rapid to Z-1. puts the tip 1 mm into the stock (formerly checked at the
    # gauge point, 19 mm above it, and passed)
    m = load_machine("vmc-moving-column")
    text = "G21 G90\nG43 H1 Z25.\nG0 X1. Y1.\nG0 Z-1.\nG0 Z25.\nM30\n"
    stock = HalfSpace(0.0)
    with pytest.raises(VerifyError, match=r"line 4 \(G0 Z-1\.\): rapid move: the tool enters the stock "
                                          r"at -1000 µm") as e:
        verify_program(m, text, stock=stock, tool_lengths={1: 20.0})
    assert e.value.result.violations[0].value == pytest.approx(-1.0, abs=1e-9)
    errors = ErrorSet(ToolSetting((0.001, 0.0, 0.0)))
    with pytest.raises(VerifyError, match=r"line 4 \(G0 Z-1\.\): rapid move: the tool enters"):
        compensate_program(text, m, errors, tool_lengths={1: 20.0}, stock=stock)
    ok = verify_program(m, text.replace("Z-1.", "Z1."), stock=stock, tool_lengths={1: 20.0})
    assert ok.min_clearance == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize("b", [0.0, 30.0])
def test_ball_tool_under_tcp_sits_along_the_tilted_tool_axis(b):
    # a ball of radius r whose tip is on the plane z = 0 with the tool tilted by B (the table
    # turns the blank): the ball centre is r cos(B) above the plane, so it enters the material
    # by r (1 - cos B)
    m = load_machine("robonano-a0ib")
    r = 0.5
    text = tcp_program(f"G00 C0. B{b:.0f}. X-5. Y0. Z1.\nG01 Z0. F100.\nG01 X5.\nG00 Z5.\n")
    res = verify_program(m, text, part=HalfSpace(0.0), tool_radius=r, raise_on_violation=False,
                         tool_lengths={1: 30.0})
    assert res.min_part == pytest.approx(-r * (1 - np.cos(np.radians(b))), abs=1e-9)
    assert [v.line for v in res.violations] == ([] if b == 0 else [4, 5])


def test_after_g49_the_tool_is_still_in_the_spindle():
    # G49 cancels the length compensation: the words are axis positions again, but the 20 mm
    # tool still hangs below the gauge point until another tool is selected
    m = load_machine("vmc-moving-column")
    stock = HalfSpace(0.0)
    text = "G21 G90\nG43 H1 Z5.\nG0 X1. Y1.\nG49\nG0 Z15.\nG0 X2.\nT2\nG0 X3.\nM30\n"
    p = parse(text, axes=m.axis_names, tool_lengths={1: 20.0})
    assert p.tool_tip.tolist() == [20.0, 20.0, 20.0, 20.0, 0.0]
    res = verify_program(m, text, stock=stock, tool_lengths={1: 20.0}, raise_on_violation=False)
    assert [v.line for v in res.violations] == [5, 6]            # the tip 5 mm into the stock
    assert res.violations[1].value == pytest.approx(-5.0, abs=1e-9)


@pytest.mark.parametrize("source", ["lengths", "table", "offsets"])
def test_verify_command_checks_the_tool_tip_with_the_tool_lengths(tmp_path, capsys, source):
    # G43 H1 with a 40 mm tool, then G49: the axes stand where the words say and the tip 40 mm
    # below, so the rapid to Z42. puts the tip at Z2., into a stock whose top is at Z3.;
    # `mtcomp verify` had no tool lengths and checked the gauge point (40 mm up)
    from mtcomp.cli import main
    nc = tmp_path / "g43.nc"
    nc.write_text("G21 G90\nT1 M6\nG43 H1 Z50.\nG0 X1. Y1.\nG49\nG0 Z42.\nG0 Z90.\nM30\n")
    opt = {"lengths": ["--tool-lengths", "1=40"],
           "table": ["--tool-table", str(tmp_path / "tool.tbl")],
           "offsets": ["--offsets", str(tmp_path / "off.toml")]}[source]
    (tmp_path / "tool.tbl").write_text("T1 P1 Z+40.0 D6.0 ;end mill\n")
    (tmp_path / "off.toml").write_text("[H]\n1 = 40.0\n")
    base = ["verify", str(nc), "-m", "vmc-moving-column", "--clearance", "0.5"]
    assert main(base + ["--stock", "box:-10,-10,-10,10,10,3"] + opt) == 2
    io = capsys.readouterr()
    assert "line 6 (G0 Z42.)" in io.err and "enters the stock at -1000 µm" in io.err
    assert main(base + ["--stock", "box:-10,-10,-10,10,10,1"] + opt) == 0
    assert "passed" in capsys.readouterr().out
    # without the length the gauge point is checked and (wrongly) passes
    assert main(base + ["--stock", "box:-10,-10,-10,10,10,3"]) == 0


def test_verify_command_tcp_rapids_option(tmp_path, capsys):
    # the G00 B-30 swing of the test above, through the command: tip-straight passes, the
    # axis-linear path (default "both", and "joint") is refused naming the block
    from mtcomp.cli import main
    nc = tmp_path / "t.nc"
    nc.write_text(tcp_program("G00 C0. B0. X-5. Y0. Z1.\nG00 B-30. X5. Z1.\n"))
    base = ["verify", str(nc), "-m", "robonano-a0ib", "--stock", "box:-10,-10,-3,10,10,0",
            "--tool-lengths", "1=40"]
    assert main(base + ["--tcp-rapids", "tip"]) == 0
    for mode in ([], ["--tcp-rapids", "joint"]):
        capsys.readouterr()
        assert main(base + mode) == 2
        assert "line 4 (G00 B-30. X5. Z1.)" in capsys.readouterr().err


TOOL_CHANGE = ("G21 G90\nG43 H1 Z50.\nG0 X1. Y1.\nG49\nG0 Z90.\nT2 M6\nG0 Z45.\nG43 H2 Z50.\n"
               "G0 Z60.\nM30\n")


def test_after_a_tool_change_before_its_g43_the_new_tools_tip_is_checked():
    # T2 M6 loads a 40 mm tool; until G43 H2 the axes stand where the words say and the tip is
    # 40 mm below: G0 Z45. puts it at Z5., 1 mm into a stock whose top is at Z6. (checked at
    # the gauge point, 45 mm up, it passed)
    m = load_machine("vmc-moving-column")
    stock = Box((-10.0, -10.0, -10.0), (10.0, 10.0, 6.0))
    p = parse(TOOL_CHANGE, axes=m.axis_names, tool_lengths={1: 20.0, 2: 40.0})
    assert p.tool_tip.tolist() == [20.0, 20.0, 20.0, 40.0, 40.0, 40.0]
    assert not p.tool_unknown.any()
    with pytest.raises(VerifyError, match=r"line 7 \(G0 Z45\.\): rapid move: the tool enters the "
                                          r"stock at -1000 µm") as e:
        verify_program(m, TOOL_CHANGE, stock=stock, tool_lengths={1: 20.0, 2: 40.0})
    assert not e.value.result.warnings
    # a lower stock: the tip keeps 1 mm
    ok = verify_program(m, TOOL_CHANGE, stock=Box((-10.0, -10.0, -10.0), (10.0, 10.0, 4.0)),
                        tool_lengths={1: 20.0, 2: 40.0})
    assert ok.ok and ok.min_clearance == pytest.approx(1.0, abs=ok.step / 2)
    # the length set by the program (G10 L1: LinuxCNC tool table entry) before the change
    g10 = TOOL_CHANGE.replace("T2 M6\n", "G10 L1 P2 Z40.\nT2 M6\n")
    p = parse(g10, axes=m.axis_names, tool_lengths={1: 20.0})
    assert p.tool_tip.tolist() == [20.0, 20.0, 20.0, 40.0, 40.0, 40.0]
    assert not p.tool_unknown.any()
    # a preselected T (no M6 yet) does not change the tool in the spindle
    pre = TOOL_CHANGE.replace("T2 M6\n", "T2\n").replace("G43 H2 Z50.\n", "M6\nG43 H2 Z50.\n")
    p = parse(pre, axes=m.axis_names, tool_lengths={1: 20.0, 2: 40.0})
    assert p.tool_tip.tolist() == [20.0, 20.0, 20.0, 20.0, 40.0, 40.0]


def test_after_a_tool_change_with_unknown_length_the_report_says_gauge_point(tmp_path, capsys):
    from mtcomp.cli import main
    m = load_machine("vmc-moving-column")
    stock = Box((-10.0, -10.0, -10.0), (10.0, 10.0, 6.0))
    res = verify_program(m, TOOL_CHANGE, stock=stock, tool_lengths={1: 20.0})
    assert res.ok and len(res.warnings) == 1
    assert res.warnings[0].startswith("line(s) 7 (after a tool change, before its G43) were "
                                      "checked at the gauge point only")
    assert "warning: line(s) 7 " in res.summary()
    # a tool the program never compensates (no G43 after its change: written for the machine
    # file's tool point, as mtcomp cad toolpath writes) is not flagged
    plain = "G21 G90\nT1 M6\nG0 X1. Y1. Z50.\nG0 Z7.\nM30\n"
    assert verify_program(m, plain, stock=stock).warnings == ()
    assert verify_program(m, plain + "G43 H1 Z9.\n", stock=stock).warnings[0].startswith(
        "line(s) 3-4 (after a tool change")
    nc = tmp_path / "tc.nc"
    nc.write_text(TOOL_CHANGE)
    tbl = tmp_path / "tool.tbl"
    tbl.write_text("T1 P1 Z+20.0\nT2 P2 Z+40.0\n")
    args = ["verify", str(nc), "-m", "vmc-moving-column", "--stock", "box:-10,-10,-10,10,10,6"]
    assert main(args + ["--tool-lengths", "1=20"]) == 0
    assert "warning: line(s) 7 (after a tool change" in capsys.readouterr().out
    assert main(args + ["--tool-table", str(tbl)]) == 2
    io = capsys.readouterr()
    assert "line 7 (G0 Z45.)" in io.err and "warning" not in io.out


def test_compensate_verification_says_gauge_point_after_a_tool_change():
    m = load_machine("vmc-moving-column")
    errors = ErrorSet(ToolSetting((0.001, 0.0, 0.0)))
    stock = Box((-10.0, -10.0, -10.0), (10.0, 10.0, 6.0))
    # within the Z travel (at most 50): the axes stand at 40 (G43 H1), 45 (T2, tip at 5), 47
    text = ("G21 G90\nG43 H1 Z20.\nG0 X1. Y1.\nG49\nG0 Z40.\nT2 M6\nG0 Z45.\nG43 H2 Z7.\n"
            "G0 X2.\nM30\n")
    _, rep = compensate_program(text, m, errors, tool_lengths={1: 20.0}, stock=stock)
    assert rep["verify"].ok and rep["verify"].warnings[0].startswith("line(s) 7 (after a tool")
    with pytest.raises(VerifyError, match=r"line 7 \(G0 Z45\.\)"):
        compensate_program(text, m, errors, tool_lengths={1: 20.0, 2: 40.0}, stock=stock)
