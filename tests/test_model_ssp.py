"""The exported parameter set bound into the SSP of `mtcomp fmu ssp` runs in libcosim with the
diagnosed parameters applied (read back from the running machine FMU)."""
from __future__ import annotations

import math
import subprocess
import sys
import zipfile

import pytest

pytest.importorskip("fmpy")


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
