"""Fleet benchmark: `mtcomp fleet diagnose` on Dask with 1 and 2 workers, memory per worker, and
the nodes a plant of 1,000 machines x 100 MB of recordings per night would need.

A. Throughput.  A generated fleet (mtcomp.fleet.generate, default 5 machines x 6 nights of 12 s
   at 50 Hz) is diagnosed (1) serially in this process with plain `diagnose` (the baseline),
   (2) by run_fleet on a local Dask cluster of 1 worker process, (3) of 2 worker processes
   (single-threaded, without the workers' statistical profiler, as the embedded cluster).  Wall time, the workers' CPU time (summed from the
   dataset's cpu_s), nights per hour, the speed-up 2 vs 1 worker, and each worker's peak RSS.
   The workers import the diagnosis before the clock starts (once per worker over a long night).
   The load average is printed beside: on a shared machine the wall times say as much about the
   neighbours as about the code.
B. Cost against recording size.  One night at several sizes (duration x rate), each diagnosed in a
   fresh process: CPU time, wall time and peak RSS against the size of SIM + REC in MB.  A
   straight line through (MB, CPU s) and (MB, RSS) is extrapolated to 100 MB per night, and the
   nodes for 1,000 machines in an 8-hour night follow (cores per node x the efficiency of A).
   An extrapolation, said so.

Usage: python benchmarks/bench_fleet.py [--machines 5] [--nights 6] [--sizes 12x50,60x200,120x500]
                                        [--write-docs]
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def _serial(fleet, src) -> dict:
    from mtcomp.diagnose import diagnose
    c0, w0 = time.process_time(), time.perf_counter()
    for n in fleet.nights:
        d = src / n.machine / n.date
        diagnose(str(d / "sim.csv"), str(d / "rec.csv"), same_clock=True)
    return {"cpu_s": time.process_time() - c0, "wall_s": time.perf_counter() - w0}


def _warm_up() -> None:
    import scipy.interpolate  # noqa: F401
    import scipy.optimize  # noqa: F401
    import scipy.signal  # noqa: F401
    import mtcomp.diagnose.engine  # noqa: F401
    import mtcomp.fleet.night  # noqa: F401


def _worker_peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _on_cluster(jobs, out, workers: int) -> dict:
    import logging
    from distributed import Client, LocalCluster
    from mtcomp.fleet.dataset import read
    from mtcomp.fleet.run import run_fleet
    import dask
    with dask.config.set({"distributed.worker.profile.enabled": False}), \
            LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                         dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR) as cluster, \
            Client(cluster) as client:
        client.run(_warm_up)   # imports once per worker, as over a long night; not timed
        load0 = os.getloadavg()[0]
        run = run_fleet(jobs, out, scheduler=cluster.scheduler_address)
        rss = client.run(_worker_peak_rss_mb)
    t = read(out)
    nights = {}
    for m, d, c in zip(*(t.column(k).to_pylist() for k in ("machine", "date", "cpu_s"))):
        nights[(m, d)] = c
    cpu = sum(nights.values())
    return {"workers": workers, "wall_s": run.wall_s, "cpu_s": cpu, "nights": run.nights,
            "nights_per_h": 3600.0 * run.nights / run.wall_s,
            "rss_mb": sorted(rss.values()), "load": load0, "errors": len(run.errors)}


def part_a(machines: int, nights: int) -> dict:
    from mtcomp.fleet.generate import FleetSpec, make_fleet, write_fleet
    from mtcomp.fleet.source import plan
    spec = FleetSpec(machines=machines, nights=nights, grow_machine=min(1, machines - 1),
                     grow_from=1, repair_machine=machines - 1, repair_night=min(2, nights - 1))
    with tempfile.TemporaryDirectory(prefix="bench-fleet-") as tmp:
        tmp = Path(tmp)
        fleet = make_fleet(spec)
        src = write_fleet(fleet, tmp / "src")
        mb = sum(f.stat().st_size for f in src.rglob("*.csv")) / 1e6
        jobs = plan(src, {"same_clock": True})
        out = {"spec": f"{machines} machines x {nights} nights, {spec.duration:g} s at "
                       f"{spec.rec_rate:g} Hz", "mb": mb}
        out["serial"] = _serial(fleet, src)
        print(f"A serial: {out['serial']}", flush=True)
        for w in (1, 2):
            r = _on_cluster(jobs, tmp / f"ds{w}", w)
            print(f"A {w} worker(s): {r}", flush=True)
            out[f"w{w}"] = r
    out["speedup"] = out["w1"]["wall_s"] / out["w2"]["wall_s"]
    return out


_ONE = r"""
import json, resource, sys, time
from mtcomp.diagnose import diagnose
# the diagnosis' lazy imports, before the clock starts (a worker pays them once, not per night)
import mtcomp.diagnose.engine, mtcomp.diagnose.report, scipy.optimize, scipy.signal, scipy.interpolate
c0, w0 = time.process_time(), time.perf_counter()
res = diagnose(sys.argv[1], sys.argv[2], same_clock=True)
print(json.dumps({"cpu_s": time.process_time() - c0, "wall_s": time.perf_counter() - w0,
                  "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
                  "samples": res.alignment["samples"], "effects": res.names}))
