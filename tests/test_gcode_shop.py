"""Issue 31, safety first: nothing over tolerance leaves `mtcomp compensate`, the parser's and
the verifier's refusals are one clear line naming the right word, one provenance rule for every
writer of NC (the header, the refusal of a compensated source unless --force, no output over
its input), and `verify` says what it checked."""
from __future__ import annotations

import os
import warnings

import numpy as np
import pytest

from mtcomp import InputError
from mtcomp.commands import compensate_program
from mtcomp.errors import ErrorSet, ToolSetting, WorkpieceSetting, save_errors
from mtcomp.gcode.provenance import MARKER, compensated_line
from mtcomp.machine import load_machine

CYCLE_THEN_G91 = "G99 G81 Z-8. R-22.\nG91\nG00 Z50.\n"
BOX = "box:-10,-10,-3,10,10,0"


@pytest.fixture
def run(capsys):
    """The CLI in this process (exit code, stdout, stderr); warnings raise."""
    from types import SimpleNamespace

    from mtcomp.cli import main

    def call(*args):
        capsys.readouterr()
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            code = main([str(a) for a in args])
        got = capsys.readouterr()
        return SimpleNamespace(returncode=code, stdout=got.out, stderr=got.err)
    return call


def _zero(tmp_path):
    z = tmp_path / "zero.toml"
    z.write_text("# no errors\n")
    return z


# ------------------------------------------------------------- nothing over tolerance leaves
@pytest.mark.parametrize("machine", ["vmc-moving-column", "robonano-ui"])
def test_retract_after_a_cycle_of_unknown_start_keeps_its_50_mm(tmp_path, machine, run):
    """The reproducer: a G99 cycle before the start is known, then G91: `G00 Z50.` was written
    `G00 Z0.0000` (the control's Z after the cycle read as 0) with exit 0 and a summary of
    50,000 µm after compensation.  Zero errors: the program comes back as it is."""
    src = tmp_path / "c1.nc"
    src.write_text(CYCLE_THEN_G91)
    out = tmp_path / "out.nc"
    r = run("compensate", src, "-m", machine, "-e", _zero(tmp_path), "-o", out)
    assert r.returncode == 0, r.stderr
    body = out.read_text().splitlines()
    assert body[-1] == "G00 Z50." and "Z0.0000" not in out.read_text()
    # the library: the block is compensated and read where the control stands (Z 28)
    new, rep = compensate_program(CYCLE_THEN_G91, load_machine(machine), ErrorSet())
    assert new == CYCLE_THEN_G91 and rep["after_max"] == 0.0


def test_a_block_over_tolerance_is_refused_by_line_not_written(tmp_path, run):
    """With a translation the same program's X Y corrections cannot be written (the program
    never writes X Y): the block misses by 39 µm and was written with exit 0.  Refused, exit
    2, naming line 3, nothing written."""
    src = tmp_path / "c1.nc"
    src.write_text(CYCLE_THEN_G91)
    err = save_errors(ErrorSet(workpiece=WorkpieceSetting((0.03, -0.025, 0.01), (0, 0, 0))),
                      tmp_path / "t.toml")
    out = tmp_path / "out.nc"
    r = run("compensate", src, "-m", "vmc-moving-column", "-e", err, "-o", out)
    assert r.returncode == 2 and not out.exists()
    assert f"{src}:3: the compensated block misses the programmed tool edge by 39.05 µm" in r.stderr
    assert "--start" in r.stderr and "Traceback" not in r.stderr
    # with the start stated every block is compensated and within tolerance
    r = run("compensate", src, "-m", "vmc-moving-column", "-e", err, "-o", out,
            "--start", "X=0,Y=0,Z=10")
    assert r.returncode == 0, r.stderr


def test_the_limit_is_the_tolerance_or_the_rounding_if_larger():
    """A 1 µm linear resolution leaves up to 0.87 µm at a block end from rounding alone: not
    refused (the limit is the larger of the tolerance and that bound); a block within
    tolerance passes."""
    from dataclasses import replace
    from mtcomp.commands import residual_limit
    m = load_machine("vmc-moving-column")
    assert residual_limit(m, 5e-4) == 5e-4
    coarse = replace(m, axes=tuple(replace(a, resolution=1e-3) for a in m.axes))
    assert residual_limit(coarse, 5e-4) == pytest.approx(np.sqrt(3) * 5e-4, rel=1e-6)
    text = "G90 G0 X0 Y0 Z5.\nG1 X10. Y3. Z-1. F100\n"
    _, rep = compensate_program(text, m, ErrorSet(ToolSetting((0.002, -0.001, 0.0005))))
    assert rep["after_max"] < 1e-4 and rep["before_max"] > 2e-3


