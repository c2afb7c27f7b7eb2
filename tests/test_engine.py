"""covert_env.world.engine: one slot of physics at a time, recorded as a Trajectory.

References: :func:`covert_env.geometry.dynamics.unicycle_step` (itself tested against RK4) for unicycle slots,
:func:`covert_env.geometry.dynamics.solve_manoeuvre` for which waypoints are feasible and where they lead.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from covert_env.geometry.dynamics import solve_manoeuvre, unicycle_step
from covert_env.geometry.flight import HEADING_GRID, POSITION_GRID
from covert_env.world.config import Config
from covert_env.world.engine import Engine
from covert_env.world.scenario import Scenario
from covert_env.world.trajectory import Trajectory

TWO_PI = 2 * math.pi


def wrapped(a):
    return np.abs(np.angle(np.exp(1j * np.asarray(a, float))))


@pytest.fixture(scope="module")
def paper():
    return Scenario.paper()


@pytest.fixture(scope="module")
def short():
    return Scenario.paper(Config(n_slots=4))


def chord_checks(path, theta0, theta1, v, w_max, delta):
    """Samples of one UAV's slot path: equally timed points of a C1 curve of speed v and turn rate <= w_max."""
    p = path.shape[0]
    dt = delta / (p - 1)
    seg = np.diff(path, axis=0)
    step = np.hypot(seg[:, 0], seg[:, 1])
    assert np.all(step <= v * dt + 1e-9 + POSITION_GRID), (step.max(), v * dt)
    direc = np.arctan2(seg[:, 1], seg[:, 0])
    # The end pose is settled (v4): the last sample moves by up to a grid step, which turns the last chord by up to
    # that over its length, and the end heading by up to half a heading step.
    settled = POSITION_GRID / step[-1]
    # The chord direction turns by at most w_max * dt between consecutive chords, and the first / last
    # chord is within half of that of the start / end heading: the path has no kinks.
    assert np.all(wrapped(np.diff(direc)) <= w_max * dt + 1e-9 + np.append(np.zeros(len(step) - 2), settled))
    assert wrapped(direc[0] - theta0) <= w_max * dt / 2 + 1e-9 + (settled if len(step) == 1 else 0.0)
    assert wrapped(direc[-1] - theta1) <= w_max * dt / 2 + 1e-9 + settled + HEADING_GRID / 2


# ----------------------------------------------------------------------------- construction / reset
def test_initial_state(paper):
    e = Engine(paper)
    assert e.k == 0 and not e.done and e.n_uavs == 3
    np.testing.assert_array_equal(e.uav_xy, paper.uav_xy)
    np.testing.assert_allclose(e.uav_theta, np.mod(paper.uav_theta, TWO_PI))
    assert np.all((e.uav_theta >= 0) & (e.uav_theta < TWO_PI))
    np.testing.assert_allclose(e.target_xyz, paper.track.position(0))
    assert e.target_phi == pytest.approx(paper.track.heading(0))
    q, phi = e.predict()
    q_ref, phi_ref = paper.track.predict(0, paper.config.horizon)
    np.testing.assert_allclose(q, q_ref)
    np.testing.assert_allclose(phi, phi_ref)
    assert q.shape == (paper.config.horizon, 3)


@pytest.mark.parametrize("p", [0, 1])
def test_path_samples_must_be_at_least_two(paper, p):
    with pytest.raises(ValueError, match="path_samples"):
        Engine(paper, path_samples=p)


def test_reset_restores_the_start(paper):
    e = Engine(paper)
    for _ in range(3):
        e.step(unicycle=[[30.0, 1.0], [20.0, -2.0], [45.0, 0.5]])
    assert e.k == 3
    assert not np.allclose(e.uav_xy, paper.uav_xy)
    e.reset()
    assert e.k == 0 and not e.done
    np.testing.assert_array_equal(e.uav_xy, paper.uav_xy)
    np.testing.assert_allclose(e.uav_theta, np.mod(paper.uav_theta, TWO_PI))
    t = e.trajectory()
    assert t.n_slots == 0
    assert t.uav_xy.shape == (1, 3, 2)
    np.testing.assert_array_equal(t.uav_xy[0], paper.uav_xy)
    np.testing.assert_allclose(e.target_xyz, paper.track.position(0))
    # The episode replays identically after reset.
    q1 = e.step(unicycle=[[30.0, 1.0], [20.0, -2.0], [45.0, 0.5]])
    e2 = Engine(paper)
    q2 = e2.step(unicycle=[[30.0, 1.0], [20.0, -2.0], [45.0, 0.5]])
    np.testing.assert_array_equal(e.uav_xy, e2.uav_xy)
    np.testing.assert_array_equal(q1.g, q2.g)


