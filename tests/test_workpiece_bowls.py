"""Bowl plan, NC programs, touches CSV, virtual probing and sphere fits (paper 001)."""
import math
import re

import numpy as np
import pytest

from mtcomp import InputError, MtcompError
from mtcomp.errors import WorkpieceSetting
from mtcomp.setting.bowls import (Touches, fit_bowls, fit_sphere, load_plan, plan_bowls,
                                  probing_program, read_touches, roughing_program, save_plan,
                                  touch_moves, virtual_probe, write_touches)

POSE = WorkpieceSetting((0.012, -0.021, 0.033), (0.03, -0.02, 0.25))


def test_default_plan_geometry():
    plan = plan_bowls(3)
    np.testing.assert_allclose(plan.centres, [[-7, -7, 1], [7, -7, 1], [-7, 7, 1]])
    assert plan.probe_sphere_radius == 1.5
    assert plan.opening_radius == pytest.approx(math.sqrt(3))
    assert plan.rim_polar_angle == pytest.approx(60.0)
    d = plan.dirs
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    polar = np.degrees(np.arccos(-d[:, 2]))
    assert polar.max() < plan.rim_polar_angle - 5               # every contact below the rim
    assert len(d) == 9 and np.sum(polar < 1e-9) == 1
    assert len(plan_bowls(6).bowls) == 6


@pytest.mark.parametrize("kw,match", [
    (dict(n=2), "at least 3 bowls"),
    (dict(depth=2.5), "depth must be in"),
    (dict(probe_radius=1.9), "probe radius"),
    (dict(positions=[(-7, -7), (-6, -7), (-7, 7)]), "overlap"),
    (dict(positions=[(-9.5, -7), (7, -7), (-7, 7)]), "runs off"),
    (dict(positions=[(-1, -7), (7, -7), (-7, 7)], keepout_radius=6.0), "part region"),
])
def test_plan_refuses_impossible_geometry(kw, match):
    with pytest.raises(InputError, match=match):
        plan_bowls(**kw)


def test_plan_file_round_trip(tmp_path):
    plan = plan_bowls(4, probe_radius=0.3, touches=11)
    save_plan(plan, tmp_path / "p.toml")
    back = load_plan(tmp_path / "p.toml")
    assert back == plan


@pytest.mark.parametrize("key,value,field", [("depth", "-1.0", "depth"), ("depth", "2.5", "depth"),
                                             ("tool_radius", "0.0", "tool_radius"),
                                             ("blank", "[20.0, 20.0]", "blank")])
def test_plan_file_with_impossible_geometry_names_the_field(tmp_path, key, value, field):
    path = save_plan(plan_bowls(3), tmp_path / "p.toml")
    text = re.sub(rf"(?m)^{key} = .*$", f"{key} = {value}", path.read_text())
    if key == "blank":   # written over several lines: replace the whole array
        text = re.sub(r"(?ms)^blank = \[.*?\]", f"blank = {value}", path.read_text())
    path.write_text(text)
    with pytest.raises(InputError, match=rf"p.toml \[{field}\]: "):
        load_plan(path)


def test_roughing_program_plunges_each_bowl_to_depth():
    plan = plan_bowls(3)
    text = roughing_program(plan)
    for b in plan.bowls:
        assert f"G00 X{b.x:g}. Y{b.y:g}." in text
    assert text.count("G01 Z-1. F") == 3
    assert text.strip().endswith("%")
    # read back: the deepest point of each plunge is the bowl position at -depth
    from mtcomp import gcode
    p = gcode.parse(text, axes=("X", "Y", "Z"))
    low = p.position[np.isclose(p.position[:, 2], -plan.depth)]
    np.testing.assert_allclose(low[:, :2], [(b.x, b.y) for b in plan.bowls])


@pytest.mark.parametrize("program", [roughing_program, probing_program])
def test_axis_words_carry_a_decimal_point(program):
    # without one, a control reading least input increments takes X7 as 7 um
    code = re.sub(r"\([^)]*\)", "", program(plan_bowls(3)))
    words = re.findall(r"[XYZ](-?[0-9.]+)", code)
    assert words and all("." in w for w in words)


