"""The observation's predicted target path (``target_path=P``): its values against the tracker's predictions, the
default layout unchanged, the vector and parallel envs alike, the checkers, and bad values."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import covert_env
from covert_env.envs.observation import field_slices, observation_table
from covert_env.world.config import Config
from covert_env.world.scenario import Scenario


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


def _in_target_frame(d, phi):
    c, s = np.cos(phi), np.sin(phi)
    return np.stack([c * d[..., 0] + s * d[..., 1], c * d[..., 1] - s * d[..., 0]], axis=-1)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 10_000), error=st.sampled_from([0.0, 1.0, 3.0]), horizon=st.integers(1, 5))
def test_predicted_ahead_is_predict_at_every_slot(seed, error, horizon):
    sc = Scenario.random(seed, Config(prediction_error=error))
    tr = sc.track
    q, phi = tr.predicted_ahead(horizon)
    assert q.shape == (tr.n_slots + 1, horizon, 3) and phi.shape == (tr.n_slots + 1, horizon)
    for k in range(tr.n_slots + 1):
        qk, pk = tr.predict(k, horizon)
        if tr.exact:
            assert np.array_equal(qk, q[k]) and np.array_equal(pk, phi[k])
        else:
            np.testing.assert_allclose(q[k], qk, atol=1e-9)
            np.testing.assert_allclose(phi[k], pk, atol=1e-12)


@pytest.mark.parametrize("task", ["paper-3uav", "paper-3uav-deviating", "winding-3uav"])
def test_path_fields_are_the_trackers_predictions(task):
    """At every slot, the path fields are TargetTrack.predict(k, P) in the target's frame at k (/ R2), and the
    headings' cos, sin of the predicted heading minus the current one."""
    p = 4
    env = covert_env.parallel_env(task=task, action_mode="waypoint", target_path=p)
    obs, _ = env.reset(seed=7, options={"scene_seed": 1_000_003})
    c, tr, at = env.config, env.scenario.track, env.layout.slices
    k = 0
    while env.agents:
        qk, phik = tr.positions[k], tr.headings[k]
        q, phi = tr.predict(k, p)
        want = np.clip(_in_target_frame(q[:, :2] - qk[:2], phik) / c.r2, -5, 5).ravel()
        turn = phi - phik
        for a in env.agents:
            np.testing.assert_allclose(obs[a][at["target_path"]], want, atol=2e-6)
            np.testing.assert_allclose(obs[a][at["target_path_heading"]],
                                       np.stack([np.cos(turn), np.sin(turn)], -1).ravel(), atol=2e-6)
        # The first predicted slot is the one target_displacement already shows.
        disp = obs[env.agents[0]][at["target_displacement"]] * (c.v_max * c.delta / c.r2)
        np.testing.assert_allclose(obs[env.agents[0]][at["target_path"]][:2], disp, atol=2e-6)
        obs, *_ = env.step({a: int(np.flatnonzero(env.action_mask(a))[0]) for a in env.agents})
        k += 1
    assert k == env.episode_length
    env.close()


@pytest.mark.parametrize("mode", ["unicycle", "waypoint"])
def test_default_layout_and_numbers_unchanged(mode):
    """target_path=P only appends fields: the first D entries of every row, the rewards and the infos of a seeded
    rollout are those of the default env, and the state is the default state with the path after it."""
    base = covert_env.parallel_env(n_uavs=3, action_mode=mode, max_cycles=15)
    path = covert_env.parallel_env(n_uavs=3, action_mode=mode, max_cycles=15, target_path=5)
    d = base.observation_space("uav_0").shape[0]
    assert path.observation_space("uav_0").shape[0] == d + 4 * 5
    assert path.state_space.shape[0] == base.state_space.shape[0] + 4 * 5
    o0, _ = base.reset(seed=11)
    o1, _ = path.reset(seed=11)
    rng = np.random.default_rng(0)
    while base.agents:
        for a in base.agents:
            assert np.array_equal(o0[a], o1[a][:d])
        assert np.array_equal(base.state(), path.state()[:base.state_space.shape[0]])
        assert np.array_equal(path.state()[-20:], o1["uav_2"][-20:])
        act = {a: base.action_space(a).sample() if mode == "unicycle" else
               int(rng.choice(np.flatnonzero(base.action_mask(a)))) for a in base.agents}
        o0, r0, *_ = base.step(act)
        o1, r1, *_ = path.step(act)
        assert r0 == r1


