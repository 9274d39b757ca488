"""A reversal error that leads the command (negative backlash: the control over-compensates the
play) is named as backlash with a negative width, not left as an unexplained mismatch."""
import numpy as np
import pytest

from mtcomp.diagnose import diagnose, synth


def _play_error(p, b):
    """Error y - p of a play of width b > 0, one sample after the other (independent of the
    library's vectorised form); the play starts taken up in the first motion's direction."""
    h = 0.5 * b
    d0 = np.sign(p[np.flatnonzero(np.diff(p))[0] + 1] - p[0])
    y = p[0] - d0 * h
    out = np.empty_like(p)
    for k, pk in enumerate(p):
        y = min(max(y, pk - h), pk + h)
        out[k] = y - pk
    return out


@pytest.mark.parametrize("reversal", [-0.004, 0.004])
def test_reversal_error_of_either_sign_is_recovered_and_named(reversal):
    case = synth.make_case([], seed=21, duration=20.0, sim_rate=500, rec_rate=500, rec_start=0.0)
    rec = dict(case.rec)
    p = np.interp(rec["t"], case.sim["t"], case.sim["x"])
    # over-compensated: the mirror image of the play, leading the command by |B|/2
    rec["x"] = rec["x"] + np.sign(reversal) * _play_error(p, abs(reversal))
    res = diagnose(case.sim, rec)
    assert res.names == ["backlash"], res.summary()
    e = res.effects[0]
    assert abs(e.params["backlash_mm"] - reversal) < 3 * e.uncertainty["backlash_mm"]
    assert not res.unexplained
    text = res.summary()
    if reversal < 0:
        assert "over-compensates" in e.evidence["meaning"]
        assert "negative backlash" in text and "reversal value B negative" in text
    else:
        assert "meaning" not in e.evidence
