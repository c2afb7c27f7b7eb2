"""Cost and disguise (eqs. 11-18), with angle wrapping near alpha = +-pi."""

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from covert_env.geometry.angles import wrap_angle
from covert_env.geometry.cost import disguise, stage_cost, uav_target_angle, uav_target_distance

angles = st.floats(-50, 50, allow_nan=False)


@given(angles)
def test_wrap_range_and_congruence(a):
    w = wrap_angle(a)
    assert -math.pi < w <= math.pi
    assert abs(math.remainder(w - a, 2 * math.pi)) < 1e-9


def test_alpha_behind_target_is_near_pi():
    # Target at the origin heading +x; UAV straight behind.
    assert abs(abs(uav_target_angle([-60.0, 0.0], [0.0, 0.0], 0.0)) - math.pi) < 1e-12
    assert uav_target_angle([0.0, 10.0], [0.0, 0.0], 0.0) == math.pi / 2


@given(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(-math.pi, math.pi))
def test_crossing_straight_behind_gives_small_dalpha(y0, y1, phi):
    # A UAV 70 m behind the target moves 2 m sideways across the line straight behind it: alpha jumps
    # from ~+pi to ~-pi, yet the wrapped change is tiny (|dy| / 70 rad), not ~2 pi.
    rot = np.array([[math.cos(phi), -math.sin(phi)], [math.sin(phi), math.cos(phi)]])
    p0, p1 = rot @ [-70.0, y0], rot @ [-70.0, y1]
    a0, a1 = uav_target_angle(p0, [0, 0], phi), uav_target_angle(p1, [0, 0], phi)
    k = disguise(a0, a1, 70.0, 70.0, eta=55.0)
    assert abs(wrap_angle(a1 - a0)) <= abs(y1 - y0) / 69.0 + 1e-12
    assert k <= 55.0 * abs(y1 - y0) / 69.0 + 1e-9


def test_stage_cost_values():
    # Path 30 m, alpha changes by 0.1 rad (across the +-pi cut), distance by 4 m.
    a0, a1 = math.pi - 0.05, -math.pi + 0.05
    g = stage_cost(30.0, a0, a1, 70.0, 66.0, eta=55.0, lam=10.0)
    assert np.isclose(g, 30.0 - 10 * 55 * 0.1 - 10 * 4.0)
    assert np.isclose(disguise(a0, a1, 70.0, 66.0, 55.0), 55 * 0.1 + 4.0)
    assert np.isclose(uav_target_distance([3.0, 4.0], [0.0, 0.0]), 5.0)


def test_broadcasting():
    xy = np.random.default_rng(0).normal(size=(7, 3, 2)) * 50
    a = uav_target_angle(xy, np.zeros(2), 0.3)
    assert a.shape == (7, 3) and np.all(np.abs(a) <= math.pi)
