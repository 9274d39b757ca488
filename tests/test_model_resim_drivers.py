"""Re-simulation with what was recorded: a temperature logged only in REC drives the
re-simulated thermal drift; a drift whose driver was logged nowhere is named as not
re-simulated; the residual is reported beside its floor (noise, REC's quantisation, the
resampling) and above 3x the floor the model is called incomplete, with where."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("fmpy")

from mtcomp.model.floor import interpolation_error, noise_from_recording, quantisation_step  # noqa: E402

M = "vmc-moving-column"
STEP = 2e-3
NOISE = 2e-4          # mm: 0.2 µm, the noise
PROGRAM = "G90 G1 F1200\nX0 Y0 Z0\nX20 Y5\nX-20 Y-10\nX15 Y10\nX-15 Y-5\nX0 Y0\n"


def _temperature(t):
    return 21.0 + 0.4 * (t > 0.7) - 0.3 * (t > 1.9) + 0.5 * (t > 3.1) + 0.2 * np.sin(t / 0.7)


def _run(cwd, *a, ok=True):
    r = subprocess.run([sys.executable, "-m", "mtcomp", *map(str, a)], capture_output=True, text=True, cwd=cwd)
    if ok:
        assert r.returncode == 0, r.stderr
    return r


@pytest.fixture(scope="module")
def thermal_case(tmp_path_factory):
    """SIM made without any driver; REC with a thermal drift (4 µm/K, tau 2 s) driven by a
    temperature that only REC logs, plus a 3 µm backlash on X, noise 0.2 µm (the issue's third
    loop case).  Made and diagnosed through the library (the same code as `model simulate` and
    `diagnose --json`); the re-simulation is the command under test."""
    from mtcomp.diagnose import diagnose
    from mtcomp.fmu.build import MachineDynamics
    from mtcomp.model.simulate import simulate, write_signals
    d = tmp_path_factory.mktemp("thermal_rec_only")
    (d / "p.nc").write_text(PROGRAM)
    sim = simulate(d / "p.nc", M, step=STEP, compiler="cc")
    write_signals(d / "sim.csv", sim, M, program=d / "p.nc", step=STEP)
    dyn = MachineDynamics(thermal_driver="temperature", thermal_time_constant=2.0, drift=(0, 0, 0.004),
                          backlash=(0.003, 0, 0), noise=NOISE, seed=3)
    rec = simulate(d / "p.nc", M, None, dyn, step=STEP, temperature=_temperature, compiler="cc")
    write_signals(d / "rec.csv", rec, M, program=d / "p.nc", dynamics=dyn, step=STEP)
    lines = (d / "rec.csv").read_text().splitlines()
    assert "temperature [degC]" in lines[0] and "temperature" not in (d / "sim.csv").read_text().splitlines()[0]
    n = int(0.6 * (len(lines) - 1))
    (d / "train.csv").write_text("\n".join(lines[:1 + n]) + "\n")
    diag = diagnose(str(d / "sim.csv"), str(d / "train.csv"), inputs=["temperature"])
    (d / "d.json").write_text(json.dumps(diag.to_dict()))
    _run(d, "model", "export", "d.json", "--sim", "sim.csv", "-o", "model", "--quiet")
    return d, float(lines[1 + n].split(",")[0])


def test_temperature_logged_only_in_rec_is_resimulated(thermal_case):
    d, t_split = thermal_case
    names = [e["name"] for e in json.loads((d / "d.json").read_text())["effects"]]
    assert "thermal_drift" in names or "thermal_direct" in names, names
    r = _run(d, "model", "resimulate", "model", "--rec", "rec.csv", "--sim", "sim.csv", "--diagnosis", "d.json",
             "--heldout-from", t_split, "--json", "rs.json")
    res = json.loads((d / "rs.json").read_text())
    assert res["heldout_rms"]["before"]["z"] > 5 * NOISE
    # with the temperature ignored (as before) the drift stayed whole in the residual: now at the noise
    assert res["heldout_rms"]["after"]["z"] <= 2 * NOISE, r.stdout
    assert any("temperature from REC" in n for n in res["notes"]), res["notes"]
    assert "floor" in r.stdout and res["ratio_to_floor"]["z"] <= 2.0


def test_drift_without_its_driver_is_named_not_resimulated(thermal_case, tmp_path):
    d, t_split = thermal_case
    # REC without its temperature column: nothing can drive the drift
    lines = (d / "rec.csv").read_text().splitlines()
    head = lines[0].split(",")
    k = head.index("temperature [degC]")
    (tmp_path / "rec.csv").write_text("\n".join(",".join(c for i, c in enumerate(ln.split(",")) if i != k)
                                                for ln in lines) + "\n")
    r = _run(d, "model", "resimulate", "model", "--rec", tmp_path / "rec.csv", "--sim", "sim.csv",
             "--heldout-from", t_split, "--json", tmp_path / "rs.json")
    res = json.loads((tmp_path / "rs.json").read_text())
    assert any(n.startswith("thermal_drift") and "NOT re-simulated" in n for n in res["notes"]), res["notes"]
    assert "NOT re-simulated" in r.stdout
    # the drift is left in the residual: far above its floor, the model called incomplete on z
    assert "z" in res["incomplete"] and "MODEL INCOMPLETE on z" in r.stdout
    assert "slow drift" in res["incomplete"]["z"]


def test_floor_parts():
    rng = np.random.default_rng(1)
    t = np.arange(4000) * 1e-3
    v = 5.0 * np.sin(t) + rng.normal(0, 2e-4, t.size)
    assert noise_from_recording(v) == pytest.approx(2e-4, rel=0.1)
    q = 1e-4
    assert quantisation_step(np.round(v / q) * q) == pytest.approx(q)
    assert quantisation_step(v) == 0.0
    ts = np.arange(0, 4.0, 0.01)
    y = np.sin(2 * np.pi * 2 * ts)
    assert interpolation_error(ts, ts, y) == 0.0
    tq = ts[:-1] + 0.005
    true = np.sin(2 * np.pi * 2 * tq)
    exact = float(np.sqrt(np.mean((np.interp(tq, ts, y) - true) ** 2)))
    assert interpolation_error(tq, ts, y) == pytest.approx(exact, rel=0.2)
