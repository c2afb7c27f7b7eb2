"""covert_env.geometry.dynamics: exact unicycle steps and the turn-then-straight manoeuvre (eqs. 1, 7, 22-29).

The references here are independent of the module: a fine RK4 integration of eq. 1, and a literal
evaluation of the paper's tangent-point construction (eqs. 23-28) on a dense grid of speeds.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from covert_env.geometry.dynamics import (
    Manoeuvre,
    fly_manoeuvre,
    solve_manoeuvre,
    unicycle_arc,
    unicycle_path,
    unicycle_step,
)

TWO_PI = 2 * np.pi


def wrapped_diff(a, b):
    return np.abs(np.angle(np.exp(1j * (np.asarray(a) - np.asarray(b)))))


def rk4(x, y, th, v, om, dt, n):
    """Classic RK4 on eq. 1 with constant controls; vectorised over the batch."""
    s = np.stack(np.broadcast_arrays(*(np.asarray(q, float) for q in (x, y, th))), axis=0).astype(float)
    h = np.asarray(dt, float) / n

    def f(st_):
        return np.stack([v * np.cos(st_[2]), v * np.sin(st_[2]), om * np.ones_like(st_[2])])

    for _ in range(n):
        k1 = f(s)
        k2 = f(s + 0.5 * h * k1)
        k3 = f(s + 0.5 * h * k2)
        k4 = f(s + h * k3)
        s = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return s[0], s[1], s[2]


def paper_F(a, b, r, wd):
    """Eq. 29 residual r tau + |z - g| - delta W r built literally from eqs. 23-28 (left-turn frame, b >= 0).

    The centre is c = (0, r) (eq. 23); z is c + r * (c->g rotated by +-rho), rho = arccos(r / |g - c|)
    (eqs. 24-26), keeping the sign whose departure direction at z points at g (the paper's feasibility
    test); tau is the counter-clockwise angle from c->p to c->z. NaN where g is inside the circle.
    """
    ux, uy = a, b - r
    dist = np.hypot(ux, uy)
    with np.errstate(invalid="ignore"):
        rho = np.arccos(r / dist)
    best = None
    for sgn in (1.0, -1.0):
        cr, sr = np.cos(sgn * rho), np.sin(sgn * rho)
        czx, czy = r * (cr * ux - sr * uy) / dist, r * (sr * ux + cr * uy) / dist
        zx, zy = czx, r + czy
        dep = -czy * (a - zx) + czx * (b - zy)  # CCW departure direction . (g - z)
        cand = (dep, czx, czy, zx, zy)
        if best is not None:
            cand = tuple(np.where(dep > best[0], c1, c0) for c1, c0 in zip(cand, best, strict=True))
        best = cand
    _, czx, czy, zx, zy = best
    tau = np.mod(np.arctan2(czy, czx) + np.pi / 2, TWO_PI)
    f = r * tau + np.hypot(a - zx, b - zy) - wd * r
    return np.where(dist >= r, f, np.nan)


def random_goals(rng, n, radius=60.0):
    p = rng.uniform(-100, 100, (n, 2))
    th = rng.uniform(-4 * np.pi, 4 * np.pi, n)
    ang = rng.uniform(-np.pi, np.pi, n)
    rad = radius * np.sqrt(rng.uniform(0, 1, n))
    return p, th, p + np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=-1)


# ------------------------------------------------------------------------------------ unicycle


def test_unicycle_step_matches_fine_rk4():
    rng = np.random.default_rng(0)
    n = 64
    x, y = rng.uniform(-50, 50, n), rng.uniform(-50, 50, n)
    th = rng.uniform(-10, 10, n)
    v = rng.uniform(0, 50, n)
    om = rng.uniform(-3, 3, n)
    om[:4] = [0.0, 1e-12, -1e-9, 3.0]
    dt = rng.uniform(0, 2, n)
    ex, ey, eth = unicycle_step(x, y, th, v, om, dt)
    rx, ry, rth = rk4(x, y, th, v, om, dt, 10_000)
    assert np.max(np.hypot(ex - rx, ey - ry)) < 1e-6
    assert np.max(wrapped_diff(eth, rth)) < 1e-9
    assert np.all((eth >= 0) & (eth < TWO_PI))


def test_unicycle_step_beats_euler_step():
    # One Euler step (eq. 7) over a full turning slot lands far from the true arc; ours does not.
    x, y, th = unicycle_step(0.0, 0.0, 0.0, 50.0, 3.0, 1.0)
    r = 50.0 / 3.0
    assert x == pytest.approx(r * np.sin(3.0), abs=1e-12)
    assert y == pytest.approx(r * (1 - np.cos(3.0)), abs=1e-12)
    assert th == pytest.approx(3.0)
    assert np.hypot(x - 50.0, y) > 40.0  # where eq. 7 would put it


@pytest.mark.parametrize("om", [0.0, 1e-12, -1e-12, 1e-300])
def test_unicycle_step_tiny_omega_is_straight(om):
    th = 0.7
    x, y, th1 = unicycle_step(1.0, -2.0, th, 40.0, om, 1.5)
    assert x == pytest.approx(1.0 + 60.0 * np.cos(th), abs=1e-9)
    assert y == pytest.approx(-2.0 + 60.0 * np.sin(th), abs=1e-9)
    assert th1 == pytest.approx(th, abs=1e-11)


def test_unicycle_step_broadcasts_and_scalars():
    x, y, th = unicycle_step(np.zeros((3, 1)), 0.0, 0.0, np.array([1.0, 2.0, 3.0, 4.0]), 0.5, 1.0)
    assert x.shape == y.shape == th.shape == (3, 4)
    np.testing.assert_allclose(x[0], x[2])
    xs, ys, ts = unicycle_step(0.0, 0.0, -0.1, 10.0, 0.0, 1.0)
    assert np.ndim(xs) == np.ndim(ys) == np.ndim(ts) == 0
    assert ts == pytest.approx(TWO_PI - 0.1)
    # theta wraps into [0, 2 pi), also for values that round to 2 pi
    _, _, t0 = unicycle_step(0.0, 0.0, -1e-18, 1.0, 0.0, 1.0)
    assert 0.0 <= t0 < TWO_PI


def test_unicycle_step_composes():
    # Exactness means two half steps equal one full step.
    a = unicycle_step(3.0, 4.0, 1.0, 20.0, -2.0, 0.8)
    h = unicycle_step(3.0, 4.0, 1.0, 20.0, -2.0, 0.4)
    b = unicycle_step(*h, 20.0, -2.0, 0.4)
    np.testing.assert_allclose(a, b, atol=1e-12)


def test_unicycle_arc_is_the_same_per_element_whatever_the_batch():
    # Every caller of eq. 1 (engine, vector env, fallback grid, manoeuvre points) relies on this: a factor
    # computed once for a broadcast axis gives the bits the element-by-element evaluation gives.
    rng = np.random.default_rng(4)
    k, nv, nw = 6, 5, 7
    x, y, th = rng.uniform(-80, 80, (k, 1, 1)), rng.uniform(-80, 80, (k, 1, 1)), rng.uniform(0, TWO_PI, (k, 1, 1))
    v, om = rng.uniform(0.5, 50, (k, nv, 1)), rng.uniform(-3, 3, (k, 1, nw))
    om[:, :, 0] = 0.0                                                      # straight flight in the grid
    dt = 0.8
    bx, by, bth = unicycle_arc(x, y, th, v, om, dt)
    assert bx.shape == by.shape == (k, nv, nw) and bth.shape == (k, 1, nw)
    flat = np.broadcast_arrays(x, y, th, v, om)
    ex, ey, eth = (np.empty((k, nv, nw)) for _ in range(3))
    for i in np.ndindex(k, nv, nw):
        ex[i], ey[i], eth[i] = unicycle_arc(*(a[i] for a in flat), dt)
    assert np.array_equal(bx, ex) and np.array_equal(by, ey)
    assert np.array_equal(np.broadcast_to(bth, (k, nv, nw)), eth)
    np.testing.assert_array_equal(bth, th + om * dt)                       # the heading, unwrapped
    # Written into given arrays: the same bits.
    ox, oy = np.empty((k, nv, nw)), np.empty((k, nv, nw))
    rx, ry, _ = unicycle_arc(x, y, th, v, om, dt, out=(ox, oy))
    assert rx is ox and ry is oy and np.array_equal(ox, bx) and np.array_equal(oy, by)


def test_unicycle_arc_straight_leg_equals_the_general_arc():
    # omega the scalar 0 takes one sine and cosine per heading (the manoeuvre's straight leg); the result must be
    # the general formula's at omega = 0, bit for bit.
    rng = np.random.default_rng(8)
    x, y, th = rng.uniform(-80, 80, (4, 3, 1)), rng.uniform(-80, 80, (4, 3, 1)), rng.uniform(0, TWO_PI, (4, 3, 1))
    v, dt = rng.uniform(0.5, 50, (4, 3, 1)), rng.uniform(0, 1, (4, 3, 9))
    fast = unicycle_arc(x, y, th, v, 0.0, dt)
    general = unicycle_arc(x, y, th, v, np.zeros((4, 3, 9)), dt)
    for a, b in zip(fast, general, strict=True):
        assert np.array_equal(a, b)
    np.testing.assert_allclose(fast[0], x + v * dt * np.cos(th), rtol=0, atol=1e-12)


def test_unicycle_path_shape_and_geometry():
    pts = unicycle_path(np.zeros(5), 0.0, 0.0, 30.0, np.linspace(-3, 3, 5), 1.0, 11)
    assert pts.shape == (11, 5, 3)
    np.testing.assert_allclose(pts[0, :, :2], 0.0)
    end = np.stack(unicycle_step(np.zeros(5), 0.0, 0.0, 30.0, np.linspace(-3, 3, 5), 1.0), axis=-1)
    np.testing.assert_allclose(pts[-1], end)
    # omega = 3 (last): every point lies on the circle of radius v / omega about (0, v / omega)
    r = 10.0
    np.testing.assert_allclose(np.hypot(pts[:, -1, 0], pts[:, -1, 1] - r), r, atol=1e-12)
    # omega = 0 (middle): straight along +x at constant speed
    np.testing.assert_allclose(pts[:, 2, 0], np.linspace(0, 30, 11), atol=1e-12)
    np.testing.assert_allclose(pts[:, 2, 1], 0.0, atol=1e-12)
    with pytest.raises(ValueError):
        unicycle_path(0, 0, 0, 1, 0, 1, 0)


# --------------------------------------------------------------------------- manoeuvre: landing


def test_manoeuvre_flies_onto_goal():
    rng = np.random.default_rng(1)
    p, th, g = random_goals(rng, 6000)
    m = solve_manoeuvre(p, th, g)
    f = m.feasible
    assert f.sum() >= 1000
    v, om, tt = m.controls()
    assert np.all(v[f] > 0) and np.all(v[f] <= 50.0)
    assert np.all(np.abs(om[f]) <= 3.0)
    assert np.all((tt[f] >= 0) & (tt[f] <= 1.0))
    assert np.all(np.isin(m.turn[f], [-1, 0, 1]))
    np.testing.assert_array_equal(om[f], 3.0 * m.turn[f])
    np.testing.assert_allclose(m.length[f], v[f] * 1.0)
    assert np.all((m.heading_after[f] >= 0) & (m.heading_after[f] < TWO_PI))

    # Independent fine simulation of the returned controls: RK4, 1000 substeps in each phase.
    ps, ths, gs = p[f], th[f], g[f]
    x1, y1, th1 = rk4(ps[:, 0], ps[:, 1], ths, v[f], om[f], tt[f], 1000)
    x2, y2, th2 = rk4(x1, y1, th1, v[f], 0.0, 1.0 - tt[f], 1000)
    assert np.max(np.hypot(x2 - gs[:, 0], y2 - gs[:, 1])) < 0.01
    assert np.max(wrapped_diff(th2, m.heading_after[f])) < 1e-4

    end, end_th = fly_manoeuvre(p, th, m)
    assert np.max(np.abs(end[f] - g[f])) < 1e-8
    assert np.max(wrapped_diff(end_th[f], m.heading_after[f])) < 1e-10
    assert np.all(np.isnan(end[~f]))

    # The tangent point: the turn ends there and the heading then points straight at the goal.
    z = m.tangent[f]
    seg = gs - z
    long = np.hypot(seg[:, 0], seg[:, 1]) > 1e-3
    bearing = np.arctan2(seg[long, 1], seg[long, 0])
    assert np.max(wrapped_diff(bearing, m.heading_after[f][long])) < 1e-8
    zx, zy, _ = unicycle_step(ps[:, 0], ps[:, 1], ths, v[f], om[f], tt[f])
    np.testing.assert_allclose(np.stack([zx, zy], -1), z, atol=1e-9)


def test_feasible_goal_is_never_inside_its_turning_circle():
    rng = np.random.default_rng(2)
    p, th, g = random_goals(rng, 4000)
    m = solve_manoeuvre(p, th, g)
    f = m.feasible & (m.turn != 0)
    r = m.v[f] / 3.0
    nrm = np.stack([-np.sin(th[f]), np.cos(th[f])], -1) * m.turn[f][:, None]
    centre = p[f] + r[:, None] * nrm
    assert np.all(np.hypot(*(g[f] - centre).T) >= r * (1 - 1e-12))


@pytest.mark.slow
def test_feasibility_matches_brute_force_over_speeds():
    # Independent check of the classification: eq. 29 (paper-literal) on a dense grid of radii up to
    # V_max / W_max must change sign iff solve_manoeuvre reports a manoeuvre, and near the same speed.
    rng = np.random.default_rng(3)
    for w_max in (3.0, 5.0):
        n = 1500
        ang = rng.uniform(-np.pi, np.pi, n)
        rad = 55 * np.sqrt(rng.uniform(0, 1, n))
        g = np.stack([rad * np.cos(ang), rad * np.sin(ang)], -1)
        m = solve_manoeuvre([0.0, 0.0], 0.0, g, w_max=w_max)
        rs = np.linspace(1e-4, 50 / w_max, 3000)[:, None]
        F = paper_F(g[:, 0], np.abs(g[:, 1]), rs, w_max)
        change = (F[:-1] > 0) & (F[1:] <= 0)
        has = change.any(axis=0)
        np.testing.assert_array_equal(m.feasible, has)
        first = rs[np.argmax(change, axis=0), 0]
        step = rs[1, 0] - rs[0, 0]
        assert np.all(np.abs(m.v[has] / w_max - first[has]) <= 1.01 * step)


def test_two_roots_behind_returns_the_slower():
    # W_max delta > pi: a goal behind can have two solutions of eq. 29; the slower (shorter) one is chosen.
    g = np.array([-6.88013699, -4.65514131])
    m = solve_manoeuvre([0.0, 0.0], 0.0, g, w_max=5.0)
    assert m.feasible and m.turn == -1
    r = m.v / 5.0
    a, b = g[0], abs(g[1])
    r_hi = min((a * a + b * b) / (2 * b), 10.0)
    grid = np.linspace(1e-6, r_hi, 20001)
    F = paper_F(a, b, grid, 5.0)
    roots = grid[1:][(F[:-1] > 0) & (F[1:] <= 0)]
    back = grid[1:][(F[:-1] <= 0) & (F[1:] > 0)]
    assert len(roots) == 1 and len(back) == 1 and back[0] > r  # F dips below 0 and comes back
    assert r == pytest.approx(roots[0], abs=2 * (grid[1] - grid[0]))
    end, _ = fly_manoeuvre([0.0, 0.0], 0.0, m)
    np.testing.assert_allclose(end, g, atol=1e-9)


# ----------------------------------------------------------------------- manoeuvre: edge cases


def test_straight_ahead_needs_no_turn():
    m = solve_manoeuvre([1.0, 2.0], np.pi / 2, [1.0, 32.0])
    assert m.feasible and m.turn == 0 and m.omega == 0.0
    assert m.v == pytest.approx(30.0) and m.turn_time == 0.0
    assert m.heading_after == pytest.approx(np.pi / 2)
    np.testing.assert_allclose(m.points(4), [[1, 2], [1, 12], [1, 22], [1, 32]], atol=1e-12)


def test_nearly_straight_ahead_is_accurate():
    for lat in (1e-13, 1e-10, 1e-7, 1e-4):
        m = solve_manoeuvre([0.0, 0.0], 0.0, [[40.0, lat], [40.0, -lat]])
        assert m.feasible.all()
        end, th = fly_manoeuvre([0.0, 0.0], 0.0, m)
        np.testing.assert_allclose(end, [[40.0, lat], [40.0, -lat]], atol=1e-9)
        assert np.all(wrapped_diff(th, 0.0) < 1e-5)


def test_too_fast_is_infeasible():
    m = solve_manoeuvre([0.0, 0.0], 0.0, [[60.0, 0.0], [50.0, 0.0], [50.001, 0.0], [40.0, 29.0], [0.0, 60.0]])
    np.testing.assert_array_equal(m.feasible, [False, True, False, False, False])
    assert m.v[1] == pytest.approx(50.0)
    assert np.isnan(m.v[0]) and np.isnan(m.turn_time[0]) and m.turn[0] == 0
    # (40, 29) is closer than 50 m, but even at V_max the turn-then-straight path exceeds the 50 m one slot
    # allows (and for a goal ahead the residual of eq. 29 only grows as v decreases).
    assert np.hypot(40.0, 29.0) < 50.0
    assert paper_F(40.0, 29.0, 50.0 / 3.0, 3.0) > 0
    # ... whereas (45, 20), also < 50 m away, is reachable a little below V_max
    m2 = solve_manoeuvre([0.0, 0.0], 0.0, [45.0, 20.0])
    assert m2.feasible and np.hypot(45.0, 20.0) / 1.0 < m2.v < 50.0


def test_goal_beside_needs_a_half_turn():
    # (0, 1) beside the UAV lies on its turning circle only for r = 0.5 and needs a half turn (tau = pi):
    # impossible when W_max delta = 3 < pi, possible (at low speed) when W_max delta = 4.
    assert not solve_manoeuvre([0.0, 0.0], 0.0, [0.0, 1.0]).feasible
    m = solve_manoeuvre([0.0, 0.0], 0.0, [0.0, 1.0], w_max=4.0)
    assert m.feasible and m.turn == 1 and m.v <= 2.0 + 1e-12
    end, _ = fly_manoeuvre([0.0, 0.0], 0.0, m)
    np.testing.assert_allclose(end, [0.0, 1.0], atol=1e-10)


@settings(max_examples=200, deadline=None)
@given(d=st.floats(0.01, 40.0), frac=st.floats(0.0, 0.999), side=st.sampled_from([1.0, -1.0]),
       th=st.floats(0.0, TWO_PI))
def test_goal_inside_turning_circle_for_every_speed_is_infeasible(d, frac, side, th):
    # Any path to g is >= d long, so r = v / W_max >= d / (delta W_max). With W_max delta = 1.5, a goal
    # with lateral offset b > d * W_max delta / 2 lies inside the turning circle (r > d^2 / (2b)) for
    # every speed that could reach it in time: it must be infeasible.
    w_max = 1.5
    b = d * (0.75 + 0.25 * frac) + 1e-9 * d
    b = min(b, d)
    a = np.sqrt(max(d * d - b * b, 0.0))
    c, s = np.cos(th), np.sin(th)
    g = np.array([a * c - side * b * s, a * s + side * b * c])
    assert not solve_manoeuvre([0.0, 0.0], th, g, w_max=w_max).feasible


def eq22_turn(sigma, theta):
    """Eq. 22 as printed, on angles: sigma in [0, 2 pi) the bearing of p[k] -> p[k+1], theta in [0, 2 pi)."""
    x = sigma - theta                                  # in (-2 pi, 2 pi)
    if x == 0:
        return 0
    if -np.pi <= x < 0 or np.pi <= x < TWO_PI:
        return -1                                      # right
    return 1                                           # left: (-2 pi, -pi) u (0, pi)


def test_straight_behind_turns_right_as_eq_22_states():
    """sigma - theta = pi (waypoint dead behind) is in eq. 22's right set [pi, 2 pi), as is -pi in [-pi, 0)."""
    # theta = 0 is exact; for the others cos / sin of the heading round, leaving the goal a few ulps off pi.
    for theta, goal in ((0.0, [-5.0, 0.0]), (np.pi, [5.0, 0.0]), (np.pi / 2, [0.0, -5.0])):
        m = solve_manoeuvre([0.0, 0.0], theta, goal, w_max=8.0)
        assert m.feasible and m.turn == -1
        end, th_end = fly_manoeuvre([0.0, 0.0], theta, m)
        np.testing.assert_allclose(end, goal, atol=1e-10)
        # A right turn by tau ends with heading theta - tau.
        np.testing.assert_allclose(wrapped_diff(th_end, theta - m.turn_time * 8.0), 0.0, atol=1e-9)
    assert eq22_turn(np.pi, 0.0) == -1 and eq22_turn(0.0, np.pi) == -1
    # W_max delta <= pi: nothing behind the UAV is reachable in one slot
    assert not solve_manoeuvre([0.0, 0.0], 0.0, [-5.0, 0.0]).feasible


