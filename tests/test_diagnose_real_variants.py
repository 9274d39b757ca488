"""Diagnosis of real recordings unlike the one it was developed on (excerpts of the UMich CNC
runs: a 300-sample sub-range, accelerations as outputs): what a new user would point it at."""
from pathlib import Path

import pytest

from mtcomp.diagnose import diagnose

DATA = Path(__file__).parent / "data" / "umich"


def _ratio(res, o):
    return res.fit["holdout_rms_after"][o] / res.fit["holdout_rms_before"][o]


@pytest.mark.xfail(strict=True, reason=(
    "issue 30's held-out re-check (every parameter refitted without each block, from neutral "
    "starts) drops the vz lag on this 300-row excerpt of run 01: the refits of the lag do worse "
    "than a clock offset in its place; the same lag is kept on the whole runs and predicts run 04 "
    "from 01/06/11 at 0.42 (benchmarks/diagnose_umich_loro.py). Open: whether the refit or the rule "
    "is at fault on short excerpts. Strict: it fails the day the lag is kept again."))
def test_a_large_unexplained_mismatch_on_one_axis_does_not_hide_the_lags_of_the_others():
    # Z holds a mismatch 40x its noise floor that no effect explains; pooled over the axes,
    # its residual swamped the evidence for the lags of X and Y (the old answer: servo lag on
    # Z only, X and Y "unexplained" with a held-out ratio of 1.00 although their residuals
    # follow the commanded acceleration with r = -0.9)
    d = DATA / "exp01_rows150-450"
    res = diagnose(d / "sim.csv", d / "rec.csv")
    lags = {e.outputs[0]: e for e in res.effects if e.name == "servo_lag" and len(e.outputs) == 1}
    assert {"vx", "vy", "vz"} <= set(lags), res.summary()
    for o in ("vx", "vy", "vz"):
        # a position-loop time constant of a few ms, as on the whole runs
        assert 0.003 < lags[o].params["tau_s"] < 0.015, lags[o].params
        assert _ratio(res, o) < 0.75, (o, _ratio(res, o))
    assert "explained by noise" not in res.summary()


def test_accelerations_as_outputs_get_no_lag_fitted_into_its_bound():
    # measured against commanded acceleration at 10 Hz: the old answer was a servo lag with
    # kv = 0.5 1/s (tau = 2 s, the slowest the fit allowed), an unidentified parameter named as
    # physics (brought in by the exchange pass and the final refit, past the forward checks)
    d = DATA / "exp04_acc"
    res = diagnose(d / "sim.csv", d / "rec.csv")
    assert res.alignment["columns"]["ax"]["kind"] == "acceleration"
    for e in res.effects:
        if e.name == "servo_lag":
            assert e.params["kv_per_s"] > 1.0, (e.params, res.log)
    for o in res.outputs:
        assert _ratio(res, o) <= 1.0, (o, _ratio(res, o))
    assert "explained by noise" not in res.summary()


def test_an_effect_that_held_out_data_do_not_support_is_not_named():
    # 150 samples in which Z moves in one block of the five only: without that block its lag's
    # time constant is anywhere, and the old answer named a lag on Z at the bound of its range
    # whose held-out error (every parameter refitted without the block) was 1.06x no model
    d = DATA / "exp06_rows864-1014"
    res = diagnose(d / "sim.csv", d / "rec.csv")
    for e in res.effects:
        for o in e.outputs:
            assert _ratio(res, o) <= 1.0, (e.name, o, _ratio(res, o), res.log)
    lags = {e.outputs[0] for e in res.effects if e.name == "servo_lag"}
    assert {"vx", "vy"} <= lags, res.summary()
    # what is left on Z is said, not called noise
    assert "vz" in [u["output"] for u in res.unexplained]


def test_joint_names_pair_a_rate_with_its_commanded_derivative(tmp_path):
    # a robot's convention: joint rates q1..q3 [deg/s] and the commanded accelerations q1dd..
    # (also written qdd1, ddq1, q1_ddot). The real UMich velocities under such names (a lag is
    # the same whatever the unit): the old answer paired no acceleration with its rate and,
    # at 10 Hz, named only a delay on all three (held out 0.81-0.97)
    import csv
    src = DATA / "exp06"
    names = {"vx": "q1", "vy": "q2", "vz": "q3", "ax_cmd": "qdd1", "ay_cmd": "q2dd",
             "az_cmd": "q3_ddot"}

    def convert(name):
        with open(src / name, newline="") as f:
            rows = list(csv.reader(f))
        keep = [i for i, h in enumerate(rows[0]) if h == "t[s]" or h.split("[")[0] in names]
        head = []
        for i in keep:
            h = rows[0][i]
            base = h.split("[")[0]
            head.append(h if base == "t" else names[base] + h[len(base):].replace("mm", "deg"))
        (tmp_path / name).write_text("\n".join(",".join(r[i] for i in keep)
                                               for r in [head] + rows[1:]) + "\n")
    convert("sim.csv")
    convert("rec.csv")
    res = diagnose(tmp_path / "sim.csv", tmp_path / "rec.csv")
    assert res.alignment["columns"]["q1"]["kind"] == "angular_velocity"
    lags = {e.outputs[0]: e for e in res.effects if e.name == "servo_lag"}
    assert set(lags) == {"q1", "q2", "q3"}, res.summary()
    accel = {"q1": "qdd1", "q2": "q2dd", "q3": "q3_ddot"}
    for o, e in lags.items():
        assert accel[o] in e.inputs, e.inputs
        assert 0.003 < e.params["tau_s"] < 0.015


