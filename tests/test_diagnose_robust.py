"""Diagnosis of recordings written in other ways than the project's own: missing cells, logger
pauses, time stamps, repeated times, decimal commas, other units, other column names, a few
samples, coarse quantisation.  The answer must stay honest: the concealed effect, or nothing
named and the mismatch reported, never a wrong name."""
import math

import numpy as np
import pytest

from mtcomp.diagnose import data, diagnose, synth

BACKLASH = {"backlash_mm": 4e-3}


def _case(seed=5, **kw):
    kw = {"duration": 20.0, "sim_rate": 200.0, "rec_rate": 100.0, "n_temps": 1, "n_junk": 1, **kw}
    return synth.make_case([("backlash", BACKLASH)], seed=seed, **kw)


def _write(path, cols, sep=",", dec=".", fmt="{:.9g}", tfmt=None, drop=(), blank=()):
    """cols: header -> values; drop: rows left out; blank: (header, row) cells written empty."""
    keys = list(cols)
    n = len(cols[keys[0]])
    lines = [sep.join(keys)]
    for i in range(n):
        if i in drop:
            continue
        cells = []
        for k in keys:
            if (k, i) in blank:
                cells.append("")
            elif k == keys[0] and tfmt is not None:
                cells.append(tfmt(cols[k][i]))
            else:
                cells.append(fmt.format(cols[k][i]).replace(".", dec))
        lines.append(sep.join(cells))
    path.write_text("\n".join(lines) + "\n")
    return path


def _honest(res, truth):
    """No wrong name; and a residual left above 3x the noise floor is reported."""
    assert set(res.names) <= set(truth), res.summary()
    flagged = {u["output"] for u in res.unexplained}
    for o in res.outputs:
        if res.fit["rms_after"][o] > 3 * res.noise_floor[o]:
            assert o in flagged, res.summary()


def test_missing_cells_and_a_logger_pause_are_reported_not_interpolated(tmp_path):
    case = _case()
    n = len(case.rec["t"])
    blank = {("x", i) for i in (100, 101, 700, 1500)} | {("aux0", 300)}
    gap = set(range(900, 1200))  # a 3 s pause of the logger
    sim = _write(tmp_path / "sim.csv", case.sim)
    rec = _write(tmp_path / "rec.csv", case.rec, drop=gap, blank=blank)
    res = diagnose(sim, rec)
    assert res.names == ["backlash"], res.summary()
    assert res.effects[0].params["backlash_mm"] == pytest.approx(4e-3, rel=0.02)
    text = " ".join(res.notes)
    assert "'x' of rec.csv: 4 missing values" in text and "'aux0' of rec.csv: 1 missing" in text
    assert "gaps of REC (longest 3.01 s)" in text
    # the samples of the pause and of the missing x cells take no part
    assert res.alignment["grid_samples"] - res.alignment["samples"] >= len(gap) - 3
    assert res.alignment["samples"] <= n - len(gap) - 4
    assert res.fit["holdout_rms_after"]["x"] < 1.5 * res.noise_floor["x"]


def test_time_stamps_on_both_files_share_one_clock(tmp_path):
    from datetime import datetime, timedelta
    case = _case()
    t0 = datetime(2024, 3, 1, 23, 59, 50)  # the run passes midnight

    def stamp(t):
        return (t0 + timedelta(seconds=float(t))).isoformat(sep=" ", timespec="microseconds")
    sim = _write(tmp_path / "sim.csv", case.sim, tfmt=stamp)
    rec = _write(tmp_path / "rec.csv", case.rec, tfmt=stamp)
    res = diagnose(sim, rec)
    ref = diagnose(case.sim, case.rec)
    assert res.names == ref.names == ["backlash"]
    assert res.fit["rms_before"]["x"] == pytest.approx(ref.fit["rms_before"]["x"], rel=1e-3)
    assert any("one clock" in n for n in res.notes)
    tab = data.read_table(rec)
    assert tab.origin[0] == "date" and tab.t[0] == 0.0


