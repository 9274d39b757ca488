"""The native FMUs against bad calls and bad data (issue 15 item 4), their platforms and model
structure (issue 19 item 1), and the compiled-binary cache (issue 16 item 5).

Every FMU is built here from the shipped C sources and run by fmpy; the FMU states, GUIDs and
times below are the fuzz reproducers that the FMUs used to accept.
"""
from __future__ import annotations

import os
import shutil
import struct
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
from fmpy import read_model_description, supported_platforms  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

from mtcomp.errors import ErrorSet, ToolSetting, WorkpieceSetting  # noqa: E402
from mtcomp.fmu.build import WIN64_CC, FmuBuildError, build_compensator_fmu, build_machine_fmu  # noqa: E402
from mtcomp.fmu.cosim import FmuRunner  # noqa: E402
from mtcomp.kinematics import retarget  # noqa: E402
from mtcomp.machine import load_machine  # noqa: E402

SETTING = ErrorSet(ToolSetting((0.35, -0.20, 0.15)), WorkpieceSetting((0.10, -0.05, 0.02), (0.01, -0.02, 0.03)))
HAVE_MINGW = shutil.which(WIN64_CC) is not None


from _fmpy import binary_cache, live_fmpy_logger  # noqa: E402,F401 (autouse fixtures of the FMU tests)


@pytest.fixture(scope="module")
def fmus(tmp_path_factory, binary_cache):
    d = tmp_path_factory.mktemp("robust")
    return {
        "comp5": build_compensator_fmu("robonano-a0ib", d / "comp5.fmu", SETTING, compiler="cc"),
        "comp3": build_compensator_fmu("vmc-moving-column", d / "comp3.fmu", ErrorSet(ToolSetting((0.1, 0, 0))),
                                       compiler="cc"),
        "machine": build_machine_fmu("robonano-a0ib", d / "machine.fmu", SETTING, compiler="cc"),
        "comp5_fmi3": build_compensator_fmu("robonano-a0ib", d / "comp5-3.fmu", SETTING, compiler="cc",
                                            fmi_version=3),
    }


def _initialised(path, name, logs, q=(0.0, 10.0, 0.0, 0.0, 0.0)):
    r = FmuRunner(path, name, logs)
    r.fmu.enterInitializationMode()
    r.fmu.setReal([r.vr[f"command.{a}"] for a in ("C", "B", "X", "Y", "Z")], list(q))
    r.fmu.exitInitializationMode()
    return r


def _errors(logs):
    return [m for s, _, m in logs if s >= 3]


def _slave(md, unzipped, logs, guid=None):
    """An instance whose log messages are collected; a message that is not UTF-8 is recorded as
    a failure (the FMU must not echo raw bytes from a corrupt state into its log).  Never fmpy's
    default callbacks: they forward to whatever Python logger fmpy registered last, which may be
    gone (a crash in fmpy, not in the FMU)."""
    from fmpy import calloc, free
    from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                           fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)

    def logger(env, instance, status, category, message):
        try:
            logs.append(message.decode("utf-8"))
        except UnicodeDecodeError:
            logs.append(None)

    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(logger)
    cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    s = FMU2Slave(guid=guid or md.guid, unzipDirectory=unzipped, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="fuzz")
    s.instantiate(loggingOn=False, callbacks=cb)
    s._keep_callbacks = cb
    return s


# ---------------------------------------------------------------------------------------- times

@pytest.mark.parametrize("t,h", [(float("nan"), 1e-3), (float("inf"), 1e-3), (0.0, float("nan")),
                                 (0.0, float("inf")), (0.0, -1e-3), (0.0, 0.0)])
def test_do_step_refuses_non_finite_times_and_steps(fmus, t, h):
    """fmi2DoStep(NaN, h) used to return OK and make the FMU's time NaN."""
    logs = []
    r = _initialised(fmus["comp5"], "nan-time", logs)
    try:
        with pytest.raises(FMICallException):
            r.fmu.doStep(t, h)
        assert _errors(logs), logs
        # time unchanged: the next regular step from 0 is accepted
        r.fmu.doStep(0.0, 1e-3)
    finally:
        r.close()


def test_setup_experiment_refuses_a_non_finite_start_time(fmus):
    md = read_model_description(str(fmus["comp5"]))
    logs = []
    s = _slave(md, fmpy.extract(str(fmus["comp5"])), logs)
    try:
        with pytest.raises(FMICallException):
            s.setupExperiment(startTime=float("nan"))
        assert any("start time must be finite" in m for m in logs), logs
    finally:
        s.freeInstance()


