"""One log holding both the commanded and the measured signals, as controls and drive loggers
write it (the UMich runs as published: an unnamed row-index column, no time column, text
columns): `mtcomp diagnose --sim LOG --rec LOG --dt 0.1`."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mtcomp import InputError
from mtcomp.csvtable import parse_csv
from mtcomp.diagnose import data, diagnose
from mtcomp.diagnose.columns import role

RAW = Path(__file__).parent / "data" / "umich" / "exp11_raw" / "experiment_11_rows400-799.csv"
VEL = [f"{a}1_CommandVelocity={a}1_ActualVelocity" for a in "XYZ"]


def test_an_unnamed_first_column_is_a_row_index_only_where_asked():
    text = ",x,y\n0,1,2\n1,3,4\n"
    with pytest.raises(InputError, match="column 1 of the header has no name"):
        parse_csv(text)
    tab = parse_csv(text, index_name="(row index)")
    assert list(tab.names) == ["(row index)", "x", "y"]
    # only the first column: an unnamed column elsewhere is still an error
    with pytest.raises(InputError, match="column 2 of the header has no name"):
        parse_csv("a,,y\n0,1,2\n", index_name="(row index)")


def test_role_words():
    assert role("X1_CommandVelocity") == "command" and role("x_cmd") == "command"
    assert role("X1_ActualVelocity") == "measured" and role("Istposition") == "measured"
    assert role("Sollposition") == "command"
    assert role("X1_OutputCurrent") is None and role("vx") is None


def test_raw_log_without_time_column_needs_the_period(tmp_path):
    with pytest.raises(InputError, match="--dt 0.1"):
        diagnose(RAW, RAW, outputs=VEL)


def test_raw_log_read_with_its_index_and_period():
    tab = data.read_table(RAW, dt=0.1)
    # the index column starts at 400: t counts from the first row, 0.1 s per index step
    assert tab.t[0] == 0.0 and tab.t[-1] == pytest.approx(39.9)
    assert "(row index)" not in tab.columns
    assert "Machining_Process" not in tab.columns   # text: left out, with a note
    assert any("holds text" in n for n in tab.notes)


def test_rows_removed_before_keep_their_instants(tmp_path):
    lines = RAW.read_text().splitlines()
    f = tmp_path / "cut.csv"
    f.write_text("\n".join(lines[:1] + lines[1:11] + lines[21:41]) + "\n")
    tab = data.read_table(f, dt=0.1)
    assert np.allclose(tab.t[:10], 0.1 * np.arange(10))
    assert tab.t[10] == pytest.approx(2.0)   # index 420 after 409: 1 s missing


def test_one_log_names_the_servo_lags_and_keeps_measurements_out_of_the_inputs():
    res = diagnose(RAW, RAW, outputs=VEL, dt=0.1)
    lag = {o for e in res.effects if e.name == "servo_lag" for o in e.outputs}
    # X and Y move through these 40 s; the drives follow with a first-order lag
    assert {"X1_ActualVelocity", "Y1_ActualVelocity"} <= lag
    for o in ("X1_ActualVelocity", "Y1_ActualVelocity"):
        assert res.fit["holdout_rms_after"][o] < 0.6 * res.fit["holdout_rms_before"][o]
    text = res.summary()
    assert "one log for SIM and REC" in text and "both on one clock" in text
    # no measured signal (a current, an actual acceleration) explains a measured velocity
    for e in res.effects:
        for c in e.inputs:
            assert role(c) != "measured" or c in res.outputs, (e.name, c)
    assert "OutputCurrent" not in text.split("effects:")[1]


def test_one_log_from_the_command_line(tmp_path):
    out = tmp_path / "r.json"
    args = [sys.executable, "-m", "mtcomp", "diagnose", "--sim", str(RAW), "--rec", str(RAW),
            "--dt", "0.1", "--json", str(out), "--quiet"]
    for o in VEL:
        args += ["--output", o]
    p = subprocess.run(args, capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    res = json.loads(out.read_text())
    assert res["outputs"] == ["X1_ActualVelocity", "Y1_ActualVelocity", "Z1_ActualVelocity"]
    # without --dt: one line naming the option, no traceback
    p = subprocess.run(args[:6] + ["--quiet"], capture_output=True, text=True)
    assert p.returncode == 2 and "--dt" in p.stderr and "Traceback" not in p.stderr


def test_one_log_under_other_names_units_and_quantisation(tmp_path):
    """The same log written as another control would: German role words, m/min quantised to
    0.001 m/min, time in ms, a drive current with no role word: the same lags."""
    import csv
    rows = list(csv.reader(RAW.open()))
    h = rows[0]
    ren = {"X1_CommandVelocity": "vx_soll[m/min]", "X1_ActualVelocity": "vx_ist[m/min]",
           "Y1_CommandVelocity": "vy_soll[m/min]", "Y1_ActualVelocity": "vy_ist[m/min]",
           "X1_CommandAcceleration": "ax_soll[mm/s^2]", "Y1_CommandAcceleration": "ay_soll[mm/s^2]",
           "X1_OutputCurrent": "Strom_X"}
    f = tmp_path / "log.csv"
    lines = ["Zeit[ms]," + ",".join(ren.values())]
    for i, r in enumerate(rows[1:]):
        vals = [round(float(r[h.index(k)]) * 0.06, 3) if "Velocity" in k else float(r[h.index(k)])
                for k in ren]
        lines.append(f"{100 * i}," + ",".join(repr(v) for v in vals))
    f.write_text("\n".join(lines) + "\n")
    ref = diagnose(RAW, RAW, outputs=VEL, dt=0.1)
    res = diagnose(f, f)
    lag = {e.outputs[0]: e.params["tau_s"] for e in res.effects if e.name == "servo_lag"}
    lag_ref = {e.outputs[0]: e.params["tau_s"] for e in ref.effects if e.name == "servo_lag"}
    for o, r in (("vx_ist", "X1_ActualVelocity"), ("vy_ist", "Y1_ActualVelocity")):
        assert lag[o] == pytest.approx(lag_ref[r], rel=0.15), (lag, lag_ref)
    assert any("Strom_X" in n and "left out" in n for n in res.notes)
