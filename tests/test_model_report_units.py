"""Units in the re-simulation report: a rotary axis' velocity is in deg/s, never µm/s."""
from mtcomp.model.simulate import _velocity_formatter


def test_rotary_velocity_is_reported_in_deg_per_s():
    assert _velocity_formatter("vC")(0.0123) == "12.3 mdeg/s"
    assert _velocity_formatter("vB")(2.5) == "2.5 deg/s"


def test_linear_velocity_is_reported_in_mm_per_s():
    assert _velocity_formatter("vX")(0.0123) == "12.3 µm/s"
    assert _velocity_formatter("vz")(2.5) == "2.5 mm/s"
