"""covert_env.geometry.flight computes the reference numbers bit for bit: waypoint controls, the best-effort fallback
(against the plain 17 x 17 grid search below), the turn-then-straight path and the held-control arc (against two
``unicycle_step`` arcs per sample, below), while computing each sine and cosine once per distinct value."""

from __future__ import annotations

import numpy as np
import pytest

from covert_env.geometry import flight
from covert_env.geometry.dynamics import solve_manoeuvre, unicycle_step
from covert_env.world.config import Config

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


def _reference_fly(xy, theta, v, w, t_turn, t):
    """The plain integration: turn (v, w) for t_turn then straight (v, 0) from poses (..., U): path samples at the
    times ``t`` (P,) as (..., U, P, 2), and the end heading (..., U)."""
    t = t.reshape((-1,) + (1,) * theta.ndim)                          # (P, 1, ...)
    if t_turn is None or (t_turn >= t[-1]).all():                     # one constant control: one arc
        x2, y2, th2 = unicycle_step(xy[..., 0], xy[..., 1], theta, v, w, t)
    else:
        t1 = np.minimum(t, t_turn)
        t2 = np.maximum(t - t_turn, 0.0)
        x1, y1, th1 = unicycle_step(xy[..., 0], xy[..., 1], theta, v, w, t1)
        x2, y2, th2 = unicycle_step(x1, y1, th1, v, 0.0, t2)
    path = np.empty(x2.shape[1:] + x2.shape[:1] + (2,))               # (..., U, P, 2)
    path[..., 0] = np.moveaxis(x2, 0, -1)
    path[..., 1] = np.moveaxis(y2, 0, -1)
    path[..., 0, :] = xy                                              # exact start, no round-off
    return _settled(path, th2[-1])


def _settled(path, end_heading):
    """The end pose on the grids of docs/decisions/flight.md#settled-slot-end-poses, written out independently."""
    path = path.copy()
    path[..., -1, :] = np.rint(path[..., -1, :] * 2.0 ** 20) / 2.0 ** 20
    end = np.rint(np.mod(np.asarray(end_heading), 2 * np.pi) * 2.0 ** 24) / 2.0 ** 24
    return path, np.where(end >= 2 * np.pi, 0.0, end)


def _reference_fallback(xy, theta, goals, c):
    """The plain grid search: every (v, omega) of a 17 x 17 grid flown by unicycle_step, refined twice."""
    x0, y0, th0 = xy[:, 0, None], xy[:, 1, None], theta[:, None]
    lo_v, hi_v = np.full(len(goals), 0.01 * c.v_max), np.full(len(goals), c.v_max)
    lo_w, hi_w = np.full(len(goals), -c.w_max), np.full(len(goals), c.w_max)
    f = np.linspace(0.0, 1.0, 17)
    for _ in range(3):
        gv = (lo_v[:, None] + (hi_v - lo_v)[:, None] * f)[:, :, None] * np.ones(17)
        gw = (lo_w[:, None] + (hi_w - lo_w)[:, None] * f)[:, None, :] * np.ones((17, 1))
        gv, gw = gv.reshape(len(goals), -1), gw.reshape(len(goals), -1)
        x, y, _ = unicycle_step(x0, y0, th0, gv, gw, c.delta)
        best = np.argmin((x - goals[:, :1]) ** 2 + (y - goals[:, 1:]) ** 2, axis=1)
        bv, bw = gv[np.arange(len(goals)), best], gw[np.arange(len(goals)), best]
        dv, dw = (hi_v - lo_v) / 16, (hi_w - lo_w) / 16
        lo_v, hi_v = np.maximum(bv - dv, 0.01 * c.v_max), np.minimum(bv + dv, c.v_max)
        lo_w, hi_w = np.maximum(bw - dw, -c.w_max), np.minimum(bw + dw, c.w_max)
    return bv, bw