@pytest.mark.parametrize("theta", [0.0, 0.7, np.pi, 4.0])
def test_turn_side_follows_eq_22_around_dead_behind(theta):
    """Bearings pi - eps (left of the heading) turn left, pi + eps turn right, for eps from 1e-9 to 0.5, as eq.
    22 evaluated literally on sigma and theta says. (Exactly pi is only representable on the axes: see
    test_straight_behind_turns_right_as_eq_22_states.)"""
    eps = np.array([1e-9, 1e-6, 1e-3, 0.1, 0.5])
    rel = np.concatenate([np.pi - eps, np.pi + eps])
    goals = 5.0 * np.column_stack([np.cos(theta + rel), np.sin(theta + rel)])
    m = solve_manoeuvre(np.zeros(2), theta, goals, w_max=8.0)
    assert np.all(m.feasible)
    np.testing.assert_array_equal(m.turn, [1] * len(eps) + [-1] * len(eps))
    sigma = np.mod(np.arctan2(goals[:, 1], goals[:, 0]), TWO_PI)
    np.testing.assert_array_equal(m.turn, [eq22_turn(s_, theta) for s_ in sigma])
    end, _ = fly_manoeuvre(np.zeros(2), theta, m)
    np.testing.assert_allclose(end, goals, atol=1e-8)


