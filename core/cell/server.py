"""mtcomp as the Modbus TCP server the cell PLC polls (pymodbus 3.x, asyncio).

pymodbus keeps its own copy of the registers; we hook its per-request `action` callback
(`pymodbus.simulator.SimDevice`, the datastore API that replaces the deprecated
ModbusServerContext in pymodbus 3.10+): reads copy the cycle's register image into the reply,
writes are validated and handed to the cycle, which may refuse them with an exception code.
Coil and discrete-input function codes are answered with ILLEGAL FUNCTION: the map is
registers only.
"""
from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass
from pathlib import Path

from .._io import MtcompError
from .cycle import CellConfig, CellResult, Cycle, MeasureFn
from .registers import N_REGISTERS

log = logging.getLogger("mtcomp.cell")

READ_FCS = (3, 4, 6, 16, 23)   # 6/16/23 read back after writing (pymodbus does that internally)
WRITE_FCS = (6, 16, 23)


class CellServer:
    """A cycle exposed on Modbus TCP. Binds 127.0.0.1 unless `host` says otherwise; port 0
    picks a free port (see `.port` after `start`). Answers every unit id."""

    def __init__(self, cycle: Cycle, host: str = "127.0.0.1", port: int = 502):
        self.cycle, self.host, self.port = cycle, host, port
        self._server = None

    async def start(self) -> "CellServer":
        from pymodbus.server import ModbusTcpServer
        from pymodbus.simulator import DataType, SimData, SimDevice
        await self.cycle.start()
        device = SimDevice(id=0, simdata=[SimData(address=0, values=[0] * N_REGISTERS,
                                                  datatype=DataType.REGISTERS)],
                           action=self._action)
        self._server = ModbusTcpServer(device, address=(self.host, self.port))
        await self._server.serve_forever(background=True)
        self.port = self._server.transport.sockets[0].getsockname()[1]
        log.info("cell: Modbus TCP server on %s:%d", self.host, self.port)
        return self

    async def stop(self) -> None:
        """Close the listening socket and every connection, stop the cycle, close the journal.
        A running measurement is abandoned as in a crash (the journal resumes it)."""
        if self._server is not None:
            await self._server.shutdown()
            self._server = None
        await self.cycle.stop()

    async def __aenter__(self):
        return await self.start()

    async def __aexit__(self, *exc):
        await self.stop()

    async def _action(self, fc, start, address, count, regs, values):
        from pymodbus.constants import ExcCodes
        if values is None and fc in READ_FCS:
            regs[address - start:address - start + count] = \
                self.cycle.image.regs[address:address + count]
            return None
        if values is not None and fc in WRITE_FCS:
            bad = self.cycle.plc_write(address, list(values))
            return ExcCodes(bad[0]) if bad else None
        log.warning("cell: function code %d refused (registers only)", fc)
        return ExcCodes.ILLEGAL_FUNCTION


class BackgroundServer:
    """A CellServer running in its own thread and event loop, for tests, benchmarks and
    notebooks: `start()` returns once it listens, `stop()` once it is down, `restart()` drops
    everything (as a crash would, minus the process) and serves again from the same journal on
    the same port. Use as a context manager so it always stops."""

    def __init__(self, journal: str | Path, measure_and_compute: MeasureFn,
                 config: CellConfig = CellConfig(), host: str = "127.0.0.1", port: int = 0):
        self.journal, self.measure, self.config = Path(journal), measure_and_compute, config
        self.host, self.port = host, port
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread = None
        self.server: CellServer | None = None

    def start(self) -> "BackgroundServer":
        import threading
        ready = threading.Event()

        def run():
            self._loop = asyncio.new_event_loop()
            asyncio.set_event_loop(self._loop)
            ready.set()
            self._loop.run_forever()
            self._loop.close()

        self._thread = threading.Thread(target=run, name="mtcomp-cell-server", daemon=True)
        self._thread.start()
        ready.wait()
        try:
            self._serve()
        except BaseException:
            self.stop()
            raise
        return self

    def _serve(self) -> None:
        async def up():
            srv = CellServer(Cycle(self.journal, self.measure, self.config), self.host, self.port)
            await srv.start()
            return srv
        self.server = self.call(up())
        self.port = self.server.port

    def call(self, coro_or_fn, timeout: float = 30.0):
        """Run a coroutine, or a plain function of the Cycle, in the server's loop; return
        its value."""
        if not asyncio.iscoroutine(coro_or_fn):
            fn = coro_or_fn

            async def wrap():
                return fn(self.server.cycle)
            coro_or_fn = wrap()
        return asyncio.run_coroutine_threadsafe(coro_or_fn, self._loop).result(timeout)

    def restart(self) -> None:
        if self.server is not None:
            self.call(self.server.stop())
            self.server = None
        self._serve()

    def stop(self) -> None:
        if self._loop is None:
            return
        try:
            if self.server is not None:
                self.call(self.server.stop())
        finally:
            self.server = None
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(10)
            self._loop = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()


@dataclass(frozen=True)
class OnceResult:
    """Outcome of `run_virtual_cell_once`: the result as the PLC read it, the journal path,
    the true placement of the blank (None unless the step is a `VirtualCell`) and the PLC
    simulator's report."""
    result: CellResult
    result_seq: int
    go: bool
    true_pose: tuple
    journal: Path
    report: object


def run_virtual_cell_once(journal: str | Path, part_id: int = 1, program_id: int = 100,
                          seed: int = 0, word_order: str = "big",
                          measure_and_compute: MeasureFn | None = None,
                          config: CellConfig | None = None, timeout_s: float = 30.0) -> OnceResult:
    """Start the server and the PLC simulator on loopback, run one load cycle, stop both.

    Returns what the PLC received (decoded from the registers) and the journal path; the
    journal is appended to, so repeated calls continue its sequence numbers (its directory
    must exist).
    """
    from .plcsim import PlcSim
    from .virtual import VirtualCell, robot_placement
    measure = measure_and_compute or VirtualCell(seed=seed)
    cfg = config or CellConfig(word_order=word_order)

    async def main():
        server = CellServer(Cycle(journal, measure, cfg), port=0)
        await server.start()
        try:
            plc = PlcSim("127.0.0.1", server.port, word_order=cfg.word_order,
                         first_part_id=part_id, program_id=program_id)
            return await asyncio.wait_for(plc.run(1), timeout_s)
        finally:
            await server.stop()

    report = asyncio.run(main())
    if not report.results:
        raise MtcompError(f"the cycle produced no result (faults: {report.faults})")
    got = report.results[0]
    res = CellResult(got.pose, got.sigma, got.program_id)
    # the truth is known only to the virtual cell (its own seed and robot model)
    truth = (tuple(float(v) for v in robot_placement(part_id, measure.seed, measure.robot))
             if isinstance(measure, VirtualCell) else None)
    return OnceResult(res, got.result_seq, got.go, truth, Path(journal), report)
