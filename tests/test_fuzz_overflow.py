"""Integers beyond float range in the plan and measurement-set TOML files (TOML integers are
unbounded): each is an InputError naming the file, never an OverflowError traceback.  The three
reproducers are what benchmarks/fuzz.py found (300 inputs per surface, seed 7)."""
from __future__ import annotations

import re

import pytest

from mtcomp._io import InputError
from mtcomp.cli import main

HUGE = "1" * 400


def _mutate(path, pattern):
    """Replace the first number after `pattern` in the file by a 400-digit integer."""
    text = path.read_text()
    new, n = re.subn(pattern + r"(\s*)-?[0-9.]+(e-?[0-9]+)?", lambda m: m.group(0)[:m.end(1) - m.start(0)] + HUGE,
                     text, count=1)
    assert n == 1, pattern
    path.write_text(new)


def test_tool_setting_plan(tmp_path):
    from mtcomp.setting.tool_plan import load_plan
    assert main(["tool-setting", "plan", "-o", str(tmp_path / "tp"), "--no-png"]) == 0
    plan = tmp_path / "tp" / "plan.toml"
    _mutate(plan, r"eu = \[")
    with pytest.raises(InputError, match="plan.toml"):
        load_plan(plan)


def test_workpiece_plan(tmp_path):
    from mtcomp.setting.bowl_plan import load_plan
    plan = tmp_path / "wp.toml"
    assert main(["workpiece-setting", "plan", "-o", str(plan)]) == 0
    _mutate(plan, r"directions = \[\s*\[")
    with pytest.raises(InputError, match=r"wp.toml \[directions\]"):
        load_plan(plan)


def test_geometric_measurement_set(tmp_path):
    from mtcomp.geometric.tables import load_measurement_set
    s = tmp_path / "set.toml"
    assert main(["geometric", "simulate", "-o", str(s)]) == 0
    _mutate(s, r"offset = \[")
    with pytest.raises(InputError, match=r"set.toml \[run\[0\]\.offset\]"):
        load_measurement_set(s)


@pytest.mark.parametrize("pattern, field", [
    (r"depth =", r"\[depth\]"),
    (r"id = 2, x =", r"\[bowls\[1\]\.x\]"),
    (r"\{ id =", r"\[bowls\[0\]\.id\]"),
    (r"blank = \[", r"\[blank\]"),
], ids=["depth", "bowl-x", "bowl-id", "blank"])
def test_workpiece_plan_scalars(tmp_path, pattern, field):
    # the 10,000-input campaign (seed 11) found these four: a number, a bowl id, a bowl
    # position and a blank size given as a 320-digit integer
    from mtcomp.setting.bowl_plan import load_plan
    plan = tmp_path / "wp.toml"
    assert main(["workpiece-setting", "plan", "-o", str(plan)]) == 0
    _mutate(plan, pattern)
    with pytest.raises(InputError, match=r"wp.toml " + field) as e:
        load_plan(plan)
    assert len(str(e.value)) < 300   # the number is not echoed in full


@pytest.mark.parametrize("pattern, field", [(r"clearance_mm =", r"\[plan\.clearance_mm\]"),
                                            (r"plate_mm = \[", r"\[plan\.plate_mm\]")],
                         ids=["clearance", "plate"])
def test_tool_setting_plan_head(tmp_path, pattern, field):
    # found by the 10,000-input campaign (seed 12): a [plan] number and the plate size as a
    # 320-digit integer gave OverflowError tracebacks
    from mtcomp.setting.tool_plan import load_plan
    assert main(["tool-setting", "plan", "-o", str(tmp_path / "tp"), "--no-png"]) == 0
    plan = tmp_path / "tp" / "plan.toml"
    _mutate(plan, pattern)
    with pytest.raises(InputError, match=r"plan.toml " + field) as e:
        load_plan(plan)
    assert len(str(e.value)) < 300   # the number is not echoed in full


# --- tool tables and offsets files (fuzz campaign of the tool-table and offsets-toml surfaces) ---

BIG = "1" * 320


@pytest.mark.parametrize("text", [f"T{BIG} P1\n", f"T12 P1 H{BIG} Z+5.0\nT7 P2 H2 Z+7.5\n",
                                  f"T1 P{BIG} Z+5.0\n"])
def test_tool_table_with_a_huge_number_is_refused_by_line(tmp_path, text):
    from mtcomp._io import InputError
    from mtcomp.gcode.offsets import read_tool_table
    f = tmp_path / "tool.tbl"
    f.write_text(text)
    with pytest.raises(InputError) as e:
        read_tool_table(f)
    assert e.value.line == 1 and "tool.tbl" in str(e.value)


@pytest.mark.parametrize("text, field", [(f"[H]\n1 = 5.0\n2 = {BIG}\n", "H.2"),
                                         (f"[G55]\nX = 1.0\nY = {BIG}\n", "G55.Y")])
def test_offsets_file_with_a_huge_integer_is_refused_by_field(tmp_path, text, field):
    from mtcomp._io import InputError
    from mtcomp.gcode.offsets import read_offsets
    f = tmp_path / "offsets.toml"
    f.write_text(text)
    with pytest.raises(InputError) as e:
        read_offsets(f, ("X", "Y", "Z"))
    assert field in str(e.value)