def test_probing_moves_start_inside_and_end_beyond_the_probe_sphere():
    plan = plan_bowls(3)
    text = probing_program(plan)
    assert text.count("G31") == 27
    for bid, j, s, e, d in touch_moves(plan):
        c = plan.centre_of(bid)
        assert np.linalg.norm(s - c) == pytest.approx(plan.probe_sphere_radius - plan.clearance)
        assert np.linalg.norm(e - c) == pytest.approx(plan.probe_sphere_radius + plan.overtravel)
        np.testing.assert_allclose((e - s) / np.linalg.norm(e - s), d, atol=1e-12)


def test_virtual_touches_lie_on_the_real_probe_sphere():
    plan = plan_bowls(3)
    t = virtual_probe(POSE, plan, 0.0, 0)
    R, tr = np.asarray(POSE.matrix), np.asarray(POSE.translation)
    for b, c in zip(plan.bowls, plan.centres):
        p = t.points[t.of(b.id)]
        np.testing.assert_allclose(np.linalg.norm(p - (R @ c + tr), axis=1), 1.5, atol=1e-12)


def test_negative_noise_and_threshold_are_refused():
    plan = plan_bowls(3)
    with pytest.raises(InputError, match=r"\[noise\]: probe noise must be >= 0"):
        virtual_probe(POSE, plan, -0.001, 0)
    with pytest.raises(InputError, match=r"\[k\]: outlier threshold must be > 0"):
        fit_bowls(virtual_probe(POSE, plan, 0.0, 0), plan.probe_radius, k=0.0)


def test_virtual_probe_names_the_bowl_it_misses():
    plan = plan_bowls(3)
    with pytest.raises(MtcompError, match="bowl 1: touch .* outside the bowl"):
        virtual_probe(WorkpieceSetting((0.6, 0, 0), (0, 0, 0)), plan, 0.0, 0)


def test_sphere_fit_exact_and_probe_radius_accounted():
    plan = plan_bowls(3, probe_radius=0.3)
    t = virtual_probe(POSE, plan, 0.0, 0, bowl_radius_error=0.004)
    fit = fit_bowls(t, plan.probe_radius)
    R, tr = np.asarray(POSE.matrix), np.asarray(POSE.translation)
    for f, c in zip(fit.fits, plan.centres):
        np.testing.assert_allclose(f.centre, R @ c + tr, atol=1e-9)
        assert f.radius == pytest.approx(2.004, abs=1e-9)          # bowl radius, not probe sphere
        assert f.rms < 1e-9
    # fixing the radius at the true value gives the same centres
    fit2 = fit_bowls(t, plan.probe_radius, bowl_radius=2.004)
    np.testing.assert_allclose(fit2.centres, fit.centres, atol=1e-9)


def test_sphere_fit_covariance_is_sigma2_inverse_normal_matrix():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(12, 3))
    d[:, 2] = -np.abs(d[:, 2])
    d /= np.linalg.norm(d, axis=1)[:, None]
    c, rho = np.array([1.0, 2.0, 3.0]), 1.5
    sig = 1e-3
    est = []
    for _ in range(2000):
        p = c + (rho + rng.normal(0, sig, 12))[:, None] * d
        cc, rr, *_ = fit_sphere(p)
        est.append(np.r_[cc, rr])
    t = Touches(np.ones(12, int), c + rho * d, d)
    pred = fit_bowls(t, 0.5, probe_sigma=sig).fits[0].cov
    ratio = np.sqrt(np.diag(np.cov(np.array(est).T)) / np.diag(pred))
    assert np.all(np.abs(ratio - 1) < 0.08)


@pytest.mark.parametrize("sigma", [0.0005, None])
def test_one_outlier_touch_is_rejected_with_a_warning(sigma):
    rng = np.random.default_rng(4)
    plan = plan_bowls(3)
    t = virtual_probe(POSE, plan, 0.0005, rng)
    clean = fit_bowls(t, plan.probe_radius, probe_sigma=0.0005)
    pts = t.points.copy()
    k = t.of(2)[5]
    pts[k] += 0.015 * t.approach[k]                                # a chip: 15 um
    bad = Touches(t.bowl, pts, t.approach)
    fit = fit_bowls(bad, plan.probe_radius, probe_sigma=sigma)
    assert len(fit.warnings) == 1 and fit.warnings[0].startswith("bowl 2: touch 6 rejected")
    assert fit.fits[1].rejected == (5,)
    # the remaining touches give the centre to within its uncertainty
    f = fit.fits[1]
    e = f.centre - clean.fits[1].centre
    assert np.linalg.norm(e) < 5 * np.sqrt(np.trace(f.centre_cov))
    assert fit.fits[0].rejected == () and fit.fits[2].rejected == ()


