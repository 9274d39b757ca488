"""G68 coordinate rotation in the plane (issue 20): read as the control does, compensated in the
reference frame, written back in the rotated frame.  Checked against a rotation written out in
this test (the control: words rotated about the centre, then the work offset)."""
from __future__ import annotations

import numpy as np
import pytest

from mtcomp import InputError, gcode
from mtcomp.commands import compensate_program
from mtcomp.errors import ErrorSet, ToolSetting, WorkpieceSetting
from mtcomp.gcode.rotation import to_reference
from mtcomp.kinematics import forward
from mtcomp.machine import load_machine

XYZ = ("X", "Y", "Z")
PROG = ("G90 G17 G0 X0 Y0 Z5.\nG68 X10. Y5. R30.\nG0 X20. Y5.\nG1 Z-1. F100\nG3 X10. Y15. I-10. J0\n"
        "G91 G1 X-2. Y1.\nG90 G69\nG0 X0 Y0\nG68 X0 Y0 R15.\nG90 G1 X3. Y4.\nG69\nG0 X0 Y0 Z5.\n")


def control(text):
    """Reference positions per block, by hand: a G68 block's X Y rotated about its centre."""
    rows, pos, ang, c = [], {"X": 0.0, "Y": 0.0, "Z": 0.0}, 0.0, (0.0, 0.0)
    inc = False
    for ln in text.splitlines():
        w = dict((t[0], float(t[1:])) for t in ln.split())
        g = [v for k, v in ((t[0], t[1:]) for t in ln.split()) if k == "G"]
        inc = True if "91" in g else False if "90" in g else inc
        if "68" in g:
            ang = (ang if inc else 0.0) + w["R"]
            c = (w["X"], w["Y"]) if "X" in w else (rows[-1][0], rows[-1][1])   # or where it is
            continue
        if "69" in g:
            ang = 0.0
        if not any(k in w for k in "XYZ"):
            continue
        for k in "XYZ":
            if k in w:
                pos[k] = pos[k] + w[k] if inc else w[k]
        t = np.radians(ang)
        dx, dy = pos["X"] - c[0], pos["Y"] - c[1]
        rows.append((c[0] + np.cos(t) * dx - np.sin(t) * dy, c[1] + np.sin(t) * dx + np.cos(t) * dy,
                     pos["Z"]))
    return np.array(rows)


def test_rotation_read_as_the_control_does():
    p = gcode.parse(PROG, axes=XYZ, rotation=True)
    assert p.known.all()
    assert np.allclose(to_reference(p, p.position), control(PROG), atol=1e-12)
    # the arc keeps its radius about the rotated centre
    t = np.radians(30)
    centre = np.array([10 + np.cos(t) * 0 - np.sin(t) * 0, 5.0])       # programmed centre (10, 5)
    assert np.allclose(p.arc_centre[3, :2], centre)
    assert gcode.rewrite(p, lambda q: q.copy()) == PROG
    assert any("G68" in n for n in p.notes)


def test_a_translation_is_written_in_the_rotated_frame():
    p = gcode.parse(PROG, axes=XYZ, rotation=True)
    d = np.array([0.003, -0.002, 0.001])
    out = gcode.rewrite(p, lambda q: q + d)
    back = gcode.parse(out, axes=XYZ, rotation=True)
    assert np.allclose(to_reference(back, back.position), control(PROG) + d, atol=1.5e-6)
    assert np.allclose(control(out), control(PROG) + d, atol=1.5e-6)
    t = np.radians(-30)
    wd = (np.cos(t) * d[0] - np.sin(t) * d[1], np.sin(t) * d[0] + np.cos(t) * d[1])
    assert out.splitlines()[2] == f"G0 X{20 + wd[0]:.6f} Y{5 + wd[1]:.6f}"


def test_compensated_rotated_program_hits_the_programmed_points():
    m = load_machine("vmc-moving-column")
    e = ErrorSet(ToolSetting((0.002, -0.001, 0.0005)), WorkpieceSetting((0.01, 0.02, 0), (0, 0, 0.01)))
    text = PROG.replace("Z-1.", "Z-10.").replace("Z5.", "Z-5.")
    assert compensate_program(text, m, ErrorSet())[0] == text
    out, rep = compensate_program(text, m, e)
    want = forward(m, control(text)).p
    got = forward(m, control(out), e).p
    assert np.abs(got - want).max() < 2e-4                     # 0.1 µm resolution of the machine
    assert rep["after_max"] < 2e-4 < 0.01 < rep["before_max"]


