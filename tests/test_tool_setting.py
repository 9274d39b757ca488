"""Tool setting errors by grooving (paper 000): plan, virtual grooving, closed forms, estimator."""
from __future__ import annotations

import re

import numpy as np
import pytest

from mtcomp import InputError, MtcompError
from mtcomp.errors import ErrorSet, ToolSetting
from mtcomp.kinematics import forward
from mtcomp.machine import load_machine
from mtcomp.setting import tool_estimate as te
from mtcomp.setting.tool import (GroovingMeasurements, MicroscopeNoise, PlanOptions, cut_grooves, intersection,
                                 load_plan, make_plan, nc_programs, paper_experiment, paper_offset, paper_reproduction, paper_truth,
                                 simulate_grooving, table1_distances)
from mtcomp.setting.tool_plan import groove_top_centre_offset, groove_width, plan_to_toml, sheet_template

M = load_machine("robonano-ui")


def rot(axis, deg):
    """Independent right-hand rotation matrix (written out, not taken from mtcomp)."""
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def edge_shift(angles, t):
    """Shift of the cut edge for the robonano-ui chain Z -> A -> B -> C -> tool."""
    a, b, c = angles
    return rot("x", a) @ rot("y", b) @ rot("z", c) @ np.asarray(t)


@pytest.fixture(scope="module")
def plan():
    return make_plan(M)


# ---------------------------------------------------------------------------------- plan

def test_default_plan_fits_plate_and_lists_each_point_once(plan):
    assert plan.ids == ("C0", "C120", "C240", "A0-1", "A0-2", "A180-1", "A180-2", "B0", "B+10", "B-10")
    for g in plan.grooves:
        for p in (g.start, g.end):
            assert max(abs(p[0]), abs(p[1])) <= 10.0
    feats = plan.features()
    # the A grooves share their start point: measured once per orientation
    assert ("A0-2", "start") not in feats and ("A180-2", "start") not in feats
    assert len(feats) == 2 * len(plan.grooves) - 2
    # the triangle closes nominally and is equilateral
    c = [g for g in plan.grooves if g.test == "C"]
    assert np.allclose(c[-1].end, c[0].start, atol=1e-9)
    assert np.allclose([np.hypot(*np.subtract(g.end, g.start)) for g in c], 6.0)


def test_plan_too_big_for_plate_is_rejected():
    with pytest.raises(InputError, match="outside the 20 x 20 mm plate"):
        make_plan(M, PlanOptions(length=15.0))
    with pytest.raises(InputError, match="tip angle"):
        PlanOptions(tip_angle=180.0)


def test_plan_needs_tool_side_rotary_axes():
    with pytest.raises(MtcompError, match="tool side"):
        make_plan("robonano-a0ib", PlanOptions(tests=("B", "C")))


def test_plan_toml_round_trip(plan, tmp_path):
    p = tmp_path / "plan.toml"
    p.write_text(plan_to_toml(plan))
    back = load_plan(p)
    assert back.grooves == plan.grooves and back.machine == plan.machine
    assert sheet_template(back) == sheet_template(plan)


@pytest.mark.parametrize("line,match", [
    ('depth_mm = "x"', r"\[plan.depth_mm\]: expected a number, got 'x'"),
    ("depth_mm = -0.1", r"\[plan.depth_mm\]: expected a positive number"),
    ("tip_angle_deg = 200.0", r"\[plan.tip_angle_deg\]: tip angle"),
    ("plate_mm = [20.0]", r"\[plan.plate_mm\]: expected two positive sizes"),
])
def test_plan_toml_bad_head_names_the_key(plan, tmp_path, line, match):
    key = line.split(" =")[0]
    text = plan_to_toml(plan)
    head, rest = text.split("[[face]]", 1)
    head = re.sub(rf"(?ms)^{key} = (\[.*?\]|[^\n]*)$", line, head)
    p = tmp_path / "plan.toml"
    p.write_text(head + "[[face]]" + rest)
    with pytest.raises(InputError, match=match):
        load_plan(p)


