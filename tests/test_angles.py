"""covert_env.geometry.angles: the intervals (-pi, pi] and [0, 2 pi), their ends, arrays and float32."""

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from covert_env.geometry.angles import TWO_PI, abs_wrapped, wrap_angle, wrap_heading


def test_wrap_angle_keeps_pi_and_moves_minus_pi():
    # (-pi, pi]: +pi stays, -pi (outside) becomes +pi, as does every odd multiple of pi.
    assert wrap_angle(math.pi) == math.pi
    assert wrap_angle(-math.pi) == math.pi
    np.testing.assert_array_equal(wrap_angle(np.array([3 * math.pi, -3 * math.pi])), [math.pi, math.pi])
    assert wrap_angle(np.float32(-np.pi)) == np.float32(np.pi)


@given(st.floats(-50, 50, allow_nan=False))
def test_wrap_heading_range_and_congruence(a):
    w = wrap_heading(a)
    assert 0.0 <= w < TWO_PI
    assert abs(math.remainder(w - a, TWO_PI)) < 1e-9


def test_wrap_heading_folds_what_rounds_to_two_pi():
    # np.mod(-1e-18, 2 pi) is exactly 2 pi: outside [0, 2 pi).
    assert np.mod(-1e-18, TWO_PI) == TWO_PI
    assert wrap_heading(-1e-18) == 0.0
    np.testing.assert_array_equal(wrap_heading(np.array([-1e-18, TWO_PI, -TWO_PI, 7.0])), [0.0, 0.0, 0.0, 7.0 - TWO_PI])


def test_dtypes_are_kept():
    a32 = np.linspace(-9, 9, 50, dtype=np.float32)
    assert wrap_angle(a32).dtype == wrap_heading(a32).dtype == abs_wrapped(a32).dtype == np.float32
    assert wrap_angle(np.arange(5)).dtype == np.float64
    assert isinstance(wrap_angle(1), float) and isinstance(wrap_heading(-1), float)


def test_abs_wrapped_is_the_size_of_the_wrapped_difference():
    rng = np.random.default_rng(0)
    a, b = rng.uniform(-np.pi, np.pi, 2000), rng.uniform(-np.pi, np.pi, 2000)
    a[:3], b[:3] = [math.pi, 0.5, -1.0], [-math.pi + 1e-12, 0.5, 2.0]
    d = a - b
    np.testing.assert_allclose(abs_wrapped(d), np.abs(wrap_angle(d)), rtol=0, atol=1e-15)
    small = np.abs(d) <= math.pi
    assert np.array_equal(abs_wrapped(d)[small], np.abs(d)[small])        # exact where no wrap is needed
    out = d.astype(np.float32)
    assert abs_wrapped(out, out=out) is out and (out >= 0).all() and (out <= np.float32(np.pi)).all()
