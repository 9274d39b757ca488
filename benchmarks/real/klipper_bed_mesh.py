"""Bed meshes of 3D printers from their Klipper configuration repositories (printer.cfg's
SAVE_CONFIG block `[bed_mesh default]`): every distinct mesh in the history of a printer's
configuration (the newest four) becomes one case.  One converter for the six printer sources of
the manifest:

    python benchmarks/real/klipper_bed_mesh.py --source NAME --src SNAPSHOT --out CORPUS

(NAME: a key of SOURCES below; the snapshot is that source's repository.)  Only grumat's
repository states a licence (MIT: a short excerpt is committed under
tests/data/real/grumat_bed_mesh/); the data of the others stay out of the repository.

A mesh is what the printer's Z probe read at rest on a grid of the bed: the probe visits the
grid row by row (x alternating direction, y stepping), stops, and reads the height of the bed
against the plane the nozzle moves in.  SIM is that visit with z = 0 (a flat bed in the
gantry's plane), REC the reading at each stop.  The cause of the mismatch is the bed itself: a
tilt (z proportional to x or y: `squareness` of z to that axis, as in the corpus's gantry
cases) and a form (a bow or twist: `straightness` of z along x or y), with the probe's own
trigger offset as a constant (`workpiece_setting`).

The expected set of a mesh follows from the mesh's own figures, by a rule fixed before any
diagnosis ran on it: a tilt across the probed span above 0.05 mm is expected (between 0.02
and 0.05 mm it is acceptable), a form above 0.05 mm peak to valley about the best plane is
expected (between 0.02 and 0.05 mm acceptable); 0.02 mm is about four times the repeatability
that makers give for such probes (about 0.005 mm standard deviation).
"""
from __future__ import annotations

import argparse
import hashlib
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import (Snapshot, case_dir, progress, stop_and_measure, write_csv,  # noqa: E402
                     write_truth)

EXPECT_MM, ACCEPT_MM = 0.05, 0.02


def parse_mesh(text: str):
    """(points (ny, nx) in mm, min_x, max_x, min_y, max_y) of `[bed_mesh default]`, or None."""
    m = re.search(r"#\*# \[bed_mesh default\](.*?)(?=#\*# \[|\Z)", text, re.S)
    if not m:
        return None
    block = m.group(1)
    rows, keys = [], {}
    in_points = False
    for line in block.splitlines():
        s = line.replace("#*#", "", 1).strip()
        if s.startswith("points"):
            in_points = True
            continue
        if in_points and re.match(r"^[-+0-9.]", s):
            rows.append([float(v) for v in s.split(",") if v.strip()])
            continue
        in_points = False
        kv = re.match(r"^(\w+)\s*=\s*([-+0-9.eE]+)$", s)
        if kv:
            keys[kv.group(1)] = float(kv.group(2))
    if not rows or any(len(r) != len(rows[0]) for r in rows):
        return None
    need = ("min_x", "max_x", "min_y", "max_y")
    if any(k not in keys for k in need):
        return None
    return (np.array(rows),) + tuple(keys[k] for k in need)


def history(git_dir, rel: str) -> list:
    """(commit, date, text) of every version of `rel`, newest first."""
    out = subprocess.run(["git", f"--git-dir={git_dir}", "log", "--format=%H %cs", "--", rel],
                         check=True, capture_output=True, text=True).stdout.split("\n")
    res = []
    for line in out:
        if not line.strip():
            continue
        c, d = line.split()
        txt = subprocess.run(["git", f"--git-dir={git_dir}", "show", f"{c}:{rel}"],
                             capture_output=True).stdout.decode("utf-8", "replace")
        res.append((c, d, txt))
    return res


def backups(git_dir) -> list:
    """(tag, date, text) of Klipper's own backups at HEAD (printer-YYYYMMDD_HHMMSS.cfg, written
    by SAVE_CONFIG before it rewrites printer.cfg), newest first."""
    names = subprocess.run(["git", f"--git-dir={git_dir}", "ls-tree", "-r", "--name-only", "HEAD"],
                           check=True, capture_output=True, text=True).stdout.split("\n")
    res = []
    for n in names:
        m = re.search(r"printer-(\d{4})(\d{2})(\d{2})_(\d{6})\.cfg$", n)
        if not m:
            continue
        txt = subprocess.run(["git", f"--git-dir={git_dir}", "show", f"HEAD:{n}"],
                             capture_output=True).stdout.decode("utf-8", "replace")
        res.append((f"{m.group(1)}{m.group(2)}{m.group(3)}_{m.group(4)}",
                    f"{m.group(1)}-{m.group(2)}-{m.group(3)}", txt, n))
    return [r[:3] for r in sorted(res, reverse=True)], {r[0]: r[3] for r in res}


