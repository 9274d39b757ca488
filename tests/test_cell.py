"""mtcomp.cell without sockets: register map and codecs, journal and replay, virtual cell."""
import json
import re
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from mtcomp import InputError
from mtcomp.cell import registers as rg
from mtcomp.cell.cycle import Job
from mtcomp.cell.journal import Journal, read_records, replay
from mtcomp.cell.virtual import VirtualCell, robot_placement

DOCS = Path(__file__).resolve().parent.parent / "docs" / "cell.md"


# -- register map ---------------------------------------------------------------------------
def test_map_fields_do_not_overlap_and_stay_in_their_blocks():
    used = {}
    for f in rg.FIELDS.values():
        for a in range(f.address, f.address + f.size):
            assert a not in used, f"{f.name} overlaps {used[a]}"
            used[a] = f.name
        lo, hi = rg.PLC_BLOCK if f.plc_writes else rg.OUT_BLOCK
        assert lo <= f.address and f.address + f.size <= hi, f.name
    assert max(used) == rg.N_REGISTERS - 1


def test_docs_table_matches_the_map():
    """docs/cell.md lists every field with its address and type, as in the code."""
    text = DOCS.read_text(encoding="utf-8")
    rows = dict(re.findall(r"^\|\s*(\d+)(?:\.\.\d+)?\s*\|\s*`(\w+)`", text, re.M))
    rows = {name: int(addr) for addr, name in rows.items()}
    for f in rg.FIELDS.values():
        assert rows.get(f.name) == f.address, f"{f.name} missing or wrong address in docs"


@given(st.floats(width=32, allow_nan=False), st.sampled_from(rg.WORD_ORDERS))
def test_f32_round_trip_and_word_order(x, order):
    regs = rg.encode_f32(x, order)
    assert rg.decode_f32(regs, order) == x
    hi, lo = struct.unpack(">HH", struct.pack(">f", x))  # IEEE bytes ABCD
    assert regs == ([hi, lo] if order == "big" else [lo, hi])


def test_f32_matches_pymodbus_codec():
    from pymodbus.client import AsyncModbusTcpClient as C
    for x in (0.0123456, -1.5e-4, 12.75, -0.0):
        for order in rg.WORD_ORDERS:
            assert rg.encode_f32(x, order) == C.convert_to_registers(
                x, C.DATATYPE.FLOAT32, word_order=order)


@given(st.integers(0, 2**32 - 1), st.sampled_from(rg.WORD_ORDERS))
def test_u32_round_trip(v, order):
    regs = rg.encode_u32(v, order)
    assert all(0 <= r <= 0xFFFF for r in regs)
    assert rg.decode_u32(regs, order) == v


def test_check_plc_write():
    assert rg.check_plc_write(0, [1, 1, 5, 1, 0, 42, 100, 0, 0]) is None
    assert rg.check_plc_write(16, [0])[0] == 2           # mtcomp's block
    assert rg.check_plc_write(7, [0, 0, 0])[0] == 2       # straddles the end of the PLC block
    assert rg.check_plc_write(1, [4])[0] == 3             # no command 4
    assert rg.check_plc_write(3, [2])[0] == 3             # blank_loaded is 0/1
    assert rg.check_plc_write(6, [10000])[0] == 3         # program id > 9999
    with pytest.raises(ValueError):
        rg.encode_f32(1.0, "middle")


def test_register_image_typed_access():
    img = rg.RegisterImage("little")
    img.set("result_seq", 70000)
    img.set("dx", 0.015)
    f = rg.FIELDS["result_seq"]
    assert img.regs[f.address:f.address + 2] == [70000 & 0xFFFF, 70000 >> 16]
    assert img.get("result_seq") == 70000
    assert img.get("dx") == np.float32(0.015)
    out = rg.decode_outputs(img.regs[rg.OUT_BLOCK[0]:], "little")
    assert out["result_seq"] == 70000 and out["word_order"] == 1
    assert out["pose"][0] == np.float32(0.015)


