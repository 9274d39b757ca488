"""One machine-night on a worker: hash the files, diagnose (through the adapter), make the rows.

`run_job` is what Dask runs; it never raises for a bad night: the night gets an "error" row with
the reason, so that one corrupt file does not stop a fleet.
"""
from __future__ import annotations

import hashlib
import math
import time

from .adapter import NightResult, diagnose_night
from .source import Job

# unit words that end a parameter name (backlash_mm, gain_mm_per_degC, coulomb_mm_s_per_...)
_UNITS = ("mm", "deg", "s", "degC", "rpm", "um", "mrad", "rad", "mm_s", "deg_s", "pct", "unit")


def param_unit(name: str) -> str:
    """The unit a parameter name carries: backlash_mm -> mm, kv_per_s -> 1/s,
    gain_mm_per_degC -> mm/degC, scale -> '' (dimensionless)."""
    if "_per_" in name:
        left, right = name.rsplit("_per_", 1)
        num = _unit_tail(left.split("_"))
        return f"{num or '1'}/{right.replace('_', '/')}"
    return _unit_tail(name.split("_"))


def _unit_tail(words: list) -> str:
    """The unit word(s) ending a name's words after a base name (mm, or mm_s -> mm/s)."""
    for n in (2, 1):
        if len(words) > n and "_".join(words[-n:]) in _UNITS:
            return "_".join(words[-n:]).replace("_", "/")
    return ""


def sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _versions() -> dict:
    import numpy
    import scipy
    from .. import __version__
    return {"mtcomp_version": __version__, "numpy_version": numpy.__version__,
            "scipy_version": scipy.__version__}


def _rms(d: dict, outputs) -> float:
    v = [d[o] for o in outputs if o in d]
    return math.sqrt(sum(x * x for x in v) / len(v)) if v else float("nan")


def common_columns(job: Job) -> dict:
    sims = [r[0] for r in job.recordings]
    recs = [r[1] for r in job.recordings]
    out = {"sim_files": ";".join(sims), "rec_files": ";".join(recs), "options": job.options_json}
    try:
        out["sim_sha256"] = ";".join(sha256(f) for f in sims)
        out["rec_sha256"] = ";".join(sha256(f) for f in recs)
    except OSError:
        out["sim_sha256"] = out["rec_sha256"] = ""
    out.update(_versions())
    return out


def rows_of(res: NightResult, common: dict) -> list[dict]:
    """One row per effect x parameter, and one "none" row per output without an effect."""
    rows = []

    def fit_cols(outputs):
        before, after = _rms(res.holdout_before, outputs), _rms(res.holdout_after, outputs)
        return {"output_unit": ",".join(sorted({res.units.get(o) or "" for o in outputs})),
                "rms_before": _rms(res.rms_before, outputs),
                "residual_rms": _rms(res.rms_after, outputs),
                "holdout_rms_before": before, "holdout_rms_after": after,
                "holdout_gain": 1.0 - after / before if before > 0 else float("nan"),
                "noise_floor": _rms(res.noise_floor, outputs),
                "unexplained": any(o in res.unexplained for o in outputs),
                "night_unexplained": ",".join(sorted(res.unexplained)),
                "samples": res.samples, "status": "ok"}
    covered = set()
    for e in res.effects:
        covered.update(e.outputs)
        fc = fit_cols(e.outputs)
        for p, v in e.params.items():
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                continue      # a driver's name and the like: not a number to trend
            s = e.uncertainty.get(p)
            rows.append(dict(common, **fc, effect=e.name, output=",".join(e.outputs), parameter=p,
                             unit=param_unit(p), value=float(v),
                             sigma=float(s) if isinstance(s, (int, float)) else float("nan")))
    for o in res.outputs:
        if o not in covered:
            rows.append(dict(common, **fit_cols((o,)), effect="none", output=o, parameter="",
                             unit="", value=float("nan"), sigma=float("nan")))
    return rows


def error_rows(common: dict, reason: str) -> list[dict]:
    return [dict(common, effect="error", output="", parameter="", unit="", value=float("nan"),
                 sigma=float("nan"), status=reason or "error")]


def run_job(job: Job) -> list[dict]:
    """Diagnose one machine-night and return its rows (the dataset's schema, without the
    partition columns machine and date)."""
    from .._io import MtcompError
    common = common_columns(job)
    # the task's own thread: a worker process also runs Dask's event loop and heartbeats
    t0, c0 = time.perf_counter(), time.thread_time()
    res = reason = None
    try:
        res = diagnose_night(job.recordings, job.options)
    except MtcompError as exc:
        reason = f"error: {exc}"
    except OSError as exc:
        reason = f"error: {exc.filename or ''}: {exc.strerror or exc}"
    except Exception as exc:  # noqa: BLE001 - a bug on one night must not stop the fleet
        reason = f"internal error: {type(exc).__name__}: {str(exc)[:200]}"
    common.update(cpu_s=time.thread_time() - c0, wall_s=time.perf_counter() - t0)
    return error_rows(common, reason) if res is None else rows_of(res, common)