def distinct_meshes(versions, limit: int) -> list:
    """(commit, date, mesh) of the newest `limit` distinct meshes, newest first."""
    seen, out = set(), []
    for c, d, txt in versions:
        mesh = parse_mesh(txt)
        if mesh is None:
            continue
        key = hashlib.sha1(np.round(mesh[0], 6).tobytes()).hexdigest()
        if key in seen:
            continue
        seen.add(key)
        out.append((c, d, mesh))
        if len(out) >= limit:
            break
    return out


def probe_path(points, min_x, max_x, min_y, max_y):
    """Targets (n, 2) in the order Klipper probes them (rows along x, alternating) and the
    readings (n,)."""
    ny, nx = points.shape
    xs, ys = np.linspace(min_x, max_x, nx), np.linspace(min_y, max_y, ny)
    tg, rd = [], []
    for j in range(ny):
        order = range(nx) if j % 2 == 0 else range(nx - 1, -1, -1)
        for i in order:
            tg.append((xs[i], ys[j]))
            rd.append(points[j, i])
    return np.array(tg), np.array(rd)


def mesh_figures(points, min_x, max_x, min_y, max_y) -> dict:
    """Tilt across the span along x and y and the form about the best plane (mm)."""
    ny, nx = points.shape
    X, Y = np.meshgrid(np.linspace(min_x, max_x, nx), np.linspace(min_y, max_y, ny))
    A = np.column_stack([np.ones(X.size), X.ravel(), Y.ravel()])
    coef, *_ = np.linalg.lstsq(A, points.ravel(), rcond=None)
    form = points.ravel() - A @ coef
    return {"tilt_x_mm": float(coef[1] * (max_x - min_x)), "tilt_y_mm": float(coef[2] * (max_y - min_y)),
            "form_ptv_mm": float(np.ptp(form)), "mean_mm": float(points.mean()),
            "points": int(points.size)}


def expected_sets(fig: dict):
    """Expected and acceptable effect names of z by the rule in the module docstring."""
    exp, acc = set(), {"workpiece_setting"}
    tilt = max(abs(fig["tilt_x_mm"]), abs(fig["tilt_y_mm"]))
    if tilt > EXPECT_MM:
        exp.add("squareness")
    elif tilt > ACCEPT_MM:
        acc.add("squareness")
    if fig["form_ptv_mm"] > EXPECT_MM:
        exp.add("straightness")
    elif fig["form_ptv_mm"] > ACCEPT_MM:
        acc.add("straightness")
    # a tilt is also the first term of a straightness profile, a form of one line may read
    # as a tilt of another: where one is expected, the other is not wrong
    if exp:
        acc |= {"squareness", "straightness"} - exp
    return sorted(exp), sorted(acc - exp)