# -- journal --------------------------------------------------------------------------------
def test_journal_round_trip_and_replay(tmp_path):
    p = tmp_path / "j.jsonl"
    job = {"job_no": 1, "part_id": 9, "program_id": 100}
    with Journal.open(p) as j:
        j.append("start", cmd_seq=1, status=0, job=job)
        j.append("result", result_seq=1, job=job, pose=[0.0] * 6, sigma=[0.0] * 6,
                 program_id=1100, go=True, info={})
    recs, keep = read_records(p)
    assert keep is None and [r["n"] for r in recs] == [1, 2]
    r = replay(recs)
    assert r.state == "ready" and r.result["result_seq"] == 1 and r.cmd_seq == 1
    with Journal.open(p) as j:
        j.append("ack", cmd_seq=2, status=0, result_seq=1)
    r = replay(read_records(p)[0])
    assert r.state == "idle" and r.acked == {1} and r.cmd_seq == 2 and r.result_seq == 1


def test_journal_torn_tail_is_cut_and_appending_continues(tmp_path):
    p = tmp_path / "j.jsonl"
    with Journal.open(p) as j:
        j.append("reset", cmd_seq=1, status=0)
    good = p.read_bytes()
    p.write_bytes(good + b'{"n":2,"t":"x","ev":"sta')   # crash in the middle of a write
    recs, keep = read_records(p)                          # reading skips the tail and says where
    assert [r["cmd_seq"] for r in recs] == [1] and keep == len(good)
    with Journal.open(p) as j:
        assert j.n == 1
        j.append("reset", cmd_seq=2, status=0)
    recs, keep = read_records(p)
    assert keep is None and [r["cmd_seq"] for r in recs] == [1, 2]
    assert p.read_bytes().startswith(good)


def test_journal_damage_in_the_middle_names_the_line(tmp_path):
    p = tmp_path / "j.jsonl"
    with Journal.open(p) as j:
        for s in range(3):
            j.append("reset", cmd_seq=s + 1, status=0)
    lines = p.read_text().splitlines(keepends=True)
    p.write_text(lines[0] + "garbage\n" + lines[2])
    with pytest.raises(InputError, match=r"j.jsonl:2"):
        Journal.open(p)
    p.write_text(lines[0] + lines[2])                      # a record went missing
    with pytest.raises(InputError, match=r"j.jsonl:2 \[n\]"):
        read_records(p)


def test_journal_has_one_writer(tmp_path):
    from mtcomp import MtcompError
    p = tmp_path / "j.jsonl"
    with Journal.open(p):
        with pytest.raises(MtcompError, match="in use"):
            Journal.open(p)
    Journal.open(p).close()                               # free again once closed


def test_journal_lines_are_plain_json(tmp_path):
    p = tmp_path / "j.jsonl"
    with Journal.open(p) as j:
        j.append("fault", code=2, name="MEASURE_FAILED", why="x", job=None)
    rec = json.loads(p.read_text())
    assert rec["ev"] == "fault" and rec["n"] == 1 and rec["t"].endswith("+00:00")


# -- virtual cell ---------------------------------------------------------------------------
def test_virtual_cell_estimates_are_consistent_with_their_uncertainty():
    """Normalised errors (estimate - truth) / sigma over 100 blanks have unit scatter."""
    vc = VirtualCell(seed=3)
    z = []
    for pid in range(100):
        res = vc(Job(1, pid, 100))
        z.append((np.array(res.pose6) - robot_placement(pid, 3)) / np.array(res.sigma6))
    z = np.array(z)
    assert np.all(np.abs(z.mean(0)) < 0.4)
    assert np.all((z.std(0) > 0.7) & (z.std(0) < 1.35))
    assert res.program_id == 1100 and res.ok
    assert vc(Job(1, 7, 100)) == vc(Job(1, 7, 100))          # a resumed job reports the same
    assert vc(Job(2, 7, 100)).pose6 != vc(Job(1, 7, 100)).pose6


