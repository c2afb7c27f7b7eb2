"""The environments: PettingZoo's and Gymnasium's test batteries, SB3's checker, determinism, spaces."""

import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from _extras import needs
from pettingzoo.test import (
    api_test,
    max_cycles_test,
    parallel_api_test,
    parallel_seed_test,
    render_test,
    seed_test,
    state_test,
)
from pettingzoo.utils import parallel_to_aec

import covert_env
from covert_env import covert_sensing_v4

MODES = ["unicycle", "waypoint"]
TEAMS = [1, 3]
SHORT = 12   # max_cycles for the batteries: enough slots to move, fast enough for CI


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("u", TEAMS)
def test_pettingzoo_battery(mode, u):
    kw = dict(action_mode=mode, n_uavs=u, max_cycles=SHORT)
    parallel_api_test(covert_sensing_v4.parallel_env(**kw), num_cycles=40)
    api_test(parallel_to_aec(covert_sensing_v4.parallel_env(**kw)), num_cycles=40)
    seed_test(lambda: covert_sensing_v4.env(**kw), num_cycles=40)
    parallel_seed_test(lambda: covert_sensing_v4.parallel_env(**kw))
    state_test(covert_sensing_v4.env(**kw), covert_sensing_v4.parallel_env(**kw), num_cycles=40)


def test_dict_obs_battery():
    kw = dict(action_mode="waypoint", n_uavs=3, max_cycles=SHORT, dict_obs=True)
    parallel_api_test(covert_sensing_v4.parallel_env(**kw), num_cycles=20)
    api_test(parallel_to_aec(covert_sensing_v4.parallel_env(**kw)), num_cycles=20)


def test_max_cycles():
    max_cycles_test(covert_sensing_v4)


@pytest.mark.parametrize("mode", MODES)
def test_render_battery(mode):
    import matplotlib

    matplotlib.use("Agg")
    render_test(lambda render_mode=None: covert_sensing_v4.env(action_mode=mode, max_cycles=3,
                                                               render_mode=render_mode))


@pytest.mark.parametrize("env_id", ["covert_env/CovertSensing-v4", "covert_env/CovertSensingWaypoint-v4"])
def test_gymnasium_checker(env_id):
    from gymnasium.utils.env_checker import check_env

    env = gym.make(env_id, render_mode="rgb_array", max_cycles=SHORT)
    check_env(env.unwrapped, skip_render_check=False)


@pytest.mark.parametrize("env_id", ["covert_env/CovertSensing-v4", "covert_env/CovertSensingWaypoint-v4"])
def test_sb3_checker(env_id):
    sb3_check_env = needs("stable_baselines3.common.env_checker").check_env
    sb3_check_env(gym.make(env_id, max_cycles=SHORT).unwrapped, warn=True)


def test_make_without_import_prefix():
    env = gym.make("covert_env:covert_env/CovertSensing-v4", max_cycles=3)
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)


def test_pettingzoo_registry():
    import pettingzoo

    penv = pettingzoo.make("parallel", "covert_env/CovertSensing-v4", n_uavs=2)
    assert penv.possible_agents == ["uav_0", "uav_1"]


def _rollout(env, seed, steps, action_seed):
    """Reset with ``seed`` and run ``steps`` slots of seeded random actions (resetting at episode ends)."""
    rng = np.random.default_rng(action_seed)
    out = []
    obs, infos = env.reset(seed=seed)
    out.append((obs, infos))
    for _ in range(steps):
        if not env.agents:
            obs, infos = env.reset()
            out.append((obs, infos))
            continue
        acts = {}
        for a in env.agents:
            space = env.action_space(a)
            if isinstance(space, gym.spaces.Discrete):
                mask = infos[a]["action_mask"]
                acts[a] = int(rng.choice(np.flatnonzero(mask)))
            else:
                acts[a] = rng.uniform(-1, 1, 2).astype(np.float32)
        obs, rew, term, trunc, infos = env.step(acts)
        out.append((obs, rew, term, trunc, infos))
    return out


