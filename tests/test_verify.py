"""Verification of NC programs (mtcomp.verify): rapids against the stock with a clearance,
feeds against the part, every block interpolated in axis space through the forward model."""
import math

import numpy as np
import pytest

from mtcomp.cli import main
from mtcomp.kinematics import forward
from mtcomp.machine import load_machine
from mtcomp.verify import (Box, CylinderZ, HalfSpace, Intersection, SphereCavity, VerifyError,
                           parse_stock, verify_commands, verify_program)

PLATE = Box((-10.0, -10.0, -3.0), (10.0, 10.0, 0.0))   # the groove plate's blank

# The rapid of issue 14: from B+30 with the tool about 1 mm over the plate to B-30.
REPRODUCER = """%
O1000 (SEEDED GOUGING RAPID)
N10 G21 G90 G94 G17
N20 G00 C0.00000 B30.00000 X0.025000 Y-4.000000 Z0.956699
N30 G00 B-30.00000 X3.439102 Y-8.000000 Z-1.043301
N40 G01 Z-2.043301 F50
N50 M30
%
"""


def test_box_distance_is_exact_inside_and_outside():
    b = Box((0, 0, 0), (2, 4, 6))
    pts = np.array([[1, 2, 3], [3, 2, 3], [3, 5, 3], [3, 5, 7], [1, 2, 0.5], [-1, 2, 3]])
    want = [-1.0, 1.0, math.sqrt(2), math.sqrt(3), -0.5, 1.0]
    assert np.allclose(b.distance(pts), want, rtol=0, atol=1e-15)
    dish = Intersection((CylinderZ(5, -3, 1), SphereCavity((0, 0, 20), 20)))
    # on the axis 0.1 mm over the dish bottom: 0.1 mm of air; 0.1 mm below: in the material
    assert dish.distance(np.array([[0, 0, 0.1], [0, 0, -0.1]])) == pytest.approx([0.1, -0.1])
    assert HalfSpace(0.5).distance(np.array([[9, 9, 0.7]]))[0] == pytest.approx(0.2)
    assert parse_stock("box:-10,-10,-3,10,10,0") == PLATE
    with pytest.raises(ValueError, match="box:x0"):
        parse_stock("box:1,2,3")


def test_seeded_gouging_rapid_is_caught_and_named():
    m = load_machine("robonano-a0ib")
    with pytest.raises(VerifyError, match=r"line 5 \(N30 G00 B-30.00000") as exc:
        verify_program(m, REPRODUCER, stock=PLATE, clearance=0.2)
    res = exc.value.result
    assert [v.line for v in res.violations] == [5] and res.violations[0].kind == "rapid"
    # Independent model of this block: the B table turns the plate about the machine Y axis
    # through the origin (C = 0), the linear axes move the tool; the tool tip in the plate's
    # frame is the machine position turned back by B.  Axes interpolated linearly, sampled
    # 200,000 times: the deepest point is 45.7 µm below the top face (issue 14).
    t = np.linspace(0, 1, 200001)
    a, b = np.array([30.0, 0.025, -4.0, 0.956699]), np.array([-30.0, 3.439102, -8.0, -1.043301])
    s = a + t[:, None] * (b - a)
    B = np.radians(s[:, 0])
    z_plate = -np.sin(B) * s[:, 1] + np.cos(B) * s[:, 3]
    q_end = np.array([[0.0, *a], [0.0, *b]])
    zf = forward(m, q_end).p[:, 2]
    assert zf == pytest.approx([-math.sin(B[0]) * a[1] + math.cos(B[0]) * a[3],
                                -math.sin(B[-1]) * b[1] + math.cos(B[-1]) * b[3]], abs=1e-12)
    assert z_plate.min() == pytest.approx(-0.0457, abs=2e-4)
    assert res.min_clearance == pytest.approx(z_plate.min(), abs=res.step / 2)
    # As a warning: the same report, no exception.
    warn = verify_program(m, REPRODUCER, stock=PLATE, clearance=0.2, raise_on_violation=False)
    assert not warn.ok and "line 5" in warn.summary()


def test_sampling_bounds_the_clearance_of_a_rotary_rapid():
    m = load_machine("robonano-a0ib")
    q = np.array([[0, 40, -12, 0, 6.0], [170, -60, 8, 3, 4.0]])
    for step in (0.05, 0.005):
        r = verify_commands(m, q, [0, 0], stock=PLATE, clearance=0.0, step=step,
                            raise_on_violation=False)
        t = np.linspace(0, 1, 400001)
        dense = PLATE.distance(forward(m, q[0] + t[:, None] * (q[1] - q[0])).p).min()
        assert dense <= r.min_clearance + 1e-12 <= dense + step / 2 + 1e-9


