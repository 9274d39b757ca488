"""mtcomp fleet on a generated fleet with known parameter histories, on a real Dask cluster.

The default fleet is 3 machines x 3 nights (a backlash that grows on m02 from the 2nd night, a
servo lag that steps on m03 on the 3rd night): each night's diagnosis costs about 1 s of CPU, and
the machine running the tests is shared.  MTCOMP_FLEET_FULL=1 runs the acceptance fleet of the
issue, 20 machines x 10 nights, through the same checks (several minutes of CPU).
"""
from __future__ import annotations

import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("distributed")
pytest.importorskip("pyarrow")

from mtcomp.cli import main  # noqa: E402
from mtcomp.diagnose import diagnose  # noqa: E402
from mtcomp.fleet.dataset import PART, TMP, read  # noqa: E402
from mtcomp.fleet.generate import FleetSpec, make_fleet, write_fleet  # noqa: E402
from mtcomp.fleet.trend import trends  # noqa: E402

SMALL = FleetSpec(machines=3, nights=3, grow_machine=1, grow_from=1, repair_machine=2,
                  repair_night=2)
FULL = FleetSpec(machines=20, nights=10)
# columns that say how long a night took: the only ones that differ from run to run
TIMING = ("cpu_s", "wall_s")


def _run_local(spec, root: Path):
    fleet = make_fleet(spec)
    src = write_fleet(fleet, root / "src")
    ds = root / "ds"
    rc = main(["fleet", "diagnose", str(src), "-o", str(ds), "--same-clock", "--workers", "2",
               "--quiet"])
    assert rc == 0
    return fleet, src, ds


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    return _run_local(SMALL, tmp_path_factory.mktemp("fleet"))


def _rows(ds) -> list[dict]:
    t = read(ds)
    return [{k: v for k, v in r.items() if k not in TIMING} for r in t.to_pylist()]


def _same(a, b) -> bool:
    """Bit for bit (NaN equals NaN)."""
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


def check_rows_equal_plain_diagnose(fleet, src, ds, every=1):
    """Every row's value and sigma are those of a plain diagnose of the night, bit for bit."""
    rows = _rows(ds)
    by_night: dict = {}
    for r in rows:
        by_night.setdefault((r["machine"], r["date"]), []).append(r)
    assert set(by_night) == {(n.machine, n.date) for n in fleet.nights}
    for i, n in enumerate(fleet.nights):
        if i % every:
            continue
        d = src / n.machine / n.date
        res = diagnose(str(d / "sim.csv"), str(d / "rec.csv"), same_clock=True)
        want = {}
        for e in res.effects:
            for p, v in e.params.items():
                if isinstance(v, float):
                    want[(e.name, ",".join(e.outputs), p)] = (v, e.uncertainty[p])
        got = {(r["effect"], r["output"], r["parameter"]): (r["value"], r["sigma"])
               for r in by_night[(n.machine, n.date)] if r["effect"] != "none"}
        assert got.keys() == want.keys(), (n.machine, n.date)
        for k in want:
            assert _same(got[k][0], want[k][0]) and _same(got[k][1], want[k][1]), (n.machine, n.date, k)
        for r in by_night[(n.machine, n.date)]:
            o = r["output"].split(",")[0]
            if len(r["output"].split(",")) == 1:
                assert r["holdout_rms_after"] == res.fit["holdout_rms_after"][o]
                assert r["residual_rms"] == res.fit["rms_after"][o]


def check_warnings_exactly_changed(fleet, ds):
    tr = trends(read(ds))
    assert tr.errors == ()
    assert {w.key for w in tr.warnings} == set(fleet.changed)


def test_rows_equal_plain_diagnose(small):
    fleet, src, ds = small
    check_rows_equal_plain_diagnose(fleet, src, ds)


def test_plain_cli_json_equals_row(small, tmp_path):
    """`mtcomp diagnose --json` of one night gives the row's numbers (JSON keeps every bit)."""
    import json
    fleet, src, ds = small
    n = fleet.nights[-1]
    d = src / n.machine / n.date
    out = tmp_path / "d.json"
    assert main(["diagnose", "--sim", str(d / "sim.csv"), "--rec", str(d / "rec.csv"),
                 "--same-clock", "--json", str(out), "--quiet"]) == 0
    js = json.loads(out.read_text())
    rows = [r for r in _rows(ds) if (r["machine"], r["date"]) == (n.machine, n.date)]
    for e in js["effects"]:
        for p, v in e["params"].items():
            if isinstance(v, float):
                r, = [r for r in rows if (r["effect"], r["output"], r["parameter"]) ==
                      (e["name"], e["output"], p)]
                assert r["value"] == v and r["sigma"] == e["uncertainty"][p]