def test_nc_program_cuts_the_programmed_grooves(plan):
    """Parse the NC words back and run them through the forward model: G01 cut blocks put the
    nominal edge at the groove points at depth D on the face."""
    progs = nc_programs(M, plan)
    assert set(progs) == {"A", "B", "C"}
    for test, text in progs.items():
        cuts = [ln for ln in text.splitlines() if ln.startswith("G01") and "(cut)" in ln]
        grooves = [g for g in plan.grooves if g.test == test]
        assert len(cuts) == len(grooves)
        for ln, g in zip(cuts, grooves):
            q = [float(re.search(rf"\b{a}(-?\d+\.\d+)", ln).group(1)) for a in M.axis_names]
            p = forward(M, np.array([q])).p[0]
            face = plan.face_of(g)
            assert np.allclose(face.coords(p[None])[0], (*g.end, g.depth), atol=1e-6)


def test_groove_width():
    assert groove_width(0.1, 90.0) == pytest.approx(0.2)
    assert groove_width(0.1, 60.0) == pytest.approx(2 * 0.1 * np.tan(np.radians(30)))
    # tilting the V widens the groove: tan(45+10) + tan(45-10)
    assert groove_width(0.1, 90.0, 10.0) == pytest.approx(0.1 * (np.tan(np.radians(55)) + np.tan(np.radians(35))))
    assert groove_top_centre_offset(0.1, 90.0) == 0.0
    # top edges of a V tilted by 10 deg: at d tan(55) and -d tan(35) from the bottom line
    assert groove_top_centre_offset(0.1, 90.0, 10.0) == pytest.approx(
        (0.1 * np.tan(np.radians(55)) - 0.1 * np.tan(np.radians(35))) / 2)


# ---------------------------------------------------------------------------------- virtual grooving

def test_virtual_grooves_match_an_independent_rigid_model(plan):
    t = np.array([0.3, -0.2, 0.15])
    cuts = cut_grooves(M, plan, ToolSetting(tuple(t)))
    ref_depth = {}
    for c in cuts:
        g = c.groove
        face = plan.face_of(g)
        shift = face.basis @ edge_shift(g.angles, t)
        assert np.allclose(c.start, np.add(g.start, shift[:2]), atol=1e-12)
        assert np.allclose(c.end, np.add(g.end, shift[:2]), atol=1e-12)
        ref_depth.setdefault(g.test, shift[2])
        assert c.depth == pytest.approx(g.depth + shift[2] - ref_depth[g.test], abs=1e-12)
    b = {c.groove.id: c for c in cuts}
    th = np.radians(10)
    assert b["B+10"].depth == pytest.approx(0.1 + np.sin(th) * t[0] + (1 - np.cos(th)) * t[2], abs=1e-12)
    assert b["B+10"].tilt == pytest.approx(10.0) and b["B-10"].tilt == pytest.approx(-10.0)
    assert b["B0"].width == pytest.approx(0.2)


def test_a_patterns_intersect_where_shifted_lines_cross(plan):
    # A = 180 moves the L shape by (-2 t_y, 2 t_x): with t_x, t_y < 0 its corner lies inside the
    # A = 0 L shape, so the horizontal A0-1 crosses the vertical A180-2 there
    cuts = {c.groove.id: c for c in cut_grooves(M, plan, (-0.3, -0.2, 0.0))}
    x = intersection(cuts["A0-1"], cuts["A180-2"])
    assert x is not None
    assert x == pytest.approx((cuts["A180-2"].start[0], cuts["A0-1"].start[1]))
    assert intersection(cuts["A0-1"], cuts["A180-1"]) is None   # parallel


def test_uncut_groove_is_reported(plan):
    shallow = make_plan(M, PlanOptions(depth=0.01))
    with pytest.raises(MtcompError, match="would not be cut"):
        simulate_grooving(M, (-0.5, 0.0, 0.0), plan=shallow, seed=1)


# ---------------------------------------------------------------------------------- closed forms

