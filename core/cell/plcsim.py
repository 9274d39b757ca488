"""A PLC simulator: plays the cell PLC against mtcomp's Modbus server, for demos and tests.

Per cycle the robot places blank `part_id` (its placement error is `virtual.robot_placement`,
which the virtual machine also uses, so results can be compared with the truth), the PLC sets
``blank_loaded``, sends START, polls until READY or FAULT, takes the result over, ACKs exactly
that ``result_seq`` and unloads. Commands carry a fresh ``command_seq``; after any connection
loss the PLC reconnects and writes the same command again (idempotent on the server side).

The simulator also checks the server: a result presented again after its ACK was confirmed is
counted in `PlcReport.duplicates` (must stay 0).
"""
from __future__ import annotations

import asyncio
import logging
import random
import time
from dataclasses import dataclass, field

from .._io import MtcompError
from .registers import (FIELDS, OUT_BLOCK, PLC_BLOCK, Command, CommandStatus, State,
                        decode_outputs, encode_u32)

log = logging.getLogger("mtcomp.cell.plc")


@dataclass(frozen=True)
class Received:
    """One result as the PLC took it over (decoded from the registers)."""
    result_seq: int
    job_no: int
    part_id: int
    program_id: int
    go: bool
    pose: tuple
    sigma: tuple
    t_seen: float  # time.perf_counter() when the PLC first read it
    nogo: int = 0          # why go is 0 (registers.NoGo bits)
    program_crc: int = 0   # CRC-32 of the compensated program file, 0 = none


@dataclass
class PlcReport:
    cycles: int = 0
    results: list = field(default_factory=list)      # Received, in order
    duplicates: int = 0                              # results presented again after their ACK
    faults: list = field(default_factory=list)       # (part_id, fault_code)
    rejected: list = field(default_factory=list)     # (command, status)
    reconnects: int = 0
    disconnects: int = 0                             # connections dropped on purpose
    cycle_times: list = field(default_factory=list)  # s per completed cycle

    def summary(self) -> str:
        return (f"{self.cycles} cycles, {len(self.results)} results, {len(self.faults)} faults, "
                f"{self.duplicates} duplicates, {self.disconnects} forced disconnects, "
                f"{self.reconnects} reconnects")