def test_dataset_layout_and_versions(small):
    fleet, src, ds = small
    parts = sorted(ds.glob(f"machine=*/date=*/{PART}"))
    assert len(parts) == len(fleet.nights)
    assert not (ds / TMP).exists()
    rows = read(ds).to_pylist()
    assert {r["status"] for r in rows} == {"ok"}
    r = rows[0]
    import hashlib
    sim = src / r["machine"] / r["date"] / "sim.csv"
    assert r["sim_sha256"] == hashlib.sha256(sim.read_bytes()).hexdigest()
    assert r["mtcomp_version"] and r["numpy_version"] and r["scipy_version"]
    assert r["cpu_s"] > 0
    # readable as it is by pyarrow's own Hive discovery (what pandas.read_parquet uses)
    import pyarrow.dataset as pds
    t = pds.dataset(str(ds), format="parquet", partitioning="hive").to_table()
    assert t.num_rows == len(rows) and "machine" in t.column_names and "date" in t.column_names


def test_report_warns_exactly_for_the_changed_nights(small, tmp_path):
    fleet, src, ds = small
    check_warnings_exactly_changed(fleet, ds)
    html = tmp_path / "r.html"
    assert main(["fleet", "report", str(ds), "-o", str(html), "--quiet"]) == 1
    text = html.read_text()
    assert text.count("data:image/png;base64,") == SMALL.machines
    for m, d, p in fleet.changed:
        assert d in text and m in text
    # one machine without a change: no warning, exit status 0
    quiet = tmp_path / "m01"
    shutil.copytree(ds / "machine=m01", quiet / "machine=m01")
    assert main(["fleet", "report", str(quiet), "-o", str(tmp_path / "q.html"), "--quiet"]) == 0


def test_limit_crossed_warns(small, tmp_path):
    """A limit below the grown backlash of m02's last night: a limit warning on that night only
    (the grown nights warn for change anyway; the others stay silent)."""
    fleet, src, ds = small
    truth = fleet.truth()
    grown = [truth[("m02", d)]["backlash_mm"] for d in SMALL.dates()]
    lim = 0.5 * (grown[-1] + grown[-2])
    f = tmp_path / "limits.toml"
    f.write_text(f'[change]\nk = 5\n\n[[limit]]\nparameter = "backlash_mm"\nmax = {lim!r}\n')
    from mtcomp.fleet.trend import load_limits
    tr = trends(read(ds), load_limits(f))
    lims = [w for w in tr.warnings if w.kind == "limit"]
    assert [(w.machine, w.date) for w in lims] == [("m02", SMALL.dates()[-1])]
    assert main(["fleet", "report", str(ds), "-o", str(tmp_path / "r.html"), "--limits", str(f),
                 "--quiet"]) == 1


# --- a real cluster: `dask scheduler` and two `dask worker` processes on 127.0.0.1 ---------------

def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def cluster():
    """A scheduler and two single-threaded workers (no nanny: a SIGKILL ends the worker for
    good); every process is killed at the end, and stops by itself if the test process dies
    (the scheduler after 10 min without a client, the workers 60 s after the scheduler)."""
    dask = str(Path(sys.executable).with_name("dask"))
    port = _free_port()
    addr = f"tcp://127.0.0.1:{port}"
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    procs = []

    def start(*args):
        p = subprocess.Popen([dask, *args], env=env, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL, start_new_session=True)
        procs.append(p)
        return p
    try:
        start("scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard",
              "--idle-timeout", "600")
        workers = [start("worker", addr, "--host", "127.0.0.1", "--nthreads", "1", "--no-nanny",
                         "--no-dashboard", "--death-timeout", "60") for _ in range(2)]
        from distributed import Client
        with Client(addr, timeout="60s") as c:
            c.wait_for_workers(2, timeout=120)
        yield addr, workers
    finally:
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
            p.wait()


def run_with_kill(src, ds, addr, workers, total):
    """Run the fleet through --scheduler, SIGKILL one worker once a first night is written."""
    before = {p: p.stat().st_mtime_ns for p in ds.glob(f"machine=*/date=*/{PART}")}
    cmd = [str(Path(sys.executable).with_name("mtcomp")), "fleet", "diagnose", str(src), "-o",
           str(ds), "--same-clock", "--scheduler", addr, "--quiet"]
    run = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        killed = False
        deadline = time.monotonic() + 600
        while run.poll() is None and time.monotonic() < deadline:
            fresh = [p for p in ds.glob(f"machine=*/date=*/{PART}")
                     if p.stat().st_mtime_ns != before.get(p)]
            if fresh and not killed:
                os.killpg(workers[0].pid, signal.SIGKILL)
                killed, written_at_kill = True, len(fresh)
            time.sleep(0.05)
        out, err = run.communicate(timeout=600)
    finally:
        if run.poll() is None:
            run.kill()
    assert killed
    assert run.returncode == 0, err
    assert written_at_kill < total       # the worker died while nights were left
    return before


