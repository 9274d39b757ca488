"""Diagnosis of the four UMich CNC runs (real command-vs-actual recordings): what it finds.

    python benchmarks/diagnose_umich.py DATA_DIR [--no-docs]

DATA_DIR holds experiment_01/04/06/11.csv of the "CNC Mill Tool Wear" data set (public
domain; University of Michigan SMART lab).  Each run is converted as in
tests/data/umich/make_excerpt.py (SIM = commanded velocity, acceleration and position;
REC = measured velocity, outputs vx, vy, vz in mm/s at 10 Hz) and diagnosed.  Writes the
table and the figure of run 06 into docs/diagnose.md (section `diagnose-umich`).
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "tests" / "data" / "umich"))

RUNS = ("01", "04", "06", "11")


def run(data_dir: Path):
    from make_excerpt import convert
    from mtcomp.diagnose import diagnose
    out = {}
    with tempfile.TemporaryDirectory() as d:
        for r in RUNS:
            src = data_dir / f"experiment_{r}.csv"
            convert(src, Path(d) / r)
            out[r] = diagnose(Path(d) / r / "sim.csv", Path(d) / r / "rec.csv")
    return out


def markdown(results) -> str:
    lines = ["| run | samples | output | noise floor | held-out RMS before | held-out RMS after | "
             "after / before | servo lag tau (1/kv) | other effects | unexplained (x noise) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r, res in results.items():
        for o in res.outputs:
            lag = [e for e in res.effects if e.name == "servo_lag" and o in e.outputs]
            other = [e.name for e in res.effects if e.name != "servo_lag" and o in e.outputs]
            lat = res.alignment["clock_offset_s"]
            if lat:
                # a delay common to all lagging axes is reported as latency in the alignment
                other.append(f"latency {lat * 1e3:.2f} ± {res.alignment['clock_offset_uncertainty_s'] * 1e3:.2f} ms")
            un = [u for u in res.unexplained if u["output"] == o]
            f = res.fit
            lines.append(
                f"| {r} | {res.alignment['samples']} | {o} | {res.noise_floor[o]:.3g} mm/s | "
                f"{f['holdout_rms_before'][o]:.3f} mm/s | {f['holdout_rms_after'][o]:.3f} mm/s | "
                f"{f['holdout_rms_after'][o] / f['holdout_rms_before'][o]:.2f} | "
                + (f"{lag[0].params['tau_s'] * 1e3:.2f} ± {lag[0].uncertainty['tau_s'] * 1e3:.2f} ms"
                   if lag else "not named")
                + f" | {', '.join(other) or '-'} | "
                + (f"{un[0]['ratio']:.1f}" if un else "-") + " |")
    tot = []
    for r, res in results.items():
        b = sum(v ** 2 for v in res.fit["holdout_rms_before"].values())
        a = sum(v ** 2 for v in res.fit["holdout_rms_after"].values())
        tot.append(f"{r}: {(a / b) ** 0.5:.2f}")
    lines += ["", "Held-out RMS after / before over the three axes together: " + ", ".join(tot) + "."]
    return "\n".join(lines)


def main(argv=None) -> int:
    import argparse
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data_dir", type=Path)
    ap.add_argument("--no-docs", action="store_true")
    a = ap.parse_args(argv)
    results = run(a.data_dir)
    md = markdown(results)
    print(md)
    for r, res in results.items():
        print(f"--- run {r}\n{res.summary()}\n")
    if not a.no_docs:
        from _report import update_section
        update_section("diagnose-umich", md, doc=HERE.parent / "docs" / "diagnose.md")
        results["06"].plot(HERE.parent / "docs" / "diagnose_umich06.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
