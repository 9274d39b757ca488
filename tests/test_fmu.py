"""The native FMUs: validation, kernel parity with the core, error handling, FMU state,
co-simulation, and runs in two more importers (libcosimpy, the ecos C++ simulator).

Every FMU here is built in the test session from the shipped C sources and run for real.
"""
from __future__ import annotations

import csv
import os
import shutil
import subprocess
import sys
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
from fmpy import extract, read_model_description  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

from mtcomp.errors import (AxisErrorTable, ErrorSet, GeometricErrors, ToolSetting,  # noqa: E402
                           WorkpieceSetting, component_names)
from mtcomp.fmu.build import MachineDynamics, build_compensator_fmu, build_machine_fmu  # noqa: E402
from mtcomp.fmu.cosim import FmuRunner, cosimulate, interpolate_program  # noqa: E402
from mtcomp.fmu.ssp import write_ssp  # noqa: E402
from mtcomp.kinematics import ConvergenceError, LimitError, compensate, forward, retarget  # noqa: E402
from mtcomp.machine import load_machine  # noqa: E402

PRESETS = ("robonano-ui", "robonano-a0ib", "vmc-moving-column")


from _fmpy import binary_cache, live_fmpy_logger  # noqa: E402,F401 (autouse fixtures of the FMU tests)

# A 5-axis program for the B-C table machine: simultaneous moves of X Y Z B C, an arc, a rapid.
PROGRAM_5AX = """%
O0005 (5-axis test path)
G90 G21 G17
G0 X0 Y0 Z5 B10 C0
G1 X10 Y0 Z0 B20 C45 F600
G1 X10 Y10 Z-2 B30 C120
G2 X0 Y20 I-10 J0 F600
G1 X-10 Y5 Z0 B15 C200 F900
M30
%
"""
# Setting errors of the size paper 000 reports (hundreds of um) plus a small workpiece tilt.
SETTING = ErrorSet(ToolSetting((0.35, -0.20, 0.15)), WorkpieceSetting((0.10, -0.05, 0.02), (0.01, -0.02, 0.03)))


def random_errors(machine, rng) -> ErrorSet:
    """Setting, location and table errors of realistic size; tables reach beyond the travel."""
    tables = {}
    for a in machine.axes:
        lo, hi = a.limits
        pos = np.linspace(lo - 0.2 * (hi - lo), hi + 0.2 * (hi - lo), 31)
        tables[a.name] = AxisErrorTable(a.name, pos, {
            n: rng.normal(0, 2e-3 if j < 3 else 1e-5, pos.size) for j, n in enumerate(component_names(a.name))})
    loc = {f"E{c}0{a.name}": float(rng.normal(0, 5e-3 if c in "XYZ" else 2e-5))
           for a in machine.axes for c in "XYZABC"}
    return ErrorSet(ToolSetting(tuple(rng.normal(0, 0.3, 3))),
                    WorkpieceSetting(tuple(rng.normal(0, 0.1, 3)), tuple(rng.normal(0, 0.02, 3))),
                    GeometricErrors(tables, loc))


@pytest.fixture(scope="module")
def built(tmp_path_factory, binary_cache):
    """Compensators for every preset (random errors), machine FMUs; one built through CMake."""
    d = tmp_path_factory.mktemp("fmus")
    rng = np.random.default_rng(2026)
    out = {"dir": d, "errors": {}, "comp": {}}
    for name in PRESETS:
        m = load_machine(name)
        e = random_errors(m, rng)
        out["errors"][name] = e
        compiler = "cmake" if name == "robonano-ui" else "cc"
        out["comp"][name] = build_compensator_fmu(m, d / f"comp-{name}.fmu", e, compiler=compiler)
    out["machine"] = build_machine_fmu("robonano-a0ib", d / "machine-a0ib.fmu", SETTING,
                                       MachineDynamics(kv=40.0, noise=1e-4, seed=7), compiler="cc")
    out["comp_setting"] = build_compensator_fmu("robonano-a0ib", d / "comp-a0ib-setting.fmu", SETTING, compiler="cc")
    out["machine_ideal"] = build_machine_fmu("robonano-a0ib", d / "machine-a0ib-ideal.fmu", SETTING, compiler="cc")
    return out


def all_fmus(built):
    return list(built["comp"].values()) + [built["machine"], built["comp_setting"], built["machine_ideal"]]


# ---------------------------------------------------------------------------------------- build

def test_every_fmu_validates_and_is_complete(built):
    for path in all_fmus(built):
        assert validate_fmu(str(path)) == [], path.name
        names = set(zipfile.ZipFile(path).namelist())
        for f in ("documentation/index.html", "documentation/externalDependencies.txt", "resources/machine.txt",
                  "sources/mtk.c", "sources/fmi2_base.c", "sources/fmi2Functions.h"):
            assert f in names, (path.name, f)
        assert any(n.startswith("binaries/linux64/") and n.endswith(".so") for n in names)
        md = read_model_description(str(path))
        assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate
        for v in md.modelVariables:
            assert v.description, v.name
            if v.type == "Real":
                assert v.unit in {"mm", "deg", "rad", "s", "1/s", "mm/s", "deg/s", "1/min", "degC", "mm/K", "K.min", "K", "1"}, v.name
        # translational errors display in um
        units = {v.name: (v.unit, v.displayUnit) for v in md.modelVariables}
        assert units["tool_setting.offset.x"] == ("mm", "um")
        assert {v.index for v in md.outputs} == {v.index for v in md.initialUnknowns}


