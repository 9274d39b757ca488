"""Thermal drift that follows a logged temperature: the gain is recovered, not traded for a
cancelling transient and offset; a temperature copied into SIM drives, it is not compared."""
import numpy as np
import pytest

from mtcomp.diagnose import diagnose

GAIN = 0.004  # mm/degC, 4 µm/degC


def _case(stop_and_measure: bool, seed: int, temp_in_sim: bool = False):
    rng = np.random.default_rng(seed)
    if stop_and_measure:  # one reading a minute at a fixed position for an hour
        t = np.arange(0, 3600, 60.0)
        z = np.full_like(t, 50.0)
    else:  # 1 Hz log of a moving axis
        t = np.arange(0, 3600, 1.0)
        z = 100 * np.sin(2 * np.pi * t / 300)
    temp = 20 + 3 * (1 - np.exp(-t / 900))    # the structure warms up like exp(-t/900 s)
    rec_z = z + GAIN * (temp - 20) + rng.normal(0, 3e-4, len(t))
    sim = {"t": t, "z[mm]": z}
    if temp_in_sim:
        sim["T_spindle[degC]"] = temp
    return sim, {"t": t, "z[mm]": np.round(rec_z, 4), "T_spindle[degC]": temp}


@pytest.mark.parametrize("stop", [True, False], ids=["stop-and-measure", "moving"])
def test_drift_following_a_logged_temperature_has_its_gain(stop):
    # the temperature rises exactly like exp(-t/tau): the lagged model with a free initial
    # transient fits as well with any gain (0.01 µm/degC and +-12 µm transient/offset were
    # reported before); the direct response is the identifiable answer
    for seed in (1, 2, 3):
        res = diagnose(*_case(stop, seed))
        assert res.names == ["thermal_drift"], res.summary()
        e = res.effects[0]
        assert e.inputs == ("T_spindle",)
        g, sg = e.params["gain_mm_per_degC"], e.uncertainty["gain_mm_per_degC"]
        assert abs(g - GAIN) < max(3 * sg, 2e-4), (g, sg)
        assert sg < 0.1 * GAIN


def test_a_temperature_in_both_files_is_a_driver_not_an_output():
    res = diagnose(*_case(True, 4, temp_in_sim=True))
    assert res.names == ["thermal_drift"], res.summary()
    assert "T_spindle" not in res.outputs
    assert any("T_spindle" in n and "input" in n for n in res.notes), res.notes
    res2 = diagnose(*_case(True, 4, temp_in_sim=True), outputs=["z", "T_spindle"])
    assert "T_spindle" in res2.outputs
