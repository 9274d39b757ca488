"""Canned drilling cycles (issue 20): hole positions and R/Z levels compensated where the
correction is a rigid shift at the holes, written out as moves where it is not, refused where
the control's parameters would be needed; what was done is said in the program."""
from __future__ import annotations

import numpy as np
import pytest

from mtcomp import InputError, gcode

XYZ = ("X", "Y", "Z")
DRILL = ("G90 G0 X0 Y0 Z10.\nG99 G81 X5. Y5. Z-3. R2. F100\nX10.\nG98 Y10.\nG80\nG0 X0\n")


def tilt(q):
    """X correction proportional to Z: not a rigid shift over a hole's depth."""
    q = q.copy()
    q[:, 0] += 0.001 * q[:, 2]
    return q


def test_cycle_positions_and_return_levels():
    p = gcode.parse(DRILL, axes=XYZ)
    assert p.cycle.tolist() == [0, 81, 81, 81, 0]
    # G99 returns to R (2), G98 to the initial level (10)
    assert np.allclose(p.position, [[0, 0, 10], [5, 5, 2], [10, 5, 2], [10, 10, 10], [0, 10, 10]])
    assert np.allclose(p.cycle_data[1, :3], [10, 2, -3])
    assert gcode.rewrite(p, lambda q: q.copy()) == DRILL


def test_rigid_shift_moves_holes_and_levels():
    out = gcode.rewrite(gcode.parse(DRILL, axes=XYZ), lambda q: q + [0.001, 0.002, 0.003])
    assert out.splitlines()[1] == "G99 G81 X5.001000 Y5.002000 Z-2.997000 R2.003000 F100"
    assert out.splitlines()[2] == "X10.001000"                   # R and Z modal, same shift
    q = gcode.parse(out, axes=XYZ)
    assert np.allclose(q.position, gcode.parse(DRILL, axes=XYZ).position + [0.001, 0.002, 0.003])
    assert np.allclose(q.cycle_data[1:4, 1:3], [[2.003, -2.997]] * 3)


def test_rigid_shift_in_g91_keeps_relative_levels():
    text = "G90 G0 X0 Y0 Z10.\nG91 G99 G81 X5. Y5. Z-5. R-8. F100\nX5.\nG90 G80\n"
    p = gcode.parse(text, axes=XYZ)
    assert np.allclose(p.cycle_data[1, :3], [10, 2, -3])
    out = gcode.rewrite(p, lambda q: q + [0.001, 0, 0.003])
    assert out.splitlines()[1] == "G91 G99 G81 X5. Y5. Z-5. R-8. F100"       # all increments


def test_not_rigid_is_written_out_as_moves_and_said():
    p = gcode.parse(DRILL, axes=XYZ)
    out, lines = gcode.rewrite_with_lines(p, tilt)
    assert "(G81 WRITTEN OUT AS MOVES: THE CORRECTION IS NOT A RIGID SHIFT AT THE HOLES)" in out
    q = gcode.parse(out, axes=XYZ)
    assert not q.cycle.any()
    # every point the control passes: the hole at the arrival level, R, bottom, back
    want = tilt(np.array([[5, 5, 10], [5, 5, 2], [5, 5, -3], [5, 5, 2]], float))
    got = q.position[1:5]
    assert np.allclose(got, want, atol=1e-6)
    # the block after the run starts where the original program expects the tool (compensated)
    assert np.allclose(q.position[-1], tilt(np.array([[0, 10, 10.]]))[0], atol=1e-6)
    assert lines[-1] == len(out.splitlines())


@pytest.mark.parametrize("code", ["G84", "G74", "G86", "G76 Q0.1"])
def test_cycles_needing_control_parameters_are_refused_when_not_rigid(code):
    text = f"G90 G0 X0 Y0 Z10.\nG99 {code} X5. Y5. Z-3. R2. F100\nG80\n"
    p = gcode.parse(text, axes=XYZ)
    out = gcode.rewrite(p, lambda q: q + [0.001, 0, 0])
    assert "X5.001000" in out
    with pytest.raises(InputError, match=r":2: canned cycle G\d+: the correction is not the same"):
        gcode.rewrite(p, tilt)