def test_two_bad_touches_or_a_far_touch_is_an_error_naming_bowl_and_line(tmp_path):
    rng = np.random.default_rng(5)
    plan = plan_bowls(3)
    t = virtual_probe(POSE, plan, 0.0005, rng)
    pts = t.points.copy()
    i2 = t.of(3)
    pts[i2[2]] += 0.02 * t.approach[i2[2]]
    pts[i2[6]] -= 0.02 * t.approach[i2[6]]
    with pytest.raises(InputError, match="bowl 3: touches disagree"):
        fit_bowls(Touches(t.bowl, pts, t.approach), plan.probe_radius, probe_sigma=0.0005)
    pts = t.points.copy()
    pts[i2[4]] += 0.3 * t.approach[i2[4]]                          # hit something else
    path = tmp_path / "touches.csv"
    write_touches(Touches(t.bowl, pts, t.approach), path)
    with pytest.raises(InputError, match=r"touches.csv \[bowl\]: bowl 3: line 25 is 299.9 µm off"):
        fit_bowls(read_touches(path), plan.probe_radius, probe_sigma=0.0005)


def test_too_few_or_degenerate_touches_name_the_bowl():
    plan = plan_bowls(3)
    t = virtual_probe(POSE, plan, 0.0, 0)
    keep = np.ones(len(t.bowl), bool)
    keep[t.of(2)[4:]] = False
    short = Touches(t.bowl[keep], t.points[keep], t.approach[keep])
    with pytest.raises(InputError, match="bowl 2: 4 touches, at least 5 needed"):
        fit_bowls(short, plan.probe_radius)
    # one ring only: coplanar touches cannot give a free radius
    ring = plan_bowls(3, touches=9)
    pts = t.points.copy()
    idx = t.of(1)
    c = pts[idx].mean(axis=0)
    pts[idx] = c + np.column_stack([np.cos(np.arange(9)), np.sin(np.arange(9)), np.zeros(9)])
    with pytest.raises(InputError, match="bowl 1: touches are coplanar"):
        fit_bowls(Touches(t.bowl, pts, t.approach), ring.probe_radius)


def test_touches_csv_round_trip_and_errors(tmp_path):
    plan = plan_bowls(3)
    t = virtual_probe(POSE, plan, 0.0005, 1)
    path = tmp_path / "t.csv"
    write_touches(t, path)
    back = read_touches(path)
    np.testing.assert_array_equal(back.bowl, t.bowl)
    np.testing.assert_allclose(back.points, t.points, atol=1e-9)
    np.testing.assert_allclose(back.approach, t.approach, atol=1e-9)
    assert back.lines[0] == 3                                      # comment, header, first row
    bad = path.read_text().splitlines()
    bad[4] = bad[4].replace(bad[4].split(",")[2], "abc", 1)
    path.write_text("\n".join(bad))
    with pytest.raises(InputError, match=r"t.csv:5 \[y\]: expected a number"):
        read_touches(path)
    path.write_text("bowl,x,y,z\n1,0,0,0\n")
    with pytest.raises(InputError, match="missing ax,ay,az"):
        read_touches(path)
    path.write_bytes(b"\xff\xfe\x00b\x00o\x00w\x00l\x00\n")     # UTF-16, not a touches CSV
    with pytest.raises(InputError, match=r"t.csv(:1: header must contain|: not a text file)"):
        read_touches(path)


@pytest.mark.parametrize("cell, match", [
    ("1_0", r"t.csv:4 \[x\]: expected a number, got '1_0'"),      # float() read it as 10
    ("1e300", r"t.csv:4 \[x\]: '1e300' is out of range"),         # overflowed the fit
    ("nan", r"t.csv:4 \[x\]: expected a number, got 'nan'"),
])
def test_touches_cells_are_checked_by_the_shared_reader(tmp_path, cell, match):
    t = virtual_probe(POSE, plan_bowls(3), 0.0, 1)
    path = tmp_path / "t.csv"
    write_touches(t, path)
    lines = path.read_text().splitlines()
    c = lines[3].split(",")
    c[1] = cell
    lines[3] = ",".join(c)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=match):
        read_touches(path)


