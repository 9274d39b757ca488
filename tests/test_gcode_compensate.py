"""`mtcomp compensate` on NC programs: provenance, no double compensation, clean errors for the
NC parts of issues 14 and 15."""
from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mtcomp import InputError, gcode
from mtcomp.commands import compensate_program
from mtcomp.errors import ErrorSet, GeometricErrors, ToolSetting, WorkpieceSetting, save_errors
from mtcomp.gcode.provenance import insert_header, strip_header
from mtcomp.machine import load_machine

PROGRAM = "%\nO0042 (TEST)\nG21 G90 G17\nG0 X0 Y0 Z5.\nG1 Z0 F200\nG2 X10. Y0 I5. J0\nG0 Z5.\nM30\n%\n"


def run(*args):
    return subprocess.run([sys.executable, "-m", "mtcomp", *map(str, args)], capture_output=True,
                          text=True, timeout=120)


@pytest.fixture
def files(tmp_path):
    prog = tmp_path / "p.nc"
    prog.write_text(PROGRAM)
    err = save_errors(ErrorSet(ToolSetting((0.002, -0.001, 0.0005))), tmp_path / "e.toml")
    return prog, err


def test_provenance_header_and_refusal_to_compensate_again(files, tmp_path):
    prog, err = files
    out = tmp_path / "o.nc"
    r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", out)
    assert r.returncode == 0, r.stderr
    text = out.read_text()
    lines = text.splitlines()
    # after % and the program number, as controls expect them first
    assert lines[:2] == ["%", "O0042 (TEST)"]
    assert lines[2].startswith("(MTCOMP COMPENSATED PROGRAM")
    head = "\n".join(lines[2:9])
    sha = hashlib.sha256(err.read_bytes()).hexdigest()
    for item in ("(VERSION mtcomp ", f"(ERRORS e.toml SHA256 {sha})", "(MACHINE vmc-moving-column)",
                 "(DATE 20", "(SOURCE p.nc)", "(OPTIONS "):
        assert item in head, head
    assert strip_header(text).splitlines()[:3] == PROGRAM.splitlines()[:3]
    again = tmp_path / "o2.nc"
    r = run("compensate", out, "-m", "vmc-moving-column", "-e", err, "-o", again)
    assert r.returncode == 2 and "already compensated by mtcomp" in r.stderr
    assert f"{out}:3:" in r.stderr and not again.exists()
    r = run("compensate", out, "-m", "vmc-moving-column", "-e", err, "-o", again, "--force")
    assert r.returncode == 0, r.stderr


def test_zero_errors_byte_exact_apart_from_the_header(files, tmp_path):
    prog, _ = files
    err = tmp_path / "zero.toml"
    err.write_text("")
    out = tmp_path / "o.nc"
    assert run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", out).returncode == 0
    assert strip_header(out.read_text()) == PROGRAM


def test_header_in_semicolon_programs_and_crlf():
    text, at, n = insert_header("; siemens\r\nG0 X1\r\n", ["MTCOMP COMPENSATED PROGRAM: X", "MACHINE m"])
    assert text == "; MTCOMP COMPENSATED PROGRAM: X\r\n; MACHINE m\r\n; siemens\r\nG0 X1\r\n"
    assert strip_header(text) == "; siemens\r\nG0 X1\r\n"


@pytest.mark.parametrize("body", [PROGRAM, "G21 G90\nG0 X0 Y0 Z-10.\nG1 X10. F100\nM30\n",
                                  "(HEAD)\r\nG21 G90\r\nG0 X0 Y0 Z-10.\r\nM30", "%"])
def test_header_goes_after_a_byte_order_mark(body):
    """A program starting with a UTF-8 byte-order mark keeps it as its first character: the
    header used to be inserted before it, which left the mark in the middle of the output (a
    stray character to a control; the read-back refused it in some programs)."""
    text = "\ufeff" + body
    new, at, n = insert_header(text, ["MTCOMP COMPENSATED PROGRAM: X", "MACHINE m"])
    assert new.startswith("\ufeff") and new.count("\ufeff") == 1
    assert strip_header(new) == text
    if body.startswith("%\n"):        # after % and the program number, as without the mark
        assert new.splitlines()[:3] == ["\ufeff%", "O0042 (TEST)", "(MTCOMP COMPENSATED PROGRAM: X)"]
    buf = bytearray(text.encode())
    at_b, n_b = gcode.provenance.insert_header_bytes(buf, ["MTCOMP COMPENSATED PROGRAM: X", "MACHINE m"])
    assert bytes(buf) == new.encode() and (at_b, n_b) == (at, n)


def test_byte_order_mark_stays_first_through_the_cli(files, tmp_path):
    prog, err = files
    prog.write_bytes(b"\xef\xbb\xbf" + PROGRAM.encode())
    zero = tmp_path / "zero.toml"
    zero.write_text("")
    out = tmp_path / "o.nc"
    for e in (err, zero):
        r = run("compensate", prog, "-m", "vmc-moving-column", "-e", e, "-o", out)
        assert r.returncode == 0, r.stderr
        data = out.read_bytes()
        assert data.startswith(b"\xef\xbb\xbf%\nO0042 (TEST)\n(MTCOMP COMPENSATED PROGRAM")
        assert data.count(b"\xef\xbb\xbf") == 1
    assert strip_header(data.decode("utf-8")) == "\ufeff" + PROGRAM


def test_arcs_on_a_machine_with_coarse_resolution_do_not_traceback(files, tmp_path):
    prog, err = files
    out = tmp_path / "o.nc"
    r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", out)
    assert r.returncode == 0 and "Traceback" not in r.stderr
    r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", out, "--chordal-tol", "0.1")
    assert r.returncode == 2 and "below twice the linear axis resolution" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("tol", ["0", "-1", "nan", "inf"])
def test_bad_chordal_tolerance_is_one_line(files, tmp_path, tol):
    prog, err = files
    r = run("compensate", prog, "-m", "robonano-a0ib", "-e", err, "-o", tmp_path / "o.nc", f"--chordal-tol={tol}")
    assert r.returncode == 2 and "--chordal-tol" in r.stderr and "Traceback" not in r.stderr


def test_outside_travel_names_the_block_not_convergence():
    m = load_machine("robonano-a0ib")
    with pytest.raises(InputError, match=r"^p.nc:2: X 400 is outside the travel \[-140, 140\]"):
        compensate_program("G90 G0 X0 Y0 Z5.\nG1 X400. F100\n", m, ErrorSet(), filename="p.nc")


