"""Fanuc G16/G15 polar coordinate command: read from the control's rules (X radius, Y angle in
deg counter-clockwise from +X, from the work origin in G90, each word modal in the G16
section) and compensated by writing the compensated point's radius and angle (issue 20)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from mtcomp import InputError, gcode

XYZ = ("X", "Y", "Z")
D = np.array([0.0123, -0.0071, 0.0042])
# the bolt-hole circle of the Fanuc manuals' polar coordinate example: radius modal
BOLT = ("G90 G17 G0 X0 Y0 Z10.\nG16\nG81 X100. Y30. Z-20. R-5. F200.\nY150.\nY270.\n"
        "G15 G80\nG0 X10.\n")


def control_points(text, offset=(0.0, 0.0)):
    """The X Y the control reaches at each polar block, from the words as written (written
    here from the rules, for the checks)."""
    out, r, a, on = [], None, None, False
    for ln in text.split("\n"):
        w = dict((m[0], float(m[1:])) for m in ln.split() if m[0] in "GXY" and m[0] != "G")
        gs = [float(m[1:]) for m in ln.split() if m[0] == "G"]
        if 16 in gs:
            on, r, a = True, None, None
        if 15 in gs:
            on = False
        if on and ("X" in w or "Y" in w):
            r, a = w.get("X", r), w.get("Y", a)
            out.append((np.nan, np.nan) if r is None or a is None else
                       (offset[0] + r * math.cos(math.radians(a)),
                        offset[1] + r * math.sin(math.radians(a))))
    return np.array(out)


def test_fanuc_bolt_hole_example_positions():
    p = gcode.parse(BOLT, axes=XYZ)
    assert p.known.all() and p.polar.tolist() == [False, True, True, True, False]
    want = [(0, 0), (100 * math.cos(math.pi / 6), 50), (-100 * math.cos(math.pi / 6), 50),
            (0, -100), (10, -100)]
    assert np.allclose(p.position[:, :2], want, atol=1e-12)
    assert np.allclose(p.position[1:4, 2], 10.0)          # G98: back to the initial level


def test_identity_byte_exact_and_a_translation_moves_every_hole():
    p = gcode.parse(BOLT, axes=XYZ)
    assert gcode.rewrite(p, lambda q: q.copy()) == BOLT
    out = gcode.rewrite(p, lambda q: q + D)
    got = control_points(out)
    assert np.abs(got - (p.position[p.polar][:, :2] + D[:2])).max() <= 1e-6   # one count
    lines = out.split("\n")
    # the modal radius changes with the translation: the blocks writing only the angle get one
    assert lines[3].startswith("X") and "Y" in lines[3]
    assert lines[6] == "G0 X10.012300"                    # after G15: Cartesian again
    assert gcode.rewrite(gcode.parse(out, axes=XYZ), lambda q: q.copy()) == out


def test_work_offset_is_the_polar_origin_and_inch_words():
    text = "G20 G90 G55 G0 X0 Y0 Z1.\nG16 G1 X2. Y90. F10.\nY180.\nG15\n"
    p = gcode.parse(text, axes=XYZ, work_offsets={"G55": {"X": 100.0, "Y": 50.0}})
    # positions in the frame of G55 (the only offset): the words are in inch
    assert np.allclose(p.position[1:, :2], [[0, 2 * 25.4], [-2 * 25.4, 0]], atol=1e-9)
    out = gcode.rewrite(p, lambda q: q + D)
    got = control_points(out) * 25.4
    assert np.abs(got - (p.position[1:, :2] + D[:2])).max() <= 2.54e-6


def test_a_section_whose_radius_is_not_yet_written_is_unknown_until_it_is():
    """At the start of a G16 section a word not written would be the control's own state
    (controls differ): the plane's axes are unknown there, the block passes unchanged."""
    text = "G90 G0 X10. Y0 Z5.\nG16\nG0 Y45.\nX20. Y45.\nY90.\nG15\n"
    p = gcode.parse(text, axes=XYZ)
    assert p.known.tolist() == [True, False, True, True]
    out = gcode.rewrite(p, lambda q: q + D).split("\n")
    assert out[2] == "G0 Y45."
    assert out[3].startswith("X20.") and "Z5.004200" in out[3]
    with pytest.raises(InputError, match=r":3: position of X Y not known"):
        gcode.rewrite(p, lambda q: q + D, unknown="refuse")


def test_angle_keeps_its_turn():
    text = "G90 G0 X0 Y0 Z1.\nG16\nG1 X10. Y359.99 F100.\nY-180.\nG15\n"
    p = gcode.parse(text, axes=XYZ)
    out = gcode.rewrite(p, lambda q: q + np.array([0.0, 0.01, 0.0])).split("\n")
    assert " Y0.0" not in out[2] and "Y360.047" in out[2]
    assert "Y-180.057" in out[3]


