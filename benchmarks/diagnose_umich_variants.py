"""Diagnosis of recordings cut from the UMich CNC runs the way unseen logs differ: short
sub-ranges (150 and 300 samples), decimated clocks (5 and 3.3 Hz), one axis only, a stretch with
Z idle, positions (3 significant figures) and accelerations as outputs, the spindle.

    python benchmarks/diagnose_umich_variants.py DATA_DIR [--no-docs]

DATA_DIR holds experiment_NN.csv files of the "CNC Mill Tool Wear" data set (public domain;
University of Michigan SMART lab); every one found is cut.  Each case is judged on what holds
for any recording, not on a known answer: no error, never "explained by noise" (nor silence)
with a residual above 3x the noise floor, every named lag with a time constant of 1 ms..0.5 s,
and no named effect that makes an output's held-out error worse.  Writes the table into
docs/diagnose.md (section `diagnose-umich-variants`) when DATA_DIR holds the development set.
"""
from __future__ import annotations

import csv
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

V = {a: (f"v{a.lower()}[mm/s]", f"{a}1_CommandVelocity") for a in "XYZ"}
A = {a: (f"a{a.lower()}[mm/s^2]", f"{a}1_CommandAcceleration") for a in "XYZ"}
P = {a: (f"{a.lower()}[mm]", f"{a}1_CommandPosition") for a in "XYZ"}
RV = {a: (f"v{a.lower()}[mm/s]", f"{a}1_ActualVelocity") for a in "XYZ"}
RA = {a: (f"a{a.lower()}[mm/s^2]", f"{a}1_ActualAcceleration") for a in "XYZ"}
RP = {a: (f"{a.lower()}[mm]", f"{a}1_ActualPosition") for a in "XYZ"}
VEL = ([V[a] for a in "XYZ"] + [A[a] for a in "XYZ"] + [P[a] for a in "XYZ"], [RV[a] for a in "XYZ"])


