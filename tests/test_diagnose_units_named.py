"""Units said by name or refused by name; duplicated time stamps refused by line; the unit
mistakes (x1000, ms for s) told before any physics."""
import subprocess
import sys

import numpy as np
import pytest

from mtcomp import InputError
from mtcomp.diagnose import data, diagnose, synth

SHORT = dict(duration=12.0, sim_rate=100.0, rec_rate=250.0, n_temps=1, n_junk=0)


def _csv(path, header, rows):
    path.write_text(header + "\n" + "\n".join(",".join(f"{v:.10g}" for v in r) for r in rows) + "\n")
    return path


def test_units_in_names_and_brackets(tmp_path):
    t = np.arange(10) * 0.1
    p = _csv(tmp_path / "a.csv", "t,pos_um,x[0.1um],b[arcmin],c_arcsec,q[arcsec]",
             [(ti, 1000.0 * i, 10.0 * i, 60.0 * i, 3600.0 * i, 1.0) for i, ti in enumerate(t)])
    tab = data.load(p, "REC")
    assert tab.columns["pos_um"].values[2] == pytest.approx(2.0)      # µm -> mm
    assert tab.columns["x"].values[2] == pytest.approx(2e-3)          # counts of 0.1 µm -> mm
    assert tab.columns["b"].values[2] == pytest.approx(2.0)           # arcmin -> deg
    assert tab.columns["c_arcsec"].values[2] == pytest.approx(2.0)
    assert tab.columns["pos_um"].unit == "mm"


def test_time_in_ms_by_name(tmp_path):
    p = _csv(tmp_path / "a.csv", "t_ms,x", [(100.0 * i, i) for i in range(10)])
    assert data.load(p, "REC").t[-1] == pytest.approx(0.9)


@pytest.mark.parametrize("header,unit", [("x[counts]", None), ("x", "counts")])
def test_counts_refused_by_name(tmp_path, header, unit):
    p = _csv(tmp_path / "a.csv", f"t,{header}", [(0.1 * i, i) for i in range(10)])
    with pytest.raises(InputError, match="a count needs its size.*0.1um"):
        data.load(p, "REC", units={"x": unit} if unit else None)


def test_duplicated_time_stamp_refused_by_line(tmp_path):
    # before: averaged with exit 0, although a time going back is refused ("t must increase")
    rows = [(0.1 * i, float(i)) for i in range(10)]
    rows.insert(5, (rows[4][0], 7.5))
    p = _csv(tmp_path / "rec.csv", "t,x", rows)
    with pytest.raises(InputError) as e:
        data.load(p, "REC")
    assert e.value.line == 7 and "repeats the time stamp of line 6" in str(e.value)
    s = _csv(tmp_path / "sim.csv", "t,x", [(0.1 * i, float(i)) for i in range(10)])
    out = subprocess.run([sys.executable, "-m", "mtcomp", "diagnose", "--sim", str(s), "--rec",
                          str(p)], capture_output=True, text=True)
    assert out.returncode != 0 and "rec.csv:7" in out.stderr and "Traceback" not in out.stderr


def test_row_written_twice_is_kept_once(tmp_path):
    rows = [(0.1 * i, float(i)) for i in range(10)]
    rows.insert(5, rows[4])
    tab = data.load(_csv(tmp_path / "rec.csv", "t,x", rows), "REC")
    assert len(tab.t) == 10 and any("kept once" in n for n in tab.notes)


def test_unknown_unit_of_a_compared_column_refused(tmp_path):
    case = synth.make_case([], seed=1, **SHORT)
    rec = {("x[furlong]" if k == "x" else k): v for k, v in case.rec.items()}
    sim = {("x[furlong]" if k == "x" else k): v for k, v in case.sim.items()}
    with pytest.raises(InputError, match="unknown unit 'furlong' of compared column 'x'"):
        diagnose(sim, rec)


def test_rec_in_um_under_a_plain_header_warned():
    # before: `scale_error` x1005 named on y, no word of the unit
    case = synth.make_case([], seed=2, **SHORT)
    rec = dict(case.rec, y=case.rec["y"] * 1e3)
    res = diagnose(case.sim, rec)
    said = [n for n in res.notes if n.startswith("likely unit mistake") and "REC's y x 0.001" in n]
    assert said and "y[um]" in said[0], res.notes


def test_rec_time_in_ms_warned():
    # before: "8 samples, step 2.5e+03 ms" and a diagnosis without a word of the unit
    case = synth.make_case([], seed=3, **SHORT)
    rec = dict(case.rec, t=case.rec["t"] * 1e3)
    try:
        res = diagnose(case.sim, rec)
        text = " ".join(res.notes)
    except InputError as e:
        text = str(e)
    assert "likely unit mistake: REC's time spans" in text and "t[ms]" in text