def test_reset_to_given_poses(paper):
    e = Engine(paper)
    e.reset(uav_xy=[[70.0, 5.0], [50.0, -5.0]], uav_theta=[-math.pi / 2, 7.0])
    assert e.n_uavs == 2
    np.testing.assert_array_equal(e.uav_xy, [[70.0, 5.0], [50.0, -5.0]])
    np.testing.assert_allclose(e.uav_theta, [1.5 * math.pi, 7.0 - TWO_PI])
    q = e.step(unicycle=[[10.0, 0.0], [10.0, 0.0]])
    assert q.g.shape == (1, 2)
    with pytest.raises(ValueError, match="headings"):
        e.reset(uav_xy=[[70.0, 5.0], [50.0, -5.0]], uav_theta=[0.0])


# ----------------------------------------------------------------------------- unicycle slots
@pytest.mark.parametrize("ctl", [
    [[50.0, 3.0], [10.0, -3.0], [1e-3, 0.0]],
    [[25.0, 0.0], [49.9, 1.234], [33.0, -0.001]],
])
def test_unicycle_step_is_the_exact_arc(paper, ctl):
    e = Engine(paper, path_samples=9)
    x0, th0 = e.uav_xy.copy(), e.uav_theta.copy()
    ctl = np.array(ctl)
    e.step(unicycle=ctl)
    x, y, th = unicycle_step(x0[:, 0], x0[:, 1], th0, ctl[:, 0], ctl[:, 1], paper.config.delta)
    np.testing.assert_allclose(e.uav_xy, np.column_stack([x, y]), atol=1e-9)
    assert np.all(wrapped(e.uav_theta - th) <= HEADING_GRID / 2 + 1e-12)   # the settled heading (v4)
    t = e.trajectory()
    fr = np.linspace(0.0, 1.0, 9)
    for i in range(3):
        xs, ys, _ = unicycle_step(x0[i, 0], x0[i, 1], th0[i], ctl[i, 0], ctl[i, 1], fr * paper.config.delta)
        np.testing.assert_allclose(t.path_xy[0, i], np.column_stack([xs, ys]), atol=1e-9)
    np.testing.assert_allclose(t.path_length[0], ctl[:, 0] * paper.config.delta)
    np.testing.assert_allclose(t.max_speed[0], ctl[:, 0])
    np.testing.assert_allclose(t.max_turn_rate[0], np.abs(ctl[:, 1]))
    assert not t.infeasible.any()


@pytest.mark.parametrize("ctl,field", [
    ([[0.0, 0.0], [10.0, 0.0], [10.0, 0.0]], r"\bv\b"),
    ([[-5.0, 0.0], [10.0, 0.0], [10.0, 0.0]], r"\bv\b"),
    ([[10.0, 0.0], [50.5, 0.0], [10.0, 0.0]], r"\bv\b"),
    ([[10.0, 0.0], [10.0, 3.01], [10.0, 0.0]], "omega"),
    ([[10.0, 0.0], [10.0, 0.0], [10.0, -3.5]], "omega"),
    ([[np.nan, 0.0], [10.0, 0.0], [10.0, 0.0]], "unicycle"),
    ([[10.0, 0.0], [10.0, np.inf], [10.0, 0.0]], "unicycle"),
])
def test_invalid_unicycle_controls_raise_naming_the_field(paper, ctl, field):
    e = Engine(paper)
    with pytest.raises(ValueError, match=field):
        e.step(unicycle=ctl)
    # A rejected step changes nothing.
    assert e.k == 0
    np.testing.assert_array_equal(e.uav_xy, paper.uav_xy)
    assert e.trajectory().n_slots == 0


def test_controls_at_the_limits_are_accepted(paper):
    c = paper.config
    e = Engine(paper)
    e.step(unicycle=[[c.v_max, c.w_max], [c.v_max, -c.w_max], [1e-6, 0.0]])
    assert e.k == 1


def test_step_needs_exactly_one_control_kind(paper):
    e = Engine(paper)
    with pytest.raises(ValueError, match="exactly one"):
        e.step()
    with pytest.raises(ValueError, match="exactly one"):
        e.step(unicycle=[[10.0, 0.0]] * 3, waypoints=paper.uav_xy + 10.0)


