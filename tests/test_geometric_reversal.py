"""Reversal (backlash) from ISO 230-2 runs: hand computation, controller tables, compensation of a
simulated axis with backlash by the direction of approach."""
import numpy as np
import pytest

from mtcomp import InputError
from mtcomp.cli import main
from mtcomp.geometric import iso230_2 as iso
from mtcomp.geometric.reversal import ReversalTable, reversal_table

# Hand example (µm), two cycles, three targets:
#   up:   T0: -3 -1 (mean -2)   T1: 1 3 (mean 2)    T2: -4 -6 (mean -5)
#   down: T0:  2  4 (mean  3)   T1: 6 6 (mean 6)    T2:  0 -2 (mean -1)
# ISO 230-2: B_i = x̄_i↑ − x̄_i↓ = -5, -4, -4;  B = max |B_i| = 5;  B̄ = -13/3
UP = np.array([[-3, 1, -4], [-1, 3, -6]]) * 1e-3
DOWN = np.array([[2, 6, 0], [4, 6, -2]]) * 1e-3
TARGET = np.array([0.0, 50.0, 120.0])


def test_reversal_values_match_the_hand_computation():
    res = iso.evaluate(iso.PositioningRun(TARGET, UP, DOWN, axis="X"))
    tab = reversal_table(res)
    np.testing.assert_allclose(tab.reversal_i, np.array([-5, -4, -4]) * 1e-3, atol=1e-12)
    assert tab.B == pytest.approx(5e-3, abs=1e-12) and res.B == pytest.approx(5e-3, abs=1e-12)
    assert tab.B_mean == pytest.approx(-13 / 3 * 1e-3, abs=1e-12)
    assert tab.backlash == pytest.approx(13 / 3 * 1e-3, abs=1e-12)       # lost motion, positive
    # corrections by direction: minus the mean deviation of that direction, linear between targets
    assert tab.correction(0.0, +1) == pytest.approx(2e-3)
    assert tab.correction(0.0, -1) == pytest.approx(-3e-3)
    assert tab.correction(25.0, +1) == pytest.approx(0.0)                # halfway -2 .. 2 µm
    assert tab.correction(200.0, -1) == pytest.approx(1e-3)              # held beyond the end
    # backlash mode: mean table ± B̄/2 by direction
    assert tab.correction(0.0, +1, "backlash") == pytest.approx(-0.5e-3 - (-13 / 3 * 1e-3) / 2)
    assert tab.correction(0.0, -1, "mean") == pytest.approx(-0.5e-3)


def test_fanuc_style_table_increments_sum_to_the_corrections():
    tab = ReversalTable("X", TARGET, UP.mean(axis=0), DOWN.mean(axis=0))
    text = tab.fanuc_pitch(unit=1e-4, interval=10.0)
    rows = [ln.split(",") for ln in text.splitlines() if ln and not ln.startswith("#")][1:]
    assert len(rows) == 13 and float(rows[-1][1]) == pytest.approx(120.0)
    inc_up = np.array([int(r[2]) for r in rows])
    abs_up = np.array([int(r[4]) for r in rows])
    np.testing.assert_array_equal(np.cumsum(inc_up) + abs_up[0], abs_up)
    pos = np.array([float(r[1]) for r in rows])
    exact = tab.correction(pos, +1) / 1e-4
    assert np.max(np.abs(abs_up - exact)) <= 0.5 + 1e-9                  # rounded, never drifting
    assert "backlash parameter (lost motion, -B_mean): 43 detection units" in text
    with pytest.raises(InputError, match="unit"):
        tab.fanuc_pitch(unit=0.0)
    with pytest.raises(InputError, match="direction"):
        tab.correction(1.0, 0)


def _axis(x_cmd, direction, rng, lost=0.004, sigma=0.0003):
    """A simulated axis: smooth pitch error, lost motion (backlash) by direction, reading noise."""
    pitch = 0.006 * np.sin(2 * np.pi * x_cmd / 700.0) + 2e-5 * x_cmd
    return x_cmd + pitch - np.asarray(direction) * lost / 2 + rng.normal(0.0, sigma, np.shape(x_cmd))


