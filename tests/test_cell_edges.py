"""The cell's edges: who may take a result, requests with exception-range function codes, and the
register map exported for PLC programmers. Modbus over a real TCP socket on 127.0.0.1."""
from __future__ import annotations

import csv
import io
import json
import logging
import struct

import pytest
from test_cell_modbus import RawModbus, wait_for

from mtcomp.cell.cycle import CellConfig
from mtcomp.cell.journal import read_records
from mtcomp.cell.registers import (FIELDS, MAP_VERSION, OUT_BLOCK, PLC_BLOCK, CommandStatus, State,
                                   register_map)
from mtcomp.cell.server import BackgroundServer
from mtcomp.cell.virtual import VirtualCell
from mtcomp.cli import main

pytestmark = pytest.mark.timeout(120)


@pytest.fixture
def server(tmp_path):
    bs = BackgroundServer(tmp_path / "j.jsonl", VirtualCell(), CellConfig()).start()
    yield bs
    bs.stop()


def _ready(bs):
    wait_for(lambda: bs.call(lambda c: c.state) == State.READY, what="READY")


# -- ACK bound to the connection that took the job -------------------------------------------------
def test_a_second_client_that_read_the_result_cannot_ack_it_while_the_plc_is_connected(server):
    """An HMI or a diagnostic tool on an allowed address reads the result block and ACKs: the
    result would be gone before the PLC took it. Only the connection that sent START may ACK
    (or, after it closed, a connection from its address)."""
    plc, other = RawModbus(server.port), RawModbus(server.port)
    try:
        assert plc.command(1, 1) is None
        _ready(server)
        assert other.outputs()["result_seq"] == 1        # it has read the result ...
        assert other.command(2, 2, ack=1) is None        # ... and ACKs it: refused
        out = plc.outputs()
        assert (out["state"], out["cmd_seq_echo"], out["cmd_status"]) == \
            (State.READY, 2, CommandStatus.NOT_OWNER)
        assert plc.command(2, 3, ack=1) is None          # the PLC takes it
        out = plc.outputs()
        assert (out["state"], out["cmd_status"]) == (State.IDLE, CommandStatus.OK)
    finally:
        plc.close()
        other.close()
    assert [r["cmd_seq"] for r in read_records(server.journal)[0] if r["ev"] == "ack"] == [3]


def test_after_the_plc_reconnects_its_new_connection_may_ack(server):
    plc = RawModbus(server.port)
    assert plc.command(1, 1) is None
    _ready(server)
    plc.close()
    wait_for(lambda: server.call(lambda c: c._owner.closed), what="closed")
    plc = RawModbus(server.port)
    try:
        assert plc.outputs()["result_seq"] == 1
        assert plc.command(2, 2, ack=1) is None
        assert plc.outputs()["cmd_status"] == CommandStatus.OK
    finally:
        plc.close()


# -- function codes in the exception range ----------------------------------------------------------
@pytest.mark.parametrize("fc", [0x80, 0x83, 0x90, 0xAB, 0xFF])
def test_exception_range_function_codes_get_an_answer_and_no_traceback(server, caplog, fc):
    """A request whose function code has the exception bit set (0x80..0xFF) is not a request:
    answered ILLEGAL FUNCTION (or ignored), one log line, no traceback, the server serves on."""
    caplog.set_level(logging.DEBUG)
    mb = RawModbus(server.port)
    try:
        mb.sock.settimeout(2.0)
        try:
            rsp = mb.pdu(struct.pack(">BHH", fc, 0, 1))
        except (TimeoutError, ConnectionError, OSError):
            rsp = None
        if rsp is not None:
            assert rsp[0] == fc | 0x80 and rsp[1] == 0x01, rsp
    finally:
        mb.close()
    mb = RawModbus(server.port)
    try:
        assert mb.outputs()["state"] == State.IDLE     # still serving
    finally:
        mb.close()
    assert not [r for r in caplog.records if r.exc_info or "Traceback" in r.getMessage()], \
        [r.getMessage() for r in caplog.records]


# -- the register map as CSV and JSON ----------------------------------------------------------------
def test_cell_map_csv_is_the_servers_table(tmp_path, capsys):
    assert main(["cell", "map", "--format", "csv"]) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert [r["name"] for r in rows] == list(FIELDS)
    for r in rows:
        f = FIELDS[r["name"]]
        assert int(r["address"]) == f.address and int(r["plc_address"]) == 40001 + f.address
        assert int(r["registers"]) == f.size and r["type"] == f.kind
        assert r["access"] == ("rw" if f.plc_writes else "r")
    # the blocks are contiguous and nothing overlaps
    used = [a for r in rows for a in range(int(r["address"]), int(r["address"]) + int(r["registers"]))]
    assert len(used) == len(set(used))
    assert {a for a in used if a < 16} == set(range(*PLC_BLOCK))
    assert {a for a in used if a >= 16} == set(range(*OUT_BLOCK))
    out = tmp_path / "map.csv"
    assert main(["cell", "map", "--format", "csv", "-o", str(out)]) == 0
    assert list(csv.DictReader(out.open(encoding="utf-8"))) == rows


@pytest.mark.parametrize("order", ["big", "little"])
def test_cell_map_json_addresses_read_right_on_a_live_server(tmp_path, capsys, order):
    """Decode a live server's registers with nothing but the exported JSON map."""
    assert main(["cell", "map", "--format", "json", "--word-order", order]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["map_version"] == MAP_VERSION and doc["word_order"] == order
    assert doc["enums"]["cmd_status"]["NOT_OWNER"] == CommandStatus.NOT_OWNER
    fields = {f["name"]: f for f in doc["fields"]}
    assert fields == {r["name"]: r for r in register_map(order)}
    bs = BackgroundServer(tmp_path / "j.jsonl", VirtualCell(), CellConfig(word_order=order)).start()
    mb = RawModbus(bs.port)
    try:
        def u16(name):
            return mb.read(fields[name]["address"], 1)[0]

        def f32(name):
            w = mb.read(fields[name]["address"], 2)
            return struct.unpack(">f", struct.pack(">HH", *(w if order == "big" else w[::-1])))[0]
        assert u16("map_version") == MAP_VERSION
        assert u16("word_order") == ("big", "little").index(order)
        part = [0, 4242] if order == "big" else [4242, 0]
        assert mb.write(0, [0, 1, 1, 1, *part, 100, 0, 0]) is None   # START, part 4242, program 100
        _ready(bs)
        w = mb.read(fields["part_id_out"]["address"], 2)
        assert (w[0] << 16 | w[1] if order == "big" else w[1] << 16 | w[0]) == 4242
        assert u16("state") == doc["enums"]["state"]["READY"]
        pose = bs.call(lambda c: c._presented["pose"])
        assert f32("dx") == pytest.approx(pose[0], abs=1e-6)
    finally:
        mb.close()
        bs.stop()
