"""mtcomp.fleet without a cluster: the change and limit tests, the limits TOML, the source
folder/manifest, the dataset's atomic partitions, the generator's histories, and the message
when Dask is not installed."""
from __future__ import annotations

import math
import os
import subprocess
import sys

import pytest

from mtcomp import InputError
from mtcomp.fleet.generate import FleetSpec, changed, history
from mtcomp.fleet.night import param_unit
from mtcomp.fleet.source import plan
from mtcomp.fleet.trend import Limits, Rule, Series, change_warnings, limit_warnings, limits_from


def _series(values, sigma=0.01, machine="m1", parameter="backlash_mm"):
    dates = tuple(f"2026-01-{i + 1:02d}" for i in range(len(values)))
    sig = sigma if isinstance(sigma, (list, tuple)) else [sigma] * len(values)
    return Series(machine, "backlash", "x", parameter, "mm", dates, tuple(values), tuple(sig))


# --- the change test ------------------------------------------------------------------------

def test_step_warns_once():
    s = _series([1.0, 1.001, 0.999, 1.0, 1.2, 1.201, 1.199, 1.2])
    w = change_warnings(s, k=5.0, window=5)
    assert [x.date for x in w] == ["2026-01-05"]
    # the reference was the inverse-variance mean of the four nights before
    assert w[0].reference == pytest.approx(1.0)
    assert w[0].band == pytest.approx(0.01 * math.sqrt(1 + 1 / 4))


def test_growth_warns_every_night_it_grows_beyond_the_band():
    s = _series([1.0, 1.0, 1.0, 1.1, 1.2, 1.3])
    assert [x.date for x in change_warnings(s, 5.0, 5)] == ["2026-01-04", "2026-01-05", "2026-01-06"]


def test_within_band_is_silent_and_threshold_is_k_combined_sigma():
    # |1.06 - 1.0| = 6 sigma of each night, 6/sqrt(2) = 4.24 combined sigmas
    assert change_warnings(_series([1.0, 1.06]), 5.0, 5) == []
    assert len(change_warnings(_series([1.0, 1.06]), 4.0, 5)) == 1


def test_birge_ratio_widens_the_band_by_the_night_to_night_scatter():
    # nights scatter by about 3 sigma while each says sigma 0.01; the 5th night is 0.06 off:
    # 5.4 sigma combined, but the reference's chi2/dof = 6 (B = 2.45) says 2.2 bands
    vals = [1.0, 1.03, 0.97, 1.0, 1.06]
    assert change_warnings(_series(vals), 5.0, 5) == []
    w = change_warnings(_series(vals + [1.3]), 5.0, 5)
    assert [x.date for x in w] == ["2026-01-06"]
    assert w[0].band == pytest.approx(math.sqrt(46.8 / 4) * 0.01 * math.sqrt(1 + 1 / 5), rel=1e-3)


def test_limits_rule_and_fnmatch():
    s = _series([0.004, 0.009, 0.012])
    r = Rule("backlash_*", output="x", max=0.010)
    w = limit_warnings(s, [r])
    assert [(x.date, x.limit) for x in w] == [("2026-01-03", 0.010)]
    assert limit_warnings(s, [Rule("backlash_mm", output="y", max=0.0)]) == []
    assert limit_warnings(s, [Rule("backlash_mm", min=0.005)])[0].date == "2026-01-01"


def test_limits_toml(tmp_path):
    lim = limits_from({"change": {"k": 4, "window": 3},
                       "limit": [{"parameter": "kv_per_s", "machine": "m0*", "min": 20.0}]})
    assert lim == Limits(4.0, 3, (Rule("kv_per_s", machine="m0*", min=20.0),))
    from mtcomp.fleet.trend import load_limits
    f = tmp_path / "l.toml"
    f.write_text('[change]\nk = 5\n\n[[limit]]\nparameter = "backlash_mm"\nmaxx = 0.01\n')
    with pytest.raises(InputError, match=r"l.toml:6 \[limit\[0\].maxx\]: unknown key"):
        load_limits(f)
    for data, field in [({"change": {"k": -1}}, "change.k"),
                        ({"change": {"window": 0}}, "change.window"),
                        ({"limit": [{"max": 1.0}]}, "limit[0].parameter"),
                        ({"limit": [{"parameter": "a"}]}, "limit[0]"),
                        ({"limit": [{"parameter": "a", "min": 2.0, "max": 1.0}]}, "limit[0]"),
                        ({"limits": []}, "limits")]:
        with pytest.raises(InputError) as e:
            limits_from(data)
        assert e.value.field == field


