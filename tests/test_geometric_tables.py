"""Tables from simulated interferometer runs reproduce the synthetic machine; compensation."""
from dataclasses import replace

import numpy as np
import pytest

from mtcomp import InputError
from mtcomp.errors import AxisErrorTable
from mtcomp.geometric import comptables as ct
from mtcomp.geometric import synthetic, tables, volumetric as vol
from mtcomp.machine import load_machine

STEP = 2.5           # run target spacing, mm
NOISE = tables.Noise(linear=0.1e-3, straightness=0.2e-3, angular=0.2e-6, reversal=2e-3)


@pytest.fixture(scope="module")
def vmc():
    return load_machine("vmc-moving-column")


@pytest.fixture(scope="module")
def syn(vmc):
    return synthetic.make_synthetic(vmc, seed=11, min_wavelength=250.0, run_step=STEP)


@pytest.fixture(scope="module")
def truth(syn):
    return syn.errors()


@pytest.fixture(scope="module")
def setup():
    return tables.Setup.typical(seed=5)


@pytest.fixture(scope="module")
def clean(vmc, truth, setup):
    return tables.build_tables(vmc, tables.simulate_runs(vmc, truth, setup, step=STEP))


@pytest.fixture(scope="module")
def grid(vmc):
    return vol.volume_grid(vmc, 25.0)


@pytest.fixture(scope="module")
def truth_map(vmc, truth, grid):
    return vol.error_map(vmc, truth, grid)


def test_noise_free_tables_reproduce_the_volumetric_error(vmc, syn, truth, clean, grid, truth_map):
    built = vol.error_map(vmc, clean.errors, grid)
    assert truth_map.stats()["max"] > 0.03          # tens of µm to reproduce
    assert vol.compare(truth_map, built)["max"] < 1e-5   # 10 nm: second-order Abbe terms
    for name, v in syn.squareness.items():
        assert clean.geometric.location[name] == pytest.approx(v, abs=2e-8)
    t = clean.geometric.tables["Y"]
    d_true, e_true = truth.geometric.tables["Y"].evaluate(t.position)
    np.testing.assert_allclose(t.values["ECY"], e_true[:, 2], atol=1e-12)
    np.testing.assert_allclose(t.values["EXY"], d_true[:, 0], atol=1e-6)


def test_without_abbe_removal_the_tables_are_wrong(vmc, truth, setup, grid, truth_map):
    """The same runs built as if the optics had sat at the tool tip: µm-level errors."""
    mset = tables.simulate_runs(vmc, truth, setup, step=STEP)
    blind = replace(mset, runs=tuple(replace(r, offset=(0.0, 0.0, 0.0)) for r in mset.runs))
    wrong = vol.error_map(vmc, tables.build_tables(vmc, blind).errors, grid)
    assert vol.compare(truth_map, wrong)["max"] > 2e-3


def test_square_misalignment_and_zero_offsets_drop_out(vmc, truth, grid, truth_map):
    s1 = tables.Setup.typical(seed=5)
    s2 = replace(s1, square_angles={k: -3 * v for k, v in s1.square_angles.items()})
    a = tables.build_tables(vmc, tables.simulate_runs(vmc, truth, s1, step=STEP))
    b = tables.build_tables(vmc, tables.simulate_runs(vmc, truth, s2, step=STEP))
    for name in a.geometric.location:
        assert a.geometric.location[name] == pytest.approx(b.geometric.location[name], abs=1e-12)
    assert vol.compare(vol.error_map(vmc, a.errors, grid), vol.error_map(vmc, b.errors, grid))["max"] < 1e-9


