"""mtcomp control export|import: the controls' own files, their limits, and exact round trips."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from mtcomp._io import InputError
from mtcomp.control import CONTROLS, ControlLimitError, export_control, import_control
from mtcomp.control.synthetic import grid_errors
from mtcomp.errors import AxisErrorTable, ErrorSet, GeometricErrors, load_errors
from mtcomp.machine import list_presets

PRESETS = ("robonano-a0ib", "robonano-ui", "vmc-moving-column")


def _same(a: ErrorSet, b: ErrorSet):
    """Exact equality of the geometric parts (every float bit for bit)."""
    ga, gb = a.geometric, b.geometric
    assert dict(ga.location) == dict(gb.location)
    assert set(ga.tables) == set(gb.tables)
    for ax in ga.tables:
        ta, tb = ga.tables[ax], gb.tables[ax]
        assert np.array_equal(ta.position, tb.position), ax
        assert set(ta.values) == set(tb.values), (ax, sorted(ta.values), sorted(tb.values))
        for k in ta.values:
            assert np.array_equal(ta.values[k], tb.values[k]), (ax, k, ta.values[k] - tb.values[k])


def test_presets_are_the_three():
    assert set(PRESETS) <= set(list_presets())


@pytest.mark.parametrize("reversal", (True, False), ids=("bidirectional", "mean"))
@pytest.mark.parametrize("control", CONTROLS)
@pytest.mark.parametrize("preset", PRESETS)
def test_round_trip_exact(tmp_path, control, preset, reversal):
    """Without reversal, EXX is not 0 at the reference position: Fanuc leaves that constant to
    the program (remainder.toml) and the import adds it back exactly."""
    errors, rev = grid_errors(preset, seed=7, reversal=reversal)
    res = export_control(control, preset, errors, tmp_path, rev)
    back, rev_back = import_control(control, preset, tmp_path)
    _same(errors, back)
    assert set(rev_back) == set(rev)
    for ax, r in rev.items():
        assert np.array_equal(rev_back[ax].reversal_i, r.reversal_i), ax
    # and the control's files alone hold the pitch tables exactly (nothing of them in the remainder)
    rem = res.remainder.geometric
    for ax, t in rem.tables.items():
        v = t.values.get(f"E{ax}{ax}")
        # only Fanuc leaves something of a pitch table: its constant at the reference position
        assert v is None or (control == "fanuc" and not reversal and np.ptp(v) == 0 and v[0] != 0), ax


@pytest.mark.parametrize("control", CONTROLS)
def test_export_of_import_is_byte_identical(tmp_path, control):
    errors, rev = grid_errors("robonano-a0ib", seed=3)
    export_control(control, "robonano-a0ib", errors, tmp_path / "a", rev)
    back, rev_back = import_control(control, "robonano-a0ib", tmp_path / "a")
    export_control(control, "robonano-a0ib", back, tmp_path / "b", rev_back)
    for f in sorted((tmp_path / "a").iterdir()):
        if f.suffix != ".toml":
            assert f.read_bytes() == (tmp_path / "b" / f.name).read_bytes(), f.name


def _pitch_only(preset, axis, position, values):
    return ErrorSet(geometric=GeometricErrors({axis: AxisErrorTable(axis, position, {f"E{axis}{axis}": values})}))


def test_linuxcnc_comp_file_is_what_linuxcnc_reads(tmp_path):
    """Three numbers per line, no header (LinuxCNC stops at the first other line), trims = -error."""
    pos = np.array([-10.0, 0.0, 10.0])
    e = _pitch_only("vmc-moving-column", "X", pos, np.array([0.0012, 0.0, -0.0005]))
    export_control("linuxcnc", "vmc-moving-column", e, tmp_path)
    lines = (tmp_path / "x.comp").read_text().splitlines()
    assert lines == ["-10.0 -0.0012 -0.0012", "0.0 0.0000 0.0000", "10.0 0.0005 0.0005"]
    ini = (tmp_path / "linuxcnc-comp.ini").read_text()
    assert "[JOINT_0]\nCOMP_FILE = x.comp\nCOMP_FILE_TYPE = 1" in ini


def test_linuxcnc_refuses_more_than_256_points(tmp_path):
    pos = np.linspace(-300, 300, 257)
    e = _pitch_only("vmc-moving-column", "X", pos, np.zeros(257))
    with pytest.raises(ControlLimitError, match=r"X pitch.*257 points.*at most 256"):
        export_control("linuxcnc", "vmc-moving-column", e, tmp_path / "out")
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_fanuc_tapes(tmp_path):
    """Incremental values per point, reference point at machine zero, magnification, bidirectional block."""
    pos = np.array([-60.0, -30.0, 0.0, 30.0, 60.0])
    err = np.array([0.0003, 0.0001, 0.0, -0.0004, -0.0010])       # mm; corrections -3 -1 0 4 10 (0.1 µm)
    e = _pitch_only("vmc-moving-column", "X", pos, err)
    export_control("fanuc", "vmc-moving-column", e, tmp_path)
    prm = (tmp_path / "fanuc-params.txt").read_text().splitlines()
    assert "N3620A1P2" in prm and "N3621A1P0" in prm and "N3622A1P4" in prm
    assert "N3623A1P1" in prm and "N3624A1P300000" in prm      # 30 mm in 0.1 µm units
    assert (tmp_path / "fanuc-pitch.txt").read_text().split() == [
        "%", "N10000P0", "N10001P2", "N10002P1", "N10003P4", "N10004P6", "%"]
    # a change of 10 units over one interval needs magnification 2 (values within +-7)
    e2 = _pitch_only("vmc-moving-column", "X", pos, np.array([0.0, 0.0, 0.0, -0.0010, -0.0020]))
    export_control("fanuc", "vmc-moving-column", e2, tmp_path / "m")
    assert "N3623A1P2" in (tmp_path / "m" / "fanuc-params.txt").read_text().splitlines()


def test_fanuc_refuses_by_name(tmp_path):
    pos = np.array([-60.0, -30.0, 0.0, 30.0, 60.0])
    steep = _pitch_only("vmc-moving-column", "X", pos, np.array([0.0, 0.0, 0.0, 0.1, 0.2]))
    with pytest.raises(ControlLimitError, match=r"X pitch.*changes by 1000 detection units.*at most 7 x"):
        export_control("fanuc", "vmc-moving-column", steep, tmp_path)
    uneven = _pitch_only("vmc-moving-column", "X", np.array([-60.0, -20.0, 0.0, 30.0]), np.zeros(4))
    with pytest.raises(ControlLimitError, match=r"X pitch.*not equally spaced"):
        export_control("fanuc", "vmc-moving-column", uneven, tmp_path)
    no_zero = _pitch_only("vmc-moving-column", "X", np.array([10.0, 40.0, 70.0]), np.zeros(3))
    with pytest.raises(ControlLimitError, match=r"X pitch.*point at the reference position"):
        export_control("fanuc", "vmc-moving-column", no_zero, tmp_path)
    assert not list(tmp_path.iterdir())


def test_remainder_holds_what_the_control_cannot(tmp_path):
    errors, rev = grid_errors("robonano-a0ib", seed=1)
    res = export_control("linuxcnc", "robonano-a0ib", errors, tmp_path, rev)
    rem = load_errors(tmp_path / "remainder.toml")
    assert "EYX" in rem.geometric.tables["X"].values           # no straightness in LinuxCNC
    assert "EA0C" in rem.geometric.location                      # trt kinematics has no tilts
    assert "EX0C" not in rem.geometric.location                  # ... but the C axis position
    assert "x-rot-point" in (tmp_path / "linuxcnc-kins.hal").read_text()
    assert "stays for the NC rewrite" in res.summary()


def test_cli_round_trip_and_refusal(tmp_path):
    from mtcomp.errors import save_errors
    from mtcomp.cli import main
    errors, rev = grid_errors("vmc-moving-column", seed=2)
    src = tmp_path / "e.toml"
    save_errors(errors, src)
    files = []
    for ax, r in rev.items():
        (tmp_path / f"{ax}_reversal.csv").write_text(r.to_csv())
        files += ["--reversal", str(tmp_path / f"{ax}_reversal.csv")]
    assert main(["control", "export", "--control", "fanuc", "--machine", "vmc-moving-column",
                 "--errors", str(src), *files, "-o", str(tmp_path / "f")]) == 0
    assert main(["control", "import", "--control", "fanuc", "--machine", "vmc-moving-column",
                 str(tmp_path / "f"), "-o", str(tmp_path / "back.toml")]) == 0
    _same(errors, load_errors(tmp_path / "back.toml"))
    assert (tmp_path / "back_X_reversal.csv").exists()
    bad = subprocess.run([sys.executable, "-m", "mtcomp", "control", "export", "--control", "fanuc",
                          "--machine", "vmc-moving-column", "--errors", str(tmp_path / "nope.toml"),
                          "-o", str(tmp_path / "g")], capture_output=True, text=True)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr and "nope.toml" in bad.stderr


def test_linuxcnc_reads_comp_file_type_0(tmp_path):
    """Type 0 files hold nominal, actual forward, actual reverse positions: trims = nominal - actual."""
    (tmp_path / "linuxcnc-comp.ini").write_text("[JOINT_0]\nCOMP_FILE = x.comp\nCOMP_FILE_TYPE = 0\n")
    (tmp_path / "x.comp").write_text("-10.0 -10.0012 -10.0010\n0.0 0.0 0.0\n10.0 10.0005 10.0007\n")
    errors, rev = import_control("linuxcnc", "vmc-moving-column", tmp_path)
    exx = errors.geometric.tables["X"].values["EXX"]
    assert np.allclose(exx, [-0.0011, 0.0, 0.0006], atol=1e-12)     # mean of the two directions
    assert np.allclose(rev["X"].reversal_i, [-0.0002, 0.0, -0.0002], atol=1e-12)


def test_siemens_and_heidenhain_refuse_by_name(tmp_path):
    many = _pitch_only("vmc-moving-column", "X", np.arange(-1000, 1001) * 3 / 10, np.zeros(2001))
    with pytest.raises(ControlLimitError, match=r"X pitch.*2001 points.*at most 2000"):
        export_control("siemens", "vmc-moving-column", many, tmp_path / "s")
    with pytest.raises(ControlLimitError, match=r"X.COM.*2001 points.*at most 256"):
        export_control("heidenhain", "vmc-moving-column", many, tmp_path / "h")
    assert not (tmp_path / "s").exists() and not (tmp_path / "h").exists()


def test_siemens_cec_tables(tmp_path):
    """Bidirectional pitch as two tables (direction 1 and -1), straightness EYX as input X1 -> output Y1."""
    errors, rev = grid_errors("vmc-moving-column", seed=9)
    export_control("siemens", "vmc-moving-column", errors, tmp_path, rev)
    text = (tmp_path / "siemens-cec.ini").read_text().splitlines()
    assert text[0] == "%_N_NC_CEC_INI" and text[-1] == "M17"
    assert '$AN_CEC_INPUT_AXIS[0]="X1"' in text and "$AN_CEC_DIRECTION[0]=1" in text
    assert "$AN_CEC_DIRECTION[1]=-1" in text
    ins = {ln.split("=")[0][len("$AN_CEC_INPUT_AXIS"):]: ln.split("=")[1] for ln in text if ln.startswith("$AN_CEC_INPUT_AXIS")}
    outs = {ln.split("=")[0][len("$AN_CEC_OUTPUT_AXIS"):]: ln.split("=")[1] for ln in text if ln.startswith("$AN_CEC_OUTPUT_AXIS")}
    assert ('"X1"', '"Y1"') in {(ins[k], outs[k]) for k in ins}
    eyx = errors.geometric.tables["X"].values["EYX"]
    t = next(k for k in ins if ins[k] == '"X1"' and outs[k] == '"Y1"')
    first = float(next(ln for ln in text if ln.startswith(f"$AN_CEC[{t[1:-1]},0]=")).split("=")[1])
    assert first == -eyx[0]                              # the correction is the error's negative


@pytest.mark.parametrize("control", CONTROLS)
def test_remainder_after_the_control_is_the_export_remainder(tmp_path, control):
    """Errors minus what the control's files hold = what the export left for the program: nothing
    is compensated twice, nothing is lost."""
    from mtcomp.control import remainder_after
    errors, _ = grid_errors("robonano-a0ib", seed=11, reversal=False)   # EXX not 0 at the reference
    res = export_control(control, "robonano-a0ib", errors, tmp_path)
    held, _ = import_control(control, "robonano-a0ib", tmp_path, remainder=False)
    rest, notes = remainder_after("robonano-a0ib", errors, held)
    a, b = rest.geometric, res.remainder.geometric
    assert dict(a.location) == dict(b.location) and set(a.tables) == set(b.tables)
    for ax, t in a.tables.items():
        assert set(t.values) == set(b.tables[ax].values), ax
        for k, v in t.values.items():     # Fanuc's constant at the reference: one rounding of a difference
            assert np.allclose(v, b.tables[ax].values[k], rtol=0, atol=1e-15), (ax, k)
    assert not notes


def test_cli_remainder(tmp_path, capsys):
    from mtcomp.cli import main
    from mtcomp.errors import save_errors
    errors, _ = grid_errors("vmc-moving-column", seed=12, reversal=False)
    save_errors(errors, tmp_path / "e.toml")
    export_control("siemens", "vmc-moving-column", errors, tmp_path / "ctl")
    (tmp_path / "ctl" / "remainder.toml").unlink()            # a shop's folder: the control's files only
    assert main(["control", "remainder", "--control", "siemens", "--machine", "vmc-moving-column",
                 "--errors", str(tmp_path / "e.toml"), "--control-has", str(tmp_path / "ctl"),
                 "-o", str(tmp_path / "rest.toml")]) == 0
    rest = load_errors(tmp_path / "rest.toml")
    t = rest.geometric.tables["X"].values
    assert "EXX" not in t and "EYX" not in t and "EAX" in t          # pitch and straightness are the control's
    assert "the control holds for axis X" in capsys.readouterr().out


def test_export_reports_its_rounding(tmp_path):
    """Off-grid errors: the export says by how much the control's increments round them."""
    pos = np.array([-60.0, -30.0, 0.0, 30.0, 60.0])
    e = _pitch_only("vmc-moving-column", "X", pos, np.array([0.00031, 0.00012, 0.0, -0.00044, -0.00104]))
    res = export_control("heidenhain", "vmc-moving-column", e, tmp_path)      # 0.1 µm increments
    fig = res.figures["largest rounding to the control's increments"]
    assert fig.startswith("0.0400 µm")
    res = export_control("siemens", "vmc-moving-column", e, tmp_path / "s")
    assert res.figures["largest rounding to the control's increments"].startswith("0.0400 µm")
    errors, rev = grid_errors("robonano-a0ib", seed=7)
    res = export_control("linuxcnc", "robonano-a0ib", errors, tmp_path / "l", rev)
    assert res.figures["largest rounding to the control's increments"].startswith("0.0000 µm")


def test_import_refuses_broken_files_by_name(tmp_path):
    errors, rev = grid_errors("vmc-moving-column", seed=3)
    for control in ("siemens", "fanuc"):
        export_control(control, "vmc-moving-column", errors, tmp_path / control, rev)
    cec = tmp_path / "siemens" / "siemens-cec.ini"
    cec.write_text("\n".join(ln for ln in cec.read_text().splitlines() if not ln.startswith("$AN_CEC_MIN[0]")))
    with pytest.raises(InputError, match=r"siemens-cec.ini \[AN_CEC_MIN\[0\]\]: missing"):
        import_control("siemens", "vmc-moving-column", tmp_path / "siemens")
    prm = tmp_path / "fanuc" / "fanuc-params.txt"
    prm.write_text("\n".join(ln for ln in prm.read_text().splitlines() if not ln.startswith("N3624")))
    with pytest.raises(InputError, match=r"fanuc-params.txt \[3624\]: axis 1 \(X\) has No.3620 but no No.3624"):
        import_control("fanuc", "vmc-moving-column", tmp_path / "fanuc")
