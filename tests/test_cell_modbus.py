"""The cell bridge over real loopback sockets: full cycles, disconnects, restarts (in-process
and a killed process), malformed and out-of-range writes, two clients, faults, and an
independent Modbus TCP reader (raw sockets + struct, no pymodbus) checking the float32s."""
import asyncio
import logging
import os
import signal
import socket
import struct
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from mtcomp.cell.cycle import CellConfig, CellResult
from mtcomp.cell.journal import read_records
from mtcomp.cell.plcsim import PlcSim
from mtcomp.cell.registers import FIELDS, OUT_BLOCK, POSE_NAMES
from mtcomp.cell.server import BackgroundServer, run_virtual_cell_once
from mtcomp.cell.virtual import VirtualCell, robot_placement

pytestmark = pytest.mark.timeout(120)


# -- an independent Modbus TCP client: MBAP header + PDU, packed by hand ----------------------
class RawModbus:
    def __init__(self, port, unit=1):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        self.tid, self.unit = 0, unit

    def close(self):
        self.sock.close()

    def _recv(self, n):
        buf = b""
        while len(buf) < n:
            chunk = self.sock.recv(n - len(buf))
            if not chunk:
                raise ConnectionError("server closed the connection")
            buf += chunk
        return buf

    def pdu(self, pdu: bytes) -> bytes:
        self.tid = (self.tid + 1) & 0xFFFF
        self.sock.sendall(struct.pack(">HHHB", self.tid, 0, len(pdu) + 1, self.unit) + pdu)
        tid, proto, length, unit = struct.unpack(">HHHB", self._recv(7))
        assert (tid, proto, unit) == (self.tid, 0, self.unit)
        return self._recv(length - 1)

    def read(self, address, count):
        """Function 3. Returns the registers, or the exception code (int)."""
        rsp = self.pdu(struct.pack(">BHH", 3, address, count))
        if rsp[0] == 0x83:
            return rsp[1]
        assert rsp[0] == 3 and rsp[1] == 2 * count
        return list(struct.unpack(f">{count}H", rsp[2:]))

    def write(self, address, values):
        """Function 16. Returns None, or the exception code."""
        rsp = self.pdu(struct.pack(f">BHHB{len(values)}H", 16, address, len(values),
                                   2 * len(values), *values))
        if rsp[0] == 0x90:
            return rsp[1]
        assert struct.unpack(">BHH", rsp) == (16, address, len(values))
        return None

    def write1(self, address, value):
        """Function 6. Returns None, or the exception code."""
        rsp = self.pdu(struct.pack(">BHH", 6, address, value))
        return rsp[1] if rsp[0] == 0x86 else None

    def outputs(self, word_order="big"):
        """Decode the mtcomp -> PLC block with struct only."""
        regs = self.read(OUT_BLOCK[0], OUT_BLOCK[1] - OUT_BLOCK[0])
        assert isinstance(regs, list), regs

        def reg(name):
            return regs[FIELDS[name].address - OUT_BLOCK[0]]

        def two(name):
            a = FIELDS[name].address - OUT_BLOCK[0]
            w = regs[a:a + 2] if word_order == "big" else regs[a:a + 2][::-1]
            return struct.pack(">HH", *w)
        out = {n: reg(n) for n in ("state", "fault_code", "cmd_seq_echo", "cmd_status", "go",
                                   "program_id_out", "word_order", "job_no")}
        out["result_seq"] = struct.unpack(">I", two("result_seq"))[0]
        out["pose"] = [struct.unpack(">f", two(n))[0] for n in POSE_NAMES]
        out["sigma"] = [struct.unpack(">f", two("s_" + n))[0] for n in POSE_NAMES]
        return out

    def command(self, command, seq, blank=1, part=1, program=100, ack=0):
        return self.write(0, [0, command, seq, blank, part >> 16, part & 0xFFFF, program,
                              ack >> 16, ack & 0xFFFF])


def wait_for(pred, timeout=10.0, what="condition"):
    t = time.monotonic() + timeout
    while time.monotonic() < t:
        v = pred()
        if v:
            return v
        time.sleep(0.01)
    raise AssertionError(f"timed out waiting for {what}")


def results_in(journal):
    return {r["result_seq"]: r for r in read_records(journal)[0] if r["ev"] == "result"}


