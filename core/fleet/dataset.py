"""The fleet's results as a Parquet dataset, partitioned by machine and date (Hive style).

Layout: DATASET/machine=<m>/date=<YYYY-MM-DD>/part-0.parquet, one file per machine-night, so
pandas (`pd.read_parquet(DATASET)`), pyarrow.dataset and duckdb
(`read_parquet('DATASET/*/*/*.parquet', hive_partitioning=true)`) read it as it is.  A night's
file is written in DATASET/_tmp/ (ignored by readers: its name starts with '_') and renamed onto
its place: a reader sees the old partition or the new one, never half of one, and re-running a
night replaces its partition.

One row per machine x night x effect x output x parameter.  An output without a named effect has
one row with effect "none"; a night that could not be diagnosed one row with effect "error" and
the reason in `status`.
"""
from __future__ import annotations

import os
import shutil
import uuid
from pathlib import Path
from urllib.parse import quote

PART = "part-0.parquet"
TMP = "_tmp"


def schema():
    import pyarrow as pa
    return pa.schema([
        ("effect", pa.string()),          # effect name, "none" or "error"
        ("output", pa.string()),          # output(s) the effect acts on, "x" or "x,z"
        ("parameter", pa.string()),       # name carrying its unit: backlash_mm, kv_per_s
        ("unit", pa.string()),            # unit of value and sigma: mm, 1/s, mm/degC
        ("value", pa.float64()),
        ("sigma", pa.float64()),          # one standard deviation
        ("output_unit", pa.string()),     # unit of the RMS columns
        ("rms_before", pa.float64()),     # RMS of REC - SIM on the effect's output(s)
        ("residual_rms", pa.float64()),   # RMS after the named effects
        ("holdout_rms_before", pa.float64()),
        ("holdout_rms_after", pa.float64()),
        ("holdout_gain", pa.float64()),   # 1 - holdout_rms_after / holdout_rms_before
        ("noise_floor", pa.float64()),
        ("unexplained", pa.bool_()),      # residual still > 3x the noise floor (the row's outputs)
        ("night_unexplained", pa.string()),  # outputs of the night left unexplained, "x,z"
        ("samples", pa.int64()),
        ("status", pa.string()),          # "ok" or the reason the night failed
        ("sim_files", pa.string()),       # ';'-joined paths as given
        ("rec_files", pa.string()),
        ("sim_sha256", pa.string()),      # ';'-joined, one per recording
        ("rec_sha256", pa.string()),
        ("options", pa.string()),         # the diagnose options, JSON
        ("mtcomp_version", pa.string()),
        ("numpy_version", pa.string()),
        ("scipy_version", pa.string()),
        ("cpu_s", pa.float64()),          # CPU time of the night's diagnosis (its thread)
        ("wall_s", pa.float64()),
    ])


def partition_dir(root, machine: str, date: str) -> Path:
    return Path(root) / f"machine={quote(machine, safe='')}" / f"date={quote(date, safe='')}"


def write_night(root, machine: str, date: str, rows: list[dict]) -> Path:
    """Write one machine-night's rows as its partition, atomically (temp file, fsync, rename)."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    root = Path(root)
    table = pa.Table.from_pylist(rows, schema=schema())
    tmpdir = root / TMP
    tmpdir.mkdir(parents=True, exist_ok=True)
    tmp = tmpdir / f"{uuid.uuid4().hex}.parquet"
    try:
        pq.write_table(table, tmp)
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        dest = partition_dir(root, machine, date)
        dest.mkdir(parents=True, exist_ok=True)
        os.replace(tmp, dest / PART)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return dest / PART


SIGNATURE = ("sim_sha256", "rec_sha256", "options", "mtcomp_version", "status")


def signature(root, machine: str, date: str):
    """What a written night was diagnosed from: (sim hashes, rec hashes, options, mtcomp version,
    status) when its partition holds one such tuple, else None."""
    import pyarrow.parquet as pq
    f = partition_dir(root, machine, date) / PART
    if not f.is_file():
        return None
    try:
        t = pq.read_table(f, columns=list(SIGNATURE)).to_pylist()
    except Exception:  # noqa: BLE001 - an unreadable partition is not done: diagnose it again
        return None
    sigs = {tuple(r[k] for k in SIGNATURE) for r in t}
    return sigs.pop() if len(sigs) == 1 else None


def clean_tmp(root) -> None:
    """Remove what a killed writer may have left in DATASET/_tmp."""
    shutil.rmtree(Path(root) / TMP, ignore_errors=True)


def read(root):
    """The whole dataset as a pyarrow Table with `machine` and `date` columns (strings)."""
    import pyarrow as pa
    import pyarrow.dataset as ds
    from .._io import InputError
    root = Path(root)
    if not root.is_dir():
        raise InputError("not a folder (expected a fleet dataset written by `mtcomp fleet "
                         "diagnose`)", root)
    part = ds.partitioning(pa.schema([("machine", pa.string()), ("date", pa.string())]),
                           flavor="hive")
    files = sorted(str(p) for p in root.glob(f"machine=*/date=*/{PART}"))
    if not files:
        raise InputError(f"no partitions machine=*/date=*/{PART} (expected a fleet dataset "
                         "written by `mtcomp fleet diagnose`)", root)
    full = schema().append(pa.field("machine", pa.string())).append(pa.field("date", pa.string()))
    d = ds.dataset(files, schema=full, format="parquet", partitioning=part,
                   partition_base_dir=str(root))
    t = d.to_table()
    return t.sort_by([("machine", "ascending"), ("date", "ascending"), ("output", "ascending"),
                      ("effect", "ascending"), ("parameter", "ascending")])