def test_touches_header_units_and_order(tmp_path):
    # the format takes columns in any order and case; units in the header are converted
    t = virtual_probe(POSE, plan_bowls(3), 0.0, 1)
    rows = ["AX,ay,az,X [um],y,z,Bowl,note"]
    rows += [",".join([*(repr(float(v)) for v in a), repr(float(p[0]) * 1e3), repr(float(p[1])),
                       repr(float(p[2])), str(int(b)), '"a, b"'])
             for b, p, a in zip(t.bowl, t.points, t.approach)]
    (tmp_path / "u.csv").write_text("\n".join(rows) + "\n")
    back = read_touches(tmp_path / "u.csv")
    np.testing.assert_array_equal(back.bowl, t.bowl)
    np.testing.assert_allclose(back.points, t.points, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(back.approach, t.approach, atol=1e-12)
    assert back.lines[0] == 2


def test_shared_radius_fit_is_exact_and_cuts_the_tilt_uncertainty():
    from mtcomp.setting.frame import frame_from_bowls
    plan = plan_bowls(3)
    t = virtual_probe(POSE, plan, 0.0, 0, bowl_radius_error=-0.003)
    fit = fit_bowls(t, plan.probe_radius, probe_sigma=0.0005)
    assert fit.shared_radius
    R, tr = np.asarray(POSE.matrix), np.asarray(POSE.translation)
    for f, c in zip(fit.fits, plan.centres):
        np.testing.assert_allclose(f.centre, R @ c + tr, atol=1e-9)
        assert f.radius == pytest.approx(1.997, abs=1e-9)
    # the shared radius correlates the centre heights: off-diagonal blocks are not zero
    full = fit.centre_cov_full
    assert full[2, 5] > 0.5 * np.sqrt(full[2, 2] * full[5, 5])
    per = fit_bowls(t, plan.probe_radius, probe_sigma=0.0005, shared_radius=False)
    assert not np.any(per.centre_cov_full[0:3, 3:6])
    e_sh = frame_from_bowls(fit, plan, reference="centre")
    e_per = frame_from_bowls(per, plan, reference="centre")
    assert e_sh.std[3] < 0.3 * e_per.std[3] and e_sh.std[4] < 0.3 * e_per.std[4]
    assert e_sh.std[2] < e_per.std[2]
    # bottom points (centre - fitted radius) do not carry the radius error at all: per-bowl fits
    # then give the tilt better than centres, and the shared radius adds little
    b_sh, b_per = frame_from_bowls(fit, plan), frame_from_bowls(per, plan)
    assert b_per.std[3] < 0.5 * e_per.std[3] and b_per.std[2] < 0.5 * e_per.std[2]
    assert b_sh.std[3] <= b_per.std[3] * 1.0001


def test_a_bowl_of_another_radius_is_refused_by_the_shared_fit():
    plan = plan_bowls(3)
    t = virtual_probe(POSE, plan, 0.0, 0)
    pts = t.points.copy()
    i2 = t.of(2)
    pts[i2] += 0.2 * t.approach[i2]                               # bowl 2 cut 0.2 mm larger
    bad = Touches(t.bowl, pts, t.approach)
    with pytest.raises(InputError, match="bowl 2: the bowls do not share one radius"):
        fit_bowls(bad, plan.probe_radius, probe_sigma=0.0005)
    fit = fit_bowls(bad, plan.probe_radius, probe_sigma=0.0005, shared_radius=False)
    assert fit.fits[1].radius == pytest.approx(2.2, abs=1e-4)


# ------------------------------------------------------------------ issue 17: cutter radius, run-out

def test_cutter_radius_error_moves_the_centre_not_the_bottom():
    """A ball end mill 2 µm larger, plunged to the planned depth, cuts a sphere 2 µm larger whose
    centre sits 2 µm higher; the bottom stays (the old simulation kept the centre fixed)."""
    plan = plan_bowls(3)
    t = virtual_probe(None, plan, 0.0, 0, cutter_radius_error=0.002)
    fit = fit_bowls(t, plan.probe_radius, probe_sigma=0.0005)
    for f, c in zip(fit.fits, plan.centres):
        np.testing.assert_allclose(f.centre, c + [0, 0, 0.002], atol=1e-9)
        assert f.radius == pytest.approx(plan.tool_radius + 0.002, abs=1e-9)
        assert f.centre[2] - f.radius == pytest.approx(-plan.depth, abs=1e-9)


def test_frame_height_from_bottom_points_ignores_the_cutter_radius():
    from mtcomp.setting.frame import frame_from_bowls
    plan = plan_bowls(3)
    t = virtual_probe(POSE, plan, 0.0, 0, cutter_radius_error=0.002)
    fit = fit_bowls(t, plan.probe_radius, probe_sigma=0.0005)
    est = frame_from_bowls(fit, plan)
    np.testing.assert_allclose(est.pose.translation, POSE.translation, atol=1e-8)
    np.testing.assert_allclose(est.pose.angles, POSE.angles, atol=1e-7)
    old = frame_from_bowls(fit, plan, reference="centre")
    # the centres read the radius error as height: dz = dR along the blank's z
    assert old.pose.translation[2] - POSE.translation[2] == pytest.approx(0.002, abs=1e-6)
    with pytest.raises(InputError, match="reference"):
        frame_from_bowls(fit, plan, reference="top")


def test_cutter_radius_error_of_2um_changes_pyramid_widths_by_less_than_half_a_micron():
    """Issue 17 acceptance: compensated pyramid widths (paper 001) with a 2 µm cutter radius error
    differ from those without by < 0.5 µm; from centres they moved by 15 dR = 30 µm."""
    from mtcomp.setting.cellsim import CellConfig, simulate_cell
    out = {}
    for ref in ("bottom", "centre"):
        for dR in (0.0, 0.002):
            r = simulate_cell(CellConfig(trials=4, seed=5, cutter_radius_error=dR, reference=ref))
            out[ref, dR] = np.array([r.compensated[f"W{k}"] for k in range(1, 5)])
    assert np.max(np.abs(out["bottom", 0.002] - out["bottom", 0.0])) < 0.5
    assert np.min(out["centre", 0.002] - out["centre", 0.0]) > 25.0


def test_runout_widens_the_bowl_and_barely_moves_its_bottom():
    """2 µm radial run-out: the cavity is a spindle torus; the sphere fit's bottom stays within
    0.4 µm of the true bottom (the centre moves 3.4 µm)."""
    plan = plan_bowls(3)
    t = virtual_probe(None, plan, 0.0, 0, runout=0.002)
    fit = fit_bowls(t, plan.probe_radius, probe_sigma=0.0005)
    for f, c in zip(fit.fits, plan.centres):
        np.testing.assert_allclose(f.centre[:2], c[:2], atol=1e-9)        # symmetric about the axis
        # r(phi) = R + e sin(phi) on the wall: the sphere through touches up to 48 deg from the
        # bottom extrapolates it to a radius R + 1.9 e with the centre 1.7 e higher
        assert 0.003 < f.radius - plan.tool_radius < 0.0045
        assert abs(f.centre[2] - f.radius + plan.depth) < 0.0005           # bottom within 0.5 µm
        assert f.centre[2] - c[2] > 0.002                                  # the centre rises more


@pytest.mark.parametrize("edit,field", [
    (lambda d: d.update(directions=[[0, 0, -1, 0]]), "directions"),
    (lambda d: d.update(directions=[0, 0, -1]), "directions"),
    (lambda d: d.update(directions=[["a", 0, -1]]), "directions"),
    (lambda d: d["bowls"][0].update(id=float("inf")), "bowls[0].id"),
    (lambda d: d["bowls"][0].update(id=1.5), "bowls[0].id"),
    (lambda d: d["bowls"][0].update(id="1"), "bowls[0].id"),
    (lambda d: d["bowls"][1].update(x=float("nan")), "bowls[1].x"),
    (lambda d: d.update(bowls=[1, 2, 3]), "bowls[0]"),
    (lambda d: d.update(bowls="x"), "bowls"),
    (lambda d: d.update(depth=float("inf")), "depth"),
])
def test_bad_plan_fields_are_input_errors(edit, field):
    """Issue 15: a bad `directions` shape (ValueError) or a bowl id = inf (OverflowError) crashed."""
    from mtcomp.setting.bowls import plan_from_dict, plan_to_dict
    d = plan_to_dict(plan_bowls(3))
    edit(d)
    with pytest.raises(InputError) as exc:
        plan_from_dict(d, file="plan.toml")
    assert exc.value.field == field


def test_paper_001_reproduction_states_its_assumptions_and_bowl_errors_widen_the_widths():
    from mtcomp.setting.cellsim import CellConfig, PAPER_ASSUMPTIONS, paper_reproduction, simulate_cell
    r = paper_reproduction(trials=8, seed=4)
    assert all(a in r["text"] for a in PAPER_ASSUMPTIONS)
    assert "from the paper" in r["text"] and "assumed" in r["text"] and "not modelled" in r["text"]
    sd = [np.mean([r[k].compensated[f"W{i}"].std(ddof=1) for i in range(1, 5)]) for k in ("ideal", "bowl_errors")]
    assert sd[1] > 2 * sd[0]
    # a microscope scale error scales the measured widths, nothing else
    a = simulate_cell(CellConfig(trials=3, seed=2))
    b = simulate_cell(CellConfig(trials=3, seed=2, microscope_scale=0.001))
    np.testing.assert_allclose(b.compensated["W1"], a.compensated["W1"] * 1.001, rtol=1e-12)
    np.testing.assert_allclose(b.compensated["S1&S2"], a.compensated["S1&S2"], rtol=1e-12)


# ------------------------------------------------------------------ issue 15: property tests

from hypothesis import given, settings, strategies as st  # noqa: E402

_TOML_VALUES = st.one_of(
    st.integers(-2 ** 70, 2 ** 70), st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=4),
    st.booleans(), st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=4),
    st.lists(st.lists(st.floats(-2.0, 2.0), max_size=4), max_size=3),
    st.lists(st.dictionaries(st.sampled_from(["id", "x", "y", "z"]), st.one_of(st.integers(-5, 5), st.floats())),
             max_size=3),
    st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))