def _equal(x, y):
    if isinstance(x, dict):
        return x.keys() == y.keys() and all(_equal(x[k], y[k]) for k in x)
    if isinstance(x, (tuple, list)):
        return len(x) == len(y) and all(_equal(a, b) for a, b in zip(x, y, strict=True))
    if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
        return np.array_equal(np.asarray(x), np.asarray(y))
    return x == y


@pytest.mark.parametrize("mode", MODES)
def test_determinism_1000_steps(mode):
    steps = 1000 if mode == "unicycle" else 300
    a = _rollout(covert_env.parallel_env(action_mode=mode, n_uavs=3, scene_pool=3), 7, steps, 1)
    b = _rollout(covert_env.parallel_env(action_mode=mode, n_uavs=3, scene_pool=3), 7, steps, 1)
    assert _equal(a, b)
    # Another seed: another scene or other starts.
    c = _rollout(covert_env.parallel_env(action_mode=mode, n_uavs=3, scene_pool=3), 8, 20, 1)
    assert not _equal(a[:21], c)
    # A fixed scene: the seed still changes the starts.
    d = _rollout(covert_env.parallel_env(action_mode=mode, n_uavs=3, scene_pool=1), 8, 0, 1)
    e = _rollout(covert_env.parallel_env(action_mode=mode, n_uavs=3, scene_pool=1), 9, 0, 1)
    assert not _equal(d, e)