def test_cycle_refusals():
    with pytest.raises(InputError, match=r":2: canned cycle G81 without an R level"):
        gcode.parse("G90 G0 X0 Y0 Z10.\nG81 X5. Z-3.\n", axes=XYZ)
    for words, what in (("K0", "repeat count K0 in a canned cycle .the cycle data stored"),
                        ("L0", "repeat count L0"), ("K2.5", "repeat count K2.5 in a canned cycle: a whole"),
                        ("K2 L2", "two repeat counts")):
        with pytest.raises(InputError, match=rf":2: {what}"):
            gcode.parse(f"G90 G0 X0 Y0 Z10.\nG81 X5. Z-3. R1. {words}\n", axes=XYZ)
    # L outside a cycle is still no repeat count (a Siemens call or a word not read)
    with pytest.raises(InputError, match=r":2: L3: a Siemens subprogram call"):
        gcode.parse("G90 G0 X0 Y0 Z10.\nG1 X5. L3\n", axes=XYZ)


# -- repeat counts: Fanuc K, LinuxCNC and Haas L (issue 20 follow-up)

ROW = "G90 G0 X0 Y0 Z10.\nG91 G99 G81 X5. Y1. Z-5. R-8. K3 F100\nX-2. L2\nG90 G80\nG0 Y20.\n"


@pytest.mark.parametrize("letter", ["K", "L"])
def test_repeats_in_g91_step_the_hole_each_time(letter):
    """G91 with K3 (Fanuc) or L3 (LinuxCNC, Haas): three holes 5 mm apart, the block ending at
    the last; the next block continues from there (before: refused)."""
    text = ROW.replace("K3", letter + "3").replace("L2", letter + "2")
    p = gcode.parse(text, axes=XYZ)
    assert p.cycle_repeat.tolist() == [1, 3, 2, 1]
    assert np.allclose(p.position, [[0, 0, 10], [15, 3, 2], [11, 3, 2], [11, 20, 2]])
    assert gcode.rewrite(p, lambda q: q.copy()) == text


def test_repeats_in_g90_drill_the_same_hole():
    text = "G90 G0 X0 Y0 Z10.\nG98 G81 X5. Y5. Z-3. R2. L3 F100\nX8. K2\nG80\n"
    p = gcode.parse(text, axes=XYZ)
    assert np.allclose(p.position[1:], [[5, 5, 10], [8, 5, 10]])
    out = gcode.rewrite(p, lambda q: q + [0.001, 0.002, 0.003])
    assert out.splitlines()[1:3] == ["G98 G81 X5.001000 Y5.002000 Z-2.997000 R2.003000 L3 F100",
                                     "X8.001000 K2"]
    with pytest.raises(InputError, match=r":2: canned cycle G81 with repeat count 3: the correction "
                                         "is not the same"):
        gcode.rewrite(p, tilt)


def test_repeats_in_g91_keep_their_step_under_a_rigid_shift_and_later_blocks_follow():
    """The step of a G91 repeat is unchanged by a shift common to the block before and every
    hole; a block after it that gets an inserted word gets the position after all repeats."""
    p = gcode.parse(ROW, axes=XYZ)
    info = {}
    out = gcode.rewrite(p, lambda q: q + [0.001, 0.002, 0.003], info=info)
    assert out.splitlines()[1:3] == ROW.splitlines()[1:3]            # increments as written
    assert info["cycles_kept"] == 5                                  # holes: 3 + 2
    q = gcode.parse(out, axes=XYZ)
    assert np.allclose(q.position, p.position + [0.001, 0.002, 0.003])

    def far(q):            # X corrected only beyond Y 10: the holes see no correction
        q = q.copy()
        q[:, 0] += 0.004 * (q[:, 1] > 10)
        return q
    out = gcode.rewrite(p, far)
    assert out.splitlines()[4] == "G0 X11.004000 Y20."              # after 3 + 2 repeats


def test_repeats_in_g91_whose_correction_changes_are_refused():
    p = gcode.parse(ROW, axes=XYZ)

    def scale(q):          # X grows with X: every hole has its own correction
        q = q.copy()
        q[:, 0] *= 1.0001
        return q
    with pytest.raises(InputError, match=r":2: canned cycle repeat count 3 in G91: the correction"):
        gcode.rewrite(p, scale)


