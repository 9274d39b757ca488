"""Tolerant reading, exact writing (issues 15 and 20): what CAM systems and controls write is
read as the control reads it, and a transform that changes nothing changes no byte."""
from __future__ import annotations

import numpy as np
import pytest

from mtcomp import InputError, gcode

XYZ = ("X", "Y", "Z")


def shift(d):
    d = np.asarray(d, float)
    return lambda q: q + d


def identity(text, **kw):
    return gcode.rewrite(gcode.parse(text, axes=XYZ, **kw), lambda q: q.copy())


def test_byte_order_mark_is_read_and_kept():
    text = "\ufeff%\nG90 G0 X1. Y2. Z3.\n%\n"
    p = gcode.parse(text, axes=XYZ)
    assert np.allclose(p.position[0], [1, 2, 3])
    assert identity(text) == text
    assert gcode.rewrite(p, shift([1, 0, 0])).startswith("\ufeff%\nG90 G0 X2.000000 Y2. Z3.")


def test_blank_between_letter_and_number():
    text = "G90 G0 X 10. Y -2.5 Z5\n"
    p = gcode.parse(text, axes=XYZ)
    assert np.allclose(p.position[0], [10, -2.5, 5])
    assert identity(text) == text
    assert gcode.rewrite(p, shift([0.5, 0, 0])) == "G90 G0 X 10.500000 Y -2.5 Z5\n"
    with pytest.raises(InputError, match="address X without a number"):
        gcode.parse("G0 X\n10.\n", axes=XYZ)


@pytest.mark.parametrize("arc", [
    "G3 X0 Y10 I-10 J0.0001",        # mismatch 0.1 um: was rewritten to I-9.999950 J0.000050
    "G3 X5.403 Y8.415 I-10. J0",     # 3-decimal end point 0.2 um off the circle
    "G3 X9.637 Y0.362 I-0.363 J0",   # Fusion, 3 decimals: radius 0.363 at the start, 0.362 at the end
])
def test_programmed_radius_mismatch_is_kept_byte_for_byte(arc):
    text = f"G90 G1 X10. Y0 Z0 F100\n{arc}\n"
    assert identity(text) == text
    # a translation keeps the programmed arc words too
    out = gcode.rewrite(gcode.parse(text, axes=XYZ), shift([0.25, -0.125, 0]))
    assert "I" + arc.split(" I")[1].split(" J")[0] in out and "G1" not in out.splitlines()[1]


def test_radius_tolerance_is_configurable_and_refusal_names_the_line():
    text = "G90 G1 X10. Y0 Z0 F100\nG3 X0 Y10.05 I-10. J0\n"
    with pytest.raises(InputError, match=r":2: arc end point is not on the circle"):
        gcode.parse(text, axes=XYZ)
    assert len(gcode.parse(text, axes=XYZ, arc_tol=0.1)) == 2


def test_full_circle_with_end_below_the_resolution():
    for y in ("-0.0000004", "0.0000004"):
        text = f"G90 G1 X1. Y0 Z0 F100\nG2 X1. Y{y} I-1. J0\n"
        p = gcode.parse(text, axes=XYZ)
        assert p.arc_sweep[1] == pytest.approx(-2 * np.pi)       # the control cuts 360 deg
        assert identity(text) == text                           # not 300 lines
        out = gcode.rewrite(p, shift([0.001, 0, 0]))
        assert out.splitlines()[1].startswith("G2 X1.001000") and len(out.splitlines()) == 2


def test_radius_below_the_resolution_is_refused():
    with pytest.raises(InputError, match=r":2: arc radius .* below the axis resolution"):
        gcode.parse("G90 G1 X0 Y0 Z0\nG2 X0.0000001 Y0 I0.00000005 J0\n", axes=XYZ)


def test_numbers_too_large():
    with pytest.raises(InputError, match=":1: number .* too large"):
        gcode.parse("G0 X" + "9" * 400 + "\n", axes=XYZ)
    p = gcode.parse("G0 X1e13\n".replace("1e13", "1" + "0" * 13) + "G0 Y0 Z0\n", axes=XYZ)
    with pytest.raises(InputError, match=":1: axis word X.* too large"):
        gcode.rewrite(p, shift([0, 0, 0]))


def test_sub_resolution_increments_survive_the_identity():
    text = "G90 G1 X0 Y0 Z0 F100\nG91\n" + "X0.0000005 Y0.0000015\n" * 7 + "G90 X1.\n"
    assert identity(text) == text


def test_inserted_words_follow_case_and_spacing():
    out = gcode.rewrite(gcode.parse("g90 g0 x1. y2.\nz3.\n", axes=XYZ, start={"Z": 0}), shift([0, 0, 1]))
    assert out == "g90 g0 x1. y2. z1.000000\nz4.000000\n"
    out = gcode.rewrite(gcode.parse("G0X1.Y2.Z0\nG1X1.\nZ3.\n", axes=XYZ), shift([0, 1, 0]))
    assert out == "G0X1.Y3.000000Z0\nG1X1.\nZ3.\n"
    out = gcode.rewrite(gcode.parse("G0X1.Y2.\nZ3.\n", axes=XYZ), shift([0, 1, 0]))
    assert out == "G0X1.Y2.\nY3.000000Z3.\n"       # one-word block: the program's style


def test_resolution_not_a_power_of_ten_in_parse_and_rewrite():
    text = "G90 G1 X1. Y0 Z0 F100\nG2 X1. Y0.000002 I-1. J0\n"
    p = gcode.parse(text, axes=XYZ, resolution={"X": 5e-6, "Y": 5e-6})
    assert p.arc_sweep[1] == pytest.approx(-2 * np.pi)
    assert gcode.rewrite(p, lambda q: q.copy(), resolution={"X": 5e-6, "Y": 5e-6}) == text


def test_spiral_ending_at_the_start_angle_is_refused():
    # found by the fuzz test: a zero sweep read from an end point 0.01 mm outside the start
    with pytest.raises(InputError, match=r":2: arc end point at the start angle"):
        gcode.parse("G90 G1 X12. Y0 Z-1.\nG2 X12.01 Y0 Z-2. I-12. J0\n", axes=XYZ)
