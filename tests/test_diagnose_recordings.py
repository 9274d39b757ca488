"""Several recordings of one machine: one set of physical parameters, a clock per recording,
validation leave-one-recording-out."""
import subprocess
import sys

import pytest

from mtcomp import InputError
from mtcomp.diagnose import diagnose, synth

KV = 40.0


def _runs(tmp_path, n=3):
    sims, recs = [], []
    for i in range(n):
        # each recording of its own length, REC starting 0.2 .. 0.6 s before SIM
        case = synth.make_case([("servo_lag", {"kv_per_s": KV})], seed=20 + i,
                               rec_start=-0.2 - 0.2 * i,
                               duration=8.0, sim_rate=100.0, rec_rate=100.0, n_temps=1, n_junk=0)
        d = tmp_path / f"run{i}"
        d.mkdir()
        synth.write_csv(d / "sim.csv", case.sim)
        synth.write_csv(d / "rec.csv", case.rec)
        sims.append(d / "sim.csv")
        recs.append(d / "rec.csv")
    return sims, recs


def test_one_lag_across_recordings_each_predicted_from_the_others(tmp_path):
    sims, recs = _runs(tmp_path)
    res = diagnose(sims, recs)
    assert res.names == ["servo_lag"], res.summary()
    assert res.effects[0].params["kv_per_s"] == pytest.approx(KV, rel=0.02)
    per = res.fit["recordings"]
    assert list(per) == ["run0", "run1", "run2"]
    for name, d in per.items():
        # held out: the recording is predicted by the lag fitted on the two others
        assert d["ratio"] < 0.1, (name, d)
    assert [r["name"] for r in res.alignment["recordings"]] == ["run0", "run1", "run2"]


def test_cli_repeats_sim_and_rec(tmp_path):
    sims, recs = _runs(tmp_path, 2)
    args = []
    for s, r in zip(sims, recs):
        args += ["--sim", str(s), "--rec", str(r)]
    out = subprocess.run([sys.executable, "-m", "mtcomp", "diagnose", *args, "--json",
                          str(tmp_path / "o.json")], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    import json
    d = json.loads((tmp_path / "o.json").read_text())
    assert set(d["fit"]["recordings"]) == {"run0", "run1"}


def test_unequal_counts_refused(tmp_path):
    sims, recs = _runs(tmp_path, 2)
    with pytest.raises(InputError, match="2 SIM and 1 REC"):
        diagnose(sims, recs[:1])