def test_nuisance_and_fixed_parameters_are_not_trended():
    from mtcomp.fleet.trend import trended
    assert trended("backlash", "backlash_mm", 1e-5)
    assert not trended("backlash", "initial_state_mm", 1e-5)
    assert not trended("thermal_drift", "offset_mm", 1e-5)
    assert trended("time_offset", "offset_s", 1e-5)
    assert not trended("servo_lag", "tau_s", 1e-6)          # 1/kv, trended as kv
    assert not trended("thermal_drift", "tau_s", 0.0)       # fixed by the model's form


def test_param_unit():
    assert param_unit("backlash_mm") == "mm"
    assert param_unit("kv_per_s") == "1/s"
    assert param_unit("gain_mm_per_degC") == "mm/degC"
    assert param_unit("tau_s") == "s"
    assert param_unit("scale") == ""
    assert param_unit("coulomb_mm_s") == "mm/s"
    assert param_unit("initial_state_mm") == "mm"


# --- the generator's histories ----------------------------------------------------------------

def test_generated_histories():
    spec = FleetSpec(machines=4, nights=6, grow_machine=1, grow_from=3, repair_machine=2,
                     repair_night=4)
    b = [history(spec, 1, k)["backlash_mm"] for k in range(6)]
    assert b[0] == b[1] == b[2] and b[3] - b[2] == pytest.approx(spec.grow_per_night)
    kv = [history(spec, 2, k)["kv_per_s"] for k in range(6)]
    assert kv[4] == pytest.approx(spec.repair_kv * kv[3]) and kv[5] == kv[4]
    g = [history(spec, 0, k)["gain_mm_per_degC"] for k in range(6)]
    # the season: spring (March) warms, the gain rises slowly (< 0.1 % a night)
    assert all(0 < g[k + 1] / g[k] - 1 < 1e-3 for k in range(5))
    d = spec.dates()
    assert changed(spec) == {("m2", d[3], "backlash_mm"), ("m2", d[4], "backlash_mm"),
                             ("m2", d[5], "backlash_mm"), ("m3", d[4], "kv_per_s")} or \
        changed(spec) == {("m02", d[3], "backlash_mm"), ("m02", d[4], "backlash_mm"),
                          ("m02", d[5], "backlash_mm"), ("m03", d[4], "kv_per_s")}


# --- source: folder and manifest ----------------------------------------------------------------

def _night(root, m, d, files=("sim.csv", "rec.csv")):
    p = root / m / d
    p.mkdir(parents=True)
    for f in files:
        (p / f).write_text("t,x\n0,0\n")
    return p


def test_plan_folder_with_machine_options(tmp_path):
    _night(tmp_path, "m1", "2026-01-02")
    _night(tmp_path, "m1", "2026-01-01")
    _night(tmp_path, "m2", "2026-01-01")
    (tmp_path / "m2" / "diagnose.toml").write_text('output = ["x"]\nsame_clock = true\ndt = 0.1\n')
    jobs = plan(tmp_path, {"same_clock": False, "where": ["x<5"]})
    assert [(j.machine, j.date) for j in jobs] == [("m1", "2026-01-01"), ("m1", "2026-01-02"),
                                                    ("m2", "2026-01-01")]
    assert jobs[0].options == {"same_clock": False, "where": ["x<5"]}
    assert jobs[2].options == {"outputs": ["x"], "same_clock": True, "dt": 0.1, "where": ["x<5"]}


