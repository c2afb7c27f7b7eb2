"""The SB3 adapter on the vector env gives what the ParallelEnv adapter gives for the same seed, and trains."""

from __future__ import annotations

import numpy as np
import pytest
from _extras import needs

needs("stable_baselines3")

from covert_env.envs.vector import INFO_KEYS  # noqa: E402
from training.sb3.vec_env import make_vec_env  # noqa: E402
from training.sb3.vector_adapter import make_vector_vec_env  # noqa: E402


@pytest.mark.parametrize("mode", ["unicycle", "waypoint"])
def test_same_results_as_the_parallel_env_adapter(mode):
    kw = dict(n_uavs=2, action_mode=mode, max_cycles=3)
    new, old = make_vector_vec_env(3, kw), make_vec_env(3, kw)
    for v in (new, old):
        v.seed(5)
    obs_new, obs_old = new.reset(), old.reset()
    assert np.array_equal(obs_new, obs_old) and obs_new.dtype == obs_old.dtype
    rng = np.random.default_rng(0)
    ends = 0
    for _ in range(7):
        if mode == "unicycle":
            act = rng.uniform(-1, 1, (6, 2)).astype(np.float32)
        else:
            masks = np.array(new.env_method("action_masks"))
            assert np.array_equal(masks, np.array(old.env_method("action_masks")))
            act = np.array([rng.choice(np.flatnonzero(m)) for m in masks])
        a, b = new.step(act), old.step(act)
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]) and np.array_equal(a[2], b[2])
        assert a[1].dtype == b[1].dtype and a[2].dtype == b[2].dtype
        for info_new, info_old in zip(a[3], b[3], strict=True):
            assert {k: info_new[k] for k in INFO_KEYS} == {k: info_old[k] for k in INFO_KEYS}
            assert ("terminal_observation" in info_new) == ("terminal_observation" in info_old)
            if "terminal_observation" in info_new:
                ends += 1
                assert np.array_equal(info_new["terminal_observation"], info_old["terminal_observation"])
                assert info_new["TimeLimit.truncated"] == info_old["TimeLimit.truncated"] is True
    assert ends == 12                                     # every row ended twice


def test_ppo_trains_on_it_with_reward_shaping():
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor

    shaped = []
    venv = VecMonitor(make_vector_vec_env(4, dict(n_uavs=3, max_cycles=5),
                                          reward_fn=lambda r, info: shaped.append(info["env_reward"]) or r - 1.0))
    PPO("MlpPolicy", venv, n_steps=16, batch_size=48, n_epochs=1, seed=0, device="cpu").learn(32)
    assert len(shaped) >= 16 * 12                         # one rollout of 16 steps x 12 rows, all shaped
    with pytest.raises(ValueError, match="shape"):
        venv.step(np.zeros((5, 2)))
