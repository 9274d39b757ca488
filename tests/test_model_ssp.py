"""The exported parameter set bound into the SSP of `mtcomp fmu ssp` runs in libcosim with the
diagnosed parameters applied (read back from the running machine FMU)."""
from __future__ import annotations

import math
import subprocess
import sys
import zipfile

import pytest

pytest.importorskip("fmpy")

from mtcomp.model.mapping import _encoder_harmonics  # noqa: E402


def test_bound_ssv_is_applied_by_libcosim(tmp_path):
    pytest.importorskip("libcosimpy")
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    log_output_level(CosimLogLevel.ERROR)
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimObserver import CosimObserver

    from mtcomp.fmu.build import build_compensator_fmu, build_machine_fmu
    from mtcomp.fmu.ssp import write_ssp
    M = "vmc-moving-column"
    effects = [{"name": "backlash", "output": "x", "inputs": ["x"], "params": {"backlash_mm": 0.002},
                "uncertainty": {"backlash_mm": 1e-6}},
               {"name": "squareness", "output": "x", "inputs": ["y"], "params": {"angle_deg": 2e-3},
                "uncertainty": {"angle_deg": 1e-5}}]
    diag = tmp_path / "d.json"
    import json
    diag.write_text(json.dumps({"effects": effects}))
    c = build_compensator_fmu(M, tmp_path / "c.fmu", compiler="cc")
    m = build_machine_fmu(M, tmp_path / "m.fmu", compiler="cc")
    write_ssp(tmp_path / "cell.ssp", c, m, commands={"X": 5.0, "Y": 10.0})
    run = [sys.executable, "-m", "mtcomp", "model"]
    r = subprocess.run(run + ["export", str(diag), "--machine", M, "--step", "0.001", "-o", str(tmp_path / "model")],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    r = subprocess.run(run + ["ssp", str(tmp_path / "cell.ssp"), str(tmp_path / "model" / "machine.ssv"),
                              "-o", str(tmp_path / "cell2.ssp")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "resources/machine.ssv" in zipfile.ZipFile(tmp_path / "cell2.ssp").namelist()
    ex = CosimExecution.from_ssp_file(str(tmp_path / "cell2.ssp"), step_size=1_000_000)
    obs = CosimObserver.create_last_value()
    ex.add_observer(obs)
    assert ex.simulate_until(20_000_000)
    mi = ex.slave_index_from_instance_name("machine")
    refs = {v.name.decode(): v.reference for v in ex.slave_variables(mi)}
    bl, ec0y, x = obs.last_real_values(mi, [refs["backlash.X"], refs["location.EC0Y"], refs["tool.x"]])
    g = math.radians(2e-3)
    assert bl == pytest.approx(0.002, abs=1e-15) and ec0y == pytest.approx(-g, rel=1e-12)
    # the uncompensated machine (the compensator knows no errors) shows the squareness at Y = 10
    assert x == pytest.approx(5.0 + g * 10.0, abs=1e-9)


def test_bound_ssv_reads_and_runs_in_fmpy(tmp_path):
    """fmpy reads the bound parameter set from the SSD (annotations included) and, handed it as
    simulate_ssp's parameter set (fmpy does not apply SSD bindings itself, docs/fmu.md), runs the
    machine with the diagnosed squareness."""
    from fmpy.ssp.simulation import simulate_ssp
    from fmpy.ssp.ssd import read_ssd

    from mtcomp.fmu.build import build_compensator_fmu, build_machine_fmu
    from mtcomp.fmu.ssp import write_ssp
    from mtcomp.model.export import export_model
    from mtcomp.model.ssp import bind_parameter_set
    M = "vmc-moving-column"
    export_model({"effects": [{"name": "squareness", "output": "x", "inputs": ["y"], "params": {"angle_deg": 2e-3},
                               "uncertainty": {"angle_deg": 1e-5}}]}, M, tmp_path / "model", step=1e-3)
    c = build_compensator_fmu(M, tmp_path / "c.fmu", compiler="cc")
    m = build_machine_fmu(M, tmp_path / "m.fmu", compiler="cc")
    write_ssp(tmp_path / "cell.ssp", c, m, commands={"X": 5.0, "Y": 10.0})
    bind_parameter_set(tmp_path / "cell.ssp", tmp_path / "model" / "machine.ssv", tmp_path / "cell2.ssp")
    ssd = read_ssd(str(tmp_path / "cell2.ssp"))

    class Param:
        def __init__(self, name, value):
            self.name, self.value = name, value

    class ParamSet:
        parameters = [Param(f"{el.name}.{p.name}", p.value) for el in ssd.system.elements
                      for b in el.parameterBindings for pv in b.parameterValues for p in pv.parameters]

    names = {p.name for p in ParamSet.parameters}
    assert "machine.location.EC0Y" in names
    res = simulate_ssp(str(tmp_path / "cell2.ssp"), stop_time=0.005, step_size=1e-3, parameter_set=ParamSet())
    assert res["machine.tool.x"][-1] == pytest.approx(5.0 + math.radians(2e-3) * 10.0, abs=1e-9)


def test_ssp_bad_inputs_name_the_file(tmp_path):
    from mtcomp._io import InputError
    from mtcomp.model.ssp import bind_parameter_set
    notzip, notxml = tmp_path / "a.ssp", tmp_path / "b.ssv"
    notzip.write_text("t,x\n0,1\n")
    notxml.write_text("t,x\n")
    with pytest.raises(InputError, match="b.ssv"):
        bind_parameter_set(notzip, notxml, tmp_path / "o.ssp")
    ssv = tmp_path / "p.ssv"
    ssv.write_text('<ssv:ParameterSet xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues" '
                   'version="1.0" name="x"><ssv:Parameters/></ssv:ParameterSet>')
    with pytest.raises(InputError, match="a.ssp"):
        bind_parameter_set(notzip, ssv, tmp_path / "o.ssp")
    assert not (tmp_path / "o.ssp").exists()


DYNAMIC_EFFECTS = [
    {"name": "backlash", "output": "x", "inputs": ["x"], "params": {"backlash_mm": 0.002},
     "uncertainty": {"backlash_mm": 1e-6}},
    {"name": "squareness", "output": "x", "inputs": ["y"], "params": {"angle_deg": 2e-3},
     "uncertainty": {"angle_deg": 1e-5}},
    {"name": "time_offset", "output": "x,y,z", "inputs": ["t"], "params": {"offset_s": 0.002},
     "uncertainty": {"offset_s": 1e-6}},
    {"name": "quadrant_glitch", "output": "y", "inputs": ["y"], "params": {"breakaway_mm": 0.003, "tau_s": 0.02},
     "uncertainty": {"breakaway_mm": 1e-5, "tau_s": 1e-4}},
    {"name": "quadrant_glitch", "output": "x", "inputs": ["x"], "params": {"peak_mm": 0.0025, "tau_s": 0.015},
     "uncertainty": {"peak_mm": 2e-6, "tau_s": 3e-5}},        # the spike form (no reversal here: no glitch)
    {"name": "thermal_drift", "output": "z", "inputs": ["temperature"],
     "params": {"gain_mm_per_degC": 4e-3, "tau_s": 3.0, "initial_mm": 1e-3, "offset_mm": -2e-3},
     "uncertainty": {"gain_mm_per_degC": 1e-5, "tau_s": 0.01, "initial_mm": 1e-5, "offset_mm": 1e-5}},
    {"name": "friction", "output": "vZ", "inputs": ["vZ"], "params": {"coulomb_mm_per_s": 0.05, "viscous": 0.01},
     "uncertainty": {"coulomb_mm_per_s": 1e-3, "viscous": 1e-4}},     # velocity friction (Z at rest: no effect)
    # a 50 µm signal period on 600 mm of Z: no table, the encoder element of Z (Z at 0: z moves by r(0))
    {"name": "encoder_cyclic_error", "output": "z", "inputs": ["z"],
     "params": {"period_mm": 0.05, "amplitude_h1_mm": 3e-4, "phase_h1_deg": 30.0, "amplitude_h2_mm": 1e-4,
                "phase_h2_deg": -45.0},
     "uncertainty": {"period_mm": 1e-6, "amplitude_h1_mm": 1e-6, "phase_h1_deg": 0.1, "amplitude_h2_mm": 1e-6,
                     "phase_h2_deg": 0.5}}]
# the element holds the error's harmonics on the axis position (the export solves r(q) = r_d(q +
# r(q)) for the diagnosis' r_d, read at the recorded position; tests/test_model_export.py checks
# that against an independent model): 3.004e-4 and 0.99e-4 mm here
(ENC_A1, ENC_F1, _, _), (ENC_A2, ENC_F2, _, _) = _encoder_harmonics(DYNAMIC_EFFECTS[-1], 0.05)
ENCODER_Z0 = ENC_A1 * math.sin(math.radians(ENC_F1)) + ENC_A2 * math.sin(math.radians(ENC_F2))  # r at z = 0, mm
VELOCITY_PEAKS = {"vZ": 10.0}    # SIM's peak speed on vZ, mm/s: v_s = 0.2 mm/s
# what the machine FMU must hold: thermal driver 1 (logged temperature), excess = r0/k, reference = 20 - c/k
DYNAMIC_PARAMS = {"backlash.X": 0.002, "location.EC0Y": -math.radians(2e-3), "delay": 0.002,
                  "friction.breakaway.Y": 0.003, "friction.tau.Y": 0.02, "glitch.height.X": 0.0025,
                  "glitch.time.X": 0.015, "thermal.time_constant": 3.0,
                  "thermal.drift.z": 4e-3, "thermal.initial_excess": 0.25, "thermal.reference": 20.5,
                  "velfriction.coulomb.Z": 0.05, "velfriction.viscous.Z": 0.01, "velfriction.vs.Z": 0.2,
                  "encoder.period.Z": 0.05, "encoder.a1.Z": ENC_A1, "encoder.a2.Z": ENC_A2}


@pytest.fixture(scope="module")
def dynamic_ssp(tmp_path_factory):
    """The cell SSP with the diagnosed delay, friction and thermal drift (and a backlash and a
    squareness) bound to the machine, the set named like the compensator's "commands"."""
    from mtcomp.fmu.build import build_compensator_fmu, build_machine_fmu
    from mtcomp.fmu.ssp import write_ssp
    from mtcomp.model.export import export_model
    from mtcomp.model.ssp import bind_parameter_set
    d = tmp_path_factory.mktemp("dynssp")
    M = "vmc-moving-column"
    export_model({"effects": DYNAMIC_EFFECTS}, M, d / "model", step=1e-3, velocity_peaks=VELOCITY_PEAKS)
    c = build_compensator_fmu(M, d / "c.fmu", compiler="cc")
    m = build_machine_fmu(M, d / "m.fmu", compiler="cc")
    write_ssp(d / "cell.ssp", c, m, commands={"X": 5.0, "Y": 10.0})
    return bind_parameter_set(d / "cell.ssp", d / "model" / "machine.ssv", d / "cell2.ssp", set_name="commands")


def _tool(t, y=10.0):
    """Tool edge (x, z) of the machine at rest at X5 Y10 Z0 at time t: the squareness moves x,
    the thermal state (ambient 20 degC + 0.25 K decaying with 3 s) moves z by drift (T - 20.5),
    the encoder cyclic error of Z by its value at z = 0 (the tool edge's z with the axes at 0)."""
    T = 20.0 + 0.25 * math.exp(-t / 3.0)
    return 5.0 + math.radians(2e-3) * y, 4e-3 * (T - 20.5) + ENCODER_Z0


def test_diagnosed_dynamics_applied_by_libcosim(dynamic_ssp):
    pytest.importorskip("libcosimpy")
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    log_output_level(CosimLogLevel.ERROR)
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimObserver import CosimObserver
    ex = CosimExecution.from_ssp_file(str(dynamic_ssp), step_size=1_000_000)
    obs = CosimObserver.create_last_value()
    ex.add_observer(obs)
    assert ex.simulate_until(20_000_000)
    mi = ex.slave_index_from_instance_name("machine")
    refs = {v.name.decode(): v.reference for v in ex.slave_variables(mi)}
    got = dict(zip(DYNAMIC_PARAMS, obs.last_real_values(mi, [refs[k] for k in DYNAMIC_PARAMS])))
    for k, v in DYNAMIC_PARAMS.items():
        assert got[k] == pytest.approx(v, rel=1e-12), k
    assert obs.last_integer_values(mi, [refs["thermal.driver"]]) == [1]
    x, z = obs.last_real_values(mi, [refs["tool.x"], refs["tool.z"]])
    assert (x, z) == pytest.approx(_tool(0.02), abs=1e-12)


def test_diagnosed_dynamics_applied_by_fmpy(dynamic_ssp):
    """fmpy reads every bound value (the Integer driver too) and, handed them as the parameter
    set (it does not apply SSD bindings itself), runs the machine with them."""
    from fmpy.ssp.simulation import simulate_ssp
    from fmpy.ssp.ssd import read_ssd
    ssd = read_ssd(str(dynamic_ssp))

    class Param:
        def __init__(self, name, value):
            self.name, self.value = name, value

    class ParamSet:
        parameters = [Param(f"{el.name}.{p.name}", p.value) for el in ssd.system.elements
                      for b in el.parameterBindings for pv in b.parameterValues for p in pv.parameters]

    read = {p.name: p.value for p in ParamSet.parameters}
    for k, v in DYNAMIC_PARAMS.items():
        assert float(read[f"machine.{k}"]) == pytest.approx(v, rel=1e-12), k
    assert int(read["machine.thermal.driver"]) == 1
    res = simulate_ssp(str(dynamic_ssp), stop_time=0.02, step_size=1e-3, parameter_set=ParamSet())
    x, z = _tool(float(res["time"][-1]) + 1e-3)       # fmpy records before the last step
    # fmpy initialises the machine before the compensator's commands reach it: X starts at 0 and
    # moves to 5 in the first step, so the play (2 µm) leaves it b/2 behind
    assert res["machine.tool.x"][-1] == pytest.approx(x - 0.001, abs=1e-12)
    assert res["machine.tool.z"][-1] == pytest.approx(z, abs=1e-9)


def test_diagnosed_dynamics_applied_by_the_ecos_cli(dynamic_ssp, tmp_path):
    """The ecos CLI (from ecospy) applies the set by its name, on both components: the machine's
    parameters read back from its CSV (6 decimals), the tool edge as expected."""
    import csv
    import importlib.util
    import os
    import shutil
    from pathlib import Path
    spec = importlib.util.find_spec("ecospy")
    if spec is None or not spec.submodule_search_locations or sys.platform != "linux":
        pytest.skip("ecospy with a linux ecos binary not installed")
    src = Path(list(spec.submodule_search_locations)[0]) / "binaries"
    if not (src / "ecos").exists():
        pytest.skip("ecos binary not shipped")
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for f in ("ecos", "proxyfmu", "libecosc.so"):
        if (src / f).exists():
            shutil.copy(src / f, bin_dir / f)
            (bin_dir / f).chmod(0o755)        # the wheel ships them without the exec bit
    env = dict(os.environ)
    env["LD_LIBRARY_PATH"] = os.pathsep.join([str(Path(sys.prefix) / "lib"), env.get("LD_LIBRARY_PATH", "")])
    run = subprocess.run([str(bin_dir / "ecos"), "simulate", "--path", str(dynamic_ssp), "--stepSize", "0.001",
                          "--stopTime", "0.02", "-l", "err", "--parameterSet", "commands"], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    with open(next(tmp_path.glob("*.csv"))) as fh:
        rows = list(csv.reader(fh))
    last = {h.strip(): r for h, r in zip(rows[0], rows[-1])}
    for k, v in DYNAMIC_PARAMS.items():
        assert float(last[f"machine::{k}[REAL]"]) == pytest.approx(v, abs=1e-6), k
    assert int(last["machine::thermal.driver[INT]"]) == 1
    x, z = _tool(float(last["time"]))
    assert float(last["machine::tool.x[REAL]"]) == pytest.approx(x, abs=1e-6)
    assert float(last["machine::tool.z[REAL]"]) == pytest.approx(z, abs=1e-6)