def test_noisy_tables_reproduce_the_volumetric_error_within_the_noise(vmc, truth, setup, grid,
                                                                       truth_map):
    """The build is linear in the readings, so its deviation is the propagated noise: compare
    one realisation with the spread of others, and with the noise-free deviation."""
    def deviation(seed):
        ms = tables.simulate_runs(vmc, truth, setup, NOISE, step=STEP, seed=seed)
        return vol.error_map(vmc, tables.build_tables(vmc, ms).errors, grid).exact - truth_map.exact
    spread = np.array([deviation(s) for s in range(1, 13)])
    sigma = np.sqrt(np.mean(spread**2, axis=0))          # per point, all three components
    d = deviation(99)
    rms_pred = np.sqrt(np.mean(sigma**2))
    rms = np.sqrt(np.mean(d**2))
    assert 0.6 * rms_pred < rms < 1.6 * rms_pred
    assert np.max(np.abs(d)) < 5.0 * np.max(sigma)
    assert rms_pred < 0.5e-3                              # sub-µm: noise of 0.1-0.2 µm, 0.2 µrad
    # the reversal of 2 µm is seen by ISO 230-2 and kept out of the tables (mean bidirectional)
    ms = tables.simulate_runs(vmc, truth, setup, NOISE, step=STEP, seed=1)
    res = tables.build_tables(vmc, ms)
    for ax in "XYZ":
        assert res.iso[ax].B_mean == pytest.approx(2e-3, abs=0.1e-3)


def test_propagated_uncertainty_matches_the_scatter_of_repeated_builds(vmc, truth, setup):
    builds = [tables.build_tables(vmc, tables.simulate_runs(vmc, truth, setup, NOISE, step=10.0,
                                                            seed=s)) for s in range(30)]
    for name in ("EXX", "EYX", "EBX", "EXZ", "EZZ", "ECY"):
        v = np.array([b.geometric.tables[name[-1]].values[name] for b in builds])
        emp = np.sqrt(np.mean(v.std(axis=0, ddof=1) ** 2))
        pred = np.sqrt(np.mean(np.mean([b.uncertainty[name] for b in builds], axis=0) ** 2))
        assert 0.67 < pred / emp < 1.5, name
    for name in ("EC0Y", "EB0Z", "EA0Z"):
        emp = np.std([b.geometric.location[name] for b in builds], ddof=1)
        pred = np.mean([b.uncertainty[name] for b in builds])
        assert 0.5 < pred / emp < 2.0, name


def test_measurement_set_round_trip(tmp_path, vmc, truth, setup):
    ms = tables.simulate_runs(vmc, truth, replace(setup, mounts={"EXX": "workpiece"}), NOISE,
                              step=20.0, seed=3)
    path = tables.save_measurement_set(ms, tmp_path / "set.toml")
    back = tables.load_measurement_set(path)
    assert back.run("EXX").mount == "workpiece" and back.run("EYX").mount == "tool"
    a, b = tables.build_tables(vmc, ms), tables.build_tables(vmc, back)
    for ax in "XYZ":
        assert a.geometric.tables[ax] == b.geometric.tables[ax]   # CSVs carry every bit
    assert dict(a.geometric.location) == dict(b.geometric.location)


def test_missing_positioning_run_and_bad_set(tmp_path, vmc, truth):
    ms = tables.simulate_runs(vmc, truth, step=50.0)
    no_exx = replace(ms, runs=tuple(r for r in ms.runs if r.component != "EXX"))
    with pytest.raises(InputError, match="no positioning run EXX"):
        tables.build_tables(vmc, no_exx)
    short = replace(ms, runs=tuple(
        replace(r, run=replace(r.run, target=r.run.target[:-1], up=r.run.up[:, :-1],
                               down=r.run.down[:, :-1])) if r.component == "EBY" else r
        for r in ms.runs))
    with pytest.raises(InputError, match=r"run of EBY covers -200 .. 150 mm, less than"):
        tables.build_tables(vmc, short)
    p = tables.save_measurement_set(ms, tmp_path / "s.toml")
    text = p.read_text().replace('component = "EYX"', 'component = "EYQ"', 1)
    p.write_text(text)
    with pytest.raises(InputError, match=r"s.toml \[run\[\d+\].component\]"):
        tables.load_measurement_set(p)


def test_compensation_leaves_under_0_1_um(vmc, truth, clean):
    """Acceptance: noise-free tables from the runs, corrected commands, true machine."""
    rng = np.random.default_rng(8)
    lo = np.array([a.limits[0] for a in vmc.axes])
    hi = np.array([a.limits[1] for a in vmc.axes])
    q = np.vstack([vol.volume_grid(vmc, 50.0), lo + (hi - lo) * rng.random((3000, 3))])
    rep = ct.compensation_report(vmc, truth, clean.errors, q=q)
    assert rep.figures["uncompensated"][0] > 0.03
    assert rep.figures["model-based (corrected commands)"][0] < 1e-4


