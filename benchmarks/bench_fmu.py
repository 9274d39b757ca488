"""Cost per communication step of the compensator FMU, native C beside a pythonfmu build.

The same compensation (robonano-a0ib, setting errors like paper 000's plus geometric tables on
every axis) is run along the same smooth 5-axis path:

- through fmpy.simulate_fmu (input signal, output every step),
- in a ctypes loop (fmpy's FMU2Slave: setReal, doStep, getReal per step),
- for the native FMU also from a C host (dlopen, a plain C loop; compiled here with gcc),
- and, as the reference, mtcomp.kinematics.retarget on one pose at a time and vectorised.

Writes its section of docs/benchmarks.md.  Run: python benchmarks/bench_fmu.py
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import machine_line, update_section  # noqa: E402

from mtcomp.errors import AxisErrorTable, ErrorSet, GeometricErrors, ToolSetting, WorkpieceSetting, component_names  # noqa: E402
from mtcomp.fmu.build import build_compensator_fmu  # noqa: E402
from mtcomp.fmu.cosim import FmuRunner  # noqa: E402
from mtcomp.fmu.pyfmu import build_python_compensator_fmu  # noqa: E402
from mtcomp.kinematics import retarget  # noqa: E402
from mtcomp.machine import load_machine  # noqa: E402

C_HOST = r"""
#include <dlfcn.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "fmi2Functions.h"
static void logger(fmi2ComponentEnvironment e, fmi2String n, fmi2Status s, fmi2String c, fmi2String m, ...)
{ (void)e; (void)n; (void)s; (void)c; fprintf(stderr, "%s\n", m); }
int main(int argc, char **argv)
{
    void *h = dlopen(argv[1], RTLD_NOW);
    int n = atoi(argv[3]), steps = atoi(argv[4]), k, i, bad = 0;
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    fmi2ValueReference in[9], out[9];
    double q[9], o[9], t = 0.0, dt = 1e-3, sum = 0.0;
    struct timespec a, b;
    if (!h) { fprintf(stderr, "%s\n", dlerror()); return 1; }
    fmi2InstantiateTYPE *inst = (fmi2InstantiateTYPE *)dlsym(h, "fmi2Instantiate");
    fmi2SetupExperimentTYPE *setup = (fmi2SetupExperimentTYPE *)dlsym(h, "fmi2SetupExperiment");
    fmi2EnterInitializationModeTYPE *enter = (fmi2EnterInitializationModeTYPE *)dlsym(h, "fmi2EnterInitializationMode");
    fmi2ExitInitializationModeTYPE *leave = (fmi2ExitInitializationModeTYPE *)dlsym(h, "fmi2ExitInitializationMode");
    fmi2SetRealTYPE *set = (fmi2SetRealTYPE *)dlsym(h, "fmi2SetReal");
    fmi2GetRealTYPE *get = (fmi2GetRealTYPE *)dlsym(h, "fmi2GetReal");
    fmi2DoStepTYPE *step = (fmi2DoStepTYPE *)dlsym(h, "fmi2DoStep");
    fmi2Component c = inst("bench", fmi2CoSimulation, "", argv[2], &cb, fmi2False, fmi2False);
    for (i = 0; i < n; i++) { in[i] = i; out[i] = 10 + i; }
    setup(c, fmi2False, 0, 0, fmi2False, 0);
    enter(c);
    for (i = 0; i < n; i++) q[i] = 0.0;
    q[1] = 20.0;
    set(c, in, n, q);
    if (leave(c) != fmi2OK) return 2;
    clock_gettime(CLOCK_MONOTONIC, &a);
    for (k = 0; k < steps; k++) {
        double s = k * 1e-4;
        q[0] = 30.0 * sin(s); q[1] = 20.0 + 10.0 * sin(0.7 * s); q[2] = 40.0 * sin(1.3 * s);
        q[3] = 20.0 * cos(s); q[4] = -10.0 * sin(0.5 * s);
        set(c, in, n, q);
        bad |= step(c, t, dt, fmi2True) != fmi2OK;
        get(c, out, n, o);
        sum += o[2];
        t += dt;
    }
    clock_gettime(CLOCK_MONOTONIC, &b);
    printf("%.6e %d %.6f\n", ((b.tv_sec - a.tv_sec) + 1e-9 * (b.tv_nsec - a.tv_nsec)) / steps, bad, sum);
    return 0;
}
"""


def path(n: int) -> np.ndarray:
    """The same path as the C host: C, B, X, Y, Z (robonano-a0ib order)."""
    s = np.arange(n) * 1e-4
    return np.column_stack([30 * np.sin(s), 20 + 10 * np.sin(0.7 * s), 40 * np.sin(1.3 * s),
                            20 * np.cos(s), -10 * np.sin(0.5 * s)])


def errors(machine, rng) -> ErrorSet:
    tables = {}
    for a in machine.axes:
        lo, hi = a.limits
        pos = np.linspace(lo, hi, 41)
        tables[a.name] = AxisErrorTable(a.name, pos, {
            n: rng.normal(0, 1e-3 if j < 3 else 5e-6, pos.size) for j, n in enumerate(component_names(a.name))})
    return ErrorSet(ToolSetting((0.35, -0.20, 0.15)), WorkpieceSetting((0.10, -0.05, 0.02), (0.01, -0.02, 0.03)),
                    GeometricErrors(tables))


def via_simulate_fmu(fmu, q, step) -> float:
    import fmpy
    names = [f"command.{a}" for a in ("C", "B", "X", "Y", "Z")]
    sig = np.zeros(len(q), dtype=[("time", np.float64)] + [(n, np.float64) for n in names])
    sig["time"] = np.arange(len(q)) * step
    for j, n in enumerate(names):
        sig[n] = q[:, j]
    t0 = time.perf_counter()
    fmpy.simulate_fmu(str(fmu), stop_time=(len(q) - 1) * step, output_interval=step, input=sig,
                      output=["compensated.X", "compensated.B"])
    return (time.perf_counter() - t0) / len(q)


def via_ctypes_loop(fmu, q, step) -> float:
    r = FmuRunner(fmu, "bench")
    try:
        cin = r.refs([f"command.{a}" for a in ("C", "B", "X", "Y", "Z")])
        cout = r.refs([f"compensated.{a}" for a in ("C", "B", "X", "Y", "Z")])
        r.fmu.enterInitializationMode()
        r.fmu.setReal(cin, list(q[0]))
        r.fmu.exitInitializationMode()
        set_real, get_real, do_step = r.fmu.setReal, r.fmu.getReal, r.fmu.doStep
        t0 = time.perf_counter()
        for k in range(len(q)):
            set_real(cin, list(q[k]))
            do_step(k * step, step)
            get_real(cout)
        return (time.perf_counter() - t0) / len(q)
    finally:
        r.close()


def via_c_host(fmu, work: Path, steps: int) -> float | None:
    import fmpy
    cc = shutil.which("cc") or shutil.which("gcc")
    if not cc:
        return None
    d = Path(fmpy.extract(str(fmu), str(work / "unzipped")))
    src = work / "host.c"
    src.write_text(C_HOST)
    exe = work / "host"
    subprocess.run([cc, "-O2", "-I", str(d / "sources"), str(src), "-o", str(exe), "-ldl", "-lm"], check=True)
    so = next((d / "binaries").glob("*/*.so"))
    out = subprocess.run([str(exe), str(so), (d / "resources").as_uri(), "5", str(steps)], check=True,
                         capture_output=True, text=True).stdout.split()
    if out[1] != "0":
        raise RuntimeError("the C host saw a failed step")
    return float(out[0])


def main() -> None:
    machine = load_machine("robonano-a0ib")
    e = errors(machine, np.random.default_rng(0))
    step = 1e-3
    with tempfile.TemporaryDirectory(prefix="mtcomp-bench-fmu-") as td:
        work = Path(td)
        print("building the native and the pythonfmu compensator ...", flush=True)
        native = build_compensator_fmu(machine, work / "native.fmu", e)
        pyfmu = build_python_compensator_fmu(machine, work / "python.fmu", e)
        n_native, n_py = 20_000, 2_000
        q_native, q_py = path(n_native), path(n_py)
        print("native FMU ...", flush=True)
        rows = {}
        rows["simulate_fmu"] = (via_simulate_fmu(native, q_native, step), via_simulate_fmu(pyfmu, q_py, step))
        rows["ctypes loop"] = (via_ctypes_loop(native, q_native, step), via_ctypes_loop(pyfmu, q_py, step))
        c_host = via_c_host(native, work, 200_000)
        print("core reference ...", flush=True)
        t0 = time.perf_counter()
        for k in range(500):
            retarget(machine, q_py[k:k + 1], e)
        core_single = (time.perf_counter() - t0) / 500
        t0 = time.perf_counter()
        retarget(machine, q_native, e)
        core_vec = (time.perf_counter() - t0) / n_native
    us = lambda x: f"{x * 1e6:.2f}"  # noqa: E731
    lines = [
        "## Compensator FMU: cost per communication step",
        "",
        "`benchmarks/bench_fmu.py`: robonano-a0ib, tool and workpiece setting errors plus component "
        "tables on all five axes, a smooth simultaneous 5-axis path; each step sets the five "
        "programmed commands, steps, and reads the compensated commands. " + machine_line()
        + f" Load average during the run: {os.getloadavg()[0]:.1f} (other jobs share the machine; repeated runs "
        "vary by tens of percent).",
        "",
        "| how the step is driven | native C FMU (us/step) | pythonfmu FMU (us/step) | ratio |",
        "|---|---:|---:|---:|",
    ]
    for k, (a, b) in rows.items():
        lines.append(f"| {k} (fmpy) | {us(a)} | {us(b)} | {b / a:.0f}x |")
    if c_host is not None:
        lines.append(f"| C host loop (dlopen, no Python) | {us(c_host)} | not possible (needs Python) | |")
    lines += [
        "",
        f"Reference, the core in Python: `retarget` on one pose per call {us(core_single)} us, "
        f"vectorised over {n_native} poses {us(core_vec)} us per pose.",
        "",
        f"Native steps: {n_native} through fmpy, 200000 from C; pythonfmu steps: {n_py}. The native "
        "FMU's cost through fmpy is mostly fmpy's ctypes marshalling; the compensation itself "
        "(a damped Gauss-Newton with a chord Jacobian) is what the C host loop shows.",
    ]
    text = "\n".join(lines)
    print(text)
    update_section("fmu", text)


if __name__ == "__main__":
    main()