def test_plan_folder_errors(tmp_path):
    _night(tmp_path, "m1", "2026-13-01")
    with pytest.raises(InputError, match="2026-13-01.*expected an ISO date"):
        plan(tmp_path)
    other = tmp_path / "o"
    _night(other, "m1", "2026-01-01", files=("sim.csv",))
    with pytest.raises(InputError, match="rec.csv missing"):
        plan(other)
    with pytest.raises(InputError, match="not found"):
        plan(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no recordings"):
        plan(tmp_path / "empty")


def test_plan_manifest(tmp_path):
    _night(tmp_path, "a", "x")
    (tmp_path / "man.csv").write_text(
        "# fleet of two\nmachine,date,sim,rec,output,same_clock\n"
        "m1,2026-01-01,a/x/sim.csv,a/x/rec.csv,x;y,true\n"
        "m2,2026-01-01,a/x/sim.csv,a/x/rec.csv,,\n")
    jobs = plan(tmp_path / "man.csv")
    assert jobs[0].options == {"outputs": ["x", "y"], "same_clock": True}
    assert jobs[1].options == {}
    assert jobs[0].recordings == ((str(tmp_path / "a/x/sim.csv"), str(tmp_path / "a/x/rec.csv")),)
    bad = tmp_path / "bad.csv"
    bad.write_text("machine,date,sim\nm1,2026-01-01,a/x/sim.csv\n")
    with pytest.raises(InputError, match=r"bad.csv:1: header lacks column\(s\) rec"):
        plan(bad)
    bad.write_text("machine,date,sim,rec\nm1,2026-01-01,a/x/sim.csv,a/x/nope.csv\n")
    with pytest.raises(InputError, match=r"bad.csv:2 \[rec\]: rec file 'a/x/nope.csv' not found"):
        plan(bad)
    bad.write_text("machine,date,sim,rec,dt\nm1,2026-01-01,a/x/sim.csv,a/x/rec.csv,-1\n")
    with pytest.raises(InputError, match=r"bad.csv:2 \[dt\]"):
        plan(bad)
    bad.write_text("machine,date,sim,rec,dt\nm1,2026-01-01,a/x/sim.csv,a/x/rec.csv,0.1\n"
                   "m1,2026-01-01,a/x/sim.csv,a/x/rec.csv,0.2\n")
    with pytest.raises(InputError, match=r"bad.csv:3: options differ"):
        plan(bad)


# --- one night on a worker, and the dataset ---------------------------------------------------------

def test_bad_night_becomes_an_error_row(tmp_path):
    from mtcomp.fleet.night import run_job
    from mtcomp.fleet.source import Job
    p = _night(tmp_path, "m1", "2026-01-01")
    (p / "sim.csv").write_text("t,x\n0,0\n1,1\n2,2\n")
    (p / "rec.csv").write_text("t,x\n0,0\n1,zz\n2,2\n")
    rows = run_job(Job("m1", "2026-01-01", ((str(p / "sim.csv"), str(p / "rec.csv")),)))
    assert len(rows) == 1 and rows[0]["effect"] == "error"
    assert rows[0]["status"].startswith("error: ") and "rec.csv" in rows[0]["status"]
    assert len(rows[0]["rec_sha256"]) == 64


def test_partition_replaced_atomically(tmp_path):
    pytest.importorskip("pyarrow")
    from mtcomp.fleet.dataset import PART, TMP, read, write_night
    from mtcomp.fleet.night import error_rows
    ds = tmp_path / "ds"
    write_night(ds, "m1", "2026-01-01", error_rows({}, "first"))
    write_night(ds, "m1", "2026-01-02", error_rows({}, "other"))
    write_night(ds, "m1", "2026-01-01", error_rows({}, "second"))
    t = read(ds).to_pylist()
    assert [(r["date"], r["status"]) for r in t] == [("2026-01-01", "second"), ("2026-01-02", "other")]
    assert len(list(ds.rglob("*.parquet"))) == 2
    # a write that fails (a value of the wrong type) leaves the old partition and no temp file
    with pytest.raises(Exception):
        write_night(ds, "m1", "2026-01-01", [dict(error_rows({}, "x")[0], value="not a number")])
    assert read(ds).to_pylist()[0]["status"] == "second"
    assert list((ds / TMP).iterdir()) == []
    assert (ds / "machine=m1" / "date=2026-01-01" / PART).is_file()
    from mtcomp.fleet.trend import trends
    tr = trends(read(ds))
    assert tr.errors == (("m1", "2026-01-01", "second"), ("m1", "2026-01-02", "other"))


def test_read_not_a_dataset(tmp_path):
    pytest.importorskip("pyarrow")
    from mtcomp.fleet.dataset import read
    with pytest.raises(InputError, match="no partitions"):
        read(tmp_path)


# --- without Dask -------------------------------------------------------------------------------

@pytest.mark.parametrize("argv", [["fleet"], ["fleet", "diagnose", "src", "-o", "ds"]])
def test_without_dask_says_how_to_install(argv, tmp_path):
    code = ("import sys; sys.modules['distributed'] = None; from mtcomp.cli import main; "
            f"sys.exit(main({argv!r}))")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path,
                       env=dict(os.environ, PYTHONWARNINGS="ignore"))
    assert p.returncode == 2
    assert "pip install 'mtcomp[fleet]'" in p.stderr and "dask[distributed]" in p.stderr
    assert "Traceback" not in p.stderr