def test_3axis_program_on_a_tilted_blank_keeps_the_rotary_axes():
    """Once refused ("did not converge", then a hint at --mode 3axis), and before that solved with
    C swinging to about 34 deg: at the B-C pole the kernel keeps C as programmed, the linear axes
    take the position, and no rotary word is written."""
    m = load_machine("robonano-a0ib")
    e = ErrorSet(workpiece=WorkpieceSetting((0, 0, 0), (0.03, 0, 0)))
    text, rep = compensate_program("G90 G0 X0 Y0 Z5.\nG1 X120. F100\n", m, e, filename="p.nc")
    assert "B" not in text and "C" not in text
    # the tilt about X moves the point by z * 0.03 deg in Y: -2.618 µm at z = 5 mm
    assert "Y-0.002618" in text.splitlines()[0]
    assert rep["after_max"] < 1e-6 < 2e-3 < rep["before_max"]


def test_arc_interior_errors_carry_the_line():
    m = load_machine("robonano-a0ib")
    e = ErrorSet(workpiece=WorkpieceSetting((0, 0.1, 0), (0, 0, 0)))
    text = "G90 G0 X-10. Y30. Z0 B0 C0\nG1 X-10. Y35.\nG2 X10. Y35. I10. J-5.\n"
    with pytest.raises(InputError, match=r"^p.nc:3: cannot compensate an interior point of the arc"):
        compensate_program(text, m, e, filename="p.nc")


@pytest.mark.parametrize("key", ["EX0U", "EC0W"])
def test_errors_for_axes_the_machine_lacks_are_refused(key):
    m = load_machine("robonano-a0ib")
    e = ErrorSet(geometric=GeometricErrors(location={key: 1e-3}))
    with pytest.raises(InputError, match=f"location error {key} of axis {key[-1]}"):
        compensate_program(PROGRAM, m, e)


def test_dev_zero_as_program_is_a_clean_error(tmp_path):
    # a device is refused before reading (/dev/zero never ends); a binary file by its first NUL
    # byte or its first byte that is not UTF-8; line endings are kept
    with pytest.raises(InputError, match=r"^/dev/zero: NC program is a device, not a regular file"):
        gcode.read_program("/dev/zero")
    f = tmp_path / "bin.nc"
    f.write_bytes(b"G1 X1.\r\nG1 X2.\0\n")
    with pytest.raises(InputError, match=r"bin.nc: not a text file \(NUL byte at byte 14\)"):
        gcode.read_program(f)
    f.write_bytes(b"G1 X1.\r\n(\xe9)\n")
    with pytest.raises(InputError, match=r"bin.nc: not a text file \(not UTF-8: invalid continuation byte at byte 9\)"):
        gcode.read_program(f)
    f.write_bytes(b"\xef\xbb\xbfG1 X1.\r\nM30")
    assert gcode.read_program(f) == "\ufeffG1 X1.\r\nM30"
    with pytest.raises(InputError, match=r"nope.nc: NC program not found"):
        gcode.read_program(tmp_path / "nope.nc")
    with pytest.raises(InputError, match=r": NC program is a directory"):
        gcode.read_program(tmp_path)
    r = run("compensate", "/dev/zero", "-m", "robonano-a0ib", "-e", tmp_path / "none.toml")
    assert r.returncode != 0 and "Traceback" not in r.stderr


def test_start_option_on_the_cli(tmp_path):
    prog = tmp_path / "p.nc"
    prog.write_text("G90 G0 X10. Y10.\nG0 Z5.\n")
    err = save_errors(ErrorSet(ToolSetting((0.002, 0, 0))), tmp_path / "e.toml")
    out = tmp_path / "o.nc"
    r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", out)
    assert r.returncode == 0 and "1 blocks before every axis position is known" in r.stdout
    assert "G90 G0 X10. Y10.\n" in out.read_text()
    r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", out, "--start", "Z=50")
    assert r.returncode == 0 and "G90 G0 X10. Y10.\n" not in out.read_text()
    r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", out, "--unknown", "refuse")
    assert r.returncode == 2 and f"{prog}:1: position of Z not known" in r.stderr
    r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", out, "--start", "Q=1")
    assert r.returncode == 2 and "--start" in r.stderr


def test_tool_lengths_and_work_offsets_on_the_cli(tmp_path):
    prog = tmp_path / "p.nc"
    prog.write_text("G54 G90 G0 X0 Y0 Z-50.\nG43 H1 Z-100.\nG55 X0\nG81 X5. Y5. Z-101. R-98. F50\nG80\nM30\n")
    err = save_errors(ErrorSet(ToolSetting((0.002, 0, 0.001))), tmp_path / "e.toml")
    wo = tmp_path / "wo.toml"
    wo.write_text('[G54]\nX = 0.0\n[G55]\nX = 100.0\nY = -20.0\n')
    tl = tmp_path / "tools.csv"
    tl.write_text("H,length_mm\n1,80.5\n")
    out = tmp_path / "o.nc"
    r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", out)
    assert r.returncode == 2 and "give the work offsets (G54, G55)" in r.stderr
    for tools in (tl, "1=80.5"):
        r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", out,
                "--work-offsets", wo, "--tool-lengths", tools)
        assert r.returncode == 0, r.stderr
        assert "canned cycle holes: 1 kept" in r.stdout
        assert "(OPTIONS " in out.read_text() and "H1=80.5" in out.read_text()
    r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", out,
            "--work-offsets", wo, "--tool-lengths", "H1=abc")
    assert r.returncode == 2 and "--tool-lengths" in r.stderr


def test_travel_refusal_says_where_the_tool_length_comes_in(tmp_path):
    """A G43 length added to Z that takes the axis outside its travel: the refusal names the
    programmed position and the offset added to it (the number alone was not the word)."""
    prog = tmp_path / "p.nc"
    prog.write_text("G20 G90 G54\nG43 H1 Z1.0\nG1 X1. F10.\nM30\n")
    err = save_errors(ErrorSet(ToolSetting((0.002, 0, 0.001))), tmp_path / "e.toml")
    r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "--tool-lengths", "1=100")
    assert r.returncode == 2
    assert (f"{prog}:2: Z 125.4 is outside the travel [-250, 50] of axis Z on vmc-moving-column "
            "(programmed 25.4 mm plus 100 mm of tool length") in r.stderr
    assert "Traceback" not in r.stderr


def test_arc_tolerance_option(tmp_path):
    prog = tmp_path / "p.nc"
    prog.write_text("G90 G1 X10. Y0 Z0 F100\nG3 X0 Y10.05 I-10. J0\n")
    err = save_errors(ErrorSet(ToolSetting((0.002, 0, 0))), tmp_path / "e.toml")
    out = tmp_path / "o.nc"
    r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", out)
    assert r.returncode == 2 and ":2: arc end point is not on the circle" in r.stderr
    r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", out, "--arc-tol", "60")
    assert r.returncode == 0, r.stderr
    assert "(OPTIONS unknown-start defer; arc-tol 0.06 mm)" in out.read_text()
    r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", out, "--arc-tol", "nan")
    assert r.returncode == 2 and "--arc-tol" in r.stderr


