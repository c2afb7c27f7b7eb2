"""The vector env: copy i equals the parallel env for the same scene, starts and actions (bit for bit, both action
modes, across automatic resets); seeding; shapes and dtypes; clear errors for bad actions and arguments."""

from __future__ import annotations

import numpy as np
import pytest

import covert_env
from covert_env import Config
from covert_env.envs.vector import INFO_KEYS
from covert_env.world.scenario import Scenario


def _actions(venv, rng):
    b, u = venv.num_envs, len(venv.possible_agents)
    if venv.action_mode == "unicycle":
        return rng.uniform(-1.2, 1.2, (b, u, 2)).astype(np.float32)     # some out of range: clipped alike
    m = venv.action_masks()
    return np.array([[rng.choice(np.flatnonzero(m[j, i])) for i in range(u)] for j in range(b)])


def _assert_same(obs, infos, ref, penvs, where):
    """Vector obs/infos rows against the parallel envs' per-agent results ``ref`` [(obs, infos)]."""
    for j, ((p_obs, p_inf), p) in enumerate(zip(ref, penvs, strict=True)):
        for i, a in enumerate(p.possible_agents):
            row = obs["observation"][j, i] if isinstance(obs, dict) else obs[j, i]
            p_row = p_obs[a]["observation"] if isinstance(p_obs[a], dict) else p_obs[a]
            assert np.array_equal(row, p_row), f"{where}: observation of copy {j}, {a}"
            for key in INFO_KEYS:
                assert infos[key][j, i] == p_inf[a][key], f"{where}: infos[{key!r}] of copy {j}, {a}"


def _run_side_by_side(kw, b, steps, *, seed=11, options=None, copy_options=None):
    """Step a vector env of b copies and b parallel envs reset with the copies' seeds, with the same actions."""
    venv = covert_env.vector_env(num_envs=b, **kw)
    obs, infos = venv.reset(seed=seed, options=options)
    penvs = [covert_env.parallel_env(**kw) for _ in range(b)]
    ref = [p.reset(seed=int(s), options=None if copy_options is None else copy_options[j])
           for j, (p, s) in enumerate(zip(penvs, venv.copy_seeds, strict=True))]
    _assert_same(obs, infos, ref, penvs, "reset")
    rng = np.random.default_rng(0)
    ends = 0
    for t in range(steps):
        if venv.action_mode == "waypoint":
            masks = venv.action_masks()
            for j, p in enumerate(penvs):
                for i, a in enumerate(p.possible_agents):
                    assert np.array_equal(masks[j, i], p.action_mask(a)), f"step {t}: mask of copy {j}, {a}"
        act = _actions(venv, rng)
        obs, rew, term, trunc, infos = venv.step(act)
        ref = []
        for j, p in enumerate(penvs):
            p_obs, p_rew, p_term, p_trunc, p_inf = p.step({a: act[j, i] for i, a in enumerate(p.possible_agents)})
            for i, a in enumerate(p.possible_agents):
                assert (rew[j, i], term[j, i], trunc[j, i]) == (p_rew[a], p_term[a], p_trunc[a]), f"step {t}"
            if not p.agents:
                ends += 1
                assert infos["_final_obs"][j] and infos["_final_info"][j]
                final_info = {key: val[j:j + 1] for key, val in infos["final_info"].items()}
                _assert_same(infos["final_obs"][j:j + 1], final_info, [(p_obs, p_inf)], [p], f"final, step {t}")
                assert np.array_equal(infos["final_state"][j], p.state()), f"final state, step {t}"
                p_obs, p_inf = p.reset()
            ref.append((p_obs, p_inf))
        _assert_same(obs, infos, ref, penvs, f"step {t}")
        state = venv.state()
        for j, p in enumerate(penvs):
            assert np.array_equal(state[j], p.state()), f"step {t}: state of copy {j}"
    return ends


@pytest.mark.parametrize("mode", ["unicycle", "waypoint"])
def test_copies_equal_the_parallel_env_across_automatic_resets(mode):
    ends = _run_side_by_side(dict(n_uavs=3, action_mode=mode, max_cycles=4), b=3, steps=9)
    assert ends == 6                                      # two automatic resets per copy, compared too


