"""baselines.policies: one interface for the DP planner, random and heuristic policies in the envs."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import covert_env
from baselines.policies import (
    DPPolicy,
    HoldZoneCentrePolicy,
    RandomPolicy,
    arc_action,
    make_policy,
    parallel_env_of,
    run_episode,
)
from baselines.reproduce import HELDOUT_SEED_BASE, make_scenario, rollout
from covert_env import Config
from covert_env.dynamics import unicycle_step

CFG = Config(n_slots=8)


def test_dp_policy_through_the_waypoint_env_reproduces_the_reproduce_trajectory():
    """Same scene, same planner: the PettingZoo rollout and `covert-env reproduce`'s rollout coincide."""
    ref = rollout(make_scenario("paper", 0, 3, CFG))["trajectory"]
    env = covert_env.parallel_env(config=CFG, n_uavs=3, scenario="paper", action_mode="waypoint")
    res = run_episode(DPPolicy(), env, seed=0)
    np.testing.assert_array_equal(res["trajectory"].uav_xy, ref.uav_xy)
    np.testing.assert_array_equal(res["trajectory"].uav_theta, ref.uav_theta)
    assert res["steps"] == CFG.n_slots


def test_dp_policy_through_the_gymnasium_waypoint_env_on_a_heldout_scene():
    seed = HELDOUT_SEED_BASE + 3
    ref = rollout(make_scenario("random", seed, 1, CFG), shadow_aware=False)["trajectory"]
    env = gym.make("covert_env/CovertSensingWaypoint-v1", config=CFG)
    res = run_episode(DPPolicy(shadow_aware=False), env, seed=0, options={"scene_seed": seed})
    np.testing.assert_array_equal(res["trajectory"].uav_xy, ref.uav_xy)


def test_dp_policy_in_unicycle_mode_stays_within_limits_and_keeps_the_target():
    env = covert_env.parallel_env(config=CFG, n_uavs=3, scenario="paper", action_mode="unicycle")
    res = run_episode(DPPolicy(), env, seed=0)
    traj = res["trajectory"]
    assert np.all(traj.max_speed <= CFG.v_max + 1e-9) and np.all(traj.max_turn_rate <= CFG.w_max + 1e-9)
    for m in res["metrics"]:
        assert m["zone_violation_rate"] <= 0.25 and m["occlusion_rate"] <= 0.25 and m["separation_violations"] == 0


def test_gymnasium_actions_are_single_actions_in_the_action_space():
    for env_id in ("covert_env/CovertSensingWaypoint-v1", "covert_env/CovertSensing-v1"):
        env = gym.make(env_id, scenario="paper", config=CFG)
        obs, _ = env.reset(seed=0)
        par, agent = parallel_env_of(env)
        assert agent == "uav_0" and par is env.unwrapped.par
        for pol in (DPPolicy(), RandomPolicy(), HoldZoneCentrePolicy()):
            pol.reset(env, seed=0)
            act = pol.act(obs, env)
            assert env.action_space.contains(np.asarray(act, dtype=env.action_space.dtype)
                                             if env.action_space.shape else int(act))


@pytest.mark.parametrize("mode", ["waypoint", "unicycle"])
def test_random_and_heuristic_policies_run_and_are_seeded(mode):
    for cls in (RandomPolicy, HoldZoneCentrePolicy):
        runs = []
        for _ in range(2):
            env = covert_env.parallel_env(config=CFG, n_uavs=2, scenario="paper", action_mode=mode)
            runs.append(run_episode(cls(), env, seed=5)["trajectory"].uav_xy)
        np.testing.assert_array_equal(runs[0], runs[1])
    # Random waypoints respect the action mask: every flown move is reachable (no fallback flight).
    env = covert_env.parallel_env(config=CFG, n_uavs=2, scenario="paper", action_mode="waypoint")
    traj = run_episode(RandomPolicy(), env, seed=5)["trajectory"]
    assert np.all(traj.max_speed <= CFG.v_max + 1e-9)


def test_hold_centre_stays_in_the_zone_with_little_disguise():
    env = covert_env.parallel_env(config=CFG, n_uavs=1, scenario="paper", action_mode="waypoint")
    hold = run_episode(HoldZoneCentrePolicy(), env, seed=0)["metrics"][0]
    env = covert_env.parallel_env(config=CFG, n_uavs=1, scenario="paper", action_mode="waypoint")
    dp = run_episode(DPPolicy(), env, seed=0)["metrics"][0]
    assert hold["zone_violation_rate"] == 0.0
    assert hold["mean_disguise"] < 0.5 * dp["mean_disguise"]


def test_arc_action_lands_on_reachable_goals():
    """Holding the mapped (v, omega) for one slot flies the arc through the goal (when within the limits)."""
    c = Config()
    rng = np.random.default_rng(1)
    for _ in range(200):
        th = rng.uniform(0, 2 * np.pi)
        beta = rng.uniform(-1.4, 1.4)
        chord = rng.uniform(5, 40)
        goal = np.array([chord * np.cos(th + beta), chord * np.sin(th + beta)])
        a = arc_action(np.zeros(2), th, goal, c).astype(float)
        v = c.v_max * (0.01 + 0.99 * (a[0] + 1) / 2)
        if a[0] >= 1.0 - 1e-6:
            continue                                   # needs more than V_max: clipped, documented loss
        x, y, _ = unicycle_step(0.0, 0.0, th, v, c.w_max * a[1], c.delta)
        assert np.hypot(x - goal[0], y - goal[1]) < 1e-3


def test_make_policy_names():
    assert make_policy("dp").name == "dp-aware-inherited"
    assert make_policy("dp-blind").name == "dp-blind-inherited"
    assert make_policy("dp-binned").name == "dp-aware-binned16"
    assert make_policy("random").name == "random"
    assert make_policy("hold-centre").name == "hold-centre"
    with pytest.raises(ValueError, match="unknown policy"):
        make_policy("oracle")
    with pytest.raises(TypeError):
        parallel_env_of(object())
