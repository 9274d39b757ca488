"""Dial-gauge checks of a Rat Rig based antenna measurement chamber (a 3-axis gantry; Nils
Bade, NilsBade/PythonChamberApp, docs/MovementAccuracy/MovementAccuracy.md; GPL-3.0: the data
stay out of the repository, this converter rebuilds the cases).

    python benchmarks/real/nilsbade_chamber.py --src SNAPSHOT --out CORPUS

Cases, all stop-and-measure readings of a dial gauge (0.01 mm):
- z_steps: the bed stepped down in Z (10 steps of 0.01 mm, then 0.5 mm steps), three runs; the
  author: "after going down, going up follows about 0.02 mm later than meant to" (lead screw
  and decouplers): lost motion at the reversal.
- bed_along_y: the bed probed along Y (10 points over 425 mm, three runs): the readings rise
  by 0.13 mm, a tilt of the bed of 0.018 deg about X (the author's figure).
- bed_along_x: the same along X (11 points over 458 mm): no steady trend, an uneven bed
  surface (the author: "more likely ... an imperfect bed-surface than a misaligned bed-plane").
- square_run1..3: a steel square on the bed, its two edges followed along X and along Y (4
  readings each): the square's own rotation on the bed and the X-Y squareness of the gantry
  (the author: +0.125, +0.141, +0.239 deg, about +0.2 deg on average).
"""
from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import (Snapshot, case_dir, cli, progress, stop_and_measure, write_csv,  # noqa: E402
                     write_truth)

SOURCE = "nilsbade_chamber"
URL = "https://github.com/NilsBade/PythonChamberApp"
DOC = "docs/MovementAccuracy/MovementAccuracy.md"
LICENCE = "GPL-3.0 (data not redistributed here)"
AUTHORS = "Nils Bade"


def tables(text: str) -> list:
    """Markdown tables of the document as lists of rows (cells stripped), headers included."""
    out, cur = [], []
    for line in text.splitlines():
        if line.strip().startswith("|"):
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            if not all(re.fullmatch(r":?-+:?", c) for c in cells if c):
                cur.append(cells)
        elif cur:
            out.append(cur)
            cur = []
    if cur:
        out.append(cur)
    return out


def num(cell: str):
    """A cell as a number (decimal comma allowed), or None."""
    c = cell.replace(",", ".").replace("*", "").strip()
    m = re.fullmatch(r"[-+]?\d+(\.\d+)?", c)
    return float(c) if m else None


def z_steps(tab):
    """(z targets, readings) of the three runs, in the order measured, rows with text skipped."""
    runs = []
    for k in (1, 2, 3):
        zs, rs = [], []
        for row in tab[1:]:
            z = num(row[0])
            r = num(row[k]) if k < len(row) else None
            if r is None and k == 1 and "reference" in row[k]:
                r = 0.0
            if z is not None and r is not None:
                zs.append(z)
                rs.append(r)
        runs.append((np.array(zs), np.array(rs)))
    return runs


def write_case(out, case, ts, sim_cols, tr, rec_cols, truth):
    d = case_dir(out, SOURCE, case)
    write_csv(d / "sim.csv", {"t[s]": ts, **sim_cols})
    write_csv(d / "rec.csv", {"t[s]": tr, **rec_cols})
    write_truth(d / "truth.toml", source=SOURCE, licence=LICENCE, url=URL,
                authors=AUTHORS, files=[DOC], **truth)