def test_tables_travel_as_resources(built):
    z = zipfile.ZipFile(built["comp"]["robonano-ui"])
    names = z.namelist()
    for ax in load_machine("robonano-ui").axis_names:
        assert f"resources/tables/{ax}.csv" in names
    start = z.read("resources/start.txt").decode()
    assert "s 0 X:tables/X.csv;" in start


# ---------------------------------------------------------------------------------------- parity

def _sample(machine, n, rng):
    lo = np.array([a.limits[0] for a in machine.axes])
    hi = np.array([a.limits[1] for a in machine.axes])
    q = lo + (hi - lo) * (0.1 + 0.8 * rng.random((n, machine.n_axes)))
    if machine.name == "robonano-a0ib":
        # Keep B off the B-C singularity (B = 0), where a tilted workpiece needs C turned by a
        # quarter turn (the restarts, tested on their own below).
        b = machine.index("B")
        q[:, b] = np.sign(q[:, b] + 1e-9) * (10.0 + np.abs(q[:, b]) * 0.8)
    return q


def _compensate_through_fmu(path, machine, q, name, logs=None, extra=()):
    """Drive the compensator FMU with the commands q (one setReal/getReal per row); returns the
    compensated commands (K, n) and the values of the `extra` variables after the last row."""
    r = FmuRunner(path, name, logs)
    try:
        cin = list(range(machine.n_axes))
        cout = r.refs([f"compensated.{a}" for a in machine.axis_names])
        r.fmu.enterInitializationMode()
        r.fmu.setReal(cin, list(q[0]))
        r.fmu.exitInitializationMode()
        got = np.empty_like(q)
        set_real, get_real = r.fmu.setReal, r.fmu.getReal
        for k in range(len(q)):
            set_real(cin, list(q[k]))
            got[k] = get_real(cout)
        return got, (get_real(r.refs(list(extra))) if extra else [])
    finally:
        r.close()


@pytest.mark.parametrize("name", PRESETS)
def test_c_kernel_matches_core_on_10000_poses(built, name):
    m = load_machine(name)
    e = built["errors"][name]
    q = _sample(m, 10_000, np.random.default_rng(zlib.crc32(name.encode())))
    expected = retarget(m, q, e)
    got, _ = _compensate_through_fmu(built["comp"][name], m, q, "parity")
    assert np.max(np.abs(got - expected)) <= 1e-9
    # and the C result really does its job on the core's model
    assert np.max(np.abs(forward(m, got, e).p - forward(m, q).p)) <= 1e-9
    # the compensation is not trivial: it moves the axes by the size of the errors
    assert np.max(np.abs(got - q)) > 1e-2


def test_c_iteration_matches_the_core_closed_form_for_rigid_errors(tmp_path):
    """With setting errors only and no workpiece rotation the core solves in closed form; the C
    kernel iterates; both must agree."""
    m = load_machine("robonano-a0ib")
    e = ErrorSet(ToolSetting((0.35, -0.20, 0.15)), WorkpieceSetting((0.10, -0.05, 0.02)))
    path = build_compensator_fmu(m, tmp_path / "rigid.fmu", e, compiler="cc")
    q = _sample(m, 2000, np.random.default_rng(11))
    got, _ = _compensate_through_fmu(path, m, q, "rigid")
    assert np.max(np.abs(got - retarget(m, q, e))) <= 1e-9


def test_c_kernel_restarts_like_the_core_at_the_b_c_singularity(tmp_path):
    """A 3-axis program (B = C = 0) on the B-C table with the blank tilted about X: the iteration
    from the programmed angles fails, and the kernel must restart from the same rotary seeds as
    mtcomp.kinematics.compensate and keep the same solution (C turned by 90 deg, B tilted)."""
    m = load_machine("robonano-a0ib")
    e = ErrorSet(workpiece=WorkpieceSetting((0.01, 0.02, -0.005), (0.5, 0.0, 0.0)))
    path = build_compensator_fmu(m, tmp_path / "tilted.fmu", e, compiler="cc")
    q = np.zeros((7, 5))
    q[:, 2:] = [[0, 0, 1], [5, 0, 0], [5, 3, 0], [0, 3, -0.5], [-20, 10, 2], [30, -15, -5], [-35, -25, 8]]
    expected = retarget(m, q, e)
    # the core's answer is the restart one: C a quarter turn away, B tilted by the blank's angle
    assert np.allclose(np.abs(expected[:, 0]), 90.0, atol=1e-6)
    assert np.allclose(np.abs(expected[:, 1]), 0.5, atol=1e-6)
    logs = []
    got, (residual,) = _compensate_through_fmu(path, m, q, "tilted", logs, extra=("residual",))
    assert not [msg for s, _, msg in logs if s >= 3], logs
    assert np.max(np.abs(got - expected)) <= 1e-9
    assert residual < 1e-7
    pose, ideal = forward(m, got, e), forward(m, q)
    assert np.max(np.abs(pose.p - ideal.p)) <= 1e-9 and np.max(np.abs(pose.v - ideal.v)) <= 1e-9
    # With 2 iterations per attempt no seed converges: both refuse, naming the residual of the
    # attempt from the programmed commands.
    with pytest.raises(ConvergenceError) as core_error:
        compensate(m, forward(m, q[2:3]), e, q[2:3], max_iter=2)
    logs = []
    r = FmuRunner(path, "few-iterations", logs)
    try:
        r.set({"max_iterations": 2})
        r.fmu.enterInitializationMode()
        r.fmu.setReal(list(range(5)), list(q[2]))
        with pytest.raises(FMICallException):
            r.fmu.exitInitializationMode()
    finally:
        r.close()
    residual_text = str(core_error.value).split("(residual ")[1].split(")")[0]
    assert any(s == 3 and f"did not converge (residual {residual_text})" in msg for s, _, msg in logs), logs


