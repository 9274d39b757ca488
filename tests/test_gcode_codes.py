"""Codes shop programs use (issue 20): tool length and work offsets, machine-coordinate moves
passed through, arc centre modes, feed modes, headers CAM post-processors write."""
from __future__ import annotations

import numpy as np
import pytest

from mtcomp import InputError, gcode

XYZ = ("X", "Y", "Z")


def shift(d):
    d = np.asarray(d, float)
    return lambda q: q + d


def test_cam_header_codes_are_read():
    text = ("%\nO1001 (FACE)\nG90 G94 G91.1 G40 G49 G17\nG21\nG28 G91 Z0.\nG90\n"
            "T1 M6\nS12000 M3\nG54\nG0 X10. Y5.\nG43 Z15. H1\nG0 Z5.\nG98 G1 Z-1. F300.\n"
            "G64 G61.1 G99\nG1 X20.\nG28 G91 Z0.\nG90\nM30\n%\n")
    p = gcode.parse(text, axes=XYZ)
    assert gcode.rewrite(p, lambda q: q.copy()) == text
    assert any("H1" in n for n in p.notes) and any("G28" in n for n in p.notes)
    assert list(p.known) == [False, True, True, True, True]


def test_tool_length_offset_from_a_table():
    text = "G90 G0 X0 Y0 Z100.\nG43 H2 Z10.\nG1 Z-1. F100\nG49 Z150.\n"
    p = gcode.parse(text, axes=XYZ, tool_lengths={2: 50.0})
    # positions in the reference frame: G43 adds the tool length along Z
    assert np.allclose(p.position[:, 2], [100, 60, 49, 150])
    seen = []
    out = gcode.rewrite(p, lambda q: (seen.append(q.copy()), q + [0, 0, 0.001])[1])
    assert np.allclose(seen[0][:, 2], [100, 60, 49, 150])
    assert out == "G90 G0 X0 Y0 Z100.001000\nG43 H2 Z10.001000\nG1 Z-0.999000 F100\nG49 Z150.001000\n"


def test_work_offsets_switch_with_their_values():
    text = "G54 G90 G0 X0 Y0 Z5.\nG55 X0\nG54.1 P3 X1.\n"
    with pytest.raises(InputError, match=r":2: the program switches from G54 to G55: give the work offsets"):
        gcode.parse(text, axes=XYZ)
    wo = {"G54": (0, 0, 0), "G55": {"X": 100.0}, "G54.1 P3": (200.0, 0, 0)}
    p = gcode.parse(text, axes=XYZ, work_offsets=wo)
    assert np.allclose(p.position[:, 0], [0, 100, 201])
    assert gcode.rewrite(p, lambda q: q.copy()) == text
    out = gcode.rewrite(p, lambda q: q + [0.002, 0, 0])
    assert out.splitlines() == ["G54 G90 G0 X0.002000 Y0 Z5.", "G55 X0.002000", "G54.1 P3 X1.002000"]


def test_local_shift_g52():
    text = "G90 G0 X1. Y1. Z1.\nG52 X10.\nG0 X1.\nG52 X0\nX1.\n"
    p = gcode.parse(text, axes=XYZ)
    assert np.allclose(p.position[:, 0], [1, 11, 1])
    assert gcode.rewrite(p, lambda q: q.copy()) == text
    assert "G52 X10.\n" in gcode.rewrite(p, shift([0.5, 0, 0]))          # the shift stays


@pytest.mark.parametrize("code", ["G53 G0 Z0", "G28 G91 Z0.", "G30 Z0."])
def test_machine_coordinate_moves_pass_and_make_the_axis_unknown(code):
    text = f"G90 G0 X1. Y1. Z1.\n{code}\nG90 G0 X2.\nZ3.\nX4.\n"
    p = gcode.parse(text, axes=XYZ)
    assert list(p.known) == [True, False, True, True]
    out = gcode.rewrite(p, shift([0.1, 0.1, 0.1]))
    lines = out.splitlines()
    assert lines[1] == code and lines[2] == "G90 G0 X2."             # passed, then deferred
    assert lines[3] == "X2.100000 Y1.100000 Z3.100000" and lines[4] == "X4.100000"
    assert any(code.split()[0] in n for n in p.notes)