@pytest.mark.parametrize("text,line,what", [
    ("G0 X0 Y0 Z1.\nG16\nG91 G1 X1. Y10.\n", 3, "G91 under G16"),
    ("G0 X0 Y0 Z1.\nG18 G16\nG1 X1. Y10.\n", 3, "outside the G17 plane"),
    ("G0 X0 Y0 Z1.\nG16\nG1 X10. Y0\nG2 X10. Y90. R10.\n", 4, "arc under G16"),
    ("G0 X0 Y0 Z1.\nG16\nG1 X10. Y0\nG28 X0 Y0\n", 4, "X Y words of G10/G28"),
    ("G0 X0 Y0 Z1.\nG16 G92 X10.\n", 2, "X Y words of G10/G28"),
])
def test_what_is_not_read_under_g16_is_refused(text, line, what):
    with pytest.raises(InputError, match=rf"p.nc:{line}: .*{what}"):
        gcode.parse(text, axes=XYZ, filename="p.nc")


def test_a_rewrite_the_polar_words_cannot_carry_is_refused():
    """Angle words at 0.01 deg put the point up to 17 µm off at 200 mm: refused, naming the
    line, rather than written with an error beyond the resolution."""
    text = "G90 G0 X0 Y0 Z1.\nG16\nG1 X200. Y30. F100.\nG15\n"
    p = gcode.parse(text, axes=XYZ, filename="p.nc")
    with pytest.raises(InputError, match=r"p.nc:3: G16 polar block: the compensated point cannot"):
        gcode.rewrite(p, lambda q: q + D, resolution={"X": 1e-3, "Y": 1e-2, "Z": 1e-3})
    # at 0.0001 deg the same block is written within a count
    out = gcode.rewrite(p, lambda q: q + D, resolution={"X": 1e-3, "Y": 1e-4, "Z": 1e-3})
    assert np.abs(control_points(out) - (p.position[1, :2] + D[:2])).max() <= 1e-3


def test_a_cycle_under_g16_that_must_be_written_out_is_refused():
    """A correction that is not a rigid shift at the holes writes a cycle out as moves, which
    under G16 would be polar words too: refused."""
    p = gcode.parse(BOLT, axes=XYZ, filename="b.nc")

    def tilt(q):                       # a rotation about X: the correction varies with Z
        out = q.copy()
        out[:, 1] += 1e-3 * q[:, 2]
        return out
    with pytest.raises(InputError, match=r"b.nc:3: this canned cycle must be written out .* G16"):
        gcode.rewrite(p, tilt)


def test_generated_polar_programs_identity_and_translation():
    """Seeded programs mixing G16 sections (angle-only and radius-only blocks, cycles, Z moves)
    with Cartesian blocks: every one comes back byte for byte under the identity, and under a
    translation every polar block the rewrite compensates lands, as the control reads the
    written words, within one count of the programmed point plus the translation."""
    rng = np.random.default_rng(20)
    checked = 0
    for _ in range(40):
        lines, on = ["G21 G90 G0 X0 Y0 Z5."], False
        for _ in range(12):
            k = rng.integers(6)
            if k == 0:
                lines.append("G15" if on else "G16")
                on = not on
            elif k == 1:
                lines.append(f"G1 Z{rng.uniform(-3, 3):.3f} F100.")
            else:
                w = []
                if rng.random() < 0.7:
                    w.append(f"X{rng.uniform(1, 60):.3f}")
                if rng.random() < 0.7 or not w:
                    w.append(f"Y{rng.uniform(-400, 400):.3f}")
                lines.append(("G1 " if rng.random() < 0.5 else "") + " ".join(w))
        text = "\n".join(lines) + "\n"
        p = gcode.parse(text, axes=XYZ)
        assert gcode.rewrite(p, lambda q: q.copy()) == text
        if p.polar is None:                       # no G16 in this one
            continue
        info = {}
        out, _ = gcode.rewrite_with_lines(p, lambda q: q + D, info=info)
        got = control_points(out)
        rows = np.flatnonzero(p.polar)
        ok = info["compensated"][rows] & np.isfinite(p.polar_xy[rows, 0])
        assert len(got) == len(rows)
        if ok.any():
            err = got.reshape(-1, 2)[ok] - (p.position[rows[ok], :2] + D[:2])
            assert np.abs(err).max() <= 1e-6, text
            checked += int(ok.sum())
    assert checked > 50                       # the test reaches polar blocks


def test_polar_words_beyond_the_counts_are_refused_naming_the_line():
    # found by fuzzing: an angle word of 1e20 deg overflowed the count conversion (OverflowError)
    text = "G90 G17 G0 X0 Y0 Z5.\nG16\nG0 X40. Y99999999999999999999\nG15\n"
    p = gcode.parse(text, axes=XYZ)
    with pytest.raises(InputError, match=r":3: polar words \(G16\) too large for the resolution"):
        gcode.rewrite(p, lambda q: q.copy())


def test_radius_zero_keeps_its_angle_words_under_zero_errors():
    # found by fuzzing: holes at radius 0 (the origin) with angles 60..300 came back as Y0 and
    # Y360 (the angle of the origin taken as 0): not byte-identical under zero errors
    text = ("G90 G17 G0 X0 Y0 Z50.\nG16\nG98 G81 X0 Y0. Z-3. R2. F150\nY60.\nY120.\nY180.\n"
            "Y240.\nY300.\nG15 G80\n")
    p = gcode.parse(text, axes=XYZ)
    assert gcode.rewrite(p, lambda q: q.copy()) == text
    out = gcode.rewrite(p, lambda q: q + D)                  # moved off the origin: written
    assert out != text and np.abs(control_points(out) - D[:2]).max() <= 1e-6