# ---------------------------------------------------------------------------------------- errors

def test_nan_and_out_of_range_parameters_are_errors_with_a_message(built):
    logs = []
    r = FmuRunner(built["comp_setting"], "bad", logs)
    try:
        with pytest.raises(FMICallException):
            r.set({"tool_setting.offset.x": float("nan")})
        assert any(s == 3 and "NaN" in m and "tool_setting.offset.x" in m for s, _, m in logs)
        logs.clear()
        with pytest.raises(FMICallException):
            r.set({"workpiece_setting.angle.b": 45.0})
        assert any(s == 3 and "out of range" in m and "workpiece_setting.angle.b" in m for s, _, m in logs)
        # the rejected values were not stored: the FMU still initialises and works
        r.fmu.enterInitializationMode()
        r.fmu.setReal(list(range(5)), [0, 10, 0, 0, 0])
        r.fmu.exitInitializationMode()
        assert np.isfinite(r.fmu.getReal(r.refs(["compensated.X"]))).all()
        logs.clear()
        with pytest.raises(FMICallException):
            r.fmu.setReal([0], [float("inf")])
        assert any("must be finite" in m for _, _, m in logs)
    finally:
        r.close()


def test_missing_or_bad_table_resource_fails_initialisation_cleanly(built):
    logs = []
    r = FmuRunner(built["comp"]["robonano-ui"], "bad", logs)
    try:
        r.set({"geometric_tables": "X:tables/X.csv;Y:tables/nonexistent.csv"})
        r.fmu.enterInitializationMode()
        with pytest.raises(FMICallException):
            r.fmu.exitInitializationMode()
        assert any(s == 3 and "nonexistent.csv" in m and "not found" in m for s, _, m in logs)
        with pytest.raises(FMICallException):  # no stepping after a failed initialisation
            r.fmu.doStep(0.0, 1e-3)
    finally:
        r.close()
    # a malformed table (a table for an axis of the wrong name) is reported too
    logs.clear()
    r = FmuRunner(built["comp"]["robonano-ui"], "bad", logs)
    try:
        r.set({"geometric_tables": "Q:tables/X.csv"})
        r.fmu.enterInitializationMode()
        with pytest.raises(FMICallException):
            r.fmu.exitInitializationMode()
        assert any("unknown axis 'Q'" in m for _, _, m in logs)
    finally:
        r.close()


def _repack(fmu, tmp_path, files: dict) -> Path:
    """A copy of `fmu` with some archive files replaced or added (tampered resources)."""
    d = tmp_path / "fmu"
    with zipfile.ZipFile(fmu) as z:
        z.extractall(d)
    for name, text in files.items():
        (d / name).parent.mkdir(parents=True, exist_ok=True)
        (d / name).write_text(text)
    path = tmp_path / "repacked.fmu"
    with zipfile.ZipFile(path, "w") as z:
        for f in sorted(d.rglob("*")):
            if f.is_file():
                z.write(f, f.relative_to(d).as_posix())
    return path


def test_out_of_range_start_values_are_refused_at_build_and_at_initialisation(built, tmp_path):
    from mtcomp import MtcompError
    with pytest.raises(MtcompError, match=r"tool_setting.offset.x = 60.0 is outside \[-50.0, 50.0\]"):
        build_compensator_fmu("robonano-a0ib", tmp_path / "big.fmu", ErrorSet(ToolSetting((60.0, 0, 0))),
                              compile_binary=False)
    assert not (tmp_path / "big.fmu").exists()
    # a start value the FMU never saw through fmi2SetReal (resources/start.txt) is checked too
    start = zipfile.ZipFile(built["comp_setting"]).read("resources/start.txt").decode()
    assert "\nr 20 0.35\n" in start
    path = _repack(built["comp_setting"], tmp_path,
                   {"resources/start.txt": start.replace("\nr 20 0.35\n", "\nr 20 60.0\n")})
    logs = []
    r = FmuRunner(path, "start", logs)
    try:
        r.fmu.enterInitializationMode()
        with pytest.raises(FMICallException):
            r.fmu.exitInitializationMode()
    finally:
        r.close()
    assert any(s == 3 and "tool_setting.offset.x = 60 is out of range" in m for s, _, m in logs), logs


@pytest.mark.parametrize("table", [
    "position,EXX,EXX\n0,1e-3,1e-3\n1,2e-3,2e-3\n",            # a component named twice
    "position,EXX\n0,1e-3" + "0" * 5000 + "\n1,2e-3\n",          # a line longer than the reader's buffer
    "position,EXX\n1,1e-3\n0,2e-3\n",                           # positions not increasing
    "position,EXX\n0,nan\n1,2e-3\n",
])
def test_malformed_table_resource_is_refused_with_file_and_line(built, tmp_path, table):
    path = _repack(built["comp_setting"], tmp_path, {"resources/tables/bad.csv": table})
    logs = []
    r = FmuRunner(path, "badtable", logs)
    try:
        r.set({"geometric_tables": "X:tables/bad.csv"})
        r.fmu.enterInitializationMode()
        with pytest.raises(FMICallException):
            r.fmu.exitInitializationMode()
    finally:
        r.close()
    assert any(s == 3 and "bad.csv:" in m and "malformed error table" in m for s, _, m in logs), logs