def f32(x):
    return [float(np.float32(v)) for v in x]


def run_plc(port, n, **kw):
    plc = PlcSim("127.0.0.1", port, **kw)
    return asyncio.run(asyncio.wait_for(plc.run(n), 90))


def assert_exactly_once(report, journal):
    """Every journaled result reached the PLC once, bit-equal to the journal (as float32)."""
    jr = results_in(journal)
    got = [r.result_seq for r in report.results]
    assert len(got) == len(set(got)), "a result was taken over twice"
    assert sorted(got) == sorted(jr), "results lost or invented"
    assert report.duplicates == 0
    for r in report.results:
        j = jr[r.result_seq]
        assert list(r.pose) == f32(j["pose"]) and list(r.sigma) == f32(j["sigma"])
        assert (r.part_id, r.program_id, r.go) == (j["job"]["part_id"], j["program_id"], j["go"])
    acks = [r["result_seq"] for r in read_records(journal)[0] if r["ev"] == "ack"]
    assert sorted(acks) == sorted(jr), "every result acknowledged exactly once"


class Gate:
    """A measurement step that holds job `hold` until the test opens the gate."""

    def __init__(self, inner=None, hold=1):
        self.inner, self.hold = inner or VirtualCell(), hold
        self.entered, self.open, self.done = threading.Event(), threading.Event(), threading.Event()

    def __call__(self, job):
        if job.job_no == self.hold:
            self.entered.set()
            self.open.wait(20)
        try:
            return self.inner(job)
        finally:
            self.done.set()


PART_PROGRAM = "%\nO0100 (PYRAMID)\nG90 G21 G54\nG00 X0 Y0 Z2.\nG01 Z-0.1 F100.\nG01 X1. Y0.5\nM30\n%\n"


def nc_dir(where, ids=(100,)):
    """A directory of part programs O<id>.nc (the same short program under each number)."""
    where.mkdir(exist_ok=True)
    for i in ids:
        (where / f"O{i:04d}.nc").write_text(PART_PROGRAM.replace("O0100", f"O{i:04d}"))
    return where


@pytest.fixture
def cell(tmp_path):
    servers = []
    nc = nc_dir(tmp_path / "nc")

    def make(measure=None, journal=None, **cfg):
        bs = BackgroundServer(journal or tmp_path / "journal.jsonl",
                              measure or VirtualCell(nc_dir=str(nc)), CellConfig(**cfg))
        servers.append(bs.start())
        return bs
    yield make
    for s in servers:
        s.stop()


# -- tests ------------------------------------------------------------------------------------
def test_full_cycles_recover_the_robot_placement(cell):
    bs = cell()
    assert bs.server._server.transport.sockets[0].getsockname()[0] == "127.0.0.1"
    rep = run_plc(bs.port, 5, first_part_id=11)
    assert rep.cycles == 5 and not rep.faults
    assert [r.result_seq for r in rep.results] == [1, 2, 3, 4, 5]
    assert_exactly_once(rep, bs.journal)
    for r in rep.results:
        err = (np.array(r.pose) - robot_placement(r.part_id)) / np.array(r.sigma)
        assert np.all(np.abs(err) < 5) and r.go and r.program_id == 1100
    assert bs.call(lambda c: c.state.name) == "IDLE"
    mb = RawModbus(bs.port)
    try:
        hb = mb.read(FIELDS["heartbeat"].address, 1)[0]
        wait_for(lambda: mb.read(FIELDS["heartbeat"].address, 1)[0] != hb, 5, "heartbeat")
        assert mb.read(FIELDS["map_version"].address, 1) == [2]
    finally:
        mb.close()


@pytest.mark.parametrize("order", ["big", "little"])
def test_independent_reader_decodes_the_float32s(cell, order):
    bs = cell(word_order=order)
    rep = run_plc(bs.port, 1, word_order=order)
    mb = RawModbus(bs.port)
    try:
        out = mb.outputs(order)
        wrong = mb.outputs("little" if order == "big" else "big")
    finally:
        mb.close()
    j = results_in(bs.journal)[1]
    assert out["word_order"] == (0 if order == "big" else 1)
    assert out["result_seq"] == 1 and out["program_id_out"] == j["program_id"]
    assert out["pose"] == f32(j["pose"]) and out["sigma"] == f32(j["sigma"])
    assert wrong["pose"] != out["pose"]   # the word order matters, so this check can fail
    assert list(rep.results[0].pose) == out["pose"]


