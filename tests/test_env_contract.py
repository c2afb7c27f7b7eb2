"""What frameworks and users rely on: flat infos with the same keys at reset and step, constraint costs, one place
for the action mask, PettingZoo's whole battery at its default arguments, max_cycles, no leaks, clear errors."""

from __future__ import annotations

import functools
import gc
import weakref
from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest
from pettingzoo.test import (
    api_test,
    max_cycles_test,
    parallel_api_test,
    parallel_seed_test,
    performance_benchmark,
    render_test,
    seed_test,
)

import covert_env
from covert_env import covert_sensing_v4

MODES = ("unicycle", "waypoint")
TERMS = ("path", "disguise", "los", "los_path", "zone", "separation", "terrain")
COSTS = ("los", "los_path", "zone", "separation", "terrain")


def _actions(env, obs, infos):
    acts = {}
    for a in env.agents:
        mask = env.action_mask(a) if env.action_mode == "waypoint" else None
        acts[a] = env.action_space(a).sample(mask)
    return acts


def _signature(info: dict) -> dict:
    """Key -> type, with arrays as (dtype, shape): what TorchRL infers an info spec from."""
    return {k: (v.dtype, v.shape) if isinstance(v, np.ndarray) else type(v) for k, v in info.items()}


# ---------------------------------------------------------------------- infos
@pytest.mark.parametrize("mode, dict_obs", [("unicycle", False), ("waypoint", False), ("waypoint", True)])
def test_infos_flat_and_same_at_reset_and_every_step(mode, dict_obs):
    env = covert_env.parallel_env(n_uavs=3, action_mode=mode, dict_obs=dict_obs, max_cycles=8)
    obs, infos = env.reset(seed=3)
    ref = _signature(infos["uav_0"])
    scalars = {k for k, t in ref.items() if not isinstance(t, tuple)}
    assert scalars >= {"slot", "los", "in_zone", "infeasible", "kappa", "g", "v", "separation", "terrain_clearance",
                       "cost", *(f"reward_{t}" for t in TERMS), *(f"cost_{c}" for c in COSTS)}
    assert all(t in (int, float, bool) for k, t in ref.items() if k in scalars)
    assert ("action_mask" in ref) == (mode == "waypoint" and not dict_obs)
    assert all(infos[a][f"reward_{t}"] == 0.0 and infos[a]["cost"] == 0.0 for a in env.agents for t in TERMS)
    steps = 0
    while env.agents:
        obs, rew, _, _, infos = env.step(_actions(env, obs, infos))
        steps += 1
        for a in env.possible_agents:
            assert _signature(infos[a]) == ref
            assert rew[a] == pytest.approx(sum(infos[a][f"reward_{t}"] for t in TERMS))
            if dict_obs:
                assert np.array_equal(obs[a]["action_mask"], env.action_mask(a))
            elif mode == "waypoint":
                assert np.array_equal(infos[a]["action_mask"], env.action_mask(a))
    assert steps == 8


def test_reset_infos_describe_the_starts():
    env = covert_env.parallel_env(n_uavs=3, scenario="paper")
    obs, infos = env.reset(seed=0)
    xy = env.engine.uav_xy
    d = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1)) + np.diag([np.inf] * 3)
    for i, a in enumerate(env.agents):
        assert infos[a]["separation"] == pytest.approx(d[i].min())
        assert infos[a]["los"] == bool(obs[a][5]) and infos[a]["in_zone"] == bool(obs[a][6])
        tops = env.scenario.terrain.highest_points
        clearance = np.sqrt(((tops[:, :2] - xy[i]) ** 2).sum(1) + (80.0 - tops[:, 2]) ** 2).min()
        assert infos[a]["terrain_clearance"] == pytest.approx(clearance)


