"""covert_env.geometry.ties: argmin and argmax whose choice does not hinge on the last bit
(docs/decisions/flight.md#settled-slot-end-poses)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from covert_env.geometry.ties import TIE_RTOL_FLOAT32, TIE_RTOL_FLOAT64, first_argmax, first_argmin, tie_tolerance

values = st.lists(st.floats(-1e6, 1e6, allow_nan=False), min_size=1, max_size=40)


@given(values, st.integers(0, 2 ** 32 - 1))
@settings(max_examples=300, deadline=None)
def test_equal_values_computed_with_last_bit_noise_pick_the_first_of_them(vals, seed):
    """Values equal on paper, then perturbed by a few ulp each (as another CPU's rounding would): the choice is the
    first index of the minimum of the exact values, whatever the noise."""
    v = np.array(vals)
    gap = np.abs(v[:, None] - v[None])
    assume(((gap == 0) | (gap > 2 * tie_tolerance(np.maximum(np.abs(v[:, None]), np.abs(v[None])), v.dtype))).all())
    rng = np.random.default_rng(seed)
    clean = np.array(vals * 2)                                   # every value twice: exact ties everywhere
    noisy = clean + rng.integers(-4, 5, clean.shape) * np.spacing(np.abs(clean))
    want = int(np.flatnonzero(clean == clean.min())[0])
    assert first_argmin(noisy) == want
    assert first_argmax(-noisy) == want


@given(values)
@settings(max_examples=300, deadline=None)
def test_values_apart_by_more_than_the_tolerance_give_numpys_choice(vals):
    v = np.array(vals)
    apart = np.abs(v[:, None] - v[None]) > 2 * tie_tolerance(np.maximum(np.abs(v[:, None]), np.abs(v[None])),
                                                                     v.dtype)
    if not (apart | np.eye(len(v), dtype=bool)).all():
        return
    assert first_argmin(v) == int(np.argmin(v)) and first_argmax(v) == int(np.argmax(v))


def test_the_tolerance_is_relative_with_an_absolute_floor_and_per_dtype():
    assert tie_tolerance(0.0, np.float64) == TIE_RTOL_FLOAT64
    assert tie_tolerance(-250.0, np.float64) == pytest.approx(250 * TIE_RTOL_FLOAT64)
    assert tie_tolerance(10.0, np.float32) == pytest.approx(10 * TIE_RTOL_FLOAT32)
    assert first_argmin([1.0 + 1e-12, 1.0]) == 0 and first_argmin([1.0 + 1e-6, 1.0]) == 1
    assert first_argmax(np.array([1, 5, 5.00001], np.float32)) == 1
    assert first_argmax(np.array([1, 5, 5.001], np.float32)) == 2


def test_masked_and_nan_entries_and_axes():
    inf, nan = np.inf, np.nan
    assert first_argmin([inf, inf]) == 0 == int(np.argmin([inf, inf]))         # all masked: as numpy
    assert first_argmin([1.0, -inf, -inf]) == 1
    assert first_argmax([-inf, 2.0, -inf]) == 1
    assert first_argmin([nan, 2.0, 1.0]) == 2                                    # NaN never wins ...
    assert first_argmin([nan, nan]) == 0                                         # ... unless all are NaN
    a = np.array([[1.0, 2.0, 1.0], [3.0, 0.0, 0.0]])
    assert first_argmin(a, axis=1).tolist() == [0, 1] and first_argmin(a, axis=0).tolist() == [0, 1, 1]
    assert first_argmin(a) == 4 and isinstance(first_argmin(a), int)
    assert first_argmax(np.where([[True, False, True]], a[:1], -inf), axis=-1).tolist() == [0]