def test_time_in_ms_repeated_stamps_and_irregular_sampling(tmp_path):
    case = _case(rec_rate=200.0)
    rng = np.random.default_rng(3)
    rec = dict(case.rec)
    t = rec.pop("t")
    # irregular sampling: a third of the rows dropped at random, times in ms, and 20 rows
    # written twice by the logger (the same stamp and values)
    keep = np.sort(rng.choice(len(t), size=2 * len(t) // 3, replace=False))
    keep = np.sort(np.concatenate([keep, rng.choice(keep, 20, replace=False)]))
    out = {"t[ms]": t[keep] * 1e3}
    out.update({k: v[keep] for k, v in rec.items()})
    assert np.sum(np.diff(out["t[ms]"]) == 0) == 20
    path = _write(tmp_path / "rec.csv", out)
    res = diagnose(case.sim, path)
    assert res.names == ["backlash"], res.summary()
    assert any("repeat the time stamp" in n for n in res.notes)
    _honest(res, ["backlash"])


def test_semicolons_and_decimal_commas_read_like_commas(tmp_path):
    case = _case()
    a = diagnose(_write(tmp_path / "s1.csv", case.sim), _write(tmp_path / "r1.csv", case.rec))
    b = diagnose(_write(tmp_path / "s2.csv", case.sim, sep=";", dec=","),
                 _write(tmp_path / "r2.csv", case.rec, sep="\t", dec=","))
    assert a.names == b.names == ["backlash"]
    assert a.fit["rms_before"] == b.fit["rms_before"]


def test_inches_counts_and_micrometres_against_mm(tmp_path):
    case = _case(seed=6)
    rec = dict(case.rec)
    rec["x[in]"] = rec.pop("x") / 25.4
    rec["y[0.1um]"] = np.round(rec.pop("y") * 1e4)  # counts of a 0.1 µm scale
    rec["z[µm]"] = rec.pop("z") * 1e3
    res = diagnose(case.sim, rec)
    assert res.names == ["backlash"], res.summary()
    assert res.effects[0].params["backlash_mm"] == pytest.approx(4e-3, rel=0.02)
    assert res.alignment["columns"]["y"]["unit"] == "mm"
    # counts given by option: the same
    rec2 = dict(case.rec)
    rec2["y"] = np.round(rec2["y"] * 1e4)
    sim2 = {("y[mm]" if k == "y" else k): v for k, v in case.sim.items()}  # the option is for REC's y
    res2 = diagnose(sim2, rec2, units={"y": "0.1um"})
    assert res2.names == ["backlash"]


@pytest.mark.parametrize("names", [("X_cmd", "X_act"), ("Soll_X", "Ist_X"), ("cmd_pos[mm]", "act_pos[mm]"),
                                   ("Sollposition_X", "Istposition_X")])
def test_command_and_measurement_named_by_role_words_are_paired(names):
    case = _case()
    s, r = names
    sim = {("t" if k == "t" else s if k == "x" else k): v for k, v in case.sim.items()}
    rec = {("t" if k == "t" else r if k == "x" else k): v for k, v in case.rec.items()}
    res = diagnose(sim, rec)
    key = r.split("[")[0]
    assert key in res.outputs
    assert [(e.name, e.outputs) for e in res.effects] == [("backlash", (key,))], res.summary()
    assert any("compared with SIM's" in n for n in res.notes)


def test_two_recorded_columns_for_one_simulated_column():
    # a motor encoder (no backlash: it sits before the screw) and a linear scale (sees it)
    with_b = _case(seed=7)
    without = synth.make_case([], seed=7, duration=20.0, sim_rate=200.0, rec_rate=100.0,
                              n_temps=1, n_junk=1)
    np.testing.assert_array_equal(with_b.sim["x"], without.sim["x"])
    sim = {("X" if k == "x" else k): v for k, v in with_b.sim.items()}
    rec = {k: v for k, v in with_b.rec.items() if k != "x"}
    rec["X_enc"] = without.rec["x"]
    rec["X_scale"] = with_b.rec["x"]
    res = diagnose(sim, rec, outputs=["X=X_enc", "X=X_scale", "y", "z"])
    assert set(res.outputs) == {"X_enc", "X_scale", "y", "z"}
    assert [(e.name, e.outputs) for e in res.effects] == [("backlash", ("X_scale",))], res.summary()


def test_a_few_samples_and_three_significant_figures_stay_honest():
    # 60 and 20 samples: the backlash, or nothing named with the mismatch reported
    for rate, n in ((3.0, 61), (1.0, 21)):
        case = _case(seed=9, rec_rate=rate)
        res = diagnose(case.sim, case.rec)
        assert 8 <= res.alignment["samples"] <= n
        _honest(res, ["backlash"])
    # positions of up to 100 mm written with 3 significant figures (0.1 mm steps): a 4 µm
    # backlash cannot be seen; nothing else may be named instead
    case = _case(seed=10)
    rec = {k: (np.array([float(f"{v:.3g}") for v in vals]) if k in "xyz" else vals)
           for k, vals in case.rec.items()}
    res = diagnose(case.sim, rec)
    assert res.names in ([], ["backlash"]), res.summary()
    _honest(res, ["backlash"])
    assert res.noise_floor["x"] > 0.01  # the rounding, not 20 nm


def test_other_naming_conventions_get_their_kind():
    k = data.kind_from_name
    assert [k("Pos_Act"), k("Geschwindigkeit_X"), k("Vitesse_Y"), k("Drehzahl"), k("Winkel_B"),
            k("Temperatur_Spindel"), k("J1"), k("joint3"), k("Lage_Z")] == [
        "length", "velocity", "velocity", "speed", "angle", "temperature", "angle", "angle", "length"]
    assert data.stem("X1_ActualPosition") == data.stem("X1_CommandPosition") == "x_1_position"
    assert data._unit_of("0.5um") == ("length", 0.5e-3, 0.0)
    assert data._unit_of("rad")[1] == pytest.approx(180 / math.pi)


def test_cli_reads_a_semicolon_file_and_pairs_columns_by_option(tmp_path, capsys):
    import json

    from mtcomp.cli import main
    case = _case()
    sim = {("X" if k == "x" else k): v for k, v in case.sim.items()}
    rec = {("X_scale" if k == "x" else k): v for k, v in case.rec.items()}
    s = _write(tmp_path / "sim.csv", sim, sep=";", dec=",")
    r = _write(tmp_path / "rec.csv", rec)
    out = tmp_path / "d.json"
    assert main(["diagnose", "--sim", str(s), "--rec", str(r), "--output", "X=X_scale",
                 "--output", "y", "--json", str(out), "--quiet"]) == 0
    d = json.loads(out.read_text())
    assert sorted(d["outputs"]) == ["X_scale", "y"]
    assert [(e["name"], e["output"]) for e in d["effects"]] == [("backlash", "X_scale")]
    # a pair naming a column that is not there: one line naming it, exit 2
    assert main(["diagnose", "--sim", str(s), "--rec", str(r), "--output", "X=X_enc"]) == 2
    assert "REC has no column 'X_enc'" in capsys.readouterr().err
