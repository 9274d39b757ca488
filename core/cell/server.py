"""mtcomp as the Modbus TCP server the cell PLC polls (pymodbus 3.x, asyncio).

pymodbus keeps its own copy of the registers; we hook its per-request `action` callback
(`pymodbus.simulator.SimDevice`, the datastore API that replaces the deprecated
ModbusServerContext in pymodbus 3.10+): reads copy the cycle's register image into the reply,
writes are validated and handed to the cycle, which may refuse them with an exception code.

Before pymodbus sees a request, a screen per connection answers only what docs/cell.md
documents: function codes 3, 4, 6, 16 and 23 (anything else, diagnostics 8 and the serial-line
functions 7, 11, 12, 17, 20, 24 that pymodbus would answer, gets ILLEGAL FUNCTION), the
configured unit id (and 255, the Modbus TCP "no sub-device" value; others get exception 0B), and
writes only from the allowed peers (the PLC; default loopback). The connection is handed to the
cycle with every request, so that an ACK is taken only from a connection that read the result.
"""
from __future__ import annotations

import asyncio
import contextvars
import ipaddress
import logging
from dataclasses import dataclass
from pathlib import Path

from .._io import InputError, MtcompError
from .cycle import CellConfig, CellResult, Cycle, MeasureFn
from .registers import N_REGISTERS

log = logging.getLogger("mtcomp.cell")

READ_FCS = (3, 4, 6, 16, 23)   # 6/16/23 read back after writing (pymodbus does that internally)
WRITE_FCS = (6, 16, 23)
ANSWERED_FCS = frozenset((3, 4, 6, 16, 23))   # the documented ones; everything else is refused
ANY_UNIT = 255                 # Modbus TCP: "no sub-device" (Siemens, Beckhoff clients send it)
LOOPBACK = ("127.0.0.1", "::1")

_peer = contextvars.ContextVar("mtcomp_cell_peer", default=None)


class Peer:
    """One client connection as the cycle sees it: its address and whether it has closed
    (a weak reference: a closed connection is not kept alive by the cycle)."""
    __slots__ = ("address", "_conn", "__weakref__")

    def __init__(self, conn):
        import weakref
        try:
            self.address = conn.transport.get_extra_info("peername")[0]
        except (AttributeError, TypeError, IndexError):
            self.address = None
        self._conn = weakref.ref(conn)

    @property
    def closed(self) -> bool:
        conn = self._conn()
        return conn is None or conn.transport is None or conn.transport.is_closing()


def parse_allow(allow) -> tuple:
    """Peer allow-list: addresses or networks (``10.0.0.5``, ``10.0.0.0/24``, ``::1``)."""
    nets = []
    for a in ([allow] if isinstance(allow, str) else allow):
        for part in str(a).split(","):
            if part.strip():
                try:
                    nets.append(ipaddress.ip_network(part.strip(), strict=False))
                except ValueError:
                    raise InputError(f"{part.strip()!r} is not an IP address or network",
                                     field="--allow") from None
    if not nets:
        raise InputError("no address given", field="--allow")
    return tuple(nets)


