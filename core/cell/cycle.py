"""The load cycle behind the Modbus handshake: a state machine with timeouts, faults and a journal.

    IDLE --START--> MEASURING --(probe data in)--> COMPUTING --(result journaled)--> READY
    READY --ACK(result_seq)--> IDLE;  MEASURING/COMPUTING --timeout/error/blank removed--> FAULT
    FAULT --RESET--> IDLE;  MEASURING/COMPUTING --RESET--> IDLE (job aborted, no result)

The cycle is transport-free: the Modbus server (or the client-mode poller) hands it the PLC's
register writes (`plc_write`) and serves reads from `image`. It runs in one asyncio event loop;
the measurement step runs in a worker thread so that the bus keeps answering.

Exactly once: every command is identified by the PLC's ``command_seq`` and journaled (fsync)
before its Modbus write is answered; a repeated ``command_seq`` is a no-op, so a PLC that lost a
response simply writes the same command again. Every result gets a ``result_seq`` and is
journaled before it appears in the registers; it stays presented (also across restarts) until
the PLC acknowledges exactly that ``result_seq``.

No GO without a program: a result is a GO only if the step returned the program it wrote
(`program.write_program`) and the cycle, reading the file again right before publishing (and at
every restart while the result waits for its ACK), finds it intact, for this blank and job, and
within the travel; otherwise ``nogo`` says why. Program numbers come from the cycle's offset and
range (never wrapped); an ACK counts only from the connection that read the result.
"""
from __future__ import annotations

import asyncio
import logging
import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from .._io import MtcompError
from .journal import Journal, replay
from .program import DEFAULT_OFFSET, DEFAULT_RANGE, CellFault, ProgramInfo, recheck, target_number
from .registers import (FIELDS, POSE_NAMES, Command, CommandStatus, Fault, NoGo,
                        RegisterImage, State, check_plc_write)

log = logging.getLogger("mtcomp.cell")


@dataclass(frozen=True)
class Job:
    """One blank to measure. `on_phase` (not journaled) lets the measurement step report
    that probing is done and computation started: call ``job.on_phase("computing")``.
    `out_program_id` is the number the compensated program must get (the cycle derives it from
    its program offset and range; None outside a cycle: `program.DEFAULT_OFFSET` applies)."""
    job_no: int
    part_id: int
    program_id: int
    on_phase: Callable[[str], None] | None = field(default=None, compare=False, repr=False)
    out_program_id: int | None = None

    def to_dict(self) -> dict:
        return {"job_no": self.job_no, "part_id": self.part_id, "program_id": self.program_id,
                "out_program_id": self.out_program_id}


@dataclass(frozen=True)
class CellResult:
    """What the measurement step returns.

    pose6: workpiece setting (dx, dy, dz mm, a, b, c deg) with x_nominal = R x_real + d,
    R = Rz(c) Ry(b) Rx(a); sigma6: its standard uncertainties (same units); program_id: the
    compensated NC program; ok: False if the step itself judges the part unusable (no-go);
    info: JSON-serialisable extras journaled with the result (e.g. fit residuals in mm);
    program: the program as written and verified (`program.write_program`), None if the step
    wrote none. Without a program the result is always a no-go: the cell never says GO for a
    program it has not written and verified for this blank.
    """
    pose6: tuple
    sigma6: tuple
    program_id: int
    ok: bool = True
    info: dict = field(default_factory=dict)
    program: ProgramInfo | None = None

    def summary(self) -> str:
        p, s = self.pose6, self.sigma6
        lin = ", ".join(f"{n}={p[i] * 1e3:+.2f}±{s[i] * 1e3:.2f} µm" for i, n in
                        enumerate(POSE_NAMES[:3]))
        ang = ", ".join(f"{n}={p[i + 3] * 3600:+.1f}±{s[i + 3] * 3600:.1f}\"" for i, n in
                        enumerate(POSE_NAMES[3:]))
        return f"program {self.program_id}: {lin}; {ang}; {'ok' if self.ok else 'NOT ok'}"


MeasureFn = Callable[[Job], CellResult]