class PlcSim:
    """Simulated cell PLC (Modbus TCP client). `disconnect_prob` is the probability that the
    PLC drops its connection around any request (sometimes while the request is in flight).

    In client mode (mtcomp polls the PLC) the PLC's logic talks to its own data block; here
    that block is a plain Modbus server and `base` the register where the map starts in it.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 502, word_order: str = "big",
                 first_part_id: int = 1, program_id: int = 100, disconnect_prob: float = 0.0,
                 seed: int = 0, poll_s: float = 0.0, request_timeout_s: float = 1.0,
                 reconnect_timeout_s: float = 30.0, cycle_timeout_s: float = 120.0,
                 load_time_s: float = 0.0, device_id: int = 1, base: int = 0):
        self.host, self.port, self.word_order = host, port, word_order
        self.part_id, self.program_id = first_part_id, program_id
        self.disconnect_prob, self.poll_s = disconnect_prob, poll_s
        self.request_timeout_s, self.reconnect_timeout_s = request_timeout_s, reconnect_timeout_s
        self.cycle_timeout_s, self.load_time_s = cycle_timeout_s, load_time_s
        self.device_id = device_id
        self.base = base  # where the map starts in the server's holding registers
        self._rng = random.Random(seed)
        self._client = None
        self._connected_once = False
        self._seq: int | None = None
        self._heartbeat = 0
        self.blank_loaded = 0
        self.ack_seq = 0
        self._confirmed: set[int] = set()   # result_seqs whose ACK the server confirmed
        self._taken: set[int] = set()
        self.report = PlcReport()

    # -- connection -------------------------------------------------------------------------
    async def _connect(self) -> None:
        from pymodbus.client import AsyncModbusTcpClient
        deadline = time.monotonic() + self.reconnect_timeout_s
        while True:
            client = AsyncModbusTcpClient(self.host, port=self.port, timeout=self.request_timeout_s,
                                          retries=0, reconnect_delay=0)
            try:
                if await client.connect():
                    self._client = client
                    if self._connected_once:
                        self.report.reconnects += 1
                    self._connected_once = True
                    return
            except OSError:
                pass
            client.close()
            if time.monotonic() > deadline:
                raise MtcompError(f"PLC simulator: no Modbus server at {self.host}:{self.port}")
            await asyncio.sleep(0.02)

    def _drop(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None

    async def close(self) -> None:
        self._drop()

    async def _request(self, make):
        """Run `make(client)` until it gets a Modbus response, reconnecting on any loss."""
        from pymodbus.exceptions import ModbusException
        deadline = time.monotonic() + self.reconnect_timeout_s
        while True:
            if self._client is None or not self._client.connected:
                self._drop()
                await self._connect()
            client = self._client
            if self.disconnect_prob and self._rng.random() < self.disconnect_prob:
                self.report.disconnects += 1
                if self._rng.random() < 0.5:
                    self._drop()           # before the request
                    continue
                # ... or while it is in flight: the response (or the request) gets lost
                asyncio.get_running_loop().call_later(self._rng.uniform(0, 0.001), client.close)
            try:
                rsp = await make(client)
            except (ModbusException, OSError, asyncio.TimeoutError) as exc:
                log.debug("PLC: request failed (%s), reconnecting", exc)
                self._drop()
                if time.monotonic() > deadline:
                    raise MtcompError(f"PLC simulator: lost {self.host}:{self.port}") from None
                await asyncio.sleep(0.005)
                continue
            return rsp

    async def read(self) -> dict:
        """Read and decode the whole mtcomp -> PLC block in one request."""
        start, end = OUT_BLOCK
        rsp = await self._request(lambda c: c.read_holding_registers(
            self.base + start, count=end - start, device_id=self.device_id))
        if rsp.isError():
            raise MtcompError(f"PLC simulator: read refused: {rsp}")
        return decode_outputs(rsp.registers, self.word_order)

    async def _write(self, command: Command, seq: int) -> None:
        self._heartbeat = (self._heartbeat + 1) & 0xFFFF
        regs = [0] * (PLC_BLOCK[1] - PLC_BLOCK[0])
        f = FIELDS
        regs[f["plc_heartbeat"].address] = self._heartbeat
        regs[f["command"].address] = int(command)
        regs[f["command_seq"].address] = seq
        regs[f["blank_loaded"].address] = self.blank_loaded
        a = f["part_id"].address
        regs[a:a + 2] = encode_u32(self.part_id, self.word_order)
        regs[f["program_id"].address] = self.program_id
        a = f["ack_seq"].address
        regs[a:a + 2] = encode_u32(self.ack_seq, self.word_order)
        rsp = await self._request(lambda c: c.write_registers(self.base + PLC_BLOCK[0], regs,
                                                              device_id=self.device_id))
        if rsp.isError():
            raise MtcompError(f"PLC simulator: write refused: {rsp}")

    async def command(self, command: Command) -> tuple[CommandStatus, dict]:
        """Send one command with a fresh command_seq; return its status once echoed."""
        if self._seq is None:  # PLC cold start: continue after the server's last command
            self._seq = (await self.read())["cmd_seq_echo"]
        self._seq = self._seq % 65535 + 1
        seq = self._seq
        deadline = time.monotonic() + self.reconnect_timeout_s
        while True:
            if time.monotonic() > deadline:
                raise MtcompError(f"PLC simulator: {command.name} (seq {seq}) not taken within "
                                  f"{self.reconnect_timeout_s} s")
            await self._write(command, seq)
            out = await self.read()
            if out["cmd_seq_echo"] == seq:
                status = CommandStatus(out["cmd_status"])
                if status != CommandStatus.OK:
                    self.report.rejected.append((command.name, status.name))
                return status, out
            # not taken (yet): the server restarted before journaling it, or mtcomp polls us
            # (client mode); writing the same command_seq again is harmless
            await asyncio.sleep(self.poll_s)

    # -- the cycle --------------------------------------------------------------------------
    async def _take_over(self, out: dict) -> None:
        seq = out["result_seq"]
        if seq in self._confirmed:
            self.report.duplicates += 1
            log.error("PLC: result %d presented again after its ACK was confirmed", seq)
        elif seq not in self._taken:
            self._taken.add(seq)
            self.report.results.append(Received(
                seq, out["job_no"], out["part_id_out"], out["program_id_out"], bool(out["go"]),
                out["pose"], out["sigma"], time.perf_counter(), out["nogo"], out["program_crc"]))
        self.ack_seq = seq
        deadline = time.monotonic() + self.reconnect_timeout_s
        status, out = await self.command(Command.ACK)
        # NOT_READ: the ACK went out on a new connection (after a drop) that has not read the
        # result; command() has just read it on this one, so the same ACK again is taken
        while status == CommandStatus.NOT_READ and out["result_seq"] == seq \
                and State(out["state"]) == State.READY and time.monotonic() < deadline:
            status, out = await self.command(Command.ACK)
        if status == CommandStatus.OK or State(out["state"]) == State.IDLE:
            self._confirmed.add(seq)

    async def cycle(self) -> None:
        t0 = time.perf_counter()
        out = await self.read()
        # leftovers of an earlier session: a result waiting for its ACK, or a fault
        if State(out["state"]) == State.READY:
            await self._take_over(out)
        elif State(out["state"]) == State.FAULT:
            await self.command(Command.RESET)
        if self.load_time_s:
            await asyncio.sleep(self.load_time_s)      # robot places the blank
        self.blank_loaded = 1
        status, out = await self.command(Command.START)
        deadline = time.monotonic() + self.cycle_timeout_s
        while status == CommandStatus.OK:
            state = State(out["state"])
            if state == State.READY:  # (a result ACKed before would count as a duplicate)
                await self._take_over(out)
                break
            if state == State.FAULT:
                self.report.faults.append((self.part_id, out["fault_code"]))
                await self.command(Command.RESET)
                break
            if state == State.IDLE:  # aborted by a RESET from another client
                self.report.faults.append((self.part_id, 0))
                break
            if time.monotonic() > deadline:
                raise MtcompError(f"PLC simulator: no result for part {self.part_id} within "
                                  f"{self.cycle_timeout_s} s (state {state.name})")
            if self.poll_s:
                await asyncio.sleep(self.poll_s)
            else:
                await asyncio.sleep(0)
            out = await self.read()
        self.blank_loaded = 0                           # the robot takes the part away
        await self._write(Command.NONE, self._seq)      # same seq: no new command
        self.report.cycles += 1
        self.report.cycle_times.append(time.perf_counter() - t0)
        self.part_id += 1

    async def run(self, n_cycles: int, progress=None) -> PlcReport:
        """Run `n_cycles` load cycles; `progress(i, report)` is called after each."""
        try:
            for i in range(n_cycles):
                await self.cycle()
                if progress is not None:
                    progress(i + 1, self.report)
        finally:
            self._drop()
        return self.report
