"""Property tests of the errors file formats (TOML and table CSV): whatever the bytes, reading
gives a valid ErrorSet / AxisErrorTable or an InputError naming the file, never another
exception; valid data round-trips exactly.  Seeded and derandomized, a few seconds in CI
(benchmarks/fuzz.py runs the long campaigns)."""
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mtcomp import InputError
from mtcomp._io import dump_toml
from mtcomp.errors import (AxisErrorTable, ErrorSet, GeometricErrors, ToolSetting, WorkpieceSetting,
                           load_errors, save_errors)

FUZZ = settings(max_examples=80, derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

# TOML values of every kind a parser can hand over, nested a little
scalars = st.one_of(st.booleans(), st.integers(min_value=-2**70, max_value=2**70),
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8),
                    st.sampled_from(["X", "x.csv", "", ".", "EC0Y", "1e-6"]))
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                       st.dictionaries(st.text(max_size=5), inner, max_size=3)),
                      max_leaves=8)
KEYS = {"": ["tool_setting", "workpiece_setting", "geometric", "uncertainty", "meta", "x"],
        "tool_setting": ["offset", "sigma", "y"],
        "workpiece_setting": ["translation", "angles", "sigma"],
        "geometric": ["tables", "location"],
        "geometric.tables": ["X", "Y", "U", "C", "Q", "xx"],
        "geometric.location": ["EC0Y", "EX0C", "EA0Z", "EX0U", "EQ0Y", "EC0C"]}


def _base():
    return {"tool_setting": {"offset": [0.1, -0.2, 0.05]},
            "workpiece_setting": {"translation": [0.01, 0.0, -0.02], "angles": [0.0, 0.01, 0.1]},
            "geometric": {"tables": {"X": "t_X.csv"}, "location": {"EC0Y": 1e-5, "EX0C": 0.002}}}


@st.composite
def mutated_errors(draw):
    d = _base()
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(sorted(KEYS)))
        node = d
        for part in [p for p in path.split(".") if p]:
            if not isinstance(node.get(part), dict):
                node[part] = {}
            node = node[part]
        key = draw(st.sampled_from(KEYS[path]))
        if draw(st.booleans()) and key in node:
            del node[key]
        else:
            node[key] = draw(values)
    return d


TABLE = "position,EXX,EBX\n-10,0.001,2e-6\n0,0.0,0.0\n10,-0.002,1e-6\n"


@FUZZ
@given(mutated_errors())
def test_errors_toml_never_crashes(tmp_path, data):
    (tmp_path / "t_X.csv").write_text(TABLE)
    f = tmp_path / "e.toml"
    try:
        f.write_text(dump_toml(data))
    except Exception:  # noqa: BLE001 - tomli_w cannot write some values (nan keys etc.): not our input
        return
    try:
        e = load_errors(f, machine="vmc-moving-column")
    except InputError as exc:
        assert str(f) in str(exc) and exc.field  # file and field named
        return
    # accepted: every number is finite and within the documented limits
    for v in (*e.tool.offset, *e.workpiece.translation, *e.workpiece.angles, *e.geometric.location.values()):
        assert isinstance(v, float) and math.isfinite(v)


# CSV text from tokens that matter to the reader
TOKENS = ["position", "EXX", "EYX", "EAX", "ECC", "EXY", ",", ",", ",", "\n", "\n", "#", " ", '"', "[um]",
          "(rad)", "[deg]", "0", "1", "-2.5", "1e-3", "1e400", "nan", "inf", "1_0", "\u0661", "\x00", "\r",
          "\ufeff", "9" * 30]


@FUZZ
@given(st.lists(st.sampled_from(TOKENS), max_size=40), st.booleans())
def test_table_csv_never_crashes(tmp_path, tokens, with_header):
    text = ("position,EXX,EAX\n" if with_header else "") + "".join(tokens)
    f = tmp_path / "t.csv"
    f.write_bytes(text.encode("utf-8", "surrogatepass"))
    try:
        t = AxisErrorTable.from_csv(f)
    except InputError as exc:
        assert str(f) in str(exc)
        return
    assert t.position.size >= 2 and np.all(np.diff(t.position) > 0) and np.all(np.isfinite(t.position))
    for v in t.values.values():
        assert np.all(np.isfinite(v)) and v.shape == t.position.shape


finite = st.floats(min_value=-1e-2, max_value=1e-2, allow_nan=False)


@FUZZ
@given(st.sampled_from("XYZABC"), st.lists(st.floats(-1e3, 1e3, allow_nan=False), min_size=2, max_size=12,
                                             unique=True), st.data())
def test_table_round_trip_is_exact(tmp_path, axis, pos, data):
    pos = sorted(pos)
    if np.any(np.diff(pos) <= 0):
        return
    names = data.draw(st.lists(st.sampled_from([f"E{c}{axis}" for c in "XYZABC"]), min_size=1, unique=True))
    vals = {n: [data.draw(finite) for _ in pos] for n in names}
    t = AxisErrorTable(axis, pos, vals)
    f = tmp_path / "t.csv"
    f.write_text(t.to_csv())
    assert AxisErrorTable.from_csv(f) == t


@FUZZ
@given(st.lists(st.floats(-5, 5, allow_nan=False), min_size=3, max_size=3),
       st.lists(st.floats(-50, 50, allow_nan=False), min_size=3, max_size=3),
       st.lists(st.floats(-10, 10, allow_nan=False), min_size=3, max_size=3),
       st.dictionaries(st.sampled_from(["EC0Y", "EB0Z", "EA0Z", "EX0C", "EY0C", "EC0C"]), finite, max_size=4))
def test_errors_round_trip_is_exact(tmp_path, off, tr, ang, loc):
    e = ErrorSet(ToolSetting(tuple(off)), WorkpieceSetting(tuple(tr), tuple(ang)), GeometricErrors(location=loc))
    f = save_errors(e, tmp_path / "e.toml")
    back = load_errors(f)
    assert back.tool == e.tool and back.workpiece == e.workpiece
    # an all-zero geometric part is not written; otherwise every entry comes back
    want = {k: float(v) for k, v in loc.items()} if any(loc.values()) else {}
    assert dict(back.geometric.location) == want


@pytest.mark.parametrize("blob", [b"\x00" * 10, b"\xff\xfe\x00", b"[a\n" * 3, b"a = [" * 5000])
def test_errors_toml_garbage(tmp_path, blob):
    f = tmp_path / "e.toml"
    f.write_bytes(blob)
    with pytest.raises(InputError):
        load_errors(f)
