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
from covert_env.geometry.dynamics import solve_manoeuvre, unicycle_step
from covert_env.geometry.zone import to_world

CFG = Config(n_slots=8)


@pytest.mark.parametrize("cfg", [CFG, CFG.replace(prediction_error=4.0, r_u=4.0)], ids=["exact", "deviating"])
def test_dp_policy_through_the_waypoint_env_reproduces_the_reproduce_trajectory(cfg):
    """Same scene, same planner: the PettingZoo rollout and `covert-env reproduce`'s rollout coincide, also when the
    target deviates from its prediction (the env's waypoints are about the predicted next pose, as the planner's;
    about the true one they were up to 50 m off)."""
    ref = rollout(make_scenario("paper", 0, 3, cfg))["trajectory"]
    env = covert_env.parallel_env(config=cfg, n_uavs=3, scenario="paper", action_mode="waypoint")
    res = run_episode(DPPolicy(), env, seed=0)
    np.testing.assert_array_equal(res["trajectory"].uav_xy, ref.uav_xy)
    np.testing.assert_array_equal(res["trajectory"].uav_theta, ref.uav_theta)
    assert res["steps"] == cfg.n_slots


def test_dp_policy_through_the_gymnasium_waypoint_env_on_a_heldout_scene():
    seed = HELDOUT_SEED_BASE + 3
    ref = rollout(make_scenario("random", seed, 1, CFG), shadow_aware=False)["trajectory"]
    env = gym.make("covert_env/CovertSensingWaypoint-v4", config=CFG)
    res = run_episode(DPPolicy(shadow_aware=False), env, seed=0, options={"scene_seed": seed})
    np.testing.assert_array_equal(res["trajectory"].uav_xy, ref.uav_xy)


def test_dp_policy_in_unicycle_mode_keeps_the_target_in_sight():
    """Flying arcs toward the planned waypoints still keeps line of sight at every slot of the paper scene,
    separated. arc_action flies another path than the planned manoeuvre (its documented losses), so a UAV
    may end a slot just outside the zone: at most one slot in ten."""
    cfg = Config(n_slots=20)
    env = covert_env.parallel_env(config=cfg, n_uavs=3, scenario="paper", action_mode="unicycle")
    res = run_episode(DPPolicy(), env, seed=0)
    traj = res["trajectory"]
    assert not traj.infeasible.any()
    for m in res["metrics"]:
        assert m["occlusion_rate"] == 0.0 and m["separation_violations"] == 0 and m["zone_violation_rate"] <= 0.1


def test_gymnasium_actions_are_single_actions_in_the_action_space():
    for env_id in ("covert_env/CovertSensingWaypoint-v4", "covert_env/CovertSensing-v4"):
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


def test_random_waypoints_follow_the_mask_and_are_flown_without_fallback():
    """Random waypoints are drawn from the action mask: whenever some node is reachable the drawn one is, and
    the engine flies it exactly (no fallback flag). A UAV the random flight left with no reachable node (the
    mask is then all ones) is the only flagged case."""
    env = covert_env.parallel_env(config=CFG, n_uavs=2, scenario="paper", action_mode="waypoint")
    obs, _ = env.reset(seed=5)
    pol = RandomPolicy()
    pol.reset(env, seed=5)
    c = env.config
    flown = 0
    while env.agents:
        eng = env.engine
        q1, phi1 = eng.predict(1)
        goals = to_world(env.lattice, q1[0, :2], float(phi1[0]))
        reach = solve_manoeuvre(eng.uav_xy[:, None], eng.uav_theta[:, None], goals[None], v_max=c.v_max,
                                w_max=c.w_max, delta=c.delta).feasible
        act = pol.act(obs, env)
        obs, _, _, _, info = env.step(act)
        for i, a in enumerate(env.possible_agents):
            if reach[i].any():
                assert reach[i, act[a]] and not info[a]["infeasible"]
                flown += 1
            else:
                assert info[a]["infeasible"]
    assert flown >= 2 * CFG.n_slots - 2


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


