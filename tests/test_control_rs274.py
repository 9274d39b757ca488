"""LinuxCNC's own interpreter (rs274, Debian linuxcnc-uspace) against mtcomp's reading of the same
programs: every LinuxCNC-dialect program in examples/ and tests/data, the CAM post's output and a
program mtcomp compensate wrote -- 0 differing positions."""
from __future__ import annotations

from pathlib import Path

import pytest

from mtcomp.control import rs274

pytestmark = pytest.mark.skipif(not rs274.available(), reason="rs274 (apt linuxcnc-uspace) not installed")

ROOT = Path(__file__).resolve().parents[1]
NC = ROOT / "tests" / "data" / "nc"
# the LinuxCNC dialect: the .ngc programs, FreeCAD's LinuxCNC post, and the example (plain G-code
# without Fanuc-only words); the Fanuc/Haas/Siemens ones use M98/G68/G16/inch data rs274 reads otherwise
PROGRAMS = sorted(NC.glob("*.ngc")) + [NC / "freecad_post.nc", ROOT / "examples" / "programs" / "groove5x.nc"]


@pytest.mark.parametrize("path", PROGRAMS, ids=lambda p: p.name)
def test_rs274_agrees_position_by_position(path):
    c = rs274.compare(path, subroutine_path=NC / "subprograms")
    assert c.n_mtcomp > 0 and c.n_rs274 > 0
    assert c.differing == 0, c.first
    assert c.matched == c.n_mtcomp


def test_cam_post_output_agrees(tmp_path):
    """The post's output in LinuxCNC's dialect: its Fanuc safe-start line (G69 G15 G50.1) is an
    unknown G code to rs274, which stops there, and LinuxCNC's G28 goes to the stored reference
    position, so the safe start is the common part and the retract is left out."""
    from mtcomp.cad_plugin.post import PostOptions, post
    from mtcomp.cad_plugin.toolpath import groove_plate_passes
    from mtcomp.machine import load_machine
    prog = tmp_path / "groove_plate.nc"
    opts = PostOptions(preamble="G21\nG17 G40 G49 G80 G90 G94\n{work_offset}", retract="none")
    prog.write_text(post(load_machine("robonano-a0ib"), groove_plate_passes(), options=opts))
    c = rs274.compare(prog)
    assert c.n_mtcomp >= 50 and c.differing == 0, c.first
    # the default (Fanuc) safe start is refused by LinuxCNC's interpreter by name
    fanuc = tmp_path / "fanuc.nc"
    fanuc.write_text(post(load_machine("robonano-a0ib"), groove_plate_passes()))
    assert rs274.compare(fanuc).n_rs274 == 0


def test_compensated_program_agrees(tmp_path):
    """A program mtcomp compensate wrote (a0ib, synthetic geometric errors) reads the same in rs274."""
    from mtcomp.cli import main
    from mtcomp.control.synthetic import grid_errors
    from mtcomp.errors import save_errors
    errors, _ = grid_errors("robonano-a0ib", seed=5, reversal=False)
    save_errors(errors, tmp_path / "e.toml")
    out = tmp_path / "comp.nc"
    # geometric errors live at machine positions: the program's G54 is stated (here: at the
    # machine origin), as compensate asks for it with tables
    (tmp_path / "offsets.toml").write_text("[G54]\nX = 0.0\nY = 0.0\nZ = 0.0\nB = 0.0\nC = 0.0\n")
    assert main(["compensate", "--machine", "robonano-a0ib", "--errors", str(tmp_path / "e.toml"),
                 "--offsets", str(tmp_path / "offsets.toml"),
                 str(ROOT / "examples" / "programs" / "groove5x.nc"), "-o", str(out)]) == 0
    assert out.read_text() != (ROOT / "examples" / "programs" / "groove5x.nc").read_text()
    c = rs274.compare(out)
    assert c.n_mtcomp >= 50 and c.differing == 0, c.first


def test_a_difference_is_found(tmp_path, monkeypatch):
    """The comparison can fail: rs274 reads a program 1 µm off from what mtcomp is given."""
    good = NC / "linuxcnc.ngc"
    bad = tmp_path / "bad.ngc"
    bad.write_text(good.read_text().replace("g1 x 20 y 0", "g1 x 20.001 y 0"))
    real = rs274.mtcomp_moves_and_start
    monkeypatch.setattr(rs274, "mtcomp_moves_and_start", lambda path, *a, **k: real(good, *a, **k))
    c = rs274.compare(bad)
    assert c.differing >= 1 and "20.0" in c.first


SHIPPED = Path("/usr/share/linuxcnc/ncfiles")      # LinuxCNC's own example programs (installed with it)


# mtcomp's subprogram expansion keeps only the lines before "o1000 sub" of this one (an o-word
# macro with # parameters): 0 moves, and compensate passes it on unchanged with exit 0, where
# rs274 runs 3,076 moves
KNOWN_SILENT = {"flowsnake.ngc"}


@pytest.mark.slow
@pytest.mark.skipif(not SHIPPED.is_dir(), reason="LinuxCNC's example programs not installed")
def test_linuxcnc_shipped_programs_agree():
    """Every example program LinuxCNC ships that mtcomp reads (o-word macros and the like it
    refuses by name) agrees with rs274: 0 differing positions, inch programs included; none that
    rs274 moves through is read by mtcomp as a program without moves."""
    from mtcomp._io import InputError
    agree, differ = [], []
    for f in sorted(SHIPPED.rglob("*.ngc")):
        if f.name in KNOWN_SILENT:
            continue
        try:
            c = rs274.compare(f, subroutine_path=SHIPPED)
        except (InputError, RuntimeError):      # mtcomp refuses it, or rs274 stops on it
            continue
        if c.n_mtcomp or c.n_rs274:
            (agree if c.differing == 0 and c.n_mtcomp else differ).append(f.name)
    assert not differ, differ
    assert len(agree) >= 10 and "arcspiral.ngc" in agree and "plasmatest.ngc" in agree


@pytest.mark.skipif(not (SHIPPED / "flowsnake.ngc").exists(), reason="LinuxCNC's example programs not installed")
@pytest.mark.xfail(strict=True, reason="mtcomp's subprogram expansion keeps only the lines before "
                                       "'o1000 sub': 0 moves and no refusal (core/gcode/flow.py)")
def test_flowsnake_is_read_or_refused():
    from mtcomp._io import InputError
    try:
        c = rs274.compare(SHIPPED / "flowsnake.ngc", subroutine_path=SHIPPED)
    except InputError:
        return                                   # refused by name: fine
    assert c.n_mtcomp > 0 and c.differing == 0