# ---------------------------------------------------------------------------------------- GUID and state

def test_instantiation_with_another_fmus_guid_is_refused(fmus):
    md = read_model_description(str(fmus["comp5"]))
    other = read_model_description(str(fmus["comp3"])).guid
    assert other != md.guid
    unzipped = fmpy.extract(str(fmus["comp5"]))
    logs = []
    with pytest.raises(Exception, match="[Ii]nstantiat"):
        _slave(md, unzipped, logs, guid=other)
    assert any("is not the GUID of this FMU" in m and other in m for m in logs), logs
    _slave(md, unzipped, []).freeInstance()


def test_state_of_the_3_axis_compensator_is_refused_by_the_5_axis_one(fmus):
    """Same magic and size: only the GUID tells them apart."""
    logs = []
    r3 = FmuRunner(fmus["comp3"], "three", logs)
    try:
        r3.fmu.enterInitializationMode()
        r3.fmu.exitInitializationMode()
        st = r3.fmu.getFMUstate()
        blob3 = r3.fmu.serializeFMUstate(st)
        r3.fmu.freeFMUstate(st)
    finally:
        r3.close()
    r5 = _initialised(fmus["comp5"], "five", logs)
    try:
        st = r5.fmu.getFMUstate()
        blob5 = r5.fmu.serializeFMUstate(st)
        r5.fmu.freeFMUstate(st)
        assert len(blob3) == len(blob5) and blob3[:4] == blob5[:4]
        with pytest.raises(FMICallException):
            r5.fmu.deSerializeFMUstate(blob3)
        assert any("another FMU" in m for m in _errors(logs)), logs
        own = r5.fmu.deSerializeFMUstate(blob5)     # its own state is fine
        r5.fmu.setFMUstate(own)
        r5.fmu.freeFMUstate(own)
    finally:
        r5.close()


def test_serialized_state_with_a_workpiece_angle_of_1000_deg_is_refused(fmus):
    logs = []
    r = FmuRunner(fmus["comp5"], "angle", logs)
    try:
        marker = 0.0123456789
        r.set({"workpiece_setting.angle.c": marker})
        r.fmu.enterInitializationMode()
        r.fmu.setReal([r.vr[f"command.{a}"] for a in ("C", "B", "X", "Y", "Z")], [0, 10, 0, 0, 0])
        r.fmu.exitInitializationMode()
        st = r.fmu.getFMUstate()
        blob = bytes(r.fmu.serializeFMUstate(st))
        r.fmu.freeFMUstate(st)
        packed = struct.pack("=d", marker)
        assert blob.count(packed) == 1
        bad = blob.replace(packed, struct.pack("=d", 1000.0))
        with pytest.raises(FMICallException):
            r.fmu.deSerializeFMUstate(bad)
        assert any("workpiece_setting.angle.c = 1000 is out of range" in m for m in _errors(logs)), logs
        # a NaN anywhere in the values (here the compensated X output) is refused too
        corrupt = bytearray(blob)
        out = struct.pack("=d", r.fmu.getReal([r.vr["compensated.X"]])[0])
        assert blob.count(out) == 1
        i = blob.index(out)
        corrupt[i:i + 8] = struct.pack("=d", float("nan"))
        with pytest.raises(FMICallException):
            r.fmu.deSerializeFMUstate(bytes(corrupt))
        # the instance still works with its own state
        st = r.fmu.deSerializeFMUstate(blob)
        r.fmu.setFMUstate(st)
        r.fmu.freeFMUstate(st)
        r.fmu.doStep(0.0, 1e-3)
    finally:
        r.close()


# ---------------------------------------------------------------------------------------- machine travel

def test_machine_refuses_commands_outside_its_travel(fmus):
    m = load_machine("robonano-a0ib")
    x_lo = m.axes[m.index("X")].limits[0]
    logs = []
    r = _initialised(fmus["machine"], "travel", logs)
    try:
        r.fmu.setReal([r.vr["command.X"]], [x_lo - 1.0])
        with pytest.raises(FMICallException):
            r.fmu.doStep(0.0, 1e-3)
        assert any("command.X" in m_ and "outside the travel" in m_ for m_ in _errors(logs)), logs
    finally:
        r.close()
    # and at initialisation
    logs.clear()
    r = FmuRunner(fmus["machine"], "travel-init", logs)
    try:
        r.fmu.enterInitializationMode()
        r.fmu.setReal([r.vr["command.Y"]], [1e6])
        with pytest.raises(FMICallException):
            r.fmu.exitInitializationMode()
    finally:
        r.close()
    assert any("command.Y" in m_ for m_ in _errors(logs)), logs