@pytest.mark.parametrize("tx,tz", [(0.34, 0.2), (-0.12, 0.45), (0.05, -0.3)])
def test_paper_eq2_misprint(tx, tz):
    """Depths from the forward model; printed eq. (1) recovers Delta X = -t_x, printed eq. (2)
    does not recover Delta Z = -t_z, the derived eq. (2) does exactly."""
    plan = make_plan(M, PlanOptions(tests=("B",), b_angles=(0.0, 15.0, -25.0), depth=0.5))
    cuts = {c.groove.id: c for c in cut_grooves(M, plan, (tx, 0.07, tz))}
    D = cuts["B0"].depth                       # theta_1 = 0: the reference, = depth of cut
    d1, d2 = cuts["B+15"].depth, cuts["B-25"].depth
    assert te.paper_eq1_dx(15.0, -25.0, d1, d2, D) == pytest.approx(-tx, abs=1e-12)
    assert te.paper_eq2_dz_derived(15.0, -25.0, d1, d2, D) == pytest.approx(-tz, abs=1e-12)
    printed = te.paper_eq2_dz_printed(15.0, -25.0, d1, d2, D)
    assert abs(printed - (-tz)) > 0.05 * abs(tz) + 0.01
    # our own sign convention
    assert te.b_depth_closed_form(15.0, -25.0, D, d1, d2) == pytest.approx((tx, tz), abs=1e-12)
    w2 = cuts["B+15"].start[0] - plan.groove("B+15").start[0] - (cuts["B0"].start[0] - plan.groove("B0").start[0])
    w3 = cuts["B-25"].start[0] - plan.groove("B-25").start[0] - (cuts["B0"].start[0] - plan.groove("B0").start[0])
    assert te.b_position_closed_form(15.0, -25.0, w2, w3) == pytest.approx((tx, tz), abs=1e-12)


def test_closed_forms_recover_noise_free_offset(plan):
    t = (0.21, -0.37, 0.12)
    meas = simulate_grooving(M, t, plan=plan, noise=MicroscopeNoise(0.0, 0.0), seed=1, frame_offset=0.4)
    cf = te.closed_forms(meas)
    assert cf["A"] == pytest.approx(t[:2], abs=1e-12)
    assert cf["C"] == pytest.approx(t[:2], abs=1e-12)
    assert cf["B_depth"] == pytest.approx((t[0], t[2]), abs=1e-12)
    assert cf["B_position"] == pytest.approx((t[0], t[2]), abs=1e-9)


def test_depth_closed_form_sigma_matches_monte_carlo():
    rng = np.random.default_rng(5)
    d = 0.1 + rng.normal(0, 1e-4, (4000, 3))
    tx, tz = te.b_depth_closed_form(10.0, -10.0, d[:, 0], d[:, 1], d[:, 2])
    sx, sz = te.b_depth_closed_form_sigma(10.0, -10.0, 1e-4)
    assert np.std(tz) == pytest.approx(sz, rel=0.05)
    assert np.std(tx) == pytest.approx(sx, rel=0.05)
    # the field-note figure: about 8 um at +-10 deg with 0.1 um depth noise, 0.4 um at +-45 deg
    assert sz * 1e3 == pytest.approx(8.06, abs=0.05)
    assert te.b_depth_closed_form_sigma(45.0, -45.0, 1e-4)[1] * 1e3 == pytest.approx(0.42, abs=0.01)


# ---------------------------------------------------------------------------------- least squares

def test_least_squares_exact_without_noise(plan):
    t = (-0.61, 0.83, -0.44)
    meas = simulate_grooving(M, t, plan=make_plan(M, PlanOptions(depth=0.3)), noise=MicroscopeNoise(0, 0), seed=2,
                             frame_offset=0.5)
    est = te.estimate(M, meas)
    assert est.offset == pytest.approx(t, abs=1e-9)
    assert np.max(np.abs(est.residuals)) < 1e-9


def _coverage(n, seed0):
    plan = make_plan(M, PlanOptions(depth=0.3))
    rng = np.random.default_rng(seed0)
    inside, d2 = 0, []
    for k in range(n):
        t = rng.uniform(-1.0, 1.0, 3)
        meas = simulate_grooving(M, t, MicroscopeNoise(0.001, 0.001), seed0 + 1 + k, plan=plan, frame_offset=0.5)
        est = te.estimate(M, meas, closed=False)
        inside += bool(np.all(np.abs(est.offset - t) <= 3 * est.sigma))
        d2.append(est.mahalanobis2(t))
    return inside / n, np.array(d2)