def test_rate_names_with_words_of_role_keep_their_quantity():
    # a unit-less `ax_cmd` (the UMich excerpt's commanded acceleration without its unit) was
    # taken as a length, `vx_act` too, and `a_x` as an angular acceleration of the A axis
    from mtcomp.diagnose.data import kind_from_name as k
    for n in ("vx_cmd", "vx_act", "cmd_vx", "vx1_cmd", "v_x_cmd", "ActualVx"):
        assert k(n) == "velocity", n
    for n in ("ax_cmd", "ax_act", "act_ax", "a_x", "a_x_cmd", "ay1"):
        assert k(n) == "acceleration", n
    assert k("va_cmd") == "angular_velocity"
    # a spindle's acceleration is not a speed (no kind holds rpm/s)
    assert k("S_acc") == "other" and k("spindle_accel") == "other"
    # unchanged: axes, spindle speeds, temperatures
    assert [k(n) for n in ("x_cmd", "a_cmd", "S", "spindle_speed", "temp_ax")] == \
        ["length", "angle", "speed", "speed", "temperature"]


def test_umich_excerpt_without_units_in_the_headers(tmp_path):
    # the same files with the units stripped from the headers: every column's quantity from its
    # name (reported), the lags found as with the units
    for name in ("sim.csv", "rec.csv"):
        lines = (DATA / "exp06" / name).read_text().splitlines()
        head = ",".join(h.split("[")[0] for h in lines[0].split(","))
        (tmp_path / name).write_text("\n".join([head] + lines[1:]) + "\n")
    res = diagnose(tmp_path / "sim.csv", tmp_path / "rec.csv")
    cols = res.alignment["columns"]
    assert cols["ax_cmd"]["kind"] == "acceleration" and cols["ax_cmd"]["kind_from"] == "name"
    assert cols["vx"]["kind"] == "velocity"
    lags = {e.outputs[0] for e in res.effects if e.name == "servo_lag"}
    assert lags == {"vx", "vy", "vz"}, res.summary()
    for e in res.effects:
        if e.name == "servo_lag":
            assert any(i.endswith("_cmd") for i in e.inputs), e.inputs


def test_unix_time_in_ms_and_us_is_read(tmp_path):
    # loggers count Unix time in ms or us: 1.7e12 ms was refused as an absurd value before its
    # unit was applied; the same excerpt on such clocks gives the same diagnosis
    base = diagnose(DATA / "exp06" / "sim.csv", DATA / "exp06" / "rec.csv")
    for unit, scale in (("ms", 1e3), ("us", 1e6)):
        for name in ("sim.csv", "rec.csv"):
            lines = (DATA / "exp06" / name).read_text().splitlines()
            out = [f"t[{unit}]," + lines[0].split(",", 1)[1]]
            for ln in lines[1:]:
                t, rest = ln.split(",", 1)
                out.append(f"{1_701_500_000 * scale + round(float(t) * scale):.0f},{rest}")
            (tmp_path / f"{unit}_{name}").write_text("\n".join(out) + "\n")
        res = diagnose(tmp_path / f"{unit}_sim.csv", tmp_path / f"{unit}_rec.csv")
        assert res.names == base.names
        for a, b in zip(res.effects, base.effects):
            for k, v in b.params.items():
                assert abs(a.params[k] - v) <= 1e-6 * max(abs(v), 1e-9), (unit, k)
    # without a unit such a count is refused, and the message says what to write
    import pytest
    from mtcomp._io import InputError
    for name in ("sim.csv", "rec.csv"):
        text = (tmp_path / f"ms_{name}").read_text().replace("t[ms]", "timestamp", 1)
        (tmp_path / f"nu_{name}").write_text(text)
    with pytest.raises(InputError, match=r"timestamp\[ms\]"):
        diagnose(tmp_path / "nu_sim.csv", tmp_path / "nu_rec.csv")


def test_every_command_actual_pair_at_once():
    # what a new user does with the source file: every Command* column in SIM, every Actual*
    # column (and some drive signals) in REC, the source's names without units: 12 outputs
    # (positions, velocities, accelerations of X, Y, Z and the spindle S1). Before, nothing was
    # named: the spindle's mismatch (58x its noise, outside the library) filled every trial of
    # the first step, and the commanded accelerations, now outputs themselves, were not offered
    # to the velocities' lags
    d = DATA / "exp06_all_columns"
    res = diagnose(d / "sim.csv", d / "rec.csv")
    assert len(res.outputs) == 12
    lags = {e.outputs[0]: e for e in res.effects if e.name == "servo_lag"}
    assert {"Y1_ActualVelocity", "Z1_ActualVelocity"} <= set(lags), res.summary()
    for o, e in lags.items():
        if o.endswith("Velocity"):
            assert 0.003 < e.params["tau_s"] < 0.015, (o, e.params)
            assert _ratio(res, o) < 0.85
    assert "explained by noise" not in res.summary()
