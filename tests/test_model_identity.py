"""A model belongs to one machine: `model ssp`, `model compensate` and `model resimulate` refuse
a model exported for another machine (another name, other axes, another kinematic chain) with
exit 2 and a message that names both machines, and write nothing."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

pytest.importorskip("fmpy")

from mtcomp.model.identity import identity_from_resource, identity_of, mismatch  # noqa: E402

M = "vmc-moving-column"
EFFECTS = [{"name": "backlash", "output": "x", "inputs": ["x"], "params": {"backlash_mm": 0.003},
            "uncertainty": {"backlash_mm": 1e-5}}]
PROGRAM = "G90 G1 F1200\nX0 Y0 Z0\nX5 Y1\nX0 Y0\n"


def _run(*args):
    return subprocess.run([sys.executable, "-m", "mtcomp", "model", *map(str, args)], capture_output=True, text=True)


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("identity")
    (d / "d.json").write_text(json.dumps({"effects": EFFECTS}))
    r = _run("export", d / "d.json", "--machine", M, "--step", "0.002", "-o", d / "model", "--quiet")
    assert r.returncode == 0, r.stderr
    (d / "p.nc").write_text(PROGRAM)
    return d


def _same_name_other_chain(path):
    """vmc-moving-column with X moved to the tool side: same name and axes, another chain."""
    from importlib import resources
    text = resources.files("mtcomp.presets").joinpath(M + ".toml").read_text(encoding="utf-8")
    i = text.index('name = "X"')
    j = text.index("side", i)
    k = text.index("\n", j)
    path.write_text(text[:j] + 'side = "tool"' + text[k:])
    return path


def test_manifest_records_the_chain(model_dir):
    text = (model_dir / "model" / "model.toml").read_text()
    assert "machine_axes" in text and "machine_chain" in text
    assert "X linear workpiece 1,0,0" in text


def test_identity_of_fmu_resource_matches_the_machine():
    from mtcomp.fmu.build import machine_resource_text
    from mtcomp.machine import load_machine
    for name in (M, "robonano-a0ib", "robonano-ui"):
        assert identity_from_resource(machine_resource_text(load_machine(name))) == identity_of(name)
    assert mismatch(identity_of(M), identity_of("robonano-a0ib"))
    assert not mismatch(identity_of(M), identity_of(M))


def test_compensate_refuses_another_machine(model_dir):
    out = model_dir / "out.nc"
    r = _run("compensate", model_dir / "p.nc", "--model", model_dir / "model", "--machine", "robonano-a0ib",
             "-o", out)
    assert r.returncode == 2, r.stdout + r.stderr
    assert "vmc-moving-column" in r.stderr and "robonano-a0ib" in r.stderr and "Traceback" not in r.stderr
    assert not out.exists()


def test_compensate_refuses_another_chain_of_the_same_name(model_dir, tmp_path):
    mach = _same_name_other_chain(tmp_path / "vmc_tool_x.toml")
    out = tmp_path / "out.nc"
    r = _run("compensate", model_dir / "p.nc", "--model", model_dir / "model", "--machine", mach, "-o", out)
    assert r.returncode == 2, r.stdout + r.stderr
    assert "kinematic chain" in r.stderr and "X linear workpiece" in r.stderr
    assert not out.exists()
    # the same machine passes
    r = _run("compensate", model_dir / "p.nc", "--model", model_dir / "model", "--machine", M, "--no-servo",
             "-o", out)
    assert r.returncode == 0, r.stderr


def test_resimulate_refuses_another_machine(model_dir, tmp_path):
    rec = tmp_path / "rec.csv"
    rec.write_text("t,x,y,z\n0,0,0,0\n0.01,0,0,0\n")
    js = tmp_path / "r.json"
    r = _run("resimulate", model_dir / "model", "--rec", rec, "--program", model_dir / "p.nc",
             "--machine", "robonano-a0ib", "--step", "0.002", "--json", js)
    assert r.returncode == 2, r.stdout + r.stderr
    assert "vmc-moving-column" in r.stderr and "robonano-a0ib" in r.stderr
    assert not js.exists()


def test_resimulate_library_refuses_an_export_of_another_machine(model_dir):
    from mtcomp._io import InputError
    from mtcomp.model.export import export_model
    from mtcomp.model.simulate import resimulate
    ex = export_model({"effects": EFFECTS}, M, None, step=0.002)
    with pytest.raises(InputError, match="robonano-a0ib"):
        resimulate(ex, ([0.0, 0.01], {"x": [0.0, 0.0]}), program=PROGRAM, machine="robonano-a0ib", step=0.002)


def test_ssp_refuses_another_machines_fmu(model_dir, tmp_path):
    from mtcomp.fmu.build import build_compensator_fmu, build_machine_fmu
    from mtcomp.fmu.ssp import write_ssp
    other = "robonano-a0ib"
    c = build_compensator_fmu(other, tmp_path / "c.fmu", compile_binary=False)
    m = build_machine_fmu(other, tmp_path / "m.fmu", compile_binary=False)
    write_ssp(tmp_path / "cell.ssp", c, m)
    out = tmp_path / "cell2.ssp"
    r = _run("ssp", tmp_path / "cell.ssp", model_dir / "model" / "machine.ssv", "-o", out)
    assert r.returncode == 2, r.stdout + r.stderr
    assert "vmc-moving-column" in r.stderr and "robonano-a0ib" in r.stderr and "Traceback" not in r.stderr
    assert not out.exists()
    # the same machine's SSP takes it
    c = build_compensator_fmu(M, tmp_path / "c2.fmu", compile_binary=False)
    m = build_machine_fmu(M, tmp_path / "m2.fmu", compile_binary=False)
    write_ssp(tmp_path / "cell_vmc.ssp", c, m)
    r = _run("ssp", tmp_path / "cell_vmc.ssp", model_dir / "model" / "machine.ssv", "-o", out)
    assert r.returncode == 0, r.stderr


def test_ssp_refuses_parameters_the_fmu_lacks(model_dir, tmp_path):
    """A .ssv carried away from its model folder: its parameter names must still be the FMU's."""
    import shutil
    from mtcomp.fmu.build import build_compensator_fmu, build_machine_fmu
    from mtcomp.fmu.ssp import write_ssp
    ssv = tmp_path / "alone" / "machine.ssv"
    ssv.parent.mkdir()
    shutil.copy(model_dir / "model" / "machine.ssv", ssv)
    ssv.write_text(ssv.read_text().replace("backlash.X", "backlash.U"))
    c = build_compensator_fmu(M, tmp_path / "c.fmu", compile_binary=False)
    m = build_machine_fmu(M, tmp_path / "m.fmu", compile_binary=False)
    write_ssp(tmp_path / "cell.ssp", c, m)
    r = _run("ssp", tmp_path / "cell.ssp", ssv, "-o", tmp_path / "o.ssp")
    assert r.returncode == 2 and "backlash.U" in r.stderr, r.stderr