def _emitted_vs_reread(text, machine, errors, chordal_tol=None, **kw):
    """The positions `compensate` verifies (taken from the emitted values) against the written
    program read back by the parser, block by block."""
    from mtcomp.commands import emitted_positions
    from mtcomp.gcode import flow
    res = {a.name: a.resolution for a in machine.axes}
    fl = flow.expand(text, search=[str(Path(__file__).parent / "data" / "nc" / "subprograms")])
    prog = gcode.parse(fl.expanded if fl else text, axes=machine.axis_names, resolution=res,
                       rotation=True, **kw)
    info = {}
    new_text, out_line = gcode.rewrite_with_lines(
        prog, lambda q: __import__("mtcomp.kinematics").kinematics.retarget(machine, q, errors),
        resolution=res, chordal_tol=chordal_tol or max(1e-4, 2 * max(res.values())), info=info)
    kn = np.asarray(info["compensated"])
    back = gcode.parse(new_text, axes=machine.axis_names, resolution=res, rotation=True, **kw)
    fast = emitted_positions(prog, info, new_text, res=res, out_line=out_line, **kw)[kn]
    idx = np.searchsorted(back.line, out_line, side="right") - 1
    return fast, np.asarray(back.position)[idx][kn], np.asarray(prog.incremental)[kn]


@pytest.mark.parametrize("path", sorted(p for p in (Path(__file__).parent / "data" / "nc").iterdir()
                                         if p.is_file()), ids=lambda p: p.name)
def test_verification_from_emitted_values_equals_reading_the_output_back(path):
    m = load_machine("vmc-moving-column")
    # a rigid shift, so that canned cycles are kept (those programs are read back)
    e = ErrorSet(ToolSetting((0.012, -0.004, 0.020)), WorkpieceSetting((0.010, 0.005, -0.003), (0, 0, 0)))
    text = gcode.read_program(path)
    fast, back, inc = _emitted_vs_reread(text, m, e, start={"X": 0, "Y": 0, "Z": 50}, chordal_tol=1e-3)
    assert len(fast) > 5
    # the same numbers to float rounding; except that the control rounds G91 increments finer
    # than the resolution one by one (as the emitted counts do) where the parser sums them
    # unrounded (linuxcnc.ngc): at most one count apart there
    res = 1e-4                                  # vmc-moving-column's resolution
    d = np.abs(fast - back).max(axis=1)
    after_inc = np.maximum.accumulate(inc)         # carried into later blocks
    assert ((d < 1e-12) | after_inc).all() and np.mean(d < 1e-12) > 0.5, d
    np.testing.assert_allclose(fast, back, rtol=0, atol=res)


def test_verification_from_emitted_values_five_axes_arcs_and_increments():
    # linearised arcs (the last segment ends the block), G91 sections, 5-axis rotary words
    m = load_machine("robonano-a0ib")
    e = ErrorSet(ToolSetting((0.012, -0.004, 0.020)), WorkpieceSetting((0.01, 0.005, -0.003), (0.02, 0.0, 0.01)))
    text = ("G90 G0 X0 Y0 Z10. B10. C0\nG1 Z0.5 F100\nX1. Y2. B12. C30.\nG3 X5. Y2. I2. J0\n"
            "G91 G1 X0.01 Y-0.002\nX0.001 Z-0.0005 C1.\nG90 G2 X1. Y2. R2.\nG1 X-3. Y4. Z1. B-10. C-90.\nM30\n")
    fast, back, _ = _emitted_vs_reread(text, m, e)
    np.testing.assert_allclose(fast, back, rtol=0, atol=1e-12)
    assert np.abs(fast - back).max() < 1e-12 and len(fast) == 8


_CORRUPT_PROG = ("G90 G0 X0 Y0 Z10. B10. C0\nG1 Z0.5 F100\nX1. Y2. B12. C30.\nG3 X5. Y2. I2. J0\n"
                 "G91 G1 X0.01 Y-0.002\nX0.001 Z-0.0005 C1.\nG90 G1 X-3. Y4. Z1. B-10. C-90.\nM30\n")


def _corrupting(fmt, at, back=1):
    """A number formatter that writes one digit wrong: the ``back``-th digit from the end of the
    ``at``-th number of its first call (its calls are counted in ``.calls``)."""
    calls = []

    def wrong(counts, decimals):
        got = fmt(counts, decimals)
        if got is None or calls or len(got[1]) <= at:
            return got
        calls.append(1)
        buf, off, ln = got
        buf = buf.copy()
        k = int(off[at] + ln[at] - back)
        buf[k] = ord("1") if buf[k] != ord("1") else ord("2")
        return buf, off, ln
    wrong.calls = calls
    return wrong


def _corrupting_edits(fn, at, back=1, calls=None):
    """The same for the compiled replacement edits (`_ctok.replace_edits`, which formats the
    numbers of the words it replaces): one digit of the ``at``-th text of its first call wrong.
    ``calls``: a list shared with a `_corrupting` formatter (only the first call of either)."""
    calls = [] if calls is None else calls

    def wrong(*args, **kw):
        got = fn(*args, **kw)
        if got is None or calls or len(got[4]) <= at:
            return got
        calls.append(1)
        buf, pos, stop, off, ln = got
        buf = buf.copy()
        k = int(off[at] - kw.get("base", args[-1]) + ln[at] - back)
        buf[k] = ord("1") if buf[k] != ord("1") else ord("2")
        return buf, pos, stop, off, ln
    wrong.calls = calls
    return wrong


def corrupt_formatting(monkeypatch, mod, at, back=1):
    """Patch the number formatter ``mod.format_counts`` and, in `_ctok`, the replacement edits,
    so that the first number formatted (by either) at index ``at`` gets one digit wrong; returns
    the list of corrupted calls."""
    from mtcomp.gcode import _ctok
    fmt = _corrupting(getattr(mod, "format_counts"), at, back)
    monkeypatch.setattr(mod, "format_counts", fmt)
    if mod is _ctok:
        monkeypatch.setattr(_ctok, "replace_edits",
                            _corrupting_edits(_ctok.replace_edits, at, back, fmt.calls))
    return fmt.calls