# ---------------------------------------------------------------------- costs
def test_costs_are_the_constraint_violations():
    # Two UAVs on top of each other, one far outside the zone: separation and zone violated.
    paper = covert_env.Scenario.paper()
    starts = covert_env.Scenario(paper.config, paper.terrain, paper.track, [[50.0, 0.0], [50.5, 0.0], [300.0, 300.0]],
                                 [0.0, 0.0, 0.0])
    env = covert_env.parallel_env(scenario=starts, los_penalty=0.0, los_path_penalty=0.0, zone_penalty=0.0,
                                  separation_penalty=0.0, terrain_penalty=0.0)
    env.reset(seed=0)
    seen = {c: 0.0 for c in COSTS}
    for _ in range(6):
        _, rew, _, _, infos = env.step({a: np.array([-0.9, 0.0]) for a in env.agents})
        for a in env.agents:
            info = infos[a]
            c = env.config
            assert info["cost_los"] == float(not info["los"])
            assert 0.0 <= info["cost_los_path"] <= 1.0 and (info["cost_los_path"] == 0.0) == info["los_path"]
            assert info["cost_zone"] == float(not info["in_zone"])
            assert info["cost_separation"] == float(info["separation"] < c.d_safe1)
            assert info["cost_terrain"] == float(info["terrain_clearance"] < c.d_safe2)
            assert info["cost"] == sum(info[f"cost_{k}"] for k in COSTS)
            # Penalties are 0: the reward is the stage cost alone, whatever the costs.
            assert rew[a] == pytest.approx(-info["g"] / 100.0)
            for k in COSTS:
                seen[k] += info[f"cost_{k}"]
    assert seen["separation"] >= 2 and seen["zone"] >= 1


def test_gymnasium_env_exposes_the_same_infos():
    genv = gym.make("covert_env/CovertSensing-v4", max_cycles=3)
    _, info0 = genv.reset(seed=1)
    _, _, _, _, info1 = genv.step(genv.action_space.sample())
    assert _signature(info0) == _signature(info1)
    assert "cost" in info1 and "reward_disguise" in info1


# ---------------------------------------------------------------------- PettingZoo's battery, default arguments
@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("u", [1, 3])
def test_pettingzoo_battery_default_arguments(mode, u):
    parallel_api_test(covert_env.parallel_env(n_uavs=u, action_mode=mode))
    api_test(covert_env.env(n_uavs=u, action_mode=mode))
    seed_test(lambda: covert_env.env(n_uavs=u, action_mode=mode))
    parallel_seed_test(lambda: covert_env.parallel_env(n_uavs=u, action_mode=mode))


def test_pettingzoo_battery_dict_obs_default_arguments():
    parallel_api_test(covert_env.parallel_env(n_uavs=3, action_mode="waypoint", dict_obs=True))
    api_test(covert_env.env(n_uavs=3, action_mode="waypoint", dict_obs=True))


@pytest.mark.slow
@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("u", [1, 3])
def test_max_cycles_render_and_performance_default_arguments(mode, u):
    # max_cycles_test takes a module exposing env() and parallel_env(); this one fixes the mode and team size.
    module = SimpleNamespace(env=functools.partial(covert_sensing_v4.env, action_mode=mode, n_uavs=u),
                             parallel_env=functools.partial(covert_sensing_v4.parallel_env, action_mode=mode, n_uavs=u))
    max_cycles_test(module)
    render_test(lambda render_mode=None: covert_env.env(action_mode=mode, n_uavs=u, render_mode=render_mode))
    performance_benchmark(covert_env.env(n_uavs=u, action_mode=mode))


def test_max_cycles_validated_on_assignment_and_bounded_by_the_route():
    env = covert_env.parallel_env(n_uavs=2, scenario="paper")
    for bad, exc in ((0, ValueError), (-5, ValueError), (2.5, TypeError), ("100", TypeError), (True, TypeError)):
        with pytest.raises(exc, match="max_cycles must be an integer"):
            env.max_cycles = bad
    env.max_cycles = 1000                     # what parallel_api_test sets: the route still ends at n_slots
    assert env.max_cycles == 1000 and env.episode_length == env.config.n_slots
    obs, _ = env.reset(seed=0)
    assert obs["uav_0"][10] == pytest.approx(1.0)
    n = 0
    while env.agents:
        _, _, term, trunc, _ = env.step({a: np.zeros(2) for a in env.agents})
        n += 1
    assert n == env.config.n_slots and all(trunc.values())
    env.max_cycles = np.int64(5)
    env.reset(seed=0)
    for _ in range(5):
        env.step({a: np.zeros(2) for a in env.agents})
    assert env.agents == []