def test_lattice_interpolation_error_is_second_order_in_the_spacing(vmc, truth, clean):
    rng = np.random.default_rng(9)
    lo = np.array([a.limits[0] for a in vmc.axes])
    hi = np.array([a.limits[1] for a in vmc.axes])
    q = lo + (hi - lo) * rng.random((2000, 3))
    res = {}
    for step in (50.0, 25.0):
        lat = ct.lattice_table(vmc, clean.errors, step)
        # at the nodes the lattice is the exact correction
        nodes = vol.volume_grid(vmc, step)[::7]
        r = ct.residuals(vmc, truth, nodes, lat.apply(nodes))
        assert np.linalg.norm(r, axis=1).max() < 1e-4
        res[step] = np.linalg.norm(ct.residuals(vmc, truth, q, lat.apply(q)), axis=1).max()
    assert res[25.0] < res[50.0]
    assert 2.5 < res[50.0] / res[25.0] < 6.0


def test_lattice_and_iso_tables_round_trip(tmp_path, vmc, clean):
    lat = ct.lattice_table(vmc, clean.errors, 100.0)
    (tmp_path / "lat.csv").write_text(lat.to_csv())
    back = ct.LatticeTable.from_csv(tmp_path / "lat.csv")
    assert back.axes == lat.axes
    np.testing.assert_array_equal(back.correction, lat.correction)
    for a, b in zip(back.nodes, lat.nodes):
        np.testing.assert_array_equal(a, b)
    bad = (tmp_path / "lat.csv").read_text().splitlines()
    k = next(i for i, ln in enumerate(bad) if ln.startswith("0,0,0,"))
    cells = bad[k].split(",")
    cells[7] = "x1"
    bad[k] = ",".join(cells)
    (tmp_path / "bad.csv").write_text("\n".join(bad) + "\n")
    with pytest.raises(InputError, match=rf"bad.csv:{k + 1} \[d{lat.axes[1]}\]: expected a number, got 'x1'"):
        ct.LatticeTable.from_csv(tmp_path / "bad.csv")
    files = ct.write_iso_tables(clean.geometric, tmp_path, "comp")
    t = AxisErrorTable.from_csv(tmp_path / "comp_X.csv")
    assert t == clean.geometric.tables["X"]
    lines = files[-1].read_text().splitlines()
    assert lines[1] == "name,value" and {ln.split(",")[0] for ln in lines[2:]} == {"EC0Y", "EB0Z", "EA0Z"}


def test_volumetric_map_png_and_figures(tmp_path, truth_map):
    vol.plot_map(truth_map, tmp_path / "m.png")
    assert (tmp_path / "m.png").read_bytes()[:4] == b"\x89PNG"
    s = truth_map.stats()
    mag = np.linalg.norm(truth_map.exact, axis=1)
    assert s["max"] == pytest.approx(mag.max()) and s["rms"] == pytest.approx(np.sqrt(np.mean(mag**2)))
    assert s["first_order_diff_max"] < 1e-5 and s["paper_diff_max"] < 1e-5
    assert s["paper_origin_diff_max"] > 1e-3


def test_synthetic_study_chain_writes_its_files(tmp_path):
    from mtcomp.geometric.study import synthetic_study
    r = synthetic_study(noise=None, seed=2, run_step=5.0, map_step=50.0, lattice_step=100.0,
                        n_random=300, out_dir=tmp_path)
    f = r.figures()
    assert f["volumetric_max"] > 0.03
    assert f["tables_minus_truth_max"] < 1e-5
    assert f["residual_max[model-based (corrected commands)]"] < 1e-4
    assert f["residual_max[3-D lattice (trilinear)]"] > 1e-3     # 100 mm lattice: µm interpolation
    for p in r.files.values():
        assert p.exists()
    assert "Synthetic study on vmc-moving-column" in r.summary()


