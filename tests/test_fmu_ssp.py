"""The SSP of compensator + machine in each importer that runs it (issue 19 item 2).

Two layouts (docs/fmu.md): "components" runs in fmpy's simulate_ssp, libcosim and ecos (the
last two in tests/test_fmu.py); "system" runs in fmpy and fmucontainer.  Every check compares
the machine's real tool edge with the ideal one: hundreds of µm apart without the compensator,
within 1e-9 mm with it.
"""
from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
from fmpy.ssp.simulation import simulate_ssp  # noqa: E402
from fmpy.ssp.ssd import read_ssd  # noqa: E402

from mtcomp.errors import ErrorSet, ToolSetting, WorkpieceSetting  # noqa: E402
from mtcomp.fmu.build import build_compensator_fmu, build_machine_fmu  # noqa: E402
from mtcomp.fmu.ssp import write_ssp  # noqa: E402
from mtcomp.kinematics import forward  # noqa: E402
from mtcomp.machine import load_machine  # noqa: E402

SETTING = ErrorSet(ToolSetting((0.35, -0.20, 0.15)), WorkpieceSetting((0.10, -0.05, 0.02), (0.01, -0.02, 0.03)))
COMMANDS = {"C": 20.0, "B": 10.0, "X": 5.0}
Q = np.array([[20.0, 10.0, 5.0, 0.0, 0.0]])
SSD_NS = {"ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
          "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon"}


from _fmpy import binary_cache, live_fmpy_logger  # noqa: E402,F401 (autouse fixtures of the FMU tests)


@pytest.fixture(scope="module")
def ssps(tmp_path_factory, binary_cache):
    d = tmp_path_factory.mktemp("ssp")
    comp = build_compensator_fmu("robonano-a0ib", d / "compensator.fmu", SETTING, compiler="cc")
    mach = build_machine_fmu("robonano-a0ib", d / "machine.fmu", SETTING, compiler="cc")
    return {layout: write_ssp(d / f"{layout}.ssp", comp, mach, commands=COMMANDS, layout=layout)
            for layout in ("components", "system")}


def _target():
    return forward(load_machine("robonano-a0ib"), Q).p[0]


def _uncompensated():
    return forward(load_machine("robonano-a0ib"), Q, SETTING).p[0]


def test_both_layouts_are_schema_valid_and_define_their_units(ssps):
    for layout, path in ssps.items():
        read_ssd(str(path), validate=True)      # fmpy checks the SSP 1.0 schema
        root = ET.fromstring(zipfile.ZipFile(path).read("SystemStructure.ssd"))
        used = {el.get("unit") for el in root.iter(f"{{{SSD_NS['ssc']}}}Real") if el.get("unit")}
        defined = {u.get("name") for u in root.findall("ssd:Units/ssc:Unit", SSD_NS)}
        assert used and used <= defined, (layout, used - defined)
        system_conns = root.findall("ssd:System/ssd:Connectors/ssd:Connector", SSD_NS)
        assert bool(system_conns) == (layout == "system")
    assert abs(np.linalg.norm(_uncompensated() - _target())) > 0.1   # the errors are large


def test_fmpy_runs_the_components_layout_with_the_bound_commands(ssps):
    """fmpy does not apply an SSD's ParameterBindings itself: the bound values are handed to
    simulate_ssp as its parameter set, named with the component prefix."""
    ssd = read_ssd(str(ssps["components"]))

    class Param:
        def __init__(self, name, value):
            self.name, self.value = name, value

    class ParamSet:
        parameters = [Param(f"{el.name}.{p.name}", p.value) for el in ssd.system.elements
                      for b in el.parameterBindings for pv in b.parameterValues for p in pv.parameters]

    assert len(ParamSet.parameters) == 3
    res = simulate_ssp(str(ssps["components"]), stop_time=0.005, step_size=1e-3, parameter_set=ParamSet())
    p = np.array([res[f"machine.tool.{c}"][-1] for c in "xyz"])
    assert np.max(np.abs(p - _target())) < 1e-9


def test_fmpy_runs_the_system_layout_with_input_functions(ssps):
    inputs = {f"command.{a}": (lambda v: (lambda t: v))(v) for a, v in COMMANDS.items()}
    res = simulate_ssp(str(ssps["system"]), stop_time=0.005, step_size=1e-3, input=inputs)
    p = np.array([res[f"machine.tool.{c}"][-1] for c in "xyz"])
    assert np.max(np.abs(p - _target())) < 1e-9