def test_the_registry_names_every_built_in_policy_and_prefix():
    """The entry point group covert_env.policies holds the built-in names (and aliases) of baselines.policies and the
    file prefixes of training, and nothing else."""
    from baselines.policies import ALIASES, POLICIES
    from covert_env.evaluation.registry import registered_policies, spec_forms

    assert set(registered_policies()) == {*POLICIES, *ALIASES, "sb3", "rllib", "mappo", "pretrained"}
    assert spec_forms() == [*sorted([*POLICIES, *ALIASES]), "mappo:PATH", "pretrained:NAME", "rllib:PATH", "sb3:PATH"]


@pytest.mark.parametrize("spec", ["oracle", "sb3", "dp:runs/a", "nope:x", "oracle@waypoint+shield"])
def test_an_unknown_spec_lists_the_registered_forms(spec):
    from covert_env.command_line import UsageError
    from covert_env.evaluation.specs import load_policy

    bare = spec.removesuffix("+shield").split("@")[0]
    with pytest.raises(UsageError, match=rf"unknown policy '{bare}'; use one of dp, dp-binned, .*, random, "
                                         r"mappo:PATH, pretrained:NAME, rllib:PATH or sb3:PATH$"):
        load_policy(spec, 3)


def test_a_registered_policy_loads_through_its_spec(monkeypatch):
    """A package adds a policy by declaring an entry point; the spec grammar (@MODE, +shield, seed groups, team
    size) applies to it as to the built-in ones."""
    import types

    from covert_env.command_line import UsageError
    from covert_env.envs.safety_filter import ShieldedPolicy
    from covert_env.evaluation import registry, specs

    def mine(spec, n_uavs, *, trust_checkpoint=False):
        return RandomPolicy(), {"n_uavs": 2, "action_mode": "waypoint", "source": spec}

    mine.argument = "PATH"
    monkeypatch.setattr(registry, "registered_policies",
                        lambda: {"mine": types.SimpleNamespace(load=lambda: mine)})
    pol, settings = specs.load_policy("mine:a/b+shield", 2)
    assert isinstance(pol, ShieldedPolicy) and settings == {"n_uavs": 2, "action_mode": "waypoint",
                                                            "source": "mine:a/b"}
    assert specs.split_seeds("mine:a,b@waypoint") == ["mine:a@waypoint", "mine:b@waypoint"]
    with pytest.raises(UsageError, match="mine:a was trained in waypoint mode; it cannot act in unicycle mode"):
        specs.load_policy("mine:a@unicycle", 2)
    with pytest.raises(UsageError, match="mine:a acts for teams of 2 UAV"):
        specs.load_policy("mine:a", 3)
    with pytest.raises(UsageError, match="unknown policy 'dp'; use one of mine:PATH$"):
        specs.load_policy("dp", 3)
    monkeypatch.setattr(registry, "registered_policies", dict)
    with pytest.raises(UsageError, match="no policy is registered .*covert_env.policies.*pip install -e"):
        specs.load_policy("dp", 3)


def _team_actions(env, pol, seed: int, scene_seed: int, after_act=None) -> list[list[int]]:
    """Every slot's actions of ``pol`` over one episode of ``env`` (scene ``scene_seed``), in agent order."""
    obs, _ = env.reset(seed=seed, options={"scene_seed": scene_seed})
    pol.reset(env, seed)
    acts = []
    while env.agents:
        a = pol.act(obs, env)
        acts.append([a[x] for x in env.possible_agents])
        if after_act is not None:
            after_act(pol)
        obs, *_ = env.step(a)
    return acts