# ---------------------------------------------------------------------------------------- locale

def _de_locale(tmp_path) -> Path:
    """A compiled de_DE.UTF-8 locale in a private folder (LOCPATH): no system change needed."""
    localedef = shutil.which("localedef")
    if localedef is None or not Path("/usr/share/i18n/locales/de_DE").exists():
        pytest.skip("localedef or the de_DE locale source is not installed")
    d = tmp_path / "locales"
    d.mkdir()
    run = subprocess.run([localedef, "-i", "de_DE", "-f", "UTF-8", str(d / "de_DE.UTF-8")],
                         capture_output=True, text=True)
    if not (d / "de_DE.UTF-8").exists():
        pytest.skip(f"localedef failed: {run.stderr[-300:]}")
    return d


def test_start_values_and_resources_read_right_in_a_comma_decimal_locale(fmus, tmp_path):
    """A host running in LC_NUMERIC=de_DE: strtod reads "0.35" as 0 there, so the FMU used to
    start with zero errors (or fail to load its machine).  The host process here proves the
    locale is active at the C level before it runs the FMU."""
    locpath = _de_locale(tmp_path)
    q = [20.0, 10.0, 5.0, -3.0, 2.0]
    expected = retarget(load_machine("robonano-a0ib"), np.array([q]), SETTING)[0]
    script = textwrap.dedent(f"""
        import ctypes, locale, sys
        import fmpy
        locale.setlocale(locale.LC_ALL, "de_DE.UTF-8")
        libc = ctypes.CDLL(None)
        libc.strtod.restype = ctypes.c_double
        libc.strtod.argtypes = [ctypes.c_char_p, ctypes.c_void_p]
        assert libc.strtod(b"0.35", None) == 0.0, "locale not active"
        assert libc.strtod(b"0,35", None) == 0.35
        res = fmpy.simulate_fmu({str(fmus["comp5"])!r}, stop_time=0.002, output_interval=1e-3,
                                start_values={dict(zip(("command.C", "command.B", "command.X", "command.Y",
                                                        "command.Z"), q))!r})
        print(repr([float(res["compensated." + a][-1]) for a in "CBXYZ"]))
    """)
    env = dict(os.environ, LOCPATH=str(locpath), LC_ALL="de_DE.UTF-8")
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    got = np.array(eval(run.stdout.strip().splitlines()[-1]))
    assert np.max(np.abs(got - expected)) <= 1e-9
    assert np.max(np.abs(got - q)) > 0.1     # the setting errors were really applied


# ---------------------------------------------------------------------------------------- platforms, structure

def test_platforms_icon_and_validation(fmus):
    for name, path in fmus.items():
        assert validate_fmu(str(path)) == [], name
        names = zipfile.ZipFile(path).namelist()
        assert zipfile.ZipFile(path).read("model.png")[:8] == b"\x89PNG\r\n\x1a\n"
        plats = set(supported_platforms(str(path)))    # fmpy names FMI 3.0 platforms as FMI 2.0 ones
        dirs = {n.split("/")[1] for n in names if n.startswith("binaries/") and n.count("/") == 2}
        fmi3 = name.endswith("fmi3")
        assert "linux64" in plats and ("x86_64-linux" if fmi3 else "linux64") in dirs
        if HAVE_MINGW:
            assert "win64" in plats and ("x86_64-windows" if fmi3 else "win64") in dirs, dirs
            assert len([n for n in names if n.endswith(".dll")]) == 1
        assert "c-code" in plats


@pytest.mark.skipif(not HAVE_MINGW, reason="mingw-w64 not installed")
def test_win64_dll_exports_fmi_and_imports_only_kernel32_and_msvcrt(fmus, tmp_path):
    objdump = shutil.which("x86_64-w64-mingw32-objdump")
    if objdump is None:
        pytest.skip("mingw objdump missing")
    with zipfile.ZipFile(fmus["comp5"]) as z:
        z.extract("binaries/win64/mtcomp_compensator.dll", tmp_path)
    out = subprocess.run([objdump, "-p", str(tmp_path / "binaries/win64/mtcomp_compensator.dll")],
                         capture_output=True, text=True).stdout
    dlls = {line.split(":", 1)[1].strip().lower() for line in out.splitlines() if "DLL Name:" in line}
    assert dlls == {"kernel32.dll", "msvcrt.dll"}
    for fn in ("fmi2Instantiate", "fmi2DoStep", "fmi2SetReal", "fmi2DeSerializeFMUstate"):
        assert fn in out