@pytest.mark.parametrize("mode", ["unicycle", "waypoint"])
def test_copies_equal_the_parallel_env_with_scene_seeds(mode):
    seeds = [4, 90_001, 4]                                # two copies share a scene (one pool row)
    _run_side_by_side(dict(n_uavs=2, action_mode=mode, max_cycles=3), b=3, steps=5,
                      options={"scene_seed": seeds}, copy_options=[{"scene_seed": s} for s in seeds])


def test_copies_equal_the_parallel_env_paper_and_fixed_scenario():
    _run_side_by_side(dict(n_uavs=3, scenario="paper", max_cycles=3), b=2, steps=4)
    sc = Scenario.random(5)
    _run_side_by_side(dict(scenario=sc, random_starts=True, max_cycles=3, reward_scale=7.0, zone_penalty=2.5),
                      b=2, steps=4)


def test_dict_obs_and_collision_termination_equal_the_parallel_env():
    _run_side_by_side(dict(n_uavs=2, action_mode="waypoint", dict_obs=True, max_cycles=3), b=2, steps=4)
    kw = dict(n_uavs=3, scenario="paper", terminate_on_collision=True, config={"d_safe1": 30.0})
    ends = _run_side_by_side(kw, b=2, steps=6)
    assert ends > 0                                       # the paper's starts are closer than 30 m


# ---------------------------------------------------------------------- seeding
def test_same_seed_same_batch_other_seed_other_batch():
    def run(seed):
        venv = covert_env.vector_env(num_envs=4, n_uavs=2, max_cycles=3)
        out = [venv.reset(seed=seed)[0]]
        rng = np.random.default_rng(1)
        for _ in range(5):
            out.append(venv.step(rng.uniform(-1, 1, (4, 2, 2)))[0])
        return np.stack(out), venv.copy_seeds

    a, seeds_a = run(3)
    b, seeds_b = run(3)
    c, _ = run(4)
    assert np.array_equal(a, b) and np.array_equal(seeds_a, seeds_b)
    assert not np.array_equal(a[0], c[0])
    assert len(set(seeds_a.tolist())) == 4                # copies draw different scenes and starts
    assert not np.array_equal(a[0, 0], a[0, 1])


def test_seed_per_copy_and_unseeded_reset_continues():
    venv = covert_env.vector_env(num_envs=2, n_uavs=2)
    obs, _ = venv.reset(seed=[5, 6])
    assert venv.copy_seeds.tolist() == [5, 6]
    p = covert_env.parallel_env(n_uavs=2)
    p_obs, _ = p.reset(seed=6)
    assert np.array_equal(obs[1, 0], p_obs["uav_0"])
    obs2, _ = venv.reset()                                # next episode from the copies' generators
    p_obs2, _ = p.reset()
    assert np.array_equal(obs2[1, 1], p_obs2["uav_1"])


# ---------------------------------------------------------------------- shapes and dtypes
@pytest.mark.parametrize("mode, dict_obs", [("unicycle", False), ("waypoint", False), ("waypoint", True)])
def test_shapes_dtypes_and_spaces(mode, dict_obs):
    b, u = 5, 3
    venv = covert_env.vector_env(num_envs=b, n_uavs=u, action_mode=mode, dict_obs=dict_obs, max_cycles=2)
    obs, infos = venv.reset(seed=0)
    d = venv.single_observation_space["observation" if dict_obs else None].shape[0] if dict_obs \
        else venv.single_observation_space.shape[0]
    for _ in range(2):
        arr = obs["observation"] if dict_obs else obs
        assert arr.shape == (b, u, d) and arr.dtype == np.float32
        assert obs in venv.observation_space
        assert list(infos)[:len(INFO_KEYS)] == list(INFO_KEYS)
        for key in INFO_KEYS:
            assert infos[key].shape == (b, u), key
            kind = "i" if key == "slot" else "b" if key in ("los", "los_path", "in_zone", "infeasible") else "f"
            assert infos[key].dtype.kind == kind, key
        state = venv.state()
        assert state.shape == (b, venv.single_state_space.shape[0]) and state in venv.state_space
        masks = venv.action_masks()
        assert masks.dtype == np.int8 and masks.shape == (b, u, len(venv.lattice) if mode == "waypoint" else 2)
        if dict_obs:
            assert np.array_equal(obs["action_mask"], masks)
        venv.action_space.seed(0)
        act = venv.action_space.sample() if mode == "unicycle" else masks.argmax(axis=-1)
        obs, rew, term, trunc, infos = venv.step(act)
        assert rew.shape == term.shape == trunc.shape == (b, u)
        assert rew.dtype == np.float64 and term.dtype == trunc.dtype == bool
    assert trunc.all() and "final_obs" in infos and infos["final_obs"].shape == (b, u, d)
    assert infos["final_info"]["slot"].tolist() == [[2] * u] * b and infos["slot"].tolist() == [[0] * u] * b