def _reference_controls(xy, theta, goals, c):
    m = solve_manoeuvre(xy, theta, goals, v_max=c.v_max, w_max=c.w_max, delta=c.delta)
    feasible = np.asarray(m.feasible, bool).reshape(-1)
    v = np.where(feasible, np.nan_to_num(m.v), 0.0)
    w = np.where(feasible, np.nan_to_num(m.omega), 0.0)
    t_turn = np.where(feasible, np.nan_to_num(m.turn_time), 0.0)
    bad = ~feasible
    if bad.any():
        v[bad], w[bad] = _reference_fallback(xy[bad], theta[bad], goals[bad], c)
        t_turn[bad] = c.delta
    return v, w, t_turn, bad


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("c", CONFIGS)
def test_waypoint_controls_and_flight_equal_the_engine(seed, c):
    rng = np.random.default_rng(seed)
    xy, theta, goals = _poses_and_goals(rng, 200, 3, c)
    got = flight.waypoint_controls(xy.reshape(-1, 2), theta.reshape(-1), goals.reshape(-1, 2), c)
    want = _reference_controls(xy.reshape(-1, 2), theta.reshape(-1), goals.reshape(-1, 2), c)
    for g, w in zip(got, want, strict=True):
        assert np.array_equal(g, w)
    v, w, t_turn, bad = got
    assert 0.02 < bad.mean() < 0.9 and (w == 0).any() and ((t_turn > 0) & (t_turn < c.delta)).any()
    times = np.linspace(0.0, 1.0, 11) * c.delta
    shape = theta.shape
    path, end = flight.fly_turn_straight(xy, theta, v.reshape(shape), w.reshape(shape), t_turn.reshape(shape), times)
    ref_path, ref_end = _reference_fly(xy, theta, v.reshape(shape), w.reshape(shape), t_turn.reshape(shape), times)
    assert np.array_equal(path, ref_path) and np.array_equal(end, ref_end)
    assert ((0 <= end) & (end < 2 * np.pi)).all()
    # The path ends at the goal where it was reachable (eq. 29), within rounding and the settling grid.
    ok = ~bad.reshape(shape)
    np.testing.assert_allclose(path[..., -1, :][ok], goals[ok], atol=1e-6)


@pytest.mark.parametrize("c", CONFIGS)
def test_fallback_equals_the_engine_and_is_admissible(c):
    rng = np.random.default_rng(5)
    xy = rng.uniform(-50, 50, (300, 2))
    theta = rng.uniform(0, 2 * np.pi, 300)
    goals = xy + rng.uniform(-400, 400, (300, 2))
    bv, bw = flight.closest_constant_control(xy, theta, goals, c)
    rv, rw = _reference_fallback(xy, theta, goals, c)
    assert np.array_equal(bv, rv) and np.array_equal(bw, rw)
    assert ((0.01 * c.v_max <= bv) & (bv <= c.v_max)).all() and (np.abs(bw) <= c.w_max).all()


def test_non_finite_waypoints_are_refused():
    c = Config()
    with pytest.raises(ValueError, match="finite"):
        flight.waypoint_controls(np.zeros((1, 2)), np.zeros(1), np.array([[np.nan, 0.0]]), c)


@pytest.mark.parametrize("c", CONFIGS)
def test_fly_arc_equals_the_plain_integration(c):
    rng = np.random.default_rng(3)
    xy, theta = rng.uniform(-100, 100, (40, 3, 2)), rng.uniform(0, 2 * np.pi, (40, 3))
    v, w = rng.uniform(0.5, c.v_max, (40, 3)), rng.uniform(-c.w_max, c.w_max, (40, 3))
    w[0] = 0.0                                                              # straight flight
    times = np.linspace(0.0, 1.0, 11) * c.delta
    path, end = flight.fly_arc(xy, theta, v, w, times)
    ref_path, ref_end = _reference_fly(xy, theta, v, w, None, times)
    assert np.array_equal(path, ref_path)
    np.testing.assert_allclose(end, ref_end, atol=1e-12)


@pytest.mark.parametrize("mode", ["arc", "manoeuvre"])
def test_the_slot_end_pose_is_settled_and_absorbs_a_last_bit_difference(mode):
    """The carried pose lies on the grids, within half a step of the flown one; a start heading one ulp off, as
    another CPU's arctan2 may give, ends in the same settled pose (all but about one in 10^6)."""
    c = Config()
    rng = np.random.default_rng(11)
    xy, theta, goals = _poses_and_goals(rng, 500, 3, c)
    times = np.linspace(0.0, 1.0, 11) * c.delta

    def fly(th):
        if mode == "arc":
            v, w = np.full(th.shape, 0.7 * c.v_max), np.full(th.shape, 0.9 * c.w_max)
            return flight.fly_arc(xy, th, v, w, times)
        v, w, t_turn, _ = flight.waypoint_controls(xy.reshape(-1, 2), th.reshape(-1), goals.reshape(-1, 2), c)
        return flight.fly_turn_straight(xy, th, v.reshape(th.shape), w.reshape(th.shape), t_turn.reshape(th.shape),
                                        times)

    path, end = fly(theta)
    end_xy = path[..., -1, :]
    assert np.array_equal(end_xy, np.rint(end_xy / flight.POSITION_GRID) * flight.POSITION_GRID)
    assert np.array_equal(end, np.rint(end / flight.HEADING_GRID) * flight.HEADING_GRID)
    assert ((0 <= end) & (end < 2 * np.pi)).all()
    path2, end2 = fly(np.nextafter(theta, np.inf))
    assert not np.array_equal(path[..., 1:-1, :], path2[..., 1:-1, :])      # the unsettled samples do differ
    assert (path2[..., -1, :] == end_xy).all(axis=-1).mean() >= 0.998 and (end2 == end).mean() >= 0.998