def test_dp_policy_horizon_plans_over_fewer_slots():
    """``DPPolicy(horizon=h)`` plans over the first h predicted slots: h = config.horizon is the paper's planner,
    action for action; h = 1 plans one slot; bad values fail naming the value."""
    env = covert_env.parallel_env(task="paper-3uav", action_mode="waypoint", max_cycles=3)
    runs = {}
    for h in (None, env.config.horizon, 1):
        def planned(pol, h=h):
            assert len(pol.last_plan.plans[0].nodes) == (h or env.config.horizon)

        runs[h] = _team_actions(env, DPPolicy(horizon=h), 2, 2, after_act=planned)
    assert runs[None] == runs[env.config.horizon]
    assert DPPolicy(horizon=1).name.endswith("-horizon1")
    for bad in (0, True, 2.5):
        with pytest.raises(ValueError, match=r"horizon must be None or an integer >= 1"):
            DPPolicy(horizon=bad)
    pol = DPPolicy(horizon=env.config.horizon + 1)
    obs, _ = env.reset(seed=2)
    with pytest.raises(ValueError, match=r"horizon 6 is longer than the env's config.horizon 5"):
        pol.act(obs, env)
    team = DPPolicy()._team(env)
    for bad in (0, 6):
        with pytest.raises(ValueError, match=r"plan_engine: horizon must be in \[1, config.horizon = 5\]"):
            team.plan_engine(env.engine, bad)
    path_team = DPPolicy(check_path=True, horizon=2)              # the path checks follow the shorter prediction
    path_team.act(obs, env)
    assert len(path_team.last_plan.plans[0].nodes) == 2
    env.close()


def test_extrapolate_target_keeps_the_known_slots_and_then_step_and_turn():
    """extrapolate_target: the known predicted poses unchanged; then the last known step, turned by the last known
    turn once more every slot (a straight target stays on its line; a turning one on its circle); bad counts fail."""
    from baselines.dp.team import extrapolate_target

    q0, phi0 = np.array([0.0, 0.0, 1.5]), 0.0
    straight = np.array([[10.0, 0.0, 1.5], [20.0, 0.0, 1.5]])
    q, phi = extrapolate_target(q0, phi0, straight[:1], np.zeros(1), 5)
    np.testing.assert_allclose(q, [[10.0 * j, 0.0, 1.5] for j in range(1, 6)], atol=1e-12)
    assert np.array_equal(phi, np.zeros(5))
    # A circle of radius r at angular step w: every extrapolated pose lies on it, headings advance by w.
    r, w = 50.0, 0.2
    pose = [np.array([r * np.sin(w * j), r * (1 - np.cos(w * j)), 1.5]) for j in range(6)]
    q, phi = extrapolate_target(pose[0], 0.0, np.array(pose[1:3]), np.array([w, 2 * w]), 5)
    np.testing.assert_allclose(q[:2], pose[1:3], atol=1e-12)
    np.testing.assert_allclose(q, pose[1:], atol=1e-9)
    np.testing.assert_allclose(phi, w * np.arange(1, 6), atol=1e-12)
    for qk, pk in ((np.zeros((0, 3)), np.zeros(0)), (np.zeros((6, 3)), np.zeros(6)),
                   (np.zeros((2, 3)), np.zeros(1)), (np.zeros((2, 2)), np.zeros(2))):
        with pytest.raises(ValueError, match=r"q_known \(k, 3\) and phi_known \(k,\) must hold the same k known "
                                             r"slots, 1 <= k <= horizon = 5, got shapes"):
            extrapolate_target(q0, phi0, qk, pk, 5)