def is_loopback_host(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class CellServer:
    """A cycle exposed on Modbus TCP. Binds 127.0.0.1 unless `host` says otherwise (with a
    warning: Modbus has no authentication); port 0 picks a free port (see `.port` after
    `start`). Answers unit id `unit_id` and 255; accepts writes only from peers in `allow`
    (addresses or networks, default loopback)."""

    def __init__(self, cycle: Cycle, host: str = "127.0.0.1", port: int = 502,
                 unit_id: int = 1, allow=LOOPBACK):
        if not 0 <= int(unit_id) <= 255:
            raise MtcompError(f"unit id {unit_id} outside 0..255")
        self.cycle, self.host, self.port = cycle, host, port
        self.unit_id, self.allow = int(unit_id), parse_allow(allow)
        self._server = None
        self._warned: set = set()

    async def start(self) -> "CellServer":
        from pymodbus.server import ModbusTcpServer
        from pymodbus.simulator import DataType, SimData, SimDevice
        if not is_loopback_host(self.host):
            log.warning("cell: listening on %s: Modbus has no authentication, keep this port on "
                        "the cell network; writes accepted only from %s", self.host,
                        ", ".join(map(str, self.allow)))
        await self.cycle.start()
        device = SimDevice(id=0, simdata=[SimData(address=0, values=[0] * N_REGISTERS,
                                                  datatype=DataType.REGISTERS)],
                           action=self._action)
        self._server = _server_class(ModbusTcpServer)(device, address=(self.host, self.port))
        self._server.cell = self
        try:
            await self._server.serve_forever(background=True)
        except BaseException:
            await self.cycle.stop()
            raise
        self.port = self._server.transport.sockets[0].getsockname()[1]
        log.info("cell: Modbus TCP server on %s:%d", self.host, self.port)
        return self

    def screen(self, conn, fc: int, unit: int):
        """Exception code to answer a request with before pymodbus handles it, or None."""
        if unit not in (self.unit_id, ANY_UNIT):
            return self._refuse(conn, 0x0B, f"unit id {unit} (this server is {self.unit_id})")
        if fc >= 0x80:   # pymodbus decodes these as exception responses and fails on them
            return self._refuse(conn, 0x01, f"function code 0x{fc:02X} (an exception response, "
                                            "not a request)")
        if fc not in ANSWERED_FCS:
            return self._refuse(conn, 0x01, f"function code {fc} (registers only: 3, 4, 6, 16, 23)")
        if fc in WRITE_FCS and not self.peer_allowed(conn):
            return self._refuse(conn, 0x01, "write from a peer outside the allow-list")
        return None

    def peer_allowed(self, conn) -> bool:
        try:
            ip = ipaddress.ip_address(conn.transport.get_extra_info("peername")[0])
        except (AttributeError, TypeError, ValueError, IndexError):
            return False
        ip = getattr(ip, "ipv4_mapped", None) or ip
        return any(ip in net for net in self.allow)

    def _refuse(self, conn, code: int, why: str) -> int:
        try:
            peer = conn.transport.get_extra_info("peername")[0]
        except (AttributeError, TypeError, IndexError):
            peer = "?"
        if (peer, why) not in self._warned:  # once per peer and reason: no log flood
            self._warned.add((peer, why))
            log.warning("cell: refused %s from %s (exception %02X)", why, peer, code)
        return code

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
            if fc in (3, 4, 23):
                self.cycle.note_read(_peer.get(), address, count)
            return None
        if values is not None and fc in WRITE_FCS:
            bad = self.cycle.plc_write(address, list(values), peer=_peer.get())
            return ExcCodes(bad[0]) if bad else None
        log.warning("cell: function code %d refused (registers only)", fc)
        return ExcCodes.ILLEGAL_FUNCTION


_CLASSES: dict = {}


def _server_class(base):
    """pymodbus' TCP server with the screen in front of every request (pymodbus offers no hook
    that sees the connection, so its per-connection handler is subclassed)."""
    if base in _CLASSES:
        return _CLASSES[base]
    from pymodbus.pdu import ExceptionResponse
    from pymodbus.server.requesthandler import ServerRequestHandler

    class Handler(ServerRequestHandler):
        async def handle_request(self):
            pdu = self.last_pdu
            if not pdu:
                return
            code = self.server.cell.screen(self, pdu.function_code, pdu.dev_id)
            if code is not None:
                rsp = ExceptionResponse(pdu.function_code & 0x7F, code)
                rsp.transaction_id, rsp.dev_id = pdu.transaction_id, pdu.dev_id
                self.server_send(rsp, self.last_addr)
                return
            if getattr(self, "cell_peer", None) is None:
                self.cell_peer = Peer(self)
            token = _peer.set(self.cell_peer)   # the cycle learns who reads and writes
            try:
                await super().handle_request()
            finally:
                _peer.reset(token)

    class Server(base):
        cell: "CellServer"

        def callback_new_connection(self):
            return Handler(self, self.trace_packet, self.trace_pdu, self.trace_connect)

    _CLASSES[base] = Server
    return Server


class BackgroundServer:
    """A CellServer running in its own thread and event loop, for tests, benchmarks and
    notebooks: `start()` returns once it listens, `stop()` once it is down, `restart()` drops
    everything (as a crash would, minus the process) and serves again from the same journal on
    the same port. Use as a context manager so it always stops."""

    def __init__(self, journal: str | Path, measure_and_compute: MeasureFn,
                 config: CellConfig = CellConfig(), host: str = "127.0.0.1", port: int = 0,
                 unit_id: int = 1, allow=LOOPBACK):
        self.journal, self.measure, self.config = Path(journal), measure_and_compute, config
        self.host, self.port, self.unit_id, self.allow = host, port, unit_id, allow
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
            srv = CellServer(Cycle(self.journal, self.measure, self.config), self.host, self.port,
                             self.unit_id, self.allow)
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