@dataclass(frozen=True)
class CellConfig:
    """Cycle settings. Limits decide go/no-go; timeouts in s; word_order of 32-bit values."""
    word_order: str = "big"
    measure_timeout_s: float = 300.0
    heartbeat_s: float = 0.1
    limit_mm: float = 0.5          # go only if |dx|, |dy|, |dz| <= limit_mm
    limit_deg: float = 0.5         # ... and |a|, |b|, |c| <= limit_deg
    sigma_limit_mm: float = 0.005  # ... and the translation uncertainties <= this
    fsync: bool = True             # False only for benchmarks of the fsync cost
    program_offset: int = DEFAULT_OFFSET        # compensated program = program_id + offset ...
    program_range: tuple = DEFAULT_RANGE        # ... which must lie in this range (inclusive)
    program_check: Callable | None = field(default=None, compare=False)  # extra verification

    def __post_init__(self):
        from .program import check_numbering
        check_numbering(self.program_offset, self.program_range)


def nogo_bits(res: CellResult, cfg: CellConfig, program_ok: bool = True) -> int:
    """Why a result is a no-go (registers.NoGo bits; 0 = go)."""
    p, s = res.pose6, res.sigma6
    bits = 0
    if not (all(abs(v) <= cfg.limit_mm for v in p[:3])
            and all(abs(v) <= cfg.limit_deg for v in p[3:])):
        bits |= NoGo.LIMITS
    if not all(v <= cfg.sigma_limit_mm for v in s[:3]):
        bits |= NoGo.UNCERTAINTY
    if not res.ok:
        bits |= NoGo.STEP
    if res.program is None:
        bits |= NoGo.NO_PROGRAM
    elif not program_ok:
        bits |= NoGo.NOT_VERIFIED
    return int(bits)


def is_go(res: CellResult, cfg: CellConfig) -> bool:
    """Go: setting and uncertainty within the limits, the step content, and a program written
    (whether it is still intact on disk is checked when the result is published)."""
    return nogo_bits(res, cfg) == 0


def _same_or_successor(first, peer) -> bool:
    """`peer` is the connection `first`, or a later one from the same address after `first`
    closed. Peers are the server's connection tokens (attributes ``address`` and ``closed``);
    anything else compares by identity only."""
    if first is peer:
        return True
    addr = getattr(first, "address", None)
    return addr is not None and addr == getattr(peer, "address", None) and getattr(first, "closed", False)