def test_non_finite_waypoints_raise(paper):
    e = Engine(paper)
    with pytest.raises(ValueError, match="waypoints"):
        e.step(waypoints=[[np.nan, 0.0], [80.0, 0.0], [70.0, 0.0]])
    assert e.k == 0


def test_step_after_done_raises(short):
    e = Engine(short)
    for _ in range(short.config.n_slots):
        assert not e.done
        e.step(unicycle=[[10.0, 0.0]] * 3)
    assert e.done and e.k == 4
    with pytest.raises(RuntimeError, match="reset"):
        e.step(unicycle=[[10.0, 0.0]] * 3)
    assert e.k == 4 and e.trajectory().n_slots == 4
    e.reset()
    e.step(unicycle=[[10.0, 0.0]] * 3)
    assert e.k == 1


# ----------------------------------------------------------------------------- waypoint slots
def _random_goals(engine, rng, n):
    """n candidate waypoint sets (n, U, 2) around the UAVs, mostly ahead of them."""
    u = engine.n_uavs
    rng_d = rng.uniform(3.0, 48.0, (n, u))
    bearing = engine.uav_theta + rng.uniform(-2.5, 2.5, (n, u))
    return engine.uav_xy + rng_d[..., None] * np.stack([np.cos(bearing), np.sin(bearing)], -1)


def turn_then_straight_residual(p0, th0, th1, v, goal, w_max, delta):
    """How far a turn at +-w_max (toward th1, speed v) followed by a straight flight along th1 for the rest of
    the slot ends from ``goal``: the paper's construction (eqs. 23-27) rebuilt from the pose and speed alone,
    independently of :func:`solve_manoeuvre`. Also returns the straight part's length (>= 0 for a manoeuvre)."""
    r = v / w_max
    turn = np.where(np.sin(th1 - th0) >= 0.0, 1.0, -1.0)
    tau = np.mod(turn * (th1 - th0), TWO_PI)
    tau = np.where(tau > TWO_PI - 1e-9, 0.0, tau)            # no turn, up to rounding
    c, s = np.cos(th0), np.sin(th0)
    fwd, lat = r * np.sin(tau), turn * r * (1.0 - np.cos(tau))
    z = p0 + np.stack([c * fwd - s * lat, s * fwd + c * lat], -1)
    straight = v * delta - r * tau
    end = z + straight[:, None] * np.stack([np.cos(th1), np.sin(th1)], -1)
    return np.hypot(*(end - goal).T), straight


def test_feasible_waypoints_are_reached_with_the_manoeuvre_heading(paper):
    """Waypoints with a turn-then-straight manoeuvre are reached, at the end of the slot, by a turn at W_max
    then a straight flight (checked from the flown pose and speed, not from the solver the engine calls);
    the others are flagged and flown as a best effort within the limits."""
    c = paper.config
    e = Engine(paper, path_samples=21)
    rng = np.random.default_rng(0)
    n_feasible = n_fallback = 0
    for goals in _random_goals(e, rng, 40):
        e.reset()
        p0, th0 = e.uav_xy.copy(), e.uav_theta.copy()
        ok = np.asarray(solve_manoeuvre(p0, th0, goals, v_max=c.v_max, w_max=c.w_max, delta=c.delta).feasible)
        e.step(waypoints=goals)
        t = e.trajectory()
        n_feasible += ok.sum()
        n_fallback += (~ok).sum()
        np.testing.assert_array_equal(t.infeasible[0], ~ok)
        err = np.hypot(*(e.uav_xy - goals).T)
        assert np.all(err[ok] <= 1e-6), err[ok]
        assert np.all(t.max_speed[0] <= c.v_max + 1e-9) and np.all(t.max_turn_rate[0] <= c.w_max + 1e-9)
        miss, straight = turn_then_straight_residual(p0, th0, e.uav_theta, t.max_speed[0], goals, c.w_max, c.delta)
        assert np.all(miss[ok] <= 1e-6) and np.all(straight[ok] >= -1e-9), (miss[ok], straight[ok])
        turning = ok & (wrapped(e.uav_theta - th0) > 1e-9)
        np.testing.assert_allclose(t.max_turn_rate[0][turning], c.w_max, rtol=1e-12)
        np.testing.assert_allclose(t.path_length[0][ok], t.max_speed[0][ok] * c.delta, rtol=1e-12)
        for i in range(e.n_uavs):
            np.testing.assert_array_equal(t.path_xy[0, i, 0], p0[i])
            np.testing.assert_array_equal(t.path_xy[0, i, -1], e.uav_xy[i])
            chord_checks(t.path_xy[0, i], th0[i], e.uav_theta[i], t.max_speed[0, i], c.w_max, c.delta)
    assert n_feasible >= 40 and n_fallback >= 10       # the sample exercises both the manoeuvre and the fallback