def test_cycle_run_starting_before_the_pose_is_known_is_left_as_written():
    # found by the fuzz test: the G98 return level was set by a block that passed uncompensated
    text = "G90 G0 Z1. Y0.5\nG99 G81 Z-0.05 R0.1 F8.\nX1.5\nG98 X0.5\nG80\nG0 Z2.\n"
    p = gcode.parse(text, axes=XYZ)
    info = {}
    out = gcode.rewrite(p, lambda q: q + [0.01, 0.02, 0.03], info=info)
    assert out.splitlines()[:5] == text.splitlines()[:5]
    assert out.splitlines()[5] == "G0 X0.510000 Y0.520000 Z2.030000"
    assert info["deferred"] == 4 and not info["compensated"][:4].any()


def _pecks(code, r, bottom, q, c):
    """Programmed Z levels a control passes below R in one pecking hole (written from the
    cycle's description: G83 back to R after each peck and rapid down to c above the last
    depth; G73 retracts by c), with the mode (0 rapid, 1 feed)."""
    out, depth = [], r
    while depth > bottom + 1e-12:
        nxt = max(depth - q, bottom)
        if depth != r:
            out.append((0, depth + c))
        out.append((1, nxt))
        if code == 83 and nxt > bottom:
            out.append((0, r))
        depth = nxt
    return out


@pytest.mark.parametrize("code, q", [(83, 1.5), (73, 2.0), (83, 10.0), (73, 0.4)])
def test_pecking_cycles_not_rigid_are_written_out_peck_by_peck(code, q):
    from mtcomp.gcode.rewrite import PECK_CLEARANCE
    text = f"G90 G0 X0 Y0 Z10.\nG99 G{code} X5. Y5. Z-3. R2. Q{q} F100\nX10.\nG80\nG0 X0\n"
    p = gcode.parse(text, axes=XYZ)
    info = {}
    out = gcode.rewrite(p, tilt, info=info)
    assert info["cycles_expanded"] == 2 and f"(G{code} WRITTEN OUT AS MOVES" in out
    assert "Q" not in out.replace("Q" + str(q), "")              # no peck word left
    o = gcode.parse(out, axes=XYZ)
    assert not o.cycle.any()
    c = min(PECK_CLEARANCE, q / 2)
    want = []
    for x, arrive in ((5.0, 10.0), (10.0, 2.0)):
        want += [(0, x, arrive), (0, x, 2.0)]
        want += [(m, x, z) for m, z in _pecks(code, 2.0, -3.0, q, c)]
        want += [(0, x, 2.0)]                                     # G99: out to R
    got = o.position[1:1 + len(want)]
    pts = tilt(np.array([[x, 5.0, z] for _, x, z in want]))
    assert np.allclose(got, pts, atol=1e-6)
    assert o.motion[1:1 + len(want)].tolist() == [m for m, _, _ in want]
    # after the run the program goes on where it expects the tool
    assert np.allclose(o.position[-1], tilt(np.array([[0, 5, 2.0]]))[0], atol=1e-6)
    # a rigid shift keeps the cycle as written, Q untouched
    kept = gcode.rewrite(p, lambda v: v + [0.001, 0, 0.002])
    assert f"G99 G{code} X5.001000 Y5. Z-2.998000 R2.002000 Q{q} F100" in kept


@pytest.mark.parametrize("words, match", [("", "without a peck depth Q"),
                                          ("Q0.00001", "more than 10000")])
def test_pecking_cycles_that_cannot_be_written_out_are_refused(words, match):
    text = f"G90 G0 X0 Y0 Z10.\nG99 G83 X5. Y5. Z-3. R2. {words} F100\nG80\n"
    with pytest.raises(InputError, match=f":2: canned cycle G83.*{match}"):
        gcode.rewrite(gcode.parse(text, axes=XYZ), tilt)