def test_refused_writes_get_modbus_exceptions_and_are_logged(cell, caplog):
    bs = cell()
    caplog.set_level(logging.WARNING, logger="mtcomp.cell")
    mb = RawModbus(bs.port)
    try:
        before = mb.read(0, 54)
        assert mb.write(FIELDS["state"].address, [3]) == 2       # mtcomp's register
        assert mb.write(8, [0, 0]) == 2                           # straddles the block end
        assert mb.write(12, [1]) == 2                             # reserved gap
        assert mb.write1(FIELDS["command"].address, 7) == 3       # no such command
        assert mb.write1(FIELDS["blank_loaded"].address, 2) == 3
        assert mb.write(FIELDS["program_id"].address, [10000]) == 3
        assert mb.read(50, 10) == 2                               # beyond the map
        rsp = mb.pdu(struct.pack(">BHH", 5, 0, 0xFF00))           # write coil: not in the map
        assert rsp == bytes([0x85, 1])
        assert mb.read(0, 54) == before                           # nothing changed
        assert mb.write1(FIELDS["plc_heartbeat"].address, 4711) is None
    finally:
        mb.close()
    refused = [r for r in caplog.records if "refused" in r.getMessage()]
    assert len(refused) >= 6


def test_malformed_frames_do_not_hurt_the_server(cell):
    bs = cell()
    s = socket.create_connection(("127.0.0.1", bs.port), timeout=5)
    # FC16 whose byte count disagrees with the register count, then plain garbage
    s.sendall(struct.pack(">HHHBBHHB", 1, 0, 8, 1, 16, 0, 2, 3) + b"\x00\x01")
    s.sendall(b"GET / HTTP/1.0\r\n\r\n" + bytes(range(256)))
    s.settimeout(1.0)
    try:
        while s.recv(4096):
            pass
    except (socket.timeout, ConnectionError):
        pass
    s.close()
    mb = RawModbus(bs.port)
    try:
        assert mb.outputs()["state"] == 0
        assert mb.read(FIELDS["command"].address, 1) == [0]
    finally:
        mb.close()
    rep = run_plc(bs.port, 1)
    assert_exactly_once(rep, bs.journal)


def test_command_rejections_and_status(cell):
    bs = cell()
    mb = RawModbus(bs.port)
    try:
        assert mb.command(1, 1, blank=0) is None                   # START without a blank
        assert (mb.outputs()["cmd_seq_echo"], mb.outputs()["cmd_status"]) == (1, 2)
        assert mb.command(1, 2, program=0) is None                 # START without a program
        assert mb.outputs()["cmd_status"] == 4
        assert mb.command(1, 3) is None
        wait_for(lambda: mb.outputs()["state"] == 3, what="READY")
        assert mb.command(3, 4) is None                            # RESET would lose the result
        assert mb.outputs()["cmd_status"] == 1
        assert mb.command(2, 5, ack=7) is None                     # ACK of the wrong result
        out = mb.outputs()
        assert (out["cmd_status"], out["state"]) == (3, 3)
        assert mb.command(2, 6, ack=1) is None
        assert mb.outputs()["state"] == 0
        assert mb.command(2, 6, ack=1) is None                     # same seq again: no-op
        assert mb.outputs()["cmd_status"] == 0
    finally:
        mb.close()
    recs = read_records(bs.journal)[0]
    assert [r["ev"] for r in recs if "cmd_seq" in r] == \
        ["command", "command", "start", "command", "command", "ack"]


