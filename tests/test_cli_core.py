"""`mtcomp compensate` and `mtcomp machines` end to end, through the installed entry point."""
import subprocess
import sys

import numpy as np
import pytest

from mtcomp import gcode
from mtcomp.commands import compensate_program
from mtcomp.errors import ErrorSet, ToolSetting, WorkpieceSetting, save_errors
from mtcomp.kinematics import forward
from mtcomp.machine import load_machine


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "mtcomp", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=120)


PROGRAM = """O0042 (5-axis test program)
G21 G90 G17
N10 G0 X0 Y0 Z5. B15. C0
N20 G1 Z0 F200
N30 X5.0 Y2 C30.5 ; cut
N40 Y-3.25 B20
N50 G0 Z5.
M30
"""


@pytest.fixture
def setup(tmp_path):
    prog = tmp_path / "p.nc"
    prog.write_text(PROGRAM)
    err = save_errors(ErrorSet(ToolSetting((0.49, -0.68, 0.1)), WorkpieceSetting((0.03, -0.02, 0.01), (0, 0, 0.1))),
                      tmp_path / "e.toml")
    return prog, err


def test_compensate_cli_round_trip(setup, tmp_path):
    prog, err = setup
    out = tmp_path / "out.nc"
    r = run("compensate", prog, "--machine", "robonano-a0ib", "--errors", err, "-o", out)
    assert r.returncode == 0, r.stderr
    assert "before compensation" in r.stdout and "after  compensation" in r.stdout
    m = load_machine("robonano-a0ib")
    E = ErrorSet(ToolSetting((0.49, -0.68, 0.1)), WorkpieceSetting((0.03, -0.02, 0.01), (0, 0, 0.1)))
    p0 = gcode.parse(PROGRAM, axes=m.axis_names)
    p1 = gcode.parse(out.read_text(), axes=m.axis_names)
    target = forward(m, p0.position).p
    before = np.abs(forward(m, p0.position, E).p - target).max()
    after = np.abs(forward(m, p1.position, E).p - target).max()
    assert before > 0.4  # mm: the setting errors are hundreds of um
    assert after < 2e-6  # 1 nm and 1e-5 deg resolution: rounding leaves about a nanometre
    # Everything but axis words stays: comments, N numbers, M30.
    assert out.read_text().splitlines()[0] == "O0042 (5-axis test program)"
    assert "; cut" in out.read_text() and out.read_text().rstrip().endswith("M30")


def test_zero_errors_reproduce_program_byte_for_byte():
    m = load_machine("robonano-a0ib")
    text, rep = compensate_program(PROGRAM, m, ErrorSet())
    assert text == PROGRAM and rep["before_max"] == 0 and rep["after_max"] == 0


def test_compensate_refuses_unknown_code_naming_line(setup, tmp_path):
    prog, err = setup
    prog.write_text(PROGRAM.replace("N40 Y-3.25", "N40 G68 Y-3.25"))
    out = tmp_path / "out.nc"
    r = run("compensate", prog, "-m", "robonano-a0ib", "-e", err, "-o", out)
    assert r.returncode == 2 and f"{prog}:6" in r.stderr
    assert not out.exists() and not list(tmp_path.glob(".out.nc*"))


def test_compensate_travel_limit_names_line(setup, tmp_path):
    prog, err = setup
    prog.write_text(PROGRAM.replace("N40 Y-3.25", "N40 Y39.8"))
    out = tmp_path / "out.nc"
    r = run("compensate", prog, "-m", "robonano-a0ib", "-e", err, "-o", out)
    assert r.returncode == 2, r.stdout
    assert f"{prog}:6" in r.stderr and "axis Y" in r.stderr and "travel" in r.stderr
    assert not out.exists()


@pytest.mark.parametrize("bad", ["missing_program", "missing_errors", "bad_machine"])
def test_missing_inputs(setup, tmp_path, bad):
    prog, err = setup
    args = {"missing_program": (tmp_path / "nope.nc", "robonano-a0ib", err),
            "missing_errors": (prog, "robonano-a0ib", tmp_path / "nope.toml"),
            "bad_machine": (prog, "no-such-machine", err)}[bad]
    r = run("compensate", args[0], "-m", args[1], "-e", args[2], "-o", tmp_path / "o.nc")
    named = "no-such-machine" if bad == "bad_machine" else "nope"
    assert r.returncode == 2 and "error:" in r.stderr and named in r.stderr, r.stderr
    assert not (tmp_path / "o.nc").exists()


