"""Post-processor: Fanuc-style text that the project's G-code reader reads back to the same
axis commands, header, decimals per resolution, TCP output, compensated output."""
import re

import numpy as np
import pytest

from mtcomp import gcode
from mtcomp.cad_plugin import post as P, toolpath as T
from mtcomp.cad_plugin.layout import BowlBlankLayout, GratingLayout
from mtcomp.errors import ErrorSet, ToolSetting, WorkpieceSetting
from mtcomp.kinematics import forward, round_to_resolution
from mtcomp.machine import load_machine


@pytest.fixture(scope="module")
def grating():
    m = load_machine("robonano-ui")
    g = GratingLayout()
    tp = T.grating_passes(g.sphere_radius, g.psi, g.span, g.depth, T.Tool("vtool", number=3))
    return m, tp, T.to_axes(m, tp)


def test_program_reads_back_to_the_axis_commands(grating):
    m, tp, q = grating
    text = P.post(m, tp, q, P.PostOptions(program_number=42))
    prog = gcode.parse(text, axes=m.axis_names)
    assert prog.position.shape == (len(tp), 6)
    assert np.max(np.abs(prog.position - round_to_resolution(m, q))) < 1e-12
    lines = text.splitlines()
    assert lines[0] == "%" and lines[-1] == "%"
    assert lines[1].startswith("O0042 (GRATING)")
    header = "\n".join(lines[:8])
    for s in ("ROBONANO-UI", "AXES X Y Z A B C", "T3", "UNITS MM DEG", "NOT COMPENSATED"):
        assert s in header
    n = [int(x) for x in re.findall(r"^N(\d+) ", text, re.M)]
    assert len(n) > len(tp) and n == list(range(10, 10 * len(n) + 1, 10))
    # Decimals follow the resolutions: 1 nm -> 6 decimals, 1e-5 deg -> 5 decimals.
    xs, bs = re.findall(r"X-?\d+\.(\d+)", text), re.findall(r"B-?\d+\.(\d+)", text)
    assert xs and bs and all(len(v) == 6 for v in xs) and all(len(v) == 5 for v in bs)
    assert "T3 M06" in text and "M30" in text


def test_decimals_override_and_no_line_numbers(grating):
    m, tp, q = grating
    text = P.post(m, tp, q, P.PostOptions(decimals={"X": 4}, line_numbers=False))
    assert not re.search(r"^N\d", text, re.M)
    xs = re.findall(r"X-?\d+\.(\d+)", text)
    assert xs and all(len(v) == 4 for v in xs)
    prog = gcode.parse(text, axes=m.axis_names)
    assert np.max(np.abs(prog.position[:, 0] - q[:, 0])) <= 0.5e-4 + 1e-12
    with pytest.raises(ValueError):
        P.post(m, tp, q, P.PostOptions(decimals={"U": 3}))
    with pytest.raises(ValueError):
        P.PostOptions(program_number=12345)


def test_compensated_program_puts_the_real_tool_on_the_path():
    m = load_machine("robonano-ui")
    g = GratingLayout()
    tp = T.grating_passes(g.sphere_radius, g.psi[:3], g.span, g.depth, T.Tool("vtool"))
    err = ErrorSet(tool=ToolSetting((0.4900, 0.6801, -0.0120)),   # paper 000 magnitudes
                   workpiece=WorkpieceSetting((0.01, 0.0, -0.02), (0.0, 0.02, -0.1)))
    text = P.post(m, tp, errors=err, errors_name="setting.toml")
    assert "COMPENSATED FOR SETTING.TOML" in text
    q = gcode.parse(text, axes=m.axis_names).position
    real = forward(m, q, err)
    # Commands rounded to 1 nm / 1e-5 deg: the edge lands within a few nm.
    assert np.max(np.abs(real.p - tp.p)) < 5e-6
    assert np.max(np.abs(real.R - tp.R)) < 1e-6
    assert np.max(np.abs(forward(m, q).p - tp.p)) > 0.4  # the nominal machine would miss


def test_tcp_output_writes_tool_point_and_rotary_angles():
    m = load_machine("robonano-a0ib")   # B and C tables carry the workpiece
    L = BowlBlankLayout()
    tp = T.bowl_milling(L.centres[:1], L.bowl_radius, L.bowl_depth, T.Tool("ball", 0.5),
                        stepover=0.3, step=0.3)
    err = ErrorSet(workpiece=WorkpieceSetting((0.0, 0.0, 0.0), (0.5, -0.4, 0.0)))
    q = T.to_axes(m, tp, err)
    assert np.max(np.abs(q[:, m.index("B")])) > 0.1  # the tables tilt to compensate
    text = P.post(m, tp, q, P.PostOptions(tcp=True, spindle=20000), errors=err)
    assert re.search(r"^N\d+ G43.4 H1$", text, re.M) and "S20000 M03" in text
    assert re.search(r"^N\d+ G49$", text, re.M)
    # Read back with the TCP lines removed: the X Y Z words are the tool point that the
    # control's nominal kinematics turns into the compensated axis commands.
    plain = re.sub(r"^N\d+ G4(3\.4 H1|9)\n", "", text, flags=re.M)
    words = gcode.parse(plain, axes=m.axis_names).position
    qr = round_to_resolution(m, q)
    lin = [m.index(a) for a in "XYZ"]
    rot = [m.index(a) for a in "CB"]
    assert np.max(np.abs(words[:, lin] - forward(m, qr).p)) <= 5e-7 + 1e-12
    assert np.max(np.abs(words[:, rot] - qr[:, rot])) < 1e-9
    # ... which differ from the machine axes where the tables are turned.
    assert np.max(np.abs(words[:, lin] - qr[:, lin])) > 1e-3


def test_probing_program_uses_skip_moves():
    m = load_machine("robonano-a0ib")
    L = BowlBlankLayout()
    tp = T.bowl_probing(L.centres, L.bowl_radius, L.bowl_depth, T.Tool("probe", 0.25, number=9))
    text = P.post(m, tp)
    assert text.count("G31") == int(np.sum(tp.motion == T.PROBE)) == 39
    assert "TOUCH PROBE R0.25" in text


def test_motion_mode_is_restated_after_a_skip_move():
    m = load_machine("robonano-a0ib")
    L = BowlBlankLayout()
    tp = T.bowl_probing(L.centres[:1], L.bowl_radius, L.bowl_depth, T.Tool("probe", 0.25))
    blocks = [ln.split(" ", 1)[1] for ln in P.post(m, tp).splitlines() if ln.startswith("N")]
    after = [blocks[i + 1] for i, b in enumerate(blocks) if b.startswith("G31")]
    assert after and all(b.startswith(("G01", "G00")) for b in after)
    # The G31 blocks carry the full target (a skip move needs its end point).
    skips = [b for b in blocks if b.startswith("G31")]
    assert skips and all(len(b.split()) >= 2 for b in skips)


def test_groove_plate_program_keeps_rotary_angles_near_zero():
    m = load_machine("robonano-ui")
    tp = T.groove_plate_passes()
    q = T.to_axes(m, tp)
    # C turns to 0 / +-120 / 90 deg with the pass directions; never a full turn near the limits.
    c = q[:, m.index("C")]
    assert np.max(np.abs(c)) <= 180 + 1e-9
    text = P.post(m, tp, q)
    assert np.max(np.abs(gcode.parse(text, axes=m.axis_names).position - round_to_resolution(m, q))) < 1e-12
    assert np.allclose(forward(m, q).R, tp.R, rtol=0, atol=1e-12)