"""


def part_b(sizes) -> dict:
    from mtcomp.diagnose.synth import write_csv
    from mtcomp.fleet.generate import FleetSpec, make_night
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-fleet-size-") as tmp:
        for dur, rate in sizes:
            spec = FleetSpec(machines=1, nights=1, duration=dur, sim_rate=rate, rec_rate=rate)
            n = make_night(spec, 0, 0)
            sim, rec = Path(tmp) / "sim.csv", Path(tmp) / "rec.csv"
            write_csv(sim, n.sim)
            write_csv(rec, n.rec)
            mb = (sim.stat().st_size + rec.stat().st_size) / 1e6
            p = subprocess.run([sys.executable, "-c", _ONE, str(sim), str(rec)],
                               capture_output=True, text=True, check=True)
            r = json.loads(p.stdout.strip().splitlines()[-1])
            r.update(duration_s=dur, rate_hz=rate, mb=mb, load=os.getloadavg()[0])
            print(f"B {r}", flush=True)
            rows.append(r)
    return {"rows": rows}


def _line(xs, ys) -> tuple[float, float]:
    """Least-squares a + b x."""
    n = len(xs)
    mx, my = sum(xs) / n, sum(ys) / n
    sxx = sum((x - mx) ** 2 for x in xs)
    b = sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sxx if sxx else 0.0
    return my - b * mx, b


def project(a: dict, b: dict, machines=1000, mb_night=100.0, window_h=8.0) -> dict:
    xs = [r["mb"] for r in b["rows"]]
    ca, cb = _line(xs, [r["cpu_s"] for r in b["rows"]])
    ra, rb = _line(xs, [r["rss_mb"] for r in b["rows"]])
    cpu_night = ca + cb * mb_night
    cpu_h = machines * cpu_night / 3600.0
    eff = a["speedup"] / 2.0
    # nodes with every core busy for the whole window (Dask's overhead per night is ~ms; the
    # efficiency measured in A on a shared machine says more about the neighbours)
    nodes = {cores: cpu_h / (cores * window_h) for cores in (2, 32)}
    return {"cpu_s_per_night": cpu_night, "cpu_h": cpu_h, "rss_mb": ra + rb * mb_night,
            "efficiency": eff, "nodes": nodes, "fit": (ca, cb, ra, rb)}


def markdown(a: dict, b: dict, p: dict) -> str:
    from _report import machine_line
    L = ["## Fleet: nightly diagnosis on Dask (`benchmarks/bench_fleet.py`)", "",
         machine_line() + " The machine is shared with other jobs: the load average (1 min) is "
         "given beside each run; wall times and the speed-up depend on it, CPU times much less.", "",
         f"A. Throughput on a generated fleet ({a['spec']}, {a['mb']:.2f} MB of CSV), the same "
         "nights each way:", "",
         "| run | wall (s) | CPU (s) | nights/h | peak RSS per worker (MB) | load |",
         "|---|---:|---:|---:|---:|---:|",
         f"| serial `diagnose` in one process (baseline) | {a['serial']['wall_s']:.1f} | "
         f"{a['serial']['cpu_s']:.1f} | {3600 * a['w1']['nights'] / a['serial']['wall_s']:.0f} | | |"]
    for w in (1, 2):
        r = a[f"w{w}"]
        L.append(f"| `mtcomp fleet`, {w} worker(s) | {r['wall_s']:.1f} | {r['cpu_s']:.1f} (workers) | "
                 f"{r['nights_per_h']:.0f} | {', '.join(f'{x:.0f}' for x in r['rss_mb'])} | "
                 f"{r['load']:.1f} |")
    L += ["", f"Speed-up of 2 workers over 1: **{a['speedup']:.2f}x** (wall). CPU per night on the "
              f"workers {a['w2']['cpu_s'] / a['w2']['nights']:.2f} s against "
              f"{a['serial']['cpu_s'] / a['w2']['nights']:.2f} s serially (the difference is the "
              "workers' share of task handling).", "",
          "B. One night against recording size (each in a fresh process):", "",
          "| recording | samples | SIM+REC (MB) | CPU (s) | wall (s) | peak RSS (MB) | effects named | load |",
          "|---|---:|---:|---:|---:|---:|---|---:|"]
    for r in b["rows"]:
        L.append(f"| {r['duration_s']:g} s at {r['rate_hz']:g} Hz | {r['samples']} | {r['mb']:.2f} | "
                 f"{r['cpu_s']:.1f} | {r['wall_s']:.1f} | {r['rss_mb']:.0f} | {', '.join(r['effects'])} | "
                 f"{r['load']:.1f} |")
    ca, cb, ra, rb = p["fit"]
    L += ["", f"Projection (a straight line through B, extrapolated: CPU = {ca:.2f} s + {cb:.2f} s/MB, "
              f"RSS = {ra:.0f} MB + {rb:.1f} MB/MB): a night of 100 MB takes about "
              f"**{p['cpu_s_per_night'] / 60:.0f} CPU-min** and **{p['rss_mb'] / 1024:.1f} GB** per "
              f"worker; 1,000 machines about **{p['cpu_h']:.0f} CPU-hours** a night. In an 8-hour "
              f"night with every core busy: **{p['nodes'][2]:.1f} nodes of 2 cores** (this "
              f"machine) or **{p['nodes'][32]:.2f} nodes of 32 cores**, i.e. "
              f"{p['cpu_h'] / 8:.0f} cores, whose workers need {p['rss_mb'] / 1024:.1f} GB each "
              f"({32 * p['rss_mb'] / 1024:.0f} GB for 32 workers on one node: memory, not CPU, "
              "bounds the workers per node). Divide by the parallel efficiency of the cluster; "
              f"A's {100 * p['efficiency']:.0f} % was measured with the 2 cores shared with other "
              "jobs (load average beside it) and does not measure Dask's own overhead. "
              "The diagnosis' cost is not linear in the size at every size (the selection runs on "
              "a strided subset of the samples); treat the projection as the order of magnitude."]
    return "\n".join(L)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--machines", type=int, default=5)
    ap.add_argument("--nights", type=int, default=6)
    ap.add_argument("--sizes", default="12x50,60x200,120x500",
                    help="recording sizes DURATIONxRATE (s x Hz), comma-separated")
    ap.add_argument("--write-docs", action="store_true", help="update docs/benchmarks.md")
    args = ap.parse_args(argv)
    sizes = [tuple(float(v) for v in s.split("x")) for s in args.sizes.split(",")]
    a = part_a(args.machines, args.nights)
    b = part_b(sizes)
    p = project(a, b)
    md = markdown(a, b, p)
    print(md)
    if args.write_docs:
        from _report import update_section
        update_section("fleet", md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