def test_arc_blocks_follow_the_circle_not_the_chord():
    m = load_machine("vmc-moving-column")
    # A half circle of radius 10 in XY about (0, 0); the chord from (10,0) to (-10,0) stays at
    # y = 0, the arc bulges to y = +10 (G03, counter-clockwise) through a pillar at y in [9, 11].
    text = "G21 G90 G17\nG00 X10. Y0. Z5.\nG03 X-10. Y0. I-10. J0.\nM30\n"
    pillar = Box((-1.0, 9.0, 0.0), (1.0, 11.0, 10.0))
    res = verify_program(m, text, part=pillar, tolerance=0.0, raise_on_violation=False)
    assert [v.line for v in res.violations] == [3]
    assert res.min_part == pytest.approx(-1.0, abs=0.003)    # at (0, 10): 1 mm from every side face
    lin = verify_program(m, text.replace("G03 X-10. Y0. I-10. J0.", "G01 X-10. Y0."), part=pillar,
                         tolerance=0.0, raise_on_violation=False)
    assert lin.ok and lin.min_part == pytest.approx(9.0)


def test_ball_feed_against_a_cadquery_part():
    cq = pytest.importorskip("cadquery")
    from mtcomp.verify import ShapeStock
    m = load_machine("vmc-moving-column")
    part = ShapeStock(cq.Workplane("XY").box(10, 10, 2).translate((0, 0, -1)), "block")
    # A ball R1 riding on the top face (tip at z = 0) touches it; 3 µm lower it gouges.
    ok = "G21 G90\nG00 X-3. Y0. Z2.\nG01 Z0. F100\nX3.\nM30\n"
    res = verify_program(m, ok, part=part, tool_radius=1.0, step=0.05)
    assert res.ok and res.min_part == pytest.approx(0.0, abs=1e-7)
    bad = ok.replace("X3.", "X3. Z-0.003")
    with pytest.raises(VerifyError, match="line 4 .*gouges the part by 3.00 µm"):
        verify_program(m, bad, part=part, tool_radius=1.0, step=0.05)


def test_verify_command_exits_nonzero_naming_the_block(tmp_path, capsys):
    nc = tmp_path / "seed.nc"
    nc.write_text(REPRODUCER)
    args = ["verify", str(nc), "-m", "robonano-a0ib", "--stock", "box:-10,-10,-3,10,10,0"]
    assert main(args) == 2
    io = capsys.readouterr()
    assert "line 5" in io.err and "Traceback" not in io.err and "FAIL" in io.out
    assert main(args + ["--warn-only"]) == 0
    assert main(["verify", str(nc), "-m", "robonano-a0ib", "--stock", "box:1,2"]) == 2
    assert "box:x0" in capsys.readouterr().err


def test_cad_toolpath_groove_plate_is_safe_and_faces_the_feed(tmp_path, capsys):
    """Issue 14's reproducer: the emitted program passes the verification with the stated
    clearance, turns the rotary axes only in links of their own, and turns C so the rake face
    of the non-rotational tool faces the feed."""
    from mtcomp import gcode
    from mtcomp.cad_plugin import toolpath as T
    nc = tmp_path / "gp.nc"
    assert main(["cad", "toolpath", "groove-plate", "-o", str(nc), "--clearance", "0.3"]) == 0
    out = capsys.readouterr().out
    assert "passed" in out and "off by 0.000000 deg" not in out and "WARNING" not in out
    assert main(["cad", "toolpath", "groove-plate", "--tcp", "-o", str(tmp_path / "t.nc")]) == 0
    assert "passed" in capsys.readouterr().out
    m = load_machine("robonano-a0ib")
    res = verify_program(m, nc.read_text(), stock=PLATE, clearance=0.3)
    assert res.ok and res.min_clearance >= 0.3
    prog = gcode.parse(nc.read_text(), axes=m.axis_names)
    fast = np.nonzero(prog.motion == 0)[0][1:]
    d = np.abs(prog.position[fast] - prog.position[fast - 1]) > 1e-9
    assert not np.any(d[:, :2].any(axis=1) & d[:, 2:].any(axis=1))   # C/B alone, never with XYZ
    tp = T.groove_plate_passes()
    q = T.to_axes(m, tp)
    assert np.nanmax(np.abs(T.rake_error(m, tp, q))) < 1e-6
    # C follows the pass directions: A pattern (+x, +y), C triangle (three sides), B grooves (+y)
    starts = np.nonzero(tp.motion == T.RAPID)[0]
    assert np.ptp(q[starts, m.index("C")]) >= 120.0


def test_tcp_program_moves_the_tool_point_straight():
    """G43.4: X Y Z are the tool point in the workpiece frame and the control keeps it on the
    straight line while B turns; the same words as machine axes swing the tool instead."""
    from mtcomp.verify import tcp_to_axes
    m = load_machine("robonano-a0ib")
    body = "G00 C0. B0. X-5. Y0. Z1.\nG00 B30. X5. Z1.\n"
    tcp = verify_program(m, "G21 G90\nG43.4 H1\n" + body + "G49\nM30\n", stock=PLATE,
                         clearance=0.2)
    assert tcp.min_clearance == pytest.approx(1.0, abs=tcp.step / 2)
    axes = verify_program(m, "G21 G90\n" + body + "M30\n", stock=PLATE, clearance=0.2,
                          raise_on_violation=False)
    assert abs(axes.min_clearance - 1.0) > 0.5
    w = np.array([[0.0, 30.0, 5.0, 0.0, 1.0], [10.0, -20.0, -3.0, 2.0, 0.5]])
    q = tcp_to_axes(m, w)
    assert np.allclose(forward(m, q).p, w[:, 2:], atol=1e-12) and np.array_equal(q[:, :2], w[:, :2])
    # axis moves before G43.4 are verified as axis moves (formerly refused)
    mixed = verify_program(m, "G21 G90\nG00 X1. Y1. Z5.\nG43.4 H1\n" + body + "G49\nM30\n",
                           stock=PLATE)
    assert mixed.ok and mixed.min_clearance == pytest.approx(1.0, abs=mixed.step / 2)


