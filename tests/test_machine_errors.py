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


# ---- issue 15 reproducers: each was a traceback or a silent acceptance

@pytest.mark.parametrize("toml, field, msg", [
    ('tool_setting = ""\n', "tool_setting", "expected a table"),
    ("geometric = []\n", "geometric", "expected a table"),
    ("[geometric.tables]\nX = nan\n", "geometric.tables.X", "expected a string"),
    ("[geometric.tables]\nX = ''\n", "geometric.tables.X", "non-empty"),
    ("[geometric.tables]\nX = '.'\n", "geometric.tables.X", "is a directory"),
    ("[geometric.tables]\nQ = 'q.csv'\n", "geometric.tables.Q", "unknown axis"),
    ("[geometric.location]\nEC0Y = true\n", "geometric.location.EC0Y", "got true"),
    ("[geometric.location]\nEC0Y = '1e-6'\n", "geometric.location.EC0Y", "expected a number"),
    ("[geometric.location]\nEC0Y = 18446744073709551616\n", "geometric.location.EC0Y", "out of range"),
    ("[geometric.location]\nEC0Y = 3\n", "geometric.location.EC0Y", "out of range"),
    ("[geometric]\nlocation = 5\n", "geometric.location", "expected a table"),
    ("[tool_setting]\noffset = [1, 2, true]\n", "tool_setting.offset[2]", "got true"),
    ("[tool_setting]\noffset = [[1, 2, 3]]\n", "tool_setting.offset", "list of 3 numbers"),
    ("[workpiece_setting]\nangles = [0, 0, 1e300]\n", "workpiece_setting.angles[2]", "out of range"),
    ("[workpiece_setting]\nsigma = [-1]\n", "workpiece_setting.sigma[0]", ">= 0"),
    ("meta = 3\n", "meta", "expected a table"),
    ("extra = 1\n", "extra", "unknown key"),
])
def test_errors_toml_reproducers(tmp_path, toml, field, msg):
    f = tmp_path / "e.toml"
    f.write_text("# line 1 is a comment\n" + toml)
    with pytest.raises(InputError) as exc:
        load_errors(f)
    assert exc.value.field == field and msg in str(exc.value)
    assert str(exc.value).startswith(f"{f}:")  # the TOML line of the field is named


@pytest.mark.parametrize("csv, line, msg", [
    ("position,,EXX\n0,0,0\n1,0,0\n", 1, "column 2 of the header has no name"),
    ("position,EXX,EXX\n0,0,0\n1,0,0\n", 1, "appears twice"),
    ("position,EXX\n0,1_0\n1,0\n", 2, "expected a number"),
    ("position,EXX\n0,\u0661\n1,0\n", 2, "expected a number"),
    ("position,EXX\n0," + "9" * 400 + "\n1,0\n", 2, "out of range"),
    ("position,EXX\n0,1e300\n1,0\n", 2, "out of range"),
    ("position,EAX\n0,0.5\n1,0\n", 2, "out of range"),
    ("position,EXX\n0,\"1\n1\",0\n", 2, "quoted cell"),
    ("position,EXX [furlong]\n0,0\n1,0\n", 1, "unknown unit"),
    ("position,EXX [deg]\n0,0\n1,0\n", 1, "not a unit of length"),
    ("position,EXX,EYY\n0,0,0\n1,0,0\n", 1, "one axis"),
    ("position,EXX\n0,0\n", None, "at least two rows"),
])
def test_table_csv_reproducers(tmp_path, csv, line, msg):
    f = tmp_path / "t.csv"
    f.write_text(csv)
    with pytest.raises(InputError) as exc:
        AxisErrorTable.from_csv(f)
    assert msg in str(exc.value)
    assert exc.value.line == line and str(exc.value.file) == str(f)


def test_table_header_units_are_converted(tmp_path):
    f = tmp_path / "t.csv"
    f.write_text("# interferometer export\nposition [m],EXX [um],EBX (urad)\n0,1.5,-2\n0.1,2.5,4\n")
    t = AxisErrorTable.from_csv(f)
    assert t.axis == "X" and list(t.position) == [0.0, 100.0]
    assert np.allclose(t.values["EXX"], [1.5e-3, 2.5e-3], rtol=1e-15)
    assert np.allclose(t.values["EBX"], [-2e-6, 4e-6], rtol=1e-15)
    f.write_text("position [deg],ECC [arcsec]\n-180,3.6\n180,-3.6\n")
    t = AxisErrorTable.from_csv(f)
    assert t.axis == "C" and np.allclose(t.values["ECC"], [np.pi / 180 / 1000, -np.pi / 180 / 1000], rtol=1e-12)