def test_final_keys_only_when_a_copy_ended():
    venv = covert_env.vector_env(num_envs=2, n_uavs=1, max_cycles=2)
    venv.reset(seed=0)
    *_, infos = venv.step(np.zeros((2, 1, 2)))
    assert "final_obs" not in infos and "final_info" not in infos
    *_, infos = venv.step(np.zeros((2, 1, 2)))
    assert infos["_final_obs"].tolist() == [True, True]


# ---------------------------------------------------------------------- errors
@pytest.mark.parametrize("act, err, match", [
    (np.zeros((3, 2, 2)), ValueError, r"shape \(2, 2, 2\)"),
    (np.zeros((2, 2)), ValueError, r"shape \(2, 2, 2\)"),
    (np.full((2, 2, 2), True), TypeError, "numbers"),
    (np.full((2, 2, 2), "0.1"), TypeError, "numbers"),
    (np.array([[[0, 0], [0, 0]], [[0, 0], [np.nan, 0]]]), ValueError, "copy 1, agent uav_1 must be finite"),
    (np.array([[[0, np.inf], [0, 0]], [[0, 0], [0, 0]]]), ValueError, "copy 0, agent uav_0 must be finite"),
])
def test_bad_unicycle_actions_raise_naming_copy_and_agent(act, err, match):
    venv = covert_env.vector_env(num_envs=2, n_uavs=2)
    venv.reset(seed=0)
    with pytest.raises(err, match=match):
        venv.step(act)


@pytest.mark.parametrize("act, err, match", [
    (np.zeros((2, 2, 2), int), ValueError, r"shape \(2, 2\)"),
    (np.array([[0, 1], [2, -1]]), ValueError, r"copy 1, agent uav_1 must be an integer in \[0, "),
    (np.array([[0, 1.5], [2, 3]]), ValueError, "copy 0, agent uav_1"),
    (np.array([[0, 1], [10 ** 6, 3]]), ValueError, "copy 1, agent uav_0"),
    (np.array([[0, 1], [np.nan, 3]]), ValueError, "copy 1, agent uav_0"),
    (np.array([[True, False], [True, True]]), TypeError, "integers"),
])
def test_bad_waypoint_actions_raise_naming_copy_and_agent(act, err, match):
    venv = covert_env.vector_env(num_envs=2, n_uavs=2, action_mode="waypoint")
    venv.reset(seed=0)
    with pytest.raises(err, match=match):
        venv.step(act)