def test_a_corrupted_written_number_is_caught_and_nothing_returned(monkeypatch):
    # the check of compensate reads the written words back from the output bytes: a wrong
    # digit from the formatter (or the splice) must not pass as the emitted value
    from mtcomp.gcode import _ctok
    if _ctok.load() is None:
        pytest.skip("no compiled tokenizer")
    m = load_machine("robonano-a0ib")
    e = ErrorSet(ToolSetting((0.012, -0.004, 0.020)), WorkpieceSetting((0.01, 0.005, -0.003), (0.0, 0.0, 0.0)))
    good, rep = compensate_program(_CORRUPT_PROG, m, e)
    assert rep["after_max"] < 1e-6
    for at in (0, 2):
        calls = corrupt_formatting(monkeypatch, _ctok, at)
        with pytest.raises(InputError, match="not what was computed"):
            compensate_program(_CORRUPT_PROG, m, e)
        assert calls
        monkeypatch.undo()
    # a word the splice inserts on the wrong line is caught as well: the Y word inserted into
    # "X0.001 Z-0.0005 C1." (line 6) goes to the end of line 5 instead
    # (both compiled splices: in place in the output buffer, and into a new one)
    real, real_inplace = _ctok.splice, _ctok.splice_inplace

    def misplace(orig, pos, stop, src_off, src_len):
        pos, stop, src_off, src_len = (np.array(a) for a in (pos, stop, src_off, src_len))
        nl = np.flatnonzero(np.asarray(orig) == 10)
        ins = (pos == stop) & (pos > nl[4]) & (pos < nl[5])
        assert ins.any()
        pos[ins] = stop[ins] = nl[4]
        o = np.argsort(pos, kind="stable")
        return pos[o], stop[o], src_off[o], src_len[o]

    def misplaced(orig, src, pos, stop, src_off, src_len, total):
        return real(orig, src, *misplace(orig, pos, stop, src_off, src_len), total)

    def misplaced_inplace(buf, n_orig, src, pos, stop, src_off, src_len):
        orig = np.frombuffer(bytes(buf[:n_orig]), np.uint8)
        return real_inplace(buf, n_orig, src, *misplace(orig, pos, stop, src_off, src_len))
    for name, fn in (("splice_inplace", misplaced_inplace), ("splice", misplaced)):
        monkeypatch.setattr(_ctok, name, fn)
        if name == "splice":                     # the other path: no in-place splice
            monkeypatch.setattr(_ctok, "splice_inplace", lambda *a: False)
        with pytest.raises(InputError, match="not what was computed"):
            compensate_program(_CORRUPT_PROG, m, e)
        monkeypatch.undo()


def test_a_corrupted_written_number_shows_in_the_check_without_the_compiled_reader(monkeypatch):
    # without the compiled tokenizer the output is parsed back whole: the forward model from
    # what was written shows the wrong digit as a tool-edge error after compensation
    monkeypatch.setenv("MTCOMP_TOKENIZER", "python")
    rw = __import__("importlib").import_module("mtcomp.gcode.rewrite")
    m = load_machine("robonano-a0ib")
    e = ErrorSet(ToolSetting((0.012, -0.004, 0.020)), WorkpieceSetting((0.01, 0.005, -0.003), (0.0, 0.0, 0.0)))
    _, rep = compensate_program(_CORRUPT_PROG, m, e)
    assert rep["after_max"] < 1e-6
    monkeypatch.setattr(rw, "format_counts", _corrupting(rw.format_counts, 0))
    _, rep = compensate_program(_CORRUPT_PROG, m, e)
    assert rep["after_max"] > 0.5e-6                 # a last digit of X Y Z: at least 1 nm ... 9 nm


def test_provenance_marker_found_at_the_top_in_any_case_and_further_down():
    from mtcomp.gcode.provenance import compensated_line
    body = "G1 X1. Y2.\n" * 20000                         # over 64 kB
    assert compensated_line("%\n(Mtcomp Compensated Program: x)\n" + body) == 2
    assert compensated_line(body + "(mtcomp compensated program)\n") == 20001
    assert compensated_line(body + "(MTCOMP COMPENSATED PROGRAM: DO NOT)\n") == 20001
    assert compensated_line(body) is None


# -- verification of what compensate writes (issue 14 item 1)
CUT = "%\nO0042 (TEST)\nG21 G90 G17\nG0 X0 Y0 Z5.\nG0 Z1.\nG1 Z-0.5 F200\nG1 X10.\nG0 X20. Z0.05\nG0 Z5.\nM30\n%\n"
SAFE = CUT.replace("G0 X20. Z0.05", "G1 Z1.\nG0 X20.")     # retract at feed (the stock is not cut away)
STOCK = "box:-5,-5,-10,30,5,0"


def test_compensate_refuses_a_rapid_into_the_stock_naming_the_block(files, tmp_path):
    prog, err = files
    prog.write_text(CUT)
    out = tmp_path / "out.nc"
    r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", out, "--stock", STOCK,
            "--clearance", "0.1")
    assert r.returncode != 0 and not out.exists()
    msg = r.stderr.strip()
    assert len(msg.splitlines()) == 1 and "Traceback" not in msg
    # the first failing block is the rapid from the cut at Z-0.5 out through the stock
    assert "rapid move: the tool enters the stock at -500 µm" in msg and "(G0 X20.0000 Z0.0500)" not in msg
    assert "G0 X19.998" in msg and "and 1 more blocks" in msg


def test_compensate_warn_only_writes_and_reports(files, tmp_path):
    prog, err = files
    prog.write_text(CUT)
    out = tmp_path / "out.nc"
    r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", out, "--stock", STOCK,
            "--clearance", "0.1", "--warn-only")
    assert r.returncode == 0 and out.exists()
    assert "2 block(s) FAIL" in r.stdout and "min rapid clearance -500 µm" in r.stdout
    assert "warning: 2 block(s) fail the verification" in r.stderr


def test_compensate_reports_min_clearance_of_a_safe_program(files, tmp_path):
    prog, err = files
    prog.write_text(SAFE)
    r = run("compensate", prog, "-m", "vmc-moving-column", "-e", err, "-o", tmp_path / "o.nc",
            "--stock", STOCK, "--clearance", "0.5")
    assert r.returncode == 0, r.stderr
    # rapids down to Z1 over the stock top at Z0: the compensated program keeps 1 mm on the
    # machine with the errors (the tool offset is undone)
    assert "min rapid clearance 1000 µm" in r.stdout and "passed" in r.stdout