def test_waypoint_path_length_is_the_flown_length(paper):
    e = Engine(paper, path_samples=401)
    goals = e.uav_xy + np.array([[30.0, 20.0], [-25.0, -15.0], [10.0, 30.0]])
    e.step(waypoints=goals)
    t = e.trajectory()
    assert not t.infeasible.any()
    flown = np.hypot(*np.diff(t.path_xy[0], axis=1).transpose(2, 0, 1)).sum(axis=1)
    assert np.all(flown <= t.path_length[0] + 1e-9)
    np.testing.assert_allclose(flown, t.path_length[0], rtol=1e-4)
    # Turning costs distance: every path is longer than the straight line to its waypoint.
    assert np.all(t.path_length[0] >= np.hypot(*(goals - paper.uav_xy).T) - 1e-9)


@pytest.mark.parametrize("offset", [[200.0, 0.0], [0.0, -200.0], [-150.0, 130.0]])
def test_far_waypoint_is_best_effort_and_flagged(paper, offset):
    c = paper.config
    e = Engine(paper, path_samples=21)
    p0, th0 = e.uav_xy.copy(), e.uav_theta.copy()
    goals = p0 + np.array([offset, [10.0, 0.0], [10.0, 0.0]])
    goals[1] = unicycle_step(p0[1, 0], p0[1, 1], th0[1], 10.0, 0.0, 1.0)[:2]   # straight ahead: feasible
    goals[2] = unicycle_step(p0[2, 0], p0[2, 1], th0[2], 10.0, 0.0, 1.0)[:2]
    e.step(waypoints=goals)
    t = e.trajectory()
    np.testing.assert_array_equal(t.infeasible[0], [True, False, False])
    assert t.max_speed[0, 0] <= c.v_max + 1e-12
    assert t.max_turn_rate[0, 0] <= c.w_max + 1e-12
    assert t.path_length[0, 0] <= c.v_max * c.delta + 1e-9
    # Best effort: it flew toward the goal, along a smooth path.
    d0 = np.hypot(*(goals[0] - p0[0]))
    d1 = np.hypot(*(goals[0] - e.uav_xy[0]))
    assert d1 < d0 - 1.0
    chord_checks(t.path_xy[0, 0], th0[0], e.uav_theta[0], t.max_speed[0, 0], c.w_max, c.delta)
    np.testing.assert_allclose(e.uav_xy[1:], goals[1:], atol=1e-6)


def test_waypoint_behind_and_waypoint_at_start_are_flagged_not_crashing(paper):
    c = paper.config
    e = Engine(paper)
    p0, th0 = e.uav_xy.copy(), e.uav_theta.copy()
    behind = p0 - 20.0 * np.column_stack([np.cos(th0), np.sin(th0)])
    goals = np.array([behind[0], p0[1], p0[2] + [0.0, 0.0]])
    e.step(waypoints=goals)
    t = e.trajectory()
    assert t.infeasible[0].all()
    assert np.all(np.isfinite(e.uav_xy)) and np.all(np.isfinite(e.uav_theta))
    assert np.all(t.max_speed[0] > 0) and np.all(t.max_speed[0] <= c.v_max)
    assert np.all(t.max_turn_rate[0] <= c.w_max + 1e-12)


def test_policy_flag_and_decision_time_are_recorded(paper):
    e = Engine(paper)
    e.step(unicycle=[[10.0, 0.0]] * 3, infeasible=[False, True, False], decision_time=[0.5, 0.25, 0.125])
    e.step(unicycle=[[10.0, 0.0]] * 3)
    t = e.trajectory()
    np.testing.assert_array_equal(t.infeasible, [[False, True, False], [False, False, False]])
    np.testing.assert_array_equal(t.decision_time[0], [0.5, 0.25, 0.125])
    assert np.isnan(t.decision_time[1]).all()


