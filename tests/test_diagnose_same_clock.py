"""--same-clock: SIM and REC share one clock, so a common delay is a transport delay of the
machine (physics), never a clock offset."""
import pytest

from mtcomp.cli import main
from mtcomp.diagnose import diagnose, synth


def _delay_case(delay, seed=11):
    return synth.make_case([("time_offset", {"offset_s": delay})], seed=seed, duration=20.0,
                           rec_start=0.0)


@pytest.mark.parametrize("delay", [0.012, -0.006])
def test_injected_transport_delay_is_reported_as_a_delay(delay):
    case = _delay_case(delay)
    res = diagnose(case.sim, case.rec, same_clock=True)
    assert res.names == ["time_offset"], res.summary()
    e = res.effects[0]
    assert abs(e.params["offset_s"] - delay) < 3 * e.uncertainty["offset_s"]
    assert "transport delay" in e.evidence["meaning"]
    assert res.alignment["same_clock"] is True and res.alignment["clock_offset_s"] == 0.0
    text = res.summary()
    assert "transport delay" in text and "not a clock offset" in text
    assert any("share one clock" in n for n in res.notes)


def test_a_delay_above_the_clock_threshold_is_not_taken_as_a_clock_offset():
    # 0.15 s: without the option it is a difference between the clocks (aligned, no effect);
    # with it the same shift is the machine's transport delay
    case = _delay_case(0.15, seed=12)
    free = diagnose(case.sim, case.rec)
    assert abs(free.alignment["clock_offset_s"] - 0.15) < 1e-3 and free.names == []
    assert any("--same-clock" in n for n in free.notes)
    res = diagnose(case.sim, case.rec, same_clock=True)
    assert res.names == ["time_offset"], res.summary()
    e = res.effects[0]
    assert abs(e.params["offset_s"] - 0.15) < 3 * e.uncertainty["offset_s"]
    assert res.alignment["clock_offset_s"] == 0.0
    for o in res.outputs:
        assert res.fit["holdout_rms_after"][o] < 1.5 * res.noise_floor[o]


def test_cli_same_clock(tmp_path, capsys):
    case = _delay_case(0.012, seed=13)
    synth.write_csv(tmp_path / "sim.csv", case.sim)
    synth.write_csv(tmp_path / "rec.csv", case.rec)
    rc = main(["diagnose", "--sim", str(tmp_path / "sim.csv"), "--rec", str(tmp_path / "rec.csv"),
               "--same-clock"])
    out = capsys.readouterr().out
    assert rc == 0 and "time_offset" in out and "transport delay" in out