def test_plc_disconnects_mid_cycle(cell):
    gate = Gate()
    bs = cell(gate)
    mb = RawModbus(bs.port)
    assert mb.command(1, 1, part=5) is None
    assert gate.entered.wait(10)
    mb.close()                                    # PLC gone while the blank is measured
    gate.open.set()
    wait_for(lambda: bs.call(lambda c: c.state.name) == "READY", what="READY")
    mb = RawModbus(bs.port)                       # PLC back
    try:
        out = mb.outputs()
        assert out["state"] == 3 and out["result_seq"] == 1
        assert mb.command(2, 2, part=5, ack=1) is None
        assert mb.outputs()["state"] == 0
    finally:
        mb.close()
    # and a whole run with the PLC dropping its connection around 20 % of its requests
    rep = run_plc(bs.port, 12, first_part_id=100, disconnect_prob=0.2, seed=4,
                  request_timeout_s=0.2)
    assert rep.disconnects > 5 and rep.reconnects > 0
    jr = results_in(bs.journal)
    assert sorted(r.result_seq for r in rep.results) == list(range(2, 14))
    assert len(jr) == 13 and rep.duplicates == 0
    for r in rep.results:
        assert list(r.pose) == f32(jr[r.result_seq]["pose"])


def test_restart_mid_measurement_resumes_the_job(cell):
    gate = Gate(hold=2)
    bs = cell(gate)

    async def main():
        plc = PlcSim("127.0.0.1", bs.port, poll_s=0.005)
        task = asyncio.create_task(plc.run(4))
        assert await asyncio.to_thread(gate.entered.wait, 20)
        await asyncio.to_thread(bs.restart)       # mtcomp goes down while job 2 is measured
        gate.open.set()
        return await asyncio.wait_for(task, 60)

    rep = asyncio.run(main())
    assert rep.reconnects >= 1
    assert_exactly_once(rep, bs.journal)
    recs = read_records(bs.journal)[0]
    starts = [r["job"]["job_no"] for r in recs if r["ev"] == "start"]
    assert starts == [1, 2, 3, 4]                 # job 2 was resumed, not started twice
    boots = [r for r in recs if r["ev"] == "boot"]
    assert [b["resume"] for b in boots] == [None, 2]
    assert [r["job"]["job_no"] for r in results_in(bs.journal).values()] == [1, 2, 3, 4]


def test_restart_before_ack_represents_the_same_result(cell):
    bs = cell()
    mb = RawModbus(bs.port)
    try:
        assert mb.command(1, 1) is None
        first = wait_for(lambda: (o := mb.outputs())["state"] == 3 and o, what="READY")
    finally:
        mb.close()
    bs.restart()
    mb = RawModbus(bs.port)
    try:
        again = mb.outputs()
        assert again == first                     # same seq, same values: a re-report
        assert mb.command(1, 2) is None           # START refused until the ACK
        assert mb.outputs()["cmd_status"] == 1
        assert mb.command(2, 3, ack=first["result_seq"]) is None
        assert mb.outputs()["state"] == 0
    finally:
        mb.close()
    bs.restart()
    mb = RawModbus(bs.port)
    try:
        out = mb.outputs()
        assert out["state"] == 0 and out["cmd_seq_echo"] == 3   # not presented again
    finally:
        mb.close()


def test_two_clients_at_once(cell):
    """An HMI polls the result block while the PLC runs cycles; every READY snapshot it sees
    is a complete journaled result, and its refused writes do not disturb the PLC."""
    bs = cell()
    snaps, answers, stop = [], [], threading.Event()

    def hmi():
        # no asserts in here: a failure in a thread would not fail the test
        mb = RawModbus(bs.port)
        try:
            while not stop.is_set():
                snaps.append(mb.outputs())
                answers.append(mb.write(FIELDS["go"].address, [1]))
        finally:
            mb.close()

    t = threading.Thread(target=hmi)
    t.start()
    try:
        rep = run_plc(bs.port, 10)
    finally:
        stop.set()
        t.join(10)
    assert not t.is_alive()
    assert_exactly_once(rep, bs.journal)
    assert answers and set(answers) == {2}          # every write of mtcomp's register refused
    jr = results_in(bs.journal)
    shown = [s for s in snaps if s["result_seq"]]   # READY, and the last result after its ACK
    assert len(shown) > 5
    for s in shown:
        assert s["pose"] == f32(jr[s["result_seq"]]["pose"])
        assert s["sigma"] == f32(jr[s["result_seq"]]["sigma"])


def _fail_part_2(job):
    if job.part_id == 2:
        raise OSError("probe file from the NC is missing")
    return VirtualCell()(job)


def _nan(job):
    return CellResult((float("nan"),) * 6, (0.001,) * 6, 100)