class Cycle:
    """State machine + journal + register image. Create, `await start()`, `await stop()`."""

    def __init__(self, journal_path: str | Path, measure_and_compute: MeasureFn,
                 config: CellConfig = CellConfig()):
        self.config = config
        self.measure = measure_and_compute
        self.image = RegisterImage(config.word_order)
        self.journal = Journal.open(journal_path, fsync=config.fsync)
        self.journal_ok = True
        rec = replay(self.journal.records)
        self._job_no, self._result_seq = rec.job_no, rec.result_seq
        self._job: dict | None = None          # running job (busy states)
        self._presented: dict | None = None    # result record waiting for ACK
        self._task: asyncio.Task | None = None
        self._hb_task: asyncio.Task | None = None
        self._pool: ThreadPoolExecutor | None = None
        self._readers: list = []                # connections that read the presented result
        self._owner = None                      # connection that started the running/presented job
        self.publish_latency: list[float] = []  # s from step return to registers (benchmarks)
        img = self.image
        img.set("cmd_seq_echo", rec.cmd_seq)
        img.set("cmd_status", rec.cmd_status)
        img.set("job_no", rec.job_no)
        revoke = None
        if rec.state == "ready" and rec.result.get("go") and rec.result.get("program"):
            revoke = self._recheck_journaled(rec.result)
            if revoke is not None:
                rec.result = {**rec.result, "go": False,
                              "nogo": rec.result.get("nogo", 0) | NoGo.NOT_VERIFIED}
                rec.last_result = rec.result
        if rec.last_result is not None:
            self._show_result(rec.last_result)
        if rec.state == "busy":
            self._job = rec.job
            self._set_state(State.MEASURING)
        elif rec.state == "ready":
            self._presented = rec.result
            self._set_state(State.READY)
        elif rec.state == "fault":
            self._set_state(State.FAULT, rec.fault)
        try:
            self.journal.append("boot", state=rec.state,
                                resume=rec.job["job_no"] if rec.state == "busy" else None,
                                result_seq=rec.result_seq)
            if revoke is not None:
                log.error("cell: result %d: its program failed the check at restart, NO-GO: %s",
                          rec.result["result_seq"], revoke)
                self.journal.append("revoke", result_seq=rec.result["result_seq"],
                                    nogo=int(NoGo.NOT_VERIFIED), why=revoke)
        except BaseException:
            self.journal.close()
            raise
        log.info("cell: journal %s replayed (%d records): %s", self.journal.path,
                 len(self.journal.records), rec.state)

    def _recheck_journaled(self, result: dict) -> str | None:
        """A presented GO is published again at every restart: check its program again."""
        p = result["program"]
        try:
            info = ProgramInfo(p["path"], p["program_id"], p["source_id"], p["part_id"],
                               p["job_no"], p["sha256"], p["crc32"], p["size"], p["blocks"],
                               p["machine"])
        except (KeyError, TypeError) as exc:
            return f"journaled program record incomplete ({exc})"
        return recheck(info, extra_check=self.config.program_check)

    # -- life cycle -------------------------------------------------------------------------
    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._pool = ThreadPoolExecutor(max_workers=2, thread_name_prefix="mtcomp-cell")
        self._hb_task = asyncio.create_task(self._heartbeat())
        if self._job is not None:  # restart mid-cycle: measure the same blank again
            log.info("cell: resuming job %d after restart", self._job["job_no"])
            self._launch(self._job)

    async def stop(self) -> None:
        for t in (self._task, self._hb_task):
            if t is not None and not t.done():
                t.cancel()
                try:
                    await t
                except (asyncio.CancelledError, Exception):
                    pass
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
        self.journal.close()

    @property
    def state(self) -> State:
        return State(self.image.get("state"))

    # -- PLC side ---------------------------------------------------------------------------
    def note_read(self, peer, address: int, count: int) -> None:
        """A connection `peer` read `count` registers from `address`: if that covered
        ``result_seq`` of a presented result, the peer may ACK it (see `may_ack`)."""
        f = FIELDS["result_seq"]
        if peer is not None and self._presented is not None and \
                address <= f.address and f.address + f.size <= address + count and \
                not any(r is peer for r in self._readers):
            self._readers.append(peer)

    def may_ack(self, peer) -> bool:
        """The connection that read the result may ACK it; so may a later connection from the
        same address once that reader has closed (a PLC that reconnects, or a tool such as
        mbpoll that opens one connection per request). A client that never read the result,
        while the reader is still connected, may not. Peers are the server's connection
        tokens: attributes ``address`` and ``closed`` (anything else: same object only)."""
        if peer is None:
            return True
        for r in self._readers:
            if _same_or_successor(r, peer):
                return True
        return False

    def owns_job(self, peer) -> bool:
        """The result belongs to the connection that started the job (START): only that
        connection, or after it closed a connection from its address, may ACK it. A second
        allowed client (an HMI, a diagnostic tool) may read the result but cannot take it away
        from the PLC. No owner (client mode, or a job resumed after a restart): any peer."""
        return peer is None or self._owner is None or _same_or_successor(self._owner, peer)

    def plc_write(self, address: int, values: list[int], peer=None) -> tuple[int, str] | None:
        """Apply a PLC write; returns (Modbus exception code, reason) to refuse it, else None.

        `peer` identifies the connection (server mode): an ACK is accepted only from a
        connection that has read the presented result (`note_read`). None (client mode: the
        PLC is the only party) skips that check. Called from the event loop, so it never
        interleaves with a result being published.
        """
        bad = check_plc_write(address, values)
        if bad:
            log.warning("cell: refused PLC write at %d %s: %s", address, list(values), bad[1])
            return bad
        end = address + len(values)
        regs = self.image.regs
        regs[address:end] = [int(v) for v in values]
        bl = FIELDS["blank_loaded"].address
        if address <= bl < end and regs[bl] == 0 and self.state in (State.MEASURING,
                                                                   State.COMPUTING):
            self._fault(Fault.BLANK_REMOVED, "PLC cleared blank_loaded during the measurement")
        seq_addr = FIELDS["command_seq"].address
        if address <= seq_addr < end and regs[seq_addr] != self.image.get("cmd_seq_echo"):
            return self._command(Command(regs[FIELDS["command"].address]), regs[seq_addr], peer)
        return None

    def _command(self, cmd: Command, seq: int, peer=None) -> tuple[int, str] | None:
        img = self.image
        if not self.journal_ok:
            return 4, "journal unavailable: command not accepted"
        if cmd == Command.NONE:  # nothing to do, but the echo must survive a restart too
            return self._reject(cmd, seq, CommandStatus.OK)
        state = self.state
        try:
            if cmd == Command.START:
                if state != State.IDLE:
                    return self._reject(cmd, seq, CommandStatus.NOT_ALLOWED)
                if img.get("blank_loaded") != 1:
                    return self._reject(cmd, seq, CommandStatus.BLANK_NOT_LOADED)
                cfg = self.config
                out = target_number(img.get("program_id"), cfg.program_offset, cfg.program_range)
                if out is None:  # 0, or its compensated number would leave the shop's range
                    return self._reject(cmd, seq, CommandStatus.BAD_PROGRAM_ID)
                job = Job(self._job_no + 1, img.get("part_id"), img.get("program_id"),
                          out_program_id=out).to_dict()
                self.journal.append("start", cmd_seq=seq, status=0, job=job)
                self._job_no += 1
                self._job = job
                self._owner = peer
                img.set("job_no", job["job_no"])
                img.set("fault_code", 0)
                self._set_state(State.MEASURING)
                self._launch(job)
            elif cmd == Command.ACK:
                ack = img.get("ack_seq")
                if state != State.READY:
                    return self._reject(cmd, seq, CommandStatus.NOT_ALLOWED)
                if self._presented is None or ack != self._presented["result_seq"]:
                    return self._reject(cmd, seq, CommandStatus.BAD_ACK_SEQ)
                if not self.may_ack(peer):
                    return self._reject(cmd, seq, CommandStatus.NOT_READ)
                if not self.owns_job(peer):
                    return self._reject(cmd, seq, CommandStatus.NOT_OWNER)
                self.journal.append("ack", cmd_seq=seq, status=0, result_seq=ack)
                self._presented = None
                self._owner = None
                self._set_state(State.IDLE)
            elif cmd == Command.RESET:
                if state == State.FAULT:
                    self.journal.append("reset", cmd_seq=seq, status=0)
                elif state in (State.MEASURING, State.COMPUTING):
                    self.journal.append("abort", cmd_seq=seq, status=0, job=self._job)
                    self._cancel_job()
                else:  # IDLE: nothing to reset; READY: the result must be acknowledged first
                    return self._reject(cmd, seq, CommandStatus.NOT_ALLOWED)
                self._job = None
                self._set_state(State.IDLE)
        except OSError as exc:
            self._journal_failed(exc)
            return 4, f"journal write failed: {exc}"
        img.set("cmd_seq_echo", seq)
        img.set("cmd_status", CommandStatus.OK)
        return None

    def _reject(self, cmd: Command, seq: int, status: CommandStatus):
        """Journal and echo a command that has no effect (rejected, or NONE)."""
        if status != CommandStatus.OK:
            log.warning("cell: %s (seq %d) rejected in state %s: %s", cmd.name, seq,
                        self.state.name, status.name)
        try:
            self.journal.append("command", cmd_seq=seq, command=int(cmd), status=int(status))
        except OSError as exc:
            self._journal_failed(exc)
            return 4, f"journal write failed: {exc}"
        self.image.set("cmd_seq_echo", seq)
        self.image.set("cmd_status", status)
        return None

    # -- measurement ------------------------------------------------------------------------
    def _launch(self, job: dict) -> None:
        self._task = asyncio.create_task(self._run(job))

    def _cancel_job(self) -> None:
        if self._task is not None and not self._task.done():
            self._task.cancel()
        self._task = None

    async def _run(self, job: dict) -> None:
        loop = self._loop

        def on_phase(name: str) -> None:  # called from the worker thread
            if name == "computing":
                loop.call_soon_threadsafe(self._phase_computing, job["job_no"])

        stamp = {}
        out_id = job.get("out_program_id") or target_number(
            job["program_id"], self.config.program_offset, self.config.program_range)

        def work():
            res = self.measure(Job(job["job_no"], job["part_id"], job["program_id"], on_phase,
                                   out_program_id=out_id))
            # the program as it is on disk now, checked again in full just before publishing
            prog = getattr(res, "program", None)
            why = None
            if prog is not None:
                if not isinstance(prog, ProgramInfo):
                    why = "the step returned no ProgramInfo"
                elif (prog.part_id, prog.job_no, prog.program_id) != \
                        (job["part_id"], job["job_no"], out_id):
                    why = (f"program O{prog.program_id:04d} is for part {prog.part_id} job "
                           f"{prog.job_no}, not O{out_id:04d} part {job['part_id']} job "
                           f"{job['job_no']}")
                else:
                    why = recheck(prog, extra_check=self.config.program_check)
            stamp["t"] = time.perf_counter()
            return res, why

        try:
            res, not_verified = await asyncio.wait_for(loop.run_in_executor(self._pool, work),
                                                       self.config.measure_timeout_s)
        except asyncio.TimeoutError:
            if self._job is job:
                self._fault(Fault.MEASURE_TIMEOUT,
                            f"no result within {self.config.measure_timeout_s} s")
            return
        except asyncio.CancelledError:
            raise
        except CellFault as exc:      # a refusal with its own code: one line, no traceback
            if self._job is job:
                self._fault(exc.code, str(exc))
            return
        except MtcompError as exc:    # bad probe data, fit refused, ...: one line
            if self._job is job:
                self._fault(Fault.MEASURE_FAILED, str(exc))
            return
        except Exception as exc:  # a bug in the step: a fault code, and the traceback in the log
            log.exception("cell: measurement of job %d failed", job["job_no"])
            if self._job is job:
                self._fault(Fault.MEASURE_FAILED, f"{type(exc).__name__}: {exc}")
            return
        if self._job is not job:  # aborted or faulted meanwhile
            return
        try:
            pose = tuple(float(v) for v in res.pose6)
            sigma = tuple(float(v) for v in res.sigma6)
            if len(pose) != 6 or len(sigma) != 6 or not all(map(math.isfinite, pose + sigma)):
                raise ValueError("need 6 finite pose values and 6 sigmas")
            nogo = nogo_bits(res, self.config, program_ok=not_verified is None)
        except (TypeError, ValueError, AttributeError) as exc:
            self._fault(Fault.BAD_RESULT, str(exc))
            return
        if not_verified is not None:
            log.error("cell: job %d: program not verified, NO-GO: %s", job["job_no"],
                      not_verified)
        self._publish(job, res, pose, sigma, nogo, not_verified, stamp.get("t"))

    def _phase_computing(self, job_no: int) -> None:
        if self._job is not None and self._job["job_no"] == job_no \
                and self.state == State.MEASURING:
            self._set_state(State.COMPUTING)

    def _publish(self, job, res, pose, sigma, nogo, not_verified, t_done) -> None:
        seq = self._result_seq + 1
        prog = res.program if isinstance(res.program, ProgramInfo) else None
        program = None
        if prog is not None:
            program = prog.to_dict()
            program["verified"] = not_verified is None
            if not_verified is not None:
                program["why"] = not_verified
        try:
            # no program, no number: the PLC must not start whatever carries the number
            rec = self.journal.append("result", result_seq=seq, job=job, pose=list(pose),
                                      sigma=list(sigma),
                                      program_id=prog.program_id if prog else 0,
                                      go=nogo == 0, nogo=nogo, program=program, info=res.info)
        except (OSError, TypeError, ValueError) as exc:  # Type/ValueError: info not JSON
            if isinstance(exc, OSError):
                self._journal_failed(exc)
            else:
                self._fault(Fault.BAD_RESULT, f"result not journalable: {exc}")
            return
        self._result_seq = seq
        self._presented = rec
        self._readers = []
        self._job = None
        self._show_result(rec)
        self._set_state(State.READY)
        if t_done is not None:
            self.publish_latency.append(time.perf_counter() - t_done)

    # -- helpers ----------------------------------------------------------------------------
    def _show_result(self, rec: dict) -> None:
        img = self.image
        for n, v in zip(POSE_NAMES, rec["pose"]):
            img.set(n, v)
        for n, v in zip(POSE_NAMES, rec["sigma"]):
            img.set(f"s_{n}", v)
        img.set("program_id_out", rec["program_id"])
        img.set("part_id_out", rec["job"]["part_id"])
        img.set("go", 1 if rec["go"] else 0)
        img.set("result_seq", rec["result_seq"])
        prog = rec.get("program")
        img.set("program_crc", prog["crc32"] if prog else 0)
        # journals of map version 1 have no nogo: say "unknown" (bit 15) for their no-gos
        img.set("nogo", rec.get("nogo", 0 if rec["go"] else 0x8000))

    def _set_state(self, state: State, fault: int = 0) -> None:
        self.image.set("state", state)
        self.image.set("fault_code", fault)

    def _fault(self, code: Fault, why: str) -> None:
        log.error("cell: fault %d %s: %s", code, code.name, why)
        job = self._job
        if self._task is not None and self._task is not asyncio.current_task():
            self._cancel_job()
        self._job = None
        self._set_state(State.FAULT, code)
        try:
            self.journal.append("fault", code=int(code), name=code.name, why=why, job=job)
        except OSError as exc:
            self._journal_failed(exc)

    def _journal_failed(self, exc: OSError) -> None:
        log.error("cell: journal %s cannot be written (%s): refusing all commands",
                  self.journal.path, exc)
        self.journal_ok = False
        self._job = None
        self._set_state(State.FAULT, Fault.JOURNAL_FAILED)

    async def _heartbeat(self) -> None:
        while True:
            await asyncio.sleep(self.config.heartbeat_s)
            self.image.set("heartbeat", self.image.get("heartbeat") + 1)

