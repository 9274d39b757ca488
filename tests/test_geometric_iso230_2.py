"""ISO 230-2 evaluation: a hand-computed example, round trips and bad runs."""
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from mtcomp import InputError
from mtcomp.geometric import iso230_2 as iso

# Hand example (deviations in µm, three targets, three cycles).
#   up:   P0: 1 3 2 (mean 2, s 1)   P1: 4 6 5 (mean 5, s 1)   P2: 0 2 4 (mean 2, s 2)
#   down: P0: -2 -2 -2 (mean -2, s 0)  P1: 2 3 4 (mean 3, s 1)  P2: -1 1 0 (mean 0, s 1)
# B_i = 4, 2, 2 -> B = 4, B̄ = 8/3;  R_i↑ = 4, 4, 8; R_i↓ = 0, 4, 4;
# R_i = max(2s↑+2s↓+|B_i|, R_i↑, R_i↓) = 6, 6, 8 -> R = 8, R↑ = 8, R↓ = 4
# E↑ = 5-2 = 3, E↓ = 3-(-2) = 5, E = 5-(-2) = 7; x̄_i = 0, 4, 1 -> M = 4
# A↑ = max(4, 7, 6) - min(0, 3, -2) = 9; A↓ = max(-2, 5, 2) - min(-2, 1, -2) = 7; A = 7-(-2) = 9
UP = np.array([[1, 4, 0], [3, 6, 2], [2, 5, 4]]) * 1e-3
DOWN = np.array([[-2, 2, -1], [-2, 3, 1], [-2, 4, 0]]) * 1e-3
TARGET = np.array([0.0, 100.0, 200.0])
HAND = dict(B=4, B_mean=8 / 3, R=8, R_up=8, R_down=4, E_up=3, E_down=5, E=7, M=4, A_up=9, A_down=7,
            A=9)


def _write_hand_csv(path: Path) -> Path:
    lines = ["# hand example", "target,cycle,direction,deviation"]
    for j in range(3):
        for i in range(3):
            lines.append(f"{TARGET[i]},{j + 1},+,{float(UP[j, i])!r}")
        for i in (2, 1, 0):
            lines.append(f"{TARGET[i]},{j + 1},-,{float(DOWN[j, i])!r}")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_hand_example_from_csv(tmp_path):
    run = iso.read_run_csv(_write_hand_csv(tmp_path / "run.csv"), axis="X")
    res = iso.evaluate(run)
    for key, um in HAND.items():
        assert getattr(res, key) == pytest.approx(um * 1e-3, abs=1e-9), key
    np.testing.assert_allclose(res.mean_up, np.array([2, 5, 2]) * 1e-3, atol=1e-12)
    np.testing.assert_allclose(res.mean_down, np.array([-2, 3, 0]) * 1e-3, atol=1e-12)
    np.testing.assert_allclose(res.s_up, np.array([1, 1, 2]) * 1e-3, atol=1e-12)
    np.testing.assert_allclose(res.s_down, np.array([0, 1, 1]) * 1e-3, atol=1e-12)
    np.testing.assert_allclose(res.R_i, np.array([6, 6, 8]) * 1e-3, atol=1e-12)


