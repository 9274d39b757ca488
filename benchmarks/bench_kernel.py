"""Throughput of the core model: the compiled kernel (fmu/c/mtk.c through ctypes) beside the
numpy reference implementation of the same algorithm, in CPU and wall time, in the same run.
Writes the "kernel" section of docs/benchmarks.md with the targets of the compiled-kernel issue.

    python benchmarks/bench_kernel.py [--points 200000] [--numpy-points 40000] [--previous REV]

--previous REV: the kernel of git revision REV (its fmu/c sources, compiled here) timed on the same
poses through the same `retarget` call (every retarget row), a column beside the current kernel's:
CPU rates on a shared machine drift from run to run, the ratio in one run does not.
"""
from __future__ import annotations

import argparse
import ctypes
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from _report import machine_line, update_section  # noqa: E402
from _models import random_commands, random_errors  # noqa: E402

from mtcomp import _kernel  # noqa: E402
from mtcomp.errors import ErrorSet, ToolSetting, WorkpieceSetting  # noqa: E402
from mtcomp.kinematics import deviations, forward, forward_position, retarget  # noqa: E402
from mtcomp.machine import load_machine  # noqa: E402

RIGID = ErrorSet(ToolSetting((0.35, -0.2, 0.15)), WorkpieceSetting((0.03, -0.02, 0.01)))
ROTATED = ErrorSet(ToolSetting((0.35, -0.2, 0.15)), WorkpieceSetting((0.03, -0.02, 0.01), (0.02, -0.03, 0.15)))
TILTED = ErrorSet(workpiece=WorkpieceSetting((0.01, 0.02, 0.0), (0.025, -0.0167, 0.0)))


def timed(fn, repeat=2):
    """Best (CPU s, wall s) of `repeat` runs, and the last result."""
    best_c, best_w, out = np.inf, np.inf, None
    for _ in range(repeat):
        c, w = time.process_time(), time.perf_counter()
        out = fn()
        best_c, best_w = min(best_c, time.process_time() - c), min(best_w, time.perf_counter() - w)
    return best_c, best_w, out


def path_commands(machine, n):
    """A program-like path: consecutive poses 1e-3 of the travel apart (rotary axes sweeping)."""
    s = np.linspace(0.0, 1.0, n)
    q = np.empty((n, machine.n_axes))
    for k, a in enumerate(machine.axes):
        lo, hi = (max(a.limits[0], -60.0), min(a.limits[1], 60.0)) if a.is_rotary else \
            (0.3 * a.limits[0], 0.3 * a.limits[1])
        if a.is_rotary and a.name == "B" and machine.n_rotary == 2:
            lo, hi = 10.0, 40.0
        q[:, k] = lo + (hi - lo) * (0.5 + 0.5 * np.sin(2 * np.pi * (k + 1) * s))
    return q


def tilted_blank_program(n):
    """3-axis program (B = C = 0) on robonano-a0ib: circles in X-Y, slow feed in Z."""
    q = np.zeros((n, 5))
    s = np.linspace(0.0, 1.0, n)
    q[:, 2], q[:, 3], q[:, 4] = 30 * np.cos(40 * s), 30 * np.sin(40 * s), -0.01 * s
    return q


def previous_kernel(rev, tmp):
    """The kernel library of git revision `rev` (its sources from git, compiled into tmp)."""
    root = Path(__file__).resolve().parent.parent
    src = Path(tmp) / "src"
    src.mkdir()
    for name in _kernel.SOURCES:
        blob = subprocess.run(["git", "show", f"{rev}:fmu/c/{name}"], cwd=root, capture_output=True, check=True)
        (src / name).write_bytes(blob.stdout)
    lib = _kernel.compile_library(Path(tmp) / ("libmtk-previous" + _kernel._SUFFIX), src)
    return _kernel._bind(ctypes.CDLL(str(lib)))


