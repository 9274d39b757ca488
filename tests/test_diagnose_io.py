"""Diagnosis input/output: units in headers, bad files, the CLI and its outputs."""
import json
import math
import subprocess
import sys

import numpy as np
import pytest

from mtcomp import InputError
from mtcomp.cli import main
from mtcomp.diagnose import data, diagnose, synth
from mtcomp.diagnose.align import noise_sigma


def _write(path, header, rows):
    path.write_text(header + "\n" + "\n".join(",".join(str(v) for v in r) for r in rows) + "\n")
    return path


def test_units_in_headers_are_converted(tmp_path):
    f = _write(tmp_path / "a.csv", "t[ms],x[um],b[rad],T_spindle[K],S[rpm],load[%],y",
               [[0, 1500, math.pi / 2, 293.15, 1000, 5, 2.0], [10, 2500, math.pi, 294.15, 2000, 6, 3.0]])
    tab = data.read_table(f)
    assert tab.t.tolist() == [0.0, 0.01]
    c = tab.columns
    assert c["x"].kind == "length" and c["x"].values.tolist() == pytest.approx([1.5, 2.5])
    assert c["b"].kind == "angle" and c["b"].values.tolist() == pytest.approx([90.0, 180.0])
    # names are kept as written (case-sensitive)
    assert c["T_spindle"].kind == "temperature" and c["T_spindle"].values.tolist() == pytest.approx([20.0, 21.0])
    assert c["S"].kind == "speed"
    assert c["load"].kind == "other" and c["load"].unit == "%"
    assert c["y"].kind == "length" and c["y"].unit == "mm"  # no unit: the name says length


def test_unit_less_names_get_their_kind():
    k = data.kind_from_name
    assert [k("x"), k("y_cmd"), k("b"), k("c1"), k("t_bed"), k("temp2"), k("s"), k("spindle_speed"),
            k("aux0"), k("t")] == ["length", "length", "angle", "angle", "temperature",
                                   "temperature", "speed", "speed", "other", "time"]


def test_um_recording_matches_mm_simulation():
    case = synth.make_case([], seed=1, duration=20.0, um_headers=True)
    assert "z[um]" in case.rec
    res = diagnose(case.sim, case.rec)
    assert res.outputs == ("x", "y", "z") and res.effects == ()
    assert res.fit["rms_before"]["z"] < 30e-6  # a missed um->mm conversion would be ~1000x


def test_quantisation_sets_the_noise_floor():
    r = np.round(np.random.default_rng(0).normal(0, 1e-5, 5000) / 1e-4) * 1e-4
    # mostly zeros: the MAD of differences is 0, the floor is the resolution's q/sqrt(12)
    assert noise_sigma(r, 1e-4) == pytest.approx(1e-4 / math.sqrt(12))
    q = data._quantum(np.round(np.linspace(0, 1, 1000) / 1e-3) * 1e-3)
    assert q == pytest.approx(1e-3)
    assert data._quantum(np.random.default_rng(1).normal(size=1000)) == 0.0


BAD = {
    "no_t": ("clock,x\n0,1\n1,2\n2,3\n", "no time column `t`"),
    "unsorted": ("t,x\n0,1\n1,2\n0.5,3\n2,4\n", "t must increase"),
    "overflow": ("t,x\n0,1\n1,1e400\n2,3\n", "out of range"),
    "inf": ("t,x\n0,1\n1,inf\n2,3\n", "expected a number"),
    "text": ("t,x\n0,1\n1,abc\n2,3\n", "expected a number"),
    "short_row": ("t,x\n0,1\n1\n2,3\n", "expected 2 values"),
}


@pytest.mark.parametrize("kind", sorted(BAD))
def test_bad_rec_file_gives_clear_error_and_exit_2(tmp_path, capsys, kind):
    text, msg = BAD[kind]
    sim = _write(tmp_path / "sim.csv", "t,x", [[i * 0.1, i] for i in range(40)])
    rec = tmp_path / "rec.csv"
    rec.write_text(text)
    out = tmp_path / "out.json"
    rc = main(["diagnose", "--sim", str(sim), "--rec", str(rec), "--json", str(out)])
    err = capsys.readouterr().err
    assert rc == 2
    assert msg in err and "rec.csv" in err
    if kind in ("unsorted", "overflow", "inf", "text", "short_row"):
        assert "rec.csv:3" in err or "rec.csv:4" in err  # the line is named
    assert not out.exists()


def test_no_common_output_and_no_overlap(tmp_path, capsys):
    sim = _write(tmp_path / "sim.csv", "t,x", [[i * 0.1, i] for i in range(40)])
    rec = _write(tmp_path / "rec.csv", "t,y", [[i * 0.1, i] for i in range(40)])
    assert main(["diagnose", "--sim", str(sim), "--rec", str(rec)]) == 2
    assert "no output to compare" in capsys.readouterr().err
    rec2 = _write(tmp_path / "rec2.csv", "t,x", [[100 + i * 0.1, i] for i in range(40)])
    assert main(["diagnose", "--sim", str(sim), "--rec", str(rec2)]) == 2
    assert "do not overlap" in capsys.readouterr().err
    with pytest.raises(InputError, match="not found"):
        diagnose(tmp_path / "missing.csv", rec)


def test_cli_subprocess_writes_json_plot_and_report(tmp_path):
    case = synth.make_case(["squareness"], seed=4, duration=20.0, sim_rate=200.0, rec_rate=100.0)
    sim, rec = tmp_path / "sim.csv", tmp_path / "rec.csv"
    synth.write_csv(sim, case.sim)
    synth.write_csv(rec, case.rec)
    js, png, md = tmp_path / "out" / "d.json", tmp_path / "out" / "d.png", tmp_path / "out" / "d.md"
    (tmp_path / "out").mkdir()  # the CLI writes into existing folders only
    p = subprocess.run([sys.executable, "-m", "mtcomp", "diagnose", "--sim", str(sim), "--rec", str(rec),
                        "--json", str(js), "--plot", str(png), "--report", str(md)],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    assert "squareness on y" in p.stdout
    d = json.loads(js.read_text())
    assert [e["name"] for e in d["effects"]] == ["squareness"]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = md.read_text()
    assert "squareness" in text and "](d.png)" in text
    p = subprocess.run([sys.executable, "-m", "mtcomp", "diagnose", "--sim", str(sim)],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode != 0 and "--rec" in p.stderr


def test_library_accepts_arrays_with_units():
    case = synth.make_case(["backlash"], seed=6, duration=20.0)
    rec = dict(case.rec)
    rec["x[um]"] = rec.pop("x") * 1e3
    res = diagnose(case.sim, rec)
    assert res.names == ["backlash"]
    assert "backlash on x" in res.summary()
