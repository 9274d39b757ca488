"""What the FMU binaries show a process: only the FMI functions of their FMI version.

Built for real from the shipped C sources (both compiler routes), inspected with `nm -D`, and run
by fmpy in one process where another mtcomp FMU was loaded first with RTLD_GLOBAL: with the kernel's
and the model's functions exported, the second FMU's calls bind to the first one's copies.
"""
from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import pytest

fmpy = pytest.importorskip("fmpy")

from mtcomp.fmu.build import build_compensator_fmu, build_machine_fmu  # noqa: E402

from _fmpy import binary_cache, live_fmpy_logger  # noqa: E402,F401 (autouse fixtures of the FMU tests)

NM = shutil.which("nm")


@pytest.fixture(scope="module")
def fmus(tmp_path_factory, binary_cache):
    d = tmp_path_factory.mktemp("sym")
    return {
        ("comp", 2, "cc"): build_compensator_fmu("robonano-a0ib", d / "comp2.fmu", compiler="cc"),
        ("machine", 2, "cc"): build_machine_fmu("robonano-a0ib", d / "machine2.fmu", compiler="cc"),
        ("comp", 3, "cc"): build_compensator_fmu("robonano-a0ib", d / "comp3.fmu", compiler="cc", fmi_version=3),
        ("machine", 3, "cmake"): build_machine_fmu("robonano-a0ib", d / "machine3.fmu", compiler="cmake",
                                                   fmi_version=3),
    }


def _binary(fmu: Path, out: Path) -> Path:
    with zipfile.ZipFile(fmu) as z:
        name = next(n for n in z.namelist() if n.startswith("binaries/") and n.endswith(".so"))
        out.write_bytes(z.read(name))
    return out


def _exported(so: Path) -> list[str]:
    run = subprocess.run([NM, "-D", "--defined-only", str(so)], capture_output=True, text=True, check=True)
    return [line.split()[-1] for line in run.stdout.splitlines() if line.strip()]


@pytest.mark.skipif(NM is None, reason="binutils nm not installed")
def test_binaries_export_only_the_fmi_functions_of_their_version(fmus, tmp_path):
    for (kind, version, compiler), fmu in fmus.items():
        names = _exported(_binary(fmu, tmp_path / f"{kind}{version}{compiler}.so"))
        other = [n for n in names if not re.fullmatch(rf"fmi{version}[A-Z]\w*", n)]
        assert other == [], f"{kind} FMI {version} ({compiler}) exports {other[:10]}"
        assert f"fmi{version}DoStep" in names and len(names) >= 30


def test_fmi3_binary_has_no_fmi2_names_in_its_messages(fmus):
    """The FMI 3 binary runs the FMI 2 layer inside: a step out of order must be reported as
    fmi3DoStep, the function the importer called."""
    from fmpy import extract, read_model_description
    from fmpy.fmi3 import FMU3Slave
    path = fmus[("comp", 3, "cc")]
    md = read_model_description(str(path))
    logs = []
    s = FMU3Slave(guid=md.guid, unzipDirectory=extract(str(path)), modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="order")
    s.instantiate(logMessage=lambda env, status, cat, msg: logs.append(msg.decode()))
    try:
        with pytest.raises(Exception):
            s.doStep(0.0, 0.01)   # before initialisation
        s.enterInitializationMode()
        with pytest.raises(Exception):
            s.enterInitializationMode()
    finally:
        s.freeInstance()
    text = "\n".join(logs)
    assert "fmi3DoStep outside step mode" in text and "fmi3EnterInitializationMode called twice" in text
    assert "fmi2" not in text


# Run in a fresh interpreter: RTLD_GLOBAL changes symbol binding for everything loaded afterwards.
_TWO_FMUS = textwrap.dedent("""
    import ctypes, json, sys
    import fmpy
    from fmpy import extract, read_model_description
    preload = sys.argv[1] == "global"
    out = {}
    dirs = {}
    for key, path in (("machine", sys.argv[2]), ("comp", sys.argv[3])):
        d = extract(path)
        md = read_model_description(d)
        if preload:   # as a host that dlopens every FMU with RTLD_GLOBAL does
            so = f"{d}/binaries/{fmpy.platform if md.fmiVersion == '2.0' else fmpy.platform_tuple}/"
            ctypes.CDLL(so + md.coSimulation.modelIdentifier + ".so", mode=ctypes.RTLD_GLOBAL)
        dirs[key] = d
    logs = []
    for key, d in dirs.items():
        r = fmpy.simulate_fmu(d, stop_time=0.05, output_interval=0.01,
                              start_values={"tool_setting.offset.x": 0.2, "tool_setting.offset.z": -0.1},
                              logger=lambda *a: logs.append(a[-1].decode() if isinstance(a[-1], bytes) else str(a[-1])),
                              debug_logging=False)
        out[key] = {n: [float(v) for v in r[n]] for n in r.dtype.names}
    print(json.dumps(out))
""")


@pytest.mark.parametrize("version", [2, 3])
def test_two_fmus_loaded_rtld_global_in_one_process_both_run(fmus, tmp_path, version):
    machine = fmus[("machine", version, "cc" if version == 2 else "cmake")]
    comp = fmus[("comp", version, "cc")]
    script = tmp_path / "two.py"
    script.write_text(_TWO_FMUS, encoding="utf-8")
    runs = {}
    for mode in ("local", "global"):
        run = subprocess.run([sys.executable, str(script), mode, str(machine), str(comp)],
                             capture_output=True, text=True, timeout=120)
        assert run.returncode == 0, f"{mode}: {run.stderr[-2000:]}"
        runs[mode] = run.stdout
    assert runs["global"] == runs["local"]
    out = json.loads(runs["global"])
    assert {"machine", "comp"} <= set(out) and len(out["comp"]["time"]) >= 5


MINGW_OBJDUMP = shutil.which("x86_64-w64-mingw32-objdump")


def _dll_exports(dll: Path) -> list[str]:
    """Names of the export table as `objdump -p` prints it (one `[n] ... name` line each)."""
    out = subprocess.run([MINGW_OBJDUMP, "-p", str(dll)], capture_output=True, text=True, check=True).stdout
    part = out.split("[Ordinal/Name Pointer] Table", 1)[1]
    names = []
    for line in part.splitlines()[1:]:
        if not re.match(r"\s*\[\s*\d+\]", line):
            break
        names.append(line.split()[-1])
    return names


@pytest.mark.skipif(shutil.which("x86_64-w64-mingw32-gcc") is None or MINGW_OBJDUMP is None,
                    reason="mingw-w64 not installed")
@pytest.mark.parametrize("version", [2, 3])
def test_win64_dlls_export_only_the_fmi_functions_of_their_version(tmp_path, version):
    fmu = build_compensator_fmu("robonano-a0ib", tmp_path / "w.fmu", compiler="cc", fmi_version=version,
                                windows=True)
    plat = "win64" if version == 2 else "x86_64-windows"
    with zipfile.ZipFile(fmu) as z:
        z.extract(f"binaries/{plat}/mtcomp_compensator.dll", tmp_path)
    names = _dll_exports(tmp_path / "binaries" / plat / "mtcomp_compensator.dll")
    assert names and f"fmi{version}DoStep" in names
    assert [n for n in names if not re.fullmatch(rf"fmi{version}[A-Z]\w*", n)] == []