# ----------------------------------------------------------------------------- trajectory
def _run(scenario, n, path_samples=7, seed=0):
    e = Engine(scenario, path_samples=path_samples)
    rng = np.random.default_rng(seed)
    c = scenario.config
    for k in range(n):
        if k % 2:
            ctl = np.column_stack([rng.uniform(5, c.v_max, e.n_uavs), rng.uniform(-c.w_max, c.w_max, e.n_uavs)])
            e.step(unicycle=ctl, decision_time=rng.uniform(0, 0.01, e.n_uavs))
        else:
            e.step(waypoints=_random_goals(e, rng, 1)[0])
    return e


def test_trajectory_shapes_and_consistency(paper):
    e = _run(paper, 5)
    t = e.trajectory()
    T, U, P = 5, 3, 7
    assert t.n_slots == T and t.n_uavs == U
    shapes = {"uav_xy": (T + 1, U, 2), "uav_theta": (T + 1, U), "path_xy": (T, U, P, 2), "path_length": (T, U),
              "target_xyz": (T + 1, 3), "target_phi": (T + 1,), "target_path_xyz": (T, P, 3),
              "max_speed": (T, U), "max_turn_rate": (T, U), "infeasible": (T, U), "decision_time": (T, U)}
    for name, shape in shapes.items():
        assert getattr(t, name).shape == shape, name
    assert t.infeasible.dtype == bool
    # Paths join the slot-time positions; the target's samples join its slot-time positions.
    np.testing.assert_array_equal(t.path_xy[:, :, 0], t.uav_xy[:-1])
    np.testing.assert_allclose(t.path_xy[:, :, -1], t.uav_xy[1:], atol=1e-12)
    np.testing.assert_allclose(t.target_xyz, paper.track.position(np.arange(T + 1)))
    np.testing.assert_allclose(t.target_phi, paper.track.heading(np.arange(T + 1)))
    np.testing.assert_allclose(t.target_path_xyz[:, 0], t.target_xyz[:-1], atol=1e-12)
    np.testing.assert_allclose(t.target_path_xyz[:, -1], t.target_xyz[1:], atol=1e-12)
    np.testing.assert_allclose(t.path_length, t.max_speed * paper.config.delta)
    assert np.all((t.uav_theta >= 0) & (t.uav_theta < TWO_PI))
    np.testing.assert_array_equal(t.uav_xy[-1], e.uav_xy)
    # Slots 1 and 3 had measured decision times, the waypoint slots did not.
    assert np.isfinite(t.decision_time[[1, 3]]).all() and np.isnan(t.decision_time[[0, 2, 4]]).all()


def test_trajectory_last_is_the_tail(paper):
    e = _run(paper, 5)
    full, tail = e.trajectory(), e.trajectory(last=2)
    assert tail.n_slots == 2
    np.testing.assert_array_equal(tail.uav_xy, full.uav_xy[3:])
    np.testing.assert_array_equal(tail.path_xy, full.path_xy[3:])
    np.testing.assert_array_equal(tail.target_xyz, full.target_xyz[3:])
    np.testing.assert_array_equal(tail.decision_time, full.decision_time[3:])
    assert e.trajectory(last=50).n_slots == 5


def test_trajectory_is_a_snapshot(paper):
    e = _run(paper, 2)
    t = e.trajectory()
    before = t.uav_xy.copy()
    e.step(unicycle=[[10.0, 0.0]] * 3)
    np.testing.assert_array_equal(t.uav_xy, before)
    t.uav_xy[:] = 0.0
    assert not np.allclose(e.trajectory().uav_xy, 0.0)


def test_trajectory_json_round_trip(paper, tmp_path):
    t = _run(paper, 4).trajectory()
    path = tmp_path / "traj.json"
    t.save(path)
    back = Trajectory.load(path)
    for name in (f.name for f in dataclasses.fields(t)):
        a, b = getattr(t, name), getattr(back, name)
        assert a.shape == b.shape, name
        np.testing.assert_array_equal(a, b, err_msg=name)
    assert back.infeasible.dtype == bool
    assert back.n_slots == 4 and back.n_uavs == 3


def test_trajectory_from_dict_names_missing_fields(paper):
    d = _run(paper, 1).trajectory().to_dict()
    del d["path_xy"], d["decision_time"]
    with pytest.raises(ValueError, match="decision_time.*path_xy|path_xy.*decision_time"):
        Trajectory.from_dict(d)