@pytest.mark.parametrize("measure,code,cfg", [
    (_fail_part_2, 2, {}),
    (_nan, 3, {}),
    (Gate(hold=1), 1, {"measure_timeout_s": 0.3}),
])
def test_faults_and_reset(cell, tmp_path, measure, code, cfg):
    bs = cell(measure, journal=tmp_path / f"j{code}.jsonl", **cfg)
    rep = run_plc(bs.port, 3, poll_s=0.005)
    assert rep.cycles == 3
    assert [c for _, c in rep.faults] == [code] * len(rep.faults) and rep.faults
    assert_exactly_once(rep, bs.journal)
    recs = read_records(bs.journal)[0]
    assert sum(r["ev"] == "fault" and r["code"] == code for r in recs) == len(rep.faults)
    assert sum(r["ev"] == "reset" for r in recs) == len(rep.faults)
    if measure is _fail_part_2:
        assert [r.part_id for r in rep.results] == [1, 3]
    if cfg:
        measure.open.set()


def test_blank_removed_during_measurement_faults(cell):
    gate = Gate()
    bs = cell(gate)
    mb = RawModbus(bs.port)
    try:
        assert mb.command(1, 1) is None
        assert gate.entered.wait(10)
        assert mb.write1(FIELDS["blank_loaded"].address, 0) is None
        out = mb.outputs()
        assert (out["state"], out["fault_code"]) == (4, 4)
        gate.open.set()
        assert gate.done.wait(20)                       # the late result must be dropped
        time.sleep(0.05)
        bs.call(lambda c: None)
        assert mb.outputs()["state"] == 4 and not results_in(bs.journal)
        assert mb.command(3, 2) is None
        assert mb.outputs()["state"] == 0
    finally:
        mb.close()


def test_thirty_cycles_with_disconnects_and_a_restart(cell):
    bs = cell()

    async def main():
        plc = PlcSim("127.0.0.1", bs.port, disconnect_prob=0.05, seed=1,
                     request_timeout_s=0.2)
        task = asyncio.create_task(plc.run(30))
        while plc.report.cycles < 15:
            await asyncio.sleep(0.005)
        await asyncio.sleep(0.003)
        await asyncio.to_thread(bs.restart)
        return await asyncio.wait_for(task, 90)

    rep = asyncio.run(main())
    assert rep.cycles == 30 and len(rep.results) == 30
    assert_exactly_once(rep, bs.journal)


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _serve_process(journal, port, probe_time):
    # output to a file, not a pipe nobody drains (a full pipe would block the server)
    log = journal.with_name(f"serve-{port}-{time.monotonic_ns()}.log")
    with open(log, "wb") as out:
        p = subprocess.Popen([sys.executable, "-m", "mtcomp.cell.cli", "serve", "--journal",
                              str(journal), "--port", str(port), "--probe-time", str(probe_time)],
                             stdout=out, stderr=subprocess.STDOUT)

    def up():
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return True
        except OSError:
            assert p.poll() is None, log.read_text()
            return False
    try:
        wait_for(up, 30, "mtcomp cell serve")
    except BaseException:
        p.kill()          # never leave a server behind when it did not come up
        p.wait(10)
        raise
    p.log = log
    return p


def test_killed_process_resumes_from_the_journal(tmp_path):
    """SIGKILL during the measurement: the restarted process measures the same job again and
    reports it once."""
    journal, port = tmp_path / "j.jsonl", _free_port()
    p = _serve_process(journal, port, 1.0)
    try:
        mb = RawModbus(port)
        assert mb.command(1, 1, part=77) is None
        assert mb.outputs()["state"] == 1
        mb.close()
        p.send_signal(signal.SIGKILL)
        p.wait(10)
        assert "no --nc-dir: no compensated programs are written" in p.log.read_text()
        p = _serve_process(journal, port, 0.0)
        mb = RawModbus(port)
        out = wait_for(lambda: (o := mb.outputs())["state"] == 3 and o, 20, "READY")
        assert out["result_seq"] == 1 and out["job_no"] == 1
        assert mb.command(2, 2, part=77, ack=1) is None
        assert mb.outputs()["state"] == 0
        mb.close()
    finally:
        p.terminate()
        p.wait(10)
    recs = read_records(journal)[0]
    assert [r["ev"] for r in recs] == ["boot", "start", "boot", "result", "ack"]
    assert recs[2]["resume"] == 1
    res = results_in(journal)[1]
    assert res["job"] == {"job_no": 1, "part_id": 77, "program_id": 100, "out_program_id": 1100}
    assert out["pose"] == f32(res["pose"])


