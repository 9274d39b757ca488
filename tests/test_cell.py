"""mtcomp.cell without sockets: register map and codecs, journal and replay, virtual cell."""
import json
import re
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, strategies as st

from mtcomp import InputError
from mtcomp.cell import registers as rg
from mtcomp.cell.cycle import Job
from mtcomp.cell.journal import Journal, read_records, replay
from mtcomp.cell.virtual import (BOWL_CENTRES, VirtualCell, angles_of, fit_sphere,
                                 pose_from_centres, robot_placement, rot)

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


def test_journal_lines_are_plain_json(tmp_path):
    p = tmp_path / "j.jsonl"
    with Journal.open(p) as j:
        j.append("fault", code=2, name="MEASURE_FAILED", why="x", job=None)
    rec = json.loads(p.read_text())
    assert rec["ev"] == "fault" and rec["n"] == 1 and rec["t"].endswith("+00:00")


# -- virtual cell ---------------------------------------------------------------------------
@given(st.lists(st.floats(-2, 2), min_size=3, max_size=3),
       st.lists(st.floats(-1, 1), min_size=3, max_size=3))
def test_pose_from_centres_recovers_an_injected_pose(ang, t):
    r = rot(ang)
    measured = BOWL_CENTRES @ r.T + np.array(t)
    np.testing.assert_allclose(pose_from_centres(measured), [*t, *ang], atol=1e-9)
    np.testing.assert_allclose(angles_of(r), ang, atol=1e-9)


def test_rotation_convention_is_rz_ry_rx():
    # a = 90 deg about X takes +Y to +Z; c = 90 deg about Z takes +X to +Y (right hand)
    np.testing.assert_allclose(rot([90, 0, 0]) @ [0, 1, 0], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(rot([0, 0, 90]) @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(rot([10, 20, 30]),
                               rot([0, 0, 30]) @ rot([0, 20, 0]) @ rot([10, 0, 0]))


def test_fit_sphere_exact_points():
    rng = np.random.default_rng(1)
    d = rng.normal(size=(12, 3))
    d[:, 2] = -abs(d[:, 2])
    d /= np.linalg.norm(d, axis=1)[:, None]
    c, r, cov, rms = fit_sphere(np.array([1.0, -2.0, 0.5]) + 2.5 * d)
    np.testing.assert_allclose(c, [1.0, -2.0, 0.5], atol=1e-10)
    assert abs(r - 2.5) < 1e-10 and rms < 1e-10


def test_virtual_cell_estimates_are_consistent_with_their_uncertainty():
    """Normalised errors (estimate - truth) / sigma over 150 blanks have unit scatter."""
    vc = VirtualCell(seed=3)
    z = []
    for pid in range(150):
        res = vc(Job(1, pid, 100))
        z.append((np.array(res.pose6) - robot_placement(pid, 3)) / np.array(res.sigma6))
    z = np.array(z)
    assert np.all(np.abs(z.mean(0)) < 0.35)
    assert np.all((z.std(0) > 0.75) & (z.std(0) < 1.3))
    assert res.program_id == 1100


def test_robot_placement_scatter():
    p = np.array([robot_placement(i) for i in range(2000)])
    np.testing.assert_allclose(p.std(0), [0.010] * 3 + [0.02] * 3, rtol=0.08)
    assert np.array_equal(robot_placement(5), robot_placement(5))
