"""A headless LinuxCNC (uspace, no display) loads the joint compensation files mtcomp exports and
runs a program that moves every axis across its table both ways; the joint positions it commands
(motor-pos-cmd, sampled every servo period with HAL) equal mtcomp's model -- the programmed
position plus the correction of the error tables for the direction of motion -- to 0.1 µm."""
from __future__ import annotations

import numpy as np
import pytest

from mtcomp.control import export_control
from mtcomp.control.common import error_to_control, split_errors
from mtcomp.control.linuxcnc_sim import available, run_sim
from mtcomp.control.synthetic import grid_errors
from mtcomp.machine import load_machine

pytestmark = [pytest.mark.skipif(not available(), reason="LinuxCNC (apt linuxcnc-uspace) not installed"),
              pytest.mark.slow]


def _model(pitch, pos, vel):
    """mtcomp's correction at joint positions moving with velocity vel: the forward table moving
    up, the reverse one moving down, held while standing (0 before the first move)."""
    up = np.interp(pos, pitch.position, error_to_control(pitch.axis, pitch.up))
    down = np.interp(pos, pitch.position, error_to_control(pitch.axis, pitch.down))
    out, last = np.empty_like(pos), 0.0
    for i in range(pos.size):
        if vel[i] != 0:
            last = up[i] if vel[i] > 0 else down[i]
        out[i] = last
    return out


def test_linuxcnc_commands_equal_the_model(tmp_path):
    m = load_machine("vmc-moving-column")
    errors, rev = grid_errors(m, seed=4)
    export_control("linuxcnc", m, errors, tmp_path / "export", rev)
    pitch = split_errors(m, errors, rev).pitch
    lim = {a.name: a.limits for a in m.axes}
    prog = "G21 G90 G94\nG1 F60000 X0 Y0 Z0\n"
    for a in "XYZ":           # every axis across its whole table, up and down
        lo, hi = lim[a]
        prog += f"G1 {a}{lo:g}\nG1 {a}{hi:g}\nG1 {a}{lo:g}\nG1 {a}0\n"
    prog += "M2\n"
    # the comp files with the exported INI entries ([KINS], [JOINT_n] COMP_FILE, COMP_FILE_TYPE, BACKLASH)
    fragment = (tmp_path / "export" / "linuxcnc-comp.ini").read_text()
    data, log = run_sim(tmp_path / "sim", "XYZ", tmp_path / "export", lim, prog, timeout=150,
                        ini_fragment=fragment)
    ini = (tmp_path / "sim" / "sim.ini").read_text()
    assert ini.count("COMP_FILE_TYPE = 1") == 3 and "KINEMATICS = trivkins coordinates=XYZ" in ini
    assert len(data) > 1000, log[-2000:]
    for j, a in enumerate("XYZ"):
        pos, motor_minus_pos, vel = data[:, j, 0], data[:, j, 1], data[:, j, 2]
        lo, hi = lim[a]
        assert pos.min() < lo + 0.01 and pos.max() > hi - 0.01          # the whole table was run
        assert np.any(vel > 0) and np.any(vel < 0)
        model = _model(pitch[a], pos, vel)
        assert np.ptp(model) > 0.5e-3 and pitch[a].bidirectional      # corrections worth checking
        err = np.abs(motor_minus_pos - model)
        assert err.max() <= 1e-4, (a, err.max(), int(np.argmax(err)))
        # the trims are 32-bit floats in LinuxCNC: far below 0.1 µm
        assert err.max() < 1e-8


def test_linuxcnc_trt_kinematics_pins_equal_the_model(tmp_path):
    """robonano-a0ib on xyzbc-trt-kins with the exported pins (C axis and B axis positions off by
    8.7 to 21 µm): for tool-centre-point moves to the ideal tool points of five poses, the joints
    LinuxCNC commands equal mtcomp's compensated axis commands (kinematics.retarget) to 0.1 µm.
    This LinuxCNC's trt kinematics turns B and C opposite to the machine file's (ISO 841, tool
    relative to workpiece) senses: the program's and joints' B and C are the negated angles."""
    from mtcomp.errors import ErrorSet, GeometricErrors
    from mtcomp.kinematics import forward, retarget
    m = load_machine("robonano-a0ib")
    errors = ErrorSet(geometric=GeometricErrors({}, {"EX0C": 0.0123, "EY0C": -0.0087,
                                                     "EX0B": 0.0211, "EZ0B": -0.0154}))
    export_control("linuxcnc", m, errors, tmp_path / "export")
    hal = (tmp_path / "export" / "linuxcnc-kins.hal").read_text()
    assert "setp xyzbc-trt-kins.x-rot-point 0.012300" in hal
    q = np.array([[0, 0, 10, 5, 20], [30, 0, 10, 5, 20], [0, 20, 10, 5, 20],
                  [45, -30, -20, 8, 10], [-120, 60, 30, -10, -20]], float)      # C B X Y Z
    w = forward(m, q).p                                # the ideal tool points on the workpiece
    prog = "G21 G90 G94\n" + "".join(f"G1 F20000 X{p[0]:.6f} Y{p[1]:.6f} Z{p[2]:.6f} B{-b:g} C{-c:g}\nG4 P0.3\n"
                                     for (c, b, *_), p in zip(q, w)) + "M2\n"
    lim = {a.name: a.limits for a in m.axes}
    data, log = run_sim(tmp_path / "sim", "XYZBC", None, lim, prog, kins="xyzbc-trt-kins", hal=hal, timeout=150)
    pos, vel = data[:, :, 0], data[:, :, 2]
    still = np.all(vel == 0, axis=1)
    ends = np.nonzero(still[:-1] & ~still[1:])[0][1:].tolist() + [len(pos) - 1]
    assert len(ends) == len(q), log[-2000:]
    qc = retarget(m, q, errors)
    expected = np.column_stack([qc[:, 2], qc[:, 3], qc[:, 4], -qc[:, 1], -qc[:, 0]])
    assert np.max(np.abs(qc - q)) > 0.02              # the pins move the joints by up to 24 µm
    assert np.max(np.abs(pos[ends] - expected)) <= 1e-4, (pos[ends] - expected) * 1e3