def cases(head, body):
    """(name, sim columns, rec columns, rows, step) of every variant of one run."""
    n = len(body)
    out = [("all rows", *VEL, (0, n), 1)]
    for a in (0, n // 3, (2 * n) // 3):
        if a + 150 <= n:
            out.append((f"rows {a}-{a + 150}", *VEL, (a, a + 150), 1))
    for a in (0, n // 2):
        if a + 300 <= n:
            out.append((f"rows {a}-{a + 300}", *VEL, (a, a + 300), 1))
    out += [("every 2nd row", *VEL, (0, n), 2), ("every 3rd row", *VEL, (0, n), 3)]
    # a stretch of 200 rows in which Z is commanded to rest throughout
    iz = head.index("Z1_CommandVelocity")
    for a in range(0, n - 200, 50):
        if all(float(r[iz]) == 0.0 for r in body[a:a + 200]):
            out.append((f"Z idle, rows {a}-{a + 200}", *VEL, (a, a + 200), 1))
            break
    # the source's own column names, no units: kinds and the command/actual pairing come from
    # the names (reported in the notes)
    raw = [(c, c) for a in "XYZ" for c in (f"{a}1_CommandVelocity", f"{a}1_CommandAcceleration",
                                            f"{a}1_CommandPosition")]
    out.append(("source's names, no units", raw, [(f"{a}1_ActualVelocity",) * 2 for a in "XYZ"],
                (0, n), 1))
    out += [("X only", [V["X"], A["X"], P["X"]], [RV["X"]], (0, n), 1),
            ("positions", [P[a] for a in "XYZ"] + [V[a] for a in "XYZ"] + [A[a] for a in "XYZ"],
             [RP[a] for a in "XYZ"], (0, n), 1),
            ("accelerations", [A["X"], A["Y"], V["X"], V["Y"]], [RA["X"], RA["Y"]], (0, n), 1),
            ("spindle (no unit)", [("S1_Velocity", "S1_CommandVelocity"),
                                   ("S1_Acceleration", "S1_CommandAcceleration")],
             [("S1_Velocity", "S1_ActualVelocity")], (0, n), 1)]
    return out


def write(path, head, cols, body, dt):
    idx = [head.index(c) for _, c in cols]
    lines = ["t[s]," + ",".join(h for h, _ in cols)]
    lines += [f"{dt * i:.4g}," + ",".join(r[j] for j in idx) for i, r in enumerate(body)]
    path.write_text("\n".join(lines) + "\n")


def judge(res):
    """What is wrong with a result, for any recording (empty: nothing)."""
    bad = []
    text = res.summary()
    for o in res.outputs:
        ratio = res.fit["holdout_rms_after"][o] / max(res.noise_floor[o], 1e-300)
        named = [e for e in res.effects if o in e.outputs]
        if ratio > 3 and not named and not any(u["output"] == o for u in res.unexplained):
            bad.append(f"{o} silent at {ratio:.0f}x noise")
        b = res.fit["holdout_rms_before"][o]
        if named and b > 0 and res.fit["holdout_rms_after"][o] > 1.02 * b:
            bad.append(f"{o} held out worse ({res.fit['holdout_rms_after'][o] / b:.2f})")
    if "explained by noise" in text and res.unexplained:
        bad.append("'explained by noise'")
    for e in res.effects:
        tau = e.params.get("tau_s", 1.0 / e.params["kv_per_s"] if "kv_per_s" in e.params else None)
        if e.name == "servo_lag" and tau is not None and not 1e-3 <= tau <= 0.5:
            bad.append(f"servo_lag tau {tau:.3g} s on {','.join(e.outputs)}")
    return bad


def run(data_dir: Path):
    from mtcomp.diagnose import diagnose
    rows_out = []
    for src in sorted(Path(data_dir).glob("experiment_*.csv")):
        r = src.stem.split("_", 1)[1]
        with open(src, newline="") as f:
            table = list(csv.reader(f))
        head, body = table[0], table[1:]
        for name, sc, rc, (a, b), step in cases(head, body):
            part = body[a:b:step]
            with tempfile.TemporaryDirectory() as d:
                write(Path(d) / "sim.csv", head, sc, part, 0.1 * step)
                write(Path(d) / "rec.csv", head, rc, part, 0.1 * step)
                t0 = time.perf_counter()
                try:
                    res = diagnose(Path(d) / "sim.csv", Path(d) / "rec.csv")
                except Exception as e:  # noqa: BLE001 - any error is a finding here
                    rows_out.append((r, name, len(part), f"error: {type(e).__name__}: {e}", "", "", ["error"]))
                    continue
                dt = time.perf_counter() - t0
            eff = []
            for e in res.effects:
                p = (f" {e.params['tau_s'] * 1e3:.1f} ms" if "tau_s" in e.params
                     else f" {e.params['offset_s'] * 1e3:.1f} ms" if "offset_s" in e.params else "")
                eff.append(f"{e.name} ({', '.join(e.outputs)}{p})")
            lat = res.alignment.get("clock_offset_s") or 0.0
            if lat:
                eff.append(f"latency {lat * 1e3:.1f} ms")
            ho = ", ".join(f"{o} {res.fit['holdout_rms_after'][o] / res.fit['holdout_rms_before'][o]:.2f}"
                           if res.fit["holdout_rms_before"][o] else f"{o} -" for o in res.outputs)
            un = ", ".join(f"{u['output']} {u['ratio']:.0f}x" for u in res.unexplained)
            rows_out.append((r, name, len(part), "; ".join(eff) or "none", ho, un or "-", judge(res)))
            print(f"{r} {name:24s} {dt:5.1f} s  {rows_out[-1][3]} | {ho} | {un} {rows_out[-1][6] or ''}",
                  flush=True)
    return rows_out


def markdown(rows_out, seconds) -> str:
    bad = [x for x in rows_out if x[6]]
    lines = [f"Variants of the UMich runs (`benchmarks/diagnose_umich_variants.py`): {len(rows_out)} "
             f"cases, {len(rows_out) - len(bad)} without a finding; {seconds:.0f} s in all.", "",
             "| run | variant | samples | named (time constant / delay) | held out after / before | "
             "unexplained (x noise) | finding |", "|---|---|---|---|---|---|---|"]
    for r, name, n, eff, ho, un, b in rows_out:
        lines.append(f"| {r} | {name} | {n} | {eff} | {ho} | {un} | {'; '.join(b) or '-'} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    import argparse
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data_dir", type=Path)
    ap.add_argument("--no-docs", action="store_true")
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    rows_out = run(a.data_dir)
    md = markdown(rows_out, time.perf_counter() - t0)
    print(md)
    dev = {p.name for p in a.data_dir.glob("experiment_*.csv")}
    if not a.no_docs and dev == {f"experiment_{r}.csv" for r in ("01", "04", "06", "11")}:
        from _report import update_section
        update_section("diagnose-umich-variants", md, doc=HERE.parent / "docs" / "diagnose.md")
    return 1 if any(x[6] for x in rows_out) else 0


if __name__ == "__main__":
    raise SystemExit(main())