@pytest.mark.parametrize("name", ["haas_drill.nc", "fanuc_peck.nc"])
def test_corpus_pecks_under_a_squareness_are_written_out_and_checked(name):
    # a squareness of Z to X: the X correction changes down the hole, so no cycle is rigid;
    # compensate checks the emitted positions through the forward model block by block
    from pathlib import Path

    from mtcomp.commands import compensate_program
    from mtcomp.errors import ErrorSet, GeometricErrors
    from mtcomp.machine import load_machine
    text = gcode.read_program(Path(__file__).parent / "data" / "nc" / name)
    m = load_machine("vmc-moving-column")
    e = ErrorSet(geometric=GeometricErrors(location={"EB0Z": 2e-4}))
    out, rep = compensate_program(text, m, e, start={"X": 0, "Y": 0, "Z": 50}, chordal_tol=1e-3)
    assert rep["cycles_expanded"] > 0 and rep["cycles_kept"] == 0
    assert rep["after_max"] < 1e-4 < rep["before_max"]
    assert not gcode.parse(out, axes=m.axis_names).cycle.any()


def test_haas_variable_peck_words_are_refused_by_name():
    with pytest.raises(InputError, match=r":2: I word in canned cycle G83 \(Haas variable peck"):
        gcode.parse("G90 G0 X0 Y0 Z10.\nG99 G83 X5. Z-9. R2. I2. J0.5 F100\nG80\n", axes=XYZ)


def test_linuxcnc_lathe_threading_g76_is_refused_by_name():
    """LinuxCNC's G76 is a lathe threading cycle (P pitch, I J K depths, H R Q E L), not Fanuc's
    fine boring: refused naming it (a public LinuxCNC sample; before, "unknown address 'e.05'")."""
    text = "G18 G20 G0 X.2 Z.2\ng76 p.05 z-.5 i-.075 j.008 k.045 h3 r2.0 q29.5 e.05 l2\n"
    with pytest.raises(InputError, match=r"t.ngc:2: e.05 in a G76 block: the LinuxCNC lathe threading"):
        gcode.parse(text, axes=("X", "Y", "Z"), filename="t.ngc")


@pytest.mark.parametrize("line,what", [
    ("G70 I2. J0. L6", "G70 with I J K L words: a Haas bolt hole pattern"),
    ("G71 I2. J0. K30. L6", "G71 with I J K L words: a Haas bolt hole pattern"),
    ("G72 I1. J45. L4", "G72: G72 .Haas: bolt holes along an angle"),
    ("G71 P10 Q20 F.2", "G71 with P Q U W R words: a Fanuc lathe stock removal cycle"),
    ("G70 P10 Q20", "G70 with P Q U W R words: a Fanuc lathe finishing cycle"),
])
def test_haas_bolt_hole_patterns_are_refused_by_name(line, what):
    """On Haas mills G70/G71/G72 are bolt hole patterns run with the active cycle, on Fanuc
    lathes G70/G71 are finishing and stock removal cycles, not inch/mm: refused naming them
    (before: "L6: a Siemens subprogram call", or G71 P Q read as mm)."""
    text = "G90 G0 X0 Y0 Z1.\nG81 Z-1. R.1 F10.\n" + line + "\nG80\n"
    with pytest.raises(InputError, match=rf"h.nc:3: {what}"):
        gcode.parse(text, axes=("X", "Y", "Z"), filename="h.nc")


@pytest.mark.parametrize("retract, dist, r, z_after", [("G99", "G90", "R2.", 2.0), ("G98", "G90", "R2.", 10.0),
                                                       ("G99", "G91", "R-4.", 6.0)])
def test_block_after_a_cycle_starts_at_its_return_level(retract, dist, r, z_after):
    """After a G99 cycle the tool stands at R: a later block whose Z word is inserted (the Z
    correction changes along X) gets R plus its correction, not the Z from before the cycle
    (before: G0 X20. Z10.001000, a rapid to the old level), and a G91 arc after it is written
    from there."""
    def f(q):
        q = q.copy()
        q[:, 2] += 0.001 * (q[:, 0] > 10)
        return q
    text = (f"G90 G0 X0 Y0 Z10.\n{dist} {retract} G81 X5. Y5. Z-3. {r} F100\nG80\nG0 X20.\n"
            "G91 G2 X2. Y0 I1. J0 F100\n")
    p = gcode.parse(text, axes=XYZ)
    assert p.position[2, 2] == pytest.approx(z_after)
    out = gcode.rewrite(p, f)
    q = gcode.parse(out, axes=XYZ)
    assert np.allclose(q.position[:3], f(p.position[:3]), atol=1e-9)
    assert np.allclose(q.position[-1], f(p.position[-1:])[0], atol=1e-9)
    assert np.allclose(q.position[2:, 2], z_after + 0.001)           # every block after it


