"""Cell bridge benchmark: exactly-once delivery under disconnects and crashes, handshake speed.

A. Acceptance: N load cycles (default 1000) of the PLC simulator against `mtcomp cell serve`
   running as a separate process with the virtual cell; the PLC drops its connection around a
   fraction of its requests, and the server is killed with SIGKILL after every 100th cycle at a
   random moment, then started again on the same journal. Checked: every journaled result
   reached the PLC exactly once and bit-equal (float32), every result ACKed once, nothing lost.
B. Handshake: the same two processes with a measurement step that takes no time (probing
   excluded), back-to-back polling; cycles/s and the latency of a result write (from the step
   returning in the server to the PLC reading it), with the journal fsync'ed (the product) and,
   as the baseline, without fsync; plus the bare Modbus round trip (write + read of 9 and 41
   registers) as the floor.
C. Fuzzed cell runs (`--fuzz N`, also run by tests/test_cell_safety.py with a small N): N load
   cycles over loopback, each with a random program situation: part program present, missing,
   binary, unparsable, leaving the travel or itself a compensated program; target absent, a shop
   program, the cell's own, a cell program edited by hand or a directory; no --nc-dir or a
   missing one; program ids out of the range; the file edited, deleted, swapped for another
   blank's or rewritten identically between writing and publishing; random connection drops.
   Counted: GO without a verified program for this blank on disk (must be 0), protected files
   changed (must be 0), tracebacks logged (must be 0), and the outcomes.

Usage: python benchmarks/bench_cell.py [--cycles 1000] [--quick] | --fuzz N [--seed S]
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def instant(job):
    """Measurement step that takes no time (handshake benchmark): records when it returned."""
    from mtcomp.cell.cycle import CellResult
    return CellResult((0.001, -0.002, 0.003, 0.01, -0.02, 0.03), (1e-4,) * 6,
                      job.program_id + 1000, True, {"t_done": time.perf_counter()})


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ServerProcess:
    def __init__(self, journal, port, extra=()):
        self.journal, self.port, self.extra = journal, port, list(extra)
        self.p = None

    def start(self):
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(
            [str(HERE), os.environ.get("PYTHONPATH", "")]))
        self.p = subprocess.Popen([sys.executable, "-m", "mtcomp.cell.cli", "serve", "--journal",
                                   str(self.journal), "--port", str(self.port), *self.extra],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
        t = time.monotonic() + 30
        while time.monotonic() < t:
            if self.p.poll() is not None:
                raise RuntimeError(self.p.stderr.read().decode())
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.2).close()
                return self
            except OSError:
                time.sleep(0.02)
        raise RuntimeError("server did not come up")

    def kill(self):
        self.p.send_signal(signal.SIGKILL)
        self.p.wait(10)

    def stop(self):
        if self.p and self.p.poll() is None:
            self.p.terminate()
            self.p.wait(10)


def check_exactly_once(report, journal):
    import numpy as np
    from mtcomp.cell.journal import read_records
    recs = read_records(journal)[0]
    jr = {r["result_seq"]: r for r in recs if r["ev"] == "result"}
    acks = [r["result_seq"] for r in recs if r["ev"] == "ack"]
    got = [r.result_seq for r in report.results]
    mismatched = sum(
        list(r.pose) != [float(np.float32(v)) for v in jr[r.result_seq]["pose"]]
        or list(r.sigma) != [float(np.float32(v)) for v in jr[r.result_seq]["sigma"]]
        for r in report.results if r.result_seq in jr)
    return {
        "journal_results": len(jr),
        "plc_results": len(got),
        "taken_twice": len(got) - len(set(got)),
        "lost": len(set(jr) - set(got)),
        "invented": len(set(got) - set(jr)),
        "acked_twice": len(acks) - len(set(acks)),
        "not_acked": len(set(jr) - set(acks)),
        "value_mismatch": mismatched,
        "duplicates_after_ack": report.duplicates,
        "boots": [r for r in recs if r["ev"] == "boot"],
    }


def acceptance(n_cycles: int, every: int, p_drop: float, seed: int, workdir: Path):
    from mtcomp.cell.plcsim import PlcSim
    journal, port = workdir / "acceptance.jsonl", _free_port()
    srv = ServerProcess(journal, port).start()
    rng = random.Random(seed)
    kills = []

    async def main():
        plc = PlcSim("127.0.0.1", port, disconnect_prob=p_drop, seed=seed,
                     request_timeout_s=0.2, reconnect_timeout_s=60)
        task = asyncio.create_task(plc.run(n_cycles))
        next_kill = every
        t0 = time.perf_counter()
        while not task.done():
            await asyncio.sleep(0.001)
            if plc.report.cycles >= next_kill and next_kill < n_cycles:
                await asyncio.sleep(rng.uniform(0.0, 0.012))   # somewhere in the next cycle
                await asyncio.to_thread(srv.kill)
                kills.append(plc.report.cycles)
                await asyncio.to_thread(srv.start)
                next_kill += every
                print(f"  {plc.report.cycles}/{n_cycles} cycles, server killed and restarted "
                      f"({time.perf_counter() - t0:.1f} s)", file=sys.stderr, flush=True)
        return await task, time.perf_counter() - t0

    try:
        report, elapsed = asyncio.run(main())
    finally:
        srv.stop()
    chk = check_exactly_once(report, journal)
    boots = chk.pop("boots")[1:]  # first boot is the cold start
    chk["restarts_while"] = {s: sum(b["state"] == s for b in boots)
                             for s in ("idle", "busy", "ready", "fault")}
    return report, chk, elapsed, kills


def handshake(n_cycles: int, fsync: bool, workdir: Path):
    import numpy as np
    from mtcomp.cell.journal import read_records
    from mtcomp.cell.plcsim import PlcSim
    journal, port = workdir / f"handshake-{fsync}.jsonl", _free_port()
    extra = ["--measure", "bench_cell:instant"] + ([] if fsync else ["--no-fsync"])
    srv = ServerProcess(journal, port, extra).start()
    try:
        plc = PlcSim("127.0.0.1", port, poll_s=0.0)
        asyncio.run(plc.run(20))                       # warm-up
        plc.report = type(plc.report)()
        t0 = time.perf_counter()
        rep = asyncio.run(plc.run(n_cycles))
        elapsed = time.perf_counter() - t0
    finally:
        srv.stop()
    done = {r["result_seq"]: r["info"]["t_done"] for r in read_records(journal)[0]
            if r["ev"] == "result"}
    lat = np.array([r.t_seen - done[r.result_seq] for r in rep.results])
    return n_cycles / elapsed, np.percentile(lat, 50), np.percentile(lat, 99)


def round_trip(n: int, workdir: Path):
    import numpy as np
    from pymodbus.client import AsyncModbusTcpClient
    from mtcomp.cell.registers import OUT_BLOCK
    port = _free_port()
    srv = ServerProcess(workdir / "rt.jsonl", port, ["--measure", "bench_cell:instant"]).start()

    async def main():
        c = AsyncModbusTcpClient("127.0.0.1", port=port)
        await c.connect()
        ts = []
        for _ in range(n):
            t = time.perf_counter()
            await c.write_registers(0, [0] * 9, device_id=1)
            await c.read_holding_registers(OUT_BLOCK[0], count=OUT_BLOCK[1] - OUT_BLOCK[0],
                                           device_id=1)
            ts.append(time.perf_counter() - t)
        c.close()
        return np.array(ts)

    try:
        ts = asyncio.run(main())
    finally:
        srv.stop()
    return np.percentile(ts, 50), np.percentile(ts, 99)


def journal_append(n: int, workdir: Path):
    """p50, p99 of one journal record written and fsync'ed (the durability cost alone)."""
    import numpy as np
    from mtcomp.cell.journal import Journal
    ts = []
    with Journal.open(workdir / "append.jsonl") as j:
        for i in range(n):
            t = time.perf_counter()
            j.append("ack", cmd_seq=i % 65535 + 1, status=0, result_seq=i + 1)
            ts.append(time.perf_counter() - t)
    return np.percentile(ts, 50), np.percentile(ts, 99)