def test_the_views_live_settings_are_the_vector_envs():
    """The parallel env, the Gymnasium env and a copy read as an engine show the vector env's live settings
    (envs.arguments.Forwarded): what is assigned to a view is the vector env's at once, and the read-only ones
    refuse an assignment by name."""
    env = covert_env.parallel_env(n_uavs=2, scenario="paper")
    env.reward_scale, env.terminate_on_collision = 50.0, True
    env.penalties = {**env.penalties, "los": 3.0}
    vec = env._vec
    assert (vec.reward_scale, vec.terminate_on_collision, vec.penalties["los"]) == (50.0, True, 3.0)
    vec.max_cycles = 7
    assert env.max_cycles == 7 and env.episode_length == 7
    with pytest.raises(AttributeError, match="episode_length is read-only"):
        env.episode_length = 3
    with pytest.raises(ValueError, match="reward_scale must be a finite number"):
        env.reward_scale = 0.0
    genv = gym.make("covert_env/CovertSensing-v4").unwrapped
    genv.max_cycles = 4
    assert genv.par.max_cycles == 4 and genv.config is genv.par.config
    with pytest.raises(AttributeError, match="config is read-only"):
        genv.config = genv.config
    env.reset(seed=0)
    view = env.engine
    assert view.config is env.config and view.path_samples == vec.path_samples
    with pytest.raises(AttributeError, match="path_samples is read-only"):
        view.path_samples = 3


# ---------------------------------------------------------------------- no leaks
def test_closed_env_is_collected():
    env = covert_env.parallel_env(n_uavs=2, action_mode="waypoint", render_mode="rgb_array")
    env.observation_space("uav_0"), env.action_space("uav_0")
    env.reset(seed=0)
    env.step({a: int(np.flatnonzero(env.action_mask(a))[0]) for a in env.agents})
    env.render()
    env.close()
    ref = weakref.ref(env)
    del env
    gc.collect()
    assert ref() is None

    genv = gym.make("covert_env/CovertSensing-v4", max_cycles=2)
    genv.reset(seed=0)
    genv.step(genv.action_space.sample())
    genv.close()
    ref = weakref.ref(genv.unwrapped)
    del genv
    gc.collect()
    assert ref() is None


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096 / 2 ** 20


@pytest.mark.slow
@pytest.mark.skipif(not __import__("os").path.exists("/proc/self/statm"), reason="needs /proc (Linux)")
def test_rss_flat_over_1000_envs():
    for i in range(1000):
        env = covert_env.parallel_env(n_uavs=3, scenario="paper")
        env.observation_space("uav_0"), env.action_space("uav_0")
        env.reset(seed=i)
        env.step({a: env.action_space(a).sample() for a in env.agents})
        env.close()
        if i == 199:                           # after warm-up: imports, numpy/shapely caches
            gc.collect()
            before = _rss_mb()
    gc.collect()
    assert _rss_mb() < 1.05 * before


# ---------------------------------------------------------------------- bad input at the env's boundary
@pytest.mark.parametrize("kw, exc, pattern", [
    (dict(n_uavs=2.7), TypeError, "n_uavs must be an integer"),
    (dict(n_uavs="3"), TypeError, "n_uavs must be an integer"),
    (dict(n_uavs=True), TypeError, "n_uavs must be an integer"),
    (dict(config="abc"), TypeError, "config must be a covert_env.Config"),
    (dict(config=3), TypeError, "config must be a covert_env.Config"),
    (dict(scenario=5), ValueError, "scenario must be"),
    (dict(action_mode=None), ValueError, "action_mode must be one of"),
    (dict(map_size=8.0), TypeError, "map_size must be an integer"),
    (dict(map_size=65), ValueError, r"map_size must be an integer in \[2, 64\]"),
    (dict(path_samples=10 ** 9), ValueError, r"path_samples must be an integer in \[2, 1000\]"),
    (dict(path_samples=1), ValueError, r"path_samples must be an integer in \[2, 1000\]"),
    (dict(scene_pool=0), ValueError, r"scene_pool must be an integer in \[1, 1000000\]"),
    (dict(scene_pool=1.5), TypeError, "scene_pool must be an integer"),
    (dict(scene_pool=10 ** 30), ValueError, r"scene_pool must be an integer in \[1, 1000000\]"),
    (dict(scene_pool=1_000_001), ValueError, r"scene_pool must be an integer in \[1, 1000000\]"),
    (dict(scenario="paper", n_uavs=4), ValueError, r"scenario='paper' has starts for 3 UAVs, got n_uavs=4"),
    (dict(max_cycles="70"), TypeError, "max_cycles must be an integer"),
    (dict(reward_scale="100"), TypeError, "reward_scale must be a number"),
    (dict(reward_scale=float("nan")), ValueError, "reward_scale must be finite"),
    (dict(reward_scale=1e-320), ValueError, r"reward_scale must be a finite number in \[1e-06, 1e\+12\]"),
    (dict(config=dict(eta=1e308)), ValueError, r"Config.eta must be <= 1e\+06"),
    (dict(config=dict(lam=1e7)), ValueError, r"Config.lam must be <= 1e\+06"),
    (dict(los_penalty=True), TypeError, "los_penalty must be a number"),
    (dict(terrain_penalty=float("inf")), ValueError, "terrain_penalty must be finite"),
    (dict(terminate_on_collision="yes"), TypeError, "terminate_on_collision must be True or False"),
    (dict(random_starts=1), TypeError, "random_starts must be True or False"),
    (dict(dict_obs="no"), TypeError, "dict_obs must be True or False"),
    (dict(dict_obs=True), ValueError, "dict_obs=True needs action_mode='waypoint'"),
])
def test_bad_env_arguments(kw, exc, pattern):
    with pytest.raises(exc, match=pattern):
        covert_env.parallel_env(**kw)


