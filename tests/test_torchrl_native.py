"""The TorchRL-native env on the vector env: TorchRL's spec checker in both action modes, rollouts and a collector
across episode ends, the same episodes as the vector env for the same seed and actions, partial resets, and
``import covert_env`` staying free of torch."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from _extras import needs

torchrl = needs("torchrl")
import torch  # noqa: E402
from torchrl.envs.utils import check_env_specs, step_mdp  # noqa: E402

import covert_env  # noqa: E402
from covert_env.integrations.torchrl import make_torchrl_env  # noqa: E402

torch.set_num_threads(1)


def test_import_covert_env_does_not_import_torch():
    code = ("import sys, covert_env, covert_env.integrations, covert_env.envs.vector; "
            "assert 'torch' not in sys.modules and 'torchrl' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.parametrize("mode, categorical", [("unicycle", True), ("waypoint", True), ("waypoint", False)])
def test_check_env_specs(mode, categorical):
    env = make_torchrl_env(num_envs=3, action_mode=mode, n_uavs=2, max_cycles=3, categorical_actions=categorical)
    check_env_specs(env, seed=0)
    assert env.batch_size == torch.Size([3])
    assert env.full_reward_spec["uav", "reward"].shape == (3, 2, 1)
    assert env.full_done_spec["done"].shape == (3, 1) and env.full_done_spec["uav", "done"].shape == (3, 2, 1)
    assert env.observation_spec["state"].shape == (3, env.vector_env.state_space.shape[1])
    assert ("uav", "action_mask") in env.observation_spec.keys(True) if mode == "waypoint" else True


@pytest.mark.parametrize("mode", ["unicycle", "waypoint"])
def test_rollout_across_episode_ends(mode):
    env = make_torchrl_env(num_envs=8, action_mode=mode, n_uavs=3, max_cycles=4)
    env.set_seed(3)
    td = env.rollout(100, break_when_any_done=False)      # random actions, within the masks in waypoint mode
    assert td.batch_size == torch.Size([8, 100])
    done = td["next", "done"][..., 0]
    assert done.sum() == 8 * 25 and done[:, 3::4].all()
    slot = td["uav", "info", "slot"]
    assert (slot[:, 0::4] == 0).all() and (td["next", "uav", "info", "slot"][:, 3::4] == 4).all()
    assert (td["next", "uav", "done"][..., 0] == done[..., None]).all()
    assert torch.isfinite(td["next", "uav", "reward"]).all()
    if mode == "waypoint":
        # rand_action reads the mask off the spec
        assert td["uav", "action_mask"].gather(-1, td["uav", "action"][..., None]).all()


@pytest.mark.parametrize("mode", ["unicycle", "waypoint"])
def test_same_episodes_as_the_vector_env(mode):
    kw = dict(action_mode=mode, n_uavs=3, max_cycles=3)
    b, steps = 4, 8
    venv = covert_env.vector_env(num_envs=b, **kw)
    obs, _ = venv.reset(seed=21)
    env = make_torchrl_env(num_envs=b, **kw)
    td = env.reset(seed=21)
    rng = np.random.default_rng(5)
    for t in range(steps):
        masks = venv.action_masks()
        assert np.array_equal(td["uav", "observation"].numpy(), obs), f"step {t}"
        assert np.array_equal(td["state"].numpy(), venv.state()), f"step {t}"
        if mode == "waypoint":
            assert np.array_equal(td["uav", "action_mask"].numpy(), masks.astype(bool)), f"step {t}"
            act = np.array([[rng.choice(np.flatnonzero(m)) for m in row] for row in masks])
        else:
            act = rng.uniform(-1, 1, (b, 3, 2)).astype(np.float32)
        obs, rew, term, trunc, infos = venv.step(act)
        td["uav", "action"] = torch.from_numpy(act)
        td = env.step(td)
        nxt = td["next"]
        done = term[:, 0] | trunc[:, 0]
        assert np.array_equal(nxt["done"].numpy()[:, 0], done)
        assert np.array_equal(nxt["uav", "reward"].numpy()[..., 0], rew.astype(np.float32)), f"step {t}"
        last = infos["final_obs"] if done.any() else obs
        assert np.array_equal(nxt["uav", "observation"].numpy()[done], last[done])
        assert np.array_equal(nxt["uav", "observation"].numpy()[~done], obs[~done])
        if done.any():
            assert np.array_equal(nxt["state"].numpy()[done], infos["final_state"][done])
            assert np.array_equal(nxt["uav", "info", "cost"].numpy()[done], infos["final_info"]["cost"][done])
        td = env.maybe_reset(step_mdp(td))                # TorchRL resets the ended copies (the "_reset" mask)
    assert (nxt["uav", "info", "slot"] > 0).all()


def test_partial_reset_of_running_copies():
    env = make_torchrl_env(num_envs=3, n_uavs=2, max_cycles=5)
    td = env.reset(seed=1)
    td = step_mdp(env.step(env.rand_action(td)))
    before = td["uav", "observation"].clone()
    td.set("_reset", torch.tensor([[True], [False], [False]]))
    out = env.reset(td)
    assert out["uav", "info", "slot"].tolist() == [[0, 0], [1, 1], [1, 1]]
    assert torch.equal(out["uav", "observation"][1:], before[1:])
    assert not torch.equal(out["uav", "observation"][0], before[0])
    nxt = env.step(env.rand_action(out))["next"]
    assert nxt["uav", "info", "slot"].tolist() == [[1, 1], [2, 2], [2, 2]]
    env.set_seed(9)                                       # kept for the next reset of every copy
    td = step_mdp(env.step(env.rand_action(out)))
    td.set("_reset", torch.tensor([[False], [True], [False]]))
    assert env.reset(td)["uav", "info", "slot"].tolist() == [[2, 2], [0, 0], [3, 3]]
    venv = covert_env.vector_env(num_envs=3, n_uavs=2, max_cycles=5)
    assert torch.equal(env.reset()["uav", "observation"], torch.from_numpy(venv.reset(seed=9)[0]))


@pytest.mark.parametrize("mode", ["unicycle", "waypoint"])
def test_sync_data_collector(mode):
    import torchrl.collectors as collectors

    # TorchRL 0.14 names it Collector; SyncDataCollector before (BenchMARL's torchrl 0.11).
    SyncDataCollector = getattr(collectors, "Collector", None) or collectors.SyncDataCollector
    env = make_torchrl_env(num_envs=8, action_mode=mode, n_uavs=3, max_cycles=5)
    policy = _masked_policy(env) if mode == "waypoint" else None     # None: random actions from the spec
    collector = SyncDataCollector(env, policy=policy, frames_per_batch=80, total_frames=320)
    frames = 0
    for batch in collector:
        frames += batch.numel()
        assert batch["next", "uav", "reward"].shape[-2:] == (3, 1)
        if mode == "waypoint":
            assert batch["uav", "action_mask"].gather(-1, batch["uav", "action"][..., None]).all()
    collector.shutdown()
    assert frames == 320


def _masked_policy(env):
    """A shared MLP's logits sampled by ``MaskedCategorical`` with the mask (docs/frameworks.md, TorchRL)."""
    from tensordict.nn import TensorDictModule
    from torchrl.modules import MaskedCategorical, MultiAgentMLP, ProbabilisticActor

    n_obs = env.observation_spec["uav", "observation"].shape[-1]
    n_act = env.full_action_spec["uav", "action"].space.n
    logits = TensorDictModule(
        MultiAgentMLP(n_agent_inputs=n_obs, n_agent_outputs=n_act, n_agents=len(env.agent_names),
                      centralized=False, share_params=True, depth=1, num_cells=32),
        in_keys=[("uav", "observation")], out_keys=[("uav", "logits")])
    return ProbabilisticActor(logits, in_keys={"logits": ("uav", "logits"), "mask": ("uav", "action_mask")},
                              out_keys=[("uav", "action")], distribution_class=MaskedCategorical)


def test_check_env_specs_with_the_target_path():
    """target_path=P widens the observation and the state by 4 P: TorchRL's checker at its default arguments."""
    env = make_torchrl_env(num_envs=2, action_mode="waypoint", n_uavs=2, max_cycles=3, target_path=3)
    base = make_torchrl_env(num_envs=2, action_mode="waypoint", n_uavs=2, max_cycles=3)
    check_env_specs(env)
    width = env.observation_spec["uav", "observation"].shape[-1]
    assert width == base.observation_spec["uav", "observation"].shape[-1] + 12
    assert env.observation_spec["state"].shape[-1] == base.observation_spec["state"].shape[-1] + 12