@pytest.mark.parametrize("location", [b"", b"file:///" + b"x" * 5000])
def test_unusable_resource_location_fails_initialisation(built, tmp_path, monkeypatch, location):
    """No location (or one too long for the FMU): an error, never a machine.txt from the
    working folder or from a truncated path."""
    import ctypes
    logs = []
    r = FmuRunner(built["comp_setting"], "ok", logs)
    try:
        monkeypatch.chdir(tmp_path)
        (tmp_path / "machine.txt").write_bytes(zipfile.ZipFile(built["comp_setting"]).read("resources/machine.txt"))
        c = r.fmu.fmi2Instantiate(b"nores", 1, r.md.guid.encode(), location, ctypes.byref(r._cb), 0, 0)
        assert c
        try:
            r.fmu.fmi2EnterInitializationMode(c)
            with pytest.raises(FMICallException):
                r.fmu.fmi2ExitInitializationMode(c)
        finally:
            r.fmu.fmi2FreeInstance(c)
        assert any(s == 3 and "no usable fmuResourceLocation" in m for s, _, m in logs)
    finally:
        r.close()


def test_simulate_fmu_with_bad_start_value_raises_and_does_not_crash(built):
    with pytest.raises(FMICallException, match="fmi2SetReal"):
        fmpy.simulate_fmu(str(built["comp_setting"]), stop_time=0.01, output_interval=1e-3,
                          start_values={"location.EC0X": 1.0}, logger=lambda *a: None)
    # the importer process is alive and the FMU still runs with good values
    res = fmpy.simulate_fmu(str(built["comp_setting"]), stop_time=0.01, output_interval=1e-3,
                            start_values={"command.B": 20.0})
    assert len(res) == 11


def test_unreachable_command_is_an_error_at_the_step(built):
    logs = []
    r = FmuRunner(built["comp_setting"], "bad", logs)
    try:
        r.fmu.enterInitializationMode()
        r.fmu.setReal(list(range(5)), [0, 10, 0, 0, 0])
        r.fmu.exitInitializationMode()
        r.fmu.setReal([2], [-139.9])  # X near its travel end: the compensated X (-140.15) leaves it
        with pytest.raises(FMICallException):
            r.fmu.getReal(r.refs(["compensated.X"]))
        assert any("outside its travel" in m for _, _, m in logs)
    finally:
        r.close()


@pytest.mark.parametrize("beyond,accepted", [(0.4, True), (0.6, False)])
def test_travel_check_tolerates_half_a_resolution_step_like_the_core(built, beyond, accepted):
    m = load_machine("robonano-a0ib")
    x, res = m.index("X"), m.axes[m.index("X")].resolution
    goal = m.axes[x].limits[0] - beyond * res          # compensated X this far beyond the travel
    q = np.array([[0.0, 10.0, -139.9, 0.0, 0.0]])
    for _ in range(3):   # programmed X whose compensated X is `goal` (dX/dX = 1 up to 1e-4)
        q[0, x] -= retarget(m, q, SETTING, check=False)[0, x] - goal
    core_ok = True
    try:
        retarget(m, q, SETTING)
    except LimitError:
        core_ok = False
    logs = []
    r = FmuRunner(built["comp_setting"], "travel", logs)
    try:
        r.fmu.enterInitializationMode()
        r.fmu.setReal(list(range(5)), [0, 10, 0, 0, 0])
        r.fmu.exitInitializationMode()
        r.fmu.setReal(list(range(5)), list(q[0]))
        try:
            got = r.fmu.getReal(r.refs(["compensated.X"]))[0]
            fmu_ok = True
        except FMICallException:
            fmu_ok = False
    finally:
        r.close()
    assert core_ok == fmu_ok == accepted
    if accepted:
        assert got == pytest.approx(goal, abs=1e-9)


# ---------------------------------------------------------------------------------------- state

def _machine_outputs(r):
    return r.fmu.getReal(r.refs(["tool.x", "tool.y", "tool.z", "actual.X", "actual.B", "temperature"]))


def test_fmu_state_get_set_serialize_repeats_identically(built):
    r = FmuRunner(built["machine"], "state")
    try:
        cin = r.refs([f"command.{a}" for a in ("C", "B", "X", "Y", "Z")])
        r.set({"thermal.gain": 1e-3, "thermal.time_constant": 0.05, "thermal.drift.z": 1e-3})
        r.fmu.enterInitializationMode()
        r.fmu.setReal(cin, [0, 10, 0, 0, 0])
        r.set({"spindle_speed": 1000.0})
        r.fmu.exitInitializationMode()
        h = 1e-3

        def run(t0, k0, n):
            out = []
            for k in range(k0, k0 + n):
                r.fmu.setReal(cin, [5 * np.sin(k / 20), 10 + k / 10, k / 50, 0, -k / 100])
                r.fmu.doStep(t0 + (k - k0) * h, h)
                out.append(_machine_outputs(r))
            return np.array(out)

        run(0.0, 0, 20)
        state = r.fmu.getFMUstate()
        first = run(20 * h, 20, 30)
        r.fmu.setFMUstate(state)
        second = run(20 * h, 20, 30)
        assert np.array_equal(first, second)          # noise, servo, temperature: all restored
        assert np.ptp(first[:, 0]) > 0 and np.ptp(first[:, 5]) > 0
        blob = r.fmu.serializeFMUstate(state)
        r.fmu.freeFMUstate(state)
    finally:
        r.close()
    # a new instance continues identically from the de-serialized state
    r2 = FmuRunner(built["machine"], "state2")
    try:
        r2.set({"thermal.gain": 1e-3, "thermal.time_constant": 0.05, "thermal.drift.z": 1e-3})
        r2.fmu.enterInitializationMode()
        r2.fmu.exitInitializationMode()
        st = r2.fmu.deSerializeFMUstate(blob)
        r2.fmu.setFMUstate(st)
        r2.fmu.freeFMUstate(st)
        cin2 = r2.refs([f"command.{a}" for a in ("C", "B", "X", "Y", "Z")])
        third = []
        for k in range(20, 50):
            r2.fmu.setReal(cin2, [5 * np.sin(k / 20), 10 + k / 10, k / 50, 0, -k / 100])
            r2.fmu.doStep((k) * h, h)
            third.append(_machine_outputs(r2))
        assert np.array_equal(first, np.array(third))
        with pytest.raises(FMICallException):  # a state of another model is refused
            r2.fmu.deSerializeFMUstate(b"\0" * len(blob))
        # right header (magic, size, mode) but no String value terminated: refused, not trusted
        with pytest.raises(FMICallException):
            r2.fmu.deSerializeFMUstate(bytes(blob[:16]) + b"A" * (len(blob) - 16))
    finally:
        r2.close()