def test_integer_like_arguments_accepted():
    env = covert_env.parallel_env(n_uavs=np.int64(2), map_size=np.int32(6), max_cycles=np.int64(3))
    assert env.max_num_agents == 2 and type(env.max_cycles) is int and env.map_size == 6


@pytest.mark.parametrize("actions, exc, pattern", [
    (None, TypeError, r"step\(\) expects a dict"),
    ([np.zeros(2)] * 2, TypeError, r"step\(\) expects a dict"),
    ({"uav_0": np.zeros(2), "uav_1": np.zeros(2), "uav_7": np.zeros(2)}, ValueError, r"unknown agent\(s\) \['uav_7'\]"),
    ({"uav_0": np.zeros(2)}, ValueError, r"missing actions for \['uav_1'\]"),
    ({"uav_0": ["0.1", "0.2"], "uav_1": np.zeros(2)}, TypeError, "action for uav_0 must be 2 numbers"),
    ({"uav_0": True, "uav_1": np.zeros(2)}, TypeError, "action for uav_0 must be 2 numbers"),
    ({"uav_0": np.array([True, False]), "uav_1": np.zeros(2)}, TypeError, "action for uav_0 must be 2 numbers"),
    ({"uav_0": np.zeros(3), "uav_1": np.zeros(2)}, ValueError, r"action for uav_0 must have shape \(2,\)"),
    ({"uav_0": [0.1, [0.2]], "uav_1": np.zeros(2)}, ValueError, r"action for uav_0 must have shape \(2,\)"),
    ({"uav_0": np.zeros(2), "uav_1": [[0.1, 0.2]]}, ValueError, r"action for uav_1 must have shape \(2,\)"),
    ({"uav_0": [0.5, -0.5], "uav_1": (0, 1)}, None, None),
    ({"uav_0": np.zeros(2), "uav_1": [0.0, np.nan]}, ValueError, "action for uav_1 must be finite"),
])
def test_bad_unicycle_actions(actions, exc, pattern):
    env = covert_env.parallel_env(n_uavs=2, scenario="paper")
    env.reset(seed=0)
    if exc is None:                             # plain lists and tuples of numbers are valid actions
        env.step(actions)
        assert np.allclose(env.engine.trajectory().max_speed[-1], [50 * (0.01 + 0.99 * 0.75), 50 * 0.505])
        return
    with pytest.raises(exc, match=pattern):
        env.step(actions)


