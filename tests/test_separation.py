"""covert_env.geometry.separation: eq. 2 (the one function that measures it) and the team's priority negotiation."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from covert_env.geometry.separation import nearest_teammate, priority_negotiation, separation, team_separation


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


def _negotiate(stuck_by_order, b, u):
    """Run priority_negotiation with a settle that leaves ``stuck_by_order(copy, order)`` stuck (None: clean); returns
    the orders tried per copy and the function's answer."""
    tried = [[] for _ in range(b)]

    def settle(order, rows):
        out = np.full(b, u)
        for c in np.flatnonzero(rows):
            tried[c].append(tuple(order[c].tolist()))
            s = stuck_by_order(c, tuple(order[c].tolist()))
            out[c] = u if s is None else order[c].tolist().index(s)
        return out

    return tried, priority_negotiation(settle, b, u)


def test_negotiation_promotes_a_stuck_uav_to_the_front():
    # Copy 0 settles at once; copy 1 needs uav_2 first; copy 2 then uav_1 (the others keep their order).
    rules = [lambda o: None, lambda o: None if o[0] == 2 else 2,
             lambda o: None if o[0] == 1 else (2 if o[0] != 2 else 1)]
    tried, failed = _negotiate(lambda c, o: rules[c](o), 3, 3)
    assert tried == [[(0, 1, 2)], [(0, 1, 2), (2, 0, 1)], [(0, 1, 2), (2, 0, 1), (1, 2, 0)]]
    assert not failed.any()


def test_negotiation_tries_at_most_u_orders_and_each_uav_first_once():
    # Never clean: the last UAV of every order is stuck.
    for u in (1, 2, 3, 5, 8):
        tried, failed = _negotiate(lambda c, o: o[-1] if len(o) > 1 else None, 1, u)
        assert len(tried[0]) <= u and len(set(tried[0])) == len(tried[0])
        assert failed[0] == (u > 1)
    # A UAV stuck again after its promotion ends the negotiation (another order cannot give it more room).
    tried, failed = _negotiate(lambda c, o: 3, 1, 5)
    assert tried[0] == [(0, 1, 2, 3, 4), (3, 0, 1, 2, 4)] and failed[0]


def _greedy_one_by_one(points, order, min_dist, k):
    """The start picker's rule written out: each candidate in turn, taken if no earlier pick is closer than
    min_dist (eq. 2's distance, math.hypot per pair), until k are taken."""
    picked = []
    for i in order:
        if len(picked) == k:
            break
        if all(math.hypot(points[i][0] - points[j][0], points[i][1] - points[j][1]) >= min_dist for j in picked):
            picked.append(int(i))
    return picked


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 31 - 1), b=st.integers(1, 5), n=st.integers(0, 30), k=st.integers(1, 6),
       min_dist=st.sampled_from([0.0, 1.0, 2.5, 5.0]))
def test_spread_picks_are_each_lists_greedy_picks(seed, b, n, k, min_dist):
    """spread_picks (every copy's start picks at once) gives each list the picks of the one-by-one rule, on points
    with duplicates and exact distances (a 1 m grid), lists of different lengths included; spread_nodes is one list."""
    from covert_env.geometry.zone import spread_nodes, spread_picks

    rng = np.random.default_rng(seed)
    points = rng.integers(0, 6, (b, max(n, 1), 2)).astype(float)
    lens = rng.integers(0, n + 1, b)
    m = max(int(lens.max(initial=0)), 1)
    order = np.stack([rng.permutation(max(n, 1))[:m] if n >= m else np.zeros(m, int) for _ in range(b)])
    valid = np.arange(m) < lens[:, None]
    got = spread_picks(points, order, valid, min_dist, k)
    assert got.shape == (b, k)
    for i in range(b):
        want = _greedy_one_by_one(points[i].tolist(), order[i, :lens[i]], min_dist, k)
        assert got[i].tolist() == want + [-1] * (k - len(want))
        assert spread_nodes(points[i], order[i, :lens[i]], min_dist, k).tolist() == want
