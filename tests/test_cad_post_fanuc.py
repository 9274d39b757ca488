"""The post as a Fanuc programmer reads it: retracts before M06 and M30, a safe start, protected
probing with a missed-touch alarm, program numbers outside the macro range, N numbers that
never repeat; and the skip log reader that does not take a G31 end point for a touch."""
import re

import numpy as np
import pytest

from mtcomp import InputError
from mtcomp.cad_plugin import post as P, toolpath as T
from mtcomp.cad_plugin.layout import BowlBlankLayout
from mtcomp.machine import load_machine


def _blocks(text):
    return [ln.split(" ", 1)[1] if re.match(r"N\d+ ", ln) else ln for ln in text.splitlines()]


@pytest.fixture(scope="module")
def probing():
    m = load_machine("robonano-a0ib")
    L = BowlBlankLayout()
    probe = T.Tool("probe", 0.25, number=9)
    tp = T.bowl_probing(L.centres, L.bowl_radius, L.bowl_depth, probe)
    return m, tp, T.to_axes(m, tp), probe


@pytest.mark.parametrize("retract,before_m06,before_m30", [
    ("G28", ["G91 G28 Z0.", "G90"], ["G91 G28 Z0.", "G28 X0. Y0.", "G90"]),
    ("G53", ["G53 G00 Z0."], ["G53 G00 Z0."]),
])
def test_spindle_retracts_before_the_tool_change_and_the_end(retract, before_m06, before_m30):
    m = load_machine("robonano-a0ib")
    tp = T.groove_plate_passes()
    b = _blocks(P.post(m, tp, options=P.PostOptions(retract=retract, spindle=8000, coolant="M08")))
    i = b.index("T1 M06")
    assert b[i - len(before_m06):i] == before_m06
    assert b[-2 - len(before_m30):-2] == before_m30 and b[-2:] == ["M30", "%"]
    assert b.index("M05") < len(b) - 2 - len(before_m30) and b.index("M09") < b.index("M05")
    none = _blocks(P.post(m, tp, options=P.PostOptions(retract="none")))
    assert not any("G28" in x or "G53" in x for x in none)
    with pytest.raises(InputError, match="retract"):
        P.PostOptions(retract="G30")


def test_length_offset_is_cancelled_on_the_retract_never_before_it():
    """Cancelling G43 before the retract moves the spindle nose down by the tool length on the
    next Z move; on the reference-return block it cannot."""
    m = load_machine("robonano-a0ib")
    b = _blocks(P.post(m, T.groove_plate_passes(), options=P.PostOptions(tool_length=True)))
    g49 = [k for k, x in enumerate(b) if "G49" in x]
    assert [b[k] for k in g49] == ["G17 G40 G49 G80 G90 G94", "G49 G91 G28 Z0."]


def test_safe_start_cancels_rotation_polar_and_mirror_before_any_move():
    m = load_machine("robonano-a0ib")
    b = _blocks(P.post(m, T.groove_plate_passes()))
    first_move = next(k for k, x in enumerate(b) if re.match(r"G0[01] ", x))
    start = " ".join(b[:first_move]).split()
    for code in ("G21", "G17", "G40", "G49", "G80", "G90", "G94", "G69", "G15", "G50.1", "G54"):
        assert code in start, code


@pytest.mark.parametrize("number", [8000, 8999, 9000, 9810, 9999, 10000, 0])
def test_program_numbers_in_the_protected_and_macro_range_are_refused(number):
    with pytest.raises(InputError, match="program number must be 1..7999"):
        P.PostOptions(program_number=number)


def test_program_number_7999_is_accepted():
    m = load_machine("robonano-a0ib")
    assert "\nO7999 (" in P.post(m, T.groove_plate_passes(), options=P.PostOptions(program_number=7999))


def _numbers(text):
    return [int(x) for x in re.findall(r"^N(\d+) ", text, re.M)]