def test_run_virtual_cell_once(tmp_path):
    nc = nc_dir(tmp_path / "nc", (42,))
    r = run_virtual_cell_once(tmp_path / "once.jsonl", part_id=3, program_id=42,
                              measure_and_compute=VirtualCell(nc_dir=str(nc)))
    j = results_in(r.journal)[r.result_seq]
    assert list(r.result.pose6) == f32(j["pose"]) and r.result.program_id == 1042 and r.go
    assert np.all(np.abs(np.array(r.result.pose6) - r.true_pose) < 5 * np.array(r.result.sigma6))
    r2 = run_virtual_cell_once(tmp_path / "once.jsonl", part_id=4, word_order="little")
    assert r2.result_seq == 2


def test_cli_plc_sim_against_a_server(cell, capsys):
    from mtcomp.cell.cli import main
    bs = cell()
    assert main(["plc-sim", "--port", str(bs.port), "--cycles", "2", "--poll", "0"]) == 0
    out = capsys.readouterr().out
    assert "result 2 part 2 program O1100 GO" in out
    assert main(["serve", "--journal", os.devnull, "--measure", "nomodule"]) == 2
    missing = bs.journal.parent / "no-such-dir" / "j.jsonl"
    assert main(["serve", "--journal", str(missing), "--port", "0"]) == 2
    assert "cannot use the journal" in capsys.readouterr().err
    assert not missing.parent.exists()


def test_client_mode_polls_a_plc_server(tmp_path):
    """mtcomp as Modbus client: the PLC's data block is a plain Modbus server (no logic), the
    PLC program and mtcomp both talk to it; mtcomp is restarted mid-run."""
    from pymodbus.server import ModbusTcpServer
    from pymodbus.simulator import DataType, SimData, SimDevice
    from mtcomp.cell.client import CellClient
    from mtcomp.cell.cycle import Cycle
    journal, base = tmp_path / "client.jsonl", 100

    async def main():
        mem = ModbusTcpServer(SimDevice(id=0, simdata=[SimData(
            address=0, values=[0] * 200, datatype=DataType.REGISTERS)]),
            address=("127.0.0.1", 0))
        await mem.serve_forever(background=True)
        port = mem.transport.sockets[0].getsockname()[1]

        def client():
            return CellClient(Cycle(journal, VirtualCell(), CellConfig(word_order="little")),
                              "127.0.0.1", port, base=base, poll_s=0.003).start()
        cl = await client()
        try:
            plc = PlcSim("127.0.0.1", port, poll_s=0.003, base=base, word_order="little")
            task = asyncio.create_task(plc.run(6))
            while plc.report.cycles < 3:
                await asyncio.sleep(0.002)
            await cl.stop()
            cl = await client()
            rep = await asyncio.wait_for(task, 60)
        finally:
            await cl.stop()
            await mem.shutdown()
        return rep

    rep = asyncio.run(asyncio.wait_for(main(), 90))
    assert rep.cycles == 6 and not rep.faults
    assert_exactly_once(rep, journal)
    assert [b["ev"] for b in read_records(journal)[0]].count("boot") == 2


