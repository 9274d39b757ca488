"""A servo lag is a position loop's: a fitted time constant of seconds is not one (UMich run 06,
every command/actual pair at once, named a 1.7 s "servo lag" on X's measured acceleration)."""
from pathlib import Path

from mtcomp.diagnose import diagnose
from mtcomp.diagnose.effects.dynamic import KV_MIN

LOG = Path(__file__).parent / "data" / "umich" / "exp06_cmdact" / "experiment_06_command_actual.csv"


def test_no_servo_lag_of_seconds_with_every_pair_at_once():
    res = diagnose(LOG, LOG, dt=0.1)
    lags = {e.outputs[0]: e.params["tau_s"] for e in res.effects if e.name == "servo_lag"}
    # the drives' lags on the three velocities, 5-9 ms as with the velocity pairs alone
    for o in ("X1_ActualVelocity", "Y1_ActualVelocity", "Z1_ActualVelocity"):
        assert 0.004 < lags.get(o, 0.0) < 0.010, (o, lags)
    assert all(tau <= 1.0 / KV_MIN for tau in lags.values()), lags