@pytest.mark.slow
def test_random_steps_stay_in_space():
    rng = np.random.default_rng(0)
    total = 0
    configs = [dict(), dict(r_u=5.0, grid_step=5.0), dict(mu=1.2, r1=40.0, r2=120.0), dict(target_speed=15.0)]
    while total < 10_000:
        cfg = covert_env.Config(**configs[total // 2500 % len(configs)])
        mode = MODES[rng.integers(2)]
        env = covert_env.parallel_env(config=cfg, action_mode=mode, n_uavs=int(rng.integers(1, 4)),
                                      scene_pool=1_000_000)
        obs, infos = env.reset(seed=int(rng.integers(1 << 30)))
        while env.agents:
            for a, o in obs.items():
                assert env.observation_space(a).contains(o), (a, o)
                assert np.all(np.isfinite(o))
            acts = {a: (env.action_space(a).sample(infos[a]["action_mask"]) if mode == "waypoint"
                        else rng.uniform(-1.5, 1.5, 2)) for a in env.agents}
            obs, rew, term, trunc, infos = env.step(acts)
            assert all(np.isfinite(r) for r in rew.values())
            total += 1
        s = env.state()
        assert env.state_space.contains(s)


def test_bad_actions_raise():
    env = covert_env.parallel_env(n_uavs=1)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="uav_0 must be finite"):
        env.step({"uav_0": np.array([np.nan, 0.0])})
    with pytest.raises(ValueError, match=r"shape \(2,\)"):
        env.step({"uav_0": np.zeros(3)})
    wenv = covert_env.parallel_env(n_uavs=1, action_mode="waypoint")
    wenv.reset(seed=0)
    n = wenv.action_space("uav_0").n
    with pytest.raises(ValueError, match=rf"integer in \[0, {n - 1}\]"):
        wenv.step({"uav_0": n})
    with pytest.raises(ValueError, match="integer in"):
        wenv.step({"uav_0": float("nan")})


@pytest.mark.parametrize("kw, pattern", [
    (dict(action_mode="teleport"), "action_mode must be one of"),
    (dict(scenario="moon"), "scenario must be"),
    (dict(max_cycles=0), r"max_cycles must be an integer >= 1"),
    (dict(map_size=1), r"map_size must be an integer in \[2, 64\]"),
    (dict(reward_scale=0.0), "reward_scale must be"),
    (dict(zone_penalty=-1.0), "zone_penalty must be"),
    (dict(render_mode="ansi"), "render_mode must be"),
    (dict(n_uavs=0), "n_uavs must be an integer >= 1"),
])
def test_bad_arguments_raise(kw, pattern):
    with pytest.raises(ValueError, match=pattern):
        covert_env.parallel_env(**kw)


def test_out_of_range_actions_are_clipped():
    a = covert_env.parallel_env(n_uavs=1, scenario="paper")
    b = covert_env.parallel_env(n_uavs=1, scenario="paper")
    a.reset(seed=0)
    b.reset(seed=0)
    oa = a.step({"uav_0": np.array([5.0, -9.0])})
    ob = b.step({"uav_0": np.array([1.0, -1.0])})
    assert _equal(oa, ob)
    assert ob[4]["uav_0"]["v"] == pytest.approx(50.0)


def test_reward_terms_and_infos():
    env = covert_env.parallel_env(n_uavs=3, scenario="paper")
    env.reset(seed=0)
    _, rew, _, _, infos = env.step({a: np.array([-0.6, 0.0]) for a in env.agents})
    names = ("path", "disguise", "los", "zone", "separation", "terrain")
    for a in env.possible_agents:
        info = infos[a]
        terms = {t: info[f"reward_{t}"] for t in names}
        assert rew[a] == pytest.approx(sum(terms.values()))
        assert terms["path"] == pytest.approx(-info["v"] / 100.0)
        assert terms["disguise"] == pytest.approx(10 * info["kappa"] / 100.0)
        assert rew[a] == pytest.approx(-info["g"] / 100.0 + terms["los"] + terms["zone"] + terms["separation"]
                                       + terms["terrain"])
        for key in ("los", "in_zone", "kappa", "v", "separation", "terrain_clearance", "slot"):
            assert key in info


def test_truncation_at_route_end():
    env = covert_env.parallel_env(n_uavs=2, scenario="paper")
    env.reset(seed=0)
    n = 0
    while env.agents:
        _, _, term, trunc, _ = env.step({a: np.zeros(2) for a in env.agents})
        n += 1
        assert not any(term.values())
    assert n == env.config.n_slots and all(trunc.values())


def test_terminate_on_collision():
    paper = covert_env.Scenario.paper(covert_env.Config(n_uavs=2))
    close = covert_env.Scenario(paper.config, paper.terrain, paper.track, [[50.0, 0.0], [50.0, 2.0]], [0.0, 0.0])
    env = covert_env.parallel_env(scenario=close, terminate_on_collision=True)
    env.reset(seed=0)
    _, _, term, trunc, _ = env.step({a: np.array([-0.6, 0.0]) for a in env.agents})
    assert all(term.values()) and not any(trunc.values()) and env.agents == []


def test_waypoint_actions_land_on_lattice_node():
    env = covert_env.parallel_env(n_uavs=1, action_mode="waypoint", scenario="paper")
    _, infos = env.reset(seed=0)
    mask = infos["uav_0"]["action_mask"]
    idx = int(np.flatnonzero(mask)[len(np.flatnonzero(mask)) // 2])
    q1, phi1 = env.engine.predict(1)
    goal = covert_env.geometry.zone.to_world(env.lattice[idx:idx + 1], q1[0, :2], float(phi1[0]))[0]
    env.step({"uav_0": idx})
    assert np.allclose(env.engine.uav_xy[0], goal, atol=1e-6)
    gym_env = gym.make("covert_env/CovertSensingWaypoint-v4", scenario="paper")
    gym_env.reset(seed=0)
    assert np.array_equal(gym_env.unwrapped.action_masks(), mask.astype(bool))


def test_scripted_zone_centre_beats_random():
    """Flying to the zone centre and holding earns more than random actions: the reward is shaped sensibly."""
    def centre_policy(env):
        c = env.config
        q1, phi1 = env.engine.predict(1)
        centre = covert_env.geometry.zone.to_world(np.array([[-(c.r1 + c.r2) / 2, 0.0]]), q1[0, :2], float(phi1[0]))[0]
        acts = {}
        for i, a in enumerate(env.agents):
            rel = centre - env.engine.uav_xy[i]
            bearing = covert_env.geometry.angles.wrap_angle(np.arctan2(rel[1], rel[0]) - env.engine.uav_theta[i])
            v = min(np.hypot(*rel) / c.delta, c.v_max)
            acts[a] = np.array([2 * (v / c.v_max - 0.01) / 0.99 - 1, np.clip(bearing / c.w_max, -1, 1)])
        return acts

    def episode_return(policy, seed):
        env = covert_env.parallel_env(n_uavs=1, scene_pool=1000)
        env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        total = 0.0
        while env.agents:
            acts = policy(env) if policy else {a: rng.uniform(-1, 1, 2) for a in env.agents}
            _, rew, _, _, _ = env.step(acts)
            total += sum(rew.values())
        return total

    scripted = np.mean([episode_return(centre_policy, s) for s in range(5)])
    random = np.mean([episode_return(None, s) for s in range(5)])
    assert scripted > random + 20, (scripted, random)


def test_pickle_round_trip():
    env = covert_env.parallel_env(n_uavs=2, scenario="paper")
    env.reset(seed=3)
    env.step({a: np.zeros(2) for a in env.agents})
    clone = pickle.loads(pickle.dumps(env))
    acts = {a: np.array([0.2, -0.1]) for a in env.agents}
    assert _equal(env.step(acts), clone.step(acts))
    genv = gym.make("covert_env/CovertSensing-v4")
    genv.reset(seed=1)
    assert pickle.loads(pickle.dumps(genv)).unwrapped.par.config == genv.unwrapped.par.config


def test_make_vec_async():
    venv = gym.make_vec("covert_env/CovertSensing-v4", num_envs=2, vectorization_mode="async",
                        vector_kwargs={"context": "spawn"}, max_cycles=5)
    try:
        obs, _ = venv.reset(seed=[0, 1])
        assert obs.shape == (2,) + venv.single_observation_space.shape
        for _ in range(6):
            obs, rew, term, trunc, _ = venv.step(venv.action_space.sample())
        assert obs.dtype == np.float32 and np.all(np.isfinite(rew))
    finally:
        venv.close()


def test_rgb_frame_and_record_video(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    from gymnasium.wrappers import RecordVideo

    env = covert_env.parallel_env(n_uavs=3, render_mode="rgb_array", scenario="paper")
    env.reset(seed=0)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3 and frame.std() > 5
    genv = gym.make("covert_env/CovertSensing-v4", render_mode="rgb_array", max_cycles=3)
    needs("moviepy")                                    # RecordVideo writes the mp4 with it
    rec = RecordVideo(genv, str(tmp_path), episode_trigger=lambda e: True)
    rec.reset(seed=0)
    done = False
    while not done:
        _, _, term, trunc, _ = rec.step(rec.action_space.sample())
        done = term or trunc
    rec.close()
    assert list(tmp_path.glob("*.mp4"))


def test_episode_gif(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    from covert_env.render import save_episode_gif

    env = covert_env.parallel_env(n_uavs=1, render_mode="rgb_array", scenario="paper", max_cycles=3)
    env.reset(seed=0)
    frames = [env.render()]
    while env.agents:
        env.step({a: np.zeros(2) for a in env.agents})
        frames.append(env.render())
    save_episode_gif(frames, tmp_path / "ep.gif")
    data = (tmp_path / "ep.gif").read_bytes()
    assert data[:6] in (b"GIF89a", b"GIF87a") and len(data) > 10_000


@pytest.mark.parametrize("scene_seed", [3, 11])
def test_visibility_maps_match_exact_per_cell_check(scene_seed):
    """The observation maps (computed for many slots in one batched call) equal, cell by cell, "in the
    eroded zone (eq. 4) and clear LoS (eq. 6)" evaluated at that slot's target pose."""
    from covert_env.geometry.zone import in_feasible_zone, to_world
    from covert_env.world.visibility import line_of_sight

    env = covert_sensing_v4.parallel_env(n_uavs=2, map_size=10)
    obs, _ = env.reset(seed=0, options={"scene_seed": scene_seed})
    c, s, u = env.config, env.map_size, 2
    start = 11 + 2 * (u - 1)
    track = env.scenario.track
    blocked = 0
    for k in range(env.max_cycles):
        o = obs["uav_0"]
        for j, kk in enumerate((k, k + 1)):
            q, phi = track.position(kk), float(track.heading(kk))
            xy = to_world(env.map_offsets, q[:2], phi)
            zone = in_feasible_zone(xy, q[:2], phi, c.r1, c.r2, c.mu, c.r_u)
            clear = line_of_sight(env.scenario.terrain, xy, c.altitude, q)
            np.testing.assert_array_equal(o[start + j * s * s: start + (j + 1) * s * s], zone & clear)
            blocked += int((zone & ~clear).sum())
        obs, *_ = env.step({a: env.action_space(a).sample() for a in env.agents})
        if not env.agents:
            break
    assert 0 < zone.sum() < s * s
    if scene_seed == 3:
        assert blocked > 0, "the check would be vacuous without shadowed cells"


def test_starts_scene_seed_and_random_starts():
    """options={"scene_seed": s} flies Scenario.random(s)'s own starts; random_starts draws them from the env
    seed (any team size, fixed scenarios too); env.scenario always holds the starts actually flown."""
    from covert_env.geometry.zone import in_feasible_zone
    from covert_env.world.scenario import Scenario
    from covert_env.world.visibility import line_of_sight

    env = covert_sensing_v4.parallel_env(n_uavs=3)
    env.reset(seed=1, options={"scene_seed": 42})
    ref = Scenario.random(42, env.config)
    np.testing.assert_array_equal(env.engine.uav_xy, ref.uav_xy)
    np.testing.assert_array_equal(env.scenario.uav_theta, ref.uav_theta)
    env.reset(seed=1)                                   # a pool scene: starts from the env's RNG
    np.testing.assert_array_equal(env.engine.uav_xy, env.scenario.uav_xy)

    starts = []
    for seed in (0, 1):
        penv = covert_sensing_v4.parallel_env(n_uavs=2, scenario="paper", random_starts=True)
        penv.reset(seed=seed)
        sc, c = penv.scenario, penv.config
        assert sc.n_uavs == 2
        np.testing.assert_array_equal(penv.engine.uav_xy, sc.uav_xy)
        q, phi = sc.track.position(0), float(sc.track.heading(0))
        assert in_feasible_zone(sc.uav_xy, q[:2], phi, c.r1, c.r2, c.mu, c.r_u).all()
        assert line_of_sight(sc.terrain, sc.uav_xy, c.altitude, q).all()
        starts.append(sc.uav_xy)
    assert not np.array_equal(*starts)


def test_shortest_allowed_track_runs_to_the_end():
    """A scenario whose track has exactly n_slots + horizon slots (the minimum Scenario accepts): the last
    observation looks one slot past the track's end, clamped like TargetTrack.position."""
    from covert_env.world.config import Config
    from covert_env.world.road import Road, TargetTrack
    from covert_env.world.scenario import Scenario

    base = Scenario.paper(Config())
    c = base.config.replace(n_slots=10, horizon=1)
    track = TargetTrack.constant(Road(base.track.road.points), c.target_speed, c.n_slots + c.horizon,
                                 delta=c.delta, z=c.target_height, s0=base.track.s0)
    sc = Scenario(c, base.terrain, track, base.uav_xy, base.uav_theta)
    env = covert_sensing_v4.parallel_env(scenario=sc)
    obs, _ = env.reset(seed=0)
    steps = 0
    while env.agents:
        obs, *_ = env.step({a: env.action_space(a).sample() for a in env.agents})
        steps += 1
    assert steps == 10
    assert all(env.observation_space(a).contains(o) for a, o in obs.items())