def test_bad_arguments_and_calls():
    with pytest.raises(RuntimeError, match="before reset"):
        covert_env.vector_env(num_envs=2).step(np.zeros((2, 3, 2)))
    for bad, err in ((0, ValueError), (2.5, TypeError), ("4", TypeError), (True, TypeError)):
        with pytest.raises(err, match="num_envs"):
            covert_env.vector_env(num_envs=bad)
    with pytest.raises(ValueError, match="does not render"):
        covert_env.vector_env(num_envs=2, render_mode="rgb_array")
    with pytest.raises(ValueError, match="n_uavs"):
        covert_env.vector_env(num_envs=2, n_uavs=0)
    venv = covert_env.vector_env(num_envs=2, n_uavs=2)
    with pytest.warns(UserWarning, match=r"ignoring unknown option\(s\) \['scene'\]"):
        venv.reset(options={"scene": 1})                # as the parallel env (PettingZoo's API test passes one)
    with pytest.raises(ValueError, match="scene_seed"):
        venv.reset(options={"scene_seed": [1, 2, 3]})
    with pytest.raises(ValueError, match="2 ints"):
        venv.reset(seed=[1, 2, 3])
    with pytest.raises(ValueError, match="max_cycles"):
        venv.max_cycles = 0


# ---------------------------------------------------------------------- the scene pool's batched geometry
def test_pool_line_of_sight_equals_line_of_sight_per_copy():
    from covert_env.world.visibility import line_of_sight

    venv = covert_env.vector_env(num_envs=6, n_uavs=2)
    venv.reset(options={"scene_seed": [1, 2, 3, 4, 5, 1]})
    pool, rows, rng = venv._pool, venv.copies.rows, np.random.default_rng(3)
    blocked = 0
    near_polytope = pool.centre[rows, 0] + rng.uniform(-1, 1, (6, 2)) * pool.radius[rows, 0, None]
    for k in (0, 20, 45, "near a polytope"):      # the last: targets inside a footprint's enclosing circle
        q = pool.q[rows, 0].copy() if k == "near a polytope" else pool.q[rows, k]
        if k == "near a polytope":
            q[:, :2] = near_polytope
        for alt in (80.0, 30.0, 0.5):             # below the target: the segment goes up
            xy = q[:, None, :2] + rng.uniform(-250, 250, (6, 400, 2))
            xy[:, 0] = q[:, :2]                    # straight above the target
            got = pool.line_of_sight(rows, xy, alt, q)
            want = np.stack([line_of_sight(pool.cache(r).parts.terrain, xy[j], alt, q[j])
                             for j, r in enumerate(rows)])
            assert np.array_equal(got, want), (k, alt, np.argwhere(got != want)[:5])
            blocked += (~want).sum()
    assert blocked > 500                           # the test sees blocked and clear segments


def test_starts_fallback_equals_the_parallel_env():
    """With d_safe1 = 25 m the visible zone cannot hold 3 starts 50 m apart: the documented fallback of
    Scenario.sample_starts places them (closer, down to d_safe1), the same in both envs."""
    kw = dict(n_uavs=3, config={"d_safe1": 25.0}, max_cycles=2)
    _run_side_by_side(kw, b=6, steps=5)
    venv = covert_env.vector_env(num_envs=6, **kw)
    venv.reset(seed=11)
    xy = venv.copies.xy
    gaps = np.hypot(*(xy[:, :, None] - xy[:, None]).transpose(3, 0, 1, 2)) + np.eye(3) * 1e9
    assert (gaps.min(axis=(1, 2)) < 50.0).any() and (gaps >= 25.0 - 1e-9).all()


@pytest.mark.parametrize("mode", ["unicycle", "waypoint"])
def test_reset_mask_resets_only_those_copies_as_an_automatic_reset_would(mode):
    kw = dict(n_uavs=2, action_mode=mode, max_cycles=5)
    venv = covert_env.vector_env(num_envs=3, **kw)
    with pytest.raises(ValueError, match="full reset"):
        venv.reset(options={"reset_mask": np.ones(3, bool)})
    venv.reset(seed=4)
    rng = np.random.default_rng(1)
    flown = [_actions(venv, rng) for _ in range(2)]
    for act in flown:
        obs, _, _, _, infos = venv.step(act)
    with pytest.raises(ValueError, match="3 bools"):
        venv.reset(options={"reset_mask": [1, 0, 1]})
    with pytest.raises(ValueError, match="not with it"):
        venv.reset(seed=1, options={"reset_mask": np.ones(3, bool)})
    kept = {key: val.copy() for key, val in infos.items() if key in INFO_KEYS}
    new_obs, new_infos = venv.reset(options={"reset_mask": np.array([False, True, False])})
    assert np.array_equal(new_obs[[0, 2]], obs[[0, 2]])
    for key in INFO_KEYS:
        assert np.array_equal(new_infos[key][[0, 2]], kept[key][[0, 2]]), key
    p = covert_env.parallel_env(**kw)
    p.reset(seed=int(venv.copy_seeds[1]))
    for act in flown:
        p.step({a: act[1, i] for i, a in enumerate(p.possible_agents)})
    p_obs, p_inf = p.reset()                              # copy 1's second episode, from its own generator
    _assert_same(new_obs[1:2], {key: val[1:2] for key, val in new_infos.items()}, [(p_obs, p_inf)], [p], "mask")
    assert np.array_equal(venv.state()[1], p.state())