def test_bidirectional_table_compensates_a_machine_with_backlash_to_within_the_noise():
    rng = np.random.default_rng(230)
    target = np.linspace(0.0, 400.0, 17)
    n, sigma = 5, 0.0003
    up = np.array([_axis(target, +1, rng) - target for _ in range(n)])
    down = np.array([_axis(target, -1, rng) - target for _ in range(n)])
    tab = reversal_table(iso.evaluate(iso.PositioningRun(target, up, down, axis="X")))
    assert tab.backlash == pytest.approx(0.004, abs=4 * sigma / np.sqrt(n))
    x = rng.uniform(0.0, 400.0, 4000)
    d = rng.choice([-1, 1], x.size)
    err = {}
    for mode in ("bidirectional", "backlash", "mean"):
        err[mode] = _axis(tab.compensate(x, d, mode), d, rng) - x
    for mode in ("bidirectional", "backlash"):
        # residual: the reading noise plus the table's own uncertainty (sigma / sqrt n)
        assert np.std(err[mode]) < sigma * np.sqrt(1 + 2.0 / n) * 1.1, mode
        for s in (-1, 1):
            assert abs(np.mean(err[mode][d == s])) < 3 * sigma, mode
    # the bidirectional mean (what the component tables hold) leaves the lost motion by direction
    assert np.mean(err["mean"][d > 0]) == pytest.approx(-0.002, abs=3 * sigma)
    assert np.mean(err["mean"][d < 0]) == pytest.approx(0.002, abs=3 * sigma)


def test_reversal_cli_writes_both_tables(tmp_path, capsys):
    run = iso.PositioningRun(TARGET, UP, DOWN, axis="Y")
    p = tmp_path / "run.csv"
    p.write_text(iso.run_to_csv(run))
    assert main(["geometric", "reversal", str(p), "--axis", "Y", "--unit", "1e-4", "-o", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    assert "B = 5.000 µm" in out and "backlash (lost motion) = +4.333 µm" in out
    assert (tmp_path / "o" / "Y_reversal.csv").exists() and (tmp_path / "o" / "Y_pitch_bidirectional.csv").exists()
    assert main(["geometric", "reversal", str(p), "--unit", "-1", "-o", str(tmp_path / "bad")]) != 0
    assert not (tmp_path / "bad").exists()


# ------------------------------------------------------------------ issue 15 reproducers

def _run_rows(skip=None):
    rows = ["target,cycle,direction,deviation"]
    for j in range(1, 4):
        for t in (0.0, 10.0, 20.0):
            if (j, "+", t) != skip:
                rows.append(f"{t},{j},+,0.001")
        for t in (20.0, 10.0, 0.0):
            rows.append(f"{t},{j},-,-0.001")
    return "\n".join(rows) + "\n"


def test_target_missing_in_cycle_1_is_reported_as_missing_there(tmp_path):
    """Issue 15: it was reported as an 'extra' target of cycle 2."""
    p = tmp_path / "run.csv"
    p.write_text(_run_rows(skip=(1, "+", 10.0)))
    with pytest.raises(InputError) as exc:
        iso.read_run_csv(p)
    msg = str(exc.value)
    assert "cycle 1, direction + has missing target(s) 10" in msg and "extra" not in msg
    assert exc.value.line == 2


@pytest.mark.parametrize("entry,field", [
    ('run = [1, 2]', "run[0]"),
    ('run = ["x.csv"]', "run[0]"),
    ('[[run]]\naxis = "X"\ncomponent = "EXX"\nfile = ""', "run[0].file"),
    ('[[run]]\naxis = "X"\ncomponent = "EXX"\nfile = "."', "run[0].file"),
    ('[[run]]\naxis = "X"\ncomponent = "EXX"\nfile = "nope.csv"', "run[0].file"),
    ('[[run]]\naxis = "X"\ncomponent = "EXX"\nfile = "r.csv"\noffset = [true, 0, 0]', "run[0].offset"),
])
def test_measurement_set_with_bad_run_entries_is_an_input_error(tmp_path, entry, field):
    """Issue 15: non-table run entries (AttributeError) and file = "" (IsADirectoryError)."""
    from mtcomp.geometric.tables import load_measurement_set
    (tmp_path / "r.csv").write_text(_run_rows())
    p = tmp_path / "set.toml"
    p.write_text('machine = "vmc-moving-column"\n' + entry + "\n")
    with pytest.raises(InputError) as exc:
        load_measurement_set(p)
    assert exc.value.field == field
    assert main(["geometric", "build", str(p), "-o", str(tmp_path / "e.toml")]) != 0