def test_robot_placement_scatter():
    """RP = 30 µm (ISO 9283: mean + 3 s of the distance) is 8.3 µm per axis."""
    p = np.array([robot_placement(i) for i in range(2000)])
    np.testing.assert_allclose(p.std(0), [0.030 / 3.615] * 3 + [0.02] * 3, rtol=0.08)
    d = np.linalg.norm(p[:, :3] - p[:, :3].mean(0), axis=1)
    assert abs(d.mean() + 3 * d.std() - 0.030) < 0.002
    assert np.array_equal(robot_placement(5), robot_placement(5))


def test_virtual_cell_writes_the_compensated_program(tmp_path):
    """With NC programs configured, O<id+1000>.nc is the part program moved onto the measured
    blank: x' = R x + t with R = Rz(c) Ry(b) Rx(a) (checked with scipy's rotation)."""
    from scipy.spatial.transform import Rotation
    (tmp_path / "O0100.nc").write_text("O0100\nG90 G21 G54\nG00 X0 Y0 Z2.\nG01 Z-0.1 F100.\n"
                                       "G01 X1. Y0.5\nM30\n")
    res = VirtualCell(nc_dir=str(tmp_path))(Job(1, 5, 100))
    assert res.program_id == 1100 and res.info["program_file"] == "O1100.nc"
    text = (tmp_path / "O1100.nc").read_text()
    r = Rotation.from_euler("xyz", res.pose6[3:], degrees=True).as_matrix()
    rows = [ln for ln in text.splitlines() if ln.startswith(("G00", "G01"))]
    assert len(rows) == 3, text                   # the loop below checks every motion block
    checked = 0
    for row, p in zip(rows, ([0, 0, 2.0], [0, 0, -0.1], [1.0, 0.5, -0.1])):
        words = dict((w[0], float(w[1:])) for w in row.split()[1:] if w[0] in "XYZ")
        expected = r @ p + np.array(res.pose6[:3])
        for k, axis in enumerate("XYZ"):
            if axis in words:
                assert abs(words[axis] - expected[k]) < 1.5e-6, row
                checked += 1
    assert checked == 9, text                     # the tilt moves every axis of every block