def test_absolute_arc_centres_g90_1():
    text = "G90 G90.1 G0 X10. Y0 Z0\nG3 X0 Y10. I0 J0\nG91.1 G3 X-10. Y0 I0 J-10.\n"
    p = gcode.parse(text, axes=XYZ)
    assert np.allclose(p.arc_centre[1, :2], [0, 0]) and np.allclose(p.arc_centre[2, :2], [0, 0])
    assert gcode.rewrite(p, lambda q: q.copy()) == text
    out = gcode.rewrite(p, shift([1.0, 2.0, 0]))
    assert out.splitlines()[1] == "G3 X1.000000 Y12.000000 I1.000000 J2.000000"
    assert out.splitlines()[2] == "G91.1 G3 X-9.000000 Y2.000000 I0 J-10."


def test_mirror_cancel_axis_words_are_not_moves():
    p = gcode.parse("G90 G0 X1. Y2. Z3.\nG50.1 X0 Y0\nG1 Z0\n", axes=XYZ)
    assert len(p) == 2 and np.allclose(p.position[1], [1, 2, 0])


def test_inverse_time_accepted_but_not_linearised():
    text = "G90 G0 X10. Y0 Z0\nG93 G1 X0 Y0 F2.\nG2 X10. Y0 I5. J0 F4.\n"
    p = gcode.parse(text, axes=XYZ)
    assert p.inverse_time.tolist() == [False, True, True]
    assert gcode.rewrite(p, shift([0.1, 0, 0])).splitlines()[1] == "G93 G1 X0.100000 Y0 F2."

    def tilt(q):
        q = q.copy()
        q[:, 2] += 0.01 * q[:, 0]
        return q
    with pytest.raises(InputError, match=r":3: .*G93 inverse time"):
        gcode.rewrite(p, tilt)


def test_g92_sets_the_current_position_and_g92_1_cancels():
    text = "G90 G0 X10. Y0 Z5.\nG92 X0 Y0\nG1 X5. F100\nG92.1\nG1 X5.\n"
    p = gcode.parse(text, axes=XYZ)
    assert np.allclose(p.position[:, 0], [10, 15, 5])
    assert gcode.rewrite(p, lambda q: q.copy()) == text
    out = gcode.rewrite(p, shift([0.001, 0, 0]))
    # the tool stands at the compensated X10.001 when G92 runs: the G92 word carries the same
    # correction, so the shift the control sets is the program's (10) and X5 lands at 15.001
    assert out.splitlines() == ["G90 G0 X10.001000 Y0 Z5.", "G92 X0.001000 Y0", "G1 X5.001000 F100",
                                "G92.1", "G1 X5.001000"]
    # where the position is not known, G92 leaves the axis unknown until cancelled
    p = gcode.parse("G92 X0\nG0 X1. Y1. Z1.\nG92.1\nG0 X2.\n", axes=XYZ)
    assert p.known.tolist() == [False, True]


def test_fanuc_ai_contour_control_g05_1_q1_is_read_as_harmless():
    """G05.1 Q1 (AI contour control, written by Fanuc posts when smoothing is on) controls the
    feed by look-ahead; the path stays as programmed: read, and the program compensated as
    without it (it was an unknown G code). Q2/Q3 change the path: refused."""
    text = "G21 G90 G0 X0 Y0 Z5.\nG05.1 Q1\nG1 Z-1. F100.\nX5.\nG05.1 Q0\nG0 Z5.\n"
    p = gcode.parse(text, axes=("X", "Y", "Z"))
    q = gcode.parse(text.replace("G05.1 Q1\n", "\n").replace("G05.1 Q0\n", "\n"), axes=("X", "Y", "Z"))
    assert np.array_equal(p.position, q.position) and len(p) == 4
    out = gcode.rewrite(p, lambda x: x + 0.01)
    assert out.split("\n")[1] == "G05.1 Q1" and out.split("\n")[3] == "X5.010000"


def test_okuma_g15_h_work_coordinate_switching_is_refused():
    """Okuma's G15 H<n> selects work coordinate system n; a program switching between two was
    read as if G15 were only "polar cancel" (positions in two frames taken as one)."""
    one = "G15 H1\nG90 G0 X1. Y2. Z3.\nG1 X5. F100.\n"
    assert len(gcode.parse(one, axes=("X", "Y", "Z"))) == 2
    with pytest.raises(InputError, match=r"o.min:4: G15 H<n> .Okuma work coordinate"):
        gcode.parse(one + "G15 H2\nG0 X1.\n", axes=("X", "Y", "Z"), filename="o.min")