def test_trajectory_json_is_standard_json(paper, tmp_path):
    e = Engine(paper)
    e.step(unicycle=[[10.0, 0.0]] * 3)          # no decision_time: recorded as NaN
    path = tmp_path / "t.json"
    e.trajectory().save(path)

    def reject(token):
        raise AssertionError(f"non-standard JSON constant {token}")

    json.loads(path.read_text(), parse_constant=reject)


def test_empty_trajectory_round_trip_keeps_shapes(paper):
    t = Engine(paper).trajectory()
    back = Trajectory.from_dict(json.loads(json.dumps(t.to_dict())))
    for name in (f.name for f in dataclasses.fields(t)):
        assert getattr(back, name).shape == getattr(t, name).shape, name


@pytest.mark.parametrize("offset", [[-20.0, 0.0], [0.0, 1.0], [200.0, 0.0], [-150.0, 130.0]])
def test_fallback_is_the_closest_constant_control(paper, offset):
    """An unreachable waypoint (behind, inside the turning circle, too far) is flown by the admissible
    constant control that ends closest to it: no control on a fine grid ends much closer."""
    from covert_env.geometry.dynamics import unicycle_step

    eng = Engine(paper)
    c = paper.config
    p0, th0 = eng.uav_xy.copy(), eng.uav_theta.copy()
    rot = np.array([[np.cos(th0[0]), -np.sin(th0[0])], [np.sin(th0[0]), np.cos(th0[0])]])
    goal = p0[0] + rot @ np.asarray(offset)
    goals = p0.copy()
    goals[0] = goal
    goals[1:] += 200.0                      # the others fly far waypoints too
    eng.step(waypoints=goals)
    traj = eng.trajectory()
    assert traj.infeasible[0, 0]
    assert traj.max_speed[0, 0] <= c.v_max + 1e-9 and traj.max_turn_rate[0, 0] <= c.w_max + 1e-9
    got = np.hypot(*(eng.uav_xy[0] - goal))
    vs, ws = np.meshgrid(np.linspace(0.005, 1, 101) * c.v_max, np.linspace(-1, 1, 101) * c.w_max)
    x, y, _ = unicycle_step(p0[0, 0], p0[0, 1], th0[0], vs, ws, c.delta)
    best = np.hypot(x - goal[0], y - goal[1]).min()
    assert got <= best + 0.05   # the refined grid search is at least as good as a 101 x 101 grid, to 5 cm
    if offset[0] > 100:                    # far ahead: it gets as close as the speed limit allows
        assert got == pytest.approx(np.hypot(*offset) - c.v_max * c.delta, abs=0.5)


# ----------------------------------------------------------------------------- the envs fly the engine's flight
@pytest.mark.parametrize("mode", ["unicycle", "waypoint"])
def test_env_episode_is_the_engines(mode):
    """An env episode (the vector env's recorder, read through the parallel env) is exactly the trajectory an
    Engine records when flown with the same controls or waypoints (masked-out and unreachable ones included)."""
    import covert_env
    from covert_env.envs.batch import unicycle_controls
    from covert_env.geometry.zone import to_world

    env = covert_env.parallel_env(n_uavs=3, action_mode=mode, path_samples=7)
    env.reset(seed=4)
    eng = Engine(env.scenario, path_samples=7)
    rng = np.random.default_rng(7)
    c = env.config
    for _ in range(10):
        if mode == "unicycle":
            act = rng.uniform(-1, 1, (3, 2)).astype(np.float32)
            v, w = unicycle_controls(act.astype(float), c)
            eng.step(unicycle=np.column_stack([v, w]))
            env.step(dict(zip(env.possible_agents, act, strict=True)))
        else:
            idx = rng.integers(len(env.lattice), size=3)              # mostly masked out or unreachable
            masks = np.stack([env.action_mask(a) for a in env.possible_agents])
            q1, phi1 = eng.predict(1)
            eng.step(waypoints=to_world(env.lattice[idx], q1[0, :2], float(phi1[0])),
                     infeasible=masks[np.arange(3), idx] == 0)
            env.step(dict(zip(env.possible_agents, idx.tolist(), strict=True)))
        np.testing.assert_array_equal(env.engine.uav_xy, eng.uav_xy)
    a, b = env.engine.trajectory(), eng.trajectory()
    for f in dataclasses.fields(a):
        np.testing.assert_array_equal(getattr(a, f.name), getattr(b, f.name), err_msg=f.name)
    assert a.n_slots == 10
    if mode == "waypoint":
        assert a.infeasible.any()                                     # the fallback was exercised