PART = "%\nO{n:04d} (FUZZ PART)\nG90 G21 G54\nG00 X0 Y0 Z2.\nG01 Z-0.1 F100.\nG02 X2. Y0 I1. J0\nG01 X1. Y0.5\nM30\n%\n"
TRAVEL = "O{n:04d}\nG90 G21\nG01 X0 Y0 F100.\nG01 X139.99999\nG01 X-139.99999\nM30\n"
_W = {"source": (("ok", 10), ("missing", 1), ("binary", 1), ("unparsable", 1), ("travel", 1),
                 ("cell_output", 1)),
      "target": (("absent", 5), ("ours", 5), ("shop", 1), ("edited", 1), ("directory", 1)),
      "nc": (("ok", 10), ("none", 1), ("missing_dir", 1)),
      "tamper": (("none", 8), ("same", 2), ("edit", 1), ("delete", 1), ("swap", 1)),
      "program": ((100, 10), (1500, 3), (42, 3), (7000, 1), (9000, 1))}


def _pick(rng, what):
    names, weights = zip(*_W[what])
    return rng.choices(names, weights)[0]


def fuzz(n_cycles: int, seed: int, workdir: Path, p_drop: float = 0.02) -> dict:
    """C: fuzzed cell runs (see the module docstring); returns the counts."""
    import logging
    import shutil
    import zlib
    from mtcomp.cell import program as cp
    from mtcomp.cell.cycle import CellConfig
    from mtcomp.cell.plcsim import PlcSim
    from mtcomp.cell.registers import Fault, NoGo
    from mtcomp.cell.server import BackgroundServer
    from mtcomp.cell.virtual import VirtualCell
    from mtcomp.machine import load_machine
    rng = random.Random(seed)
    nc = workdir / "fuzz-nc"
    nc.mkdir(parents=True, exist_ok=True)
    machine = load_machine("robonano-a0ib")
    plan = {}                       # part id -> scenario
    outputs: list[bytes] = []       # verified cell outputs seen so far (for swaps and sources)
    steps = {"ok": VirtualCell(seed=seed, nc_dir=str(nc)), "none": VirtualCell(seed=seed),
             "missing_dir": VirtualCell(seed=seed, nc_dir=str(workdir / "no-such-dir"))}

    def step(job):
        sc = plan[job.part_id]
        res = steps[sc["nc"]](job)
        prog = res.program
        if prog is not None:
            path = Path(prog.path)
            outputs.append(path.read_bytes())
            t = sc["tamper"]
            if t == "same":
                path.write_bytes(path.read_bytes())
            elif t == "edit":
                with open(path, "a") as fh:
                    fh.write("G00 Z50.\n")
            elif t == "delete":
                path.unlink()
            elif t == "swap" and len(outputs) > 1:
                path.write_bytes(outputs[-2])       # an earlier blank's (marker intact)
        return res

    class Tracebacks(logging.Handler):
        n = 0

        def emit(self, record):
            if record.exc_info:
                Tracebacks.n += 1
    tb = Tracebacks()
    log = logging.getLogger("mtcomp.cell")
    log.addHandler(tb)
    counts = {"cycles": 0, "results": 0, "go": 0, "go_without_verified_program": 0,
              "protected_changed": 0, "tracebacks": 0, "start_refused": 0,
              "faults": {}, "nogo": {}}
    protected: dict[Path, bytes | None] = {}

    def prepare(part, sc):
        src = nc / cp.program_file_name(sc["program"])
        dst = nc / cp.program_file_name(sc["program"] + 1000)
        for p in (src, dst):
            protected.pop(p, None)
            if p.is_dir():
                shutil.rmtree(p)
        if sc["source"] == "missing":
            src.unlink(missing_ok=True)
        elif sc["source"] == "binary":
            src.write_bytes(bytes(range(256)))
        elif sc["source"] == "unparsable":
            src.write_text("O0001\nG01 X1..2\nM30\n")
        elif sc["source"] == "travel":
            src.write_text(TRAVEL.format(n=sc["program"]))
        elif sc["source"] == "cell_output" and outputs:
            src.write_bytes(outputs[-1])
        else:
            src.write_text(PART.format(n=sc["program"]))
        t = sc["target"]
        existing = dst.read_bytes() if dst.is_file() else None
        if t == "absent" or (t == "ours" and (existing is None or cp.read_marker(existing) is None)):
            dst.unlink(missing_ok=True)
        elif t == "shop":
            dst.write_bytes(b"O%04d (SHOP PROGRAM)\nG00 X0\nM30\n" % (sc["program"] + 1000))
        elif t == "edited":
            base = existing if existing and cp.read_marker(existing) else (outputs[-1] if outputs
                                                                           else None)
            if base is None:
                dst.write_bytes(b"(MTCOMP-CELL O1100 FROM O0100 PART 1 JOB 1 BODY 0000000000000000)\n")
            else:
                dst.write_bytes(base.replace(b"M30", b"M00\nM30"))
        elif t == "directory":
            dst.unlink(missing_ok=True)
            dst.mkdir()
        if t in ("shop", "edited", "directory"):
            protected[dst] = None if dst.is_dir() else dst.read_bytes()

    def check_go(r):
        """A GO must name a file on disk, intact, for this blank and job, that parses and stays
        in the travel, with the CRC the PLC read."""
        path = nc / cp.program_file_name(r.program_id)
        try:
            data = path.read_bytes()
            if r.program_id == 0 or zlib.crc32(data) != r.program_crc:
                return False
            mark = cp.read_marker(data)
            if mark is None or mark.part_id != r.part_id or (mark.job_no & 0xFFFF) != r.job_no:
                return False
            cp.verify_program_bytes(data, machine, name=path.name, out_id=r.program_id,
                                    part_id=r.part_id, job_no=mark.job_no)
            return True
        except (OSError, cp.CellFault):
            return False

    bs = BackgroundServer(workdir / "fuzz.jsonl", step, CellConfig(measure_timeout_s=60)).start()
    try:
        async def run():
            plc = PlcSim("127.0.0.1", bs.port, disconnect_prob=p_drop, seed=seed,
                         request_timeout_s=0.5, reconnect_timeout_s=30)
            try:
                for i in range(n_cycles):
                    part = i + 1
                    sc = {k: _pick(rng, k) for k in _W}
                    plan[part] = sc
                    prepare(part, sc)
                    plc.part_id, plc.program_id = part, sc["program"]
                    n_res, n_rej = len(plc.report.results), len(plc.report.rejected)
                    await plc.cycle()
                    counts["cycles"] += 1
                    if len(plc.report.rejected) > n_rej and \
                            plc.report.rejected[-1] == ("START", "BAD_PROGRAM_ID"):
                        counts["start_refused"] += 1
                    if len(plc.report.results) > n_res:
                        r = plc.report.results[-1]
                        counts["results"] += 1
                        if r.go:
                            counts["go"] += 1
                            if not check_go(r):
                                counts["go_without_verified_program"] += 1
                        else:
                            for b in NoGo:
                                if r.nogo & b:
                                    counts["nogo"][b.name] = counts["nogo"].get(b.name, 0) + 1
                    for p, data in protected.items():
                        now = None if p.is_dir() else (p.read_bytes() if p.exists() else b"")
                        if now != data:
                            counts["protected_changed"] += 1
            finally:
                plc._drop()
            return plc.report
        rep = asyncio.run(run())
    finally:
        bs.stop()
        log.removeHandler(tb)
    for _, code in rep.faults:
        name = Fault(code).name if code in Fault._value2member_map_ else str(code)
        counts["faults"][name] = counts["faults"].get(name, 0) + 1
    counts["tracebacks"] = Tracebacks.n
    counts["duplicates"] = rep.duplicates
    return counts


