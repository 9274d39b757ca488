"""Shop program idioms a control runs and mtcomp compensate now reads (issue 38, item 2): M99
at the end of a main program (repeat the program), G96 constant surface speed on lathes, and
control settings codes that change only look-ahead / feed control (Fanuc G05 P10000/P0,
G05.1 Q1 R<n>).  Each is byte-exact under zero errors and compensated under a translation;
the forms whose motion the control computes stay refused by name."""
from __future__ import annotations

import numpy as np
import pytest

from mtcomp import InputError, gcode
from mtcomp.commands import compensate_program
from mtcomp.errors import ErrorSet, GeometricErrors, ToolSetting
from mtcomp.gcode import flow
from mtcomp.machine import load_machine

AXES = ("X", "Y", "Z")
SHIFT = (0.002, -0.001, 0.0005)                 # tool setting error, mm


@pytest.fixture(scope="module")
def vmc():
    return load_machine("vmc-moving-column")


def _positions(text):
    """End points of the blocks of a program (its subprograms and a final M99 followed: the
    first run of the main program only)."""
    fl = flow.expand(text, "p")
    if fl is None:
        return gcode.parse(text, axes=AXES).position
    p = gcode.parse(fl.expanded, axes=AXES)
    if fl.loop_len:
        return p.position[p.line <= fl.loop_len]
    return p.position


def _check(text, machine, shift=SHIFT):
    """Byte-exact under zero errors; under a tool setting translation every known end point
    moves by minus the translation (the tool then cuts the programmed point)."""
    out, _ = compensate_program(text, machine, ErrorSet(), provenance=None)
    assert out == text
    out, rep = compensate_program(text, machine, ErrorSet(ToolSetting(shift)), provenance=None)
    a, b = _positions(text), _positions(out)
    assert a.shape == b.shape and len(a)
    known = ~np.isnan(a).any(axis=1)
    assert known.any()
    np.testing.assert_allclose(b[known] - a[known], -np.broadcast_to(shift, a[known].shape),
                               atol=1e-9)
    assert rep["after_max"] < 1e-6
    return out, rep


# -- M99 at the end of a main program
LOOP = "%\nO0001 (BAR FEED)\nG90 G54 G0 X0. Y0. Z5.\nG1 Z-1. F100.\nX10. Y5.\nG0 Z5.\nM99\n%\n"
LOOP_SUB = ("O0001\nG90 G0 X0. Y0. Z5.\nM98 P100\nG0 X20.\nM98 P100\nM99\n"
            "O100\nG91 G1 X5. F100.\nG90 G0 Z5.\nM99\n")
LOOP_NEXT = "G90 G0 X0. Y0. Z5.\nG1 Z-1. F100.\nM99\nO100\nG0 X2.\nM99\n"     # programs after it


@pytest.mark.parametrize("text", [LOOP, LOOP_SUB, LOOP.replace("\n", "\r\n"), LOOP[:-3],
                                  LOOP_NEXT])
def test_m99_ending_the_main_program_is_kept_and_each_run_compensated(text, vmc):
    out, rep = _check(text, vmc)
    assert rep["flow"] == "once" and any("repeats the main program" in n for n in rep["notes"])
    assert out.count("M99") == text.count("M99")
    assert "G90 G54 G0 X-0.0020 Y0.0010 Z4.9995" in out or "G90 G0 X-0.0020 Y0.0010 Z4.9995" in out


def test_m99_loop_whose_repetition_differs_is_refused(vmc):
    # the second run starts where the first ends (incremental move): with a squareness error
    # its absolute Y block needs another correction there
    t = "G91 G1 X10. Y10. F100.\nG90 G1 Y0.\nM99\n"
    e = ErrorSet(geometric=GeometricErrors(location={"EC0Y": 1e-4}))
    with pytest.raises(InputError, match=r"<string>:3: M99 at the end of the main program repeats"):
        compensate_program(t, vmc, e, provenance=None, start={"X": 0.0, "Y": 0.0, "Z": 0.0})
    # absolute start: every run is the same
    t = "G90 G0 X0. Y0. Z5.\nG91 G1 X10. Y10. F100.\nM99\n"
    out, _ = compensate_program(t, vmc, e, provenance=None)
    assert out.endswith("M99\n") and "X10.0010" in out


@pytest.mark.parametrize("text, line, what", [
    ("G90 G0 X1. Y1. Z1.\nM99\nG0 X2.\nM30\n", 2, "M99 before the end of the main program"),
    ("G90 G0 X1. Y1. Z1.\nM99 P10\n", 2, "M99 P in the main program"),
    ("G0 X1.\nM98 P100\nM30\nO100\nM99 P10\n", 5, "M99 P"),
])
def test_m99_jumps_stay_refused(text, line, what, vmc):
    with pytest.raises(InputError, match=rf"<string>:{line}: {what}"):
        compensate_program(text, vmc, ErrorSet(), provenance=None)


# -- G96 constant surface speed
LATHE = ("O2001 (FACE AND TURN)\nG18 G21 G40 G99\nG50 S3000\nG96 S180 M3\nG0 X42. Z2.\n"
         "G1 Z-20. F0.15\nX50.\nG0 Z2.\nG97 S800\nM30\n")


def test_g96_constant_surface_speed_is_passed_and_the_axes_compensated(vmc):
    # (a lathe program in the X-Z plane on a 3-axis frame: no Y error to correct)
    out, _ = _check(LATHE, vmc, (0.002, 0.0, 0.0005))
    assert "G0 X41.9980 Z1.9995\n" in out
    assert "G96 S180 M3\n" in out and "G50 S3000\n" in out


# -- control settings codes: look-ahead and feed control, the path as programmed
SETTINGS = ("G90 G0 X0. Y0. Z5.\nG05 P10000\nG05.1 Q1 R1\nG08 P1\nG187 P1 E0.01\n"
            "G1 Z-1. F500.\nX20. Y10.\nG187\nG08 P0\nG05.1 Q0\nG5 P0\nG0 Z5.\nM30\n")


def test_look_ahead_settings_codes_are_passed_unchanged(vmc):
    out, _ = _check(SETTINGS, vmc)
    for code in ("G05 P10000\n", "G05.1 Q1 R1\n", "G5 P0\n", "G187 P1 E0.01\n", "G08 P1\n"):
        assert code in out


def test_g5_1_q1_r_is_not_an_arc_radius_in_g2_mode():
    p = gcode.parse("G90 G0 X0. Y0. Z0.\nG2 X10. Y0. R5. F100.\nG05.1 Q1 R3\nX0. Y0. R5.\n",
                    axes=AXES)
    assert p.position[-1].tolist() == [0.0, 0.0, 0.0] and len(p) == 3


@pytest.mark.parametrize("text, what", [
    ("G05 P1\n", "G5 other than a block of its own G05 P10000"),          # high-speed cycle
    ("G5 X1. Y1. I1. J0. P1. Q1.\n", "G5 other than"),                   # LinuxCNC spline
    ("G05 R1.\n", "G5 other than"),                                      # Haas fine spindle
    ("G05 P10000 X1.\n", "G5 other than"),
    ("G5.1 Q2 X0 Y0 Z0\n", "G5.1 without Q1/Q0"),                         # smooth interpolation
])
def test_settings_forms_that_move_stay_refused(text, what):
    with pytest.raises(InputError, match=rf"<string>:2: {what}"):
        gcode.parse("G90 G0 X0. Y0. Z1.\n" + text, axes=AXES)
