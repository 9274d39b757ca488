"""Issue 31 item 1: the machine frame.  Geometric errors are in machine coordinates: a program
under a work offset is compensated where its blocks are on the machine (word + offset), and the
setting errors stay in the program's frame."""
from __future__ import annotations

import numpy as np
import pytest

from mtcomp import InputError
from mtcomp.commands import compensate_program
from mtcomp.errors import (AxisErrorTable, ErrorSet, GeometricErrors, ToolSetting,
                           WorkpieceSetting, component_names)
from mtcomp.gcode import parse
from mtcomp.machine import load_machine

M = load_machine("vmc-moving-column")
RES = {a.name: a.resolution for a in M.axes}
BODY = ("G90 G17 G0 X0 Y0 Z5.\nG1 Z-1. F200\nG1 X20. Y10.\nG2 X40. Y10. I10. J0\n"
        "G1 X60. Y-15. Z-2.\nG0 Z5.\n")


def _x_table(squareness=True):
    """A wavy X table (EXX positioning, EYX straightness, ECX yaw) that is not linear: its
    value at X differs from its value at X + 50 by micrometres."""
    pos = np.linspace(-600, 600, 121)
    vals = {"EXX": 4e-3 * np.sin(pos / 37.0), "EYX": 2e-3 * np.cos(pos / 53.0),
            "ECX": 8e-6 * np.sin(pos / 71.0)}
    loc = {"EC0Y": 20e-6} if squareness else {}
    return GeometricErrors(tables={"X": AxisErrorTable("X", pos, vals)}, location=loc)


def _words(text):
    return np.array(parse(text, axes=M.axis_names, resolution=RES).position)


@pytest.mark.parametrize("wcs", ["G54", "G55", "G54.1 P3"])
def test_g54_x50_equals_the_program_at_x_plus_50(wcs):
    """Acceptance: G54 X=50 under an X table gives the positions of the same program written at
    X+50 with no offset, shifted back, to 0.01 µm (here: to the count, 0.1 µm resolution, after
    the rounding, and exactly before it)."""
    e = ErrorSet(ToolSetting((0.002, -0.001, 0.0005)), geometric=_x_table())
    with_offset = f"{wcs}\n" + BODY
    shifted = BODY.replace("X0 ", "X50. ").replace("X20.", "X70.").replace("X40.", "X90.") \
        .replace("X60.", "X110.")
    a, _ = compensate_program(with_offset, M, e, work_offsets={wcs: {"X": 50.0}})
    b, _ = compensate_program(shifted, M, e)
    pa, pb = _words(a), _words(b)
    pb[:, 0] -= 50.0
    assert np.abs(pa - pb).max() < 1e-5                       # 0.01 µm
    # and it is not the program's frame: without the offset the X table is read 50 mm off
    c, _ = compensate_program(BODY, M, e)
    assert np.abs(_words(c)[-2:] - pa[-2:]).max() > 1e-4


def test_setting_errors_stay_in_the_program_frame():
    """A rotated blank turns about the program origin, not the machine zero: with only setting
    errors the work offset changes nothing."""
    e = ErrorSet(workpiece=WorkpieceSetting((0.01, -0.02, 0.005), (0.02, -0.03, 0.15)))
    a, _ = compensate_program("G54\n" + BODY, M, e, work_offsets={"G54": {"X": 50.0, "Y": -30.0}})
    b, _ = compensate_program("G54\n" + BODY, M, e)
    assert a == b
    # with tables as well: the setting part is still about the program origin (the result
    # differs from the one without the offset only by what the tables give)
    g = ErrorSet(workpiece=e.workpiece, geometric=_x_table(squareness=False))
    a, rep = compensate_program("G54\n" + BODY, M, g, work_offsets={"G54": {"X": 50.0}})
    assert rep["after_max"] < 2e-4


def test_a_named_work_offset_not_given_is_refused_with_geometric_errors():
    e = ErrorSet(geometric=_x_table())
    with pytest.raises(InputError, match=r"p.nc:1: the geometric errors are in machine "
                                         r"coordinates, and the value of G55 \(X Y Z\)"):
        compensate_program("G55\n" + BODY, M, e, filename="p.nc")
    # setting errors only: not needed
    compensate_program("G55\n" + BODY, M, ErrorSet(ToolSetting((0.002, 0, 0))))
    # a program naming no work offset: the machine file's origin is the program's (as before)
    compensate_program(BODY, M, e)
    # G10 in the program gives it
    compensate_program("G10 L2 P2 X50. Y0 Z0\nG55\n" + BODY, M, e)


def test_arcs_stay_arcs_within_the_tolerance_and_lines_are_the_same_bytes():
    """Under tables and squareness an arc's corrected path is no exact circle: with
    --arc-keep-tol 0.5 µm more arcs stay arcs; at the default (the chordal tolerance, 0.2 µm)
    more are linearised, and their lines (compiled formatter, all arcs at once) read back onto
    the end points the rewrite emitted (compensate's own read-back check)."""
    e = ErrorSet(ToolSetting((0.002, -0.001, 0.0005)), geometric=_x_table())
    rng = np.random.default_rng(3)
    lines, x = ["G90 G17 G0 X-280. Y0 Z5.", "G1 Z-1. F300"], -280.0
    for i in range(30):
        r = float(rng.uniform(2, 8))
        lines.append(f"G{2 + i % 2} X{x + 2 * r:.4f} Y0 I{r:.4f} J0")
        x += 2 * r
        lines.append(f"G1 X{x + 1:.4f} Y0")
        x += 1
    text = "\n".join(lines) + "\n"
    _, wide = compensate_program(text, M, e, arc_keep_tol=5e-4)
    out, narrow = compensate_program(text, M, e)
    assert narrow["linearised"] > wide["linearised"]
    assert out.count("\n") > text.count("\n") + 10 * narrow["linearised"]