# ----------------------------------------------------------------------------- no autoreset, records, copy views
@pytest.mark.parametrize("mode", ["unicycle", "waypoint"])
def test_disabled_autoreset_records_each_copy_as_the_parallel_env_does(mode):
    """autoreset_mode=DISABLED: ended copies wait (step raises until a reset_mask reset); record=True keeps each
    copy's episode, equal to the parallel env's trajectory (its engine view) for the same seed and actions; a
    copy view reads the copy in the engine's terms."""
    from gymnasium.vector import AutoresetMode

    kw = dict(n_uavs=3, action_mode=mode, max_cycles=4)
    venv = covert_env.vector_env(num_envs=2, autoreset_mode=AutoresetMode.DISABLED, record=True, **kw)
    pars = [covert_env.parallel_env(**kw) for _ in range(2)]
    venv.reset(seed=[11, 12])
    for j, par in enumerate(pars):
        par.reset(seed=11 + j)
    rng = np.random.default_rng(0)
    for _ in range(4):
        if mode == "unicycle":
            act = rng.uniform(-1, 1, (2, 3, 2)).astype(np.float32)
        else:
            act = np.array([[rng.choice(np.flatnonzero(m)) for m in copy] for copy in venv.action_masks()])
        _, _, term, trunc, _ = venv.step(act)
        for j, par in enumerate(pars):
            par.step(dict(zip(par.possible_agents, act[j], strict=True)))
    assert (trunc & ~term).all() and not any(par.agents for par in pars)
    with pytest.raises(RuntimeError, match=r"copies \[0, 1\] ended.*reset_mask"):
        venv.step(act)
    for j, par in enumerate(pars):
        a, b = venv.trajectory(j), par.engine.trajectory()
        for f in ("uav_xy", "uav_theta", "path_xy", "path_length", "target_xyz", "target_path_xyz", "max_speed",
                  "max_turn_rate", "infeasible"):
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)
        view = venv.copy_view(j)
        assert view.k == 4 and view.done is True           # max_cycles=4 ends the episode
        np.testing.assert_array_equal(view.uav_xy, par.engine.uav_xy)
        np.testing.assert_array_equal(view.predict(2)[0], par.engine.predict(2)[0])
        assert venv.scenario(j).uav_xy.tolist() == par.scenario.uav_xy.tolist()
    obs, _ = venv.reset(options={"reset_mask": np.array([False, True])})
    assert venv.slots.tolist() == [4, 0] and venv.trajectory(1).n_slots == 0
    with pytest.raises(RuntimeError, match=r"copies \[0\] ended"):
        venv.step(act)
    with pytest.raises(ValueError, match="autoreset_mode must be one of"):
        covert_env.vector_env(num_envs=1, autoreset_mode="never")
    with pytest.raises(RuntimeError, match="record=True"):
        covert_env.vector_env(num_envs=1).trajectory(0)
    with pytest.raises(ValueError, match=r"copy index must be an integer in \[0, 1\]"):
        venv.copy_view(2)