def test_degenerate_and_nan_inputs_are_infeasible():
    m = solve_manoeuvre([[1.0, 1.0], [0.0, 0.0], [0.0, 0.0]], [0.0, np.nan, 0.0],
                        [[1.0, 1.0], [5.0, 0.0], [np.nan, 3.0]])
    np.testing.assert_array_equal(m.feasible, [False, False, False])
    for field in (m.v, m.omega, m.turn_time, m.heading_after, m.length):
        assert np.all(np.isnan(field))
    np.testing.assert_array_equal(m.turn, 0)
    assert np.all(np.isnan(m.points(5)))


def test_invalid_parameters_raise():
    for kw in ({"v_max": 0.0}, {"w_max": -1.0}, {"delta": np.inf}, {"v_max": "50"}):
        with pytest.raises(ValueError):
            solve_manoeuvre([0, 0], 0.0, [1, 0], **kw)
    with pytest.raises(ValueError):
        solve_manoeuvre([0, 0, 0], 0.0, [1, 0])


# ---------------------------------------------------------------- manoeuvre: vectorisation / symmetry


def test_vectorised_equals_scalar_calls():
    rng = np.random.default_rng(4)
    p, th, g = random_goals(rng, 300, radius=55.0)
    m = solve_manoeuvre(p, th, g)
    assert m.feasible.sum() > 30
    fields = ("v", "omega", "turn_time", "heading_after", "length")
    for k in range(len(th)):
        s = solve_manoeuvre(p[k], th[k], g[k])
        assert np.ndim(s.feasible) == 0 and isinstance(s.feasible, (bool, np.bool_))
        assert s.feasible == m.feasible[k] and s.turn == m.turn[k]
        for name in fields:
            np.testing.assert_allclose(getattr(s, name), getattr(m, name)[k], rtol=1e-12, atol=1e-12)


