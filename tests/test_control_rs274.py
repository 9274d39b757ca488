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
    from mtcomp.cad_plugin.post import post
    from mtcomp.cad_plugin.toolpath import groove_plate_passes
    from mtcomp.machine import load_machine
    prog = tmp_path / "groove_plate.nc"
    prog.write_text(post(load_machine("robonano-a0ib"), groove_plate_passes()))
    c = rs274.compare(prog)
    assert c.n_mtcomp >= 50 and c.differing == 0, c.first


def test_compensated_program_agrees(tmp_path):
    """A program mtcomp compensate wrote (a0ib, synthetic geometric errors) reads the same in rs274."""
    from mtcomp.cli import main
    from mtcomp.control.synthetic import grid_errors
    from mtcomp.errors import save_errors
    errors, _ = grid_errors("robonano-a0ib", seed=5, reversal=False)
    save_errors(errors, tmp_path / "e.toml")
    out = tmp_path / "comp.nc"
    assert main(["compensate", "--machine", "robonano-a0ib", "--errors", str(tmp_path / "e.toml"),
                 str(ROOT / "examples" / "programs" / "groove5x.nc"), "-o", str(out)]) == 0
    assert out.read_text() != (ROOT / "examples" / "programs" / "groove5x.nc").read_text()
    c = rs274.compare(out)
    assert c.n_mtcomp >= 50 and c.differing == 0, c.first


def test_a_difference_is_found(tmp_path, monkeypatch):
    """The comparison can fail: rs274 reads a program 1 µm off from what mtcomp is given."""
    good = NC / "linuxcnc.ngc"
    bad = tmp_path / "bad.ngc"
    bad.write_text(good.read_text().replace("g1 x 20 y 0", "g1 x 20.001 y 0"))
    real = rs274.mtcomp_moves
    monkeypatch.setattr(rs274, "mtcomp_moves", lambda path, *a, **k: real(good, *a, **k))
    c = rs274.compare(bad)
    assert c.differing >= 1 and "20.0" in c.first
