"""covert_env.separation: eq. 2, the one function that measures it."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from covert_env.separation import nearest_teammate, separation, team_separation


def _closest(a, b):
    """The closest approach of two sampled paths (P, 2), one instant at a time."""
    return min(float(np.hypot(*(a[t] - b[t]))) for t in range(len(a)))


def test_separation_is_the_closest_approach_at_common_instants():
    rng = np.random.default_rng(0)
    a, b = rng.uniform(-20, 20, (6, 11, 2)), rng.uniform(-20, 20, (4, 11, 2))
    got = separation(a[:, None], b[None])                                    # every pair at once: (6, 4)
    want = [[_closest(a[i], b[j]) for j in range(4)] for i in range(6)]
    np.testing.assert_array_equal(got, want)
    # Same instants only: two paths crossing the same point at different times are apart.
    line = np.linspace([0.0, 0.0], [10.0, 0.0], 11)
    assert separation(line, line[::-1]) == 0.0 and separation(line, line[::-1] + [0.0, 3.0]) == 3.0
    assert separation(line[:5], line[6:]) == pytest.approx(6.0)
    assert np.isnan(separation(line, np.full((11, 2), np.nan)))             # no path: compares False


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 31 - 1), u=st.integers(1, 6), p=st.integers(1, 7))
def test_team_separation_is_each_uavs_nearest_teammate(seed, u, p):
    paths = np.random.default_rng(seed).uniform(-30, 30, (3, u, p, 2))
    got = team_separation(paths)
    assert got.shape == (3, u)
    for b, i in itertools.product(range(3), range(u)):
        want = min((_closest(paths[b, i], paths[b, j]) for j in range(u) if j != i), default=np.inf)
        assert got[b, i] == want
    np.testing.assert_array_equal(nearest_teammate(paths[..., 0, :]), team_separation(paths[..., :1, :]))