def test_batch_shapes_broadcast():
    nodes = np.stack(np.meshgrid(np.arange(5.0) * 8, np.arange(4.0) * 8), -1).reshape(-1, 2)
    S = len(nodes)
    m = solve_manoeuvre(nodes[:, None, :], 0.3, nodes[None, :, :])
    assert m.shape == (S, S) and m.v.shape == (S, S) and m.tangent.shape == (S, S, 2)
    assert m.points(7).shape == (S, S, 7, 2)
    flat = solve_manoeuvre(np.repeat(nodes, S, 0), 0.3, np.tile(nodes, (S, 1)))
    np.testing.assert_array_equal(m.feasible.ravel(), flat.feasible)
    np.testing.assert_allclose(m.v.ravel(), flat.v, rtol=1e-12)
    assert not m.feasible[np.arange(S), np.arange(S)].any()  # goal == start
    one = solve_manoeuvre([0.0, 0.0], np.zeros(3), [10.0, 1.0])
    assert one.shape == (3,)
    assert solve_manoeuvre([0.0, 0.0], 0.0, [10.0, 1.0]).points(9).shape == (9, 2)


@settings(max_examples=300, deadline=None)
@given(x=st.floats(-60, 60), y=st.floats(0.0, 60), th=st.floats(-10, 10), w=st.sampled_from([3.0, 5.0]))
def test_mirror_symmetry(x, y, th, w):
    c, s = np.cos(th), np.sin(th)
    left = np.array([x * c - y * s, x * s + y * c])
    right = np.array([x * c + y * s, x * s - y * c])
    ml = solve_manoeuvre([0.0, 0.0], th, left, w_max=w)
    mr = solve_manoeuvre([0.0, 0.0], th, right, w_max=w)
    assert ml.feasible == mr.feasible
    if ml.feasible:
        assert ml.v == pytest.approx(mr.v, rel=1e-9, abs=1e-12)
        assert ml.turn_time == pytest.approx(mr.turn_time, rel=1e-9, abs=1e-12)
        if y > 1e-9 * max(abs(x), 1.0):  # below that, rounding in the rotation may decide the side
            assert ml.turn == 1 and mr.turn == -1
        # headings mirror about the initial heading
        assert wrapped_diff(ml.heading_after - th, th - mr.heading_after) < 1e-8


