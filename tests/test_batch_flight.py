"""The vector env's waypoint flight (covert_env.envs.batch) computes the engine's numbers bit for bit: controls,
best-effort fallback and the turn-then-straight path, while computing each sine and cosine once per distinct value."""

from __future__ import annotations

import numpy as np
import pytest

from covert_env import engine
from covert_env.config import Config
from covert_env.envs import batch

#: The paper's limits, and others whose products round (delta = 1 makes many orders of operations exact).
CONFIGS = [Config(), Config(delta=0.7, v_max=37.0, w_max=2.3)]


def _poses_and_goals(rng, b, u, c):
    xy = rng.uniform(-200, 200, (b, u, 2))
    theta = rng.uniform(0, 2 * np.pi, (b, u))
    reach = c.v_max * c.delta
    # Reachable ones, unreachable ones (too far, behind) and goals straight ahead (no turn, omega = 0).
    off = rng.uniform(-1.6 * reach, 1.6 * reach, (b, u, 2))
    ahead = rng.random((b, u)) < 0.2
    dist = rng.uniform(1, reach, (b, u))
    off[ahead] = (dist[..., None] * np.stack([np.cos(theta), np.sin(theta)], -1))[ahead]
    return xy, theta, xy + off


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("c", CONFIGS)
def test_waypoint_controls_and_flight_equal_the_engine(seed, c):
    rng = np.random.default_rng(seed)
    xy, theta, goals = _poses_and_goals(rng, 200, 3, c)
    got = batch.waypoint_controls(xy.reshape(-1, 2), theta.reshape(-1), goals.reshape(-1, 2), c)
    want = engine._waypoint_controls(xy.reshape(-1, 2), theta.reshape(-1), goals.reshape(-1, 2), c)
    for g, w in zip(got, want, strict=True):
        assert np.array_equal(g, w)
    v, w, t_turn, bad = got
    assert 0.02 < bad.mean() < 0.9 and (w == 0).any() and ((t_turn > 0) & (t_turn < c.delta)).any()
    times = np.linspace(0.0, 1.0, 11) * c.delta
    shape = theta.shape
    path, end = batch.fly_turn_straight(xy, theta, v.reshape(shape), w.reshape(shape), t_turn.reshape(shape), times)
    ref_path, ref_end = engine._fly(xy, theta, v.reshape(shape), w.reshape(shape), t_turn.reshape(shape), times)
    assert np.array_equal(path, ref_path) and np.array_equal(end, ref_end)
    assert ((0 <= end) & (end < 2 * np.pi)).all()
    # The path ends at the goal where it was reachable (eq. 29), within rounding.
    ok = ~bad.reshape(shape)
    np.testing.assert_allclose(path[..., -1, :][ok], goals[ok], atol=1e-6)


@pytest.mark.parametrize("c", CONFIGS)
def test_fallback_equals_the_engine_and_is_admissible(c):
    rng = np.random.default_rng(5)
    xy = rng.uniform(-50, 50, (300, 2))
    theta = rng.uniform(0, 2 * np.pi, 300)
    goals = xy + rng.uniform(-400, 400, (300, 2))
    bv, bw = batch.closest_constant_control(xy, theta, goals, c)
    rv, rw = engine._closest_constant_control(xy, theta, goals, c)
    assert np.array_equal(bv, rv) and np.array_equal(bw, rw)
    assert ((0.01 * c.v_max <= bv) & (bv <= c.v_max)).all() and (np.abs(bw) <= c.w_max).all()


def test_non_finite_waypoints_are_refused():
    c = Config()
    with pytest.raises(ValueError, match="finite"):
        batch.waypoint_controls(np.zeros((1, 2)), np.zeros(1), np.array([[np.nan, 0.0]]), c)
