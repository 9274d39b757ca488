"""Shared steps of the real-corpus converters: where a case goes, how SIM/REC and the truth
file are written.

A case is a folder <corpus>/<source>/<case>/ with
- sim.csv, rec.csv: the files `mtcomp diagnose` reads (units in the headers);
- truth.toml: the expected effect set per output, the evidence for it, the source, its licence
  and the extra command-line arguments the case needs (e.g. `--same-clock` for one log).

The corpus folder is given with `--out DIR` or the environment variable MTCOMP_REAL_CORPUS; the
fetched snapshot of the source with `--src DIR` or MTCOMP_REAL_SRC_<SOURCE> (upper case).
"""
from __future__ import annotations

import argparse
import os
import subprocess
from pathlib import Path

import numpy as np


def cli(source: str, doc: str):
    """Parsed `--src` and `--out` of a converter (falling back to environment variables)."""
    p = argparse.ArgumentParser(description=doc.strip().splitlines()[0])
    p.add_argument("--src", default=os.environ.get(f"MTCOMP_REAL_SRC_{source.upper()}"),
                   help="the source's snapshot: a git directory or a checked-out folder")
    p.add_argument("--out", default=os.environ.get("MTCOMP_REAL_CORPUS"),
                   help="corpus folder; the cases go to OUT/<source>/<case>/")
    a = p.parse_args()
    if not a.src or not a.out:
        p.error(f"give --src (or MTCOMP_REAL_SRC_{source.upper()}) and --out (or MTCOMP_REAL_CORPUS)")
    return Path(a.src), Path(a.out)


class Snapshot:
    """Read files of a source snapshot: a bare git directory (read at HEAD, or at a given
    commit for files a later commit removed) or a plain folder."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.git = (self.path / "HEAD").exists() and (self.path / "objects").exists()
        if not self.git and (self.path / ".git").exists():
            self.path, self.git = self.path / ".git", True

    def read(self, rel: str, commit: str = "HEAD") -> str:
        return self.read_bytes(rel, commit).decode("utf-8", errors="replace")

    def read_bytes(self, rel: str, commit: str = "HEAD") -> bytes:
        if not self.git:
            return (self.path / rel).read_bytes()
        return subprocess.run(["git", f"--git-dir={self.path}", "show", f"{commit}:{rel}"],
                              check=True, capture_output=True).stdout

    def head(self) -> str:
        if not self.git:
            return "unknown"
        return subprocess.run(["git", f"--git-dir={self.path}", "rev-parse", "HEAD"],
                              check=True, capture_output=True, text=True).stdout.strip()

    def files(self, commit: str = "HEAD") -> list:
        if not self.git:
            return [str(p.relative_to(self.path)) for p in self.path.rglob("*") if p.is_file()]
        out = subprocess.run(["git", f"--git-dir={self.path}", "ls-tree", "-r", "--name-only", commit],
                             check=True, capture_output=True, text=True).stdout
        return out.splitlines()


def write_csv(path: Path, columns: dict, fmt: str = "%.9g") -> None:
    """A CSV file from header -> 1-D array (equal lengths), written to a temporary name first."""
    heads = list(columns)
    data = np.column_stack([np.asarray(columns[h], dtype=float) for h in heads])
    tmp = path.with_suffix(".tmp")
    with open(tmp, "w") as f:
        f.write(",".join(heads) + "\n")
        for row in data:
            f.write(",".join("" if not np.isfinite(v) else (fmt % v) for v in row) + "\n")
    tmp.replace(path)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    s = str(v).replace("\\", "\\\\").replace('"', '\\"').replace("\n", " ")
    return f'"{s}"'


def write_truth(path: Path, *, source: str, case: str, licence: str, url: str, commit: str,
                authors: str, files: list, expected: dict, evidence: str, args=(),
                acceptable: dict | None = None, facts: dict | None = None, kind: str = "") -> None:
    """truth.toml of a case.  `expected`: output -> list of effect names (empty: the honest
    answer is nothing beyond the instrument's resolution); `acceptable`: output -> effects that
    may be named besides without being wrong (a defensible alternative reading); `facts`:
    figures of the source (e.g. a reversal value in mm) that the tests may check."""
    lines = [f"source = {_toml_value(source)}", f"case = {_toml_value(case)}",
             f"kind = {_toml_value(kind)}",
             f"licence = {_toml_value(licence)}", f"url = {_toml_value(url)}",
             f"commit = {_toml_value(commit)}", f"authors = {_toml_value(authors)}",
             f"files = {_toml_value(list(files))}", f"evidence = {_toml_value(evidence)}",
             f"args = {_toml_value(list(args))}", "", "[expected]"]
    lines += [f"{_toml_value(o)} = {_toml_value(sorted(e))}" for o, e in expected.items()]
    lines += ["", "[acceptable]"]
    lines += [f"{_toml_value(o)} = {_toml_value(sorted(e))}" for o, e in (acceptable or {}).items()]
    lines += ["", "[facts]"]
    lines += [f"{_toml_value(k)} = {_toml_value(v)}" for k, v in (facts or {}).items()]
    tmp = path.with_suffix(".tmp")
    tmp.write_text("\n".join(lines) + "\n")
    tmp.replace(path)


def case_dir(out: Path, source: str, case: str) -> Path:
    d = Path(out) / source / case
    d.mkdir(parents=True, exist_ok=True)
    return d


def progress(source: str, case: str, n: int, total: int) -> None:
    print(f"[{source}] {n}/{total} {case}", flush=True)


def stop_and_measure(targets, readings, approach, move_s: float = 2.0, dwell_s: float = 2.0,
                     rate_hz: float = 20.0):
    """SIM and REC instants of a stop-and-measure run (ISO 230-2 style, or a CMM visiting
    features) from the visited targets in their order: SIM moves linearly from target to target
    (starting `approach` before the first one, so the first reading's direction is known) and
    rests; REC holds one reading at the end of each dwell.  `targets` is (n,) for one axis or
    (n, k) for k axes (then `approach` is a k-vector or a number).  Returns (sim_t, sim_p,
    rec_t); sim_p has the shape of the targets' rows."""
    targets = np.asarray(targets, float)
    prev = targets[0] - np.asarray(approach, float)
    ts, ps, tr = [], [], []
    t = 0.0
    n_move, n_dwell = int(move_s * rate_hz), int(dwell_s * rate_hz)
    frac = np.arange(n_move) / n_move
    for p in targets:
        ts.extend(t + np.arange(n_move) / rate_hz)
        ps.extend(prev + np.multiply.outer(frac, p - prev))
        ts.extend(t + move_s + np.arange(n_dwell) / rate_hz)
        ps.extend([p] * n_dwell)
        tr.append(t + move_s + dwell_s * 0.9)
        prev = p
        t += move_s + dwell_s
    return np.array(ts), np.array(ps), np.array(tr)
