"""The SSP with FMI 3.0 FMUs (SSP 1.0 connector types and units), its parameter set applied in
ecos, the bound parameters handed to fmpy, and `mtcomp fmu ssp --fmi 3`.

What cannot run here, upstream: fmpy's simulate_ssp instantiates FMI 1.0/2.0 FMUs only, and
libcosimpy 0.0.6 crashes on FMI 3.0 FMUs; the FMI 3.0 SSP is run in ecos."""
from __future__ import annotations

import csv
import subprocess
import zipfile
from xml.etree import ElementTree as ET

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
from fmpy.ssp.simulation import simulate_ssp  # noqa: E402
from fmpy.ssp.ssd import read_ssd  # noqa: E402

from mtcomp.fmu.build import build_compensator_fmu, build_machine_fmu  # noqa: E402
from mtcomp.fmu.ssp import bound_parameters, fmpy_parameter_set, write_ssp  # noqa: E402
from mtcomp.kinematics import forward  # noqa: E402
from mtcomp.machine import load_machine  # noqa: E402

from _fmpy import binary_cache, live_fmpy_logger  # noqa: E402,F401 (autouse fixtures of the FMU tests)
from test_fmu_ssp import COMMANDS, SETTING, SSD_NS, _target, _uncompensated  # noqa: E402


@pytest.fixture(scope="module")
def fmus(tmp_path_factory, binary_cache):
    d = tmp_path_factory.mktemp("ssp3")
    out = {}
    for v in (2, 3):
        c = build_compensator_fmu("robonano-a0ib", d / f"comp{v}.fmu", SETTING, compiler="cc", fmi_version=v)
        m = build_machine_fmu("robonano-a0ib", d / f"machine{v}.fmu", SETTING, compiler="cc", fmi_version=v)
        out[v] = write_ssp(d / f"cell{v}.ssp", c, m, commands=COMMANDS)
    return out


def test_fmi3_ssp_has_ssp1_connector_types_and_defines_its_units(fmus):
    """Issue 35: ssc:Float64 connectors (not in SSP 1.0: fmpy 'This element is not expected',
    libcosim refuses the file), no units and an empty <ssd:Units/>."""
    path = fmus[3]
    read_ssd(str(path), validate=True)
    root = ET.fromstring(zipfile.ZipFile(path).read("SystemStructure.ssd"))
    tags = {el.tag.split("}")[1] for c in root.iter(f"{{{SSD_NS['ssd']}}}Connector") for el in c}
    assert tags == {"Real"}
    used = {el.get("unit") for el in root.iter(f"{{{SSD_NS['ssc']}}}Real")}
    defined = {u.get("name") for u in root.findall("ssd:Units/ssc:Unit", SSD_NS)}
    assert used == defined == {"mm", "deg", "degC"} or (used == defined and {"mm", "deg"} <= used)
    two = ET.fromstring(zipfile.ZipFile(fmus[2]).read("SystemStructure.ssd"))
    assert [c.get("name") for c in two.iter(f"{{{SSD_NS['ssd']}}}Connector")] == \
        [c.get("name") for c in root.iter(f"{{{SSD_NS['ssd']}}}Connector")]   # one layout for both


def test_ecos_runs_the_fmi3_ssp_with_its_parameter_set(fmus, tmp_path):
    from mtcomp.fmu.ecos import EcosUnavailable, ecos_command
    try:
        exe, env = ecos_command(tmp_path / "bin")
    except EcosUnavailable as exc:
        pytest.skip(str(exc))
    run = subprocess.run([str(exe), "simulate", "--path", str(fmus[3]), "--stepSize", "0.001", "--stopTime", "0.02",
                          "-l", "err", "--parameterSet", "commands"], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    rows = list(csv.reader(open(next(tmp_path.glob("*.csv")))))
    head = [h.strip() for h in rows[0]]
    p = np.array([float(rows[-1][head.index(f"machine::tool.{c}[REAL]")]) for c in "xyz"])
    assert np.max(np.abs(p - _target())) <= 1e-6            # the bound commands, compensated
    assert np.max(np.abs(p - _uncompensated())) > 0.1


def test_bound_parameters_reach_fmpy(fmus):
    """fmpy's simulate_ssp ignores SSD bindings and its parameter_set= takes no dict."""
    values = bound_parameters(fmus[2])
    assert values == {f"compensator.command.{a}": v for a, v in COMMANDS.items()}
    assert bound_parameters(fmus[2], "other") == {}
    res = simulate_ssp(str(fmus[2]), stop_time=0.005, step_size=1e-3, parameter_set=fmpy_parameter_set(values))
    p = np.array([res[f"machine.tool.{c}"][-1] for c in "xyz"])
    assert np.max(np.abs(p - _target())) < 1e-9
    plain = simulate_ssp(str(fmus[2]), stop_time=0.005, step_size=1e-3)   # bindings ignored: commands 0
    q0 = np.zeros((1, 5))
    p0 = np.array([plain[f"machine.tool.{c}"][-1] for c in "xyz"])
    assert np.max(np.abs(p0 - forward(load_machine("robonano-a0ib"), q0).p[0])) < 1e-9


def test_cli_fmi3_ssp(tmp_path):
    from mtcomp.cli import main
    from mtcomp.errors import save_errors
    errs = tmp_path / "true.toml"
    save_errors(SETTING, errs)
    out = tmp_path / "cell3.ssp"
    assert main(["fmu", "ssp", "--machine", "robonano-a0ib", "--errors", str(errs), "-o", str(out),
                 "--compiler", "cc", "--fmi", "3", "--commands", "C=20,B=10,X=5"]) == 0
    read_ssd(str(out), validate=True)
    with zipfile.ZipFile(out) as z:
        for name in ("resources/compensator.fmu", "resources/machine.fmu"):
            (tmp_path / "x.fmu").write_bytes(z.read(name))
            assert fmpy.read_model_description(str(tmp_path / "x.fmu")).fmiVersion == "3.0"
