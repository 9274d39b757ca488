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
    data, log = run_sim(tmp_path / "sim", "XYZ", tmp_path / "export", lim, prog, timeout=150)
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