def with_library(lib, fn):
    """fn() with `lib` as the kernel library of `retarget` and `forward` (the same Python path
    around it as the current library's rows: a like-for-like baseline)."""
    def run():
        saved = _kernel._state.get("lib")
        _kernel._models.clear()
        _kernel._state["lib"] = lib
        try:
            return fn()
        finally:
            _kernel._state["lib"] = saved
            _kernel._models.clear()
    return run


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--points", type=int, default=200_000)
    ap.add_argument("--numpy-points", type=int, default=40_000)
    ap.add_argument("--no-write", action="store_true")
    ap.add_argument("--previous", metavar="REV", help="also time the kernel of this git revision (every retarget row)")
    a = ap.parse_args(argv)
    tmpdir = tempfile.TemporaryDirectory()
    prev = previous_kernel(a.previous, tmpdir.name) if a.previous else None
    if not _kernel.available():
        sys.exit("the compiled kernel is unavailable (no C compiler): nothing to compare")
    rng = np.random.default_rng(3)
    N, Nn = a.points, a.numpy_points
    rows = []  # (case, machine, C CPU rate, C wall rate, numpy CPU rate, numpy wall rate, max |C - numpy|)

    def case(label, mname, fn_c, fn_n, n_c, n_n, compare=True, fn_prev=None):
        cc, cw, qc = timed(fn_c, repeat=5)  # (best of 5: the machine is shared, CPU time suffers too)
        os.environ["MTCOMP_THREADS"] = "1"  # the same batch on one thread: the threads' gain in wall time
        try:
            c1, w1, q1 = timed(fn_c, repeat=2)
        finally:
            os.environ.pop("MTCOMP_THREADS")
        assert np.array_equal(q1, qc), "one thread and several must give the same bits"
        nc, nw, qn = timed(fn_n, repeat=1)
        diff = float(np.max(np.abs(qc[:n_n] - qn))) if compare else float("nan")
        pc = float("nan")
        if fn_prev is not None:
            os.environ["MTCOMP_THREADS"] = "1"   # (CPU time: the threads do not change it)
            try:
                pc = n_c / timed(fn_prev, repeat=3)[0]
            finally:
                os.environ.pop("MTCOMP_THREADS")
        rows.append((label, mname, n_c / cc, n_c / cw, n_n / nc, n_n / nw, diff, n_c / c1, n_c / w1, pc))
        print(f"{label:48s} {mname:18s} C {n_c / cc:>12,.0f}/s CPU ({n_c / cw:>12,.0f}/s wall; 1 thread "
              f"{n_c / c1:>12,.0f} CPU, {n_c / w1:>12,.0f} wall)  numpy "
              f"{n_n / nc:>10,.0f}/s CPU  |C-numpy| {diff:.1e}" + (f"  previous {pc:,.0f}/s CPU" if pc == pc else ""),
              flush=True)

    for name in ("robonano-ui", "robonano-a0ib", "vmc-moving-column"):
        m = load_machine(name)
        q = random_commands(m, N, rng, span=0.3)
        geo = random_errors(m, rng, wp_angle=0.05 if m.n_rotary else 0.5)
        retarget(m, q[:10], RIGID, check=False)  # load the kernel before timing
        def kernel(errs, qq):
            return lambda: retarget(m, qq, errs, check=False, backend="c")

        def before(errs, qq):
            return with_library(prev, kernel(errs, qq)) if prev else None
        case("retarget, setting errors (closed form)", name, kernel(RIGID, q),
             lambda: retarget(m, q[:Nn], RIGID, check=False, backend="numpy"), N, Nn,
             fn_prev=before(RIGID, q))
        if m.n_rotary:
            case("retarget, rigid + workpiece rotation (closed form)", name, kernel(ROTATED, q),
                 lambda: retarget(m, q[:Nn], ROTATED, check=False, backend="numpy"), N, Nn,
                 fn_prev=before(ROTATED, q))
            qp = path_commands(m, N)
            case("  same, along a path (warm start)", name, kernel(ROTATED, qp),
                 lambda: retarget(m, qp[:Nn], ROTATED, check=False, backend="numpy"), N, Nn,
                 fn_prev=before(ROTATED, qp))
        case("retarget, tables on all axes + setting + location", name, kernel(geo, q),
             lambda: retarget(m, q[:Nn // 4], geo, check=False, backend="numpy"), N, Nn // 4,
             fn_prev=before(geo, q))
        qt = path_commands(m, N)
        case("  same, along a path (warm start)", name, kernel(geo, qt),
             lambda: retarget(m, qt[:Nn // 4], geo, check=False, backend="numpy"), N, Nn // 4,
             fn_prev=before(geo, qt))
        # the compensate command's check of every block: the real tool edge against the ideal
        # one at the programmed and at the emitted commands (emitted: micrometres and
        # micro-degrees away); the baseline is what the check did before, three forward passes
        qe = q + 1e-4

        def three_forwards(errs):
            def run():
                t = forward_position(m, q, backend="c")
                d1 = forward_position(m, q, errs, backend="c") - t
                d2 = forward_position(m, qe, errs, backend="c") - t
                return np.stack([np.sqrt(np.einsum("ij,ij->i", d1, d1)), np.sqrt(np.einsum("ij,ij->i", d2, d2))], 1)
            return run
        case("check of every block, setting errors (`deviations`)", name,
             lambda: np.stack(deviations(m, q, qe, RIGID, backend="c"), 1),
             lambda: np.stack(deviations(m, q[:Nn], qe[:Nn], RIGID, backend="numpy"), 1), N, Nn,
             fn_prev=with_library(prev, three_forwards(RIGID)) if prev else None)
        case("forward, tables on all axes + setting + location", name,
             lambda: forward(m, q, geo, backend="c").p,
             lambda: forward(m, q[:Nn], geo, backend="numpy").p, N, Nn)

    m = load_machine("robonano-a0ib")
    qs = tilted_blank_program(20_000)
    case("singular: 3-axis program, blank tilted 0.03 deg", "robonano-a0ib",
         lambda: retarget(m, qs, TILTED, backend="c"), lambda: retarget(m, qs, TILTED, backend="numpy"),
         len(qs), len(qs))
    qr = qs.copy()
    qr[:, 1] = 20.0  # the same program on a tilted B: a regular pose
    case("  regular reference: same program at B = 20", "robonano-a0ib",
         lambda: retarget(m, qr, TILTED, check=False, backend="c"),
         lambda: retarget(m, qr, TILTED, check=False, backend="numpy"), len(qr), len(qr))
    singular_s = len(qs) / rows[-2][2]

    # `mtcomp compensate` end to end (bench_gcode's child run: read, parse, travel checks, retarget,
    # rewrite, the written words read back, the forward-model check of every block, atomic write),
    # beside the path without the compiled text library in the same run
    import bench_gcode
    n_lines = 200_000
    with tempfile.TemporaryDirectory() as tmp:
        pin, pout = os.path.join(tmp, "in.nc"), os.path.join(tmp, "out.nc")
        Path(pin).write_text(bench_gcode.generate(n_lines), encoding="utf-8", newline="")
        comp = min((bench_gcode.run_child(pin, pout, "compensate_e2e", False, True) for _ in range(2)),
                   key=lambda r: r["cpu"])
        comp_old = bench_gcode.run_child(pin, pout, "compensate_e2e", True, False)
    print(f"mtcomp compensate, {comp['lines']} lines: {comp['lines'] / comp['cpu']:,.0f} lines/s CPU "
          f"({comp['lines'] / comp['wall']:,.0f} wall), old path {comp_old['lines'] / comp_old['cpu']:,.0f} lines/s CPU")

    def rate(label, mname, after=None):
        """Lowest CPU rate of the rows `label` (on machine `mname`); `after`: only rows that
        directly follow a row with that label (the path rows share one label)."""
        return min(r[2] for k, r in enumerate(rows) if r[0] == label and (mname is None or r[1].strip() == mname)
                   and (after is None or (k > 0 and rows[k - 1][0] == after)))

    targets = [
        ("`retarget`, setting errors only (closed form)", ">= 10 M poses/s",
         rate("retarget, setting errors (closed form)", None), 10e6),
        ("`retarget` with component tables on all axes, random poses", ">= 2 M poses/s",
         rate("retarget, tables on all axes + setting + location", None), 2e6),
        ("the same along a path (warm start, as in an NC program or the FMU)", ">= 2 M poses/s",
         rate("  same, along a path (warm start)", None, after="retarget, tables on all axes + setting + location"),
         2e6),
        ("rigid + workpiece rotation, 5 axes", ">= 5 M poses/s",
         rate("retarget, rigid + workpiece rotation (closed form)", "robonano-a0ib"), 5e6),
    ]
    md = [f"## Core model throughput (`benchmarks/bench_kernel.py --points {N}`)", "",
          machine_line() + f" Load average during the run: {os.getloadavg()[0]:.1f} (wall time suffers "
          "most from other jobs on the machine; CPU time is the figure to compare). The compiled kernel (`fmu/c/mtk.c`, called through ctypes in one batch) "
          f"beside the numpy reference implementation of the same algorithm in the same run ({Nn} "
          f"points for numpy, {Nn // 4} with tables). Rates in poses per second of CPU time, wall "
          "time in brackets for the kernel; random poses within 30 % of each travel unless a path. "
          "Setting errors: tool (0.35, -0.2, 0.15) mm, workpiece (30, -20, 10) µm; rotation "
          "(0.02, -0.03, 0.15) deg; tables: 15-point random tables on every axis with location "
          "errors and setting errors. \"max difference\" is the largest difference of the commands "
          "(mm or deg) between the kernel and numpy." + (
              f" The previous kernel (git {a.previous}, compiled in this run) on the same poses through the "
              "same `retarget` call, on one thread, beside the current one: the machine's CPU rate drifts "
              "between runs (the closed form on a0ib measured 9-12.5 M/s in different runs on this machine, "
              "old and new kernels alike), the ratio in one run is the comparison." if prev else ""), "",
          "| case | machine | kernel, poses/s CPU (wall) | kernel on 1 thread, CPU (wall) | numpy, poses/s CPU | max difference |"
          + (f" previous kernel ({a.previous}), CPU |" if prev else ""),
          "|---|---|---|---|---|---|" + ("---|" if prev else "")]
    for r in rows:
        md.append(f"| {r[0].strip()} | {r[1].strip()} | {r[2]:,.0f} ({r[3]:,.0f}) | {r[7]:,.0f} ({r[8]:,.0f}) | "
                  f"{r[4]:,.0f} | {r[6]:.1e} |" + ((f" {r[9]:,.0f} |" if r[9] == r[9] else " |") if prev else ""))
    md += ["", f"`mtcomp compensate` end to end ({comp['lines']:,} lines, robonano-a0ib, setting errors; "
           "bench_gcode.py's child run: read, parse, travel checks, retarget, rewrite, the written "
           "words read back and checked, the forward-model check of every compensated block, atomic "
           "write): "
           f"{comp['lines'] / comp['cpu']:,.0f} lines/s CPU ({comp['lines'] / comp['wall']:,.0f} wall), "
           f"peak {comp['maxrss_mb']:.0f} MB; without the compiled text library (numpy tokenizer, output "
           f"parsed again for the check), in the same run: {comp_old['lines'] / comp_old['cpu']:,.0f} "
           "lines/s CPU. The check of every block is one kernel pass per chunk (`kinematics.deviations`: "
           "the ideal and the real tool edge at the programmed commands through one chain, the real one at "
           "the emitted commands with the rotary sines and cosines by the angle sum; its row above, beside "
           "the three forward passes it replaces, through the previous kernel); parsing the input and rewriting take most of the time "
           "(the G-code reader and writer; their figures, the profile and the 1 M-line run are in the "
           "gcode block).",
           "", "Targets of the compiled-kernel issue (CPU time, minimum over the machines; the previous "
           "kernel's column above, measured in the same run, shows how fast this machine ran in it):", "",
           "| path | target | measured | |", "|---|---|---|---|"]
    six = rate("retarget, rigid + workpiece rotation (closed form)", "robonano-ui")
    for label, target, got, need in targets:
        extra = f" (6 axes, robonano-ui: {six / 1e6:.2f} M/s)" if label.startswith("rigid") else ""
        md.append(f"| {label} | {target} | {got / 1e6:.2f} M/s{extra} | {'met' if got >= need else '**missed**'} |")
    md.append(f"| `mtcomp compensate` end to end | >= 1 M lines/s | {comp['lines'] / comp['cpu'] / 1e6:.2f} M lines/s | "
              f"{'met' if comp['lines'] / comp['cpu'] >= 1e6 else '**missed**'} |")
    md.append(f"| singular case (3-axis program on a tilted blank, a0ib), 20,000 lines | < 2 s, as fast as "
              f"the regular case | {singular_s:.3f} s ({rate('  regular reference: same program at B = 20', None) / rows[-2][2]:.1f}x "
              f"the regular case's time) | {'met' if singular_s < 2 else '**missed**'} |")
    def met_on(label, after=None):
        ok = [r[1] for k, r in enumerate(rows) if r[0] == label and r[2] >= 2e6
              and (after is None or rows[k - 1][0] == after)]
        return ", ".join(ok) if ok else "no machine"

    met_random = met_on("retarget, tables on all axes + setting + location")
    met_path = met_on("  same, along a path (warm start)", after="retarget, tables on all axes + setting + location")
    md += ["", "Where the time goes (perf, and counters in a test build). Setting errors without a workpiece "
           "rotation: the closed form, two or three sincos per pose and a 3x3 solve (constant where the "
           "linear axes come first in the chain); the Python side (allocation, the finite-command check) "
           "adds about a fifth. Setting errors with a workpiece rotation (two or three rotary axes): the "
           "rotary angles in closed form (the orientation of the rigid chain depends on them alone: "
           "Paden-Kahan subproblem 2 for the first two, subproblem 1 for the third), then the linear "
           "axes from the 3x3 system the position is affine in. Per pose, on vectors only (no rotation "
           "matrix, no forward evaluation): one sincos per rotary angle for the ideal target (its position "
           "and tool direction turned through the chain), three dot products of the target direction, the "
           "subproblems' components from constants of the batch, the far solution dropped by the cosine of "
           "its turn before any atan2 (so one atan2 per rotary angle), the pole test on the solution from "
           "the same dot products (the pole rule's invariants: the first axis' turn changes neither the "
           "lengths nor the determinant it tests), and the linear axes by undoing the rotary axes on the target position where they come "
           "first (a0ib) or by the constant inverse where they come last (ui); which of the two solutions "
           "is taken is decided without a branch (random poses pick either, and a mispredicted branch cost "
           "more than the arithmetic). About 160 ns per pose in C on a0ib, 250 ns on ui (was 330-410 ns "
           "and 380-390 ns), of which the two atan2 and two sincos are about a third; poses within "
           "five times the pole tolerance of a pole or needing a rotary turn over 10 deg go to the iteration. "
           "With tables: a pose more than 1 deg or 1 mm from the previous one starts from the rigid model's "
           "closed-form solution plus the previous pose's correction beyond it (the tables' part); then "
           "one analytic Jacobian pass of the full model (the tables' slopes and the location "
           "errors in it) at the start, which also gives the residual there, then Newton steps on the normal "
           "equations (the residual from the position and tool direction only on machines with up to two "
           "rotary axes, from the position and two columns of the tool frame with three, the third their "
           "cross product; turned on vectors from the tool end). Two things cut the forward evaluations: "
           "from such a far start the first step solves the quadratic model of the chain (its second "
           "derivatives from the same pass: d2p/dq_i dq_j = W_i x P_j, the earlier axis' angular velocity "
           "crossed with the later axis' column, and on the diagonal of a table axis its twist's own rate), "
           "which leaves about 1e-9 mm rather than 1e-6 mm; and a step is taken without evaluating the "
           "model after it where a bound on those second derivatives (the axes' angular velocities, the "
           "columns' lengths over the box the steps span, all tables within one interval) keeps the "
           "linear prediction within 5e-11 mm. The rotary sines and cosines of the iteration come from the "
           "axis' last directly taken angle by the angle sum where within 1e-2 rad (the iterates of a pose, "
           "the poses of a path). Along a path (a pose within 1 deg and 1 mm of the previous one) the start "
           "is extrapolated from the corrections of the last three poses (a parabola in the distance along "
           "the path; a line through two where the segments differ in length or direction; on the "
           "differences of the corrections, so that an axis whose correction does not change keeps its "
           "bits), which leaves it within about 1e-10 mm of the solution inside a table interval, rather "
           "than about 1e-7 mm from the previous correction alone. Such a pose is then solved on the Jacobian "
           "of an earlier pose of the path: the residual at the start evaluated (the pose's one evaluation), "
           "the chord step (the matrix (J^T J + lambda I)^-1 J^T formed once per Jacobian) taken where the "
           "same second-order bound (over the box from the Jacobian's point) keeps the linear prediction "
           "within 5e-11 mm, else the pose solved afresh and its Jacobian kept (after a failed try the next "
           "tries wait 1, 3, 7, 15 poses; not where the pole rule, tested on the pose's own target, might "
           "hold an axis). With three rotary axes the "
           "orientation rows (the skew part of T^T R) depend on the target's frame T too, which turns along "
           "the path: their columns at the Jacobian's point differ from those for the current target by at "
           "most wo |T_lin - T|_F |W_j| / sqrt 2, so the bound adds sqrt 2 wo |T_lin - T|_F sum_j w_j |s_j| "
           "(along the benchmark's path a median of 2e-13 mm beside the second-order term's 1.6e-11 mm). "
           "Counted in a test "
           "build (3,000 random poses, and the first 3,000 poses of the benchmark's path): per random pose "
           "1.3 forward evaluations after the Jacobian pass on a0ib, 1.15 on ui, 1.0 on the 3-axis machine "
           "(unchanged); per path pose 1.0 evaluation and 0.005 Jacobian passes on a0ib, 1.0 and 0.021 on ui "
           "(before: none and 1), 1.0 and 0.001 on the 3-axis machine. In instructions per pose (callgrind, "
           "same poses; random, then path) 16,600 and 3,500 on a0ib, 22,300 and 5,000 on ui, 6,800 and 2,100 "
           "on the 3-axis machine, against 16,500 and 4,000, 22,600 and 11,800, 6,700 and 2,200 before (git "
           "f960c88, same poses). On random poses "
           "the Jacobian pass (with the angular velocities and bracket columns the quadratic first step "
           "needs) is about a third of the instructions, the forward evaluations and the normal equations "
           "most of the rest, spread over 3x3 products, cross products and table look-ups with no single "
           "hot spot: the 2 M/s target needs about 2,500 instructions per pose at this machine's rate, "
           "six to nine times fewer than the iteration takes on the machines with rotary axes. Not done: "
           "SIMD across poses (the forward evaluations and the Jacobian pass on 2 or 4 poses at once); "
           "compiler flags alone (-march=native, -march=x86-64-v3, -fno-trapping-math) measured no gain on "
           "the scalar code (the same bits: no contraction under -std=c99); a prototype of the forward "
           "evaluation with tables on 4 random poses at once (GCC vector extensions over the poses, the same "
           "bits) ran 1.02-1.12x as fast as the scalar one on ui and 1.03-1.04x on a five-axis table machine "
           "at the library's baseline instruction set (SSE2: the 4 lanes as two pairs), 1.4-1.5x with -mavx2 "
           "(the sines and cosines and the table look-ups stay per pose). Along the ui path about half of a "
           "pose's instructions are its one evaluation (the position and two columns of the tool frame "
           "through six tables), a sixth the ideal target, the rest the chord step, the bound and the "
           "Jacobians taken afresh (a knot crossed or the bound exceeded, every 47 poses); before, each pose "
           "took its own Jacobian pass (about half of its instructions): with three rotary axes an earlier "
           "pose's Jacobian was not used. "
           f"With tables the 2 M/s target is met on random poses on {met_random}, along the path on "
           f"{met_path}. Threads: a batch is cut into chunks of 4,096 poses that do not "
           "depend on the number of threads (each chunk after the first takes up the path from the 16 "
           "poses before it), run on min(cores, chunks) threads started in C (MTCOMP_THREADS "
           "overrides); one thread and two give the same bits (asserted in this run). The CPU-time "
           "rates count both threads; the wall-time gain shows in the 1-thread column, and depends on "
           "what else runs on the machine. The FMU step and `mtcomp compensate` end to end are "
           "measured by bench_fmu.py and bench_gcode.py."]
    if not a.no_write:
        update_section("kernel", "\n".join(md))


if __name__ == "__main__":
    main()
