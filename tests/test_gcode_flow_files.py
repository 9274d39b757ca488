"""Subprograms in other files (issue 20): Fanuc/Haas M98 P<n> program files and LinuxCNC
o<name> call files, searched in the program's directory and --subprogram-path; written out in
the output (the control's own copies would run uncompensated)."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from mtcomp import InputError, gcode
from mtcomp.commands import compensate_program
from mtcomp.errors import ErrorSet, ToolSetting, save_errors
from mtcomp.gcode import flow
from mtcomp.machine import load_machine

XYZ = ("X", "Y", "Z")
MAIN = "%\nO0001 (MAIN)\nG21 G90 G54\nG0 X0 Y0 Z5.\nM98 P1234 L2\nG0 Z5.\nM30\n%\n"
SUB = "%\nO1234 (STEP)\nG91 G1 X10. F100\nY10.\nG90\nM99\n%\n"
# the same program as it runs, written by hand
INLINE = ("G21 G90 G54\nG0 X0 Y0 Z5.\nG91 G1 X10. F100\nY10.\nG90\nG91 G1 X10. F100\nY10.\nG90\n"
          "G0 Z5.\nM30\n")
M = load_machine("vmc-moving-column")
E = ErrorSet(ToolSetting((0.002, -0.001, 0.0005)))


def run(*args):
    return subprocess.run([sys.executable, "-m", "mtcomp", *map(str, args)], capture_output=True,
                          text=True, timeout=120)


@pytest.mark.parametrize("subname", ["O1234.nc", "O1234", "1234.NC", "O01234.txt"])
def test_fanuc_program_file_is_followed(tmp_path, subname):
    main = tmp_path / "main.nc"
    main.write_text(MAIN)
    (tmp_path / subname).write_text(SUB)
    fl = flow.expand(MAIN, str(main), search=[str(tmp_path)])
    assert fl.external and fl.calls == 2
    got = gcode.parse(fl.expanded, axes=XYZ)
    want = gcode.parse(INLINE, axes=XYZ)
    assert np.array_equal(got.position, want.position) and np.array_equal(got.known, want.known)
    out, rep = compensate_program(MAIN, M, E, filename=str(main), search_path=[str(tmp_path)])
    assert rep["flow"] == "expanded" and any(subname in n for n in rep["notes"])
    assert "(M98) (P1234) (L2)" in out and out.count("G91 G1 X10. F100") == 2
    back = gcode.parse(out, axes=XYZ)
    comp = gcode.parse(compensate_program(INLINE, M, E)[0], axes=XYZ)
    assert np.allclose(back.position, comp.position)
    # not searched: refused naming the call
    with pytest.raises(InputError, match=r"main.nc:5: M98 P1234: program O1234 is neither in this file"):
        compensate_program(MAIN, M, E, filename=str(main))


def test_subprogram_path_on_the_cli(tmp_path):
    (tmp_path / "prog").mkdir()
    (tmp_path / "subs").mkdir()
    main = tmp_path / "prog" / "main.nc"
    main.write_text(MAIN)
    (tmp_path / "subs" / "O1234.nc").write_text(SUB)
    err = save_errors(E, tmp_path / "e.toml")
    out = tmp_path / "o.nc"
    r = run("compensate", main, "-m", M.name, "-e", err, "-o", out)
    assert r.returncode == 2 and "main.nc:5: M98 P1234" in r.stderr
    r = run("compensate", main, "-m", M.name, "-e", err, "-o", out, "--subprogram-path", tmp_path / "subs")
    assert r.returncode == 0, r.stderr
    assert "O1234.nc" in r.stdout and "written out" in r.stdout
    assert out.read_text().count("(M99)") == 2 and "; subprogram-path " in out.read_text()
    r = run("compensate", main, "-m", M.name, "-e", err, "-o", out, "--subprogram-path", tmp_path / "none")
    assert r.returncode == 2 and "--subprogram-path" in r.stderr


def test_linuxcnc_named_and_local_subroutines(tmp_path):
    main = tmp_path / "lc.ngc"
    text = ("o100 sub\ng1 x3 y3\no100 endsub\ng21 g90\ng0 x0 y0 z5\no<pocket> call\no100 call\nm2\n")
    main.write_text(text)
    (tmp_path / "pocket.ngc").write_text("o<pocket> sub\ng1 z-1 f100\ng1 x5\ng0 z5\no<pocket> endsub\nm2\n")
    fl = flow.expand(text, str(main), search=[str(tmp_path)])
    want = gcode.parse("g21 g90\ng0 x0 y0 z5\ng1 z-1 f100\ng1 x5\ng0 z5\ng1 x3 y3\nm2\n", axes=XYZ)
    assert np.array_equal(gcode.parse(fl.expanded, axes=XYZ).position, want.position)
    out, rep = compensate_program(text, M, E, filename=str(main), search_path=[str(tmp_path)])
    assert rep["flow"] == "expanded" and "(o<pocket> call)" in out and "o100 sub" not in out.split("m2")[-1]
    # a local subroutine alone is compensated once, the calls kept
    local = "o100 sub\ng1 x3 y3\no100 endsub\ng21 g90\ng0 x0 y0 z5\no100 call\no100 call\nm2\n"
    out, rep = compensate_program(local, M, E, filename="l.ngc")
    assert rep["flow"] == "once" and out.splitlines()[5:7] == ["o100 call", "o100 call"]
    assert out.splitlines()[1] == "g1 x2.9980 y3.0010"


@pytest.mark.parametrize("files,text,where,what", [
    ({"O1234.nc": SUB, "1234.txt": SUB}, MAIN, "main.nc:5", "several files could be program O1234"),
    ({"O1234.nc": SUB.replace("O1234", "O5678")}, MAIN, "main.nc:5", "holds another program"),
    ({"O1234.nc": SUB.replace("Y10.", "G12 Y10.")}, MAIN, "O1234.nc:4", "unknown G code G12"),
    ({"O1234.nc": SUB.replace("M99", "M30")}, MAIN, "O1234.nc:6", "M30/M02 inside a subprogram"),
    ({}, "g0 x0 y0 z0\no<nope> call\nm2\n", "main.nc:2", "no o<nope> sub in this file nor a file nope.ngc"),
    ({"p.ngc": "o<p> sub\ng0 x1\no<p> endsub\n"}, "g0 x0 y0 z0\no<p> call [2]\nm2\n", "main.nc:2",
     "call with arguments"),
    ({"p.ngc": "o<p> sub\ng0 x1\no<p> return\no<p> endsub\n"}, "g0 x0 y0 z0\no<p> call\nm2\n",
     "p.ngc:3", "o-word 'return'"),
])
def test_subprogram_files_refused_with_the_file_and_line(tmp_path, files, text, where, what):
    main = tmp_path / "main.nc"
    main.write_text(text)
    for name, body in files.items():
        (tmp_path / name).write_text(body)
    with pytest.raises(InputError) as exc:
        compensate_program(text, M, E, filename=str(main), search_path=[str(tmp_path)])
    msg = str(exc.value)
    assert f"{where}: " in msg and what in msg, msg


def test_m97_in_a_subprogram_file_jumps_within_that_file(tmp_path):
    # Haas: M97 P<n> runs the block N<n> of the program it is in, here the subprogram file,
    # not the main program (which has an N100 of its own)
    main = tmp_path / "main.nc"
    text = "%\nO0001\nG21 G90\nN100 G0 X0 Y0 Z5.\nM98 P1234\nG0 Z50.\nM30\n%\n"
    main.write_text(text)
    (tmp_path / "O1234.nc").write_text("%\nO1234 (LOCAL)\nG0 X1. Y2.\nM97 P100 L2\nG0 Z5.\nM99\n"
                                       "N100 G91 G1 X5. F100\nG90\nM99\n%\n")
    fl = flow.expand(text, str(main), search=[str(tmp_path)])
    inline = ("G21 G90\nG0 X0 Y0 Z5.\nG0 X1. Y2.\nG91 G1 X5. F100\nG90\nG91 G1 X5. F100\nG90\n"
              "G0 Z5.\nG0 Z50.\nM30\n")
    got, want = gcode.parse(fl.expanded, axes=XYZ), gcode.parse(inline, axes=XYZ)
    assert np.array_equal(got.position, want.position)
    assert got.position[-2].tolist() == [11.0, 2.0, 5.0]
    # a label only in the main program is not found from the subprogram file
    (tmp_path / "O1234.nc").write_text("%\nO1234\nM97 P100\nM99\n%\n")
    with pytest.raises(InputError, match=r"O1234.nc:3: M97 P100: no block N100 in this program"):
        flow.expand(text, str(main), search=[str(tmp_path)])
