"""NC transform for the measured workpiece setting: paper 001's 3-axis formula and the 5-axis mode."""
import numpy as np
import pytest

from mtcomp import InputError, gcode
from mtcomp.errors import ErrorSet, WorkpieceSetting
from mtcomp.kinematics import forward
from mtcomp.machine import load_machine
from mtcomp.setting.bowls import fit_bowls, plan_bowls, virtual_probe
from mtcomp.setting.frame import frame_from_bowls
from mtcomp.setting.workpiece import compensate_commands, compensate_program, compensate_text

M = load_machine("robonano-a0ib")


def _poses(rng, n):
    return [WorkpieceSetting(tuple(rng.uniform(-1, 1, 3)), tuple(rng.uniform(-2, 2, 3)))
            for _ in range(n)]


def _program_3axis(rng, n=40):
    lines = ["%", "O0200 (PYRAMID FINISH)", "G21 G90 G17", "G00 X0. Y0. Z5."]
    for x, y, z in rng.uniform([-3, -3, 0], [3, 3, 0.3], (n, 3)):
        lines.append(f"G01 X{x:.6f} Y{y:.6f} Z{z:.6f} F200.")
    lines += ["G00 Z5.", "M30", "%"]
    return "\n".join(lines) + "\n"


def test_noise_free_chain_puts_the_tool_edge_on_the_nominal_part_within_a_nanometre():
    rng = np.random.default_rng(8)
    plan = plan_bowls(3)
    text = _program_3axis(rng)
    nominal = forward(M, gcode.parse(text, axes=M.axis_names).position).p
    for true in _poses(rng, 10):
        est = frame_from_bowls(fit_bowls(virtual_probe(true, plan, 0.0, rng, aim=true),
                                         plan.probe_radius), plan)
        new, n = compensate_text(M, text, est.pose)
        q = gcode.parse(new, axes=M.axis_names).position
        real = forward(M, q, ErrorSet(workpiece=true)).p
        # the written program carries 1 nm resolution: rounding adds at most sqrt(3)/2 nm
        assert np.abs(real - nominal).max() < 1e-6
        q_exact = compensate_commands(M, gcode.parse(text, axes=M.axis_names).position, est.pose)
        assert np.abs(forward(M, q_exact, ErrorSet(workpiece=true)).p - nominal).max() < 1e-9


def test_five_axis_program_keeps_contact_point_and_tool_direction_on_the_real_blank():
    rng = np.random.default_rng(9)
    q = np.zeros((60, 5))
    q[:, 0] = rng.uniform(-180, 180, 60)        # C
    q[:, 1] = rng.uniform(-60, 60, 60)          # B
    q[:, 2:] = rng.uniform(-5, 5, (60, 3))
    ideal = forward(M, q)
    for true in _poses(rng, 5):
        q_new = compensate_commands(M, q, true)
        real = forward(M, q_new, ErrorSet(workpiece=true))
        assert np.abs(real.p - ideal.p).max() < 1e-9
        assert np.abs(real.v - ideal.v).max() < 1e-9
        # the 3-axis formula would put the point right but not the direction
    q3 = np.zeros((5, 5))
    q3[:, 2:] = rng.uniform(-5, 5, (5, 3))
    true = WorkpieceSetting((0.1, 0, 0), (0.5, 0, 0))
    r3 = forward(M, compensate_commands(M, q3, true, "3axis"), ErrorSet(workpiece=true))
    r5 = forward(M, compensate_commands(M, q3, true, "5axis"), ErrorSet(workpiece=true))
    np.testing.assert_allclose(r3.p, q3[:, 2:], atol=1e-9)
    np.testing.assert_allclose(r5.p, q3[:, 2:], atol=1e-9)
    assert np.degrees(np.arccos(r3.v[0, 2])) == pytest.approx(0.5, abs=1e-9)   # tool tilted on the blank
    np.testing.assert_allclose(r5.v, [[0, 0, 1]] * 5, atol=1e-9)


def test_program_text_other_than_axis_words_is_kept():
    text = "%\nO0300\nG21 G90\n(COMMENT X1.)\nG01 X1. Y2. Z0.1 F100. M08\nM30\n%\n"
    new, n = compensate_text(M, text, WorkpieceSetting((0.001, 0.002, 0.003), (0, 0, 0)))
    assert n == 1
    assert new.splitlines()[3] == "(COMMENT X1.)"
    assert new.splitlines()[4] == "G01 X1.001000 Y2.002000 Z0.103000 F100. M08"


def test_angles_beyond_travel_are_refused_naming_the_line(tmp_path):
    text = "G21 G90\nG01 X1. Y0. Z1. F100.\nG01 B99.5 C10.\nG01 X2.\nM30\n"
    src = tmp_path / "five.nc"
    src.write_text(text)
    out = tmp_path / "out.nc"
    with pytest.raises(InputError, match=r"five.nc:3: the compensated angles leave the travel: axis B"):
        compensate_program(M, src, WorkpieceSetting((0, 0, 0), (0, 1.0, 0)), out)
    assert not out.exists()
    with pytest.raises(InputError, match=r":3: 3-axis transform needs the rotary axes at 0"):
        compensate_program(M, src, WorkpieceSetting((0, 0, 0), (0, 1.0, 0)), out, mode="3axis")
    assert not out.exists()
    # a linear axis beyond its travel after the transform is named as well (Y travel +-40 mm)
    src.write_text("G21 G90\nG01 X0. Y39.99 Z0. F100.\nM30\n")
    with pytest.raises(InputError, match=r"five.nc:2: axis Y would have to move to 40.0"):
        compensate_program(M, src, WorkpieceSetting((0, 0.05, 0), (0, 0, 0)), out)


@pytest.mark.parametrize("preset", ["robonano-a0ib", "robonano-ui", "vmc-moving-column"])
def test_three_axis_formula_on_every_preset(preset):
    m = load_machine(preset)
    rng = np.random.default_rng(21)
    lin = [i for i in range(m.n_axes) if i not in m.rotary_indices]
    q = np.zeros((30, m.n_axes))
    q[:, lin] = rng.uniform(-5, 5, (30, 3))
    pose = WorkpieceSetting((0.1, -0.2, 0.3), (0.5, -0.4, 1.0))
    q_new = compensate_commands(m, q, pose, "3axis")
    assert np.abs(forward(m, q_new, ErrorSet(workpiece=pose)).p - forward(m, q).p).max() < 1e-12
    assert np.array_equal(q_new[:, list(m.rotary_indices)], q[:, list(m.rotary_indices)])


def test_program_file_keeps_crlf_and_refuses_binary(tmp_path):
    src = tmp_path / "crlf.nc"
    src.write_bytes(b"G21 G90\r\nG01 X1. Y2. Z0.1 F100. (A)\r\nM30\r\n")
    out = tmp_path / "out.nc"
    assert compensate_program(M, src, WorkpieceSetting((0.001, 0.002, 0.003), (0, 0, 0)), out) == 1
    assert out.read_bytes() == b"G21 G90\r\nG01 X1.001000 Y2.002000 Z0.103000 F100. (A)\r\nM30\r\n"
    src.write_bytes(b"G01 X1.\xff\xfe\n")
    with pytest.raises(InputError, match=r"crlf.nc: not a text file"):
        compensate_program(M, src, WorkpieceSetting((0.001, 0, 0), (0, 0, 0)), tmp_path / "o2.nc")
    assert not (tmp_path / "o2.nc").exists()

