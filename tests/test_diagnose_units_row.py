"""Scope and trace exports write the units in a second header row (``Time,X`` then ``s,um``)."""
import numpy as np
import pytest

from mtcomp._io import InputError
from mtcomp.diagnose import diagnose
from mtcomp.diagnose.data import read_table


def _write(path, units_row, scale=1.0, lag=0.0):
    t = np.arange(0, 2, 0.01)
    x = 10 * np.sin(3 * t)
    with open(path, "w") as f:
        f.write("# exported by a scope\nTime,X,Temp\n")
        if units_row is not None:
            f.write(units_row + "\n")
        for a, b in zip(t, x):
            f.write(f"{a * scale:.6f},{np.interp(a - lag, t, x) * 1000:.4f},20.0\n")   # X in µm
    return path


def test_a_units_row_gives_the_units(tmp_path):
    tab = read_table(_write(tmp_path / "a.csv", "s,um,degC"))
    x = tab.columns["X"]
    assert x.kind == "length" and x.unit == "mm" and x.kind_from != "name"
    np.testing.assert_allclose(x.values[:3], 10 * np.sin(3 * np.arange(3) * 0.01), atol=1e-7)  # µm -> mm
    assert tab.n == 200 and tab.t[1] == pytest.approx(0.01)
    ms = read_table(_write(tmp_path / "b.csv", "[ms],[µm],[degC]", scale=1000.0))
    assert ms.t[1] == pytest.approx(0.01)          # the time unit of the row converts to s
    np.testing.assert_allclose(ms.columns["X"].values, tab.columns["X"].values, atol=1e-9)
    # the diagnosis sees a servo lag in mm, not in unknown units from the name
    res = diagnose(_write(tmp_path / "sim.csv", "s,um,degC"),
                   _write(tmp_path / "rec.csv", "s,um,degC", lag=0.02))
    assert not any("taken as" in n and "'X'" in n for n in res.notes), res.notes


def test_a_first_row_that_is_not_all_units_stays_data(tmp_path):
    with pytest.raises(InputError, match=r"a\.csv:3"):
        read_table(_write(tmp_path / "a.csv", "s,um,warm"))   # 'warm' is no unit: a bad number
    tab = read_table(_write(tmp_path / "b.csv", None))
    assert tab.n == 200 and tab.columns["X"].kind_from == "name"   # no units: guessed from the name