def test_k0_stores_the_cycle_data_for_the_holes_after_it():
    """Fanuc K0 / Haas L0 without X Y: the R level and depth are stored, no hole and no move
    there; the next blocks drill with them (before: refused)."""
    text = "G90 G0 X0 Y0 Z10.\nG99 G81 Z-3. R2. F100 K0\nX5. Y5.\nX10.\nG80\nG0 X20.\n"
    p = gcode.parse(text, axes=XYZ)
    assert p.line.tolist() == [1, 3, 4, 6]                      # the K0 line is no block
    assert np.allclose(p.position, [[0, 0, 10], [5, 5, 2], [10, 5, 2], [20, 5, 2]])
    assert np.allclose(p.cycle_data[1, :3], [10, 2, -3])
    assert gcode.rewrite(p, lambda q: q.copy()) == text
    out = gcode.rewrite(p, lambda q: q + [0.001, 0.002, 0.003])
    # the K0 line stays; the first hole gets the shifted levels
    assert out.splitlines()[1:3] == ["G99 G81 Z-3. R2. F100 K0", "X5.001000 Y5.002000 R2.003000 Z-2.997000"]
    q = gcode.parse(out, axes=XYZ)
    assert np.allclose(q.cycle_data[1:3, 1:3], [[2.003, -2.997]] * 2)
    # written out as moves: no hole at the K0 line, two holes after it
    w = gcode.parse(gcode.rewrite(p, tilt), axes=XYZ)
    assert not w.cycle.any()
    bottoms = w.position[np.isclose(w.position[:, 2], -3.0), :2]
    assert np.allclose(bottoms, tilt(np.array([[5, 5, -3.], [10, 5, -3.]]))[:, :2], atol=1e-6)
    # a G80 between the K0 line and the holes cancels the stored data
    with pytest.raises(InputError, match=r":4: canned cycle G81 without an R level"):
        gcode.parse("G90 G0 X0 Y0 Z10.\nG81 Z-3. R2. K0\nG80\nG81 X5.\n", axes=XYZ)
    with pytest.raises(InputError, match=r":2: repeat count L0 .* with P: not read"):
        gcode.parse("G90 G0 X0 Y0 Z10.\nG82 Z-3. R2. P200 L0\nX5.\n", axes=XYZ)


def test_g91_levels_follow_the_hole_when_its_z_correction_differs_from_the_initial_level():
    """In G91 R is counted from the initial level (where Z stood before the run, with that
    block's correction) and the depth from R: a hole whose Z correction differs gets its own R
    word, so R and the bottom are the compensated ones (before: R and Z kept, the hole off by
    the difference of the corrections, 2 µm deep here).  G98 returns to the initial level the
    control holds, and the rewrite continues from there."""
    def f(q):
        q = q.copy()
        q[:, 0] += 0.001 * (q[:, 0] > 25)
        q[:, 2] += 0.002 * (q[:, 0] > 25)
        return q
    text = ("G90 G0 X20. Y0 Z20.\nG91 G99 G81 X2. Z-5. R-12. F100\nX6.\nG98 X2.\nG90 G80\n"
            "G91 G0 Z1.\nG90\n")
    p = gcode.parse(text, axes=XYZ)
    out = gcode.rewrite(p, f)
    q = gcode.parse(out, axes=XYZ)
    # R level and bottom of each hole: the programmed ones plus the correction at the hole
    want_r = f(np.c_[p.position[1:4, :2], p.cycle_data[1:4, 1]])
    want_b = f(np.c_[p.position[1:4, :2], p.cycle_data[1:4, 2]])
    assert np.allclose(q.cycle_data[1:4, 1], want_r[:, 2], atol=1e-9)
    assert np.allclose(q.cycle_data[1:4, 2], want_b[:, 2], atol=1e-9)
    assert out.splitlines()[2] == "X6.001000 R-11.998000"
    # the G98 hole ends at the initial level the control holds (20, the block before the run
    # had no correction); the G91 move after it starts there and ends compensated
    assert q.position[3, 2] == pytest.approx(20.0)
    assert q.position[-1, 2] == pytest.approx(f(p.position[-1:])[0, 2])