@settings(max_examples=200, deadline=None)
@given(px=st.floats(-100, 100), py=st.floats(-100, 100), th=st.floats(-10, 10),
       gx=st.floats(-60, 60), gy=st.floats(-60, 60))
@example(px=0.0, py=0.0, th=0.0, gx=1e-300, gy=11.418439679169381)   # abeam, on the turning circle (was feasible
@example(px=0.0, py=0.0, th=0.0, gx=1e-16, gy=11.418439679169381)    # with tau = pi/2 for pi, missing by 0.8 m)
def test_any_feasible_result_lands(px, py, th, gx, gy):
    p = np.array([px, py])
    g = p + np.array([gx, gy])
    m = solve_manoeuvre(p, th, g)
    if m.feasible:
        assert 0 < m.v <= 50.0 and 0 <= m.turn_time <= 1.0
        end, eth = fly_manoeuvre(p, th, m)
        assert np.hypot(*(end - g)) < 1e-7
        pts = m.points(3)
        np.testing.assert_allclose(pts[0], p, atol=1e-9)
        np.testing.assert_allclose(pts[-1], g, atol=1e-7)
    else:
        assert np.isnan(m.v) and m.turn == 0


def test_points_follow_path_at_constant_speed():
    rng = np.random.default_rng(5)
    p, th, g = random_goals(rng, 400, radius=50.0)
    m = solve_manoeuvre(p, th, g)
    f = m.feasible
    pts = m.points(401)
    assert pts.shape == (400, 401, 2)
    np.testing.assert_allclose(pts[f, 0], p[f], atol=1e-9)
    np.testing.assert_allclose(pts[f, -1], g[f], atol=1e-7)
    steps = np.hypot(*np.diff(pts[f], axis=1).transpose(2, 0, 1))
    # constant speed: every chord is (at most) v delta / 400, and they add up to the path length
    assert np.all(steps <= m.v[f][:, None] / 400 * (1 + 1e-9))
    np.testing.assert_allclose(steps.sum(axis=1), m.length[f], rtol=1e-4)
    assert isinstance(m, Manoeuvre)


