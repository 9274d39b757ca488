"""An ISO 230-2 run of a closed-loop test axis at PSI (paulscherrerinstitute/ecmccfg,
examples/test/fat_sat/report.md; GPL-3.0: the data stay out of the repository).

    python benchmarks/real/psi_ecmc_iso230.py --src SNAPSHOT --out CORPUS

Five targets from -10 to 10.48 mm, five cycles, approached forward and backward; the reference
is an encoder read at rest.  The report's own ISO 230-2 figures: every deviation is -0.08 to
-0.14 µm (a constant offset of the reference's zero of about 0.09 µm), the reversal value B is
0.005-0.012 µm and the repeatability R 0.03-0.07 µm: nothing of the machine beyond the
encoder's resolution and a zero offset of a tenth of a micrometre.
"""
from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import (Snapshot, case_dir, cli, progress, stop_and_measure, write_csv,  # noqa: E402
                     write_truth)

SOURCE = "psi_ecmc_iso230"
URL = "https://github.com/paulscherrerinstitute/ecmccfg"
REPORT = "examples/test/fat_sat/report.md"


def direction_table(text: str, which: str) -> np.ndarray:
    """(targets, readings (i, j)) of the report's 'Data forward|backward direction' table."""
    part = text.split(f"### Data {which} direction", 1)[1]
    rows = []
    for line in part.splitlines():
        if re.match(r"^\d+\|", line):
            rows.append([float(v) for v in line.strip().strip("|").split("|")[1:]])
        elif rows and line.startswith("#"):
            break
    return np.array(rows)


def iso_sequence(fwd: np.ndarray, bwd: np.ndarray):
    """Targets and readings in the order of an ISO 230-2 run: per cycle j, the targets
    forward (ascending), then backward (descending)."""
    tg, rd = [], []
    for j in range(1, fwd.shape[1]):
        tg += list(fwd[:, 0]) + list(bwd[::-1, 0])
        rd += list(fwd[:, j]) + list(bwd[::-1, j])
    return np.array(tg), np.array(rd)


def convert(snap: Snapshot, out: Path) -> list:
    text = snap.read(REPORT)
    fwd, bwd = direction_table(text, "forward"), direction_table(text, "backward")
    targets, readings = iso_sequence(fwd, bwd)
    step = float(np.min(np.diff(np.sort(fwd[:, 0]))))
    ts, ps, tr = stop_and_measure(targets, readings, approach=step)
    case = "fat_sat_test_axis"
    progress(SOURCE, case, 1, 1)
    d = case_dir(out, SOURCE, case)
    # values in µm: the deviations are tenths of a micrometre, far below a mm's printed digits
    write_csv(d / "sim.csv", {"t[s]": ts, "x[um]": ps * 1e3}, fmt="%.6f")
    write_csv(d / "rec.csv", {"t[s]": tr, "x[um]": readings * 1e3}, fmt="%.6f")
    dev = readings - targets
    b = float(np.mean(fwd[:, 1:]) - np.mean(bwd[:, 1:]) - np.mean(fwd[:, 0]) + np.mean(bwd[:, 0]))
    write_truth(d / "truth.toml", source=SOURCE, case=case, kind="ISO 230-2, encoder reference, near-null",
                licence="GPL-3.0 (not redistributed)", url=URL, commit=snap.head(),
                authors="Anders Sandström (PSI)", files=[REPORT], expected={"x": []},
                acceptable={"x": ["workpiece_setting"]},
                evidence=("report.md ISO 230-2 figures: deviations -0.08..-0.14 µm at every target "
                          "(a zero offset of ~0.09 µm), B 0.005-0.012 µm, R 0.03-0.07 µm: nothing "
                          "of the machine beyond the encoder's resolution"),
                facts={"mean_deviation_mm": float(np.mean(dev)), "reversal_mm": b,
                       "readings": int(len(readings))})
    return [case]


if __name__ == "__main__":
    src, out = cli(SOURCE, __doc__)
    convert(Snapshot(src), out)
