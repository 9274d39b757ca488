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
    # G43.4 with the first move (not alone on its block), cancelled on the Z retract at the end
    assert re.search(r"^N\d+ G00 G43\.4 H1 C-?[\d.]+ B-?[\d.]+ X", text, re.M) and "S20000 M03" in text
    assert text.count("G43.4") == 2 and re.search(r"^N\d+ G49 G91 G28 Z0\.$", text, re.M)
    # Read back with the TCP words removed: the X Y Z words are the tool point that the
    # control's nominal kinematics turns into the compensated axis commands.
    plain = text.replace(" G43.4 H1", "").replace("G49 G91", "G91")
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
    assert len(re.findall(r"^N\d+ G31 ", text, re.M)) == int(np.sum(tp.motion == T.PROBE)) == 39
    assert "TOUCH PROBE R0.25" in text


def test_motion_mode_is_restated_after_a_skip_move():
    m = load_machine("robonano-a0ib")
    L = BowlBlankLayout()
    tp = T.bowl_probing(L.centres[:1], L.bowl_radius, L.bowl_depth, T.Tool("probe", 0.25))
    blocks = [ln.split(" ", 1)[1] for ln in P.post(m, tp, options=P.PostOptions(protected_macro=0)).splitlines()
              if ln.startswith("N")]
    moves = [b for b in blocks if not b.startswith(("#", "IF", "DPRNT"))]
    after = [moves[i + 1] for i, b in enumerate(moves) if b.startswith("G31")]
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


# ------------------------------------------------------------------ post conventions (issue 14)
def _blocks(text):
    return [ln.split(" ", 1)[1] if re.match(r"N\d+ ", ln) else ln for ln in text.splitlines()]


def test_probing_blocks_carry_only_the_axes_that_move():
    m = load_machine("robonano-a0ib")
    L = BowlBlankLayout()
    tp = T.bowl_probing(L.centres[:1], L.bowl_radius, L.bowl_depth, T.Tool("probe", 0.25))
    skips = [b for b in _blocks(P.post(m, tp)) if b.startswith("G31")]
    # C and B stand at 0 throughout: a skip block names neither (issue 14: a forced C0 each time)
    assert skips and not any(re.search(r"\b[BC]-?\d", b) for b in skips)


def test_rotary_feed_keeps_the_tool_tip_feed(grating):
    """Fanuc spreads a G94 F over all axes with degrees as mm: the per-block F (tool-tip mode)
    and G93's inverse time (1 / duration) both give the grating's tool tip the programmed feed,
    where plain F gives it a fraction of it (issue 14: 0.33 F)."""
    m, tp, q = grating
    qr = round_to_resolution(m, q)
    tip = np.linalg.norm(np.diff(forward(m, qr).p, axis=0), axis=1)
    axes_len = np.linalg.norm(np.diff(qr, axis=0), axis=1)   # mm and deg alike
    feed_moves = np.nonzero((tp.motion[1:] == T.FEED) & (tip > 1e-6))[0]
    turning = feed_moves[np.abs(np.diff(qr[:, 3:], axis=0))[feed_moves].max(axis=1) > 0]
    assert turning.size > 100
    plain_speed = tip[turning] / (axes_len[turning] / tp.feed)
    assert plain_speed.min() < 0.5 * tp.feed                       # what a G94 F does at the tip
    text = P.post(m, tp, q)                                          # default: tool-tip
    prog = gcode.parse(text, axes=m.axis_names)
    assert prog.position.shape[0] == len(tp)
    speed = tip[turning] / (axes_len[turning] / prog.feed[turning + 1])
    assert np.max(np.abs(speed / tp.feed - 1)) < 1e-3               # F written to 4 decimals
    inv = P.post(m, tp, q, P.PostOptions(rotary_feed="inverse-time"))
    fl = [b for b in _blocks(inv) if b.startswith(("G93", "G01", "X", "Y", "Z", "A", "B", "C"))]
    g93 = [b for b in _blocks(inv) if "G93" in b]
    assert len(g93) == 9 and "G94" in _blocks(inv)[-6]            # one switch per groove, back at the end
    # every block in G93 carries its F = feed / tip length (1/min)
    per_block = {}
    mode = "G94"
    k = -1
    for b in _blocks(inv):
        if "G28" in b:
            continue   # the retracts: no pose of the path
        if re.search(r"\b[XYZABC]-?\d", b):
            k += 1
        mode = "G93" if "G93" in b else ("G94" if "G94" in b else mode)
        if mode == "G93" and re.search(r"\b[XYZABC]-?\d", b):
            per_block[k] = float(re.search(r"F([\d.]+)", b).group(1))
    assert fl and per_block
    idx = np.array(sorted(per_block))
    assert np.allclose([per_block[i] for i in idx], tp.feed / tip[idx - 1], rtol=2e-4)