# ---------------------------------------------------------------------------------------- machine model

def test_machine_fmu_reproduces_core_forward_model(built):
    m = load_machine("robonano-a0ib")
    r = FmuRunner(built["machine_ideal"], "fwd")
    q = _sample(m, 200, np.random.default_rng(3))
    try:
        cin = r.refs([f"command.{a}" for a in m.axis_names])
        r.fmu.enterInitializationMode()
        r.fmu.setReal(cin, list(q[0]))
        r.fmu.exitInitializationMode()
        got = []
        for k in range(len(q)):
            r.fmu.setReal(cin, list(q[k]))
            r.fmu.doStep(k * 1e-3, 1e-3)   # an ideal servo is at the command by the end of the step
            got.append(r.fmu.getReal(r.refs(["tool.x", "tool.y", "tool.z", "tool_direction.x",
                                              "tool_direction.y", "tool_direction.z"])))
    finally:
        r.close()
    got = np.array(got)
    pose = forward(m, q, SETTING)
    assert np.max(np.abs(got[:, :3] - pose.p)) < 1e-11
    assert np.max(np.abs(got[:, 3:] - pose.v)) < 1e-13


def test_servo_is_first_order_and_backlash_a_play(built):
    r = FmuRunner(built["machine_ideal"], "servo")
    try:
        r.set({"servo.kv.X": 20.0, "backlash.Y": 0.004})
        cin = r.refs([f"command.{a}" for a in ("C", "B", "X", "Y", "Z")])
        r.fmu.enterInitializationMode()
        r.fmu.setReal(cin, [0, 10, 0, 0, 0])
        r.fmu.exitInitializationMode()
        r.fmu.setReal(cin, [0, 10, 1.0, 0.003, 0])   # X step of 1 mm; Y moves 3 um (inside the play)
        h = 1e-3
        xs = []
        for k in range(100):
            r.fmu.doStep(k * h, h)
            xs.append(r.fmu.getReal(r.refs(["actual.X", "actual.Y"])))
        xs = np.array(xs)
        t = (np.arange(100) + 1) * h
        assert np.allclose(xs[:, 0], 1.0 - np.exp(-20.0 * t), rtol=0, atol=1e-12)
        assert np.allclose(xs[:, 1], 0.001, rtol=0, atol=1e-15)   # moved 3 um - 2 um half play
        r.fmu.setReal(cin, [0, 10, 1.0, -0.001, 0])       # reverse by 4 um: still inside the play
        r.fmu.doStep(100 * h, h)
        assert r.fmu.getReal(r.refs(["actual.Y"]))[0] == pytest.approx(0.001, abs=1e-15)
    finally:
        r.close()


def test_thermal_drift_is_first_order_and_moves_the_tool_edge(built):
    m = load_machine("robonano-a0ib")
    r = FmuRunner(built["machine_ideal"], "thermal")
    q = [30.0, 15.0, 2.0, -1.0, 3.0]
    tau, gain, speed, drift = 0.05, 2e-4, 5000.0, (0.0, 0.0, 1.5e-3)   # 1 K per 5000 1/min
    try:
        r.set({"thermal.time_constant": tau, "thermal.gain": gain, "thermal.drift.z": drift[2]})
        cin = r.refs([f"command.{a}" for a in m.axis_names])
        r.fmu.enterInitializationMode()
        r.fmu.setReal(cin, q)
        r.set({"spindle_speed": speed})
        r.fmu.exitInitializationMode()
        h = 0.01
        for k in range(20):
            r.fmu.doStep(k * h, h)
        temp = r.fmu.getReal(r.refs(["temperature"]))[0]
        p = np.array(r.fmu.getReal(r.refs(["tool.x", "tool.y", "tool.z"])))
    finally:
        r.close()
    dT = gain * speed * (1 - np.exp(-0.2 / tau))
    assert temp == pytest.approx(20.0 + dT, abs=1e-12)
    hot = ErrorSet(ToolSetting(tuple(np.add(SETTING.tool.offset, np.multiply(drift, dT)))), SETTING.workpiece)
    assert np.allclose(p, forward(m, np.array([q]), hot).p[0], rtol=0, atol=1e-12)
    assert np.linalg.norm(p - forward(m, np.array([q]), SETTING).p[0]) == pytest.approx(1.5e-3 * dT, rel=1e-9)