def test_compensate_program_verification_in_the_library():
    from mtcomp.verify import Box, VerifyError
    m = load_machine("vmc-moving-column")
    e = ErrorSet(ToolSetting((0.0, 0.0, -0.3)))      # tool 0.3 mm longer than nominal
    box = Box((-5, -5, -10), (30, 5, 0))
    # nominally 0.2 mm over the stock: compensated, the real machine keeps those 0.2 mm
    text = SAFE.replace("Z1.", "Z0.2")
    _, rep = compensate_program(text, m, e, stock=box, clearance=0.1)
    assert abs(rep["verify"].min_clearance - 0.2) < 1e-6
    # a program that rapids across the stock at 0.05 mm fails, naming its line
    with pytest.raises(VerifyError, match=r"line 8 \(G0 X20\.0* Z0\.35"):
        compensate_program(CUT, m, e, stock=box, clearance=0.1)
    _, rep = compensate_program(CUT, m, e, stock=box, clearance=0.1, warn_only=True)
    assert [v.line for v in rep["verify"].violations] == [8, 9]


@pytest.mark.parametrize("word", ["G43.5 H1", "g43.5"])
def test_tool_vector_tcp_programs_are_refused_naming_the_line(word):
    # documented limit (docs/gcode.md): G43.5 I J K tool vectors are not compensated (G43.4 is,
    # tests/test_gcode_tcp.py)
    m = load_machine("robonano-a0ib")
    text = f"G90 G0 X0 Y0 Z5. B10. C0\n{word}\nG1 X1. B12. F100\n"
    with pytest.raises(InputError, match=r"^p.nc:2: [Gg]43\.5: G43\.5 tool centre point"):
        compensate_program(text, m, ErrorSet(ToolSetting((0.002, 0, 0))), filename="p.nc")


def _insert_header_by_lines(text, lines):
    """Reference: the header placement on the program split into all its lines."""
    import re
    semicolon = ";" in text and "(" not in text
    eol = "\r\n" if text.split("\n", 1)[0].endswith("\r") else "\n"
    comments = [f"; {ln}" if semicolon else f"({ln})" for ln in lines]
    src = re.findall(r"[^\n]*\n|[^\n]+\Z", text)
    at = 0
    while at < len(src) and not src[at].strip():
        at += 1
    if at < len(src) and src[at].strip().startswith("%"):
        at += 1
    if at < len(src) and re.match(r"\s*[Oo]\d|\s*:\d", src[at]):
        at += 1
    if at and not src[at - 1].endswith("\n"):   # the program ends there: the header goes before
        at -= 1
    return "".join(src[:at]) + "".join(c + eol for c in comments) + "".join(src[at:]), at, len(comments)


@pytest.mark.parametrize("text", ["", "%", "%\n", "\n\n%\nO1\nG1 X1\n", "O1", "%\nO0042", "  \n%\r\n:1\r\nG0\r\n",
                                  "G1 X1\n%\n", "\n\n", "%\n%\n", "(c)\n", "%\n\nO1\n"])
def test_insert_header_reads_only_the_top_lines_same_placement(text):
    lines = ["MTCOMP COMPENSATED PROGRAM: X", "MACHINE m"]
    assert insert_header(text, lines) == _insert_header_by_lines(text, lines)


@pytest.mark.parametrize("text", ["O0001", "%\nO0001", "%\r\nO0001", "\n\nO12", "G0 X1.", "O0001\n",
                                  "%\nO0001\nG0 X1.\n"])
def test_provenance_header_strips_back_to_the_program_byte_for_byte(text):
    """A program ending on its % or O line without a line break got one added under the header
    (found by benchmarks/fuzz.py, seed 11: 'O0001' came back as 'O0001\\n')."""
    from mtcomp.gcode.provenance import compensated_line, insert_header, strip_header
    new, at, added = insert_header(text, ["MTCOMP COMPENSATED PROGRAM: DO NOT COMPENSATE AGAIN",
                                          "VERSION mtcomp test", "DATE 2026-01-01T00:00:00Z"])
    assert added == 3 and compensated_line(new) is not None
    assert strip_header(new) == text


def test_inch_arcs_with_the_default_chordal_tolerance():
    # inch words are written one decimal finer (0.254 µm on a 0.1 µm machine): the default
    # tolerance follows, rather than refusing every inch program with arcs
    m = load_machine("vmc-moving-column")
    text = "G20 G90 G0 X0 Y0 Z1.\nG1 Z0 F10.\nG2 X1. Y0 I0.5 J0\nG0 Z1.\n"
    out, rep = compensate_program(text, m, ErrorSet(geometric=GeometricErrors(location={"EB0Z": 2e-4})))
    assert rep["after_max"] < 1e-4 and out.startswith("G20")


def test_latin1_comments_are_kept_byte_for_byte(tmp_path):
    """Windows CAM systems write comments in Latin-1 (a public LinuxCNC example: "Fräser"):
    compensate reads such a program when every 8-bit byte is inside a comment and writes them
    back unchanged; an 8-bit byte in the code is still refused, naming the line (issue 20)."""
    from mtcomp.cli import main
    src = tmp_path / "p.nc"
    body = "(Fr\xe4ser \xd86 mm)\nG21 G90 G54\nG0 X1. Y2. Z5. ; Ma\xdf\nG1 Z-1. F100\nM30\n".encode("latin-1")
    src.write_bytes(body)
    text, enc = gcode.read_program_8bit(src)
    assert enc == "latin-1" and text.encode("latin-1") == body
    assert gcode.read_program_8bit(tmp_path / "p.nc")[0].startswith("(Fr\xe4ser")
    err = tmp_path / "zero.toml"
    err.write_text("")
    out = tmp_path / "o.nc"
    assert main(["compensate", str(src), "-m", "vmc-moving-column", "-e", str(err), "-o", str(out)]) == 0
    written = out.read_bytes()
    assert written.endswith(body)                  # after the ASCII provenance header
    src.write_bytes("(ok)\nG0 X1. Y\xe42.\n".encode("latin-1"))
    with pytest.raises(InputError, match=r"p.nc:2: not a text file .*outside a comment"):
        gcode.read_program_8bit(src)
    with pytest.raises(InputError, match=r"not UTF-8"):
        gcode.read_program(tmp_path / "p.nc")      # the strict reader is unchanged


@pytest.mark.parametrize("text", [
    "", "G1 X1\n", "%\nO1234 (PART)\nG1 X1.\nM30\n%\n", "%\r\nO12\r\nG1 X1\r\n", ":123\nG1 X1\n",
    "; only semicolons\nG1 X1 ; c\n", "\n\n%\nO7", "O7", "%", "(caf\u00e9 \udce9)\nG1 X1\n",
    "\n" * 70000 + "%\nO1\nG1 X1\n", "(" + "x" * 70000 + ")\nG1 X1\n",
])
def test_header_inserted_into_bytes_as_into_text(text):
    # compensate inserts its header into the output bytes in place (no copy of a large text):
    # the same bytes as the text version
    from mtcomp.gcode.provenance import header_lines, insert_header_bytes
    lines = header_lines([("VERSION", "x"), ("SOURCE", "a (b).nc")])
    want, at, added = insert_header(text, lines)
    buf = bytearray(text.encode("utf-8", "surrogateescape"))
    assert insert_header_bytes(buf, lines) == (at, added)
    assert bytes(buf) == want.encode("utf-8", "surrogateescape")