def test_line_numbers_templates_g43_plunge_and_coolant():
    m = load_machine("robonano-a0ib")
    tp = T.groove_plate_passes()
    opts = P.PostOptions(line_start=99000, line_step=20, line_max=99999, tool_length=True,
                         plunge_feed=5.0, coolant="M08", spindle=None,
                         preamble="G21 G90 G94 G17\n{work_offset} (PROGRAM {program})",
                         postamble="G53 Z0.", program_number=7)
    text = P.post(m, tp, options=opts)
    ns = [int(x) for x in re.findall(r"^N(\d+) ", text, re.M)]
    # 999 numbers left above N99000 at step 20 are too few: the step shrinks, nothing repeats
    assert ns[0] == 99000 and max(ns) <= 99999 and len(set(ns)) == len(ns) == len(text.splitlines()) - 8
    assert np.all(np.diff(ns) == ns[1] - ns[0]) and 1 <= ns[1] - ns[0] < 20
    b = _blocks(text)
    assert b[7:9] == ["G21 G90 G94 G17", "G54 (PROGRAM 7)"] and "T1 M06" in b and "M08" in b
    first_move = next(x for x in b if re.search(r"\bZ-?\d", x) and "G28" not in x)
    assert first_move.startswith("G00 G43 H1 ")
    assert b[-7:] == ["M09", "G49 G91 G28 Z0.", "G28 X0. Y0.", "G90", "G53 Z0.", "M30", "%"]
    # plunges (straight down the tool axis into the groove) at 5 mm/min, the cut at 50
    plunges = [x for x in b if re.fullmatch(r"(G01 )?Z-?[\d.]+ F5\.0", x)]
    assert len(plunges) == 8                                  # 2 A, 3 C and 3 B grooves
    assert sum(x.endswith("F50.0") for x in b) == 8           # each cut back at the feed
    none = P.post(m, tp, options=P.PostOptions(line_numbers=False))
    assert not re.search(r"^N\d", none, re.M)
    with pytest.raises(ValueError, match="spindle"):
        P.post(m, tp, options=P.PostOptions(preamble="S{spindel}"))
    with pytest.raises(ValueError, match="line_max"):
        P.PostOptions(line_start=100, line_max=50)


def test_probing_macro_log_reads_back_into_touches_that_fit_the_real_bowls(tmp_path):
    """The probe_log program writes T<bowl> I J K and the skip positions (#5061...) per touch;
    the control's log, read by read_skip_log, gives the touches CSV (the setting code's own
    reader and sphere fit) whose spheres are the real bowls seen in the nominal frame."""
    from mtcomp.cad_plugin.check import simulate_probing
    from mtcomp.setting.workpiece import fit_bowls, read_touches, write_touches
    m = load_machine("robonano-a0ib")
    L = BowlBlankLayout()
    probe = T.Tool("probe", 0.25, number=9)
    tp = T.bowl_probing(L.centres, L.bowl_radius, L.bowl_depth, probe)
    q = T.to_axes(m, tp)
    text = P.post(m, tp, q, P.PostOptions(probe_log=True))
    b = _blocks(text)
    assert "POPEN" in b and "PCLOS" in b and sum(x.startswith("DPRNT[") for x in b) == 39
    assert all(not x.startswith("G31") or not re.search(r"\b[BC]-?\d", x) for x in b)
    dp = next(x for x in b if x.startswith("DPRNT["))
    # DPRNT fields [integer digits, decimals] with a + b <= 8: X travel 140 mm -> [35]
    assert "X#5061[35]" in dp and "Y#5062[26]" in dp and "Z#5063[26]" in dp and "B#5064[35]" in dp
    # The control: the skip stops each G31 where the real stylus meets the real bowl; DPRNT
    # prints the macro variables (spaces for '*', a sign only when negative, padded fields).
    wp = WorkpieceSetting((0.012, -0.02, 0.008), (0.01, -0.015, 0.05))
    run = simulate_probing(m, tp, q, ErrorSet(workpiece=wp))
    idx = np.nonzero(tp.motion == T.PROBE)[0]
    qs = q[idx - 1] + run.fraction[:, None] * (q[idx] - q[idx - 1])
    var, log, k = {}, ["MTCOMP PROBE LOG"], 0
    for x in b:
        if x.startswith("#") and not x.startswith("#104="):
            key, val = x.split("=")
            var[key] = float(val)
        elif x.startswith("DPRNT["):
            words = [f"T{var['#100']:3.0f}"] + [f"{c}{var[v]: .6f}" for c, v in
                                                 zip("IJK", ("#101", "#102", "#103"))]
            fields = re.findall(r"([A-Z])#50\d\d\[(\d)(\d)\]", x)   # the printed decimals
            words += [f"{a}{qs[k, m.index(a)]: {int(i) + int(d) + 2}.{d}f}" for a, i, d in fields]
            log.append("  ".join(words))
            k += 1
    touches = P.read_skip_log("\n".join(log), m, probe.radius)
    assert len(touches.bowl) == 39 and sorted(set(touches.bowl.tolist())) == [1, 2, 3]
    write_touches(touches, tmp_path / "touches.csv")
    back = read_touches(tmp_path / "touches.csv")
    assert np.allclose(back.points, touches.points, atol=1e-9)
    fit = fit_bowls(back, probe.radius, probe_sigma=1e-4, bowl_radius=L.bowl_radius)
    real = np.array([[cx, cy, L.bowl_radius - L.bowl_depth] for cx, cy in L.centres])
    seen = real @ wp.matrix.T + np.asarray(wp.translation)        # real bowls in the nominal frame
    assert np.max(np.abs(fit.centres - seen)) < 5e-6      # X printed to 10 nm: a few nm
    with pytest.raises(ValueError, match=":2: skip log line without C, B, Z"):
        P.read_skip_log("MTCOMP\nT1 I0 J0 K-1 X1.0 Y2.0\n", m, 0.25)