def convert_repo(source: str, snap, out, *, rel: str, url: str, authors: str, licence: str,
                 printer: str, limit: int = 4, use_backups: bool = False) -> list:
    """Write one case per distinct mesh (newest `limit`) of `rel` in the snapshot's history and,
    with `use_backups`, of Klipper's backup files at HEAD."""
    if not snap.git:   # a checked-out folder: its one version of the file
        found = [(snap.head(), "undated", snap.read(rel))]
    else:
        found = history(snap.path, rel)
    files = {}
    if use_backups and snap.git:
        bk, files = backups(snap.path)
        found = bk + found
    meshes = distinct_meshes(found, limit)
    head = snap.head()
    names = []
    for k, (commit, date, mesh) in enumerate(meshes, 1):
        points, x0, x1, y0, y1 = mesh
        # a backup file is named by its time stamp and read at HEAD; a version of printer.cfg
        # by its commit
        case = f"mesh_{commit}" if commit in files else f"mesh_{date}_{commit[:7]}"
        src_file, src_commit = (files[commit], head) if commit in files else (rel, commit)
        progress(source, case, k, len(meshes))
        tg, rd = probe_path(points, x0, x1, y0, y1)
        step = (x1 - x0) / max(points.shape[1] - 1, 1)
        ts, ps, tr = stop_and_measure(tg, rd, approach=[step, 0.0])
        d = case_dir(out, source, case)
        write_csv(d / "sim.csv", {"t[s]": ts, "x[mm]": ps[:, 0], "y[mm]": ps[:, 1],
                                  "z[mm]": np.zeros(len(ts))}, fmt="%.6f")
        write_csv(d / "rec.csv", {"t[s]": tr, "z[mm]": rd}, fmt="%.6f")
        fig = mesh_figures(points, x0, x1, y0, y1)
        exp, acc = expected_sets(fig)
        write_truth(d / "truth.toml", source=source, case=case, kind="Z-probe bed mesh, stop-and-measure",
                    licence=licence, url=url, commit=src_commit, authors=authors, files=[src_file],
                    expected={"z": exp}, acceptable={"z": acc},
                    evidence=(f"{printer}: Klipper's saved bed mesh of {date}, {points.shape[1]}x"
                              f"{points.shape[0]} probe readings over x {x0:g}-{x1:g} mm, y {y0:g}-"
                              f"{y1:g} mm: tilt {fig['tilt_x_mm']:+.3f} mm along x, "
                              f"{fig['tilt_y_mm']:+.3f} mm along y, form {fig['form_ptv_mm']:.3f} mm "
                              "peak to valley about the best plane; the bed's shape against the "
                              "gantry's plane (expected set by the rule of the converter)"),
                    facts=fig)
        names.append(case)
    return names


NONE = "none stated (not redistributed)"
# source -> the repository, its file, who wrote it, the licence and the printer
SOURCES = {
    "klipper_voron24_mesh": dict(
        repo="0x3333/klipper_voron2.4", authors="Tercio Gaudencio Filho (0x3333)", licence=NONE,
        printer="a Voron 2.4 (inductive probe, bed trammed by quad gantry levelling)"),
    "klipper_k1c_mesh": dict(
        repo="2wenty2wo/k1c-klipper-backup2", authors="2wenty2wo", licence=NONE,
        printer="a Creality K1C (strain-gauge nozzle probe, prtouch_v2)"),
    "klipper_neptune4_mesh": dict(
        repo="AlexWH10/Klipper_Backup_Neptune_4", authors="AlexWH10", licence=NONE,
        printer="an Elegoo Neptune 4 (inductive probe, 11x11 grid)", use_backups=True),
    "klipper_creality_mesh": dict(
        repo="AlexBinkovskyy/CrealityBackUps", authors="AlexBinkovskyy", licence=NONE,
        printer="a Creality printer (nozzle strain-gauge probe, 5x5 or 6x6 grid)", use_backups=True),
    "klipper_v2465_mesh": dict(
        repo="Alexander-T-Moss/V2.2465-AutoBackup", authors="Alexander T. Moss", licence=NONE,
        printer="a Voron 2.4 (serial V2.2465; 9x9 grid)", use_backups=True),
    "grumat_bed_mesh": dict(
        repo="grumat/voron-trident-250_config", authors="grumat", licence="MIT",
        printer="grumat's Voron Trident 250 (inductive probe, 5x5 grid)", rel="backup/printer.cfg"),
}


def convert(source: str, snap: Snapshot, out) -> list:
    """The cases of one source of SOURCES from its snapshot."""
    m = SOURCES[source]
    return convert_repo(source, snap, out, rel=m.get("rel", "printer.cfg"),
                        url=f"https://github.com/{m['repo']}", authors=m["authors"],
                        licence=m["licence"], printer=m["printer"],
                        use_backups=m.get("use_backups", False))


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description="Klipper bed meshes -> real-corpus cases")
    p.add_argument("--source", required=True, choices=sorted(SOURCES))
    p.add_argument("--src", help="the source's snapshot (or MTCOMP_REAL_SRC_<SOURCE>)")
    p.add_argument("--out", default=os.environ.get("MTCOMP_REAL_CORPUS"),
                   help="corpus folder (or MTCOMP_REAL_CORPUS)")
    a = p.parse_args(argv)
    src = a.src or os.environ.get(f"MTCOMP_REAL_SRC_{a.source.upper()}")
    if not src or not a.out:
        p.error("give --src and --out")
    convert(a.source, Snapshot(Path(src)), Path(a.out))


if __name__ == "__main__":
    main()