def test_dp_policy_known_slots_reads_only_the_first_slots():
    """DPPolicy(known_slots=N) is the paper's planner action for action; with known_slots=1 the planner is handed
    the track's first predicted slot and then extrapolate_target's poses, which leave the track where the road
    bends; bad values and deviating targets fail naming the value."""
    from baselines.dp.team import DPTeamPlanner, extrapolate_target

    env = covert_env.parallel_env(task="winding-3uav", action_mode="waypoint", max_cycles=4)
    runs = {k: _team_actions(env, DPPolicy(known_slots=k), 3, 1_000_003) for k in (None, env.config.horizon, 1)}
    assert runs[None] == runs[env.config.horizon] and len(runs[1]) == 4
    assert DPPolicy(known_slots=1).name.endswith("-known1")
    handed = []
    real_plan = DPTeamPlanner.plan

    def spy(self, xy, theta, tq, tp, **kw):
        handed.append((tq.copy(), tp.copy()))
        return real_plan(self, xy, theta, tq, tp, **kw)

    obs, _ = env.reset(seed=3, options={"scene_seed": 1_000_003})
    team = DPPolicy()._team(env)
    try:
        DPTeamPlanner.plan = spy
        team.plan_engine(env.engine, known_slots=1)
        team.plan_engine(env.engine)
    finally:
        DPTeamPlanner.plan = real_plan
    (tq1, tp1), (tq, tp) = handed
    eng = env.engine
    want_q, want_p = extrapolate_target(eng.target_xyz, eng.target_phi, tq[1:2], tp[1:2], env.config.horizon)
    np.testing.assert_array_equal(tq1[:2], tq[:2])
    np.testing.assert_allclose(tq1[1:], want_q, atol=1e-12)
    np.testing.assert_allclose(tp1[1:], want_p, atol=1e-12)
    assert np.abs(tq1[2:, :2] - tq[2:, :2]).max() > 0.1          # the winding road bends within five slots
    for bad in (0, -2, True, 1.5):
        with pytest.raises(ValueError, match=r"plan_engine: known_slots must be None or an integer >= 1"):
            team.plan_engine(env.engine, known_slots=bad)
    with pytest.raises(ValueError, match=r"known_slots 3 is more than the horizon 2"):
        DPPolicy(horizon=2, known_slots=3)
    with pytest.raises(ValueError, match=r"known_slots 6 is more than the env's config.horizon 5"):
        DPPolicy(known_slots=6).act(obs, env)
    for bad in (0, True, 1.5):
        with pytest.raises(ValueError, match=r"known_slots must be None or an integer >= 1"):
            DPPolicy(known_slots=bad)
    with pytest.raises(ValueError, match=r"known_slots does not go with check_path"):
        DPPolicy(known_slots=1, check_path=True)
    dev = covert_env.parallel_env(task="paper-3uav-deviating", action_mode="waypoint", max_cycles=2)
    obs, _ = dev.reset(seed=0)
    with pytest.raises(ValueError, match=r"known_slots needs a target without prediction error, got "
                                         r"config.prediction_error = 4"):
        DPPolicy(known_slots=1).act(obs, dev)


def test_dp_horizon_benchmark_terms_add_up_to_the_reward():
    """benchmarks/dp_horizon.py's episode: the reward per UAV is the sum of its terms (path cost, disguise bonus,
    penalties), and the learned team's row runs through the harness's loader."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "dp_horizon.py"
    spec = importlib.util.spec_from_file_location("dp_horizon", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    row = mod.episode_terms("dp-h2", "paper-3uav", 1_000_000)
    assert row["reward"] == pytest.approx(sum(row[t] for t in mod.TERMS), abs=1e-6)
    assert row["disguise"] > 0 > row["path"]
    learned = mod.episode_terms("pretrained:mappo", "paper-3uav", 1_000_000)
    assert learned["reward"] == pytest.approx(sum(learned[t] for t in mod.TERMS), abs=1e-6)
    with pytest.raises(SystemExit):
        mod.main(["--scenes", "0"])
    known = mod.episode_terms("dp-h5-k1", "paper-3uav", 1_000_000)
    assert known["reward"] == pytest.approx(sum(known[t] for t in mod.TERMS), abs=1e-6)
    for argv in (["--known-slots", "5"], ["--known-slots", "1", "--tasks", "paper-3uav-deviating"]):
        with pytest.raises(SystemExit):
            mod.main(argv)