def fuzz_markdown(c: dict, seed: int, elapsed: float) -> str:
    faults = ", ".join(f"{k} {v}" for k, v in sorted(c["faults"].items())) or "none"
    nogo = ", ".join(f"{k} {v}" for k, v in sorted(c["nogo"].items())) or "none"
    ok = not (c["go_without_verified_program"] or c["protected_changed"] or c["tracebacks"]
              or c["duplicates"])
    return f"""**Fuzzed cell runs** (`python benchmarks/bench_cell.py --fuzz {c['cycles']} --seed {seed}`,
{elapsed:.0f} s): {c['cycles']} load cycles over loopback with random part programs, targets,
directories, program numbers, edits between writing and publishing and connection drops.

| count | value |
|---|---|
| GO without a verified program for this blank on disk | **{c['go_without_verified_program']}** |
| protected files (shop programs, edited cell programs, directories) changed | **{c['protected_changed']}** |
| tracebacks logged | **{c['tracebacks']}** |
| results / GO | {c['results']} / {c['go']} |
| NO-GO reasons | {nogo} |
| faults | {faults} |
| START refused (number outside the range) | {c['start_refused']} |

Verdict: **{'PASS' if ok else 'FAIL'}**."""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=1000, help="acceptance load cycles (1000)")
    ap.add_argument("--restart-every", type=int, default=100)
    ap.add_argument("--drop", type=float, default=0.02,
                    help="probability the PLC drops its connection around a request (0.02)")
    ap.add_argument("--handshake-cycles", type=int, default=500)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--quick", action="store_true", help="small run, do not write the docs")
    ap.add_argument("--fuzz", type=int, metavar="N",
                    help="only C: N fuzzed cycles; writes the counts to docs/cell.md")
    args = ap.parse_args(argv)
    if args.fuzz:
        import logging
        logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
        logging.getLogger("mtcomp.cell").setLevel(logging.ERROR)
        sys.path.insert(0, str(HERE))
        from _report import update_section
        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory() as tmp:
            c = fuzz(args.fuzz, args.seed, Path(tmp))
        md = fuzz_markdown(c, args.seed, time.perf_counter() - t0)
        print(json.dumps(c), file=sys.stderr)
        print(md)
        if not args.quick:
            update_section("cell_fuzz", md, HERE.parent / "docs" / "cell.md")
        return 0 if "**PASS**" in md else 1
    if args.quick:
        args.cycles, args.restart_every, args.handshake_cycles = 60, 20, 100
    import logging
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)  # dropped connections are the test
    sys.path.insert(0, str(HERE))
    from _report import machine_line, update_section
    from mtcomp.cell.registers import OUT_BLOCK

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        print(f"A: {args.cycles} cycles, kill -9 every {args.restart_every}, drop {args.drop}",
              file=sys.stderr)
        rep, chk, elapsed, kills = acceptance(args.cycles, args.restart_every, args.drop,
                                              args.seed, work)
        ok = (chk["journal_results"] == chk["plc_results"] == rep.cycles - len(rep.faults)
              and not any(chk[k] for k in ("taken_twice", "lost", "invented", "acked_twice",
                                           "not_acked", "value_mismatch",
                                           "duplicates_after_ack")))
        print(json.dumps(chk), rep.summary(), f"{elapsed:.1f} s", "PASS" if ok else "FAIL",
              file=sys.stderr)
        print("B: handshake", file=sys.stderr)
        hs = {f: handshake(args.handshake_cycles, f, work) for f in (True, False)}
        rt = round_trip(1000, work)
        ja = journal_append(500, work)
    load = os.getloadavg()
    us = 1e6
    rs = chk["restarts_while"]
    md = f"""## cell: Modbus TCP bridge (`benchmarks/bench_cell.py`)

{machine_line()} Server = `mtcomp cell serve` in its own process, PLC = `mtcomp.cell.plcsim`
in another, loopback TCP, pymodbus on both sides. Load average during the run (1 min):
{load[0]:.1f} on {os.cpu_count()} cores (other jobs shared the machine; the handshake figures are
upper bounds of what a quiet machine needs).

**A. Exactly once under disconnects and crashes.** {rep.cycles} load cycles with the virtual
cell (robot placement, virtual probing, bowl fit, frame); the PLC dropped its connection around
{args.drop:.0%} of its requests ({rep.disconnects} drops, {rep.reconnects} reconnects) and the
server was killed with SIGKILL after every {args.restart_every}th cycle at a random moment
({len(kills)} kills: {rs['busy']} while measuring, {rs['ready']} with a result waiting for its
ACK, {rs['idle']} idle), restarted on the same journal. Wall time {elapsed:.1f} s.

| check | count |
|---|---|
| results in the journal | {chk['journal_results']} |
| results taken over by the PLC | {chk['plc_results']} |
| taken over twice / presented again after the ACK | {chk['taken_twice']} / {chk['duplicates_after_ack']} |
| lost (journaled, never taken over) / invented | {chk['lost']} / {chk['invented']} |
| values differing from the journal (float32) | {chk['value_mismatch']} |
| ACKed twice / never ACKed | {chk['acked_twice']} / {chk['not_acked']} |
| faults | {len(rep.faults)} |

Verdict: **{'PASS' if ok else 'FAIL'}**.

**B. Handshake, probing excluded** ({args.handshake_cycles} cycles, measurement step returning at
once, PLC polling back to back). A cycle is START, poll, take over, ACK, unload: 7 or more
Modbus requests and three journal records.

| journal | cycles/s | result write latency p50 | p99 |
|---|---|---|---|
| fsync (product) | {hs[True][0]:.0f} | {hs[True][1] * us:.0f} µs | {hs[True][2] * us:.0f} µs |
| no fsync (baseline) | {hs[False][0]:.0f} | {hs[False][1] * us:.0f} µs | {hs[False][2] * us:.0f} µs |

Result write latency: from the measurement step returning in the server to the PLC's first read
that shows the result (journal append + fsync, register update, PLC poll). Floor: one bare Modbus
write (9 registers) + read ({OUT_BLOCK[1] - OUT_BLOCK[0]} registers) round trip takes {rt[0] * us:.0f} µs p50,
{rt[1] * us:.0f} µs p99; one journal record written and fsync'ed {ja[0] * us:.0f} µs p50,
{ja[1] * us:.0f} µs p99.
"""
    if args.quick:
        print(md)
    else:
        update_section("cell", md)
        print(md)
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
