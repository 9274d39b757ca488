"""The kernel's own elementary functions of the closed forms (fmu/c/mtk.c) against libm over their
whole domain: small_atan2, the series that takes the small turns from the reference angle."""
import ctypes
import math

import numpy as np
import pytest

from mtcomp import _kernel

pytestmark = pytest.mark.skipif(not _kernel.available(), reason="no C compiler: the numpy reference runs alone")

SMALL_ATAN_MAX = 0.18   # |y / x| up to which the series applies (fmu/c/mtk.c)


def _small_atan2():
    f = _kernel.load().mtk_small_atan2
    f.restype = ctypes.c_double
    f.argtypes = [ctypes.c_double, ctypes.c_double]
    return f


def _ulps(a, b):
    """|a - b| in units of the last place of b (the reference)."""
    return abs(a - b) / math.ulp(b) if b != 0.0 else (0.0 if a == b else math.inf)


def test_small_atan2_is_within_one_ulp_of_atan2_over_its_domain():
    """|y / x| <= 0.18 with x > 0 (turns up to 10.2 deg, above the closed form's 10 deg): within
    one ulp of libm's atan2, at the domain's ends, around the switch of series length (t^2 =
    1e-4), for the usual turns (about 0.1 deg) and down to subnormal y."""
    f = _small_atan2()
    rng = np.random.default_rng(16)
    t = np.concatenate([
        rng.uniform(-SMALL_ATAN_MAX, SMALL_ATAN_MAX, 40000),
        rng.uniform(-0.01, 0.01, 20000),
        10.0 ** rng.uniform(-320, -0.75, 20000) * rng.choice([-1.0, 1.0], 20000),
        [SMALL_ATAN_MAX, -SMALL_ATAN_MAX, np.nextafter(SMALL_ATAN_MAX, 0), 0.01, -0.01,
         np.nextafter(0.01, 1), np.nextafter(0.01, 0), 1e-150, 5e-324, -5e-324],
    ])
    x = 10.0 ** rng.uniform(-3, 3, t.size)
    x[-10:] = 1.0
    worst = 0.0
    for ti, xi in zip(t, x):
        y = float(ti * xi)
        worst = max(worst, _ulps(f(y, float(xi)), math.atan2(y, float(xi))))
    assert worst <= 1.0


def test_small_atan2_keeps_zero_and_hands_the_rest_to_atan2():
    """y = 0 gives exactly 0 of y's sign; outside the domain (x <= 0, |y / x| > 0.18, NaN, inf)
    the result is libm's atan2 to the bit."""
    f = _small_atan2()
    for x in (1e-300, 1.0, 7.5, 1e300, math.inf):
        assert f(0.0, x) == 0.0 and math.copysign(1.0, f(0.0, x)) == 1.0
        assert f(-0.0, x) == 0.0 and math.copysign(1.0, f(-0.0, x)) == -1.0
    cases = [(1.0, -1.0), (0.0, -1.0), (-0.0, -1.0), (0.5, 1.0), (-0.19, 1.0), (1.0, 0.0), (-1.0, 0.0),
             (3.0, 1e-300), (1.0, math.inf), (math.inf, 1.0), (math.inf, math.inf), (1.0, -math.inf)]
    for y, x in cases:
        assert f(y, x) == math.atan2(y, x) and math.copysign(1.0, f(y, x)) == math.copysign(1.0, math.atan2(y, x))
    assert math.isnan(f(math.nan, 1.0)) and math.isnan(f(1.0, math.nan))