def test_import_is_light():
    import subprocess
    import sys
    code = ("import sys, mtcomp.cell, mtcomp.cell.cli, mtcomp.cell.registers; "
            "print(any(m.startswith(('pymodbus', 'scipy')) for m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


# -- the cycle against random PLC behaviour (no sockets) --------------------------------------
def _instant(job):
    from mtcomp.cell.cycle import CellResult
    return CellResult((0.001 * job.job_no, 0.0, 0.0, 0.0, 0.0, 0.01), (1e-4,) * 6,
                      job.program_id + 1)


_op = st.one_of(
    st.tuples(st.just("cmd"), st.integers(0, 3), st.integers(1, 4), st.integers(0, 1),
              st.sampled_from([0, 100]), st.integers(0, 3)),
    st.tuples(st.just("restart")),
    st.tuples(st.just("blank"), st.integers(0, 1)))


@settings(max_examples=60, deadline=None)  # 1,500 examples pass too; 60 keep CI fast
@given(st.lists(_op, min_size=1, max_size=25))
def test_cycle_restart_is_transparent_and_results_go_out_once(ops):
    """Whatever the PLC writes, in whatever order, with repeated command numbers: a restart
    shows the PLC exactly the registers it saw before (heartbeat aside), a result is never
    presented again after its ACK, and every result is ACKed at most once."""
    import asyncio
    import tempfile
    from mtcomp.cell.cycle import Cycle
    from mtcomp.cell.registers import State

    def visible(c):
        r = list(c.image.regs[rg.OUT_BLOCK[0]:])
        r[rg.FIELDS["heartbeat"].address - rg.OUT_BLOCK[0]] = 0
        return r

    async def settle(c):
        for _ in range(2000):
            if c.state not in (State.MEASURING, State.COMPUTING):
                return
            await asyncio.sleep(0.001)
        raise AssertionError("measurement did not finish")

    async def main(path):
        c = Cycle(path, _instant)
        await c.start()
        acked = set()
        try:
            for op in ops:
                if op[0] == "restart":
                    before = visible(c)
                    await c.stop()
                    c = Cycle(path, _instant)
                    await c.start()
                    await settle(c)
                    assert visible(c) == before
                elif op[0] == "blank":
                    assert c.plc_write(3, [op[1]]) is None
                else:
                    _, cmd, seq, blank, prog, ack = op
                    assert c.plc_write(0, [0, cmd, seq, blank, 0, 1, prog, 0, ack]) is None
                await settle(c)
                if c.state == State.READY:
                    assert c.image.get("result_seq") not in acked
                acked = {r["result_seq"] for r in c.journal.records if r["ev"] == "ack"}
        finally:
            await c.stop()

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "j.jsonl"
        asyncio.run(main(path))
        recs = read_records(path)[0]
        res = [r["result_seq"] for r in recs if r["ev"] == "result"]
        acks = [r["result_seq"] for r in recs if r["ev"] == "ack"]
        assert res == list(range(1, len(res) + 1))
        assert len(acks) == len(set(acks)) and set(acks) <= set(res)
        assert replay(recs).state in ("idle", "ready", "fault")


def test_virtual_cell_verifies_the_program_on_the_measured_blank(tmp_path):
    """Issue 14 item 3: no GO for a program that has not passed the verification on this blank.
    A rapid into the blank (the plan's 20 x 20 x 5 mm box, top at z = 0) is a PROGRAM_FAILED
    fault naming the line, and no file is written; the clearance of a good program is in the
    result (the 2 mm of the first rapid, the 0.1 mm cut's rapid retract does not count)."""
    from mtcomp.cell.program import CellFault
    from mtcomp.cell.registers import Fault
    good = "O0100\nG90 G21 G54\nG00 X0 Y0 Z2.\nG01 Z-0.1 F100.\nG01 X1. Y0.5\nG00 Z3.\nM30\n"
    (tmp_path / "O0100.nc").write_text(good.replace("G00 Z3.\n", "G00 Z3.\nG00 X5. Z-0.5\n"))
    with pytest.raises(CellFault, match=r"O1100.nc: .*line 8 \(G00 X.*enters the stock") as exc:
        VirtualCell(nc_dir=str(tmp_path))(Job(1, 5, 100))
    assert exc.value.code == Fault.PROGRAM_FAILED and not (tmp_path / "O1100.nc").exists()
    # the check can be left out (clearance None), and a custom check still runs beside it
    res = VirtualCell(nc_dir=str(tmp_path), clearance=None)(Job(2, 5, 100))
    assert res.program is not None and "min_clearance_mm" not in res.info
    (tmp_path / "O1100.nc").unlink()
    (tmp_path / "O0100.nc").write_text(good)
    seen = []
    res = VirtualCell(nc_dir=str(tmp_path), program_check=lambda m, p, t: seen.append(t))(Job(3, 5, 100))
    assert res.info["min_clearance_mm"] == pytest.approx(2.0, abs=2e-3) and res.info["retracts"] == 1
    assert len(seen) == 1 and "MTCOMP-CELL O1100" in seen[0]


@pytest.mark.parametrize("opt, value, field", [("--program-check", "no_such_module_x:check", "--program-check"),
                                               ("--program-check", "json", "--program-check"),
                                               ("--clearance", "-1", "--clearance")])
def test_serve_refuses_a_bad_program_check_or_clearance(tmp_path, capsys, opt, value, field):
    from mtcomp.cli import main
    rc = main(["cell", "serve", "--journal", str(tmp_path / "j.jsonl"), "--port", "0", opt, value])
    assert rc != 0 and field in capsys.readouterr().err
    assert not (tmp_path / "j.jsonl").exists()