def test_fmucontainer_builds_a_container_from_the_system_layout_that_compensates(ssps, tmp_path):
    if importlib.util.find_spec("fmu_manipulation_toolbox") is None:
        pytest.skip("fmu-manipulation-toolbox not installed")
    work = tmp_path / "container"
    work.mkdir()
    (work / "cell.ssp").write_bytes(Path(ssps["system"]).read_bytes())
    run = subprocess.run([sys.executable, "-c", "import sys; from fmu_manipulation_toolbox.cli.fmucontainer "
                          "import fmucontainer; sys.exit(fmucontainer())", "-container", "cell.ssp",
                          "-fmu-directory", str(work)], capture_output=True, text=True, cwd=work, timeout=300)
    container = work / "cell.fmu"
    assert container.exists(), run.stdout[-2000:] + run.stderr[-2000:]
    md = fmpy.read_model_description(str(container))
    ports = {v.name: v.causality for v in md.modelVariables if v.causality in ("input", "output")}
    assert {f"command.{a}" for a in "CBXYZ"} | {"spindle_speed"} <= {n for n, c in ports.items() if c == "input"}
    assert {"tool.x", "tool.y", "tool.z"} <= {n for n, c in ports.items() if c == "output"}
    res = fmpy.simulate_fmu(str(container), stop_time=0.005, output_interval=1e-3,
                            start_values={f"command.{a}": v for a, v in COMMANDS.items()},
                            output=["tool.x", "tool.y", "tool.z"])
    p = np.array([res[f"tool.{c}"][-1] for c in "xyz"])
    assert np.max(np.abs(p - _target())) < 1e-9


def test_components_layout_has_no_open_input_connector(ssps):
    """What fmpy needs: every declared input connector is connected (else UnboundLocalError)."""
    root = ET.fromstring(zipfile.ZipFile(ssps["components"]).read("SystemStructure.ssd"))
    ends = {(c.get("endElement"), c.get("endConnector")) for c in root.iter(f"{{{SSD_NS['ssd']}}}Connection")}
    for comp in root.iter(f"{{{SSD_NS['ssd']}}}Component"):
        for conn in comp.findall("ssd:Connectors/ssd:Connector", SSD_NS):
            if conn.get("kind") == "input":
                assert (comp.get("name"), conn.get("name")) in ends


def test_unknown_layout_or_axis_is_refused(ssps, tmp_path):
    from mtcomp._io import InputError
    d = Path(ssps["components"]).parent
    with pytest.raises(InputError, match="layout"):
        write_ssp(tmp_path / "x.ssp", d / "compensator.fmu", d / "machine.fmu", layout="flat")
    with pytest.raises(InputError, match="no axis 'Q'"):
        write_ssp(tmp_path / "x.ssp", d / "compensator.fmu", d / "machine.fmu", commands={"Q": 1.0})
    assert not (tmp_path / "x.ssp").exists()


def test_cli_writes_either_layout_and_cosim_csv_rows(tmp_path, capsys):
    from mtcomp.cli import main
    from mtcomp.errors import save_errors
    errs = tmp_path / "true.toml"
    save_errors(SETTING, errs)
    for layout in ("components", "system"):
        out = tmp_path / f"{layout}.ssp"
        assert main(["fmu", "ssp", "--machine", "robonano-a0ib", "--errors", str(errs), "-o", str(out),
                     "--compiler", "cc", "--layout", layout, "--commands", "C=20,B=10,X=5"]) == 0
        root = ET.fromstring(zipfile.ZipFile(out).read("SystemStructure.ssd"))
        assert bool(root.findall("ssd:System/ssd:Connectors/ssd:Connector", SSD_NS)) == (layout == "system")
        ssv = "{http://ssp-standard.org/SSP1/SystemStructureParameterValues}"
        assert {p.get("name") for p in root.iter(f"{ssv}Parameter")} == {"command.C", "command.B", "command.X"}
    assert main(["fmu", "ssp", "--machine", "robonano-a0ib", "-o", str(tmp_path / "bad.ssp"),
                 "--commands", "C=twenty"]) == 2
    assert not (tmp_path / "bad.ssp").exists()
    prog = tmp_path / "p.nc"
    prog.write_text("G90 G0 X0 Y0 Z0 B10 C0\nG1 X2 B12 C10 F600\nG0 X0\n")
    args = ["cosim", str(prog), "--machine", "robonano-a0ib", "--errors", str(errs), "--step", "0.01",
            "--compiler", "cc"]
    assert main(args + ["--out", str(tmp_path / "run"), "--full-csv"]) == 0
    text = capsys.readouterr().out
    assert "cutting:" in text and "G0 rapids:" in text and "every step" in text
    rows = (tmp_path / "run.csv").read_text().splitlines()
    assert "every 1. of" in rows[0] and rows[1].startswith("t,")
    # an output prefix in a folder that does not exist: one clear error, nothing written
    assert main(args + ["--out", str(tmp_path / "no" / "such" / "run")]) == 2
    assert not (tmp_path / "no").exists()
