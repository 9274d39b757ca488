"""The four UMich CNC runs as recordings of one machine: leave-one-recording-out.

    python benchmarks/diagnose_umich_loro.py DATA_DIR

Each run is converted as in tests/data/umich/make_excerpt.py (SIM = commanded velocity,
acceleration and position; REC = measured velocity vx, vy, vz, mm/s at 10 Hz) and the runs are
diagnosed together (`mtcomp diagnose --sim 01/sim.csv --rec 01/rec.csv --sim 04/sim.csv ...`):
one set of effects for the machine, each run predicted by the model fitted on the others.
Prints per run the held-out RMS after / before over the three axes together, and the effects.
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / ".." / "tests" / "data" / "umich"))

RUNS = ("01", "04", "06", "11")


def run(data_dir: Path, runs=RUNS):
    from make_excerpt import convert
    from mtcomp.diagnose import diagnose
    with tempfile.TemporaryDirectory() as d:
        for r in runs:
            convert(Path(data_dir) / f"experiment_{r}.csv", Path(d) / r)
        return diagnose([Path(d) / r / "sim.csv" for r in runs],
                        [Path(d) / r / "rec.csv" for r in runs])


def markdown(res) -> str:
    lines = ["| run (held out) | held-out RMS before (vx, vy, vz) | after | after / before |",
             "|---|---|---|---|"]
    for name, d in res.fit["recordings"].items():
        b = ", ".join(f"{v:.3f}" for v in d["holdout_rms_before"].values())
        a = ", ".join(f"{v:.3f}" for v in d["holdout_rms_after"].values())
        lines.append(f"| {name} | {b} mm/s | {a} mm/s | **{d['ratio']:.2f}** |")
    eff = "; ".join(f"{e.name}[{e.output}] " + ", ".join(f"{k} {v:.4g}" for k, v in e.params.items())
                    for e in res.effects)
    return "\n".join(lines) + f"\n\nEffects (one set for the four runs): {eff or 'none'}"


def main(argv=None) -> int:
    data = Path((argv or sys.argv[1:])[0])
    c0, w0 = time.process_time(), time.perf_counter()
    res = run(data)
    print(markdown(res))
    print(f"\n{time.process_time() - c0:.1f} s CPU, {time.perf_counter() - w0:.1f} s wall")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