# ------------------------------------------------------------------- one-line refusals
def test_huge_cycle_level_is_one_line_refusal_not_out_of_memory(tmp_path, run):
    for text, line in (("G99 G81 Z-6. R123456789012.5\n", 1),
                       ("G0 X0 Y0 Z10.\nG99 G81 X1. Z-6. R123456789012.5\nX2.\n", 2)):
        src = tmp_path / "v.nc"
        src.write_text(text)
        r = run("verify", src, "-m", "vmc-moving-column", "--stock", BOX)
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
        assert f"v.nc:{line}: the tool path of this block is 1.235e+08 m long" in r.stderr
        assert len(r.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("letter", ["G", "M", "H", "T"])
def test_300_digit_codes_give_the_error_line_and_no_warning(tmp_path, letter, run):
    src = tmp_path / "v.nc"
    src.write_text("G0 X1 " + letter + "9" * 300 + "\nG43 H1 Z10.\n")
    r = run("verify", src, "-m", "vmc-moving-column", "--stock", BOX)
    assert r.returncode == 2 and "RuntimeWarning" not in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "v.nc:1:" in r.stderr


def test_a_blank_after_the_sign_names_its_word():
    from mtcomp import gcode
    for text in ("G1 X 1.5 Y - 2.5\n", "G1 X1.5 Y - 2.5\n"):
        with pytest.raises(InputError, match=r":1: malformed number in word 'Y - 2.5'"):
            gcode.parse(text, axes=("X", "Y", "Z"))
    p = gcode.parse("G1 X 1.5 Y -2.5 Z0\n", axes=("X", "Y", "Z"))    # blanks after letters: read
    assert p.position[0].tolist() == [1.5, -2.5, 0.0]
    with pytest.raises(InputError, match=r":1: number '2.5' without an address letter"):
        gcode.parse("G1 X 1.5 2.5\n", axes=("X", "Y", "Z"))


# ------------------------------------------------------------------------- provenance
def test_output_equal_to_input_is_refused_also_by_another_name(tmp_path, run):
    src = tmp_path / "same.nc"
    src.write_text("G90 G0 X0 Y0 Z5.\nG1 X10. F100\n")
    before = src.read_bytes()
    err = save_errors(ErrorSet(ToolSetting((0.002, -0.001, 0.0005))), tmp_path / "e.toml")
    link = tmp_path / "link.nc"
    os.symlink(src, link)
    hard = tmp_path / "hard.nc"
    os.link(src, hard)
    for out in (src, link, hard, tmp_path / "sub" / ".." / "same.nc", err):
        (tmp_path / "sub").mkdir(exist_ok=True)
        r = run("compensate", src, "-m", "vmc-moving-column", "-e", err, "-o", out, "--force")
        assert r.returncode == 2 and "the output is the input" in r.stderr, (out, r.stderr)
    assert src.read_bytes() == before


def test_check_nc_write_is_the_one_rule(tmp_path):
    from mtcomp.gcode.provenance import check_nc_write
    text = f"({MARKER}: DO NOT COMPENSATE AGAIN)\nG0 X1\n"
    with pytest.raises(InputError, match=r"p.nc:1: this program was already compensated"):
        check_nc_write(text, filename="p.nc")
    check_nc_write(text, filename="p.nc", force=True)
    check_nc_write("G0 X1\n", filename="p.nc", output=tmp_path / "o.nc", inputs=(tmp_path / "p.nc",))


def _workpiece_errors(tmp_path):
    return save_errors(ErrorSet(workpiece=WorkpieceSetting((0.03, -0.025, 0.01), (0.02, -0.03, 0.15))),
                       tmp_path / "w.toml")


def test_workpiece_setting_compensate_writes_the_header_and_refuses_twice(tmp_path, run):
    """Its output had no header: `mtcomp compensate` of it applied the errors a second time
    with exit 0, and it transformed an already compensated program with exit 0."""
    src = tmp_path / "p.nc"
    src.write_text("G90 G0 X0 Y0 Z5.\nG1 Z0 F100\nG1 X2. Y1.\nG0 Z5.\n")
    err = _workpiece_errors(tmp_path)
    out = tmp_path / "w.nc"
    r = run("workpiece-setting", "compensate", src, "--errors", err, "-o", out, "--no-verify")
    assert r.returncode == 0, r.stderr
    assert compensated_line(out.read_text()) == 1
    assert "(VERSION mtcomp" in out.read_text() and "workpiece-setting compensate" in out.read_text()
    again = tmp_path / "again.nc"
    for cmd in (["compensate", out, "-m", "robonano-a0ib", "-e", err, "-o", again],
                ["workpiece-setting", "compensate", out, "--errors", err, "-o", again, "--no-verify"]):
        r = run(*cmd)
        assert r.returncode == 2 and "already compensated by mtcomp" in r.stderr, r.stderr
        assert not again.exists()
    r = run("workpiece-setting", "compensate", out, "--errors", err, "-o", again, "--no-verify",
            "--force")
    assert r.returncode == 0, r.stderr
    r = run("workpiece-setting", "compensate", src, "--errors", err, "-o", src, "--no-verify")
    assert r.returncode == 2 and "the output is the input" in r.stderr


def test_geometric_table_program_and_model_and_post_carry_the_marker(tmp_path, run):
    from mtcomp.errors import GeometricErrors
    src = tmp_path / "p.nc"
    src.write_text("G90 G0 X0 Y0 Z5.\nG1 Z0 F100\nG1 X20. Y10.\nG0 Z5.\n")
    geo = ErrorSet(geometric=GeometricErrors(location={"EB0X": 20e-6}))
    err = save_errors(geo, tmp_path / "g.toml")
    out = tmp_path / "tab"
    r = run("geometric", "table", err, "--program", src, "-o", out)
    assert r.returncode == 0, r.stderr
    written = (out / "p_comp.nc").read_text()
    assert compensated_line(written) == 1 and "geometric table --program" in written
    r = run("geometric", "table", err, "--program", out / "p_comp.nc", "-o", tmp_path / "tab2")
    assert r.returncode == 2 and "already compensated" in r.stderr
    assert not (tmp_path / "tab2" / "p_comp_comp.nc").exists()
    r = run("geometric", "table", err, "--program", out / "p_comp.nc", "-o", tmp_path / "tab2",
            "--force")
    assert r.returncode == 0, r.stderr


def test_the_cell_refuses_a_compensated_part_program_and_its_marker_counts(tmp_path):
    from mtcomp.cell.program import CellFault
    from mtcomp.cell.cycle import Job
    from mtcomp.cell.virtual import VirtualCell
    good = "O0100\nG90 G21 G54\nG00 X0 Y0 Z2.\nG01 Z-0.1 F100.\nG01 X1. Y0.5\nG00 Z3.\nM30\n"
    (tmp_path / "O0100.nc").write_text(good.replace("O0100\n", f"O0100\n({MARKER})\n"))
    with pytest.raises(CellFault, match=r"already compensated by mtcomp"):
        VirtualCell(nc_dir=str(tmp_path))(Job(1, 5, 100))
    assert not (tmp_path / "O1100.nc").exists()
    (tmp_path / "O0100.nc").write_text(good)
    VirtualCell(nc_dir=str(tmp_path))(Job(2, 5, 100))
    # the cell's marker line is its provenance header: `mtcomp compensate` refuses its output
    assert compensated_line((tmp_path / "O1100.nc").read_text()) == 2


def test_the_cam_post_marks_a_compensated_program():
    """A program the post compensated (errors given) carries the marker: `mtcomp compensate`
    refuses it; one posted without errors does not."""
    from mtcomp.cad_plugin import post as P, toolpath as T
    from mtcomp.cad_plugin.layout import GratingLayout
    m = load_machine("robonano-ui")
    g = GratingLayout()
    tp = T.grating_passes(g.sphere_radius, g.psi[:1], g.span, g.depth, T.Tool("vtool"))
    err = ErrorSet(tool=ToolSetting((0.49, 0.68, -0.012)))
    text = P.post(m, tp, errors=err, errors_name="setting.toml")
    assert compensated_line(text) is not None
    with pytest.raises(InputError, match="already compensated"):
        compensate_program(text, m, err)
    assert compensated_line(P.post(m, tp)) is None


# --------------------------------------------------------------------- verify says what
def test_verify_without_part_says_rapids_only_and_checks_cycle_holes(tmp_path, run):
    """Without --part the summary says what was checked; a canned cycle's rapid down to an R
    level inside the stock is found (a cycle block was one point: never checked)."""
    src = tmp_path / "c.nc"
    src.write_text("G90 G0 X0 Y0 Z10.\nG99 G81 X1. Y1. Z-2. R2. F100\nX2.\nG80\nG0 Z10.\n")
    r = run("verify", src, "-m", "vmc-moving-column", "--stock", BOX)
    assert r.returncode == 0 and "passed (rapids only: the feed moves" in r.stdout
    src.write_text("G90 G0 X0 Y0 Z10.\nG99 G81 X1. Y1. Z-2. R-1. F100\nG80\nG0 Z10.\n")
    r = run("verify", src, "-m", "vmc-moving-column", "--stock", BOX)
    assert r.returncode == 2 and "line 2" in r.stdout and "FAIL" in r.stdout


def test_the_part_check_shows_progress_and_finds_a_gouge():
    """--part: the distance to a STEP solid takes about 0.3 ms per sample; the check reports
    its progress (here into a buffer) and still finds the block that cuts 0.1 mm into it."""
    import io

    import cadquery as cq

    from mtcomp.progress import Progress
    from mtcomp.verify import ShapeStock, verify_program
    part = ShapeStock(cq.Workplane().box(4, 4, 2).translate((0, 0, -1)), "part")
    text = "G90 G0 X-3. Y0 Z1.\nG1 Z0 F100\nX-1.\nZ-0.1\nX1.\nG0 Z1.\n"
    buf = io.StringIO()
    res = verify_program(load_machine("vmc-moving-column"), text, part=part,
                         raise_on_violation=False, progress=Progress("part", True, buf))
    assert "100.0%" in buf.getvalue()
    assert [v.line for v in res.violations] == [4, 5] and res.min_part == pytest.approx(-0.1)