@pytest.mark.parametrize("mutate, field, msg", [
    (lambda d: d["axis"][2].update(resolution=5e-6), "axis[2].resolution", "power of ten"),
    (lambda d: d["axis"][2].update(resolution=1e-10), "axis[2].resolution", "power of ten"),
    (lambda d: d["axis"][2].update(resolution=True), "axis[2].resolution", "got true"),
    (lambda d: d["axis"][2].update(direction=["1", "0", "0"]), "axis[2].direction[0]", "expected a number"),
    (lambda d: d["axis"][2].update(direction=[[1, 0, 0]]), "axis[2].direction", "list of 3"),
    (lambda d: d["axis"][2].update(limits=[-1, 2**64]), "axis[2].limits[1]", "out of range"),
    (lambda d: d["axis"][2].update(limits=[True, 5]), "axis[2].limits[0]", "got true"),
    (lambda d: d["axis"][2].update(location=[0, 0, 1e300]), "axis[2].location[2]", "out of range"),
    (lambda d: d["axis"][2].update(side=1), "axis[2].side", "expected a string"),
    (lambda d: d["axis"][2].update(name=["X"]), "axis[2].name", "axis name"),
    (lambda d: d["machine"].update(name=3), "machine.name", "expected a string"),
    (lambda d: d["machine"].update(tool_axis=[0, 0, 0]), "machine.tool_axis", "non-zero"),
    (lambda d: d.update(axes=[]), "axes", "unknown key"),
    (lambda d: d["machine"].update(tool_piont=[0, 0, 1]), "machine.tool_piont", "did you mean 'tool_point'"),
    (lambda d: d.update(axis={"name": "X"}), "axis", "at least one"),
])
def test_machine_reproducers(tmp_path, mutate, field, msg):
    d = _machine_dict()
    mutate(d)
    f = tmp_path / "m.toml"
    f.write_text(dump_toml(d))
    with pytest.raises(InputError) as exc:
        load_machine(f)
    assert exc.value.field == field and msg in str(exc.value)
    assert exc.value.line is not None  # the line of the field (or of its table) is named


def test_power_of_ten_resolutions_accepted(tmp_path):
    d = _machine_dict()
    for i, r in enumerate((1, 1e-3, 1e-4, 1e-7, 1e-9)):
        d["axis"][i]["resolution"] = r
    f = tmp_path / "m.toml"
    f.write_text(dump_toml(d))
    m = load_machine(f)
    assert [a.decimals for a in m.axes] == [0, 3, 4, 7, 9]


def test_check_for_machine_library_call():
    from mtcomp.errors import check_for_machine
    m = load_machine("vmc-moving-column")
    ok = ErrorSet(geometric=GeometricErrors(location={"EC0Y": 1e-5}))
    assert check_for_machine(ok, m) is ok
    with pytest.raises(InputError, match="EX0C of axis C"):
        check_for_machine(ErrorSet(geometric=GeometricErrors(location={"EX0C": 1e-3})), m)


@pytest.mark.timeout(60)
def test_column_check_does_not_backtrack(tmp_path):
    """A bad cell after many long numbers is found at once (an ambiguous number pattern over the
    whole column took 11 s for 5 rows, and doubled per row)."""
    f = tmp_path / "t.csv"
    f.write_text("position,EXX\n" + "".join(f"{i},12345678901234567890\n" for i in range(60)) + "99,x\n")
    with pytest.raises(InputError, match=r"t\.csv:62 \[EXX\]: expected a number, got 'x'"):
        AxisErrorTable.from_csv(f)


def test_documented_errors_example_loads(tmp_path):
    """The TOML example of docs/errors-format.md is a working file once its two tables exist."""
    import re
    from pathlib import Path
    doc = (Path(__file__).resolve().parent.parent / "docs" / "errors-format.md").read_text()
    toml = re.search(r"```toml\n(.*?)```", doc, re.S).group(1)
    (tmp_path / "e.toml").write_text(toml)
    for ax in "XY":
        (tmp_path / f"vmc_{ax}.csv").write_text(f"position,E{ax}{ax}\n-300,0.001\n300,-0.001\n")
    e = load_errors(tmp_path / "e.toml")
    assert e.tool.offset == (0.245, -0.340, 0.120) and set(e.geometric.tables) == {"X", "Y"}
    assert e.geometric.location["EC0Y"] == 12e-6