def test_safe_links_without_stock_and_when_nothing_fits():
    from mtcomp._io import MtcompError
    from mtcomp.cad_plugin import toolpath as T
    m = load_machine("robonano-a0ib")
    tp = T.groove_plate_passes()
    q = T.to_axes(m, tp)
    # No stock known: every rotary link retracts to 1 mm below the top of Z's travel (60 mm).
    linked, ql = T.link_safely(m, tp, q, stock=None)
    z = m.index("Z")
    turns = np.nonzero(np.any(np.abs(np.diff(ql[:, :2], axis=0)) > 0, axis=1))[0] + 1
    # C: -90 -> 0 -> 150 -> -90 -> 30 -> 0 (A pattern, C triangle, B grooves), B: 0 -> 30 -> -30
    assert turns.size == 7 and np.all(ql[turns, z] == 59.0)
    assert len(linked) == len(ql) == len(tp) + 3 * turns.size
    # Material up to 100 mm over the table: no retract height within the travel keeps clear.
    tower = Box((-50, -50, -3), (50, 50, 100))
    with pytest.raises(MtcompError, match=r"pose \d+: no retract height within the travel of Z"):
        T.link_safely(m, tp, q, stock=tower)


def test_dogleg_rapids_follow_each_axis_at_its_own_rate():
    """With non-linear rapids every axis runs at its rate and stops on arrival: Z reaches its
    end first and X carries the tool on at that height."""
    m = load_machine("vmc-moving-column")
    text = "G21 G90\nG00 X0. Y0. Z5.\nG00 X10. Z1.\nM30\n"
    block = Box((4.5, -1.0, -10.0), (5.5, 1.0, 2.0))      # 2 mm high, at x 4.5 .. 5.5
    lin = verify_program(m, text, stock=block, clearance=0.5)
    # straight in X-Z, z = 5 - 0.4 x: nearest to the block's corner (5.5, 2), 0.8 mm above it,
    # at the line's normal distance 0.8 / sqrt(1 + 0.4^2)
    assert lin.min_clearance == pytest.approx(0.8 / math.sqrt(1.16), abs=lin.step / 2)
    rates = {"X": 10000.0, "Y": 10000.0, "Z": 10000.0}
    with pytest.raises(VerifyError, match="line 3"):
        verify_program(m, text, stock=block, clearance=0.5, rapid_rates=rates)
    res = verify_program(m, text, stock=block, clearance=0.5, rapid_rates=rates,
                         raise_on_violation=False)
    # z = 1 through the block: deepest at x = 5, 0.5 mm from its side faces
    assert res.min_clearance == pytest.approx(-0.5, abs=res.step / 2)
    # Z at a tenth of X's rate: Z arrives last, the path stays high until x = 10.
    slow_z = dict(rates, Z=1000.0)
    assert verify_program(m, text, stock=block, clearance=0.5, rapid_rates=slow_z).ok


# -- retracts: a rapid that starts at the end of a cut and moves straight away ---------------
RETRACT = "G90 G00 X1. Y2. Z5. B0 C0\nG01 Z-0.05 F100.\nG01 X3.\nG00 Z5.\n"


def test_retract_from_the_cut_passes_only_when_asked_and_is_left_out_of_the_min():
    m = load_machine("robonano-a0ib")
    with pytest.raises(VerifyError, match=r"line 4 \(G00 Z5.\): rapid move: the tool enters the stock"):
        verify_program(m, RETRACT, stock=PLATE, clearance=0.2)
    res = verify_program(m, RETRACT, stock=PLATE, clearance=0.2, retracts=True)
    assert res.ok and res.retracts == 1
    assert res.min_clearance == pytest.approx(5.0) and res.min_clearance_line == 1
    assert "1 rapid(s) start closer" in res.summary()


@pytest.mark.parametrize("tail, line", [
    ("G00 X5.\n", 4),                   # sideways through the blank at the cut's depth
    ("G00 Z0.1\nG00 X5.\n", 5),          # a retract to 0.1 mm, then sideways that close
    ("G00 Z5.\nG00 Z0.1\n", 5),         # a rapid down to 0.1 mm after the retract
    ("G00 X6. Z0.5\n", 4),              # away, but at 76 deg from the normal: slides along the surface
])
def test_what_is_not_a_retract_still_fails(tail, line):
    m = load_machine("robonano-a0ib")
    text = RETRACT.rsplit("G00", 1)[0] + tail
    with pytest.raises(VerifyError, match=f"line {line} "):
        verify_program(m, text, stock=PLATE, clearance=0.2, retracts=True)