@pytest.mark.parametrize("limits", [(50.0, 3.0, 1.0), (30.0, 5.0, 1.0), (50.0, 1.0, 0.5)])
def test_manoeuvre_feasible_is_solve_manoeuvres_feasibility(limits):
    """The masks' test (a root bracket of eq. 29, no speed solved) decides every goal as solve_manoeuvre does: ahead,
    behind (two roots when W_max delta > pi), dead ahead, at the start, at the slot's reach, far away; and the
    env's controls (manoeuvre_controls) are solve_manoeuvre's."""
    from covert_env.geometry.dynamics import manoeuvre_controls, manoeuvre_feasible

    v_max, w_max, delta = limits
    rng = np.random.default_rng(21)
    n = 30_000
    reach = v_max * delta
    p = rng.uniform(-100, 100, (n, 2))
    theta = rng.uniform(-7, 7, n)
    g = p + rng.uniform(-1.2 * reach, 1.2 * reach, (n, 2))
    g[:300] = p[:300]                                                   # at the start
    ahead = np.stack([np.cos(theta[300:600]), np.sin(theta[300:600])], axis=-1)
    g[300:600] = p[300:600] + rng.uniform(0, 1.1 * reach, (300, 1)) * ahead            # dead ahead
    rim = g[600:1600] - p[600:1600]
    g[600:1600] = p[600:1600] + rim * (reach * (1 + rng.uniform(-1e-12, 1e-12, (1000, 1)))
                                       / np.linalg.norm(rim, axis=1, keepdims=True))   # at the reach
    m = solve_manoeuvre(p, theta, g, v_max=v_max, w_max=w_max, delta=delta)
    want = m.feasible
    got = manoeuvre_feasible(p, theta, g, v_max=v_max, w_max=w_max, delta=delta)
    assert got.dtype == bool and np.array_equal(got, want)
    assert 0.05 < want.mean() < 0.95
    # The controls alone (what the env flies) are solve_manoeuvre's, bit for bit, NaN where infeasible.
    feasible, v, omega, turn_time = manoeuvre_controls(p, theta, g, v_max=v_max, w_max=w_max, delta=delta)
    np.testing.assert_array_equal(feasible, want)
    for name, arr in (("v", v), ("omega", omega), ("turn_time", turn_time)):
        np.testing.assert_array_equal(arr, getattr(m, name), err_msg=name)