_PLAN_KEYS = ["blank", "tool_radius", "depth", "probe_radius", "clearance", "overtravel", "safe_z", "keepout_radius",
              "spindle_speed", "plunge_feed", "probe_feed", "bowls", "directions", "bowls.0.id", "bowls.1.x",
              "bowls.2.y", "directions.0", "directions.1.2"]


@settings(max_examples=300, deadline=None, derandomize=True)
@given(key=st.sampled_from(_PLAN_KEYS), value=_TOML_VALUES)
def test_bowl_plan_mutations_are_accepted_or_input_errors(key, value):
    """Any value anywhere in a bowl plan: either a valid plan or an InputError, never a traceback."""
    from mtcomp.setting.bowls import plan_from_dict, plan_to_dict
    d = plan_to_dict(plan_bowls(3))
    *path, last = key.split(".")
    node = d
    for p in path:
        node = node[int(p)] if p.isdigit() else node[p]
    node[int(last) if last.isdigit() else last] = value
    try:
        plan = plan_from_dict(d, file="plan.toml")
    except InputError:
        return
    assert np.all(np.isfinite(plan.centres)) and np.allclose(np.linalg.norm(plan.dirs, axis=1), 1.0, atol=1e-6)


def test_known_runout_is_taken_out_of_the_bottom_points():
    """A measured run-out passed to the frame fit removes its bias: 2 µm run-out then changes the
    compensated widths by < 0.5 µm (without it: several µm)."""
    from mtcomp.setting.cellsim import CellConfig, simulate_cell
    from mtcomp.setting.frame import frame_from_bowls
    plan = plan_bowls(3)
    for shared in (True, False):
        t = virtual_probe(POSE, plan, 0.0, 0, runout=0.002)
        fit = fit_bowls(t, plan.probe_radius, probe_sigma=0.0005, shared_radius=shared)
        est = frame_from_bowls(fit, plan, runout=0.002)
        np.testing.assert_allclose(est.pose.translation, POSE.translation, atol=2e-6)
        raw = frame_from_bowls(fit, plan)
        assert abs(raw.pose.translation[2] - POSE.translation[2]) > 2e-4
    w = {}
    for known in (False, True):
        for e in (0.0, 0.002):
            r = simulate_cell(CellConfig(trials=3, seed=5, runout=e, runout_known=known))
            w[known, e] = np.array([r.compensated[f"W{k}"] for k in range(1, 5)])
    assert np.max(np.abs(w[True, 0.002] - w[True, 0.0])) < 0.5
    assert np.min(np.abs(w[False, 0.002] - w[False, 0.0])) > 3.0
