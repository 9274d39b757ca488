"""Client mode: mtcomp polls a PLC that is the Modbus TCP server (pymodbus 3.x, asyncio).

Same register map and cycle as server mode, placed in the PLC's holding registers from `base`:
mtcomp reads the PLC block (base+0..base+8) every `poll_s` and hands it to the cycle when it
changed, and writes the mtcomp block (base+16..base+56) whenever it changed (at least with every
heartbeat). There is nobody to answer with a Modbus exception here, so a PLC block with an
out-of-range value is logged and ignored until the PLC changes it. A read that returns fewer
(or more) registers than asked for is never taken as a partial block: the connection is dropped
and the read repeated.
"""
from __future__ import annotations

import asyncio
import logging

from .cycle import Cycle
from .registers import OUT_BLOCK, PLC_BLOCK

log = logging.getLogger("mtcomp.cell")


class CellClient:
    """Poll the PLC at host:port. `start()` starts the cycle and the poll loop; `stop()` ends
    both and closes the journal."""

    def __init__(self, cycle: Cycle, host: str, port: int = 502, base: int = 0,
                 poll_s: float = 0.05, device_id: int = 1, timeout_s: float = 1.0):
        if not 0 <= base <= 65535 - OUT_BLOCK[1]:
            raise ValueError(f"base {base} leaves no room for the {OUT_BLOCK[1]} registers")
        if not 0 <= device_id <= 255:
            raise ValueError(f"unit id {device_id} outside 0..255")
        self.cycle, self.host, self.port, self.base = cycle, host, port, base
        self.poll_s, self.device_id, self.timeout_s = poll_s, device_id, timeout_s
        self._task: asyncio.Task | None = None
        self._stopping = False
        self.connected = asyncio.Event()

    async def start(self) -> "CellClient":
        await self.cycle.start()
        self._task = asyncio.create_task(self._run())
        return self

    async def stop(self) -> None:
        # a flag as well as the cancel: a cancel that lands inside a pymodbus request can come
        # back as a ModbusIOException, which the poll loop would take for a lost connection
        self._stopping = True
        if self._task is not None:
            self._task.cancel()
            try:
                await self._task
            except asyncio.CancelledError:
                pass
        await self.cycle.stop()

    async def _run(self) -> None:
        from pymodbus.client import AsyncModbusTcpClient
        from pymodbus.exceptions import ModbusException
        client, last_in, last_out, refused = None, None, None, None
        n_in = PLC_BLOCK[1] - PLC_BLOCK[0]
        try:
            while not self._stopping:
                try:
                    if client is None or not client.connected:
                        if client is not None:
                            client.close()
                        client = AsyncModbusTcpClient(self.host, port=self.port, retries=0,
                                                      timeout=self.timeout_s, reconnect_delay=0)
                        if not await client.connect():
                            raise OSError(f"cannot connect to the PLC at {self.host}:{self.port}")
                        last_in = last_out = None
                        self.connected.set()
                    rsp = await client.read_holding_registers(self.base + PLC_BLOCK[0],
                                                              count=n_in, device_id=self.device_id)
                    if rsp.isError():
                        raise ModbusException(f"PLC refused the read: {rsp}")
                    regs = list(rsp.registers)
                    if len(regs) != n_in:
                        raise ModbusException(f"PLC answered {len(regs)} registers for a read "
                                              f"of {n_in}: not taken as a partial block")
                    if regs != last_in:
                        last_in = regs
                        bad = self.cycle.plc_write(PLC_BLOCK[0], regs)
                        if bad and regs != refused:
                            log.warning("cell: PLC block ignored: %s", bad[1])
                        refused = regs if bad else None
                    out = self.cycle.image.regs[OUT_BLOCK[0]:OUT_BLOCK[1]]
                    if out != last_out:
                        rsp = await client.write_registers(self.base + OUT_BLOCK[0], out,
                                                           device_id=self.device_id)
                        if rsp.isError():
                            raise ModbusException(f"PLC refused the write: {rsp}")
                        last_out = list(out)
                except (ModbusException, OSError, asyncio.TimeoutError) as exc:
                    if self._stopping:
                        break
                    log.warning("cell: PLC connection: %s; retrying", exc)
                    self.connected.clear()
                    if client is not None:
                        client.close()
                    client = None
                    await asyncio.sleep(max(self.poll_s, 0.1))
                    continue
                await asyncio.sleep(self.poll_s)
        finally:
            if client is not None:
                client.close()
