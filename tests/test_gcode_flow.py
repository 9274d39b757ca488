"""Subprogram calls (M98 P / M97 P with L/K repeats, M99): followed by expanding them in the
order the control runs them, then folded back (subprogram compensated once) where every run of
each block comes out the same, else written out; flow that is not followed is refused with its
line (issue 20, item 5)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

from mtcomp import InputError, gcode
from mtcomp.commands import compensate_program
from mtcomp.errors import ErrorSet, GeometricErrors, ToolSetting
from mtcomp.gcode import flow
from mtcomp.machine import load_machine

NC = Path(__file__).parent / "data" / "nc"
AXES = ("X", "Y", "Z")
SUB = ("G90 G0 X0. Y0. Z5.\nG0 X10. Y10.\nM98 P100 L2\nG90 G0 X50. Y10.\nM98 P100\nG0 Z20.\nM30\n"
       "O100 (STEP)\nG91 G1 Z-6. F100.\nX5.\nG0 Z6.\nM99\n")


def test_expansion_runs_the_blocks_in_control_order():
    fl = flow.expand(SUB, "s.nc")
    # main 0..2, sub twice (lines 7..11), main 3..4, sub once, main 5..6
    sub = [7, 8, 9, 10, 11]
    assert fl.origin.tolist() == [0, 1, 2] + sub * 2 + [3, 4] + sub + [5, 6]
    assert fl.calls == 3
    p = gcode.parse(fl.expanded, axes=AXES)
    # X after each run: 10 -> 15 -> 20 (two runs), then 50 -> 55
    x = p.position[:, 0][np.isin(p.line - 1, np.flatnonzero(fl.origin == 9))]
    assert x.tolist() == [15.0, 20.0, 55.0]


def test_no_flow_is_none_and_m99_in_a_comment_is_not_flow():
    assert flow.expand("G0 X1.\n", "a") is None
    assert flow.expand("G0 X1. (M99 LATER)\n", "a") is None


def test_rigid_shift_compensates_the_subprogram_once_and_identity_is_byte_exact():
    fl = flow.expand(SUB, "s.nc")
    p = gcode.parse(fl.expanded, axes=AXES)
    assert flow.fold(fl, gcode.rewrite(p, lambda q: q.copy())) == ("once", SUB)
    mode, out = flow.fold(fl, gcode.rewrite(p, lambda q: q + [0.01, 0.0, 0.002]))
    assert mode == "once"
    assert out.splitlines()[7:] == SUB.splitlines()[7:]          # incremental body unchanged
    assert "G0 X10.010000 Y10." in out and "M98 P100 L2" in out


def test_position_dependent_errors_write_the_calls_out():
    fl = flow.expand(SUB, "s.nc")
    p = gcode.parse(fl.expanded, axes=AXES)
    mode, out = flow.fold(fl, gcode.rewrite(p, lambda q: q + 1e-5 * q[:, [1, 0, 2]] ** 2 * [0, 1, 0]))
    assert mode == "expanded"
    assert "M98" not in out.replace("(M98)", "") and "O100" not in out.replace("(O100)", "")
    q = gcode.parse(out, axes=AXES)                              # reads without flow
    assert len(q) == len(p)
    # every run at its own place: the Y of the X5. steps differs run by run
    assert len({round(float(y), 6) for y in q.position[q.position[:, 2] < 0, 1]}) > 1


def test_compensate_program_says_which(tmp_path):
    m = load_machine("vmc-moving-column")
    out, rep = compensate_program(SUB, m, ErrorSet(ToolSetting((0.002, -0.001, 0.0005))))
    assert rep["flow"] == "once" and any("compensated once" in n for n in rep["notes"])
    assert "M98 P100 L2" in out and out.count("O100") == 1
    # squareness of Z to X: the X word of the absolute Z block depends on where the call runs
    t = ("G90 G0 X0. Y10. Z5.\nM98 P100\nG0 Y40.\nM98 P100\nM30\n"
         "O100\nG90 G1 Z-1. F100.\nG91 X5.\nG90 G0 Z5.\nM99\n")
    e = ErrorSet(geometric=GeometricErrors(location={"EB0Z": 1e-4}))
    out, rep = compensate_program(t, m, e)
    assert rep["flow"] == "expanded" and any("written out" in n for n in rep["notes"])
    assert flow.expand(out, "o") is None and "(M98) (P100)" in out
    assert len(gcode.parse(out, axes=AXES)) == len(gcode.parse(flow.expand(t, "t").expanded, axes=AXES))
    assert rep["after_max"] < 1e-5


def test_haas_fanuc_eight_digit_p_and_k_repeat():
    t = "G90 G0 X0 Y0 Z5.\nM98 P30100\nM98 P100 K2\nM30\nO100\nG91 G0 X1.\nM99\n"
    p = gcode.parse(flow.expand(t, "t").expanded, axes=AXES)
    assert p.position[-1, 0] == 5.0
    t = "G90 G0 X0 Y0 Z5.\nM97 P7 L4\nM30\nN7 G91 G0 Y1.\nM99\n"
    assert gcode.parse(flow.expand(t, "t").expanded, axes=AXES).position[-1, 1] == 4.0


@pytest.mark.parametrize("text, line, match", [
    ("G0 X1.\nM99\nG0 X2.\nM30\n", 2, "M99 before the end of the main program"),
    ("G0 X1.\nM98 P200\nM30\nO100\nM99\n", 2, "O200 is neither in this file"),
    ("G0 X1.\nM97 P20\nM30\n", 2, "no block N20"),
    ("G0 X1.\nM98\nM30\n", 2, "without P"),
    ("G0 X1.\nM98 P100 L0\nM30\nO100\nM99\n", 2, "repeat count 0"),
    ("G0 X1.\nM98 P100\nM30\nO100\nM98 P100\nM99\n", 5, "calls itself"),
    ("G0 X1.\nM98 P100\nM30\nO100\nG0 X2.\n", 4, "has no M99"),
    ("G0 X1.\nM98 P100\nM30\nO100\nM99 P10\n", 5, "M99 P"),
    ("G0 X1.\nM98 P100\nM30\nO100\nM30\nM99\n", 5, "M30/M02 inside a subprogram"),
])
def test_flow_not_followed_is_refused_with_its_line(text, line, match):
    with pytest.raises(InputError, match=match) as exc:
        flow.expand(text, "f.nc")
    assert exc.value.line == line


def test_errors_inside_a_subprogram_name_its_source_line_and_the_call():
    m = load_machine("vmc-moving-column")
    t = "G90 G0 X0 Y0 Z5.\nM98 P100\nM30\nO100\nG0 Q1. X1.\nG51 X2.\nM99\n"
    with pytest.raises(InputError, match=r"G51.*called|G51.*run by the call on line 2") as exc:
        compensate_program(t, m, ErrorSet(ToolSetting((0.001, 0, 0))), filename="f.nc")
    assert exc.value.line == 6


@pytest.mark.parametrize("name", ["fanuc_subprog.nc", "haas_local_sub.nc"])
def test_cli_corpus_subprograms_once_under_a_tool_setting_error(name):
    m = load_machine("vmc-moving-column")
    text = gcode.read_program(NC / name)
    out, rep = compensate_program(text, m, ErrorSet(ToolSetting((0.0, 0.0, 0.0))),
                                  chordal_tol=1e-3)
    assert out == text and rep["flow"] == "once"


def test_notes_name_source_lines_not_expansion_lines():
    m = load_machine("vmc-moving-column")
    t = "G90 G0 X0 Y0 Z5.\nM98 P100 L3\nG28 G91 Z0.\nM30\nO100\nG91 G0 X1.\nG90\nM99\n"
    _, rep = compensate_program(t, m, ErrorSet(ToolSetting((0.001, 0, 0))))
    assert any(n.startswith("G28 on line(s) 3:") for n in rep["notes"]), rep["notes"]


def test_cli_follows_subprograms_and_says_so(tmp_path):
    import subprocess
    import sys

    from mtcomp.errors import save_errors
    err = save_errors(ErrorSet(ToolSetting((0.002, -0.001, 0.0005))), tmp_path / "e.toml")
    out = tmp_path / "o.nc"
    r = subprocess.run([sys.executable, "-m", "mtcomp", "compensate", str(NC / "haas_local_sub.nc"),
                        "-m", "vmc-moving-column", "-e", str(err), "-o", str(out),
                        "--start", "X=0,Y=0,Z=50"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "each subprogram compensated once" in r.stdout
    text = out.read_text()
    assert "M97 P100 L3" in text and "(MTCOMP COMPENSATED PROGRAM" in text
    assert flow.expand(text, "o").calls == 4
    bad = tmp_path / "b.nc"
    bad.write_text("G0 X1.\nM98 P9\nM30\n")
    r = subprocess.run([sys.executable, "-m", "mtcomp", "compensate", str(bad), "-m",
                        "vmc-moving-column", "-e", str(err)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and f"{bad}:2: M98 P9: program O9 is neither in this file nor a file O9[.ext] in the program" in r.stderr
    assert "Traceback" not in r.stderr


def test_hole_pattern_subprogram_under_two_cycles():
    # a common Fanuc pattern: the cycle is set in the main program, the hole positions are a
    # subprogram run once per tool
    t = ("G90 G0 X0 Y0 Z20.\nG99 G81 Z-3. R2. F100\nM98 P500\nG80\nG0 Z20.\n"
         "G98 G83 Z-12. R2. Q4. F80\nM98 P500\nG80\nG0 Z20.\nM30\nO500\nX5. Y5.\nX10.\nY10.\nM99\n")
    fl = flow.expand(t, "t")
    p = gcode.parse(fl.expanded, axes=AXES)
    # the cycle block itself drills at the current position (X0 Y0), as Fanuc and Haas do
    assert p.cycle.tolist().count(81) == 4 and p.cycle.tolist().count(83) == 4
    mode, out = flow.fold(fl, gcode.rewrite(p, lambda q: q + [0.001, 0.002, 0.003]))
    assert mode == "once" and "G99 G81 Z-2.997000 R2.003000 F100" in out
    assert "\nX5.001000 Y5.002000\n" in out
    tilt = lambda q: q + 1e-3 * q[:, [2, 2, 2]] * [1, 0, 0]   # noqa: E731
    info = {}
    mode, out = flow.fold(fl, gcode.rewrite(p, tilt, info=info))
    assert mode == "expanded" and info["cycles_expanded"] == 8
    o = gcode.parse(out, axes=AXES)
    assert not o.cycle.any() and flow.expand(out) is None
    # the pecks of the second run reach the bottom once per hole (the first where the first
    # run left the tool), X compensated there
    deep = o.position[o.position[:, 2] < -11.9]
    assert np.allclose(deep[:, 0], np.array([10, 5, 10, 10]) - 0.012)
    assert np.allclose(deep[:, 1], [10, 5, 5, 10]) and np.allclose(deep[:, 2], -12.0)


@pytest.mark.parametrize("eol, last", [("\r\n", "\r\n"), ("\n", ""), ("\r\n", "")])
def test_crlf_and_no_final_newline_fold_byte_exact(eol, last):
    text = SUB.replace("\n", eol)
    text = text[:-len(eol)] + last                      # the M99 line may end the file bare
    fl = flow.expand(text, "s.nc")
    assert fl.expanded.count("\n") == len(fl.origin)
    p = gcode.parse(fl.expanded, axes=AXES)
    assert flow.fold(fl, gcode.rewrite(p, lambda q: q.copy())) == ("once", text)
    mode, out = flow.fold(fl, gcode.rewrite(p, lambda q: q + [0.01, 0, 0]))
    assert mode == "once" and out.endswith("M99" + last)
    assert out.count("\r\n") == (text.count("\r\n"))        # no line ending changed


@pytest.mark.parametrize("compiled", [True, False], ids=["compiled", "str.find"])
def test_has_flow_prefilter_agrees_with_the_plain_search(compiled, monkeypatch):
    # has_flow jumps to the M/O letters with str.find and tries the pattern there only (or,
    # compiled, tries it at every M and O in one pass over the bytes): the same answer as the
    # regex searched over the whole text, on the corpus and random texts
    from mtcomp.gcode import _ctok
    if compiled and _ctok.load() is None:
        pytest.skip("no compiled tokenizer")
    if not compiled:
        monkeypatch.setattr(_ctok, "has_flow", lambda text, ascii=False: None)

    def plain(t):
        return flow._HAS_FLOW.search(t) is not None
    files = sorted(p for p in NC.rglob("*") if p.is_file())
    assert len(files) >= 10
    answers = [flow.has_flow(p.read_text(errors="replace")) for p in files]
    assert answers == [plain(p.read_text(errors="replace")) for p in files]
    assert any(answers) and not all(answers)
    rng = np.random.default_rng(7)
    alphabet = list("MmOo0123456789789 .\t\n<>()XYZGCcLlaA-")
    pieces = ["M98", "m 097", "M99.", "M990", "o<a> call", "O12 CALL", "o 3 cal", "M9 8", "O<x\n>call"]
    hit = 0
    for _ in range(3000):
        parts = rng.choice(alphabet, size=int(rng.integers(0, 40))).tolist()
        if rng.random() < 0.5:
            parts.insert(int(rng.integers(0, len(parts) + 1)), str(rng.choice(pieces)))
        t = "".join(parts)
        assert flow.has_flow(t) == plain(t), repr(t)
        assert flow.has_flow(t.encode()) == plain(t), repr(t)      # (the bytes path)
        hit += plain(t)
    assert 300 < hit < 2700
    # past the letter budget the plain search takes over: same answers
    many = "M3 " * (flow._FIND_HITS + 5)
    assert not flow.has_flow(many) and flow.has_flow(many + "M98 P1")


@seed(23)
@settings(max_examples=400, deadline=None, suppress_health_check=list(HealthCheck))
@given(st.lists(st.one_of(st.text("MmOo0789 .\t\n<>CcAaLlx", max_size=12),
                          st.sampled_from(["M98", "m 097", "M99.", "M990", "o<a> call", "O12 CALL",
                                           "o 3 cal", "M9 8", "O<x\n>call", "O 7\tcAlL", "M0098",
                                           "M97", "M987"])), max_size=12),
       st.integers(0, 16))
def test_compiled_has_flow_is_the_regex_search(parts, lead):
    """The compiled search on texts long enough for its eight-byte steps, at every alignment."""
    from mtcomp.gcode import _ctok
    if _ctok.load() is None:
        pytest.skip("no compiled tokenizer")
    t = "x" * lead + "".join(parts)
    assert _ctok.has_flow(t) == (flow._HAS_FLOW.search(t) is not None), repr(t)
    assert _ctok.has_flow(t + "é") is None              # not ASCII: the caller's search
    # the program's bytes, tested for ASCII or known to be
    assert _ctok.has_flow(t.encode()) == _ctok.has_flow(t.encode(), True) == _ctok.has_flow(t)
    assert _ctok.has_flow((t + "é").encode()) is None
