"""What a pip install delivers: ecospy usable through mtcomp.fmu.ecos (libtbb from the tbb wheel,
an executable ecos), and a wheel whose tag matches its compiled contents, with one version."""
from __future__ import annotations

import importlib.util
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
needs_ecospy = pytest.mark.skipif(importlib.util.find_spec("ecospy") is None or sys.platform != "linux",
                                  reason="ecospy (mtcomp[ecos]) not installed, or not Linux")


@needs_ecospy
def test_ecospy_imports_through_the_wrapper_in_a_fresh_process():
    """`import ecospy` after `pip install mtcomp[ecos]` fails on libtbb.so.12 (upstream); the
    wrapper loads the tbb wheel's library first. A fresh interpreter: no LD_LIBRARY_PATH help."""
    code = "from mtcomp.fmu.ecos import load_ecospy; print(load_ecospy().EcosLib.version())"
    env = {k: v for k, v in __import__("os").environ.items() if k != "LD_LIBRARY_PATH"}
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60)
    assert run.returncode == 0, run.stderr[-2000:]
    assert re.fullmatch(r"v0\.\d+\.\d+\n", run.stdout)


@needs_ecospy
def test_ecos_command_is_executable_and_finds_libtbb(tmp_path):
    from mtcomp.fmu.ecos import ecos_command
    exe, env = ecos_command(tmp_path / "bin")
    assert exe.stat().st_mode & 0o111
    run = subprocess.run([str(exe), "--version"], env=env, capture_output=True, text=True, timeout=60)
    assert run.returncode == 0 and run.stdout.startswith("v0."), run.stderr[-1000:]
    again, _ = ecos_command(tmp_path / "bin")   # a second call reuses the copies
    assert again == exe


def test_version_is_written_in_one_place():
    import mtcomp
    try:
        import tomllib
    except ImportError:   # Python 3.10
        import tomli as tomllib
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    assert "version" not in meta["project"] and "version" in meta["project"]["dynamic"]
    assert meta["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "mtcomp.__version__"}
    from importlib.metadata import version
    assert version("mtcomp") == mtcomp.__version__


def _setuptools_ok() -> bool:
    try:
        import setuptools
    except ImportError:
        return False
    return int(setuptools.__version__.split(".")[0]) >= 77


@pytest.mark.slow
@pytest.mark.skipif(not _setuptools_ok(), reason="building the wheel needs setuptools >= 77 here")
def test_wheel_with_compiled_libraries_is_tagged_for_its_platform(tmp_path):
    """Issue 35: the wheel was py3-none-any with libmtk-*.so and libmtctok-*.so inside."""
    import mtcomp
    run = subprocess.run([sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "--no-build-isolation",
                          "-q", "-w", str(tmp_path)], capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr[-3000:]
    (whl,) = tmp_path.glob("mtcomp-*.whl")
    with zipfile.ZipFile(whl) as z:
        names = z.namelist()
        elf = [n for n in names if z.read(n)[:4] == b"\x7fELF"]
        meta = z.read(next(n for n in names if n.endswith(".dist-info/METADATA"))).decode()
    tag = whl.name[:-4].split("-")[-3:]
    if elf:
        assert tag[:2] == ["py3", "none"] and tag[2] != "any", (whl.name, elf)
    else:
        assert tag == ["py3", "none", "any"]
    assert f"Version: {mtcomp.__version__}" in meta
    assert "Classifier: Operating System :: Microsoft :: Windows" in meta
    assert re.search(r"Requires-Dist: ecospy.*extra == \"ecos\"", meta)
    assert not re.search(r"Requires-Dist: ecospy.*extra == \"cosim\"", meta)