def test_emitted_counts_are_the_decimal_numbers_the_words_say():
    """3050000 steps of 1e-5 deg is the word C30.5, which a control reads as 30.5 (the product
    3050000 * 1e-5 is 30.500000000000004); steps of 5e-4 mm; unknown axes stay NaN."""
    from mtcomp.gcode.textops import decimal_values
    counts = np.array([[3050000.0, 1500000.0, 3.0], [-123456789.0, 1.0, np.nan]])
    got = decimal_values(counts, [5, 5, 4], [1, 1, 5], [1e-5, 1e-5, 5e-4])
    words = [["30.5", "15.0", "0.0015"], ["-1234.56789", "0.00001", "nan"]]
    assert got.tolist()[0] == [float(w) for w in words[0]]
    assert got[1, :2].tolist() == [float(w) for w in words[1][:2]] and np.isnan(got[1, 2])
    assert 3050000 * 1e-5 != 30.5          # (what the product gave)
    # beyond 2**53 counts the decimal division is not exact either: the product is kept
    big = decimal_values([[2.0 ** 54]], [6], [1], [1e-6])
    assert big[0, 0] == 2.0 ** 54 * 1e-6
    # a step written with extra zeros (5000 * 10**-7) is the same number
    assert decimal_values([[7.0]], [7], [5000], [5e-4])[0, 0] == 0.0035


def _values_by_search(counts, res):
    """The emitted values as compensate recovered them before the rewrite handed over its
    decimals: d and m searched from the float step (the reference for the parity test)."""
    out = np.array(counts, float)
    for j, r in enumerate(res):
        col = out[..., j]
        for d in range(16):
            m = r * 10.0 ** d
            if abs(m - round(m)) <= 1e-9 * m:
                break
        if abs(m - round(m)) > 1e-9 * m or np.nanmax(np.abs(col), initial=0.0) * round(m) >= 2.0 ** 53:
            col *= r
            continue
        if round(m) != 1:
            col *= float(round(m))
        col /= 10.0 ** d
    return out


@pytest.mark.parametrize("inch", [False, True])
@pytest.mark.parametrize("step", [1e-6, 5e-6, 1e-5, 2e-5, 1e-4, 5e-4, 2.5e-5, 1e-3, 1e-2, 0.1, 1e-7,
                                  1e-8, 1e-9, 3e-7, 0.05, 1.0, 2.0, 125e-6])
def test_emitted_values_are_those_of_the_step_search_for_every_resolution(step, inch):
    """The rewrite hands over each axis' decimals and multiple (info): the emitted values are
    the numbers the old search over powers of ten of the float step gave, bit for bit, for
    mm and inch programs (inch words: one decimal more, 25.4 mm per inch)."""
    from mtcomp.gcode.rewrite import emitted_values
    text = ("G20 " if inch else "") + "G90 G0 X0 Y0 Z1.\nG1 X0.3 Y-0.7 Z0.5 F10.\n"
    prog = gcode.parse(text, axes="XYZ")
    info = {}
    rng = np.random.default_rng(int(step * 1e9) + inch)
    shift = rng.uniform(-0.5, 0.5, 3)
    gcode.rewrite(prog, lambda q: q + shift, resolution={a: step for a in "XYZ"}, info=info,
                  chordal_tol=1.0)
    counts = np.vstack([info["emitted"], rng.integers(-10 ** 9, 10 ** 9, (200, 3)).astype(float),
                        [[2.0 ** 53, 1.0, -1.0]]])
    res = info["emitted_resolution"]
    got = emitted_values(dict(info, emitted=counts))
    want = _values_by_search(counts, res)
    assert np.array_equal(got, want)
    # consumed: written over the counts' own memory (float64 as given, int64 as the rewrite
    # gives them; rows beyond a chunk of the conversion), the same bits
    big = np.vstack([counts[:-1]] * 400 + [counts[-1:]])
    want = _values_by_search(big, res)
    for c in (big.copy(), np.rint(big).astype(np.int64)):
        d = dict(info, emitted=c)
        got = emitted_values(d, consume=True)
        assert "emitted" not in d and np.shares_memory(got, c)
        assert got.dtype == np.float64 and np.array_equal(got.view(np.int64), want.view(np.int64))


def test_decimal_values_compiled_same_bits_as_numpy():
    """The compiled pass of `textops.decimal_values` (both passes over the rows) against the
    numpy path, bit for bit: int64 and float64 counts (NaN, infinities, -0.0, counts near and
    beyond 2**53 / multiple: the columns that take the step instead), inch multiples, in place
    (over the counts' memory) and into a new array."""
    from mtcomp.gcode import _ctok, textops
    rng = np.random.default_rng(21)
    steps = ([6, 4, 5, 7, 3], [1, 254, 5, 1, 25])
    res = np.array([1e-6, 254e-4, 5e-5, 1e-7, 0.025])
    base = rng.integers(-10 ** 9, 10 ** 9, (5000, 5))
    big = base.copy()
    big[17, 1] = 2 ** 53 // 254 + 1                   # column 1: the step, not the division
    big[99, 3] = -(2 ** 62)
    for counts in (base, big, base.astype(float), big.astype(float)):
        cases = [counts]
        if counts.dtype == np.float64:
            f = counts.copy()
            f[rng.random(f.shape) < 0.01] = np.nan
            f[3, 0], f[4, 2], f[5, 4] = np.inf, -np.inf, -0.0
            g = f.copy()
            g[:, 2] = np.nan                        # a column with nothing known
            cases += [f, g]
        for c in cases:
            with pytest.MonkeyPatch.context() as mp:
                mp.setattr(_ctok, "decimal_values", lambda *a, **k: None)
                want = textops.decimal_values(c, *steps, res)
            got = textops.decimal_values(c, *steps, res)
            assert got.dtype == np.float64 and np.array_equal(got.view(np.int64), want.view(np.int64))
            mine = c.copy()
            got = textops.decimal_values(mine, *steps, res, inplace=True)
            assert np.shares_memory(got, mine)
            assert np.array_equal(got.view(np.int64), want.view(np.int64))


