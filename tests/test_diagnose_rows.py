"""Row filter of the diagnosis (--where / --exclude-rows): rows of a log that do not reflect
the machine are set aside, counted, and never bridged."""
import csv
import importlib.util
from pathlib import Path

import numpy as np
import pytest

from mtcomp import InputError
from mtcomp.cli import main
from mtcomp.diagnose import diagnose, rows, synth

UMICH = Path(__file__).parent / "data" / "umich"


def test_parse_operators_numbers_and_text():
    c = rows.parse(["FEED!=50", "x_act[mm] >= -1.5e1", "phase = 'Layer 1'"], ["mode==Prep"])
    assert [(k.column, k.op, k.value, k.keep) for k in c] == [
        ("FEED", "!=", 50.0, True), ("x_act[mm]", ">=", -15.0, True),
        ("phase", "==", "Layer 1", True), ("mode", "==", "Prep", False)]
    assert c[3].option == "--exclude-rows"


@pytest.mark.parametrize("bad, opt, what", [
    ("FEED", "--where", "expected COLUMN OP VALUE"),
    ("FEED!=", "--where", "expected COLUMN OP VALUE"),
    ("!=50", "--where", "expected COLUMN OP VALUE"),
    ("mode<Prep", "--where", "compared with == or != only"),
    ("x==nan", "--exclude-rows", "finite number"),
])
def test_bad_expression_is_an_input_error_naming_the_option(bad, opt, what):
    kw = {"where": [bad]} if opt == "--where" else {"exclude": [bad]}
    with pytest.raises(InputError, match=what) as e:
        rows.parse(**kw)
    assert e.value.field == opt and bad in str(e.value)


def test_holds_on_cells_as_written():
    c = rows.parse(["f!=50"])[0]
    # an empty cell fails a condition (so --where removes it, --exclude-rows keeps it)
    assert rows.holds(c, ["50", "50.0", "3", ""], ("",)).tolist() == [False, False, True, False]
    t = rows.parse(["f==Prep"])[0]
    assert rows.holds(t, ["Cut", "Prep", "", "Prep"], ("",)).tolist() == [False, True, False, True]
    with pytest.raises(InputError, match="holds text"):
        rows.holds(c, ["Cut", "Prep"], ("",))
    with pytest.raises(InputError, match="holds numbers"):
        rows.holds(t, ["1", "2"], ("",))


def _case(seed=3):
    """A backlash on x, REC at 200 Hz; 5 % of REC's rows (12 runs of 20) carry a fake offset
    of 50 µm on every output, and the logger marks them with ok = 0."""
    case = synth.make_case(["backlash"], seed=seed, duration=12.0, sim_rate=200, rec_rate=200)
    rec = dict(case.rec)
    bad = np.zeros(len(rec["t"]), bool)
    for s in np.random.default_rng(1).choice(len(bad) - 30, 8, replace=False):
        bad[s:s + 20] = True
    for k in ("x", "y", "z"):
        rec[k] = np.where(bad, rec[k] + 0.05, rec[k])
    rec["ok"] = (~bad).astype(float)
    return case, rec, bad


def test_rows_that_do_not_reflect_the_machine_would_ruin_the_fit_and_are_removed():
    case, rec, bad = _case()
    truth = case.truth[0][2]["backlash_mm"]
    ruined = diagnose(case.sim, rec)
    # the fake offset is many noise floors and no effect of the library: the fit is ruined
    assert max(ruined.fit["holdout_rms_after"][o] / ruined.noise_floor[o]
               for o in ruined.outputs) > 20
    res = diagnose(case.sim, rec, where=["ok==1"])
    assert res.names == ["backlash"], res.summary()
    e = res.effects[0]
    assert abs(e.params["backlash_mm"] - truth) < 3 * e.uncertainty["backlash_mm"] + 1e-12
    for o in res.outputs:
        assert res.fit["holdout_rms_after"][o] < 1.5 * res.noise_floor[o]
    rf = res.alignment["row_filter"]
    assert rf["rec_rows_removed"] == int(bad.sum()) and rf["sim_rows_removed"] == 0
    assert rf["conditions"] == ["--where 'ok==1'"]
    assert any(f"{int(bad.sum())} of {len(bad)} rows of REC removed" in n for n in res.notes)
    # the same rows by --exclude-rows
    res2 = diagnose(case.sim, rec, exclude_rows=["ok<0.5"])
    assert res2.names == ["backlash"]
    assert res2.alignment["samples"] == res.alignment["samples"]


