"""Diagnosis of the four UMich CNC runs (real command-vs-actual recordings): what it finds.

    python benchmarks/diagnose_umich.py DATA_DIR [--no-docs]

DATA_DIR holds experiment_NN.csv files of the "CNC Mill Tool Wear" data set (public
domain; University of Michigan SMART lab): the development set 01/04/06/11, or any other runs
of the set (every experiment_*.csv found is diagnosed; the docs are updated only for the
development set).  Each run is converted as in
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


def runs_in(data_dir: Path) -> tuple:
    """The run numbers of the experiment_NN.csv files in `data_dir`, in order."""
    return tuple(sorted(p.stem.split("_", 1)[1] for p in Path(data_dir).glob("experiment_*.csv")))


def run(data_dir: Path, valid_only: bool = False, runs=RUNS):
    """Diagnosis of every run, on all rows or on the rows the source's rule says are valid
    (make_excerpt.VALID_ROWS, given as `--where` conditions)."""
    from make_excerpt import VALID_ROWS, convert
    from mtcomp.diagnose import diagnose
    out = {}
    with tempfile.TemporaryDirectory() as d:
        for r in runs:
            src = data_dir / f"experiment_{r}.csv"
            convert(src, Path(d) / r)
            out[r] = diagnose(Path(d) / r / "sim.csv", Path(d) / r / "rec.csv",
                              where=VALID_ROWS if valid_only else None)
    return out


def total_ratio(res) -> float:
    """Held-out RMS after / before over the three axes together."""
    b = sum(v ** 2 for v in res.fit["holdout_rms_before"].values())
    a = sum(v ** 2 for v in res.fit["holdout_rms_after"].values())
    return (a / b) ** 0.5


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
    return "\n".join(lines)


def comparison(all_rows, valid) -> str:
    """Held-out ratios on all rows and on the valid rows, per run and axis."""
    from make_excerpt import VALID_ROWS
    lines = ["| run | samples kept (valid in both files) | held-out after / before, all rows (vx, vy, vz; together) | "
             "valid rows only (vx, vy, vz; together) |", "|---|---|---|---|"]
    for r in all_rows:
        a, v = all_rows[r], valid[r]
        rf = v.alignment["row_filter"]
        kept = f"{v.alignment['samples']} of {a.alignment['samples']}"

        def cells(res):
            f = res.fit
            per = ", ".join(f"{f['holdout_rms_after'][o] / f['holdout_rms_before'][o]:.2f}"
                            for o in res.outputs)
            return f"{per}; **{total_ratio(res):.2f}**"
        lines.append(f"| {r} | {kept} | {cells(a)} | {cells(v)} |")
    rule = " ".join(f"`--where '{c}'`" for c in VALID_ROWS)
    lines += ["", f"Valid rows: {rule}. Every row of the four runs reads program 1: the last "
              "condition removes none of them (see the text)."]
    return "\n".join(lines)


def main(argv=None) -> int:
    import argparse
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data_dir", type=Path)
    ap.add_argument("--no-docs", action="store_true")
    a = ap.parse_args(argv)
    runs = runs_in(a.data_dir) or RUNS
    results = run(a.data_dir, runs=runs)
    valid = run(a.data_dir, valid_only=True, runs=runs)
    md = ("All rows:\n\n" + markdown(results) + "\n\nValid rows only (the source's rule: rows where M1_CURRENT_FEEDRATE reads 50 or "
          "X1_ActualPosition reads 198, or with no program running, are removed):\n\n"
          + markdown(valid) + "\n\n" + comparison(results, valid))
    print(md)
    for r, res in valid.items():
        print(f"--- run {r}, valid rows\n{res.summary()}\n")
    if not a.no_docs and runs == RUNS:
        from _report import update_section
        update_section("diagnose-umich", md, doc=HERE.parent / "docs" / "diagnose.md")
        results["06"].plot(HERE.parent / "docs" / "diagnose_umich06.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