@pytest.mark.parametrize("bad", [True, "3", 2.5, -1, np.array([1, 2])])
def test_bad_waypoint_actions(bad):
    env = covert_env.parallel_env(n_uavs=1, action_mode="waypoint", scenario="paper")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action for uav_0 must be an integer in \[0, "):
        env.step({"uav_0": bad})


@pytest.mark.parametrize("env_id, kw, pattern", [
    ("covert_env/CovertSensing-v4", dict(n_uavs=3), r"flies one UAV, got n_uavs=3.*parallel_env"),
    ("covert_env/CovertSensing-v4", dict(action_mode="waypoint"), "CovertSensingWaypoint-v4"),
    ("covert_env/CovertSensingWaypoint-v4", dict(action_mode="unicycle"), "covert_env/CovertSensing-v4"),
    ("covert_env/CovertSensing-v4", dict(dict_obs=True), "dict_obs=True needs action_mode='waypoint'"),
])
def test_gymnasium_make_rejects_contradicting_arguments(env_id, kw, pattern):
    with pytest.raises(ValueError, match=pattern):
        gym.make(env_id, **kw)
    gym.make(env_id, n_uavs=1)                 # what the id already is: accepted


# ---------------------------------------------------------------------- versions
def test_v0_ids_fail_with_a_clear_message():
    from covert_env import covert_sensing_v0

    with pytest.raises(gym.error.DeprecatedEnv, match="CovertSensing-v4"):
        gym.make("covert_env/CovertSensing-v0")
    with pytest.raises(gym.error.DeprecatedEnv, match="CovertSensingWaypoint-v4"):
        gym.make("covert_env/CovertSensingWaypoint-v0")
    for make in (covert_sensing_v0.parallel_env, covert_sensing_v0.env, covert_sensing_v0.raw_env):
        with pytest.raises(RuntimeError, match=r"replaced by covert_sensing_v1.*reward_.*covert_sensing_v4"):
            make(n_uavs=3)
    assert covert_env.covert_sensing_v4.parallel_env(n_uavs=2).metadata["name"] == "covert_sensing_v4"


RETIRED = {
    1: r"replaced by covert_sensing_v2 in covert_env 0\.6\.0: random scenes come from a new.*eq\. 10.*"
       r"Use covert_env\.covert_sensing_v4 \(or covert_env\.parallel_env, gym\.make\('covert_env/CovertSensing-v4'\)",
    2: r"replaced by covert_sensing_v3 in covert_env 0\.7\.0: line of sight lost between slot times"
       r".*los_path_penalty=0",
    3: r"replaced by covert_sensing_v4 in covert_env 0\.10\.0: every UAV's pose is settled at each slot end.*"
       r"pip install 'covert_env<0\.10' for v3",
}
"""What each retired version's entry points say: what changed in the next version and where to get the old one."""


@pytest.mark.parametrize("version", sorted(RETIRED))
def test_retired_ids_fail_with_what_changed(version):
    """Every entry point of a retired version (Gymnasium ids, PettingZoo's makers and the module's functions) raises
    the same message: what the next version changed, and how to get the old behaviour."""
    import importlib

    import pettingzoo

    module = importlib.import_module(f"covert_env.covert_sensing_v{version}")
    changed = RETIRED[version]
    for env_id in (f"covert_env/CovertSensing-v{version}", f"covert_env/CovertSensingWaypoint-v{version}"):
        with pytest.raises(RuntimeError, match=changed):
            gym.make(env_id)
    for make in (module.parallel_env, module.env, module.raw_env,
                 lambda **kw: pettingzoo.make("parallel", f"covert_env/CovertSensing-v{version}", **kw),
                 lambda **kw: pettingzoo.make("aec", f"covert_env/CovertSensing-v{version}", **kw)):
        with pytest.raises(RuntimeError, match=changed):
            make(n_uavs=3)
    assert covert_env.vector_env(num_envs=1).metadata["name"] == "covert_sensing_vector_v4"


# ---------------------------------------------------------------------- costs against independent geometry
def _one_uav_scene(building, start_xy):
    from covert_env import Config, Scenario, Terrain

    c = Config(n_uavs=1)
    paper = Scenario.paper(c)
    return Scenario(c, Terrain((building,)), paper.track, np.array([start_xy]), np.array([0.0]))


def test_cost_terrain_fires_near_a_tall_pole():
    from covert_env import Polytope

    pole = Polytope.prism([[49, 59], [51, 59], [51, 61], [49, 61]], 75.0)       # 5 m below the UAVs
    env = covert_env.parallel_env(scenario=_one_uav_scene(pole, (25.0, 60.0)))
    _, infos = env.reset(seed=0)
    assert infos["uav_0"]["cost_terrain"] == 0.0 and infos["uav_0"]["terrain_clearance"] > 10
    # v = 25 m/s straight ahead ends the slot at (50, 60), beside the pole's top: eq. 3 violated.
    a0 = 2 * (25 / 50 - 0.01) / 0.99 - 1
    _, _, _, _, infos = env.step({"uav_0": np.array([a0, 0.0])})
    top = pole.highest_point
    expect = float(np.sqrt(((env.engine.uav_xy[0] - top[:2]) ** 2).sum() + (80 - top[2]) ** 2))
    assert infos["uav_0"]["terrain_clearance"] == pytest.approx(expect) and expect < 10
    assert infos["uav_0"]["cost_terrain"] == 1.0 and infos["uav_0"]["reward_terrain"] == -1.0


def test_cost_los_fires_behind_a_wall():
    from covert_env import Polytope

    # A 75 m wall across the line from the UAV (50, 0, 80) to the target (x >= 120, 0, 1.5): at x = 105 the line
    # of sight is below 30 m, so it is blocked (eq. 6); without the wall it is clear.
    wall = Polytope.prism([[100, -15], [110, -15], [110, 15], [100, 15]], 75.0)
    env = covert_env.parallel_env(scenario=_one_uav_scene(wall, (50.0, 0.0)))
    _, infos = env.reset(seed=0)
    assert infos["uav_0"]["los"] is False
    _, _, _, _, infos = env.step({"uav_0": np.array([-0.96, 0.0])})
    assert infos["uav_0"]["cost_los"] == 1.0 and infos["uav_0"]["reward_los"] == -1.0
    open_env = covert_env.parallel_env(scenario=_one_uav_scene(
        Polytope.prism([[100, 40], [110, 40], [110, 50], [100, 50]], 75.0), (50.0, 0.0)))
    open_env.reset(seed=0)
    _, _, _, _, infos = open_env.step({"uav_0": np.array([-0.96, 0.0])})
    assert infos["uav_0"]["cost_los"] == 0.0


# ---------------------------------------------------------------------- more boundaries
def test_scenario_and_a_different_config_rejected():
    from covert_env import Config, Scenario

    sc = Scenario.paper(Config())
    with pytest.raises(ValueError, match=r"config differs from scenario.config in \['altitude'"):
        covert_env.parallel_env(config=Config(altitude=30.0, min_height=5), scenario=sc)
    with pytest.raises(ValueError, match=r"config differs from scenario.config in \['v_max'\]"):
        covert_env.parallel_env(config=Config(v_max=5.0), scenario=sc, n_uavs=3)
    assert covert_env.parallel_env(config=Config(), scenario=sc).config == sc.config


@pytest.mark.parametrize("options, exc, pattern", [
    ({"scene_seed": 2.7}, TypeError, r"options\['scene_seed'\] must be an integer"),
    ({"scene_seed": "5"}, TypeError, r"options\['scene_seed'\] must be an integer"),
    ({"scene_seed": True}, TypeError, r"options\['scene_seed'\] must be an integer"),
    ({"scene_seed": -1}, ValueError, r"options\['scene_seed'\] must be an integer in \[0, 9223372036854775807\]"),
    ([1], TypeError, r"reset\(options=...\) must be a dict"),
])
def test_bad_reset_options(options, exc, pattern):
    env = covert_env.parallel_env(n_uavs=2)
    with pytest.raises(exc, match=pattern):
        env.reset(seed=0, options=options)


def test_scene_seed_needs_random_scenes_and_unknown_options_warn():
    with pytest.raises(ValueError, match="needs scenario='random'"):
        covert_env.parallel_env(n_uavs=2, scenario="paper").reset(seed=0, options={"scene_seed": 3})
    env = covert_env.parallel_env(n_uavs=2)
    with pytest.warns(UserWarning, match=r"ignoring unknown option\(s\) \['scen_seed'\]"):
        env.reset(seed=0, options={"scen_seed": 3})
    env.reset(seed=0, options={"scene_seed": np.int64(3)})
    assert env.scenario.name == "random-3"


def test_max_cycles_attribute_on_aec_and_gymnasium_envs():
    aec = covert_env.env(n_uavs=1)
    with pytest.raises(ValueError, match="max_cycles must be an integer >= 1"):
        aec.max_cycles = 0
    aec.max_cycles = 3
    aec.reset(seed=0)
    steps = 0
    for agent in aec.agent_iter():
        _, _, term, trunc, _ = aec.last()
        aec.step(None if term or trunc else aec.action_space(agent).sample())
        steps += 1
    assert steps == 3 + 1                       # three slots, then the final None step of the one agent

    genv = gym.make("covert_env/CovertSensingWaypoint-v4")
    with pytest.raises(TypeError, match="max_cycles must be an integer"):
        genv.unwrapped.max_cycles = 2.5
    genv.unwrapped.max_cycles = 2
    genv.reset(seed=0)
    mask = genv.unwrapped.action_masks()
    _, _, _, trunc1, info0 = genv.step(int(np.flatnonzero(mask)[0]))
    _, _, _, trunc2, info1 = genv.step(int(np.flatnonzero(genv.unwrapped.action_masks())[0]))
    assert (trunc1, trunc2) == (False, True) and _signature(info0) == _signature(info1)


def test_action_mask_before_reset_and_nested_waypoint_actions():
    env = covert_env.parallel_env(n_uavs=1, action_mode="waypoint", scenario="paper")
    with pytest.raises(RuntimeError, match="before reset"):
        env.action_mask("uav_0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="unknown agent 'uav_9'"):
        env.action_mask("uav_9")
    with pytest.raises(ValueError, match="must be an integer in"):
        env.step({"uav_0": np.array([[3]])})


@pytest.mark.parametrize("bad", [True, 1.0, 2, "1"])
def test_gymnasium_n_uavs_must_be_one(bad):
    with pytest.raises(ValueError, match="flies one UAV"):
        gym.make("covert_env/CovertSensing-v4", n_uavs=bad)


# ---------------------------------------------------------------------- LoS along the path
@pytest.mark.parametrize("kw", [dict(family="downtown"), dict(scenario="paper", random_starts=True),
                                dict(family="dense", config=dict(prediction_error=3.0, r_u=3.0))])
def test_path_los_cost_is_the_episode_metric(kw):
    """cost_los_path and los_path of every step are the episode metrics' blocked_path_share and los_path of the
    recorded flight (tests/test_metrics.py checks those against a dense resampling of the path), the reward's
    los_path term is -los_path_penalty times the cost, and the target between slot times is the track's."""
    from covert_env.world.metrics import slot_quantities

    env = covert_env.parallel_env(n_uavs=3, action_mode="waypoint", los_path_penalty=2.5, **kw)
    _, infos = env.reset(seed=4)
    rng = np.random.default_rng(0)
    cost, clear = [], []
    while env.agents:
        acts = {a: int(np.argmax(infos[a]["action_mask"] * (1 + rng.random(len(infos[a]["action_mask"])))))
                for a in env.agents}
        _, rew, _, _, infos = env.step(acts)
        cost.append([infos[a]["cost_los_path"] for a in env.possible_agents])
        clear.append([infos[a]["los_path"] for a in env.possible_agents])
        for a in env.possible_agents:
            assert infos[a]["reward_los_path"] == -2.5 * infos[a]["cost_los_path"]
            assert rew[a] == pytest.approx(sum(infos[a][f"reward_{t}"] for t in TERMS), abs=1e-12)
    q = slot_quantities(env.engine.trajectory(), env.engine.terrain, env.config)
    np.testing.assert_array_equal(np.array(cost), q.blocked_path_share)
    np.testing.assert_array_equal(np.array(clear), q.los_path)
    if "family" in kw:
        assert q.blocked_path_share.mean() > 0.005            # random waypoints do lose LoS between slots here
    vec, f = env._vec, np.linspace(0.0, 1.0, env.path_samples)
    got = vec._pool.target_between(vec.copies.rows, np.array([5]), f)
    np.testing.assert_array_equal(got[0], env.engine.track.position_between(5, f))


def test_no_path_penalty_gives_the_slot_time_rewards():
    """los_path_penalty=0: the reward is the sum of the other terms, bit for bit (v2's rewards)."""
    a = covert_env.vector_env(num_envs=4, n_uavs=3, family="downtown", los_path_penalty=0.0)
    b = covert_env.vector_env(num_envs=4, n_uavs=3, family="downtown")
    a.reset(seed=2)
    b.reset(seed=2)
    rng = np.random.default_rng(1)
    lost = 0.0
    for _ in range(30):
        act = rng.uniform(-1, 1, a.action_space.shape)
        _, ra, _, _, ia = a.step(act)
        _, rb, _, _, ib = b.step(act)
        assert (ia["reward_los_path"] == 0).all()
        others = np.stack([ib[f"reward_{t}"] for t in TERMS if t != "los_path"])
        np.testing.assert_array_equal(ra, others.sum(axis=0))
        lost += ib["cost_los_path"].sum()
    assert lost > 0


# ---------------------------------------------------------------------- action mask modes
def test_kinematic_mask_is_the_reachable_set_and_contains_the_visible_mask():
    """mask_mode="kinematic" allows every node reachable in one slot (the reachability table's answer), a superset
    of the default visible-zone mask that adds shadowed nodes on a shadowed family; the rest of a rollout (flight,
    rewards, costs) does not depend on the mask, and a shadowed node chosen through it is not flagged."""
    from covert_env.envs import batch

    kw = dict(num_envs=6, n_uavs=3, action_mode="waypoint", family="downtown")
    vis, kin = covert_env.vector_env(**kw), covert_env.vector_env(mask_mode="kinematic", **kw)
    vis.reset(seed=3)
    kin.reset(seed=3)
    rng = np.random.default_rng(0)
    extra = 0
    for _ in range(20):
        mv, mk = vis.action_masks(), kin.action_masks()
        pool, rows, k = kin._pool, kin.copies.rows, kin.copies.k
        reach = kin._reach.reachable(kin.copies.xy, kin.copies.theta, pool.q_next[rows, k, :2], pool.phi_next[rows, k],
                                     kin.lattice)
        rows_any = reach.any(axis=-1)
        np.testing.assert_array_equal(mk[rows_any].astype(bool), reach[rows_any])
        assert (mv <= mk).all()
        extra += int((mk > mv).sum())
        act = np.argmax(mk * (1 + rng.random(mk.shape)), axis=-1)           # kinematic choices, maybe shadowed
        _, rv, _, _, iv = vis.step(act)
        _, rk, _, _, ik = kin.step(act)
        np.testing.assert_array_equal(rv, rk)
        shadowed = (np.take_along_axis(mv, act[..., None], -1)[..., 0] == 0) & \
            (np.take_along_axis(mk, act[..., None], -1)[..., 0] == 1)
        assert iv["infeasible"][shadowed].all() and not ik["infeasible"][shadowed].any()
    assert extra > 0
    assert batch.action_masks.__doc__ and "kinematic" in batch.action_masks.__doc__


@pytest.mark.parametrize("kw, pattern", [
    (dict(mask_mode="kin"), r"mask_mode must be one of \('visible', 'kinematic'\), got 'kin'"),
    (dict(mask_mode=None), r"mask_mode must be one of"),
    (dict(mask_mode="kinematic"), r"mask_mode='kinematic' needs action_mode='waypoint'"),
])
def test_mask_mode_errors_name_the_value(kw, pattern):
    with pytest.raises(ValueError, match=pattern):
        covert_env.parallel_env(**kw)


def test_kinematic_mask_passes_pettingzoo_and_gymnasium_checks():
    from gymnasium.utils.env_checker import check_env
    from pettingzoo.test import parallel_api_test

    parallel_api_test(covert_env.parallel_env(action_mode="waypoint", mask_mode="kinematic", max_cycles=5))
    env = gym.make("covert_env/CovertSensingWaypoint-v4", mask_mode="kinematic", max_cycles=5)
    check_env(env.unwrapped)
    assert env.unwrapped.par.mask_mode == "kinematic"


def test_retired_versions_come_from_one_table_and_load_on_demand():
    """covert_env.retired.RETIRED is the one table: every retired module's constructors raise its entry, and
    ``import covert_env`` imports none of them until one is read."""
    import subprocess
    import sys

    import covert_env
    from covert_env.retired import RETIRED

    assert list(RETIRED) == [f"covert_sensing_v{v}" for v in range(4)]
    for name, message in RETIRED.items():
        module = getattr(covert_env, name)
        for make in (module.env, module.parallel_env, module.raw_env):
            with pytest.raises(RuntimeError) as err:
                make(n_uavs=3)
            assert str(err.value) == message and "covert_sensing_v4" in message
    with pytest.raises(AttributeError, match="no attribute 'covert_sensing_v9'"):
        covert_env.covert_sensing_v9       # noqa: B018
    code = "import sys, covert_env; print(sorted(m for m in sys.modules if 'covert_sensing_v' in m))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "['covert_env.covert_sensing_v4']"