def test_table_mounted_optics_as_in_paper_004(vmc, truth, grid, truth_map):
    """Positioning and straightness of the table read from the bed with the optic on the table
    at P2 from the origin (formula 10's set-up): the arm is P2 − 121, constant along the run."""
    base = tables.Setup.typical(seed=5)
    offs = dict(base.offsets, EXX=(40.0, 80.0, 30.0), EYX=(-60.0, 20.0, 45.0), EZX=(10.0, -70.0, 5.0))
    setup = replace(base, offsets=offs, mounts={"EXX": "workpiece", "EYX": "workpiece",
                                                 "EZX": "workpiece"})
    ms = tables.simulate_runs(vmc, truth, setup, step=STEP)
    good = vol.error_map(vmc, tables.build_tables(vmc, ms).errors, grid)
    assert vol.compare(truth_map, good)["max"] < 1e-5
    # the same readings taken for spindle-mounted optics: the arms are wrong by the table travel
    blind = replace(ms, runs=tuple(replace(r, mount="tool") for r in ms.runs))
    wrong = vol.error_map(vmc, tables.build_tables(vmc, blind).errors, grid)
    assert vol.compare(truth_map, wrong)["max"] > 1e-3
    # a table-mounted optic cannot move with the column
    bad = replace(ms, runs=tuple(replace(r, mount="workpiece") if r.component == "EYY" else r
                                 for r in ms.runs))
    with pytest.raises(InputError, match="EYY: a workpiece-mounted optic moves only with a"):
        tables.build_tables(vmc, bad)


def _lattice_lines(tmp_path, vmc, clean):
    lat = ct.lattice_table(vmc, clean.errors, 200.0)
    lines = lat.to_csv().splitlines()
    return lat, lines, next(i for i, ln in enumerate(lines) if ln.startswith("0,0,1,"))


@pytest.mark.parametrize("mutate, match", [
    # the old reader took float("nan") and kept the last of two positions of a node silently
    (lambda c: c.__setitem__(3, "nan"), r"\[X\]: expected a number, got 'nan'"),
    (lambda c: c.__setitem__(3, "1e400"), r"\[X\]: .*out of range"),
    (lambda c: c.__setitem__(3, str(float(c[3]) + 0.5)), r"\[X\]: node i = 0 is at .* on line \d+, here at"),
    (lambda c: c.__setitem__(2, "0"), r"\[i\]: node \(0, 0, 0\) appears twice \(also line \d+\)"),
    (lambda c: c.__setitem__(2, "-1"), r"\[k\]: expected an integer in \[0, 1000000\], got -1"),
    (lambda c: c.__setitem__(2, "1.0"), r"\[k\]: expected an integer, got '1.0'"),
    (lambda c: c.append("0"), r"expected 9 values \(one per column\), got 10"),
])
def test_lattice_reader_names_line_and_column(tmp_path, vmc, clean, mutate, match):
    _, lines, k = _lattice_lines(tmp_path, vmc, clean)
    cells = lines[k].split(",")
    mutate(cells)
    lines[k] = ",".join(cells)
    (tmp_path / "bad.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=rf"bad.csv:{k + 1}:? " + match):
        ct.LatticeTable.from_csv(tmp_path / "bad.csv")


def test_lattice_reader_takes_spaces_quotes_and_units(tmp_path, vmc, clean):
    # the old reader split on bare commas: "i, j, k" or a quoted cell was a bad header/number
    lat, lines, k = _lattice_lines(tmp_path, vmc, clean)
    h = next(i for i, ln in enumerate(lines) if ln.startswith("i,"))
    a = lat.axes
    lines[h] = ", ".join(["i", "j", "k", *a, f"d{a[0]} [um]", f"d{a[1]}", f"d{a[2]}"])
    rows = []
    for ln in lines[h + 1:]:
        c = ln.split(",")
        c[6] = repr(float(c[6]) * 1e3)
        rows.append(",".join(f'"{x}"' if i == 3 else x for i, x in enumerate(c)))
    (tmp_path / "l.csv").write_text("\n".join(lines[:h + 1] + rows) + "\n")
    back = ct.LatticeTable.from_csv(tmp_path / "l.csv")
    np.testing.assert_allclose(back.correction, lat.correction, rtol=1e-12, atol=1e-18)
    for x, y in zip(back.nodes, lat.nodes):
        np.testing.assert_array_equal(x, y)
