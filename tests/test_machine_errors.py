"""Machine files and error files: round trips and clear errors for bad input."""
import numpy as np
import pytest

from mtcomp import InputError
from mtcomp._io import dump_toml
from mtcomp.errors import (AxisErrorTable, ErrorSet, GeometricErrors, TableRangeError, ToolSetting,
                           WorkpieceSetting, angles_from_matrix, load_errors, rotation_matrix_xyz,
                           save_errors)
from mtcomp.machine import load_machine, machine_from_dict


@pytest.mark.parametrize("name", ["robonano-ui", "robonano-a0ib", "vmc-moving-column"])
def test_machine_toml_round_trip(name, tmp_path):
    m = load_machine(name)
    f = tmp_path / "m.toml"
    f.write_text(dump_toml(m.to_dict()))
    assert load_machine(f) == m


def _machine_dict():
    return load_machine("robonano-a0ib").to_dict()


@pytest.mark.parametrize("mutate, field", [
    (lambda d: d["axis"].append(dict(d["axis"][0], name="A", side="workpiece")), "axis[5].side"),
    (lambda d: d["axis"][0].update(direction=[0, 0, 0]), "axis[0].direction"),
    (lambda d: d["axis"][2].update(limits=[5, -5]), "axis[2].limits"),
    (lambda d: d["axis"][2].update(name="Q"), "axis[2].name"),
    (lambda d: d["axis"][2].update(kind="rotary"), "axis[2].kind"),
    (lambda d: d["axis"][3].update(name="X"), "axis[3].name"),
    (lambda d: d["axis"][3].update(direction=[1, "a", 0]), "axis[3].direction"),
    (lambda d: d["axis"][3].update(resolution=float("nan")), "axis[3].resolution"),
    (lambda d: d["axis"][3].update(speed=3), "axis[3].speed"),
])
def test_machine_bad_fields_are_named(mutate, field, tmp_path):
    d = _machine_dict()
    mutate(d)
    f = tmp_path / "bad.toml"
    f.write_text(dump_toml(d))
    with pytest.raises(InputError) as exc:
        load_machine(f)
    assert str(f) in str(exc.value) and (f"[{field}]" in str(exc.value) or f"[{field}[" in str(exc.value))


def test_broken_chain_message(tmp_path):
    d = _machine_dict()
    d["axis"] = [d["axis"][2], d["axis"][0]]  # tool-side X before workpiece-side C
    with pytest.raises(InputError, match="broken axis chain"):
        machine_from_dict(d, "m.toml")


def test_toml_syntax_error_names_line(tmp_path):
    f = tmp_path / "m.toml"
    f.write_text("[machine]\nname = 'x'\n[[axis]\n")
    with pytest.raises(InputError, match=r"m\.toml:3"):
        load_machine(f)


def test_missing_machine_file():
    with pytest.raises(InputError, match="no such machine file or preset"):
        load_machine("nowhere.toml")


def test_rotation_angles_round_trip(rng):
    for _ in range(50):
        a = rng.uniform([-180, -89, -180], [180, 89, 180])
        assert np.allclose(angles_from_matrix(rotation_matrix_xyz(a)), a, atol=1e-10)
    # R = Rz Ry Rx: a pure +90 deg about Z takes X onto Y.
    assert np.allclose(rotation_matrix_xyz([0, 0, 90]) @ [1, 0, 0], [0, 1, 0])


def test_errors_round_trip(tmp_path, rng):
    pos = np.linspace(-100, 100, 11)
    tab = AxisErrorTable("Y", pos, {"EYY": rng.normal(0, 0.01, 11), "EAY": rng.normal(0, 1e-5, 11)})
    E = ErrorSet(ToolSetting((0.1, 0.2, -0.3)), WorkpieceSetting((1, 2, 3), (0.1, 0.2, 0.3)),
                 GeometricErrors({"Y": tab}, {"EC0Y": 2e-5, "EX0C": 0.001}))
    f = save_errors(E, tmp_path / "e.toml")
    back = load_errors(f)
    assert back == E
    assert (tmp_path / "e_Y.csv").exists()


def test_table_interpolation_and_range():
    tab = AxisErrorTable("X", [0, 10, 20], {"EXX": [0, 0.01, 0.0], "EBX": [0, 1e-5, 2e-5]})
    d, e = tab.evaluate(np.array([5.0, 15.0]))
    assert np.allclose(d[:, 0], [0.005, 0.005]) and np.allclose(e[:, 1], [5e-6, 1.5e-5])
    with pytest.raises(TableRangeError, match="outside its error table range"):
        tab.evaluate(np.array([1.0, 20.5]))


@pytest.mark.parametrize("csv, msg, line", [
    ("position,EXX\n0,0\n10,0.1\n5,0\n", "increase strictly", 4),
    ("position,EXX\n0,0\n10,abc\n", "expected a number, got 'abc'", 3),
    ("position,EXX\n0,0\n10,nan\n", "expected a number, got 'nan'", 3),
    ("position,EXX,EQX\n0,0,0\n", "unknown column 'EQX'", 1),
    ("position,EXX\n0,0\n10\n", "expected 2 values", 3),
    ("pos,EXX\n0,0\n", "first column must be 'position'", 1),
])
def test_bad_tables_name_line(tmp_path, csv, msg, line):
    f = tmp_path / "x.csv"
    f.write_text(csv)
    with pytest.raises(InputError) as exc:
        AxisErrorTable.from_csv(f)
    assert msg in str(exc.value) and f"x.csv:{line}" in str(exc.value)


@pytest.mark.parametrize("toml, msg", [
    ("[tool_setting]\noffset = [1, 2]\n", "tool_setting.offset"),
    ("[tool_setting]\noffset = [1, 2, nan]\n", "tool_setting.offset"),
    ("[workpiece_setting]\nangle = [1, 2, 3]\n", "unknown key"),
    ("[geometric.location]\nEQ0Y = 1e-5\n", "unknown location error"),
    ("[geometric.tables]\nX = 'missing.csv'\n", "error table file not found"),
    ("[tool]\noffset = [0, 0, 0]\n", "unknown key"),
])
def test_bad_errors_files(tmp_path, toml, msg):
    f = tmp_path / "e.toml"
    f.write_text(toml)
    with pytest.raises(InputError) as exc:
        load_errors(f)
    assert msg in str(exc.value)


def test_atomic_write_permissions_and_no_leftovers(tmp_path):
    import os
    import stat
    from mtcomp._io import atomic_path, atomic_write
    f = atomic_write(tmp_path / "a.txt", "x")
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE(f.stat().st_mode) == 0o666 & ~mask
    with pytest.raises(RuntimeError):
        with atomic_path(tmp_path / "b.txt") as tmp:
            tmp.write_text("half")
            raise RuntimeError("fails midway")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]


def test_binary_files_are_named_not_tracebacks(tmp_path):
    f = tmp_path / "x.bin"
    f.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe")
    with pytest.raises(InputError, match="not a text file"):
        load_errors(f)
    with pytest.raises(InputError, match="not a text file"):
        AxisErrorTable.from_csv(f)
    with pytest.raises(InputError, match="not a text file"):
        load_machine(f)