def test_client_mode_ignores_an_out_of_range_plc_block(tmp_path, caplog):
    from pymodbus.client import AsyncModbusTcpClient
    from pymodbus.server import ModbusTcpServer
    from pymodbus.simulator import DataType, SimData, SimDevice
    from mtcomp.cell.client import CellClient
    from mtcomp.cell.cycle import Cycle
    caplog.set_level(logging.WARNING, logger="mtcomp.cell")

    async def main():
        mem = ModbusTcpServer(SimDevice(id=0, simdata=[SimData(
            address=0, values=[0] * 60, datatype=DataType.REGISTERS)]), address=("127.0.0.1", 0))
        await mem.serve_forever(background=True)
        port = mem.transport.sockets[0].getsockname()[1]
        cl = await CellClient(Cycle(tmp_path / "c.jsonl", VirtualCell(), CellConfig()),
                              "127.0.0.1", port, poll_s=0.002).start()
        plc = AsyncModbusTcpClient("127.0.0.1", port=port)
        await plc.connect()

        async def state_and_echo(until):
            for _ in range(1000):  # no timing assumption: wait for the client's poll to act
                r = await plc.read_holding_registers(16, count=4, device_id=1)
                if until(r.registers):
                    break
                await asyncio.sleep(0.01)
            return r.registers[0], r.registers[3]

        def logged(regs):
            return any("PLC block ignored" in r.getMessage() for r in caplog.records)
        try:
            await plc.write_registers(0, [0, 9, 1, 1, 0, 1, 100, 0, 0], device_id=1)
            refused = await state_and_echo(logged)
            await plc.write_registers(0, [0, 1, 1, 1, 0, 1, 100, 0, 0], device_id=1)
            accepted = await state_and_echo(lambda regs: regs[3] == 1)
        finally:
            plc.close()
            await cl.stop()
            await mem.shutdown()
        return refused, accepted

    refused, accepted = asyncio.run(asyncio.wait_for(main(), 60))
    assert refused == (0, 0)                  # IDLE, command_seq 1 not taken
    assert accepted[1] == 1 and accepted[0] in (1, 2, 3)
    assert any("PLC block ignored" in r.getMessage() for r in caplog.records)


def test_probe_file_step_waits_for_the_nc(cell, tmp_path):
    """Real-machine step: MEASURING until the NC's touch file arrives, then the result; a bad
    file is a MEASURE_FAILED fault naming it."""
    from mtcomp.cell.virtual import ProbeFileCell
    from mtcomp.errors import WorkpieceSetting
    from mtcomp.setting.workpiece import plan_bowls, save_plan, virtual_probe, write_touches
    plan, inbox = plan_bowls(3), tmp_path / "inbox"
    inbox.mkdir()
    save_plan(plan, tmp_path / "plan.toml")
    step = ProbeFileCell(str(inbox), str(tmp_path / "plan.toml"), probe_sigma_mm=0.0005,
                         poll_s=0.01, settle_s=0.05, wait_s=20)
    bs = cell(step)
    mb = RawModbus(bs.port)
    try:
        assert mb.command(1, 1, part=42) is None
        time.sleep(0.1)
        assert mb.outputs()["state"] == 1                  # no file yet: still measuring
        truth = robot_placement(42, 9)
        touches = virtual_probe(WorkpieceSetting(tuple(truth[:3]), tuple(truth[3:])), plan,
                                0.0005, np.random.default_rng(5))
        write_touches(touches, inbox / "42.csv")
        out = wait_for(lambda: (o := mb.outputs())["state"] == 3 and o, 20, "READY")
        assert np.all(np.abs(np.array(out["pose"]) - truth) < 5 * np.array(out["sigma"]))
        assert (inbox / "42.csv.job1").exists() and not (inbox / "42.csv").exists()
        assert mb.command(2, 2, part=42, ack=1) is None
        (inbox / "43.csv").write_text("bowl,x,y,z,ax,ay,az\n1,0,0,zero,0,0,-1\n")
        assert mb.command(1, 3, part=43) is None
        out = wait_for(lambda: (o := mb.outputs())["state"] == 4 and o, 20, "FAULT")
        assert out["fault_code"] == 2
    finally:
        mb.close()
    fault = [r for r in read_records(bs.journal)[0] if r["ev"] == "fault"][0]
    assert "43.csv.job2:2" in fault["why"]


def test_run_virtual_cell_once_truth_follows_the_step(tmp_path):
    from mtcomp.setting.cellsim import RobotPlacement
    robot = RobotPlacement(repeatability=0.3, offset=(0.05, 0.0, 0.0))
    r = run_virtual_cell_once(tmp_path / "j.jsonl", part_id=9,
                              measure_and_compute=VirtualCell(seed=4, robot=robot))
    assert np.allclose(r.true_pose, robot_placement(9, 4, robot))
    assert np.all(np.abs(np.array(r.result.pose6) - r.true_pose) < 5 * np.array(r.result.sigma6))
    assert run_virtual_cell_once(tmp_path / "k.jsonl", measure_and_compute=_zero_step).true_pose \
        is None


def _zero_step(job):
    return CellResult((0.0,) * 6, (1e-4,) * 6, 7)