def test_emitted_values_are_the_written_words():
    """The compensated words read as exact decimal numbers (inch: times exactly 25.4) and
    rounded once are the emitted values, bit for bit (mm and inch)."""
    import re
    from decimal import Decimal
    from mtcomp.gcode.rewrite import emitted_values
    for head, scale in (("", Decimal(1)), ("G20 ", Decimal("25.4"))):
        text = head + "G90 G0 X0 Y0 Z1.\nG1 X0.3 Y-0.7 Z0.5 F10.\nX1.25 Y3.05 Z0.25\n"
        prog = gcode.parse(text, axes="XYZ")
        info = {}
        out = gcode.rewrite(prog, lambda q: q + [0.0123456, -0.03, 0.0005], info=info,
                            resolution={"X": 5e-6, "Y": 1e-6, "Z": 1e-4})
        lines = out.splitlines()[1:]
        words = [[float(Decimal(re.search(a + r"(-?[0-9.]+)", ln).group(1)) * scale) for a in "XYZ"]
                 for ln in lines]
        assert emitted_values(info)[1:].tolist() == words


# -- the bytes path of `mtcomp compensate` (read, compensate and write the program's bytes)
NC_FILES = sorted(p for p in (Path(__file__).parent / "data" / "nc").rglob("*") if p.is_file())


@pytest.mark.parametrize("path", NC_FILES, ids=lambda p: p.name)
def test_compensating_the_bytes_gives_the_bytes_of_compensating_the_text(path):
    """compensate_program of a file's bytes returns the UTF-8 bytes of what it returns for
    the text, the same report, or the same error (subprogram files: the expansion's text)."""
    m = load_machine("vmc-moving-column")
    e = ErrorSet(ToolSetting((0.012, -0.004, 0.020)), WorkpieceSetting((0.010, 0.005, -0.003), (0, 0, 0)))
    data, enc = gcode.read_program_bytes(path)
    text = gcode.read_program(path)
    assert enc == ("ascii" if text.isascii() else "utf-8") and data == text.encode("utf-8")
    kw = dict(filename=str(path), start={"X": 0, "Y": 0, "Z": 50}, chordal_tol=1e-3,
              provenance=[("SOURCE", path.name)], search_path=[str(path.parent / "subprograms")])
    try:
        want, rep_t = compensate_program(text, m, e, **kw)
    except InputError as exc:
        for encoding in {enc, "utf-8"}:
            with pytest.raises(InputError) as got:
                compensate_program(data, m, e, encoding=encoding, **kw)
            assert str(got.value) == str(exc)
        return
    for encoding in {enc, "utf-8"}:            # (ASCII files: also without saying so)
        got, rep_b = compensate_program(data, m, e, encoding=encoding, **kw)
        assert isinstance(want, str) and not isinstance(got, str)
        assert bytes(got) == want.encode("utf-8")
        assert rep_b["after_max"] == rep_t["after_max"] and rep_b["lines"] == rep_t["lines"]


def test_non_ascii_programs_on_the_bytes_path(tmp_path):
    """UTF-8 comments pass through the bytes path byte for byte (no decoding on the way); a
    UTF-8 character in the code is refused naming the line, as from the text; a file that is
    not UTF-8 with 8-bit bytes in comments only is read as Latin-1 and written back byte for
    byte; `read_program_8bit` is the decoding of `read_program_bytes`."""
    import re
    from mtcomp.cli import main
    m = load_machine("vmc-moving-column")
    e = ErrorSet(ToolSetting((0.002, -0.001, 0.0005)))
    body = "(Fräser Ø6 — ok)\nG21 G90 G0 X1. Y2. Z5. ; Maß\nG1 Z-1. F100 (über)\nM30\n"
    data = body.encode()
    got, _ = compensate_program(data, m, e)
    want, _ = compensate_program(body, m, e)
    assert bytes(got) == want.encode() and "(Fräser Ø6 — ok)" in want and "(über)" in want
    with pytest.raises(InputError, match=r"<string>:2: unexpected character") as b:
        compensate_program("(ok)\nG0 X1. Yä2.\n".encode(), m, e)
    with pytest.raises(InputError) as t:
        compensate_program("(ok)\nG0 X1. Yä2.\n", m, e)
    assert str(b.value) == str(t.value)
    for raw, enc in ((data, "utf-8"), (body.encode("latin-1", "replace"), "latin-1"),
                     (b"G1 X1 Y0 Z0\r\nG1 X2\r\n", "ascii")):
        src = tmp_path / "p.nc"
        src.write_bytes(raw)
        assert gcode.read_program_bytes(src) == (raw, enc)
        enc = "utf-8" if enc == "ascii" else enc
        assert gcode.read_program_8bit(src) == (raw.decode(enc), enc)
        out = tmp_path / "o.nc"
        assert main(["compensate", str(src), "-m", "vmc-moving-column", "-e",
                     str(save_errors(e, tmp_path / "e.toml")), "-o", str(out)]) == 0
        written = strip_header(out.read_bytes().decode(enc)).encode(enc)
        # the comments, 8-bit bytes and line endings are where they were: only numbers moved
        comments = re.compile(rb"\([^)]*\)|;[^\n]*|\r\n|[^\x00-\x7f]")
        assert comments.findall(written) == comments.findall(raw)
        assert written.count(b"\n") == raw.count(b"\n") and written != raw


def test_parse_of_the_bytes_is_the_parse_of_the_text():
    """gcode.parse reads a program's bytes as it reads its text (same arrays); the Program's
    text is decoded only when asked for, and is the text."""
    text = (Path(__file__).parent / "data" / "nc" / "fanuc_mill.nc").read_text() + "(ä ø)\n"
    a = gcode.parse(text, axes="XYZ")
    b = gcode.parse(text.encode(), axes="XYZ")
    assert "text" not in b.__dict__
    assert b.text == text and b.data == a.data
    for f in ("line", "position", "motion", "w_value", "w_pos", "col_word", "known"):
        assert np.array_equal(getattr(a, f), getattr(b, f)), f
    assert b.lines == a.lines


@pytest.mark.parametrize("text", ["G1 X1\n" * 3, "%\n(Mtcomp Compensated Program: x)\nG1\n",
                                  "G1 X1.\n" * 20000 + "(mtcomp compensated program)\n",
                                  "(é)\n(MTCOMP COMPENSATED PROGRAM)\n", "(é)\n(mtcomp compenſated program)\n",
                                  "(é)\n" + "G1 X1.\n" * 20000 + "(MTCOMP COMPENSATED PROGRAM)\n"])