def _eq29_in_numpy(a, b, d2, r, wd):
    """Eq. 29's residual F(r) = r tau + L - delta W_max r, with tau and L, written with numpy array operations."""
    lat = np.sqrt(np.maximum(d2 - 2.0 * b * r, 0.0))
    quotient = (a > 0) & (a + lat > 1e-6 * (b + r))
    a_minus_l = np.where(quotient, b * (2.0 * r - b) / np.where(quotient, a + lat, 1.0), a - lat)
    t = np.arctan2(r * a_minus_l + lat * b, lat * a - r * (b - r))
    tau = np.where(t < 0, t + 2 * np.pi, t)
    return r * tau + lat - wd * r, tau, lat


def _dF(a, b, r, tau, lat, wd):
    return tau + (lat * (r - b) - a * r) / (lat * lat + r * r) - wd


def _newton_in_numpy(a, b, d, d2, wd, r_max):
    """The safeguarded Newton iteration of eq. 29 written with numpy array operations (the form the compiled steps
    of covert_env.geometry.turn_root follow, operation for operation)."""
    from covert_env.geometry.turn_root import _NEWTON_RTOL, root_bracket

    _F = _eq29_in_numpy

    ok, r_out = np.zeros(len(a), bool), np.full(len(a), np.nan)
    idx, lo, hi = root_bracket(a, b, d, d2, wd, r_max)
    a, b, d2 = a[idx], b[idx], d2[idx]
    x = lo.copy()
    f, tau, lat = _F(a, b, d2, x, wd)
    fp = _dF(a, b, x, tau, lat, wd)
    dx_old = hi - lo
    dx = dx_old.copy()
    act, r_res = np.arange(idx.size), np.full(idx.size, np.nan)
    for _ in range(100):
        pos = f > 0
        lo, hi = np.where(pos, x, lo), np.where(pos, hi, x)
        newton = x - f / fp
        bis = ~((newton > lo) & (newton < hi)) | (np.abs(2.0 * f) > np.abs(dx_old * fp))
        x_new = np.where(bis, 0.5 * (lo + hi), newton)
        dx_old, dx = dx, x_new - x
        done = (np.abs(dx) <= _NEWTON_RTOL * x_new) | (f == 0) | (hi - lo <= _NEWTON_RTOL * hi)
        x = x_new
        r_res[act[done]] = np.where(f[done] == 0, x[done] - dx[done], x[done])
        keep = ~done
        act, a, b, d2, x, lo, hi, dx, dx_old = (t[keep] for t in (act, a, b, d2, x, lo, hi, dx, dx_old))
        if act.size == 0:
            break
        f, tau, lat = _F(a, b, d2, x, wd)
        fp = _dF(a, b, x, tau, lat, wd)
    good = np.isfinite(r_res)
    ok[idx[good]], r_out[idx[good]] = True, r_res[good]
    return ok, r_out