def test_injected_and_recovered_quick():
    rate, d2 = _coverage(150, 100)
    assert rate >= 0.97
    assert np.mean(d2) == pytest.approx(3.0, rel=0.25)


@pytest.mark.slow
def test_injected_and_recovered_1000_trials():
    """Acceptance: 1,000 seeded trials, true offsets up to 1 mm, 1 um noise: all three components
    within 3 sigma (reported covariance) in >= 99 %; the Mahalanobis distance is chi2(3)."""
    from scipy import stats
    rate, d2 = _coverage(1000, 20260)
    assert rate >= 0.99
    assert np.mean(d2 <= stats.chi2.ppf(0.99, 3)) >= 0.98
    assert np.mean(d2) == pytest.approx(3.0, rel=0.1)


def test_positions_beat_depths_by_5x_at_10_deg(plan):
    """Acceptance: B at +-10 deg, 1 um microscope noise: the least-squares sigma of t_z using
    the lateral positions is >= 5x smaller than the closed form's from depths alone."""
    meas = simulate_grooving(M, (0.1, 0.1, 0.1), plan=plan, noise=MicroscopeNoise(0.001, 0.001), seed=3)
    est = te.estimate(M, meas)
    # the closed form gets the same data: mean of start and end depth per groove
    closed = te.b_depth_closed_form_sigma(10.0, -10.0, 0.001 / np.sqrt(2))[1]
    assert closed / est.sigma[2] >= 5.0
    # without the B grooves' lateral positions, the fit is left with the depths (and warns)
    b_depth_only = [p if meas.plan.groove(p.groove).test != "B" else
                    type(p)(p.groove, p.feature, np.nan, np.nan, p.depth) for p in meas.points]
    est_d = te.estimate(M, GroovingMeasurements(meas.plan, tuple(b_depth_only), 0.001, 0.001))
    assert est_d.sigma[2] > 5 * est.sigma[2]
    assert any("t_z" in w and "second order" in w for w in est_d.warnings)
    assert not est.warnings


def test_covariance_matches_monte_carlo_scatter(plan):
    t = np.array([0.2, -0.1, 0.3])
    ests = []
    for k in range(300):
        meas = simulate_grooving(M, t, plan=plan, noise=MicroscopeNoise(0.001, 0.0002), seed=900 + k)
        ests.append(te.estimate(M, meas, closed=False))
    scatter = np.std([e.offset for e in ests], axis=0)
    assert scatter == pytest.approx(ests[0].sigma, rel=0.15)


def test_singular_geometry_names_the_component():
    plan = make_plan(M, PlanOptions(tests=("C", "A")))
    meas = simulate_grooving(M, (0.1, 0.2, 0.3), plan=plan, seed=1)
    with pytest.raises(InputError, match="singular geometry.*t_z"):
        te.estimate(M, meas)


def test_suggested_groove_predicts_the_covariance_it_gives(plan):
    meas = simulate_grooving(M, (0.1, 0.2, 0.1), plan=plan, seed=4)
    best = te.suggest_grooves(M, meas, top=1)[0]
    assert abs(best.groove.angles[1]) == 30.0          # the steepest feasible inclination: flanks 15 deg off the surface
    est0 = te.estimate(M, meas)
    assert best.sigma[2] < 0.5 * est0.sigma[2]
    # cut and measure the suggested groove: the realised covariance is the predicted one
    g = best.groove
    from dataclasses import replace
    plan2 = type(plan)(plan.machine, plan.options, plan.grooves + (replace(g, id="Bx"),), plan.faces)
    est2 = te.estimate(M, simulate_grooving(M, (0.1, 0.2, 0.1), plan=plan2, seed=4))
    assert est2.sigma == pytest.approx(best.sigma, rel=1e-9)


# ---------------------------------------------------------------------------------- compensation

