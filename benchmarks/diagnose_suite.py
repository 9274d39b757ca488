"""Proof of the diagnosis: concealed effects in generated recordings, named or not?

Generates SIM/REC pairs (mtcomp.diagnose.synth: random moves and dwells, 20 nm noise,
temperatures and auxiliary columns logged whether they matter or not, other sample rates and
start times, um in some headers, some recordings quantised) with one or two concealed effects
and null cases with none, runs the diagnosis, and reports

- the identification rate (exact effect set named) and the confusion matrix of single effects,
- nothing named on null cases,
- parameter recovery (relative error of each effect's main parameters),
- held-out RMS after the fit relative to the noise floor,
- the time to diagnose 45,000 samples with 10 input columns (from CSV files).

Baseline in the same run: "REC - SIM" (RMS before), against which the held-out reduction is
measured.  Then the out-of-family cases of benchmarks/diagnose_outfamily.py (generators not
tuned on: fine-grid physics sampled twice, joints, velocities, stop-and-measure, 1 µm counts,
effects outside the library), reported separately.
Usage: python benchmarks/diagnose_suite.py [--quick] [--seeds N] [--jobs J] [--ood-seeds N]
Writes its sections of docs/benchmarks.md and docs/diagnose.md.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

# one BLAS thread per process: the suite runs its own process pool on the two cores
for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

NAMES = ("thermal_drift", "backlash", "servo_lag", "periodic_pitch_error", "scale_error",
         "squareness", "straightness", "pivot_offset", "workpiece_setting", "time_offset")
PAIRS = (("backlash", "thermal_drift"), ("scale_error", "periodic_pitch_error"),
         ("servo_lag", "thermal_drift"), ("squareness", "backlash"),
         ("pivot_offset", "thermal_drift"), ("straightness", "time_offset"),
         ("workpiece_setting", "backlash"), ("scale_error", "servo_lag"))


def conditions(rng, quick: bool) -> dict:
    """Random recording conditions of one case."""
    return dict(duration=float(rng.uniform(25, 40) if quick else rng.uniform(30, 90)),
                sim_rate=float(rng.choice([200.0, 250.0, 500.0, 1000.0])),
                # one in six recordings sparse (10 Hz: a few hundred samples)
                rec_rate=float(rng.choice([10.0, 100.0, 200.0, 500.0, 1000.0, 1000.0])),
                rec_start=float(rng.uniform(-2.0, 1.0)),
                n_temps=int(rng.integers(3, 6)), n_junk=int(rng.integers(1, 5)),
                um_headers=bool(rng.random() < 0.5),
                quantum=float(rng.choice([0.0, 0.0, 1e-6, 5e-6])))


def truth_value(name, truth, est):
    """(label, estimated, true) pairs of the main parameters of an effect."""
    out = []
    if name == "thermal_drift":
        gk = [k for k in truth if k.startswith("gain_")][0]
        if gk in est:
            out += [("gain", est[gk], truth[gk]), ("tau_s", est["tau_s"], truth["tau_s"])]
    elif name == "backlash":
        out.append(("backlash", est["backlash_mm"], truth["backlash_mm"]))
    elif name == "servo_lag":
        out.append(("kv", est["kv_per_s"], truth["kv_per_s"]))
    elif name == "periodic_pitch_error":
        out += [("lead", est["lead_mm"], truth["lead_mm"]),
                ("amplitude", est["amplitude_mm"], truth["amplitude_mm"])]
    elif name == "scale_error":
        out.append(("scale", est["scale"], truth["scale"]))
    elif name == "squareness":
        out.append(("angle", est["angle_deg"], truth["angle_deg"]))
    elif name == "straightness":
        from numpy.polynomial import legendre
        from mtcomp.diagnose.synth import RANGES
        x = np.linspace(est["range_lo_mm"], est["range_hi_mm"], 201)
        xi = (2 * x - sum(RANGES["x"])) / np.ptp(RANGES["x"])
        prof = legendre.legval(xi, [0, 0, truth["P2_mm"], truth["P3_mm"]])
        prof -= np.polyval(np.polyfit(x, prof, 1), x)
        out.append(("peak_to_valley", est["peak_to_valley_mm"], float(np.ptp(prof))))
    elif name == "pivot_offset":
        out += [("dx", est["dx_mm"], truth["dx_mm"]), ("dz", est["dz_mm"], truth["dz_mm"])]
    elif name == "workpiece_setting":
        out += [(k[:2], est.get(k, 0.0), truth[k]) for k in ("tx_mm", "ty_mm", "tz_mm", "rz_deg")]
    elif name == "time_offset":
        out.append(("offset", est["offset_s"], truth["offset_s"]))
    return out


def run_case(spec):
    """Generate and diagnose one case; returns a plain dict (picklable)."""
    from mtcomp.diagnose import diagnose, synth
    effects, seed, quick = spec
    rng = np.random.default_rng(1000 + seed)
    cond = conditions(rng, quick)
    case = synth.make_case(list(effects), seed=seed, **cond)
    t0 = time.perf_counter()
    res = diagnose(case.sim, case.rec)
    dt = time.perf_counter() - t0
    named = sorted(res.names)
    rec = []
    for name, outs, tp in case.truth:
        est = [e for e in res.effects if e.name == name]
        if est:
            for label, e, t in truth_value(name, tp, est[0].params):
                rec.append((name, label, float(e), float(t)))
    affected = sorted({o for _, outs, _ in case.truth for o in outs}) or list(res.outputs)
    ratio = max(res.fit["holdout_rms_after"][o] / res.noise_floor[o] for o in affected)
    red = [res.fit["holdout_rms_after"][o] / res.fit["holdout_rms_before"][o] for o in affected]
    worst = max(max(res.fit["holdout_rms_after"][o], res.fit["rms_after"][o]) / res.noise_floor[o]
                for o in res.outputs)
    silent = not res.effects and not res.unexplained and worst > 3.0
    return {"silent": bool(silent), "effects": sorted(effects), "named": named, "seed": seed, "cond": cond,
            "ok": named == sorted(effects), "recovery": rec, "ratio": float(ratio),
            "reduction": float(max(red)), "seconds": dt, "n": res.alignment["samples"],
            "log": list(res.log)}


def timing(repeats: int = 3) -> dict:
    """Diagnose 45,000 samples with 10 input columns from CSV files (SIM 500 Hz, REC 500 Hz)."""
    from mtcomp.diagnose import diagnose, synth
    case = synth.make_case(["backlash", "thermal_drift"], seed=77, duration=90.0, sim_rate=500.0,
                           rec_rate=500.0, rec_start=0.0, rec_end=90.0, n_temps=5, n_junk=3)
    with tempfile.TemporaryDirectory() as d:
        sim, rec = Path(d) / "sim.csv", Path(d) / "rec.csv"
        synth.write_csv(sim, case.sim)
        synth.write_csv(rec, case.rec)
        n_in = (len(case.sim) - 4) + (len(case.rec) - 4)
        walls, cpus, names = [], [], None
        for _ in range(repeats):
            w0, c0 = time.perf_counter(), time.process_time()
            res = diagnose(sim, rec)
            walls.append(time.perf_counter() - w0)
            cpus.append(time.process_time() - c0)
            names = res.names
    return {"samples": len(case.sim["t"]), "inputs": n_in, "wall": walls, "cpu": cpus,
            "named": names}


def confusion(results):
    labels = list(NAMES) + ["(none)"]
    idx = {n: i for i, n in enumerate(labels)}
    M = np.zeros((len(labels), len(labels)), int)
    for r in results:
        if len(r["effects"]) > 1:
            continue
        row = idx[r["effects"][0]] if r["effects"] else idx["(none)"]
        if not r["named"]:
            M[row, idx["(none)"]] += 1
        for n in r["named"]:
            M[row, idx[n]] += 1
    return labels, M


def markdown(results, tim, wall_total, quick, ood_seeds=None) -> str:
    eff = [r for r in results if r["effects"]]
    null = [r for r in results if not r["effects"]]
    ok_eff = sum(r["ok"] for r in eff)
    ok_null = sum(r["ok"] for r in null)
    ratios = np.array([r["ratio"] for r in eff])
    lines = [f"Run of `benchmarks/diagnose_suite.py{' --quick' if quick else ''}"
             f"{f' --ood-seeds {ood_seeds}' if ood_seeds else ''}`: "
             f"{len(eff)} cases with one or two concealed effects, {len(null)} null cases; "
             f"{wall_total:.0f} s in all. Noise 20 nm; SIM 200-1000 Hz, REC 10-1000 Hz on a "
             "clock starting up to 2 s apart; 3-5 temperatures and 1-4 auxiliary columns logged; "
             "um headers and 1-5 nm quantisation in some.", "",
             "| criterion | result | target |", "|---|---|---|",
             f"| right effect set named | {ok_eff}/{len(eff)} = "
             f"{100 * ok_eff / max(len(eff), 1):.1f} % | >= 95 % |",
             f"| nothing named on null cases | {ok_null}/{len(null)} = "
             f"{100 * ok_null / max(len(null), 1):.1f} % | >= 95 % |",
             f"| held-out RMS after / noise floor (effect cases) | median {np.median(ratios):.2f}, "
             f"95th pct {np.percentile(ratios, 95):.2f}, max {ratios.max():.2f}; "
             f"{np.mean(ratios <= 1.5) * 100:.1f} % <= 1.5 | <= 1.5 |",
             f"| held-out RMS after / before (baseline REC - SIM) | median "
             f"{np.median([r['reduction'] for r in eff]):.4f} | |",
             f"| cases answered 'nothing' with a residual > 3x the noise floor | "
             f"{sum(r['silent'] for r in results)} | 0 |"]
    if tim:
        lines.append(f"| {tim['samples']} samples, {tim['inputs']} input columns (CSV read to "
                     f"result) | {min(tim['wall']):.2f} s wall (best of {len(tim['wall'])}; "
                     f"mean {np.mean(tim['wall']):.2f} s), {min(tim['cpu']):.2f} s CPU | < 10 s |")
    lines += ["", "Confusion matrix of the single-effect and null cases (rows: concealed, "
              "columns: named):", ""]
    labels, M = confusion(results)
    short = {n: n.replace("periodic_pitch_error", "pitch").replace("workpiece_setting", "workpiece")
             .replace("thermal_drift", "thermal").replace("_error", "").replace("_offset", "_off")
             for n in labels}
    lines.append("| concealed \\ named | " + " | ".join(short[n] for n in labels) + " |")
    lines.append("|---" * (len(labels) + 1) + "|")
    for i, n in enumerate(labels):
        if M[i].sum() == 0:
            continue
        lines.append(f"| {short[n]} | " + " | ".join(str(v) if v else "." for v in M[i]) + " |")
    lines += ["", "Parameter recovery (relative error |estimate - truth| / |truth| where the "
              "effect was named; thermal only where the same driver was chosen):", "",
              "| effect | parameter | cases | median | max |", "|---|---|---|---|---|"]
    rec = {}
    for r in results:
        for name, label, e, t in r["recovery"]:
            rec.setdefault((name, label), []).append(abs(e - t) / abs(t) if t else abs(e))
    for (name, label), v in sorted(rec.items()):
        lines.append(f"| {name} | {label} | {len(v)} | {np.median(v):.2e} | {np.max(v):.2e} |")
    bad = [r for r in results if not r["ok"]]
    if bad:
        lines += ["", "Misidentified cases:", ""]
        for r in bad:
            lines.append(f"- seed {r['seed']}: concealed {'+'.join(r['effects']) or 'none'}, named "
                         f"{'+'.join(r['named']) or 'none'} (SIM {r['cond']['sim_rate']:.0f} Hz, "
                         f"REC {r['cond']['rec_rate']:.0f} Hz, {r['cond']['duration']:.0f} s)")
    import platform
    lines += ["", f"Measured on {platform.machine()} with {os.cpu_count()} cores, Python "
              f"{platform.python_version()}."]
    return "\n".join(lines)


def example_figure(path: Path) -> None:
    """The plot of one diagnosed case for the docs (backlash + thermal drift)."""
    from mtcomp.diagnose import diagnose, synth
    case = synth.make_case(["backlash", "thermal_drift"], seed=3, duration=60.0, sim_rate=200.0,
                           rec_rate=100.0)
    diagnose(case.sim, case.rec).plot(path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="small run (about a minute)")
    ap.add_argument("--seeds", type=int, default=None, help="repetitions of every case")
    ap.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1))
    ap.add_argument("--ood-seeds", type=int, default=None,
                    help="repetitions of every out-of-family case (default 1 quick, 2 full)")
    ap.add_argument("--no-docs", action="store_true", help="print only, do not update the docs")
    args = ap.parse_args(argv)
    seeds = args.seeds or (1 if args.quick else 3)
    specs = []
    s = 0
    for k in range(seeds):
        for n in NAMES:
            specs.append(((n,), s, args.quick))
            s += 1
        for p in (PAIRS[:4] if args.quick else PAIRS):
            specs.append((p, s, args.quick))
            s += 1
        for _ in range(4 if args.quick else 8):
            specs.append(((), s, args.quick))
            s += 1
    t0 = time.perf_counter()
    results = []
    with ProcessPoolExecutor(max_workers=args.jobs) as ex:
        for i, r in enumerate(ex.map(run_case, specs)):
            results.append(r)
            print(f"[{i + 1}/{len(specs)}] {'+'.join(r['effects']) or 'null':38s} -> "
                  f"{'+'.join(r['named']) or 'none':38s} {'ok ' if r['ok'] else 'MISS'} "
                  f"held-out/noise {r['ratio']:.2f}  {r['seconds']:.1f} s", flush=True)
    wall_total = time.perf_counter() - t0
    print("timing 45k samples ...", flush=True)
    tim = timing(1 if args.quick else 3)
    print(f"  wall {tim['wall']}, cpu {tim['cpu']}, named {tim['named']}")
    md = markdown(results, tim, wall_total + sum(tim["wall"]), args.quick, args.ood_seeds)
    print(md)
    import diagnose_outfamily as ood
    print("out-of-family cases ...", flush=True)
    ood_res = ood.run_all(args.ood_seeds or (1 if args.quick else 2), args.jobs)
    md_ood = ood.markdown(ood_res)
    print(md_ood)
    if not args.no_docs:
        from _report import update_section
        update_section("diagnose", md + "\n\n" + md_ood)
        doc = HERE.parent / "docs" / "diagnose.md"
        update_section("diagnose-suite", md, doc=doc)
        update_section("diagnose-outfamily", md_ood, doc=doc)
        example_figure(HERE.parent / "docs" / "diagnose_example.png")
    eff = [r for r in results if r["effects"]]
    null = [r for r in results if not r["effects"]]
    ok = (sum(r["ok"] for r in eff) >= 0.95 * len(eff) and sum(r["ok"] for r in null) >= 0.95 * len(null))
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