def test_removed_rows_are_never_bridged():
    # SIM at 100 Hz, REC at 250 Hz: REC is evaluated at SIM's times (the grid) by its
    # interpolant.  One REC row, 2 ms before the grid time 2.01 s, reads 1 mm off and is removed:
    # the grid time 2.01 s, between it and the next row, takes no part, and no other grid time
    # sees the removed value (it does not feed the spline)
    case = synth.make_case([], seed=5, duration=6.0, sim_rate=100, rec_rate=250)
    rec = dict(case.rec)
    t = rec["t"]
    b = int(np.searchsorted(t, 2.01)) - 1
    assert 2.0 < t[b] < 2.01 < t[b + 1]
    rec["x"] = rec["x"].copy()
    rec["x"][b] += 1.0
    rec["flag"] = (np.arange(len(t)) == b).astype(float)
    res = diagnose(case.sim, rec, exclude_rows=["flag==1"])
    assert res.alignment["samples"] == res.alignment["grid_samples"] - 1
    assert res.alignment["row_filter"]["rec_rows_removed"] == 1
    k = int(np.argmin(np.abs(res.t - 2.01)))
    assert res.heldout_corrected["x"][k] == res.sim["x"][k]  # set aside, not interpolated
    assert res.names == [] and not res.unexplained, res.summary()
    assert res.fit["rms_after"]["x"] < 2 * res.noise_floor["x"]
    # without the filter the row is a 1 mm spike the diagnosis cannot call noise
    raw = diagnose(case.sim, rec)
    assert raw.fit["rms_after"]["x"] > 10 * raw.noise_floor["x"]


def test_text_column_and_unknown_column(tmp_path):
    t = np.arange(300) * 0.01
    x = 10 * np.sin(t)
    phase = np.where((t > 1.0) & (t < 1.3), "Prep", "Cut")
    sim = tmp_path / "sim.csv"
    rec = tmp_path / "rec.csv"
    sim.write_text("t,x,phase\n" + "".join(f"{a:.2f},{b:.6f},{p}\n" for a, b, p in zip(t, x, phase)))
    noise = 1e-4 * np.random.default_rng(0).normal(size=t.size)
    rec.write_text("t,x\n" + "".join(f"{a:.2f},{b + n + (0.5 if p == 'Prep' else 0):.6f}\n"
                                     for a, b, n, p in zip(t, x, noise, phase)))
    # a column of labels is no signal: left out with a note (the row filter may still use it)
    plain = diagnose(sim, rec)
    assert any("'phase'" in n and "holds text, not numbers" in n for n in plain.notes)
    # a column of numbers with one word in it is a corrupt cell: refused, naming the line
    bad = tmp_path / "bad.csv"
    bad.write_text(rec.read_text().replace("\n1.00,", "\n1.00,abc\n1.005,", 1))
    with pytest.raises(InputError, match="expected a number"):
        diagnose(sim, bad)
    res = diagnose(sim, rec, exclude_rows=["phase==Prep"])
    assert res.alignment["row_filter"]["sim_rows_removed"] == int((phase == "Prep").sum())
    assert any("'phase'" in n and "row filter only" in n for n in res.notes)
    assert res.fit["rms_after"]["x"] < 3 * res.noise_floor["x"], res.summary()
    with pytest.raises(InputError, match="no column 'FEED' in SIM or REC") as e:
        diagnose(sim, rec, where=["FEED!=50"], exclude_rows=["phase==Prep"])
    assert e.value.field == "--where"
    with pytest.raises(InputError, match="holds numbers") as e:
        diagnose(sim, rec, exclude_rows=["phase==Prep", "x==abc"])
    with pytest.raises(InputError, match="leaves 0 rows of"):
        diagnose(sim, rec, where=["x>1e6"], exclude_rows=["phase==Prep"])


def test_cli_bad_expression_exits_with_one_line(tmp_path, capsys):
    case = synth.make_case([], seed=1, duration=3.0)
    synth.write_csv(tmp_path / "sim.csv", case.sim)
    synth.write_csv(tmp_path / "rec.csv", case.rec)
    rc = main(["diagnose", "--sim", str(tmp_path / "sim.csv"), "--rec", str(tmp_path / "rec.csv"),
               "--exclude-rows", "aux0 ~ 3"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "--exclude-rows" in err and "Traceback" not in err
    assert len(err.splitlines()) == 1


def test_real_cnc_log_with_the_sources_validity_rule():
    # the committed excerpt of UMich run 06 carries the columns of the source's validity rule
    spec = importlib.util.spec_from_file_location("make_excerpt", UMICH / "make_excerpt.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    VALID_ROWS = mod.VALID_ROWS
    d = UMICH / "exp06"
    with open(d / "sim.csv") as f:
        sim_rows = list(csv.DictReader(f))
    with open(d / "rec.csv") as f:
        rec_rows = list(csv.DictReader(f))
    n_feed = sum(float(r["M1_CURRENT_FEEDRATE"]) == 50 for r in sim_rows)
    n_x = sum(float(r["X1_ActualPosition[mm]"]) == 198 for r in rec_rows)
    either = sum(float(a["M1_CURRENT_FEEDRATE"]) == 50 or float(b["X1_ActualPosition[mm]"]) == 198
                 for a, b in zip(sim_rows, rec_rows))
    res = diagnose(d / "sim.csv", d / "rec.csv", where=VALID_ROWS)
    rf = res.alignment["row_filter"]
    assert (rf["sim_rows_removed"], rf["rec_rows_removed"]) == (n_feed, n_x)
    # same clock, one row each: the samples used are the rows valid in both files
    assert res.alignment["samples"] == len(sim_rows) - either
    # the servo lag of every axis is still named on the valid rows
    lags = {e.outputs[0]: e for e in res.effects if e.name == "servo_lag"}
    assert set(lags) == {"vx", "vy", "vz"}, res.summary()
    for e in lags.values():
        assert 0.003 < e.params["tau_s"] < 0.015