def test_n_numbers_never_repeat():
    """Issue 35: 88,704 blocks at step 10 wrapped after N99999 and the last was N87150."""
    m = load_machine("robonano-a0ib")
    tp = T.groove_plate_passes()
    plain = P.post(m, tp, options=P.PostOptions(line_numbers=False))
    n_blocks = sum(1 for x in plain.splitlines() if not x.startswith(("%", "O", "(")))
    ok = _numbers(P.post(m, tp))
    assert ok == list(range(10, 10 * n_blocks + 1, 10))
    # too many blocks for the step below N99999: the step shrinks
    shrunk = _numbers(P.post(m, tp, options=P.PostOptions(line_start=99999 - 3 * n_blocks)))
    assert len(shrunk) == n_blocks and len(set(shrunk)) == n_blocks and max(shrunk) <= 99999
    assert set(np.diff(shrunk)) == {3}
    # not even step 1 fits: no N words at all, and the header says so
    text = P.post(m, tp, options=P.PostOptions(line_start=99999 - n_blocks // 2))
    assert _numbers(text) == [] and f"(NO N NUMBERS: {n_blocks} BLOCKS DO NOT FIT BELOW N99999)" in text


def test_probing_uses_protected_moves_an_explicit_feed_and_a_missed_touch_alarm(probing):
    m, tp, q, probe = probing
    b = _blocks(P.post(m, tp, q))
    g31 = [k for k, x in enumerate(b) if x.startswith("G31 ")]
    assert len(g31) == 39
    for k in g31:
        assert re.search(r" F20\.0$", b[k])                       # a G31 states its own feed
        assert b[k + 1].startswith("#104=ABS[#5061-[") and \
            b[k + 2] == "IF[#104LT0.001]THEN#3000=91(PROBE DID NOT TOUCH)"
        before = b[k - 1] if not b[k - 1].startswith("#") else b[k - 5]
        assert before.startswith("G65 P9810 X") and " F" in before  # protected approach
    # every feed move near the part is protected; only rapids at the safe height are G00
    assert not any(x.startswith("G01") for x in b)
    # the alarm fires exactly when the skip position is the G31 end point
    for k in g31[:5]:
        end = dict(re.findall(r"([XYZ])(-?[\d.]+)", b[k + 1].replace("#5061-[", "X").replace(
            "#5062-[", "Y").replace("#5063-[", "Z")))
        for skip, fires in ((end, True), ({a: float(v) + 0.05 for a, v in end.items()}, False)):
            expr = b[k + 1].split("=", 1)[1]
            for a, var in (("X", "#5061"), ("Y", "#5062"), ("Z", "#5063")):
                expr = expr.replace(var, repr(float(skip[a])))
            d = eval(expr.replace("ABS[", "abs(").replace("[", "(").replace("]", ")"))   # noqa: S307
            assert (d < P.MISSED_TOL) == fires


def test_read_skip_log_refuses_a_g31_end_point_as_a_touch(probing):
    m, tp, q, probe = probing
    text = P.post(m, tp, q, P.PostOptions(probe_log=True))
    idx = np.nonzero(tp.motion == T.PROBE)[0][:3]
    lines = ["MTCOMP PROBE LOG"]
    for n, i in enumerate(idx):
        frac = 1.0 if n == 2 else 0.5          # the third G31 never touched
        pos = q[i - 1] + frac * (q[i] - q[i - 1])
        xyz = {a: pos[m.index(a)] for a in m.axis_names}
        d = 0.0 if frac == 1.0 else float(sum(abs(q[i, m.index(a)] - xyz[a]) for a in "XYZ"))
        words = ["T  1 I 0.000000 J 0.000000 K-1.000000"] + [f"{a}{xyz[a]: .6f}" for a in m.axis_names]
        lines.append("  ".join(words) + f"  D{d: .4f}")
    log = "\n".join(lines)
    with pytest.raises(InputError, match=r":4 \[D\]: missed touch: the skip position is the G31 end point"):
        P.read_skip_log(log, m, probe.radius)
    # a log without D (printed by an older program): the posted program tells the end points
    no_d = re.sub(r"  D[ -][\d.]+", "", log)
    with pytest.raises(InputError, match=r":4: missed touch: the skip position is the end point of G31 move 3"):
        P.read_skip_log(no_d, m, probe.radius, program=text)
    # the two real touches read as before, with or without the program
    good = "\n".join(lines[:3])
    assert len(P.read_skip_log(good, m, probe.radius).bowl) == 2
    assert len(P.read_skip_log(re.sub(r"  D[ -][\d.]+", "", good), m, probe.radius, program=text).bowl) == 2


def test_cli_probing_program_with_and_without_the_protected_macro(tmp_path, capsys):
    from mtcomp.cli import main
    out = tmp_path / "probe.nc"
    assert main(["cad", "toolpath", "probe-bowls", "-m", "robonano-a0ib", "-o", str(out)]) == 0
    text = out.read_text()
    assert "G65 P9810 " in text and "THEN#3000=91" in text and "G91 G28 Z0." in text
    assert main(["cad", "toolpath", "probe-bowls", "-m", "robonano-a0ib", "-o", str(out),
                 "--protected-macro", "0"]) == 0
    assert "G65" not in out.read_text() and "THEN#3000=91" in out.read_text()
    assert main(["cad", "toolpath", "probe-bowls", "-m", "robonano-a0ib", "-o", str(out),
                 "--program-number", "9810"]) == 2
    assert "program number must be 1..7999" in capsys.readouterr().err


def test_motion_view_keeps_line_numbers_and_turns_protected_calls_into_their_moves(probing):
    m, tp, q, probe = probing
    text = P.post(m, tp, q)
    view = P.motion_view(text)
    a, b = text.splitlines(), view.splitlines()
    assert len(a) == len(b)
    for x, y in zip(a, b):
        if re.match(r"N\d+ G65 P9810 ", x):
            assert y == x.replace("G65 P9810 ", "G01 ")
        elif "#104" in x:
            assert y == ""
        else:
            assert y == x
