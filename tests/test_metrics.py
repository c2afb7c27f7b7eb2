"""covert_env.world.metrics: per-slot quantities and per-UAV episode metrics on hand-built trajectories.

The world here is tiny and hand-checked: a target at the origin (z = 1.5 m, heading +x) and, where
needed, one box building 50 m tall between it and the UAVs (x in [-20, -10], y in [-3, 3]). Seen from
a UAV at (-60, y, 80), the sight line crosses the box iff |y| < 18 m (it leaves through the face
x = -10 at y / 6). Expected values are computed
with plain math, not with covert_env.geometry.cost.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from covert_env.world.config import Config
from covert_env.world.engine import Engine
from covert_env.world.metrics import METRIC_DESCRIPTIONS, episode_metrics, slot_quantities
from covert_env.world.scenario import Scenario
from covert_env.world.terrain import Polytope, Terrain
from covert_env.world.trajectory import Trajectory
from covert_env.world.visibility import line_of_sight

CFG = Config()                  # eta 55, lam 10, d_safe1 5, d_safe2 10, h 80, R1 55, R2 100, mu pi/4
BOX = Polytope.prism([[-20.0, -3.0], [-10.0, -3.0], [-10.0, 3.0], [-20.0, 3.0]], 50.0)
WORLD = Terrain([BOX])
EMPTY = Terrain()
Q0 = np.array([0.0, 0.0, 1.5])


def make_traj(uav_xy, *, target_xyz=None, target_phi=None, samples=11, path_xy=None, path_length=None,
              max_speed=None, max_turn_rate=None, infeasible=None, decision_time=None) -> Trajectory:
    """A Trajectory from slot-time positions (T+1, U, 2); paths are straight lines sampled uniformly."""
    uav_xy = np.asarray(uav_xy, float)
    t1, u = uav_xy.shape[:2]
    t = t1 - 1
    f = np.linspace(0.0, 1.0, samples)[:, None]
    if path_xy is None:
        path_xy = np.stack([[uav_xy[k, i] + f * (uav_xy[k + 1, i] - uav_xy[k, i]) for i in range(u)]
                            for k in range(t)]).reshape(t, u, samples, 2)
    target_xyz = np.tile(Q0, (t1, 1)) if target_xyz is None else np.asarray(target_xyz, float)
    target_phi = np.zeros(t1) if target_phi is None else np.asarray(target_phi, float)
    tp = np.stack([target_xyz[k] + f * (target_xyz[k + 1] - target_xyz[k]) for k in range(t)]).reshape(t, samples, 3)
    if path_length is None:
        seg = np.diff(path_xy, axis=2)
        path_length = np.hypot(seg[..., 0], seg[..., 1]).sum(-1)
    path_length = np.asarray(path_length, float).reshape(t, u)
    return Trajectory(
        uav_xy=uav_xy, uav_theta=np.zeros((t1, u)), path_xy=np.asarray(path_xy, float), path_length=path_length,
        target_xyz=target_xyz, target_phi=target_phi, target_path_xyz=tp,
        max_speed=path_length / CFG.delta if max_speed is None else np.asarray(max_speed, float),
        max_turn_rate=np.zeros((t, u)) if max_turn_rate is None else np.asarray(max_turn_rate, float),
        infeasible=np.zeros((t, u), bool) if infeasible is None else np.asarray(infeasible, bool),
        decision_time=np.full((t, u), np.nan) if decision_time is None else np.asarray(decision_time, float))


def hand_alpha(p, q, phi):
    return math.remainder(math.atan2(p[1] - q[1], p[0] - q[0]) - phi, 2 * math.pi)


def hand_kappa(p0, p1, q0, q1, phi0, phi1, eta=CFG.eta):
    da = math.remainder(hand_alpha(p1, q1, phi1) - hand_alpha(p0, q0, phi0), 2 * math.pi)
    dd = math.dist(p1, q1[:2]) - math.dist(p0, q0[:2])
    return eta * abs(da) + abs(dd)


def test_the_box_blocks_what_the_docstring_says():
    ys = np.array([-30.0, -18.5, -17.5, 0.0, 17.5, 18.5, 30.0])
    clear = line_of_sight(WORLD, np.column_stack([np.full(7, -60.0), ys]), CFG.altitude, Q0)
    np.testing.assert_array_equal(clear, [True, True, False, False, False, True, True])


def test_metric_keys_are_the_documented_ones():
    m = episode_metrics(make_traj([[[-60.0, 30.0]], [[-60.0, 31.0]]]), EMPTY, CFG)
    assert len(m) == 1 and set(m[0]) == set(METRIC_DESCRIPTIONS)


# ----------------------------------------------------------------------------- LoS
def test_occlusion_rate_counts_the_blocked_slot():
    # Slot 0 ends behind the box (blocked), slot 1 and 2 end in the clear.
    xy = [[[-60.0, 30.0]], [[-60.0, 0.0]], [[-60.0, -30.0]], [[-65.0, -30.0]]]
    traj = make_traj(xy)
    q = slot_quantities(traj, WORLD, CFG)
    np.testing.assert_array_equal(q.los[:, 0], [False, True, True])
    np.testing.assert_array_equal(q.los_path[:, 0], [False, False, True])
    m = episode_metrics(traj, WORLD, CFG)[0]
    assert m["occlusion_rate"] == pytest.approx(1 / 3)
    assert m["occlusion_rate_path"] == pytest.approx(2 / 3)
    # Without the box nothing is blocked.
    m0 = episode_metrics(traj, EMPTY, CFG)[0]
    assert m0["occlusion_rate"] == 0.0 and m0["occlusion_rate_path"] == 0.0


def test_occlusion_rate_path_catches_a_blockage_in_the_middle_of_a_slot():
    # Both slot ends are clear; the straight path between them passes behind the box.
    xy = [[[-60.0, -30.0]], [[-60.0, 30.0]]]
    q = slot_quantities(make_traj(xy), WORLD, CFG)
    assert q.los[0, 0] and not q.los_path[0, 0]
    m = episode_metrics(make_traj(xy), WORLD, CFG)[0]
    assert m["occlusion_rate"] == 0.0
    assert m["occlusion_rate_path"] == 1.0
    # With only the endpoints sampled the blockage is invisible, as documented.
    m2 = episode_metrics(make_traj(xy, samples=2), WORLD, CFG)[0]
    assert m2["occlusion_rate_path"] == 0.0


def test_path_los_uses_the_target_at_the_same_instant():
    # The UAV crawls across y = 0 at x = -60 (right behind the box as seen from the origin) while the
    # target drives past from (0, 40) to (0, -40): only mid-slot, with the target at the origin, is it hidden.
    uav = [[[-60.0, 0.5]], [[-60.0, -0.5]]]             # behind the box if the target were at the origin
    tgt = np.array([[0.0, 40.0, 1.5], [0.0, -40.0, 1.5]])
    q = slot_quantities(make_traj(uav, target_xyz=tgt), WORLD, CFG)
    # At both slot times the target is 40 m to the side: clear. Mid-slot it is at the origin: blocked.
    assert line_of_sight(WORLD, np.array([-60.0, 0.5]), CFG.altitude, tgt[0])
    assert q.los[0, 0] and not q.los_path[0, 0]
    # A static target at (0, 40) would never be hidden along this path.
    static = np.array([[0.0, 40.0, 1.5], [0.0, 40.0, 1.5]])
    assert slot_quantities(make_traj(uav, target_xyz=static), WORLD, CFG).los_path[0, 0]


# ----------------------------------------------------------------------------- zone
def test_zone_violation_rate():
    # Zone behind a target at the origin heading +x: 55 <= rho <= 100 and within 22.5 deg of -x.
    xy = [[[-70.0, 0.0]], [[-60.0, 0.0]], [[-60.0, 30.0]], [[-40.0, 0.0]], [[-99.0, 0.0]], [[70.0, 0.0]]]
    q = slot_quantities(make_traj(xy), EMPTY, CFG)
    np.testing.assert_array_equal(q.in_zone[:, 0], [True, False, False, True, False])
    assert episode_metrics(make_traj(xy), EMPTY, CFG)[0]["zone_violation_rate"] == pytest.approx(3 / 5)


def test_zone_uses_the_target_pose_at_the_end_of_the_slot():
    # The target turns to face +y at slot 1: (0, -70) is then right behind it, (-70, 0) is beside it.
    tgt = np.tile(Q0, (2, 1))
    phi = [0.0, math.pi / 2]
    q1 = slot_quantities(make_traj([[[-70.0, 0.0]], [[0.0, -70.0]]], target_xyz=tgt, target_phi=phi), EMPTY, CFG)
    q2 = slot_quantities(make_traj([[[-70.0, 0.0]], [[-70.0, 1.0]]], target_xyz=tgt, target_phi=phi), EMPTY, CFG)
    assert q1.in_zone[0, 0] and not q2.in_zone[0, 0]


# ----------------------------------------------------------------------------- disguise and objective
def test_mean_disguise_and_objective_by_hand():
    # Slot 0 crosses the alpha = +-pi line right behind the target: a tiny bearing change, not 2 pi.
    # Slot 1 moves away and sideways while the target drives and turns.
    p = [(-70.0, -1.0), (-70.0, 1.0), (-75.0, 12.0)]
    tgt = np.array([[0.0, 0.0, 1.5], [0.0, 0.0, 1.5], [8.0, 1.0, 1.5]])
    phi = [0.0, 0.0, 0.2]
    lengths = [2.0, 13.0]
    traj = make_traj(np.array(p)[:, None], target_xyz=tgt, target_phi=phi, path_length=[[2.0], [13.0]])
    q = slot_quantities(traj, EMPTY, CFG)

    k0 = CFG.eta * 2 * math.atan2(1.0, 70.0)                     # |d alpha| = 2 atan(1/70), |dd| = 0
    assert k0 < 2.0
    assert hand_kappa(p[0], p[1], tgt[0], tgt[1], 0.0, 0.0) == pytest.approx(k0, rel=1e-12)
    k1 = hand_kappa(p[1], p[2], tgt[1], tgt[2], 0.0, 0.2)
    np.testing.assert_allclose(q.kappa[:, 0], [k0, k1], rtol=1e-12)
    np.testing.assert_allclose(q.g[:, 0], [lengths[0] - CFG.lam * k0, lengths[1] - CFG.lam * k1], rtol=1e-12)
    np.testing.assert_allclose(q.alpha[:, 0], [hand_alpha(p[1], tgt[1], 0.0), hand_alpha(p[2], tgt[2], 0.2)],
                               atol=1e-12)
    np.testing.assert_allclose(q.d[:, 0], [math.dist(p[1], tgt[1, :2]), math.dist(p[2], tgt[2, :2])], rtol=1e-12)
    assert abs(q.alpha[0, 0]) > 3.1                              # the end of slot 0 is right behind the target

    m = episode_metrics(traj, EMPTY, CFG)[0]
    assert m["mean_disguise"] == pytest.approx((k0 + k1) / 2, rel=1e-12)
    assert m["objective"] == pytest.approx(sum(lengths) - CFG.lam * (k0 + k1), rel=1e-12)
    assert m["path_length"] == pytest.approx(15.0)


def test_disguise_is_zero_when_the_uav_keeps_its_place_relative_to_the_target():
    # The UAV and the target both move by (10, 0): same alpha and d, kappa = 0, g = path length.
    p = np.array([[-70.0, 5.0], [-60.0, 5.0], [-50.0, 5.0]])[:, None]
    tgt = np.array([[0.0, 0.0, 1.5], [10.0, 0.0, 1.5], [20.0, 0.0, 1.5]])
    traj = make_traj(p, target_xyz=tgt)
    q = slot_quantities(traj, EMPTY, CFG)
    np.testing.assert_allclose(q.kappa, 0.0, atol=1e-9)
    np.testing.assert_allclose(q.g, 10.0, atol=1e-8)
    assert episode_metrics(traj, EMPTY, CFG)[0]["objective"] == pytest.approx(20.0, abs=1e-7)


# ----------------------------------------------------------------------------- separation
def test_separation_at_slot_times():
    # Two UAVs side by side: 12 m apart at the end of slot 0, 4 m (< d_safe1) at the end of slot 1.
    xy = [[[-70.0, -8.0], [-70.0, 8.0]], [[-70.0, -6.0], [-70.0, 6.0]], [[-70.0, -2.0], [-70.0, 2.0]]]
    traj = make_traj(xy)
    q = slot_quantities(traj, EMPTY, CFG)
    np.testing.assert_allclose(q.separation, [[12.0, 12.0], [4.0, 4.0]])
    np.testing.assert_allclose(q.separation_path, [[12.0, 12.0], [4.0, 4.0]])
    for m in episode_metrics(traj, EMPTY, CFG):
        assert m["min_separation"] == pytest.approx(4.0)
        assert m["separation_violations"] == 1
    # A looser d_safe1 turns both slots into violations; a tighter one none.
    assert episode_metrics(traj, EMPTY, CFG.replace(d_safe1=13.0))[0]["separation_violations"] == 2
    assert episode_metrics(traj, EMPTY, CFG.replace(d_safe1=3.0))[0]["separation_violations"] == 0


def test_separation_along_the_path_catches_a_mid_slot_crossing():
    # The UAVs swap places: 40 m apart at both slot times, they meet in the middle of the slot.
    xy = [[[-70.0, -20.0], [-70.0, 20.0]], [[-70.0, 20.0], [-70.0, -20.0]]]
    traj = make_traj(xy)
    q = slot_quantities(traj, EMPTY, CFG)
    np.testing.assert_allclose(q.separation, [[40.0, 40.0]])
    np.testing.assert_allclose(q.separation_path, [[0.0, 0.0]], atol=1e-9)
    for m in episode_metrics(traj, EMPTY, CFG):
        assert m["min_separation"] == pytest.approx(0.0, abs=1e-9)
        assert m["separation_violations"] == 1


def test_separation_exactly_d_safe1_is_allowed_and_three_uavs():
    d = CFG.d_safe1
    xy = [[[-70.0, 0.0], [-70.0, d], [-70.0, 40.0]], [[-71.0, 0.0], [-71.0, d], [-71.0, 30.0]]]
    traj = make_traj(xy)
    q = slot_quantities(traj, EMPTY, CFG)
    np.testing.assert_allclose(q.separation, [[d, d, 30.0 - d]])
    ms = episode_metrics(traj, EMPTY, CFG)
    assert [m["separation_violations"] for m in ms] == [0, 0, 0]
    assert [m["min_separation"] for m in ms] == pytest.approx([d, d, 30.0 - d])


def test_single_uav_has_infinite_separation():
    traj = make_traj([[[-70.0, 0.0]], [[-71.0, 0.0]]])
    q = slot_quantities(traj, EMPTY, CFG)
    assert np.isinf(q.separation).all() and np.isinf(q.separation_path).all()
    m = episode_metrics(traj, EMPTY, CFG)[0]
    assert m["min_separation"] == math.inf and m["separation_violations"] == 0


# ----------------------------------------------------------------------------- terrain, speed, flags, time
def test_terrain_clearance_and_violations():
    hill = Polytope.prism([[-40.0, 20.0], [-30.0, 20.0], [-30.0, 30.0], [-40.0, 30.0]], 75.0)
    world = Terrain([BOX, hill])
    top = hill.highest_point                                     # (-40, 20, 75): dz = 5 m below the UAVs
    np.testing.assert_allclose(top, [-40.0, 20.0, 75.0])
    ends = [top[:2], top[:2] + [8.0, 0.0], top[:2] + [9.0, 0.0], [-60.0, -30.0]]
    xy = np.array([[-70.0, 0.0]] + ends)[:, None]
    q = slot_quantities(make_traj(xy), world, CFG)
    box_top = BOX.highest_point
    far = math.hypot(math.dist([-60.0, -30.0], box_top[:2]), CFG.altitude - box_top[2])
    far = min(far, math.hypot(math.dist([-60.0, -30.0], top[:2]), 5.0))
    np.testing.assert_allclose(q.terrain_clearance[:, 0], [5.0, math.sqrt(89.0), math.sqrt(106.0), far], rtol=1e-12)
    assert episode_metrics(make_traj(xy), world, CFG)[0]["terrain_violations"] == 2
    assert np.isinf(slot_quantities(make_traj(xy), EMPTY, CFG).terrain_clearance).all()
    assert episode_metrics(make_traj(xy), EMPTY, CFG)[0]["terrain_violations"] == 0


def test_speed_violations_infeasible_slots_and_decision_time():
    xy = np.array([[-70.0, 0.0], [-70.0, 1.0], [-70.0, 2.0], [-70.0, 3.0]])[:, None]
    xy2 = np.concatenate([xy, xy + [0.0, 40.0]], axis=1)
    traj = make_traj(xy2,
                     max_speed=[[50.0, 10.0], [50.5, 10.0], [40.0, 10.0]],
                     max_turn_rate=[[3.0, 0.0], [0.0, 0.0], [3.2, 3.0]],
                     infeasible=[[True, False], [False, False], [True, False]],
                     decision_time=[[0.010, np.nan], [0.030, np.nan], [np.nan, np.nan]])
    m0, m1 = episode_metrics(traj, EMPTY, CFG)
    assert m0["speed_violations"] == 2 and m1["speed_violations"] == 0   # the limits themselves are allowed
    assert m0["infeasible_slots"] == 2 and m1["infeasible_slots"] == 0
    assert m0["decision_time_ms"] == pytest.approx(20.0)                 # NaN slots are not counted
    assert math.isnan(m1["decision_time_ms"])
    for m in (m0, m1):
        assert isinstance(m["speed_violations"], int) and isinstance(m["infeasible_slots"], int)


def test_metrics_are_per_uav():
    # UAV 0 ends behind the box and out of the zone; UAV 1 is fine throughout.
    xy = [[[-60.0, 30.0], [-70.0, -40.0]], [[-60.0, 0.0], [-72.0, -42.0]]]
    m0, m1 = episode_metrics(make_traj(xy), WORLD, CFG)
    assert m0["occlusion_rate"] == 1.0 and m1["occlusion_rate"] == 0.0
    assert m0["zone_violation_rate"] == 0.0 and m1["zone_violation_rate"] == 1.0


def test_precomputed_quantities_give_the_same_metrics():
    xy = [[[-60.0, -30.0], [-80.0, 0.0]], [[-60.0, 30.0], [-81.0, 0.0]], [[-61.0, 0.0], [-82.0, 20.0]]]
    traj = make_traj(xy)
    q = slot_quantities(traj, WORLD, CFG)
    a = episode_metrics(traj, WORLD, CFG)
    b = episode_metrics(traj, WORLD, CFG, quantities=q)
    for ma, mb in zip(a, b, strict=True):
        assert ma.keys() == mb.keys()
        for key in ma:
            assert ma[key] == mb[key] or (math.isnan(ma[key]) and math.isnan(mb[key])), key
    assert a[0]["occlusion_rate_path"] == 1.0 and a[0]["occlusion_rate"] == 0.5


# ----------------------------------------------------------------------------- engine agreement
def test_engine_last_quantities_is_the_last_row_of_the_full_evaluation():
    scenario = Scenario.paper()
    e = Engine(scenario, path_samples=9)
    rng = np.random.default_rng(1)
    c = scenario.config
    rows = []
    for _ in range(8):
        ctl = np.column_stack([rng.uniform(5, c.v_max, 3), rng.uniform(-c.w_max, c.w_max, 3)])
        returned = e.step(unicycle=ctl)
        last = e.last_quantities()
        full = slot_quantities(e.trajectory(), scenario.terrain, c)
        for name in ("los", "los_path", "in_zone", "alpha", "d", "kappa", "g", "path_length", "separation",
                     "separation_path", "terrain_clearance"):
            np.testing.assert_allclose(np.asarray(getattr(last, name), float),
                                       np.asarray(getattr(full, name), float)[-1:], rtol=1e-12, atol=1e-12,
                                       err_msg=name)
            np.testing.assert_array_equal(getattr(returned, name), getattr(last, name), err_msg=name)
        rows.append(last.g[0])
    full = slot_quantities(e.trajectory(), scenario.terrain, c)
    np.testing.assert_allclose(np.array(rows), full.g, rtol=1e-12)
    m = episode_metrics(e.trajectory(), scenario.terrain, c)
    assert [x["speed_violations"] for x in m] == [0, 0, 0]
    assert [x["objective"] for x in m] == pytest.approx(full.g.sum(axis=0).tolist(), rel=1e-12)


def test_blocked_path_share_against_a_dense_resampling_of_the_flown_path():
    """The share of each slot's path with blocked LoS: equal to a per-sample loop of line_of_sight at the recorded
    samples, in [0, 1], positive exactly where los_path is False; and the DP team's episode sampled at 11 and at
    201 points per slot (the same flight: the planner does not read the samples) gives nearly the same share."""
    from baselines.policies import make_policy, run_episode
    from covert_env.envs.covert_sensing import CovertSensingParallelEnv
    from covert_env.world.metrics import slot_quantities
    from covert_env.world.visibility import line_of_sight

    shares = {}
    for samples in (11, 201):
        env = CovertSensingParallelEnv(family="downtown", action_mode="waypoint", path_samples=samples)
        run_episode(make_policy("dp"), env, seed=1_000_002, options={"scene_seed": 1_000_002})
        traj, terrain, c = env.engine.trajectory(), env.scenario.terrain, env.config
        q = slot_quantities(traj, terrain, c)
        shares[samples] = q.blocked_path_share
        assert ((q.blocked_path_share > 0) == ~q.los_path.astype(bool)).all()
        assert (0 <= q.blocked_path_share).all() and (q.blocked_path_share <= 1).all()
        if samples == 11:
            for t in range(0, traj.n_slots, 7):
                for u in range(traj.n_uavs):
                    clear = [line_of_sight(terrain, traj.path_xy[t, u, j], c.altitude, traj.target_path_xyz[t, j])
                             for j in range(1, samples)]
                    assert q.blocked_path_share[t, u] == pytest.approx(1.0 - np.mean(clear), abs=1e-12)
    assert shares[201].mean() > 0.01                         # downtown: the DP team loses LoS between slots
    assert abs(shares[11].mean() - shares[201].mean()) < 0.02
    assert np.abs(shares[11] - shares[201]).max() < 0.25