def convert(snap: Snapshot, out: Path) -> list:
    text = snap.read(DOC)
    commit = snap.head()
    tabs = tables(text)
    done = []
    # --- Z steps: the dial reads the distance the bed went down, 7.54 - z minus what was lost
    ztab = next(t for t in tabs if t[0][0].startswith("Z-Coordinate"))
    seq_p, seq_r = [], []
    for zs, rs in z_steps(ztab):
        seq_p.append(7.54 - zs)   # travel down from the reference height, mm
        seq_r.append(rs)
    # each run starts after the bed came up to 7.54 (a reversal before the first step down);
    # the runs follow one another with a move back up in between
    ts_all, ps_all, tr_all, rr_all, t0 = [], [], [], [], 0.0
    for p, r in zip(seq_p, seq_r):
        ts, ps, tr = stop_and_measure(p, r, approach=-0.1)
        ts_all.append(ts + t0)
        ps_all.append(ps)
        tr_all.append(tr + t0)
        rr_all.append(r)
        t0 += ts[-1] + 1.0
    progress(SOURCE, "z_steps", 1, 6)
    write_case(out, "z_steps", np.concatenate(ts_all), {"z[mm]": np.concatenate(ps_all)},
               np.concatenate(tr_all), {"z[mm]": np.concatenate(rr_all)},
               dict(case="z_steps", kind="dial gauge, stepped Z, stop-and-measure", commit=commit,
                    expected={"z": ["backlash"]}, acceptable={"z": ["scale_error"]},
                    evidence=("MovementAccuracy.md: after going down, going up follows about "
                              "0.02 mm later than meant to (decouplers and lead-screw play); the "
                              "first 0.02 mm of each run do not show on the dial"),
                    facts={"reversal_mm": 0.02, "dial_resolution_mm": 0.01}))
    done.append("z_steps")
    # --- the bed along Y and along X: three runs each, z read at rest at each position
    for case, key, axis, n in (("bed_along_y", "[358;425.5;7.3]", "y", 2),
                               ("bed_along_x", "[458;80;7.35]", "x", 3)):
        tab = next(t for t in tabs if len(t) > 1 and t[1][0].startswith(key))
        pos, reads = [], []
        first = num(re.findall(r"[-\d.]+", key)[0 if axis == "x" else 1])
        for row in tab[1:]:
            p = num(row[0]) if num(row[0]) is not None else first
            vals = [num(c) if num(c) is not None else (0.0 if "reference" in c else None) for c in row[1:4]]
            pos.append(p)
            reads.append(vals)
        pos, reads = np.array(pos), np.array(reads, float)
        targets = np.concatenate([pos] * 3)
        readings = reads.T.reshape(-1)
        ts, ps, tr = stop_and_measure(targets, readings, approach=-5.0)
        other = {"x": 358.0, "y": 80.0}["y" if axis == "x" else "x"]
        progress(SOURCE, case, n, 6)
        sim = {f"{axis}[mm]": ps, ("y" if axis == "x" else "x") + "[mm]": np.full_like(ps, other),
               "z[mm]": np.zeros_like(ps)}
        rec = {"z[mm]": readings}
        if axis == "y":
            truth = dict(case=case, kind="dial gauge along an axis, stop-and-measure", commit=commit,
                         expected={"z": ["squareness"]},
                         acceptable={"z": ["workpiece_setting", "straightness"]},
                         evidence=("MovementAccuracy.md: readings rise by 0.13 mm over 425 mm of Y: "
                                   "the bed is tilted by about 0.018 deg about X against the plane the "
                                   "probe head moves in (z error proportional to y)"),
                         facts={"tilt_deg": 0.0175, "dial_resolution_mm": 0.01})
        else:
            truth = dict(case=case, kind="dial gauge along an axis, stop-and-measure", commit=commit,
                         expected={"z": ["straightness"]}, acceptable={"z": ["squareness"]},
                         evidence=("MovementAccuracy.md: no steady trend along X (-0.03..+0.05 mm), "
                                   "the deviation comes from an imperfect bed surface: a curve of z "
                                   "along x, not a tilt"),
                         facts={"dial_resolution_mm": 0.01})
        # the SIM's z is an output compared with the dial; x and y are SIM's inputs
        write_case(out, case, ts, sim, tr, rec, truth)
        done.append(case)
    # --- the square: 4 readings along X (a y distance) then 4 along Y (an x distance) per run
    runs = [t for t in tabs if t[0][0].startswith(("X-position", "Y-position"))]
    author = (0.125, 0.141, 0.239)
    for k in range(3):
        tx, ty = runs[2 * k], runs[2 * k + 1]
        px = np.array([num(r[0]) for r in tx[1:]])
        dx = np.array([num(r[2]) if num(r[2]) is not None else np.nan for r in tx[1:]])
        py = np.array([num(r[0]) for r in ty[1:]])
        dy = np.array([num(r[2]) if num(r[2]) is not None else np.nan for r in ty[1:]])
        okx, oky = np.isfinite(dx), np.isfinite(dy)
        px, dx, py, dy = px[okx], dx[okx], py[oky], dy[oky]
        # along X the slide moves in x at y = 0 and the dial reads y; along Y it moves in y at
        # x = 0 and the dial reads x.  Path: x 0..110, back to x = 0, then y 0..110
        tsx, psx, trx = stop_and_measure(px, dx, approach=-5.0)
        tsy, psy, try_ = stop_and_measure(py, dy, approach=-5.0)
        off = tsx[-1] + 1.0
        ts = np.concatenate([tsx, tsy + off])
        simx = np.concatenate([psx, np.zeros_like(psy)])
        simy = np.concatenate([np.zeros_like(psx), psy])
        tr = np.concatenate([trx, try_ + off])
        recx = np.concatenate([np.full_like(dx, np.nan), dy])     # x distance read along Y
        recy = np.concatenate([dx, np.full_like(dy, np.nan)])     # y distance read along X
        case = f"square_run{k + 1}"
        progress(SOURCE, case, 4 + k, 6)
        write_case(out, case, ts, {"x[mm]": simx, "y[mm]": simy}, tr, {"x[mm]": recx, "y[mm]": recy},
                   dict(case=case, kind="dial gauge along a square, 8 readings", commit=commit,
                        expected={"x": ["squareness", "workpiece_setting"],
                                  "y": ["squareness", "workpiece_setting"]},
                        acceptable={"x": ["squareness", "workpiece_setting"],
                                    "y": ["squareness", "workpiece_setting"]},
                        evidence=(f"MovementAccuracy.md run {k + 1}: the square's two edges followed "
                                  f"along X and Y; the author finds an X-Y angle of 90 deg + "
                                  f"{author[k]} deg (mean +0.168 deg, sd 0.057 deg) besides the "
                                  f"square's rotation on the bed; only 8 readings of 0.01 mm"),
                        facts={"squareness_deg": author[k], "dial_resolution_mm": 0.01}))
        done.append(case)
    # --- the laser distance sensor (1 mm resolution) under the bed at 14 heights, five runs:
    # the author: the error is below the sensor's precision, the readings only toggle by 1 mm
    tab = next(t for t in tabs if t[0][0].startswith("Target Z"))
    zs, reads = [], []
    for row in tab[1:]:
        z = num(row[0])
        vals = [num(c) for c in row[1:6]]
        if z is None or any(v is None for v in vals):
            continue
        zs.append(z)
        reads.append(vals)
    zs, reads = np.array(zs), np.array(reads) * 1e3        # m -> mm
    # the sensor reads the distance to the floor: the bed's travel is the first reading minus
    # the reading, the first reading of each run taken as its zero (as the author reads it)
    travel = reads[0:1, :] - reads
    targets = np.concatenate([zs] * reads.shape[1])
    readings = travel.T.reshape(-1)
    ts, ps, tr = stop_and_measure(targets, readings, approach=-5.0)
    progress(SOURCE, "z_laser", 7, 7)
    write_case(out, "z_laser", ts, {"z[mm]": ps}, tr, {"z[mm]": readings},
               dict(case="z_laser", kind="laser distance sensor, stop-and-measure, nothing expected", commit=commit,
                    expected={"z": []}, acceptable={"z": []},
                    evidence=("MovementAccuracy.md: 'the error that should be measured is below the "
                              "precision of the laser sensor since over all repetitions the measured "
                              "value just toggles 1 mm' (STABILA LD520, +-1 mm)"),
                    facts={"sensor_resolution_mm": 1.0, "targets": len(zs)}))
    done.append("z_laser")
    return done


if __name__ == "__main__":
    src, out = cli(SOURCE, __doc__)
    convert(Snapshot(src), out)