def test_provenance_marker_and_flow_test_of_the_bytes_as_of_the_text(text):
    from mtcomp.gcode import flow
    from mtcomp.gcode.provenance import compensated_line
    data = text.encode()
    assert compensated_line(data) == compensated_line(text)
    if text.isascii():
        assert compensated_line(data, ascii=True) == compensated_line(text)
        assert flow.has_flow(data, ascii=True) == flow.has_flow(text)
    assert compensated_line(bytearray(data)) == compensated_line(text)
    for t in (text, text + "M98 P12\n", text + "(ü) o<a> call\n"):
        assert flow.has_flow(t.encode()) == flow.has_flow(t) == (flow._HAS_FLOW.search(t) is not None)


def test_atomic_write_of_a_bytearray(tmp_path):
    from mtcomp._io import atomic_write
    p = atomic_write(tmp_path / "x.nc", bytearray(b"G1 X1\r\n\xe4"))
    assert p.read_bytes() == b"G1 X1\r\n\xe4"


# --------------------------------------------------------------------- mid-block check

def _pole_sweep() -> str:
    """B from -1 to 1 deg in 0.01 deg steps at C = 0, X10 Y0 Z-20: through the B = 0 pole of the
    B-C table of robonano-a0ib."""
    lines = ["G90 G0 C0 B-1. X10. Y0 Z-20."]
    lines += [f"G1 B{b:.3f} F100" for b in np.arange(-1.0, 1.0001, 0.01)]
    return "\n".join(lines) + "\n"


def _midblock_deviation(m, errors, qa, qb):
    """Largest distance (mm) of the real tool tip, axes interpolated linearly from qa to qb (the
    written commands), from the ideal machine's straight segment between the programmed ends:
    the numpy forward model at 41 points of the block, independent of the check."""
    from mtcomp.kinematics import forward
    t = np.linspace(0.0, 1.0, 41)[:, None]
    return t, forward(m, qa + t * (qb - qa), errors, backend="numpy").p


def test_rotary_jump_at_the_end_of_a_pole_hold_is_refused():
    """A blank tilted 0.19 deg about X (inside the 0.2 deg pole tolerance): the real pole is
    0.19 deg off the programmed one, the exact solution before the hold turns C to 69.8 deg and
    the held one keeps C = 0, so one G1 block turns C by 69.8 deg. Its end points are right (the
    end-point check passed it); the tool in between is 1.8 mm off the programmed path, which the
    forward model at 41 points of the written block shows independently."""
    m = load_machine("robonano-a0ib")
    text = _pole_sweep()
    E = ErrorSet(workpiece=WorkpieceSetting((0, 0, 0), (0.19, 0.0, 0.0)))
    with pytest.raises(InputError) as exc:
        compensate_program(text, m, E, filename="sweep.nc")
    msg = str(exc.value)
    assert exc.value.line == 96 and "mid-block" in msg and "turns C by 69.77" in msg
    assert "1.801 mm" in msg and "\n" not in msg
    # the written block, as the end-point solutions give it (the line before the hold and the
    # first held line): C B X Y Z
    from mtcomp.kinematics import forward, retarget
    Pq = np.array([[0.0, -0.07, 10.0, 0.0, -20.0], [0.0, -0.06, 10.0, 0.0, -20.0]])
    Q = retarget(m, Pq, E, backend="numpy")
    assert abs(Q[0, 0] - 69.7751) < 1e-3 and abs(Q[1, 0]) < 1e-9
    t, real = _midblock_deviation(m, E, Q[0], Q[1])
    ideal = forward(m, Pq, backend="numpy").p
    off = np.linalg.norm(real - (ideal[0] + t * (ideal[1] - ideal[0])), axis=1)
    assert off[[0, -1]].max() < 1e-6 and 1.7 < off.max() < 1.9


@pytest.mark.parametrize("tilt", [0.3, 0.5])
def test_sweep_through_the_pole_is_kept_where_no_block_jumps(tilt):
    """Tilts beyond the pole tolerance (never held, C turns smoothly, at most about 2 deg a block
    at 0.3 deg): accepted, and in every written
    block the tool stays within 0.5 µm more than the uncompensated program of the programmed
    path at 41 points (numpy forward model)."""
    from mtcomp.kinematics import forward
    m = load_machine("robonano-a0ib")
    text = _pole_sweep()
    E = ErrorSet(workpiece=WorkpieceSetting((0, 0, 0), (tilt, 0.0, 0.0)))
    out, rep = compensate_program(text, m, E, filename="sweep.nc")
    assert rep["after_max"] < 1e-5
    P = gcode.parse(text, axes=m.axis_names).position
    Q = gcode.parse(out, axes=m.axis_names).position
    worst = 0.0
    for i in range(1, len(P)):
        t, real = _midblock_deviation(m, E, Q[i - 1], Q[i])
        _, unc = _midblock_deviation(m, E, P[i - 1], P[i])
        ideal = forward(m, P[i - 1] + t * (P[i] - P[i - 1]), backend="numpy").p
        worst = max(worst, float(np.max(np.linalg.norm(real - ideal, axis=1)
                                        - np.linalg.norm(unc - ideal, axis=1))))
    assert worst < 5e-4


def test_midblock_refusal_through_the_cli_writes_nothing(tmp_path):
    prog = tmp_path / "sweep.nc"
    prog.write_text(_pole_sweep())
    err = save_errors(ErrorSet(workpiece=WorkpieceSetting((0, 0, 0), (0.19, 0.0, 0.0))), tmp_path / "e.toml")
    out = tmp_path / "o.nc"
    r = run("compensate", prog, "-m", "robonano-a0ib", "-e", err, "-o", out)
    assert r.returncode != 0 and not out.exists()
    assert "Traceback" not in r.stderr and "sweep.nc:96" in r.stderr and "mid-block" in r.stderr


def test_workpiece_setting_five_axis_mode_has_the_mid_block_check():
    """Paper 001's own rewrite (`mtcomp workpiece-setting compensate --mode 5axis`) solves the
    same poses: the same block is refused, with the same figures; a tilt beyond the pole
    tolerance passes."""
    from mtcomp.setting.workpiece import compensate_text
    m = load_machine("robonano-a0ib")
    with pytest.raises(InputError) as exc:
        compensate_text(m, _pole_sweep(), WorkpieceSetting((0, 0, 0), (0.19, 0.0, 0.0)), mode="5axis",
                        filename="sweep.nc")
    assert exc.value.line == 96 and "1.801 mm" in str(exc.value) and "turns C by 69.77" in str(exc.value)
    new, n = compensate_text(m, _pole_sweep(), WorkpieceSetting((0, 0, 0), (0.3, 0.0, 0.0)), mode="5axis")
    assert n == 202 and new.count("\n") == 202