def test_vector_env_rows_equal_the_parallel_envs():
    venv = covert_env.vector_env(num_envs=2, n_uavs=2, action_mode="waypoint", target_path=3, task=None)
    obs, _ = venv.reset(seed=5, options={"scene_seed": [1_000_000, 1_000_001]})
    for i, s in enumerate((1_000_000, 1_000_001)):
        penv = covert_env.parallel_env(n_uavs=2, action_mode="waypoint", target_path=3)
        po, _ = penv.reset(seed=5, options={"scene_seed": s})
        assert np.array_equal(obs[i, 0], po["uav_0"]) and np.array_equal(obs[i, 1], po["uav_1"])
    assert venv.target_path == 3 and venv.single_observation_space.contains(obs[0, 0])


def test_layout_field_slices_and_table():
    s = field_slices(3, 8, 5)
    assert s["target_path"] == slice(s["map_next"].stop, s["map_next"].stop + 10)
    assert s["target_path_heading"] == slice(s["target_path"].stop, s["target_path"].stop + 10)
    assert field_slices(3, 8)["target_path"] == slice(s["map_next"].stop, s["map_next"].stop)
    assert "target_path=P" in observation_table() and "then 2P" in observation_table()
    assert "target_path" in covert_env.envs.CovertSensingParallelEnv.__doc__


def test_paper_scenario_gymnasium_and_sb3_checkers():
    from gymnasium.utils.env_checker import check_env
    from pettingzoo.test import parallel_api_test

    parallel_api_test(covert_env.parallel_env(scenario="paper", action_mode="waypoint", target_path=5, max_cycles=8))
    for env_id in ("covert_env/CovertSensing-v4", "covert_env/CovertSensingWaypoint-v4"):
        env = gym.make(env_id, target_path=2, max_cycles=8)
        check_env(env.unwrapped)
        assert env.observation_space.shape[0] == gym.make(env_id).observation_space.shape[0] + 8
    from _extras import needs

    sb3_check_env = needs("stable_baselines3.common.env_checker").check_env
    sb3_check_env(gym.make("covert_env/CovertSensingWaypoint-v4", target_path=5, max_cycles=8).unwrapped, warn=True)


@pytest.mark.parametrize("bad, exc, pattern", [
    (6, ValueError, r"target_path must be an integer in \[0, 5\], got 6"),
    (-1, ValueError, r"target_path must be an integer in \[0, 5\], got -1"),
    (True, TypeError, r"target_path must be an integer, got True"),
    (2.0, TypeError, r"target_path must be an integer, got float 2.0"),
    ("3", TypeError, r"target_path must be an integer, got str '3'"),
])
def test_bad_target_path_names_the_argument(bad, exc, pattern):
    with pytest.raises(exc, match=pattern):
        covert_env.parallel_env(target_path=bad)
    with pytest.raises(exc, match=pattern):
        covert_env.vector_env(num_envs=1, target_path=bad)


def test_target_path_bound_follows_the_horizon():
    env = covert_env.parallel_env(config=Config(horizon=8), target_path=8, max_cycles=3)
    env.reset(seed=0)
    assert env.observation_space("uav_0").shape[0] == covert_env.parallel_env().observation_space("uav_0").shape[0] + 32
    with pytest.raises(ValueError, match=r"target_path must be an integer in \[0, 2\], got 3"):
        covert_env.parallel_env(config=Config(horizon=2), target_path=3)
