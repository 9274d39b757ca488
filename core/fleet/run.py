"""Diagnose a fleet's machine-nights on Dask distributed and write them as a dataset.

The client submits one task per machine-night (`night.run_job`), takes the rows back as each
task finishes, and writes that night's partition itself (`dataset.write_night`, atomic).  So a
worker that dies mid-task leaves nothing behind: Dask runs its task again on another worker, and
each night is written once, by one process.  Workers read the recordings by path: on a cluster
SOURCE must be visible at the same path on every worker (a shared file system).
"""
from __future__ import annotations

import logging
import os
import time
import uuid
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path

from .._io import MtcompError
from . import dataset
from .night import run_job

INSTALL = "pip install 'mtcomp[fleet]'"
WAIT_FOR_WORKERS_S = 120.0


class FleetUnavailable(MtcompError):
    """Dask distributed or pyarrow is not installed."""


_PACKAGES = {"distributed": "dask[distributed]", "pyarrow": "pyarrow"}


def require(modules=("distributed", "pyarrow")) -> None:
    """Raise FleetUnavailable, saying how to install them, when a module of `modules`
    (dask.distributed, pyarrow) is missing."""
    missing = []
    for mod in modules:
        pkg = _PACKAGES[mod]
        try:
            __import__(mod)
        except ImportError:
            missing.append(pkg)
    if missing:
        raise FleetUnavailable(f"mtcomp fleet needs {' and '.join(missing)}, which are not "
                               f"installed: {INSTALL}")


@dataclass
class FleetRun:
    """What a run did: nights written, the failed ones with their reason, wall time (s)."""
    dataset: Path
    nights: int = 0
    rows: int = 0
    errors: list = field(default_factory=list)   # (machine, date, reason)
    workers: int = 0
    wall_s: float = 0.0
    skipped: int = 0                             # nights already done (skip_done)

    def summary(self) -> str:
        s = (f"{self.nights} machine-nights diagnosed on {self.workers} worker(s) in "
             f"{self.wall_s:.1f} s: {self.rows} rows in {self.dataset}")
        if self.skipped:
            s += f"; {self.skipped} night(s) already done, skipped"
        if self.errors:
            s += f"\n{len(self.errors)} night(s) failed:" + "".join(
                f"\n  {m} {d}: {r}" for m, d, r in self.errors)
        return s


def _client(stack: ExitStack, scheduler: str | None, workers: int | None):
    from distributed import Client, LocalCluster
    if scheduler:
        from .._io import InputError
        try:
            client = stack.enter_context(Client(scheduler, timeout="20s", set_as_default=False))
        except (OSError, TimeoutError, ValueError) as exc:
            raise InputError(f"cannot connect to the Dask scheduler {scheduler!r}: "
                             f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__} "
                             "(expected tcp://HOST:PORT of a running `dask scheduler`)",
                             field="--scheduler") from None
        try:   # tasks sent to a scheduler without workers would wait for ever
            client.wait_for_workers(1, timeout=WAIT_FOR_WORKERS_S)
        except TimeoutError:
            raise InputError(f"the Dask scheduler {scheduler!r} has no worker after "
                             f"{WAIT_FOR_WORKERS_S:g} s (start some: dask worker {scheduler})",
                             field="--scheduler") from None
        return client
    n = workers or os.cpu_count() or 1
    # one single-threaded worker process per core: the diagnosis holds the GIL for much of its
    # work, and one BLAS thread per process gives the same bits on every worker
    import dask
    # no statistical profiler in the workers: it samples the task's stack every 10 ms for a
    # dashboard nobody looks at here, and cost 10-20 % of a night's CPU on this workload
    with dask.config.set({"distributed.worker.profile.enabled": False}):
        cluster = stack.enter_context(LocalCluster(
            n_workers=n, threads_per_worker=1, processes=True, dashboard_address="127.0.0.1:0",
            silence_logs=logging.ERROR))
    return stack.enter_context(Client(cluster, set_as_default=False))


def is_done(out, job) -> bool:
    """The night's partition was diagnosed, without error, from the same files (SHA-256), with
    the same options and by this version of mtcomp."""
    from .night import common_columns
    sig = dataset.signature(out, job.machine, job.date)
    if sig is None or sig[-1] != "ok":
        return False
    c = common_columns(job)
    return sig[:-1] == (c["sim_sha256"], c["rec_sha256"], c["options"], c["mtcomp_version"])


def run_fleet(jobs, out, scheduler: str | None = None, workers: int | None = None,
              progress=None, skip_done: bool = False) -> FleetRun:
    """Diagnose `jobs` (source.Job) on a Dask cluster and write DATASET `out`.

    scheduler: address of a running scheduler (tcp://HOST:8786); None starts an embedded
    LocalCluster of `workers` processes (default: one per core).  progress(done, total) is
    called as nights finish.  Nights already in `out` are replaced, others are left alone;
    with skip_done, a night already diagnosed from the same files and options is not run again
    (a nightly run over the whole history then diagnoses only the new nights).
    """
    require()
    from distributed import as_completed
    from distributed.client import FutureCancelledError
    from distributed.scheduler import KilledWorker
    jobs = list(jobs)
    out = Path(out)
    if out.exists() and not out.is_dir():
        from .._io import InputError
        raise InputError("exists and is not a folder (expected the dataset's folder)", out,
                         field="--out")
    dataset.clean_tmp(out)     # the folder itself is made by the first night written
    run = FleetRun(out)
    t0 = time.perf_counter()
    if skip_done:
        todo = [j for j in jobs if not is_done(out, j)]
        run.skipped = len(jobs) - len(todo)
        jobs = todo
    if not jobs:
        return run
    say = progress or (lambda done, total: None)
    with ExitStack() as stack:
        client = _client(stack, scheduler, workers)
        run.workers = len(client.scheduler_info(n_workers=-1).get("workers", {})) \
            if scheduler else (workers or os.cpu_count() or 1)
        token = uuid.uuid4().hex[:12]   # this run's keys: never a result of another run's task
        by_key = {f"{j.key}-{token}": j for j in jobs}
        futures = client.map(run_job, jobs, key=list(by_key), pure=False)
        say(0, len(jobs))
        for fut in as_completed(futures, loop=client.loop):
            job = by_key[fut.key]
            try:
                rows = fut.result()
            except (KilledWorker, FutureCancelledError) as exc:
                # the task took its workers down every time it ran: record it, go on
                from .night import common_columns, error_rows
                rows = error_rows(common_columns(job), f"internal error: {type(exc).__name__}: "
                                                f"the night's task killed its workers")
            fut.release()
            dataset.write_night(out, job.machine, job.date, rows)
            run.nights += 1
            run.rows += len(rows)
            if rows and rows[0]["effect"] == "error":
                run.errors.append((job.machine, job.date, rows[0]["status"]))
            say(run.nights, len(jobs))
    dataset.clean_tmp(out)
    run.wall_s = time.perf_counter() - t0
    return run
