"""Honest shapes: a reversal error is called a backlash only with the shape of a play; local
mismatch is flagged even when the whole record is within 3x the floor."""
import numpy as np

from mtcomp.diagnose import diagnose, synth
from mtcomp.diagnose.effects import direction_of_motion

SHORT = dict(duration=30.0, sim_rate=200.0, rec_rate=500.0, n_temps=1, n_junk=0)


def _gradual_loop(x, h, s0):
    """A hysteresis loop that turns over s0 mm of travel after each reversal (not a play)."""
    d = direction_of_motion(x)
    ch = np.flatnonzero(d[1:] != d[:-1]) + 1
    k = np.searchsorted(ch, np.arange(len(x)), side="right") - 1
    p_rev = np.where(k >= 0, x[ch[np.clip(k, 0, None)] - 1], x[0] - 100.0 * d[0])
    s = np.abs(x - p_rev)
    return h * d * (1.0 - 2.0 * np.exp(-s / s0))


def test_gradual_hysteresis_not_passed_off_as_backlash():
    # before: named "backlash" (+ a quadrant glitch) with nothing said of the loop's shape
    case = synth.make_case([], seed=6, **SHORT)
    rec = dict(case.rec)
    rec["x"] = rec["x"] + _gradual_loop(case.rec["x"], 4e-3, 3.0)
    res = diagnose(case.sim, rec)
    said = [n for n in res.notes if n.startswith("x: the reversal error is not the step of a play")]
    named = [e for e in res.effects if e.name == "backlash"]
    assert said or not named, res.summary()
    assert said or res.unexplained or res.local, res.summary()


def test_play_keeps_its_name_without_a_shape_note():
    case = synth.make_case([("backlash", {"backlash_mm": 4e-3})], seed=6, **SHORT)
    res = diagnose(case.sim, case.rec)
    assert res.names == ["backlash"], res.summary()
    assert res.effects[0].evidence["loop_shape"]["play"] is True
    assert not [n for n in res.notes if "not the step of a play" in n]


def test_local_stick_slip_flagged():
    # a 3 µm stick-slip at the reversals of x only: small over the whole record
    case = synth.make_case([], seed=7, **SHORT)
    x = case.rec["x"]
    d = direction_of_motion(x)
    ch = np.flatnonzero(d[1:] != d[:-1]) + 1
    bump = np.zeros_like(x)
    for c in ch:
        n = min(40, len(x) - c)
        bump[c:c + n] += 3e-3 * np.sin(np.linspace(0, 6 * np.pi, n)) * d[c]
    rec = dict(case.rec, x=x + bump)
    res = diagnose(case.sim, rec)
    flagged = [d for d in res.local if d["output"] == "x"] + [u for u in res.unexplained
                                                             if u["output"] == "x"]
    assert flagged or "x" in {o for e in res.effects for o in e.outputs}, res.summary()
