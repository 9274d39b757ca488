"""Cutter radius compensation G41/G42 in `mtcomp compensate` (issue 20): programs with a G41 D
lead-in, a contour with arcs and a G40 lead-out are compensated at the programmed contour when
the correction is rigid enough over one tool radius, and refused naming the line otherwise."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mtcomp import InputError, gcode
from mtcomp.commands import compensate_program
from mtcomp.errors import ErrorSet, ToolSetting, WorkpieceSetting, save_errors
from mtcomp.gcode.cutter import offset_error_bound
from mtcomp.machine import load_machine

# Fanuc style: G41 D1 on the lead-in line, a pocket wall with two arcs, G40 on the lead-out
PROGRAM = """%
O1001 (CUTTER COMP)
G21 G90 G17 G40 G49 G80
T1 M6
G54 G0 X-20. Y-20. Z5. S3000 M3
G1 Z-2. F300
G41 D1 X0 Y-10.
Y30.
G2 X20. Y50. R20.
G1 X60.
G3 X80. Y30. I0 J-20.
G1 Y0
X0
G40 G1 X-20. Y-20.
G0 Z5.
M30
%
"""

LINES_ONLY = PROGRAM.replace("G2 X20. Y50. R20.", "X20. Y50.").replace("G3 X80. Y30. I0 J-20.",
                                                                      "X80. Y30.")


@pytest.fixture(scope="module")
def machine():
    return load_machine("vmc-moving-column")


def comp(machine, errors, text=PROGRAM, **kw):
    return compensate_program(text, machine, errors, filename="cc.nc", **kw)


def test_parse_marks_blocks_under_g41_until_g40_and_keeps_d():
    p = gcode.parse(PROGRAM, axes=("X", "Y", "Z"))
    lines = {int(ln): int(c) for ln, c in zip(p.line, p.cutter)}
    assert lines[7] == 41 and lines[13] == 41            # lead-in block to the last contour block
    assert lines[6] == 0 and lines[14] == 0 and lines[15] == 0      # before, G40 line, after
    assert np.all(p.cutter_d[p.cutter > 0] == 1)
    g42 = gcode.parse("G0 X0 Y0\nG42 D7 G1 X1. Y1.\nX2.\nG40 X3.\n", axes=("X", "Y", "Z"))
    assert g42.cutter.tolist() == [0, 42, 42, 0] and g42.cutter_d[1] == 7


def test_zero_errors_byte_identical(machine):
    out, rep = comp(machine, ErrorSet())
    assert out == PROGRAM
    assert rep["cutter"]["blocks"] == 7 and rep["cutter"]["bound"] == 0.0
    assert rep["cutter"]["source"].startswith("assumed") and rep["cutter"]["radius"] == 10.0


def test_rigid_shift_moves_every_programmed_word_exactly_and_keeps_arcs(machine):
    shift = np.array([0.012, -0.007, 0.003])
    out, rep = comp(machine, ErrorSet(workpiece=WorkpieceSetting(tuple(shift))), cutter_radius=6.0)
    p0 = gcode.parse(PROGRAM, axes=("X", "Y", "Z"))
    p1 = gcode.parse(out, axes=("X", "Y", "Z"))
    assert len(p1) == len(p0) and np.array_equal(p1.line, p0.line)     # no block added
    k = p0.known
    d = p1.position[k] - p0.position[k]
    # every block moves by the same vector (the correction of the workpiece shift), to the
    # written resolution, and the arcs stay arcs with the same I J / R
    assert np.abs(d - d[0]).max() < 1e-9 and np.abs(d[0]).max() > 1e-3
    np.testing.assert_allclose(d[0], shift, atol=1e-6)
    assert rep["linearised"] == 0
    assert "\nG2 X20.0120 Y49.9930 R20.\n" in out and "I0 J-20." in out
    assert "G41 D1 " in out and "G40 G1 " in out
    assert rep["cutter"]["bound"] < 1e-9


def test_in_plane_rotation_is_exact_under_g41(machine):
    # a workpiece turned about Z: offsetting commutes with the rotation, nothing to bound
    out, rep = comp(machine, ErrorSet(workpiece=WorkpieceSetting(angles=(0, 0, 0.02))),
                    cutter_radius=50.0)
    assert rep["linearised"] == 0
    th = np.radians(0.02)
    # second order only (sqrt(5) r theta^2 / 2), where r theta (17 µm) would refuse it
    assert rep["cutter"]["bound"] == pytest.approx(np.sqrt(5) * 50 * th**2 / 2, rel=0.05)
    assert rep["cutter"]["bound"] < 5e-4 < 50 * th


def test_tilt_beyond_tolerance_refused_naming_the_line(machine):
    errs = ErrorSet(workpiece=WorkpieceSetting(angles=(0.05, 0, 0)))
    with pytest.raises(InputError) as exc:
        comp(machine, errs, LINES_ONLY, cutter_radius=50.0)
    assert exc.value.line == 7 and "tool centre 50 mm away" in str(exc.value)
    # the same tilt with a small radius is within the 0.5 µm tolerance: accepted, bound reported
    # (r times the tilt: 5e-4 rad... is 0.87 µm at 1 mm, so take 0.1 mm)
    out, rep = comp(machine, errs, LINES_ONLY, cutter_radius=0.1)
    assert rep["cutter"]["bound"] == pytest.approx(0.1 * np.radians(0.05), rel=0.05)
    assert rep["cutter"]["bound"] <= 5e-4


def test_arc_needing_segments_under_g41_refused(machine):
    errs = ErrorSet(workpiece=WorkpieceSetting(angles=(0.05, 0, 0)))
    with pytest.raises(InputError) as exc:
        comp(machine, errs, cutter_radius=0.0)
    assert exc.value.line == 9 and "cutter radius compensation G41 is active" in str(exc.value)
    # without G41 the same arc is written as segments
    plain = PROGRAM.replace("G41 D1 ", "").replace("G40 ", "")
    _, rep = comp(machine, errs, plain)
    assert rep["linearised"] == 2 and rep["cutter"] is None


def test_d_table_radius_and_tool_setting(machine, tmp_path):
    _, rep = comp(machine, ErrorSet(ToolSetting((0.002, -0.001, 0.0005))), cutter_offsets={1: 4.0})
    assert rep["cutter"]["radius"] == 4.0 and rep["cutter"]["source"] == "D table"


def test_bound_holds_for_random_linear_corrections():
    # the first-order analysis in gcode.cutter against the exact offset of a straight contour
    rng = np.random.default_rng(3)
    for k in range(300):
        if k % 2:
            J = Rotation.from_rotvec(rng.normal(size=3) * rng.uniform(0, 0.03)).as_matrix() - np.eye(3)
        else:
            J = rng.normal(size=(3, 3)) * 1e-3
        r, th = rng.uniform(1, 50), rng.uniform(0, 2 * np.pi)
        t = np.array([np.cos(th), np.sin(th), 0.0])
        n = np.array([-t[1], t[0], 0.0])
        tc = t + J @ t
        tc[2] = 0
        tc /= np.linalg.norm(tc)
        made = r * np.array([-tc[1], tc[0], 0.0])            # control's offset of the corrected contour
        err = made - r * n - r * (J @ n)
        b = offset_error_bound(lambda q: q + q @ J.T, np.zeros((1, 3)), np.array([17]),
                               np.array([r]), ("X", "Y", "Z"))[0]
        assert np.linalg.norm(err) <= b * (1 + 1e-9) + 1e-12


def test_cli_says_the_radius_is_assumed_and_writes_it_in_the_header(tmp_path):
    prog = tmp_path / "cc.nc"
    prog.write_text(PROGRAM)
    err = save_errors(ErrorSet(ToolSetting((0.002, -0.001, 0.0005))), tmp_path / "e.toml")
    out = tmp_path / "o.nc"
    r = subprocess.run([sys.executable, "-m", "mtcomp", "compensate", prog, "-m", "vmc-moving-column",
                        "-e", err, "-o", out], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "G41/G42 on 7 blocks" in r.stdout and "radius 10 mm assumed (no --cutter-radius)" in r.stdout
    assert "(CUTTER-COMP G41/G42 on 7 blocks" in out.read_text()
    r = subprocess.run([sys.executable, "-m", "mtcomp", "compensate", prog, "-m", "vmc-moving-column",
                        "-e", err, "-o", out, "--cutter-radius", "-1"], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode != 0 and "--cutter-radius" in r.stderr


def test_rigid_shift_checked_by_the_independent_interpreter(machine):
    from test_gcode_corpus import interpret
    shift = np.array([0.0123, -0.0071, 0.0042])
    out, rep = comp(machine, ErrorSet(workpiece=WorkpieceSetting(tuple(shift))), cutter_radius=8.0)
    before, after = interpret(PROGRAM), interpret(out)
    assert [b[0] for b in after] == [b[0] for b in before]          # no line added or lost
    n_checked = 0
    for (n, p0, _, c0), (_, p1, _, c1) in zip(before, after):
        for k, a in enumerate("XYZ"):
            if p0[a] is not None:
                assert p1[a] == pytest.approx(p0[a] + shift[k], abs=1e-9), (n, a)   # a multiple of the 0.1 µm grid
                n_checked += 1
        if c0 is not None:
            np.testing.assert_allclose(np.subtract(c1, c0), shift[:2], atol=1e-9)
    assert n_checked >= 30 and rep["cutter"]["radius"] == 8.0


def test_g41_in_a_local_subprogram_reports_the_source_line(machine):
    text = ("%\nO1002\nG21 G90 G17\nG0 X-20. Y-20. Z5.\nG1 Z-2. F300\nM98 P2000\nG0 Z5.\nM30\n"
            "O2000\nG41 D1 G1 X0 Y-10.\nY30.\nG2 X20. Y50. R20.\nG40 G1 X-20. Y-20.\nM99\n%\n")
    errs = ErrorSet(ToolSetting((0.002, -0.001, 0.0005)))
    out, rep = comp(machine, errs, text, cutter_radius=5.0)
    assert rep["flow"] == "once" and rep["cutter"]["blocks"] == 3
    assert rep["cutter"]["line"] in (10, 11, 12)                  # a line of O2000 in the file
    with pytest.raises(InputError) as exc:
        comp(machine, ErrorSet(workpiece=WorkpieceSetting(angles=(0.05, 0, 0))),
             text.replace("G2 X20. Y50. R20.", "X20. Y50."), cutter_radius=50.0)
    assert exc.value.line == 10


def test_bound_in_the_g18_plane():
    # G18: the plane is Z X, its normal Y; a rotation about Y is in the plane, one about X tilts it
    r, th = 20.0, np.radians(0.1)
    for axis, expect in (((0, th, 0), 0.0), ((th, 0, 0), r * th)):
        R = Rotation.from_rotvec(axis).as_matrix()
        b = offset_error_bound(lambda q: q @ R.T, np.array([[10.0, 5.0, -3.0]]), np.array([18]),
                               np.array([r]), ("X", "Y", "Z"))[0]
        assert b == pytest.approx(expect, abs=np.sqrt(5) * r * th**2)


def test_cli_radius_from_the_tool_table_d_column_and_the_offsets_file(tmp_path):
    prog = tmp_path / "cc.nc"
    prog.write_text(PROGRAM)
    err = save_errors(ErrorSet(ToolSetting((0.002, -0.001, 0.0005))), tmp_path / "e.toml")
    tbl = tmp_path / "tool.tbl"
    tbl.write_text("T1 P1 Z+50.0 D12.0 ;end mill\nT2 P2 Z+40.0 D6.0\n")
    out = tmp_path / "o.nc"
    base = [sys.executable, "-m", "mtcomp", "compensate", prog, "-m", "vmc-moving-column", "-e", err,
            "-o", out]
    r = subprocess.run(base + ["--tool-table", tbl], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "radius 6 mm (D table)" in r.stdout                 # D12 is a diameter
    off = tmp_path / "off.toml"
    off.write_text("[D]\n1 = 4.5\n")
    r = subprocess.run(base + ["--tool-table", tbl, "--offsets", off], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "radius 4.5 mm (D table)" in r.stdout               # [D] is a radius and wins
    r = subprocess.run(base + ["--offsets", off, "--cutter-radius", "2"], capture_output=True,
                       text=True, timeout=120)
    assert "radius 2 mm (--cutter-radius)" in r.stdout and "cutter-radius 2 mm" in out.read_text()


def test_arc_midpoints_in_the_three_planes():
    from mtcomp.gcode.cutter import arc_midpoints
    p = gcode.parse("G90 G17 G0 X0 Y0 Z0\nG2 X20. Y0 I10. J0\nG3 X0 Y0 R10.\n"
                    "G18 G2 X20. Z0 I10. K0\nG19 G3 Y10. Z0 J5. K0\nG17 G1 X0\n", axes=("X", "Y", "Z"))
    blocks, mid = arc_midpoints(p, np.arange(len(p)))
    assert blocks.tolist() == [1, 2, 3, 4]
    # G2 clockwise from (0,0) about (10,0) passes (10,10); G3 back counter-clockwise too;
    # G18 G2 (clockwise seen from +Y) passes Z-10; G19 G3 from Y0 about Y5 passes Z-5
    np.testing.assert_allclose(mid, [[10, 10, 0], [10, 10, 0], [10, 0, -10], [20, 5, -5]], atol=1e-12)


def test_default_radius_refusal_says_it_was_assumed(machine):
    with pytest.raises(InputError) as exc:
        comp(machine, ErrorSet(workpiece=WorkpieceSetting(angles=(0.05, 0, 0))), LINES_ONLY)
    assert exc.value.line == 7 and "10 mm away (assumed: no --cutter-radius" in str(exc.value)


def test_canned_cycle_written_out_under_g41_refused(machine):
    text = ("G21 G90 G17\nG0 X-5. Y-5. Z5.\nG41 D1 G1 X0 Y0 F200\n"
            "G81 X10. Y10. R1. Z-5. F100\nG80\nG40 G0 X-5. Y-5.\nM30\n")
    tilt = ErrorSet(workpiece=WorkpieceSetting(angles=(0.05, 0, 0)))
    with pytest.raises(InputError) as exc:
        comp(machine, tilt, text, cutter_radius=0.0)
    assert exc.value.line == 4 and "canned cycle must be written out" in str(exc.value)
    _, rep = comp(machine, tilt, text.replace("G41 D1 ", "").replace("G40 ", ""))
    assert rep["cycles_expanded"] == 1                  # without G41 it is written out


def test_linuxcnc_dynamic_g41_1_takes_the_diameter_from_the_program(machine):
    text = PROGRAM.replace("G41 D1 ", "G41.1 D6. ")
    p = gcode.parse(text, axes=("X", "Y", "Z"))
    assert p.cutter.tolist() == gcode.parse(PROGRAM, axes=("X", "Y", "Z")).cutter.tolist()
    assert np.all(p.cutter_radius[p.cutter > 0] == 3.0) and np.isnan(p.cutter_radius[p.cutter == 0]).all()
    inch = gcode.parse("G20 G90 G0 X0 Y0\nG42.1 D0.5 G1 X1.\nG40 X2.\n", axes=("X", "Y", "Z"))
    assert inch.cutter.tolist() == [0, 42, 0] and inch.cutter_radius[1] == pytest.approx(6.35)
    out, rep = comp(machine, ErrorSet(), text, cutter_radius=20.0)
    assert out == text                                           # byte for byte
    assert rep["cutter"]["radius"] == 3.0 and rep["cutter"]["source"] == "G41.1/G42.1 D"
    with pytest.raises(InputError) as exc:
        gcode.parse("G0 X0 Y0\nG41.1 G1 X1.\n", axes=("X", "Y", "Z"))
    assert exc.value.line == 2 and "without D" in str(exc.value)
