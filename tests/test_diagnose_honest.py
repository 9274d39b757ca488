"""Selection judged on held-out data it never saw: neutral starts per fold, the final gate
(held-out gain >= 5 % on the effect's outputs, no parameter at a bound), and null cases."""
import numpy as np
import pytest

from mtcomp.diagnose import diagnose, synth
from mtcomp.diagnose.effects import Context, candidates
from mtcomp.diagnose.select import at_bound, heldout_neutral


def test_coarse_kinked_sim_names_nothing():
    # before: a quadrant_glitch (stick-slip form) named on x with its time constant pinned at
    # the lower bound: the corners of a piecewise-linear path fall between SIM's 10 Hz samples
    case = synth.null_case("coarse_kinked", 9)
    res = diagnose(case.sim, case.rec)
    assert res.names == [], res.summary()


@pytest.mark.parametrize("kind", ["white", "random_walk", "separate_clocks"])
def test_null_cases_name_no_physics(kind):
    case = synth.null_case(kind, 1, duration=15.0)
    res = diagnose(case.sim, case.rec)
    assert [n for n in res.names if n != "time_offset"] == [], res.summary()


def test_at_bound_names_the_parameter():
    case = synth.make_case(["backlash"], seed=3, duration=10.0)
    from mtcomp.diagnose import align as _align, data as _data
    S, R = _data.load(case.sim, "SIM"), _data.load(case.rec, "REC")
    al = _align.align(S, R)
    ctx = Context(al, al.rows(4))
    qg = [c for c in candidates(al) if c.name == "quadrant_glitch"][0]
    lo, hi = qg.bounds(ctx)
    assert "lower bound" in at_bound(ctx, qg, np.array(lo))
    assert "upper bound" in at_bound(ctx, qg, np.array(hi))
    assert at_bound(ctx, qg, 0.5 * (np.array(lo) + np.array(hi))) is None


def test_heldout_refits_from_neutral_starts():
    # the held-out prediction of a lag is made by fold fits that start from the candidate's own
    # grid: a start far off (the old per-fold refit began at the all-data optimum) changes nothing
    case = synth.make_case([("servo_lag", {"kv_per_s": 40.0})], seed=2, duration=12.0,
                           sim_rate=100.0, rec_rate=250.0)
    from mtcomp.diagnose import align as _align, data as _data
    al = _align.align(_data.load(case.sim, "SIM"), _data.load(case.rec, "REC"))
    ctx = Context(al, al.rows(2))
    lag = [c for c in candidates(al) if c.name == "servo_lag" and c.outputs == ("y",)][0]
    fits = []
    oof = heldout_neutral(ctx, [lag], 5, fits=fits)
    assert len(fits) == 5
    taus = [float(np.exp(-f.etas[0][0])) for f in fits]  # eta: log kv
    sl = ctx.slices["y"]
    assert float(oof[sl] @ oof[sl]) < 0.05 * float(ctx.z0[sl] @ ctx.z0[sl])
    # every fold finds the same lag (1/kv = 25 ms) on its own
    assert np.ptp(taus) < 0.05 * np.mean(taus)
    assert np.mean(taus) == pytest.approx(0.025, rel=0.03)


def test_gate_drops_pinned_and_useless_effects_keeps_the_real_one():
    from mtcomp.diagnose.select import Settings, fit, honest_gate
    case = synth.make_case([("backlash", {"backlash_mm": 4e-3})], seed=4, duration=12.0,
                           sim_rate=100.0, rec_rate=250.0, n_temps=1, n_junk=0)
    from mtcomp.diagnose import align as _align, data as _data
    al = _align.align(_data.load(case.sim, "SIM"), _data.load(case.rec, "REC"))
    ctx = Context(al, al.rows(2))
    cands = candidates(al)
    bl = [c for c in cands if c.name == "backlash" and c.outputs == ("x",)][0]
    qg = [c for c in cands if c.name == "quadrant_glitch" and c.outputs == ("z",)][0]
    sc = [c for c in cands if c.name == "scale_error" and c.outputs == ("y",)][0]
    lo, _ = qg.bounds(ctx)
    model = [bl, qg, sc]
    etas = [bl.coarse(ctx, ctx.z0, np.ones(ctx.N, bool)), np.array(lo), np.zeros(0)]
    final = fit(ctx, model, etas, max_nfev=0)
    log, ev = [], {}
    kept, f = honest_gate(ctx, cands, model, final, Settings(), ev, log)
    assert [c.label for c in kept] == [bl.label], log
    assert any(qg.label in line and "bound" in line for line in log), log
    assert any(sc.label in line and "held-out error" in line for line in log), log