def test_machines_and_help():
    r = run("machines")
    assert r.returncode == 0 and "robonano-ui" in r.stdout and "vmc-moving-column" in r.stdout
    r = run("machines", "robonano-ui")
    assert r.returncode == 0 and 'name = "robonano-ui"' in r.stdout
    r = run("--help")
    assert r.returncode == 0 and "compensate" in r.stdout


def test_import_is_light():
    code = ("import sys, time; t = time.perf_counter(); import mtcomp, mtcomp.kinematics, mtcomp.cli; "
            "print(time.perf_counter() - t); "
            "assert not {'cadquery', 'fmpy', 'pymodbus', 'matplotlib'} & set(sys.modules), sorted(sys.modules)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


def test_shipped_example_after_error_with_linearised_arcs(tmp_path):
    """The README example: arcs tilted by the workpiece rotation are linearised, and the
    before/after figures compare each input block with the output block that ends it."""
    from pathlib import Path
    root = Path(__file__).resolve().parent.parent
    out = tmp_path / "g.nc"
    r = run("compensate", root / "examples/programs/groove5x.nc", "-m", "robonano-a0ib",
            "-e", root / "examples/errors/setting-example.toml", "-o", out)
    assert r.returncode == 0, r.stderr
    after_nm = float(r.stdout.split("after  compensation: max")[1].split("nm")[0])
    before_um = float(r.stdout.split("before compensation: max")[1].split("µm")[0])
    assert after_nm < 2.0 and before_um > 300
    text = out.read_text()
    assert "LINEARISED, CHORDAL TOLERANCE 0.000100 MM" in text  # the tolerance is stated in the output
    assert len(text.splitlines()) > len((root / "examples/programs/groove5x.nc").read_text().splitlines())


def test_crlf_program_kept_byte_for_byte(tmp_path):
    prog = tmp_path / "crlf.nc"
    prog.write_bytes(PROGRAM.replace("\n", "\r\n").encode())
    err = tmp_path / "zero.toml"
    err.write_text("")
    out = tmp_path / "o.nc"
    r = run("compensate", prog, "-m", "robonano-a0ib", "-e", err, "-o", out)
    assert r.returncode == 0, r.stderr
    from mtcomp.gcode.provenance import strip_header
    assert strip_header(out.read_bytes().decode()).encode() == prog.read_bytes()


# ---- issue 15/19 reproducers: every bad input is one line and a non-zero exit, never a traceback

def main_inproc(argv):
    """mtcomp's main in this process: (exit status, stdout, stderr)."""
    import contextlib
    import io
    from mtcomp.cli import main
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = main([str(a) for a in argv])
        except SystemExit as exc:  # argparse usage errors
            rc = exc.code
    return rc, out.getvalue(), err.getvalue()


def _one_line_error(rc, err, status=2):
    assert rc == status, err
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith(("usage:", " "))]
    assert len(lines) == 1, err
    return lines[0]


def test_internal_error_is_one_line_and_debug_shows_traceback(monkeypatch):
    import mtcomp.commands as commands

    def boom(args):
        return {}["no such key"]
    monkeypatch.setattr(commands, "_cmd_machines", boom)
    rc, _, err = main_inproc(["machines"])
    line = _one_line_error(rc, err, 3)
    assert "internal error: KeyError" in line and "--debug" in line
    rc, _, err = main_inproc(["machines", "--debug"])  # accepted after the command too
    assert rc == 3 and "Traceback" in err and "boom" in err


@pytest.mark.parametrize("target", ["dir", "nonexist", "file_parent"])
def test_output_paths_refused_cleanly(setup, tmp_path, target):
    prog, err = setup
    (tmp_path / "adir").mkdir()
    (tmp_path / "afile").write_text("x")
    out = {"dir": tmp_path / "adir", "nonexist": tmp_path / "nonexist" / "deeper" / "x.nc",
           "file_parent": tmp_path / "afile" / "x.nc"}[target]
    rc, _, e = main_inproc(["compensate", prog, "-m", "robonano-a0ib", "-e", err, "-o", out])
    line = _one_line_error(rc, e)
    # the compensate command's own check and the CLI's generic one word it differently
    assert (("is a folder" in line or "is a directory" in line) if target == "dir"
            else ("cannot write" in line))
    assert not (tmp_path / "nonexist").exists()
    assert sorted(p.name for p in (tmp_path / "adir").iterdir()) == []