@pytest.mark.parametrize("w_max, v_max", [(3.0, 50.0), (5.0, 30.0), (1.0, 80.0)])
def test_compiled_newton_is_the_numpy_iteration_bit_for_bit(w_max, v_max):
    """solve_turn (compiled steps, numpy's arctangent) gives every root of the numpy form to the last bit, on goals
    ahead, abeam, behind (two roots with W_max = 5), on and near the turning circle and at the reach's edge."""
    from covert_env.geometry.turn_root import solve_turn

    rng = np.random.default_rng(7)
    n = 20000
    ang = rng.uniform(-np.pi, np.pi, n)
    dist = v_max * rng.choice([0.02, 0.3, 0.7, 0.999, 1.0], n) * rng.uniform(0.9, 1.0, n)
    a, b = dist * np.cos(ang), np.abs(dist * np.sin(ang))
    keep = b > 1e-9 * dist
    # Goals on turning circles (centre (0, r)): the bracket's end R_c = r, where a + L nearly cancels.
    r, t = v_max / w_max * rng.uniform(0.05, 1.0, 2000), rng.uniform(0.01, 2 * np.pi - 0.01, 2000)
    a, b = np.concatenate([a[keep], r * np.sin(t)]), np.concatenate([b[keep], r * (1.0 - np.cos(t))])
    d2 = a * a + b * b
    d = np.sqrt(d2)
    with np.errstate(all="ignore"):
        want = _newton_in_numpy(a, b, d, d2, w_max, v_max / w_max)
        got = solve_turn(a, b, d, d2, w_max, v_max / w_max)
    assert want[0].sum() > 1000
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])


def _points_in_numpy(m, n):
    """Manoeuvre.points written with numpy array operations: the straight leg from the tangent point at every time,
    then the turn flown from the start at the times in it (the form the compiled samples follow)."""
    from covert_env.geometry.dynamics import unicycle_arc

    t = np.linspace(0.0, m.delta, n)
    ex = (Ellipsis, None)
    v, om, tt = (np.asarray(q, dtype=float)[ex] for q in (m.v, m.omega, m.turn_time))
    th0, tha = np.asarray(m.theta0, dtype=float)[ex], np.asarray(m.heading_after, dtype=float)[ex]
    sx, sy, zx, zy = m.start[..., 0][ex], m.start[..., 1][ex], m.tangent[..., 0][ex], m.tangent[..., 1][ex]
    batch = np.broadcast_shapes(*(np.shape(a) for a in (v, om, tt, th0, tha, sx, sy, zx, zy)))
    out = np.empty(batch[:-1] + (n, 2))
    out[..., 0], out[..., 1], _ = unicycle_arc(zx, zy, tha, v, 0.0, np.maximum(t - tt, 0.0), heading=False)
    turning = np.nonzero(np.broadcast_to(t <= tt, out.shape[:-1]))
    at = turning[:-1] + (0,)
    x1, y1, _ = unicycle_arc(*(np.broadcast_to(a, batch)[at] for a in (sx, sy, th0, v, om)), t[turning[-1]],
                             heading=False)
    out[turning + (0,)] = x1
    out[turning + (1,)] = y1
    return out


@pytest.mark.parametrize("limits", [(50.0, 3.0, 1.0), (37.0, 2.3, 0.7)])
def test_manoeuvre_points_are_the_numpy_arcs_bit_for_bit(limits):
    """The compiled samples of Manoeuvre.points equal unicycle_arc's numpy form to the last bit: turns, straight
    moves, infeasible goals (NaN rows), a broadcast start and a single manoeuvre."""
    v_max, w_max, delta = limits
    rng = np.random.default_rng(5)
    p = rng.uniform(-100, 100, (500, 2))
    theta = rng.uniform(0, 2 * np.pi, 500)
    g = p + rng.uniform(-1.3 * v_max * delta, 1.3 * v_max * delta, (500, 2))
    g[:40] = p[:40] + rng.uniform(1, v_max * delta, (40, 1)) * np.stack([np.cos(theta[:40]), np.sin(theta[:40])], -1)
    m = solve_manoeuvre(p, theta, g, v_max=v_max, w_max=w_max, delta=delta)
    assert 0.1 < m.feasible.mean() < 0.95 and (m.omega == 0).any()
    for n in (2, 21, 201):
        np.testing.assert_array_equal(m.points(n), _points_in_numpy(m, n))
        # Instant-major, the same numbers: (n, K, 2), C-contiguous, as the line-of-sight kernel reads them.
        by_instant = m.points(n, by_instant=True)
        assert by_instant.shape == (n, 500, 2) and by_instant.flags.c_contiguous
        np.testing.assert_array_equal(by_instant, _points_in_numpy(m, n).transpose(1, 0, 2))
    shared = solve_manoeuvre(p[0], theta[0], g[:50], v_max=v_max, w_max=w_max, delta=delta)   # one start, 50 goals
    np.testing.assert_array_equal(shared.points(21), _points_in_numpy(shared, 21))
    one = solve_manoeuvre(p[7], theta[7], g[7], v_max=v_max, w_max=w_max, delta=delta)
    assert one.points(11).shape == (11, 2)
    np.testing.assert_array_equal(one.points(11), _points_in_numpy(one, 11))
    np.testing.assert_array_equal(one.points(11, by_instant=True), _points_in_numpy(one, 11))
