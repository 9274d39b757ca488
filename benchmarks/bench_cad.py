"""Benchmark: the CAD plugin's toolpath, post and virtual check on paper 001's pyramid.

    python benchmarks/bench_cad.py [--stepover 0.02] [--step 0.01] [--grid 0.01]

Measured in one run, side by side:

* the pyramid finishing toolpath (exact drop-cutter with chordal refinement), poses/s;
* machine axes on robonano-a0ib, nominal and compensated for a workpiece setting error
  (``to_axes`` over ``mtcomp.kinematics.compensate``), poses/s; the post-processor, blocks/s;
* the machined-surface envelope: the plugin's splat over the reach disk (``check.ball_envelope``)
  against a straightforward baseline written here (for every grid point, every ball within the
  full tool radius, found with scipy's cKDTree), both on the same swept ball centres; they must
  agree to 1e-12 mm;
* the verification of the compensated program (``mtcomp.verify``) beside reading it alone;
* the parts' build times and volumes, ``features.volume`` (adaptive integration) against
  CadQuery's ``Shape.Volume()`` and the analytic grating volume.

Figures go to docs/benchmarks.md, section "cad".
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import machine_line, update_section  # noqa: E402


def timed(fn, *a, **kw):
    w, c = time.perf_counter(), time.process_time()
    out = fn(*a, **kw)
    return out, time.perf_counter() - w, time.process_time() - c


def baseline_envelope(centres, r, pts):
    """Every ball within r of each point (exact by construction, no reach argument)."""
    from scipy.spatial import cKDTree
    tree = cKDTree(centres[:, :2])
    out = np.full(len(pts), np.nan)
    for k, idx in enumerate(tree.query_ball_point(pts, r)):
        if idx:
            c = centres[idx]
            d2 = ((c[:, :2] - pts[k]) ** 2).sum(1)
            out[k] = np.min(c[:, 2] - np.sqrt(np.maximum(r * r - d2, 0.0)))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stepover", type=float, default=0.02)
    ap.add_argument("--step", type=float, default=0.01)
    ap.add_argument("--grid", type=float, default=0.01)
    ap.add_argument("--sample", type=int, default=2000, help="grid points for the baseline")
    ap.add_argument("--no-report", action="store_true")
    args = ap.parse_args(argv)

    from mtcomp.cad_plugin import check as C, post as P, toolpath as T
    from mtcomp.errors import ErrorSet, WorkpieceSetting
    from mtcomp.kinematics import round_to_resolution
    from mtcomp.machine import load_machine

    m = load_machine("robonano-a0ib")
    err = ErrorSet(workpiece=WorkpieceSetting((0.035, -0.020, 0.015), (0.12, -0.25, 0.8)))
    print("toolpath ...", flush=True)
    tp, tw, tc = timed(T.pyramid_finishing, 3.45, 164.81, T.Tool("ball", 0.5),
                       stepover=args.stepover, step=args.step)
    n = len(tp)
    print(f"  {n} poses in {tw:.2f} s", flush=True)
    print("axes ...", flush=True)
    q0, aw, ac = timed(T.to_axes, m, tp)
    qc, cw, cc = timed(T.to_axes, m, tp, err)
    print(f"  nominal {aw:.2f} s, compensated {cw:.2f} s", flush=True)
    text, pw, pc = timed(P.post, m, tp, qc, errors=err)
    qr = round_to_resolution(m, qc)
    print("envelope ...", flush=True)
    centres = C.swept_centres(m, tp, qr, err, max_step=args.grid / 2)
    ext = 3.45 / 2 + 0.2
    xs = np.arange(-ext, ext + args.grid / 2, args.grid)
    tilt = math.acos(float(np.min(tp.normal[tp.cutting][:, 2])))
    reach = 0.5 * math.sin(tilt + math.radians(1)) + 0.5 * max(args.grid, args.stepover) + args.grid
    env, ew, ec = timed(C.ball_envelope, centres, 0.5, xs, xs, reach)
    # The baseline visits thousands of balls per point: run it on a random sample of the grid.
    rng = np.random.default_rng(1)
    iy, ix = rng.integers(0, len(xs), args.sample), rng.integers(0, len(xs), args.sample)
    base, bw, bc = timed(baseline_envelope, centres, 0.5, np.column_stack([xs[ix], xs[iy]]))
    diff = float(np.nanmax(np.abs(env[iy, ix] - base)))
    print(f"  splat {ew:.2f} s, baseline {bw:.2f} s, max difference {diff:.2e} mm", flush=True)
    meas = C.pyramid_widths_angles(m, tp, qr, err)
    print("verify ...", flush=True)
    from mtcomp import gcode
    from mtcomp.cad_plugin.layout import pyramid_height
    from mtcomp.verify import Box, HalfSpace, verify_program
    _, gw, gc = timed(gcode.parse, text, axes=m.axis_names)   # baseline: reading alone
    stock = Box((-10.0, -10.0, -5.0), (10.0, 10.0, pyramid_height(3.45, 164.81)))
    ver, verw, verc = timed(verify_program, m, text, stock=stock, part=HalfSpace(0.0), clearance=0.2,
                        tool_radius=0.5, errors=err, tolerance=1e-3)
    print(f"  read {gw:.2f} s, read + verify {verw:.2f} s, {ver.n_samples} samples", flush=True)

    print("parts ...", flush=True)
    from mtcomp.cad_plugin import features as F  # noqa: E402 (cadquery import)
    rows = []
    for name, fn in [("groove_plate", F.groove_plate), ("bowl_blank", F.bowl_blank),
                     ("pyramid_part", F.pyramid_part), ("concave_grating", F.concave_grating)]:
        wp, bw_, _ = timed(fn)
        v, vw, _ = timed(F.volume, wp)
        v0, v0w, _ = timed(wp.val().Volume)
        rows.append((name, bw_, v, vw, v0, v0w))
    g = F.GratingLayout()
    T_ = math.tan(math.radians(g.angle) / 2)
    Rs, D = g.sphere_radius, g.depth
    a_, b_, c_ = 1 + 1 / T_ ** 2, -2 * (Rs + D) / T_, (Rs + D) ** 2 - Rs ** 2
    hs = (-b_ - math.sqrt(b_ * b_ - 4 * a_ * c_)) / (2 * a_)

    def Fi(h):
        return 0.5 * (-(T_ / 3) * (Rs + D - h / T_) ** 3 - Rs ** 2 * h + h ** 3 / 3)
    groove = math.radians(g.span) * 2 * (Fi(hs) - Fi(0.0))
    zr = g.rim_height
    exact = (math.pi * g.aperture_radius ** 2 * (g.height + zr)
             - math.pi * zr * zr * (3 * Rs - zr) / 3 - g.n_grooves * groove)

    lines = [
        f"Paper 001's pyramid (3450 µm, 164.81°), ball R0.5, stepover {args.stepover} mm, step "
        f"{args.step} mm, chord tolerance 10 nm; machine robonano-a0ib; workpiece setting error "
        "(35, −20, 15) µm, (0.12, −0.25, 0.8)°. " + machine_line()
        + " Wall clock depends on the load of the (shared) machine; CPU s is the work done.",
        "",
        "| stage | poses | wall s | CPU s | rate |",
        "|---|---|---|---|---|",
        f"| toolpath (drop-cutter + refinement) | {n} | {tw:.2f} | {tc:.2f} | {n / tw:,.0f} poses/s |",
        f"| axes, nominal (`to_axes`) | {n} | {aw:.2f} | {ac:.2f} | {n / aw:,.0f} poses/s |",
        f"| axes, compensated | {n} | {cw:.2f} | {cc:.2f} | {n / cw:,.0f} poses/s |",
        f"| post-processor | {n} | {pw:.2f} | {pc:.2f} | {n / pw:,.0f} blocks/s |",
        f"| envelope, plugin splat (reach {reach:.3f} mm) | {len(centres)} balls, {len(xs) ** 2} grid points "
        f"| {ew:.2f} | {ec:.2f} | {len(xs) ** 2 / ew:,.0f} points/s |",
        f"| envelope, baseline (every ball within r, cKDTree) | same balls, {args.sample} sampled "
        f"grid points | {bw:.2f} | {bc:.2f} | {args.sample / bw:,.0f} points/s |",
        f"| program read back (`gcode.parse`, baseline of the next row) | {n} | {gw:.2f} | {gc:.2f} "
        f"| {n / gw:,.0f} blocks/s |",
        f"| verification (`verify_program`: read, every block swept at ≤ 5 µm through the forward "
        f"model with the error, rapids against the blank, feeds against z = 0) | {ver.n_samples} samples "
        f"| {verw:.2f} | {verc:.2f} | {n / verw:,.0f} blocks/s |",
        "",
        f"Splat and baseline agree to {diff:.1e} mm on the sampled points. Compensated program (rounded to 1 nm / 1e-5°) "
        "through the forward model with the same error: widths "
        + ", ".join(f"{(w - 3.45) * 1e3:+.4f}" for w in meas.widths) + " µm from 3450 µm, angles "
        + ", ".join(f"{a - 164.81:+.5f}" for a in meas.angles) + "° from 164.81°.",
        "",
        "| part | build s | `features.volume` mm³ (s) | `Shape.Volume()` mm³ (s) |",
        "|---|---|---|---|",
    ]
    for name, bw_, v, vw, v0, v0w in rows:
        lines.append(f"| {name} | {bw_:.3f} | {v:.9f} ({vw:.3f}) | {v0:.9f} ({v0w:.3f}) |")
    lines += ["", f"Grating, analytic volume {exact:.9f} mm³: adaptive integration off by "
              f"{abs(rows[-1][2] - exact) / exact:.1e} relative, `Shape.Volume()` by "
              f"{abs(rows[-1][4] - exact) / exact:.1e}."]
    md = "\n".join(lines)
    print(md)
    if not args.no_report:
        update_section("cad", "## CAD plugin (benchmarks/bench_cad.py)\n\n" + md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