def test_paper_table1_distances_and_compensation(plan):
    # the tool offset alone gives the A distances but not the C ones (one offset, both tests)
    before = table1_distances(plan, cut_grooves(M, plan, paper_offset()))
    assert before["A"] == pytest.approx((0.49004, 0.68012), abs=1e-9)
    assert before["C"] == pytest.approx((0.29790, 0.66203), abs=1e-5)
    # exact compensation leaves only the 1 nm command rounding
    exact = table1_distances(plan, cut_grooves(M, plan, paper_offset(), compensation=ErrorSet(
        tool=ToolSetting(paper_offset()))))
    assert max(max(v) for v in exact.values()) < 3e-6
    truth = table1_distances(plan, cut_grooves(M, plan, paper_truth(M, plan)))
    for seed in range(3):
        est, b, after = paper_experiment(M, noise=MicroscopeNoise(0.001, 0.001), seed=seed)
        assert max(max(v) for v in after.values()) < 0.005
        assert b == truth


def test_paper_table1_all_four_distances_from_one_fitted_model(plan):
    """Issue 17: the four original distances of paper 000's Table 1 from one set of errors (tool
    offset + C axis location), the fitted model predicts them to a few µm, and compensation brings
    all four below 5 µm; the tool-offset-only fit (the old method) leaves ~40-150 µm."""
    truth = paper_truth(M, plan)
    assert truth.geometric.location["EX0C"] == pytest.approx(0.0394, abs=2e-4)
    assert truth.geometric.location["EY0C"] == pytest.approx(-0.1499, abs=2e-4)
    r = paper_reproduction(M, seed=1, plan=plan)
    for label, orig, paper, fitted, comp, _, tonly in r.rows():
        assert orig == pytest.approx(paper, abs=1e-3), label      # µm: the hidden truth meets the Table
        assert fitted == pytest.approx(paper, abs=5.0), label
        assert comp < 5.0, label
    assert max(row[6] for row in r.rows()) > 30.0
    assert "assumed" in r.summary() and "microscope" in r.summary()
    # the setting error against C is the edge relative to the (offset) C axis line
    cx, cy = truth.geometric.location["EX0C"], truth.geometric.location["EY0C"]
    names, val, cov = r.estimate.against["C"]
    assert names == ("dx", "dy")
    assert val == pytest.approx(np.array(paper_offset()[:2]) - (cx, cy), abs=5 * np.sqrt(np.max(np.diag(cov))))
    names, val, cov = r.estimate.against["A"]
    assert val == pytest.approx(paper_offset()[:2], abs=5 * np.sqrt(np.max(np.diag(cov))))


def test_plan_observability_names_the_gauge(plan):
    from mtcomp.setting.tool_model import observable_parameters
    obs = observable_parameters(M, plan)
    assert obs.estimated == ("t_x", "t_y", "t_z", "EX0C", "EY0C", "EZ0A")
    assert set(obs.unobservable) == {"EY0A", "EX0B", "EZ0B"}
    assert "t_y + EY0C + EY0A" in obs.unobservable["EY0A"] and "rigid shift" in obs.unobservable["EY0A"]
    # without the C test, the C axis location cannot be seen at all
    obs_ab = observable_parameters(M, make_plan(M, PlanOptions(tests=("A", "B"))))
    assert "EX0C" in obs_ab.unobservable and "EY0C" in obs_ab.unobservable
    assert obs_ab.unobservable["EX0C"] == "no groove of the plan moves with it"
    with pytest.raises(InputError, match="EX0C"):
        te.estimate(M, simulate_grooving(M, (0.1, 0.1, 0.1), plan=make_plan(M, PlanOptions(tests=("A", "B"))),
                                         seed=1), locations=("EX0C",))


def _centre_trials(n, seed):
    plan = make_plan(M, PlanOptions(depth=0.3))
    rng = np.random.default_rng(seed)
    inside, d2 = [], []
    for k in range(n):
        t = rng.uniform(-0.5, 0.5, 3)
        loc = dict(zip(("EX0C", "EY0C", "EZ0A"), rng.uniform(-0.2, 0.2, 3)))
        from mtcomp.errors import GeometricErrors
        truth = ErrorSet(tool=ToolSetting(tuple(t)), geometric=GeometricErrors(location=loc))
        est = te.estimate(M, simulate_grooving(M, truth, MicroscopeNoise(0.001, 0.001), seed + 1 + k, plan=plan,
                                               frame_offset=0.5), closed=False)
        true = np.concatenate([t, [loc[n_] for n_ in est.parameters[3:]]])
        z = np.abs(est.values - true) / np.sqrt(np.diag(est.param_cov))
        inside.append(np.all(z <= 3))
        d2.append(est.mahalanobis2_all(true))
    return float(np.mean(inside)), np.array(d2)