def test_rotation_centre_is_the_current_position_and_axes_stay_known():
    # G68 about the current point leaves the tool where it is whichever way the control reads
    # the words there (modal words, or the position re-expressed): Y stays known
    text = "G90 G0 X10. Y5. Z0\nG68 R90.\nG1 X11. F100\nY5.\nX12.\n"
    p = gcode.parse(text, axes=XYZ, rotation=True)
    assert list(p.known) == [True, True, True, True]
    assert np.allclose(to_reference(p, p.position)[1], [10, 6, 0])
    assert np.allclose(p.rotation[2, :3], [90, 10, 5])
    assert np.allclose(to_reference(p, p.position)[2:], [[10, 6, 0], [10, 7, 0]])
    assert gcode.rewrite(p, lambda q: q.copy()) == text
    # incremental angle: added to the active one
    q = gcode.parse("G0 X0 Y0 Z0\nG68 X0 Y0 R10.\nG91 G68 R20.\nG90 G1 X1. Y0 F1\n", axes=XYZ, rotation=True)
    assert np.allclose(to_reference(q, q.position)[-1], [np.cos(np.pi / 6), 0.5, 0])
    # the compensation would move the centre: refused naming the G68 block
    with pytest.raises(InputError, match=r":2: G68 without a centre turns about the current"):
        gcode.rewrite(p, lambda q: q + [0.001, 0, 0])


@pytest.mark.parametrize("text,line,what", [
    ("G0 X0 Y0\nG68 X1. Y1.\n", 2, "G68 without R"),
    ("G0 X0 Y0\nG68 X1. Y1. Z0 I0 J0 K1. R10.\n", 2, "three-dimensional"),
    ("G0 X0 Y0\nG68 X1. Y1. Z2. R10.\n", 2, "expected the centre X Y"),
    ("G0 X0 Y0 Z0\nG68 X1. Y1. R10.\nG1 X1. Y1. F1\nG18 G1 X2. Z1.\n", 4, "plane change under G68"),
    ("G0 X0 Y0\nG1 G68 X1. Y1. R10.\n", 2, "G68 in a block with a motion code"),
    ("G68\nG0 X0 Y0\n", 1, "G68 without R"),
    ("G68 R10.\nG0 X0 Y0 Z0\n", 1, "without a centre where the current position is not known"),
    ("G0 X0 Y0\nG68.2 X0 Y0 Z0 I0 J45. K0\n", 2, "G68.2 tilted working plane"),
    ("G0 X0 Y0\nG51 X0 Y0 P2\n", 2, "G51 scaling"),
])
def test_rotation_refusals(text, line, what):
    with pytest.raises(InputError, match=rf"^p.nc:{line}: .*{what}"):
        gcode.parse(text, axes=XYZ, filename="p.nc", rotation=True)


def test_rotation_is_read_only_where_the_caller_says_so():
    # a caller that takes `position` as axis positions (the default) gets G68 refused
    with pytest.raises(InputError, match=r"^p.nc:2: G68: G68 coordinate rotation .* rotation=True"):
        gcode.parse(PROG, axes=XYZ, filename="p.nc")