def test_existing_file_as_output_folder(tmp_path):
    afile = tmp_path / "AFILE"
    afile.write_text("keep")
    rc, _, e = main_inproc(["tool-setting", "plan", "-o", afile])
    assert "already exists and is not a folder" in _one_line_error(rc, e)
    rc, _, e = main_inproc(["demo", "--out", afile, "--quick"])
    line = _one_line_error(rc, e)
    assert "already exists and is not a folder" in line or "is an existing file" in line
    assert afile.read_text() == "keep"


def test_device_as_program_is_refused(setup, tmp_path):
    _, err = setup
    rc, _, e = main_inproc(["compensate", "/dev/zero", "-m", "robonano-a0ib", "-e", err, "-o", tmp_path / "o.nc"])
    line = _one_line_error(rc, e)
    assert "not a regular file" in line or "not a text file" in line


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "abc"])
def test_chordal_tolerance_checked_by_the_parser(setup, tmp_path, value):
    prog, err = setup
    rc, _, e = main_inproc(["compensate", prog, "-m", "robonano-a0ib", "-e", err, "-o", tmp_path / "o.nc",
                            f"--chordal-tol={value}"])
    assert "--chordal-tol" in _one_line_error(rc, e)
    assert not (tmp_path / "o.nc").exists()


@pytest.mark.parametrize("toml, csv, field", [
    ("[geometric.location]\nEX0U = 0.001\n", None, "geometric.location.EX0U"),
    ("[geometric.location]\nEC0W = 1e-6\n", None, "geometric.location.EC0W"),
    ("[geometric.location]\nEX0A = 0.002\n", None, "geometric.location.EX0A"),
    ("[geometric.tables]\nU = 'u.csv'\n", "position,EXU\n0,0.001\n10,0.002\n", "geometric.tables.U"),
])
def test_errors_of_axes_the_machine_lacks_are_refused(setup, tmp_path, toml, csv, field):
    prog, _ = setup
    err = tmp_path / "axes.toml"
    err.write_text("# errors of an axis robonano-a0ib does not have\n" + toml)
    if csv:
        (tmp_path / "u.csv").write_text(csv)
    out = tmp_path / "o.nc"
    rc, _, e = main_inproc(["compensate", prog, "-m", "robonano-a0ib", "-e", err, "-o", out])
    line = _one_line_error(rc, e)
    assert f"axes.toml:3 [{field}]" in line and "has axes C B X Y Z" in line
    assert not out.exists()


def test_machine_resolution_not_a_power_of_ten(setup, tmp_path):
    prog, err = setup
    from mtcomp._io import dump_toml
    d = load_machine("robonano-a0ib").to_dict()
    d["axis"][2]["resolution"] = 5e-6
    mf = tmp_path / "m.toml"
    mf.write_text(dump_toml(d))
    rc, _, e = main_inproc(["compensate", prog, "-m", mf, "-e", err, "-o", tmp_path / "o.nc"])
    line = _one_line_error(rc, e)
    assert "[axis[2].resolution]" in line and "power of ten" in line


def test_machines_prints_arrays_on_one_line():
    rc, out, _ = main_inproc(["machines", "robonano-a0ib"])
    assert rc == 0
    assert "direction = [0.0, 0.0, 1.0]" in out and "limits = [-360.0, 360.0]" in out
    from mtcomp._io import parse_toml
    assert parse_toml(out) == load_machine("robonano-a0ib").to_dict()


def test_an_output_that_is_a_device_or_pipe_is_refused_not_replaced(tmp_path):
    """The atomic rename would replace the node itself: a fuzz run as root turned /dev/zero
    into a text file with `-o /dev/zero`.  A FIFO stands in for the device here."""
    import os
    import stat
    from mtcomp._io import InputError, atomic_write
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="not a regular file"):
        atomic_write(fifo, "x")
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert [p.name for p in tmp_path.iterdir()] == ["pipe"]        # no temporary file left
    rc, _, e = main_inproc(["workpiece-setting", "plan", "-o", fifo])
    assert rc == 2 and "not a regular file" in _one_line_error(rc, e)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