def test_csv_round_trip_and_report(tmp_path):
    run = iso.PositioningRun(TARGET, UP, DOWN, axis="X")
    p = tmp_path / "rt.csv"
    p.write_text(iso.run_to_csv(run))
    back = iso.read_run_csv(p)
    np.testing.assert_array_equal(back.up, UP)
    np.testing.assert_array_equal(back.down, DOWN)
    out = iso.write_report(iso.evaluate(back), tmp_path / "rep")
    assert out["plot"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    figs = dict(line.split(",") for line in out["figures"].read_text().splitlines()[1:])
    assert float(figs["A"]) == pytest.approx(9e-3, abs=1e-12)
    assert "accuracy, bidirectional" in out["text"].read_text()
    assert len(out["positions"].read_text().splitlines()) == 4


def test_rows_may_be_listed_in_any_cycle_order(tmp_path):
    """Cycles interleaved differently in the file give identical figures."""
    lines = ["target,cycle,direction,deviation"]
    for j in (2, 0, 1):
        for i in (2, 1, 0):
            lines.append(f"{TARGET[i]},{j + 1},down,{float(DOWN[j, i])!r}")
    for j in (1, 2, 0):
        for i in range(3):
            lines.append(f"{TARGET[i]},{j + 1},up,{float(UP[j, i])!r}")
    p = tmp_path / "r.csv"
    p.write_text("\n".join(lines) + "\n")
    res = iso.evaluate(iso.read_run_csv(p))
    assert res.A == pytest.approx(9e-3, abs=1e-12)


def _lines(tmp_path, drop=None, swap=None, extra=()):
    lines = _write_hand_csv(tmp_path / "x.csv").read_text().splitlines()
    if swap:
        a, b = swap
        lines[a], lines[b] = lines[b], lines[a]
    if drop is not None:
        lines = [ln for k, ln in enumerate(lines) if not drop(k, ln)]
    lines += list(extra)
    p = tmp_path / "bad.csv"
    p.write_text("\n".join(lines) + "\n")
    return p


def test_unequal_cycle_counts(tmp_path):
    p = _lines(tmp_path, drop=lambda k, ln: ln.startswith(("0.0,3,-", "100.0,3,-", "200.0,3,-")))
    with pytest.raises(InputError, match="unequal cycle counts: 3 cycles in the positive direction, 2"):
        iso.read_run_csv(p)


def test_missing_target_in_one_cycle(tmp_path):
    p = _lines(tmp_path, drop=lambda k, ln: ln.startswith("100.0,2,+"))
    with pytest.raises(InputError, match=r"cycle 2, direction \+ has missing target\(s\) 100"):
        iso.read_run_csv(p)


def test_missing_direction(tmp_path):
    p = _lines(tmp_path, drop=lambda k, ln: ",-," in ln)
    with pytest.raises(InputError, match="missing direction: the run has only positive"):
        iso.read_run_csv(p)


def test_non_monotonic_targets_name_the_line(tmp_path):
    # lines: 0 comment, 1 header, 2..4 cycle 1 up (0, 100, 200): swap 100 and 200
    p = _lines(tmp_path, swap=(3, 4))
    with pytest.raises(InputError, match=r"bad.csv:5 \[target\]: non-monotonic targets"):
        iso.read_run_csv(p)


def test_binary_file_is_an_input_error(tmp_path):
    p = tmp_path / "run.bin"
    p.write_bytes(b"\x89PNG\r\n\x1a\n\x00\xff\xfe")
    with pytest.raises(InputError, match=r"run.bin(:1: header lacks column|: not a text file)"):
        iso.read_run_csv(p)


def test_bad_fields(tmp_path):
    p = _lines(tmp_path, extra=["300.0,1,sideways,0.0"])
    with pytest.raises(InputError, match=r"\[direction\]"):
        iso.read_run_csv(p)
    p = _lines(tmp_path, extra=["300.0,x,+,0.0"])
    with pytest.raises(InputError, match=r"\[cycle\]"):
        iso.read_run_csv(p)
    (tmp_path / "h.csv").write_text("pos,cycle,direction,deviation\n0,1,+,0\n")
    with pytest.raises(InputError, match="header lacks column"):
        iso.read_run_csv(tmp_path / "h.csv")


def test_single_cycle_rejected():
    with pytest.raises(InputError, match="at least two cycles"):
        iso.PositioningRun(TARGET, UP[:1], DOWN[:1])


def test_figures_invariant_under_offset_and_reordering_of_cycles():
    """A common offset moves means but not B, R, E, M, A; cycle order changes nothing."""
    rng = np.random.default_rng(3)
    up, dn = rng.normal(0, 2e-3, (5, 7)), rng.normal(1e-3, 2e-3, (5, 7))
    t = np.linspace(0, 600, 7)
    a = iso.evaluate(iso.PositioningRun(t, up, dn))
    b = iso.evaluate(iso.PositioningRun(t, up[::-1] + 0.01, dn[[2, 0, 4, 1, 3]] + 0.01))
    for k in ("A", "B", "E", "M", "R", "R_up", "R_down", "A_up", "A_down"):
        assert getattr(a, k) == pytest.approx(getattr(b, k), abs=1e-12)
    # R_i ≥ R_i↑ and A ≥ E (definitions)
    assert np.all(a.R_i >= a.R_up_i) and a.A >= a.E



@settings(max_examples=60, deadline=None)
@given(n=st.integers(2, 6), m=st.integers(2, 8), seed=st.integers(0, 2**31 - 1),
       k=st.floats(0.01, 100.0))
def test_figure_relations_hold_for_any_run(n, m, seed, k):
    """M ≤ E ≤ A, R_i ≥ R_i↑, R_i↓, |B_i| ≤ R_i; all figures scale with the deviations."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(1, 50, m))
    up, dn = rng.normal(0, 5e-3, (n, m)), rng.normal(2e-3, 5e-3, (n, m))
    a = iso.evaluate(iso.PositioningRun(t, up, dn))
    assert a.M <= a.E + 1e-15 and a.E <= a.A + 1e-15
    assert a.E_up <= a.A_up + 1e-15 and a.E_down <= a.A_down + 1e-15
    assert np.all(a.R_i >= np.maximum(a.R_up_i, a.R_down_i))
    assert np.all(np.abs(a.reversal_i) <= a.R_i + 1e-15)
    b = iso.evaluate(iso.PositioningRun(t, k * up, k * dn))
    for key, v in a.figures().items():
        assert getattr(b, key) == pytest.approx(k * v, rel=1e-9, abs=1e-15)


@pytest.mark.parametrize("cell, col, match", [
    ("1_00.0", 0, r"\[target\]: expected a number, got '1_00.0'"),     # float() read it as 100
    ("1e300", 3, r"\[deviation\]: '1e300' is out of range"),           # overflowed the figures
])
def test_run_cells_go_through_the_shared_reader(tmp_path, cell, col, match):
    lines = _write_hand_csv(tmp_path / "x.csv").read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.startswith("100.0,1,+,"))
    c = lines[k].split(",")
    c[col] = cell
    lines[k] = ",".join(c)
    p = tmp_path / "bad.csv"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=rf"bad.csv:{k + 1} " + match):
        iso.read_run_csv(p)


def test_run_header_units_are_converted(tmp_path):
    # a laser interferometer export in µm: the old reader refused the header
    lines = _write_hand_csv(tmp_path / "x.csv").read_text().splitlines()
    h = next(i for i, ln in enumerate(lines) if ln.startswith("target"))
    lines[h] = "Target [mm],cycle,direction,Deviation [µm]"
    for i in range(h + 1, len(lines)):
        c = lines[i].split(",")
        c[3] = repr(float(c[3]) * 1e3)
        lines[i] = ",".join(c)
    (tmp_path / "um.csv").write_text("\n".join(lines) + "\n")
    run = iso.read_run_csv(tmp_path / "um.csv")
    np.testing.assert_allclose(run.up, UP, atol=1e-15)
    np.testing.assert_allclose(run.down, DOWN, atol=1e-15)
    np.testing.assert_array_equal(run.target, TARGET)