def test_scheduler_with_a_worker_killed(small, cluster, tmp_path):
    """The same fleet through a real scheduler, into a copy of the embedded run's dataset: one
    worker SIGKILLed mid-run, the run completes, each night is written once (replacing its old
    partition), nothing half-written, and every row equals the embedded cluster's."""
    fleet, src, ds_local = small
    addr, workers = cluster
    ds = tmp_path / "ds"
    shutil.copytree(ds_local, ds)
    before = run_with_kill(src, ds, addr, workers, len(fleet.nights))
    parts = sorted(ds.glob(f"machine=*/date=*/{PART}"))
    assert len(parts) == len(fleet.nights)
    assert all(p.stat().st_mtime_ns != before[p] for p in parts)    # every night rewritten
    assert not (ds / TMP).exists() and not list(ds.rglob("*.tmp"))
    assert _rows(ds) == _rows(ds_local)


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("MTCOMP_FLEET_FULL"),
                    reason="the acceptance fleet (20 machines x 10 nights) takes minutes of CPU: "
                           "set MTCOMP_FLEET_FULL=1")
def test_acceptance_fleet_20x10(tmp_path, cluster):
    fleet, src, ds = _run_local(FULL, tmp_path)
    check_warnings_exactly_changed(fleet, ds)
    check_rows_equal_plain_diagnose(fleet, src, ds)
    addr, workers = cluster
    ds2 = tmp_path / "ds2"
    shutil.copytree(ds, ds2)
    run_with_kill(src, ds2, addr, workers, len(fleet.nights))
    assert len(list(ds2.glob(f"machine=*/date=*/{PART}"))) == len(fleet.nights)
    assert _rows(ds2) == _rows(ds)


def test_skip_done_runs_only_the_changed_night(small, tmp_path, capsys):
    """--skip-done: nothing to do on an up-to-date dataset (no cluster started); a recording
    edited after its night was diagnosed is diagnosed again, and only it."""
    fleet, src, ds_local = small
    src2, ds = tmp_path / "src", tmp_path / "ds"
    shutil.copytree(src, src2)
    shutil.copytree(ds_local, ds)
    # the rows name the files they came from: the copy's nights are "done" only by content
    assert main(["fleet", "diagnose", str(src), "-o", str(ds), "--same-clock", "--skip-done"]) == 0
    assert f"{len(fleet.nights)} night(s) already done, skipped" in capsys.readouterr().out
    n = fleet.nights[0]
    rec = src / n.machine / n.date / "rec.csv"
    rec2 = src2 / n.machine / n.date / "rec.csv"
    rec2.write_text(rec.read_text() + "# a comment line: same data, other bytes\n")
    before = {p: p.stat().st_mtime_ns for p in ds.glob(f"machine=*/date=*/{PART}")}
    assert main(["fleet", "diagnose", str(src2), "-o", str(ds), "--same-clock", "--skip-done",
                 "--workers", "1"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("1 machine-nights diagnosed")
    assert f"{len(fleet.nights) - 1} night(s) already done" in out
    changed = [p for p in ds.glob(f"machine=*/date=*/{PART}") if p.stat().st_mtime_ns != before[p]]
    assert changed == [ds / f"machine={n.machine}" / f"date={n.date}" / PART]


def test_scheduler_without_workers_is_an_error(tmp_path, monkeypatch, capsys):
    """A scheduler with no worker: a clear error naming --scheduler, nothing written (the tasks
    would otherwise wait for ever)."""
    import mtcomp.fleet.run as fr
    src = write_fleet(make_fleet(FleetSpec(machines=1, nights=1)), tmp_path / "src")
    monkeypatch.setattr(fr, "WAIT_FOR_WORKERS_S", 3.0)
    port = _free_port()
    p = subprocess.Popen([str(Path(sys.executable).with_name("dask")), "scheduler", "--host",
                          "127.0.0.1", "--port", str(port), "--no-dashboard", "--idle-timeout", "300"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        from distributed import Client
        deadline = time.monotonic() + 120
        while True:     # wait until it listens
            try:
                with Client(f"tcp://127.0.0.1:{port}", timeout="5s"):
                    break
            except OSError:
                assert time.monotonic() < deadline
        rc = main(["fleet", "diagnose", str(src), "-o", str(tmp_path / "ds"), "--same-clock",
                   "--scheduler", f"tcp://127.0.0.1:{port}"])
    finally:
        os.killpg(p.pid, signal.SIGKILL)
        p.wait()
    assert rc == 2
    assert "[--scheduler]: the Dask scheduler" in capsys.readouterr().err
    assert not (tmp_path / "ds").exists()