def test_win64_can_be_required_and_fails_clearly_without_mingw(tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path))    # no cross compiler on this PATH
    monkeypatch.setenv("MTCOMP_CACHE_DIR", "off")
    monkeypatch.setenv("CC", shutil.which("gcc") or shutil.which("cc") or "cc")
    with pytest.raises(FmuBuildError, match="mingw"):
        build_compensator_fmu("vmc-moving-column", tmp_path / "w.fmu", compiler="cc", windows=True)
    assert not (tmp_path / "w.fmu").exists()


def test_model_structure_declares_feed_through(fmus):
    comp = read_model_description(str(fmus["comp5"]))
    commands = {v.name for v in comp.modelVariables if v.causality == "input"}
    for out in comp.outputs:
        assert {d.name for d in out.dependencies} == commands, out.variable.name
    mach = read_model_description(str(fmus["machine"]))
    assert mach.outputs and all(out.dependencies == [] for out in mach.outputs)
    # the machine really has no feed-through: a new command changes no output before a step
    r = _initialised(fmus["machine"], "feed", [])
    try:
        outs = [v.valueReference for v in (o.variable for o in mach.outputs)]
        before = r.fmu.getReal(outs)
        r.fmu.setReal([r.vr["command.X"], r.vr["spindle_speed"]], [7.0, 3000.0])
        assert r.fmu.getReal(outs) == before
        r.fmu.doStep(0.0, 1e-3)
        assert r.fmu.getReal([r.vr["actual.X"]])[0] == 7.0
    finally:
        r.close()
    tol = next(v for v in comp.modelVariables if v.name == "tolerance")
    assert tol.unit == "mm" and "mm or deg" not in tol.description


# ---------------------------------------------------------------------------------------- cache

def test_binaries_are_cached_by_source_hash(tmp_path, monkeypatch):
    """The compiler (a wrapper that counts its calls) runs once per distinct source set."""
    gcc = shutil.which("gcc") or shutil.which("cc")
    if gcc is None:
        pytest.skip("no C compiler")
    calls = tmp_path / "calls.txt"
    wrapper = tmp_path / "counting-cc"
    wrapper.write_text(f'#!/bin/sh\necho call >> "{calls}"\nexec "{gcc}" "$@"\n')
    wrapper.chmod(0o755)
    cache = tmp_path / "cache"
    monkeypatch.setenv("MTCOMP_CACHE_DIR", str(cache))
    monkeypatch.setenv("CC", str(wrapper))

    def ncalls():
        return len(calls.read_text().splitlines()) if calls.exists() else 0

    a = build_compensator_fmu("vmc-moving-column", tmp_path / "a.fmu", compiler="cc", windows=False)
    assert ncalls() == 1 and len(list((cache / "fmu-binaries").iterdir())) == 1
    # another machine and other errors, the same sources: from the cache
    b = build_compensator_fmu("robonano-a0ib", tmp_path / "b.fmu", SETTING, compiler="cc", windows=False)
    assert ncalls() == 1 and len(list((cache / "fmu-binaries").iterdir())) == 1
    res = fmpy.simulate_fmu(str(b), stop_time=0.002, output_interval=1e-3, start_values={"command.B": 20.0})
    expected = retarget(load_machine("robonano-a0ib"), np.array([[0, 20.0, 0, 0, 0]]), SETTING)[0]
    assert res["compensated.X"][-1] == pytest.approx(expected[2], abs=1e-9)
    assert validate_fmu(str(a)) == [] and validate_fmu(str(b)) == []
    # another source set (the machine model) is compiled
    build_machine_fmu("robonano-a0ib", tmp_path / "m.fmu", compiler="cc", windows=False)
    assert ncalls() == 2
    # MTCOMP_CACHE_DIR=off: always compiled
    monkeypatch.setenv("MTCOMP_CACHE_DIR", "off")
    build_compensator_fmu("vmc-moving-column", tmp_path / "c.fmu", compiler="cc", windows=False)
    assert ncalls() == 3


