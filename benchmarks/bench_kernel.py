"""Throughput of the core model: forward model and compensation (retarget), vectorised numpy,
side by side with a straightforward per-point loop (4x4 matrices, one pose at a time) in the
same run.  Writes the "kernel" section of docs/benchmarks.md.

    python benchmarks/bench_kernel.py [--points 200000]
"""
from __future__ import annotations

import argparse
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from _report import machine_line, update_section  # noqa: E402
from _models import independent_forward, random_commands, random_errors  # noqa: E402

from mtcomp.errors import ErrorSet, ToolSetting, WorkpieceSetting  # noqa: E402
from mtcomp.kinematics import forward, retarget  # noqa: E402
from mtcomp.machine import load_machine  # noqa: E402


def timed(fn, *a, repeat=3):
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn(*a)
        best = min(best, time.perf_counter() - t)
    return best, out


def peak_mb(fn, *a):
    tracemalloc.start()
    fn(*a)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak / 2**20


def baseline_retarget(m, q, E, forward_one):
    """Per point: Newton on the one-pose model with a finite-difference Jacobian."""
    out = np.empty_like(q)
    for k in range(len(q)):
        p_t, R_t = forward_one(m, q[k], ErrorSet())
        x = q[k].copy()
        for _ in range(6):
            p, R = forward_one(m, x, E)
            r = np.r_[p - p_t, 100 * (R[:, 2] - R_t[:, 2])] if m.n_rotary else p - p_t
            J = np.empty((len(r), len(x)))
            for j in range(len(x)):
                d = x.copy()
                d[j] += 1e-6
                p2, R2 = forward_one(m, d, E)
                r2 = np.r_[p2 - p_t, 100 * (R2[:, 2] - R_t[:, 2])] if m.n_rotary else p2 - p_t
                J[:, j] = (r2 - r) / 1e-6
            x -= np.linalg.lstsq(J, r, rcond=None)[0]
        out[k] = x
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--points", type=int, default=200_000)
    ap.add_argument("--baseline-points", type=int, default=300)
    ap.add_argument("--no-write", action="store_true")
    a = ap.parse_args(argv)
    rng = np.random.default_rng(3)
    rows = []
    for name in ("robonano-ui", "robonano-a0ib", "vmc-moving-column"):
        m = load_machine(name)
        q = random_commands(m, a.points, rng, span=0.3)
        geo = random_errors(m, rng, wp_angle=0.05 if m.n_rotary else 0.5)
        rigid = ErrorSet(ToolSetting((0.35, -0.2, 0.15)), WorkpieceSetting((0.03, -0.02, 0.01)))
        print(f"{name}: {a.points} points", flush=True)
        t_fwd, _ = timed(forward, m, q, geo, repeat=2)
        t_rig, _ = timed(retarget, m, q, rigid, repeat=2)
        t_geo, qg = timed(retarget, m, q, geo, repeat=1)
        err = np.abs(forward(m, qg, geo).p - forward(m, q).p).max()
        mem = peak_mb(retarget, m, q, geo)
        nb = a.baseline_points
        t_bf, _ = timed(lambda: [independent_forward(m, q[k], geo) for k in range(nb)], repeat=1)
        t_bc, _ = timed(baseline_retarget, m, q[:nb], geo, independent_forward, repeat=1)
        rows.append((name, a.points / t_fwd, nb / t_bf, a.points / t_rig, a.points / t_geo, nb / t_bc, err, mem))
        print(f"  forward {a.points / t_fwd:,.0f}/s (loop {nb / t_bf:,.0f}/s); retarget rigid "
              f"{a.points / t_rig:,.0f}/s, with tables {a.points / t_geo:,.0f}/s (loop {nb / t_bc:,.0f}/s); "
              f"max error {err * 1e6:.2e} nm; peak {mem:.0f} MB", flush=True)
    md = [f"## Core model throughput (`benchmarks/bench_kernel.py --points {a.points}`)", "",
          machine_line() + " Vectorised numpy (`mtcomp.kinematics`) beside a straightforward per-point "
          "loop (4x4 matrices, one pose at a time; Newton with a finite-difference Jacobian) in the "
          f"same run ({a.baseline_points} points for the loop). Errors: setting errors (rigid) or "
          "setting + component tables on every axis + location errors (tables).", "",
          "| machine | forward, tables (poses/s) | loop | retarget rigid (poses/s) | retarget tables (poses/s) "
          "| loop | max residual after | peak memory (tables) |",
          "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        md.append(f"| {r[0]} | {r[1]:,.0f} | {r[2]:,.0f} | {r[3]:,.0f} | {r[4]:,.0f} | {r[5]:,.0f} | "
                  f"{r[6] * 1e6:.1e} nm | {r[7]:.0f} MB |")
    md += ["", "Targets of issue 2: >= 10 million points/s with rigid setting errors and >= 2 million/s with "
           "tables; both are missed. Where the time goes (cProfile): the rigid case is a closed form (one "
           "nominal chain pass and a 3x3 solve per point), about 20 numpy passes over (N,3,3) arrays, "
           "memory-bound. With tables, the Gauss-Newton takes a chord Jacobian from 1 + n_axes rigid "
           "evaluations plus 3-6 full evaluations, each about 20 numpy passes per axis (interpolation, "
           "Rodrigues, 3x3 products); stacked 3x3 products go through einsum(optimize=True), 3-6x faster "
           "than matmul on stacks. Reaching the targets needs a compiled per-point kernel: the FMU's C "
           "kernel (docs/fmu.md) is such a port of the same algorithm. A numba version was tried and "
           "dropped: its parallel JIT compile took about 60 s on first use."]
    if not a.no_write:
        update_section("kernel", "\n".join(md))


if __name__ == "__main__":
    main()