def control_reexpress(text):
    """Like `control`, for a control that at G68/G69 re-expresses where the tool is in the new
    frame (instead of keeping the modal words): unwritten words then mean that point."""
    rows, pos, ang, c = [], {"X": 0.0, "Y": 0.0, "Z": 0.0}, 0.0, (0.0, 0.0)
    inc = False

    def rot(p, a, cc, sign=1.0):
        t = np.radians(a) * sign
        dx, dy = p[0] - cc[0], p[1] - cc[1]
        return cc[0] + np.cos(t) * dx - np.sin(t) * dy, cc[1] + np.sin(t) * dx + np.cos(t) * dy

    for ln in text.splitlines():
        w = dict((t[0], float(t[1:])) for t in ln.split())
        g = [v for k, v in ((t[0], t[1:]) for t in ln.split()) if k == "G"]
        inc = True if "91" in g else False if "90" in g else inc
        if "68" in g or "69" in g:
            here = rot((pos["X"], pos["Y"]), ang, c)
            if "68" in g:
                ang = (ang if inc else 0.0) + w["R"]
                c = (w["X"], w["Y"]) if "X" in w else (pos["X"], pos["Y"])
            else:
                ang = 0.0
            pos["X"], pos["Y"] = rot(here, ang, c, -1.0)
            if "68" in g:
                continue
        if not any(k in w for k in "XYZ"):
            continue
        for k in "XYZ":
            if k in w:
                pos[k] = pos[k] + w[k] if inc else w[k]
        rows.append((*rot((pos["X"], pos["Y"]), ang, c), pos["Z"]))
    return np.array(rows)


@pytest.mark.parametrize("text,known", [
    # G69 with the tool at the centre: the retract after it is compensated
    ("G90 G17 G0 X0 Y0 Z-5.\nG68 X10. Y5. R30.\nG0 X20. Y5.\nG1 Z-10. F100\nX10. Y5.\nG69\n"
     "G0 Z-5.\nX0 Y0\n", [True] * 6),
    # G68 about the current point (written: without centre words compensation is refused): X
    # alone after it is compensated
    ("G90 G17 G0 X10. Y5. Z-5.\nG68 X10. Y5. R90.\nG1 X11. F100\nZ-10.\nY6.\nG69\nG0 Z-5.\nX0 Y0\n",
     [True, True, True, True, False, True]),
    # G69 away from the centre: the two readings differ, Z alone stays deferred
    ("G90 G17 G0 X0 Y0 Z-5.\nG68 X10. Y5. R30.\nG0 X20. Y5.\nG1 Z-10. F100\nX12. Y5.\nG69\n"
     "G0 Z-5.\nX0 Y0\n", [True, True, True, True, False, True]),
])
def test_rotation_keeps_axes_known_where_the_pose_is_known(text, known):
    m = load_machine("vmc-moving-column")
    e = ErrorSet(ToolSetting((0.002, -0.001, 0.0005)), WorkpieceSetting((0.01, 0.02, 0), (0, 0, 0.01)))
    p = gcode.parse(text, axes=m.axis_names, rotation=True)
    assert p.known.tolist() == known
    k = np.asarray(p.known)
    # where known, both readings of the control agree on the program and on its compensation
    assert np.allclose(control(text)[k], control_reexpress(text)[k], atol=1e-12)
    out, rep = compensate_program(text, m, e)
    assert rep["deferred"] == known.count(False)
    a, b = control(out), control_reexpress(out)
    assert np.abs(a[k] - b[k]).max() < 2e-4
    want = forward(m, control(text)).p
    for got in (forward(m, a, e).p, forward(m, b, e).p):
        assert np.abs(got[k] - want[k]).max() < 2e-4           # 0.1 µm resolution of the machine


def test_workpiece_setting_compensates_rotated_programs():
    # the setting error is a rigid motion of the blank in the reference frame: the rotated words
    # are compensated there and written back in the rotated frame
    from mtcomp.setting.workpiece import compensate_text
    m = load_machine("vmc-moving-column")
    pose = WorkpieceSetting((0.01, 0.02, -0.005), (0.002, -0.001, 0.01))
    text = PROG.replace("Z-1.", "Z-10.").replace("Z5.", "Z-5.")
    out, n = compensate_text(m, text, pose, mode="3axis", chordal_tol=2e-4)
    assert out != text and n == 8
    want = forward(m, control(text)).p
    got = forward(m, control(out), ErrorSet(workpiece=pose)).p
    unc = forward(m, control(text), ErrorSet(workpiece=pose)).p
    assert np.abs(got - want).max() < 2e-4 < 0.01 < np.abs(unc - want).max()
    # the words really are in the rotated frame: read without the rotation they would be off
    plain = gcode.parse(out, axes=m.axis_names, rotation=True).position
    assert np.abs(forward(m, plain, ErrorSet(workpiece=pose)).p - want).max() > 1.0
