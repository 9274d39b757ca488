"""CMM measurements of drilled SDSS plug plates (Sloan Digital Sky Survey; measured on the
University of Washington shop's CMM; csayres/fitPlugPlateMeas, files under examples/ and
tests/testData/; no licence file: the data stay out of the repository).

    python benchmarks/real/sdss_plugplate_cmm.py --src SNAPSHOT --out CORPUS

Each file lists, for every hole of an aluminium plate about 0.8 m across, the measured and
nominal x, y (mm).  SIM visits the nominal positions one after another and rests at each
(stop-and-measure), REC is the CMM's measured centre.  The plate lies on the CMM table at some
offset and angle: the source's own software fits a translation, a rotation and a scale (and a
quadrupole: x against y scale and shear) and reports offsets of 0.05-0.2 mm and angles of a
few hundredths of a degree, with residuals of about 8 µm.  The defensible effect is the
setting of the workpiece (translation and rotation); a scale or squareness term of the
drilling machine may come on top.
"""
from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import (Snapshot, case_dir, cli, progress, stop_and_measure, write_csv,  # noqa: E402
                     write_truth)

SOURCE = "sdss_plugplate_cmm"
URL = "https://github.com/csayres/fitPlugPlateMeas"
LICENCE = "none stated (not redistributed)"
FOLDERS = ("examples/", "tests/testData/D")


def parse(text: str):
    """(meas (n,2), nom (n,2)) of a CMM file; the header names the columns."""
    rows = []
    for line in text.splitlines():
        p = line.split()
        if len(p) >= 4:
            try:
                rows.append([float(v) for v in p[:4]])
            except ValueError:
                continue
    a = np.array(rows)
    return a[:, 0:2], a[:, 2:4]


def transrot(meas, nom):
    """Least-squares translation (mm), rotation (deg) and scale of nominal onto measured."""
    A = np.zeros((2 * len(nom), 4))
    A[0::2, 0], A[1::2, 1] = 1, 1
    A[0::2, 2], A[0::2, 3] = nom[:, 0], -nom[:, 1]
    A[1::2, 2], A[1::2, 3] = nom[:, 1], nom[:, 0]
    c = np.linalg.lstsq(A, meas.reshape(-1), rcond=None)[0]
    resid = meas.reshape(-1) - A @ c
    return c[:2], np.degrees(np.arctan2(c[3], c[2])), float(np.hypot(c[2], c[3])), float(np.sqrt(np.mean(resid ** 2)))


def convert(snap: Snapshot, out: Path) -> list:
    commit = snap.head()
    files = [f for f in snap.files() if f.startswith(FOLDERS) and "/fit_" not in f]
    seen, done = set(), []
    for i, f in enumerate(sorted(files), 1):
        text = snap.read(f)
        h = hashlib.sha1(text.encode()).hexdigest()
        if h in seen or "Meas X" not in text:
            continue
        seen.add(h)
        meas, nom = parse(text)
        case = Path(f).name
        progress(SOURCE, case, i, len(files))
        # visit the holes in the file's order (the CMM program's), 10 mm approach in +x +y
        ts, ps, tr = stop_and_measure(nom, meas, approach=[10.0, 10.0], move_s=1.0, dwell_s=1.0, rate_hz=10.0)
        d = case_dir(out, SOURCE, case)
        write_csv(d / "sim.csv", {"t[s]": ts, "x[mm]": ps[:, 0], "y[mm]": ps[:, 1]})
        write_csv(d / "rec.csv", {"t[s]": tr, "x[mm]": meas[:, 0], "y[mm]": meas[:, 1]})
        off, rot, scale, rms = transrot(meas, nom)
        write_truth(d / "truth.toml", source=SOURCE, case=case, kind="CMM, drilled plate, measured vs nominal holes",
                    licence=LICENCE, url=URL, commit=commit, authors="SDSS / University of Washington (R. Owen, C. Sayres)",
                    files=[f], expected={"x": ["workpiece_setting"], "y": ["workpiece_setting"]},
                    acceptable={"x": ["scale_error", "squareness"], "y": ["scale_error", "squareness"]},
                    evidence=(f"the source's fit (translation, rotation, scale, quadrupole): here "
                              f"offset ({off[0]:.3f}, {off[1]:.3f}) mm, rotation {rot:.4f} deg, scale "
                              f"{(scale - 1) * 1e6:.1f} ppm, residual {rms * 1e3:.1f} µm RMS per coordinate "
                              f"over {len(nom)} holes: the plate's setting on the CMM"),
                    facts={"holes": len(nom), "offset_x_mm": round(float(off[0]), 4),
                           "offset_y_mm": round(float(off[1]), 4), "rotation_deg": round(float(rot), 5),
                           "scale_ppm": round((scale - 1) * 1e6, 2), "resid_rms_mm": round(rms, 5)})
        done.append(case)
    return done


if __name__ == "__main__":
    src, out = cli(SOURCE, __doc__)
    convert(Snapshot(src), out)