# ---------------------------------------------------------------------------------------- co-simulation

def test_interpolation_honours_the_feed():
    m = load_machine("robonano-a0ib")
    t, q = interpolate_program("G90 G1 X10 F600\nG1 X10 Y5 F300\n", m, 0.01)
    # 10 mm at 600 mm/min = 1 s, then 5 mm at 300 mm/min = 1 s
    assert t[-1] == pytest.approx(2.0)
    x, y = q[:, m.index("X")], q[:, m.index("Y")]
    assert x[50] == pytest.approx(5.0) and y[50] == 0.0
    assert x[150] == pytest.approx(10.0) and y[150] == pytest.approx(2.5)
    # a full circle of radius 5 at 600 mm/min: 2*pi*5/10 s, every sample on the circle
    t, q = interpolate_program("G90 G0 X5 Y0\nG3 X5 Y0 I-5 J0 F600\n", m, 0.005)
    on = q[t >= 0.105]                     # after the 0.1 s rapid to the start point
    assert np.allclose(np.hypot(on[:, m.index("X")], on[:, m.index("Y")]), 5.0, atol=2e-3)
    assert t[-1] == pytest.approx(5 / 3000 * 60 + 2 * np.pi * 5 / 10, abs=0.006)


@pytest.mark.slow
def test_cosimulation_compensates_setting_errors(tmp_path):
    prog = tmp_path / "path5.nc"
    prog.write_text(PROGRAM_5AX)
    res = cosimulate(prog, "robonano-a0ib", SETTING, step=0.04, compiler="cc", workdir=tmp_path)
    assert res.max_uncompensated >= 0.100             # hundreds of um without compensation
    assert res.max_compensated <= 10e-6               # <= 10 nm with it (ideal servo, no noise)
    assert len(res.t) > 500   # about 23 s of program at 0.04 s
    # with servo lag on, the remaining error is the lag, and it is large
    lag = cosimulate(prog, "robonano-a0ib", SETTING, step=0.04, compiler="cc", workdir=tmp_path,
                     dynamics=MachineDynamics(kv=30.0))
    remaining = np.linalg.norm(lag.p_compensated - lag.target - lag.p_lag, axis=1)
    assert lag.max_compensated > 1e-3
    assert np.max(remaining) <= 10e-6
    assert type(lag.plot(tmp_path / "lag.png")).__name__ == "Figure"
    assert (tmp_path / "lag.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    lag.to_csv(tmp_path / "lag.csv")
    rows = list(csv.reader(open(tmp_path / "lag.csv")))
    assert rows[1][0] == "t" and len(rows) == len(lag.t) + 2
    assert "with compensation" in lag.summary()


def test_cosimulation_with_identified_errors_leaves_the_identification_error():
    m = load_machine("robonano-a0ib")
    q = np.column_stack([np.zeros(50), np.full(50, 20.0), np.linspace(0, 5, 50), np.zeros(50), np.zeros(50)])
    ident = ErrorSet(ToolSetting((0.35, -0.20, 0.149)), SETTING.workpiece)   # 1 um off in z
    res = cosimulate(q, m, SETTING, ident, step=0.01, compiler="cc")
    # a tool z error of 1 um shows up as 1 um of tool edge error at every point
    assert np.allclose(res.error_compensated, 1e-3, rtol=0, atol=2e-6)


# ---------------------------------------------------------------------------------------- other importers

@pytest.fixture(scope="module")
def ssp_file(built, tmp_path_factory):
    d = tmp_path_factory.mktemp("ssp")
    return write_ssp(d / "cell.ssp", built["comp_setting"], built["machine_ideal"],
                     commands={"C": 20.0, "B": 10.0, "X": 5.0})


def _target():
    return forward(load_machine("robonano-a0ib"), np.array([[20.0, 10.0, 5.0, 0.0, 0.0]])).p[0]


def test_libcosimpy_runs_the_ssp_and_compensates(ssp_file):
    pytest.importorskip("libcosimpy")
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
    log_output_level(CosimLogLevel.ERROR)
    ex = CosimExecution.from_ssp_file(str(ssp_file), step_size=1_000_000)  # ns
    obs = CosimObserver.create_last_value()
    ex.add_observer(obs)
    assert ex.simulate_until(20_000_000)
    mi = ex.slave_index_from_instance_name("machine")
    refs = {v.name.decode(): v.reference for v in ex.slave_variables(mi)}
    p = obs.last_real_values(mi, [refs["tool.x"], refs["tool.y"], refs["tool.z"]])
    assert np.max(np.abs(np.array(p) - _target())) < 1e-9
    # without the compensator the same machine is hundreds of um off
    assert np.linalg.norm(forward(load_machine("robonano-a0ib"), np.array([[20.0, 10, 5, 0, 0]]), SETTING).p[0]
                          - _target()) > 0.1


def _ecos(tmp_path):
    from mtcomp.fmu.ecos import EcosUnavailable, ecos_command
    try:
        return ecos_command(tmp_path / "ecos-bin")
    except EcosUnavailable as exc:
        pytest.skip(str(exc))


def _run_ecos(tmp_path, path, stop_time, *extra):
    """Simulate `path` (FMU or SSP) with ecos at 1 ms; the REAL columns of its CSV output."""
    ecos, env = _ecos(tmp_path)
    run = subprocess.run([str(ecos), "simulate", "--path", str(path), "--stepSize", "0.001",
                          "--stopTime", str(stop_time), "-l", "err", *extra], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    return _read_ecos_csv(next(tmp_path.glob("*.csv")))


def _read_ecos_csv(path):
    with open(path) as fh:
        rows = list(csv.reader(fh))
    head = [h.strip() for h in rows[0]]
    return {h: np.array([float(r[i]) for r in rows[1:]]) for i, h in enumerate(head) if h.endswith("[REAL]")}


def test_ecos_runs_the_native_fmus_without_python(ssp_file, tmp_path):
    out = _run_ecos(tmp_path, ssp_file, 0.03, "--parameterSet", "commands")
    p = np.array([out[f"machine::tool.{c}[REAL]"][-1] for c in "xyz"])
    assert np.max(np.abs(p - _target())) <= 1e-6   # ecos writes 6 decimals (1 nm)
    assert out["compensator::compensated.X[REAL]"][-1] != pytest.approx(5.0, abs=1e-3)


def test_ecos_runs_a_single_machine_fmu(built, tmp_path):
    out = _run_ecos(tmp_path, built["machine_ideal"], 0.02)
    p0 = forward(load_machine("robonano-a0ib"), np.zeros((1, 5)), SETTING).p[0]
    p = [out[next(k for k in out if k.endswith(f"tool.{c}[REAL]"))][-1] for c in "xyz"]
    assert np.allclose(p, p0, rtol=0, atol=1e-6)
    assert np.linalg.norm(p0 - forward(load_machine("robonano-a0ib"), np.zeros((1, 5))).p[0]) > 0.1


# ---------------------------------------------------------------------------------------- CLI

@pytest.mark.slow
def test_cli_builds_and_cosimulates(tmp_path, capsys):
    from mtcomp.cli import main
    from mtcomp.errors import save_errors
    errs = tmp_path / "true.toml"
    save_errors(SETTING, errs)
    out = tmp_path / "c.fmu"
    assert main(["fmu", "build", "compensator", "--machine", "robonano-a0ib", "--errors", str(errs),
                 "-o", str(out), "--compiler", "cc"]) == 0
    assert validate_fmu(str(out)) == []
    prog = tmp_path / "p.nc"
    prog.write_text("G90 G0 X0 Y0 Z0 B10 C0\nG1 X2 B12 C10 F600\n")
    assert main(["cosim", str(prog), "--machine", "robonano-a0ib", "--errors", str(errs), "--compensate",
                 str(errs), "--step", "0.01", "--out", str(tmp_path / "run"), "--compiler", "cc"]) == 0
    text = capsys.readouterr().out
    assert "without compensation" in text and "with compensation" in text
    assert (tmp_path / "run.csv").exists() and (tmp_path / "run.png").exists()
    # bad input: a clear error, exit 2, no output written
    assert main(["cosim", str(tmp_path / "missing.nc"), "--machine", "robonano-a0ib", "--errors", str(errs),
                 "--out", str(tmp_path / "bad")]) == 2
    assert not (tmp_path / "bad.csv").exists()
    # the SSP of the pair
    assert main(["fmu", "ssp", "--machine", "robonano-a0ib", "--errors", str(errs), "-o", str(tmp_path / "c.ssp"),
                 "--compiler", "cc"]) == 0
    names = zipfile.ZipFile(tmp_path / "c.ssp").namelist()
    assert {"SystemStructure.ssd", "resources/compensator.fmu", "resources/machine.fmu"} <= set(names)


def test_an_importer_can_rebuild_the_binary_from_the_sources(built, tmp_path):
    """fmpy's own build of the archive's <SourceFiles> (what `fmpy compile` runs), no mtcomp code."""
    from fmpy.build import build_platform_binary
    d = tmp_path / "unzipped"
    with zipfile.ZipFile(built["comp_setting"]) as z:
        z.extractall(d)
    shutil.rmtree(d / "binaries")
    (tmp_path / "build").mkdir()
    build_platform_binary(d, build_dir=tmp_path / "build")
    rebuilt = tmp_path / "rebuilt.fmu"
    with zipfile.ZipFile(rebuilt, "w") as z:
        for p in sorted(d.rglob("*")):
            if p.is_file():
                z.write(p, p.relative_to(d).as_posix())
    assert validate_fmu(str(rebuilt)) == []
    res = fmpy.simulate_fmu(str(rebuilt), stop_time=0.002, output_interval=1e-3,
                            start_values={"command.B": 20.0, "command.X": 3.0})
    expected = retarget(load_machine("robonano-a0ib"), np.array([[0, 20.0, 3.0, 0, 0]]), SETTING)[0]
    assert res["compensated.X"][-1] == pytest.approx(expected[2], abs=1e-9)


def test_pythonfmu_baseline_validates_and_matches_the_core(tmp_path):
    """The benchmark's pythonfmu compensator: units added by the build, same outputs as the core."""
    pytest.importorskip("pythonfmu")
    from mtcomp.fmu.pyfmu import build_python_compensator_fmu
    path = build_python_compensator_fmu("robonano-a0ib", tmp_path / "py.fmu", SETTING)
    assert validate_fmu(str(path)) == []
    units = {v.name: v.unit for v in read_model_description(str(path)).modelVariables}
    assert units["command.X"] == "mm" and units["compensated.B"] == "deg"
    res = fmpy.simulate_fmu(str(path), stop_time=0.002, output_interval=1e-3,
                            start_values={"command.B": 20.0, "command.X": 3.0})
    expected = retarget(load_machine("robonano-a0ib"), np.array([[0, 20.0, 3.0, 0, 0]]), SETTING)[0]
    assert res["compensated.X"][-1] == pytest.approx(expected[2], abs=1e-12)
    assert abs(expected[2] - 3.0) > 0.1


# ---------------------------------------------------------------------------------------- FMI 3.0

@pytest.fixture(scope="module")
def fmi3(built):
    d = built["dir"]
    e = built["errors"]["robonano-ui"]
    return {"comp": build_compensator_fmu("robonano-ui", d / "comp3-ui.fmu", e, fmi_version=3),   # via CMake
            "machine": build_machine_fmu("robonano-a0ib", d / "machine3.fmu", SETTING,
                                         MachineDynamics(kv=25.0, noise=1e-4, seed=3), compiler="cc", fmi_version=3)}


def _slave3(path, logs):
    from fmpy.fmi3 import FMU3Slave
    md = read_model_description(str(path))
    s = FMU3Slave(guid=md.guid, unzipDirectory=extract(str(path)), modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="fmi3")
    s.instantiate(logMessage=lambda env, status, cat, msg: logs.append((status, msg.decode())))
    return s, {v.name: v.valueReference for v in md.modelVariables}


def test_fmi3_fmus_validate_and_match_the_core(built, fmi3):
    for p in fmi3.values():
        assert validate_fmu(str(p)) == []
        names = zipfile.ZipFile(p).namelist()
        assert "sources/buildDescription.xml" in names and "sources/fmi3_base.c" in names
        assert b"FMI 3.0 Co-Simulation" in zipfile.ZipFile(p).read("documentation/index.html")
        assert any(n.startswith("binaries/x86_64-linux/") for n in names)
    m = load_machine("robonano-ui")
    e = built["errors"]["robonano-ui"]
    q = _sample(m, 500, np.random.default_rng(5))
    logs = []
    s, vr = _slave3(fmi3["comp"], logs)
    try:
        cin = [vr[f"command.{a}"] for a in m.axis_names]
        cout = [vr[f"compensated.{a}"] for a in m.axis_names]
        s.enterInitializationMode()
        s.setFloat64(cin, list(q[0]))
        s.exitInitializationMode()
        got = []
        for k in range(len(q)):
            s.setFloat64(cin, list(q[k]))
            got.append(s.getFloat64(cout))
        with pytest.raises(FMICallException):
            s.setFloat64([vr["tool_setting.offset.y"]], [float("nan")])
        assert any("NaN" in msg for _, msg in logs)
        s.terminate()
    finally:
        s.freeInstance()
    assert np.max(np.abs(np.array(got) - retarget(m, q, e))) <= 1e-9


def test_fmi3_resource_path_is_a_plain_path(fmi3, tmp_path):
    """FMI 3.0 passes a path, not a URI: a folder named with a '%' escape is used as it is."""
    from fmpy.fmi3 import FMU3Slave
    d = tmp_path / "unzipped%41"
    with zipfile.ZipFile(fmi3["machine"]) as z:
        z.extractall(d)
    (tmp_path / "unzippedA").mkdir()          # what a URI decoder would wrongly open
    md = read_model_description(str(fmi3["machine"]))
    logs = []
    s = FMU3Slave(guid=md.guid, unzipDirectory=str(d), modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="pct")
    s.instantiate(logMessage=lambda env, status, cat, msg: logs.append((status, msg.decode())))
    try:
        s.enterInitializationMode()
        s.exitInitializationMode()
        vr = {v.name: v.valueReference for v in md.modelVariables}
        p0 = forward(load_machine("robonano-a0ib"), np.zeros((1, 5)), SETTING).p[0]
        assert np.max(np.abs(np.array(s.getFloat64([vr["tool.x"], vr["tool.y"], vr["tool.z"]])) - p0)) < 1e-3
        s.terminate()
    finally:
        s.freeInstance()
    assert not [m for st, m in logs if st >= 3], logs


def test_fmi3_state_restore_repeats_identically(fmi3):
    logs = []
    s, vr = _slave3(fmi3["machine"], logs)
    try:
        cin = [vr[f"command.{a}"] for a in ("C", "B", "X", "Y", "Z")]
        out = [vr[n] for n in ("tool.x", "tool.y", "tool.z", "actual.X")]
        s.enterInitializationMode()
        s.setFloat64(cin, [0, 10, 0, 0, 0])
        s.exitInitializationMode()

        def run(k0, n):
            res = []
            for k in range(k0, k0 + n):
                s.setFloat64(cin, [k / 10, 10 + k / 20, k / 30, 0, 0])
                s.doStep(k * 1e-3, 1e-3)
                res.append(s.getFloat64(out))
            return np.array(res)

        run(0, 10)
        st = s.getFMUState()
        a = run(10, 20)
        blob = s.serializeFMUState(st)
        s.setFMUState(s.deserializeFMUState(blob))
        b = run(10, 20)
        assert np.array_equal(a, b) and np.ptp(a[:, 3]) > 0
    finally:
        s.freeInstance()


def test_ecos_runs_the_fmi3_machine(fmi3, tmp_path):
    out = _run_ecos(tmp_path, fmi3["machine"], 0.02)
    p = [out[next(k for k in out if k.endswith(f"tool.{c}[REAL]"))] for c in "xyz"]
    p0 = forward(load_machine("robonano-a0ib"), np.zeros((1, 5)), SETTING).p[0]
    # sensor noise of 100 nm (1 sigma) on the tool edge: around the forward model, never exactly on it
    dev = np.array(p).T - p0
    assert np.all(np.abs(dev) < 1e-3) and np.std(dev) > 1e-5