def test_do_nothing_fmu_copies_its_inputs(tmp_path):
    """The benchmark's baseline: the compensator's interface, outputs = inputs, validates clean."""
    from mtcomp.fmu.build import build_passthrough_fmu
    path = build_passthrough_fmu("robonano-a0ib", tmp_path / "nothing.fmu", compiler="cc", windows=False)
    assert validate_fmu(str(path)) == []
    res = fmpy.simulate_fmu(str(path), stop_time=0.002, output_interval=1e-3,
                            start_values={"command.X": 3.25, "command.B": -7.5})
    assert res["compensated.X"][-1] == 3.25 and res["compensated.B"][-1] == -7.5 and res["compensated.Y"][-1] == 0.0


# ---------------------------------------------------------------------------------------- fuzzing

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings, strategies as st  # noqa: E402

FUZZ = settings(max_examples=80, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
ANY_FLOAT = st.one_of(st.floats(width=64), st.sampled_from([0.0, -0.0, 1e-300, 1e300, 49.99, 50.0, 50.0001,
                                                            30.0, 1000.0, float("nan"), float("inf")]))


@pytest.fixture(scope="module")
def comp_md(fmus):
    md = read_model_description(str(fmus["comp5"]))
    return md, fmpy.extract(str(fmus["comp5"]))


@FUZZ
@given(vr=st.integers(0, 300), value=ANY_FLOAT)
def test_fuzz_set_real_stores_only_what_it_accepts(comp_md, vr, value):
    """Any Real value reference, any double: either refused with the old value kept, or stored
    exactly and within the declared range; never a crash."""
    md, unzipped = comp_md
    var = {v.valueReference: v for v in md.modelVariables if v.type == "Real"}.get(vr)
    s = _slave(md, unzipped, [])
    try:
        old = s.getReal([vr])[0] if var is not None else None
        try:
            s.setReal([vr], [value])
            accepted = True
        except FMICallException:
            accepted = False
        if var is None or var.causality == "output":
            assert not accepted
            return
        if accepted:
            assert s.getReal([vr])[0] == value
            assert np.isfinite(value)
            lo = -np.inf if var.min is None else float(var.min)
            hi = np.inf if var.max is None else float(var.max)
            assert lo <= value <= hi, (var.name, value)
        else:
            got = s.getReal([vr])[0]
            assert got == old or (np.isnan(got) and np.isnan(old))
            assert not (np.isfinite(value) and (var.min is None or float(var.min) <= value)
                        and (var.max is None or value <= float(var.max)))
    finally:
        s.freeInstance()


@FUZZ
@given(t=ANY_FLOAT, h=ANY_FLOAT)
def test_fuzz_do_step_accepts_only_the_current_time_and_a_finite_positive_step(comp_md, t, h):
    md, unzipped = comp_md
    s = _slave(md, unzipped, [])
    try:
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
        s.setReal([0, 1, 2, 3, 4], [0.0, 10.0, 0.0, 0.0, 0.0])
        s.exitInitializationMode()
        s.doStep(0.0, 1e-3)                     # the FMU is at t = 1 ms
        valid = np.isfinite(t) and np.isfinite(h) and h > 0 and abs(t - 1e-3) <= 1e-9 * (1 + 1e-3)
        try:
            s.doStep(t, h)
            accepted = True
        except FMICallException:
            accepted = False
        assert accepted == valid, (t, h)
        now = t + h if accepted else 1e-3
        s.doStep(now, 1e-3)                     # still usable, at the expected time
        assert np.isfinite(s.getReal([12])[0])
    finally:
        s.freeInstance()


@pytest.fixture(scope="module")
def valid_state(comp_md):
    md, unzipped = comp_md
    s = _slave(md, unzipped, [])
    try:
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
        s.setReal([0, 1, 2, 3, 4], [5.0, 10.0, 3.0, -2.0, 1.0])
        s.exitInitializationMode()
        s.doStep(0.0, 1e-3)
        st_ = s.getFMUstate()
        blob = bytes(s.serializeFMUstate(st_))
        s.freeFMUstate(st_)
        return blob
    finally:
        s.freeInstance()


@FUZZ
@given(edits=st.lists(st.tuples(st.integers(0, 10**9), st.integers(0, 255)), min_size=1, max_size=8))
def test_fuzz_corrupted_states_are_refused_or_harmless(comp_md, valid_state, edits):
    """Random byte edits of a serialized state: refused, or a state whose parameters are all
    within their declared ranges and that steps to finite outputs (or an error); never a crash."""
    md, unzipped = comp_md
    blob = bytearray(valid_state)
    for pos, byte in edits:
        blob[pos % len(blob)] = byte
    logs = []
    s = _slave(md, unzipped, logs)
    try:
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
        s.setReal([0, 1, 2, 3, 4], [5.0, 10.0, 3.0, -2.0, 1.0])
        s.exitInitializationMode()
        try:
            st_ = s.deSerializeFMUstate(bytes(blob))
        except FMICallException:
            return
        try:
            s.setFMUstate(st_)
        except FMICallException:
            return
        finally:
            s.freeFMUstate(st_)
        for v in md.modelVariables:
            if v.type == "Real" and v.causality == "parameter":
                x = s.getReal([v.valueReference])[0]
                assert float(v.min) <= x <= float(v.max), (v.name, x)
        try:
            out = s.getReal([10, 11, 12, 13, 14])
            assert np.isfinite(out).all()
        except FMICallException:
            pass
    finally:
        s.freeInstance()
        assert None not in logs, "a log message that is not UTF-8"


def test_fmu_manipulation_toolbox_check_finds_nothing(fmus):
    """`fmutool -check` (conformity and semantic checks of FMI 2.0 and 3.0) on every FMU here."""
    import importlib.util
    if importlib.util.find_spec("fmu_manipulation_toolbox") is None:
        pytest.skip("fmu-manipulation-toolbox not installed")
    for name in ("comp5", "machine", "comp5_fmi3"):   # feed-through, none, and FMI 3.0
        path = fmus[name]
        run = subprocess.run([sys.executable, "-c", "import sys; from fmu_manipulation_toolbox.cli.fmutool import "
                              "fmutool; sys.exit(fmutool())", "-input", str(path), "-check"],
                             capture_output=True, text=True, timeout=120)
        out = run.stdout + run.stderr
        assert run.returncode == 0, out[-2000:]
        assert "seems to be compliant with FMI" in out and "No semantic error" in out, (name, out[-2000:])
        assert "ERROR" not in out and "WARNING" not in out, (name, out[-2000:])


@pytest.mark.parametrize("value", [0, -5, 1001, 2**31 - 1])
def test_out_of_range_max_iterations_is_refused_when_set(fmus, value):
    logs = []
    r = FmuRunner(fmus["comp5"], "maxit", logs)
    try:
        with pytest.raises(FMICallException):
            r.set({"max_iterations": value})
        assert any(f"max_iterations = {value} is out of range" in m for m in _errors(logs)), logs
        r.set({"max_iterations": 7})
        assert r.fmu.getInteger([r.vr["max_iterations"]]) == [7]
    finally:
        r.close()


def test_cli_win64_option(tmp_path, monkeypatch):
    from mtcomp.cli import main
    out = tmp_path / "c.fmu"
    assert main(["fmu", "build", "compensator", "--machine", "vmc-moving-column", "-o", str(out),
                 "--compiler", "cc", "--win64", "no"]) == 0
    assert not [n for n in zipfile.ZipFile(out).namelist() if n.endswith(".dll")]
    monkeypatch.setenv("PATH", str(tmp_path))          # no cross compiler to be found
    assert main(["fmu", "build", "compensator", "--machine", "vmc-moving-column", "-o", str(tmp_path / "w.fmu"),
                 "--compiler", "cc", "--win64", "yes"]) == 2
    assert not (tmp_path / "w.fmu").exists()


def test_fmi3_instantiation_token_is_checked(fmus):
    from fmpy.fmi3 import FMU3Slave
    path = fmus["comp5_fmi3"]
    md = read_model_description(str(path))
    unzipped = fmpy.extract(str(path))
    logs = []

    def make(token):
        s = FMU3Slave(guid=token, unzipDirectory=unzipped, modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName="token")
        s.instantiate(logMessage=lambda env, status, cat, msg: logs.append(msg.decode()))
        return s

    with pytest.raises(Exception):
        make("{00000000-0000-0000-0000-000000000000}")
    assert any("is not the GUID of this FMU" in m for m in logs), logs
    s = make(md.guid)
    try:
        s.enterInitializationMode(startTime=0.0)
        s.exitInitializationMode()
        with pytest.raises(FMICallException):
            s.doStep(float("nan"), 1e-3)
    finally:
        s.freeInstance()