def _write_synthetic(ds, machines=3, nights=4, step=("m2", 2), misfit=("m1", 3)):
    """Rows made as a worker makes them, from NightResults with a kv that steps once on one
    machine, and jumps on one night of another whose diagnosis left x unexplained."""
    from mtcomp.fleet.adapter import EffectRow, NightResult
    from mtcomp.fleet.dataset import write_night
    from mtcomp.fleet.night import rows_of
    for i in range(machines):
        m = f"m{i + 1}"
        for k in range(nights):
            kv = 40.0 + i + 0.001 * (-1) ** k + (8.0 if (m, k) >= step and m == step[0] else 0.0)
            bad = (m, k) == misfit
            kv += 1.0 if bad else 0.0
            res = NightResult(
                outputs=("x", "y"), units={"x": "mm", "y": "mm"},
                effects=(EffectRow("servo_lag", ("y",), {"kv_per_s": kv, "tau_s": 1 / kv},
                                   {"kv_per_s": 0.002, "tau_s": 0.002 / kv ** 2}),),
                rms_before={"x": 1e-3, "y": 0.2}, rms_after={"x": 1e-3, "y": 3e-4},
                holdout_before={"x": 1e-3, "y": 0.2}, holdout_after={"x": 1e-3, "y": 3e-4},
                noise_floor={"x": 3e-4, "y": 3e-4}, unexplained=("x",) if bad else (),
                samples=600)
            write_night(ds, m, f"2026-01-0{k + 1}", rows_of(res, {"status": "ok"}))


def test_report_cli_from_a_written_dataset(tmp_path, capsys):
    pytest.importorskip("pyarrow")
    from mtcomp.cli import main
    from mtcomp.fleet.dataset import read
    from mtcomp.fleet.report import html
    from mtcomp.fleet.trend import trends
    ds = tmp_path / "ds"
    _write_synthetic(ds)
    t = read(ds).to_pylist()
    bad = [r for r in t if (r["machine"], r["date"]) == ("m1", "2026-01-04")]
    assert {(r["effect"], r["output"], r["unexplained"], r["night_unexplained"]) for r in bad} == \
        {("none", "x", True, "x"), ("servo_lag", "y", False, "x")}
    kv = [r for r in t if r["parameter"] == "kv_per_s"]
    assert {r["unit"] for r in kv} == {"1/s"} and kv[0]["holdout_gain"] == pytest.approx(1 - 3e-4 / 0.2)
    out = tmp_path / "r.html"
    assert main(["fleet", "report", str(ds), "-o", str(out)]) == 1
    said = capsys.readouterr().out
    # m2's step warns; m1's jump of 500 sigma on a night not explained does not
    assert "warning: m2 2026-01-03 y servo_lag.kv_per_s: change" in said
    assert said.count("warning:") == 1
    tr = trends(read(ds))
    assert tr.unexplained == (("m1", "2026-01-04", "x", "servo_lag(y)"),)
    assert "Nights not explained" in out.read_text()
    assert out.read_text().count("data:image/png;base64,") == 3
    page = html(trends(read(ds)), max_figures=2)
    assert page.count("data:image/png;base64,") == 1 and "figures only for the 1 with a warning" in page
    # a limit: kv of every machine must stay below 45 1/s: m2's three stepped nights cross it
    lim = tmp_path / "l.toml"
    lim.write_text('[[limit]]\nparameter = "kv_per_s"\nmax = 45.0\n')
    assert main(["fleet", "report", str(ds), "-o", str(out), "--limits", str(lim), "--quiet"]) == 1
    from mtcomp.fleet.trend import load_limits
    tr = trends(read(ds), load_limits(lim))
    assert [(w.machine, w.date) for w in tr.warnings if w.kind == "limit"] == \
        [("m2", "2026-01-03"), ("m2", "2026-01-04")]