def test_tool_offset_and_rotary_centres_recovered_within_3_sigma():
    """Issue 17 acceptance (a modest number of trials; benchmarks/tool_setting_mc.py runs more):
    injected t and C/A centre offsets recovered, every parameter within 3 sigma, in >= 95 %."""
    rate, d2 = _centre_trials(200, 1717)
    assert rate >= 0.95
    assert np.mean(d2) == pytest.approx(6.0, rel=0.3)           # chi2 with 6 dof


def test_report_and_errors_file(plan, tmp_path):
    from mtcomp.errors import load_errors
    meas = simulate_grooving(M, paper_offset(), plan=plan, seed=7)
    est = te.estimate(M, meas)
    path = te.write_errors(est, tmp_path / "errors.toml")
    assert load_errors(path).tool.offset == pytest.approx(est.offset, abs=1e-15)
    text = te.report_text(M, meas, est)
    assert "t_z" in text and "±" in text and "after compensation" in text and "against C" in text
    assert " um" not in text
    te.plot_report(M, meas, est, tmp_path / "r.png")
    assert (tmp_path / "r.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# ---------------------------------------------------------------------------------- properties

from hypothesis import given, settings, strategies as st  # noqa: E402


@settings(max_examples=60, deadline=None)
@given(th2=st.floats(3, 60), th3=st.floats(-60, -3), tx=st.floats(-1, 1), tz=st.floats(-1, 1))
def test_depth_closed_forms_invert_the_rigid_model(th2, th3, tx, tz):
    """Derived forms invert d(theta) - d(0) = sin(theta) t_x + (1 - cos theta) t_z for any angles."""
    d = lambda th: 0.1 + np.sin(np.radians(th)) * tx + (1 - np.cos(np.radians(th))) * tz  # noqa: E731
    assert te.b_depth_closed_form(th2, th3, d(0), d(th2), d(th3)) == pytest.approx((tx, tz), abs=1e-9)
    assert te.paper_eq2_dz_derived(th2, th3, d(th2), d(th3), d(0)) == pytest.approx(-tz, abs=1e-9)
    assert te.paper_eq1_dx(th2, th3, d(th2), d(th3), d(0)) == pytest.approx(-tx, abs=1e-9)


@settings(max_examples=25, deadline=None)
@given(t=st.tuples(*[st.floats(-1, 1)] * 3), c=st.floats(1, 179))
def test_c_closed_form_any_angle_pair(t, c):
    def rz(a):
        a = np.radians(a)
        return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    gap = (rz(c) - rz(0)) @ np.asarray(t[:2])
    assert te.c_closed_form(0.0, c, gap) == pytest.approx(t[:2], abs=1e-9)


# ---------------------------------------------------------------------------------- microscope frame

def test_fit_rotation_removes_a_turned_microscope_frame(plan):
    t = (0.34, 0.245, 0.2)
    meas0 = simulate_grooving(M, t, MicroscopeNoise(0.0, 0.0), 3, plan=plan, frame_offset=0.5, frame_rotation=0.2)
    exact = te.estimate(M, meas0, fit_rotation=True)
    assert exact.offset == pytest.approx(t, abs=1e-10)
    assert all(abs(v) <= np.radians(0.2) for k, v in exact.nuisance.items() if k.endswith(":rot"))
    # with 1 um noise: without the rotation fit the estimate is biased and the misfit is flagged
    hits, flagged = 0, 0
    for seed in range(20):
        meas = simulate_grooving(M, t, MicroscopeNoise(0.001, 0.001), seed, plan=plan, frame_rotation=0.1)
        est = te.estimate(M, meas, fit_rotation=True)
        hits += est.mahalanobis2(t) <= 11.34
        flagged += any("exceed the stated noise" in w for w in te.estimate(M, meas).warnings)
    assert hits >= 19 and flagged >= 15
    assert "microscope frame rotation" in est.summary()


@settings(max_examples=10, deadline=None)
@given(b=st.lists(st.floats(-40, 40).filter(lambda x: abs(x) > 1), min_size=1, max_size=4, unique=True),
       c=st.lists(st.sampled_from([0.0, 60.0, 90.0, 150.0, 200.0, 270.0]), min_size=2, max_size=4, unique=True),
       t=st.tuples(*[st.floats(-0.5, 0.5)] * 3))
def test_least_squares_any_angles_exact(b, c, t):
    """Any number of B inclinations and C angles (open polygons too): noise-free data give t exactly."""
    opts = PlanOptions(tests=("B", "C"), b_angles=(0.0, *b), c_angles=tuple(c), depth=0.5, triangle_side=3.0,
                       spacing=0.5, c_centre=(-5.0, 0.0), b_origin=(1.0, -2.0))
    plan = make_plan(M, opts)
    meas = simulate_grooving(M, t, MicroscopeNoise(0.0, 0.0), 1, plan=plan, frame_offset=0.2)
    est = te.estimate(M, meas)
    assert est.offset == pytest.approx(t, abs=1e-9)


def test_known_axis_location_errors_are_included(plan):
    """A C axis off the common centre (EX0C, EY0C) makes the A and C tests disagree, as in the
    paper's Table 1; a tool-offset-only fit sees the misfit, the default fit estimates EX0C and
    EY0C with the offset, and with the location errors known the offset is recovered exactly."""
    from mtcomp.errors import GeometricErrors
    t = (0.34, 0.245, 0.2)
    geo = GeometricErrors(location={"EX0C": 0.04, "EY0C": -0.03})
    true = ErrorSet(tool=ToolSetting(t), geometric=geo)
    meas = simulate_grooving(M, true, MicroscopeNoise(0.0, 0.0), 1, plan=plan)
    blind = te.estimate(M, meas, locations=())
    assert np.max(np.abs(blind.residuals)) > 0.01         # the tests disagree by tens of um
    cf = blind.closed
    assert abs(cf["A"][0] - cf["C"][0]) > 0.01 or abs(cf["A"][1] - cf["C"][1]) > 0.01
    full = te.estimate(M, meas)
    assert full.parameters == ("t_x", "t_y", "t_z", "EX0C", "EY0C", "EZ0A")
    assert full.offset == pytest.approx(t, abs=1e-10)
    assert full.location == pytest.approx({"EX0C": 0.04, "EY0C": -0.03, "EZ0A": 0.0}, abs=1e-10)
    aware = te.estimate(M, meas, known=ErrorSet(geometric=geo), locations=())
    assert aware.offset == pytest.approx(t, abs=1e-10)
    assert np.max(np.abs(aware.residuals)) < 1e-10
    # compensating tool offset and location errors together leaves no groove distance
    after = table1_distances(plan, cut_grooves(M, plan, true, compensation=aware.errors(ErrorSet(geometric=geo))))
    assert max(max(v) for v in after.values()) < 3e-6


def test_microscope_scale_error_is_seen_and_estimated(plan):
    """Issue 17: a microscope magnification error of 0.3 % biases the fit (misfit warning); with
    fit_scale it is estimated per test and t, EX0C, EY0C come back within 3 sigma."""
    from mtcomp.errors import GeometricErrors
    truth = ErrorSet(tool=ToolSetting((0.34, 0.245, 0.2)), geometric=GeometricErrors(location={"EX0C": 0.04}))
    meas = simulate_grooving(M, truth, MicroscopeNoise(0.0005, 0.0005), 5, plan=plan, frame_scale=0.003)
    plain = te.estimate(M, meas)
    assert any("residuals exceed" in w for w in plain.warnings)
    est = te.estimate(M, meas, fit_scale=True)
    assert not est.warnings
    for t in ("A", "B", "C"):
        k, sk = est.nuisance[f"{t}:scale"], est.nuisance_sigma[f"{t}:scale"]
        assert abs(k - 0.003) < 3 * sk and sk < 0.001
    true = np.array([0.34, 0.245, 0.2, 0.04, 0.0, 0.0])
    assert np.all(np.abs(est.values - true) <= 3 * np.sqrt(np.diag(est.param_cov)))
    assert "ppm" in est.summary()