def test_scene_cache_size_keeps_every_training_scene(monkeypatch):
    """With scene_pool <= scene_cache_size every scene is built once however often it is drawn; below it, scenes
    are rebuilt; and the results do not depend on the cache size."""
    import covert_env.envs.scene_pool as scene_pool

    built = []
    real = scene_pool.SceneCache

    def counting(*a, **kw):
        built.append(kw.get("seed"))
        return real(*a, **kw)

    monkeypatch.setattr(scene_pool, "SceneCache", counting)
    runs = {}
    for size in (12, 4):
        built.clear()
        venv = covert_env.vector_env(num_envs=4, n_uavs=2, scene_pool=12, max_cycles=2, scene_cache_size=size)
        obs, _ = venv.reset(seed=1)
        seen = [obs]
        for _ in range(40):                                  # 20 episodes per copy: 80 draws from 12 scenes
            seen.append(venv.step(np.zeros((4, 2, 2)))[0])
        runs[size] = np.stack(seen)
        if size == 12:
            assert len(built) == len(set(built)) <= 12
        else:
            assert len(built) > len(set(built))               # evicted scenes were built again
    np.testing.assert_array_equal(runs[12], runs[4])


def test_refused_resets_leave_the_batch_usable_and_settings_are_checked():
    """Bad reset options are refused before anything changes; an empty reset_mask is a no-op; scene_seed needs
    random scenes; settings assigned after construction are validated."""
    venv = covert_env.vector_env(num_envs=2, n_uavs=2)
    obs, _ = venv.reset(seed=0)
    rows = venv.slots.copy()
    for options, err in (({"scene_seed": [5, -1]}, ValueError), ([1], TypeError), ({"scene_seed": 1.5}, ValueError),
                         ({"colour": 1, "scene_seed": [5, -1]}, ValueError)):
        with pytest.raises(err):
            venv.reset(options=options)
    again, _ = venv.reset(options={"reset_mask": np.array([False, False])})
    np.testing.assert_array_equal(again, obs)
    assert venv.slots.tolist() == rows.tolist()
    venv.step(np.zeros((2, 2, 2)))                      # still runs
    with pytest.raises(ValueError, match="needs scenario='random'"):
        covert_env.vector_env(num_envs=1, scenario="paper").reset(seed=0, options={"scene_seed": 3})
    for name, value, err in (("reward_scale", 0.0, ValueError), ("terminate_on_collision", 1, TypeError),
                             ("penalties", {"los": -1.0, "zone": 1.0, "separation": 1.0, "terrain": 1.0}, ValueError),
                             ("penalties", {"los": 1.0}, ValueError)):
        with pytest.raises(err, match=name.split("_")[0] if name != "penalties" else "penalt"):
            setattr(venv, name, value)
    with pytest.raises(RuntimeError, match=r"scene\(\) called before reset\(\)"):
        covert_env.vector_env(num_envs=1).scene(0)
    big = covert_env.parallel_env(scenario="paper")
    big.reset(seed=2 ** 64 + 3)                         # Gymnasium's seeding takes any int >= 0
    assert not hasattr(covert_env.parallel_env(), "scenario")


def test_a_scene_that_fails_to_build_leaves_the_pool_and_the_other_copies_as_they_were():
    """A reset whose new scene cannot be built raises, and the pool keeps every scene it had: the copy still flying
    its scene keeps it (a row taken for the failed scene before the build would later be handed to another scene
    while that copy still flies it)."""
    c = Config(n_polytopes=68)                                      # seed 3: the generator cannot place them all
    venv = covert_env.vector_env(num_envs=2, config=c, scene_cache_size=2)
    venv.reset(seed=0, options={"scene_seed": [0, 1]})
    with pytest.raises(ValueError, match="could not place all 68 polytopes"):
        venv.reset(options={"scene_seed": [3, 1], "reset_mask": [True, False]})
    venv.reset(options={"scene_seed": [2, 1], "reset_mask": [True, False]})
    assert [venv.scenario(i).name for i in range(2)] == ["random-2", "random-1"]
    fresh = covert_env.vector_env(num_envs=2, config=c)
    fresh.reset(seed=0, options={"scene_seed": [2, 1]})
    obs = venv.step(np.zeros((2, 3, 2)))[0]
    np.testing.assert_array_equal(obs, fresh.step(np.zeros((2, 3, 2)))[0])
