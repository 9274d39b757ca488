"""Virtual machining check: paper 001's pyramid program compensated for a workpiece setting
error and run through the forward model with that error (acceptance), the uncompensated run,
an injected translation recovered in the widths, and the form error of the ball envelope."""
import math

import numpy as np
import pytest

from mtcomp import gcode
from mtcomp.cad_plugin import check as C, post as P, toolpath as T
from mtcomp.cad_plugin.layout import pyramid_height
from mtcomp.errors import ErrorSet, WorkpieceSetting
from mtcomp.machine import load_machine

W, ANGLE = 3.45, 164.81
H = pyramid_height(W, ANGLE)
BETA = math.radians((180 - ANGLE) / 2)


@pytest.fixture(scope="module")
def program():
    m = load_machine("robonano-a0ib")        # paper 001's machine class
    tp = T.pyramid_finishing(W, ANGLE, T.Tool("ball", 0.5), stepover=0.1, step=0.05)
    return m, tp


def test_compensated_pyramid_meets_paper_001_targets(program, tmp_path):
    m, tp = program
    # A robot-loaded blank: tens of um off and tilted by tenths of a degree.
    err = ErrorSet(workpiece=WorkpieceSetting((0.035, -0.020, 0.015), (0.12, -0.25, 0.8)))
    text = P.post(m, tp, errors=err)
    q = gcode.parse(text, axes=m.axis_names).position      # what the control would run
    meas = C.pyramid_widths_angles(m, tp, q, err)
    assert np.max(np.abs(meas.widths - W)) < 0.01e-3      # 3450 +- 0.01 um
    assert np.max(np.abs(meas.angles - ANGLE)) < 0.001
    target = C.pyramid_surface(W, H)
    form = C.form_error(m, tp, q, err, target, W / 2 + 0.2, grid=0.02)
    # The compensated part is the part the ideal machine would cut (scallops and the fillet in
    # the base corner included), to the command resolution.
    q0 = T.to_axes(m, tp)
    ideal = C.form_error(m, tp, q0, None, target, W / 2 + 0.2, grid=0.02)
    assert np.nanmax(np.abs(form.error - ideal.error)) < 5e-6
    # Uncompensated, the same error set gives grossly wrong widths, and it is reported.
    bad = C.pyramid_widths_angles(m, tp, q0, err)
    assert np.max(np.abs(bad.widths - W)) > 0.05
    assert "width error max" in bad.summary(W, ANGLE)
    bad_form = C.form_error(m, tp, q0, err, target, W / 2 + 0.2, grid=0.02)
    assert bad_form.rms > 0.010 > 0.002 > form.rms
    C.plot_check(tp, bad_form, tmp_path / "check.png")
    assert (tmp_path / "check.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_injected_height_offset_is_recovered_in_the_widths(program):
    m, tp = program
    q = T.to_axes(m, tp)
    dz = 0.004  # real blank 4 um higher: x_nominal = x_real + (0, 0, dz)
    meas = C.pyramid_widths_angles(m, tp, q, ErrorSet(workpiece=WorkpieceSetting((0, 0, dz))))
    # The program cuts dz too deep in the real frame: each slope moves down by dz, each base
    # edge inwards by dz / tan(beta).
    assert meas.widths == pytest.approx(np.full(4, W - 2 * dz / math.tan(BETA)), abs=1e-10)
    assert meas.angles == pytest.approx([ANGLE, ANGLE], abs=1e-9)


def test_nominal_envelope_never_gouges_and_scallops_as_predicted(program):
    m, tp = program
    form = C.form_error(m, tp, T.to_axes(m, tp), None, C.pyramid_surface(W, H), W / 2 + 0.2,
                        grid=0.02)
    # Every ball touches the surface and the moves between them stay within the toolpath
    # tolerance (1e-5 mm, chords over the ridges) of the offset surface.
    assert form.min > -1e-5
    X, Y = np.meshgrid(form.x, form.y)
    r, s = 0.5, tp.meta["stepover"]
    # On the slopes' interior (away from ridges and base) the error is the scallop between
    # passes: at most (s cos)^2 / 8r on a slope climbing across the passes, s^2 / 8r on one
    # climbing along them (the cutter is swept along the moves).
    a, b = np.abs(X), np.abs(Y)
    interior = (np.maximum(a, b) < W / 2 - 0.1) & (np.abs(a - b) > 0.1) & (np.maximum(a, b) > 0.1)
    e = form.error[interior]
    assert np.nanmax(e) <= s * s / (8 * r) * 1.01 + 1e-5
    assert np.nanmax(e) > 0.5 * s * s / (8 * r)  # the scallops are resolved by the grid
    # In the concave corner along the base the ball leaves a fillet, r (1/cos(beta/2) - 1)
    # high over the edge (about 1.1 um here), plus the scallop of the passes.
    fillet = r * (1 / math.cos(BETA / 2) - 1)
    edge = (np.abs(a - W / 2) < 0.03) & (b < 0.5)
    assert fillet <= np.nanmax(form.error[edge]) <= fillet + s * s / (8 * r) * 1.01


def test_virtual_probing_recovers_the_real_bowl_centres():
    from mtcomp.cad_plugin.layout import BowlBlankLayout
    from mtcomp.setting.bowls import fit_sphere
    m = load_machine("robonano-a0ib")
    L = BowlBlankLayout()
    probe = T.Tool("probe", radius=0.25)
    tp = T.bowl_probing(L.centres, L.bowl_radius, L.bowl_depth, probe, overtravel=0.1)
    ws = WorkpieceSetting((0.030, -0.025, 0.012), (0.1, -0.15, 0.4))
    run = C.simulate_probing(m, tp, T.to_axes(m, tp), ErrorSet(workpiece=ws))
    assert np.all(np.isfinite(run.fraction)) and np.ptp(run.fraction) > 0
    Rw, t = ws.matrix, np.asarray(ws.translation)
    for k, (cx, cy) in enumerate(L.centres):
        centre, rho, *_ = fit_sphere(run.recorded[run.bowl == k])
        # x_nominal = R x_real + t: the control sees the real bowl's centre there.
        expected = Rw @ np.array([cx, cy, L.bowl_radius - L.bowl_depth]) + t
        assert np.max(np.abs(centre - expected)) < 1e-9
        assert rho == pytest.approx(L.bowl_radius - probe.radius, abs=1e-9)
    # On the ideal set-up every skip happens at the nominal contact, 2/3 along the move.
    ideal = C.simulate_probing(m, tp, T.to_axes(m, tp), None)
    assert np.allclose(ideal.fraction, 0.2 / 0.3, rtol=0, atol=1e-12)
    assert np.allclose(ideal.recorded, T.probe_contacts(tp), rtol=0, atol=1e-12)


def test_paper_001_loop_probe_fit_compensate_machine(program):
    """Probe the bowls of a misplaced blank, estimate its setting from the sphere centres
    (the workpiece-setting module), compensate the finishing program, machine virtually."""
    from mtcomp.cad_plugin.layout import BowlBlankLayout
    from mtcomp.setting.bowls import fit_sphere
    from mtcomp.setting.frame import frame_from_points
    m, tp = program
    L = BowlBlankLayout()
    true = ErrorSet(workpiece=WorkpieceSetting((-0.042, 0.018, 0.021), (-0.15, 0.2, -0.6)))
    probe = T.Tool("probe", radius=0.25)
    pp = T.bowl_probing(L.centres, L.bowl_radius, L.bowl_depth, probe)
    run = C.simulate_probing(m, pp, T.to_axes(m, pp), true)
    measured = np.array([fit_sphere(run.recorded[run.bowl == k])[0] for k in range(3)])
    design = np.array([[x, y, L.bowl_radius - L.bowl_depth] for x, y in L.centres])
    est = frame_from_points(measured, design, method="paper").pose
    assert np.allclose(est.translation, true.workpiece.translation, rtol=0, atol=1e-9)
    assert np.allclose(est.angles, true.workpiece.angles, rtol=0, atol=1e-8)
    text = P.post(m, tp, errors=ErrorSet(workpiece=est))
    q = gcode.parse(text, axes=m.axis_names).position
    meas = C.pyramid_widths_angles(m, tp, q, true)
    assert np.max(np.abs(meas.widths - W)) < 0.01e-3
    assert np.max(np.abs(meas.angles - ANGLE)) < 0.001


def test_bowl_blank_layout_is_the_workpiece_settings_default_plan():
    """The CAD blank and the probing/fit side (mtcomp.setting.workpiece, used by the cell) must
    describe the same blank: same bowls, blank size, ball radius and depth."""
    from mtcomp.cad_plugin.layout import BowlBlankLayout
    from mtcomp.setting.workpiece import plan_bowls
    L, plan = BowlBlankLayout(), plan_bowls(3)
    assert [(b.x, b.y) for b in plan.bowls] == [tuple(c) for c in L.centres]
    assert plan.blank == (L.size, L.size, L.thickness)
    assert (plan.tool_radius, plan.depth) == (L.bowl_radius, L.bowl_depth)
