"""The env with the RL frameworks researchers train with: TorchRL, BenchMARL, Tianshou, Stable-Baselines3, RLlib.

Every ```python framework=NAME``` snippet of docs/frameworks.md (the documentation's frameworks page) is run here,
then checked. Tests of a
framework skip when it is not installed, so the main suite runs anywhere; CI installs each framework in its own
virtualenv (.ci/run) and runs ``pytest tests/test_frameworks.py -k NAME`` there.
"""

from __future__ import annotations

import csv
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _extras import needs

import covert_env

ROOT = Path(__file__).resolve().parents[1]
#: Framework tag of a snippet -> the module whose absence skips it.
FRAMEWORKS = {"sb3": "sb3_contrib", "rllib": "ray.rllib", "torchrl": "torchrl", "benchmarl": "benchmarl",
              "tianshou": "tianshou"}
#: The env's per-agent infos (besides the waypoint mask), the same at reset and every step.
INFO_KEYS = {"slot", "reward_path", "reward_disguise", "reward_los", "reward_los_path", "reward_zone",
             "reward_separation", "reward_terrain", "cost", "cost_los", "cost_los_path", "cost_zone", "cost_separation",
             "cost_terrain", "los", "los_path", "in_zone", "infeasible", "kappa", "g", "v", "separation",
             "terrain_clearance"}
_SNIPPET = re.compile(r"^```python framework=(\w+)\n(.*?)^```", re.S | re.M)


def _snippets(path: Path) -> list[tuple[str, str]]:
    return [(m.group(1), m.group(2)) for m in _SNIPPET.finditer(path.read_text(encoding="utf-8"))]


def _all_snippets() -> list[tuple[str, str]]:
    """The frameworks page's snippets."""
    return _snippets(ROOT / "docs" / "frameworks.md")


def _snippet_params():
    count: dict[str, int] = {}
    params = []
    for fw, code in _all_snippets():
        i = count[fw] = count.get(fw, -1) + 1
        params.append(pytest.param(fw, code, id=f"{fw}-{i}"))
    return params


# ----------------------------------------------------------------------------- docs (no framework needed)
def test_the_frameworks_page_covers_every_framework_and_the_readme_links_it():
    page = {fw for fw, _ in _all_snippets()}
    assert page == set(FRAMEWORKS), f"docs/frameworks.md snippets for {sorted(page)}, want {sorted(FRAMEWORKS)}"
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert "](docs/frameworks.md)" in readme
    for name in ("Stable-Baselines3", "RLlib", "TorchRL", "BenchMARL", "Tianshou"):
        assert name in readme, f"the README does not name {name}"


def test_integrations_are_not_imported_by_import_covert_env():
    code = ("import sys, covert_env; bad = [m for m in sys.modules if m.startswith('covert_env.integrations') "
            "or m.split('.')[0] in ('benchmarl', 'torchrl', 'tianshou', 'tensordict')]; assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


# ----------------------------------------------------------------------------- every snippet, run and checked
def _mask_respected(mask, action) -> bool:
    """``action[..., ]`` (indices) is allowed by ``mask[..., L]`` everywhere."""
    import torch

    return bool(torch.as_tensor(mask).gather(-1, torch.as_tensor(action).long().unsqueeze(-1)).all())


def _check_sb3(ns):
    assert ns["model"].num_timesteps >= 64 and ns["team"].num_timesteps >= 192
    assert ns["venv"].num_envs == 6
    env, model = ns["env"], ns["model"]
    obs, _ = env.reset(seed=3)
    masked = 0
    for _ in range(10):
        mask = env.unwrapped.action_masks()
        assert mask.dtype == bool and mask.any()
        masked += int(not mask.all())
        action, _ = model.predict(obs, action_masks=mask)
        assert mask[int(action)], "MaskablePPO picked a masked waypoint"
        obs, *_ = env.step(action)
    assert masked, "the mask never excluded a waypoint"


def _check_rllib(ns):
    runners = ns["result"]["env_runners"]
    assert runners["num_env_steps_sampled_lifetime"] >= 192
    assert math.isfinite(runners["episode_return_mean"])


def _check_torchrl(ns):
    td, env = ns["td"], ns["env"]
    if hasattr(env, "vector_env"):                       # the native env (B copies): td is [B, T]
        pz = env.vector_env
        assert td.batch_size == (pz.num_envs, 100)
        td = td.reshape(-1)
        assert td["state"].shape == (td.batch_size[0], *pz.single_state_space.shape)
    else:
        pz = env._env
        assert td.batch_size[0] in (100, 20)
        assert td["state"].shape == (td.batch_size[0], *pz.state_space.shape)
    n = td.batch_size[0]
    assert td["uav", "action_mask"].shape == (n, 3, len(pz.lattice))
    assert _mask_respected(td["uav", "action_mask"], td["uav", "action"]), "an action outside the mask"
    assert set(td["next", "uav", "info"].keys()) == INFO_KEYS


def _check_benchmarl(ns):
    exp = ns["experiment"]
    assert exp.total_frames == 400 and exp.n_iters_performed == 2
    losses = _csv_values(Path(exp.folder_name), "train_uav_loss_objective")
    assert len(losses) == 2 and all(math.isfinite(v) for v in losses)
    assert _csv_values(Path(exp.folder_name), "collection_uav_info_cost")


def _check_tianshou(ns):
    assert ns["result"].train_step >= 210
    batch, _ = ns["buffer"].sample(0)
    assert len(batch) >= 210
    assert set(batch.obs.agent_id) == {"uav_0", "uav_1", "uav_2"}
    assert batch.obs.mask.shape[1] == ns["env"].action_space.n
    assert not batch.obs.mask.all(), "the waypoint mask never reached Tianshou"
    assert batch.obs.mask[np.arange(len(batch)), batch.act].all(), "a DQN action outside the mask"


_CHECKS = {"sb3": _check_sb3, "rllib": _check_rllib, "torchrl": _check_torchrl, "benchmarl": _check_benchmarl,
           "tianshou": _check_tianshou}


@pytest.mark.slow
@pytest.mark.parametrize(("framework", "code"), _snippet_params())
def test_snippet(framework, code, tmp_path, monkeypatch):
    needs(FRAMEWORKS[framework])
    monkeypatch.chdir(tmp_path)                      # BenchMARL and SB3 write logs to the current folder
    monkeypatch.syspath_prepend(str(ROOT))           # `from training.sb3.vec_env import ...`
    ns: dict = {"__name__": f"snippet_{framework}"}
    exec(compile(code, f"<{framework} snippet>", "exec"), ns)
    _CHECKS[framework](ns)


# ----------------------------------------------------------------------------- TorchRL
MODES = [("unicycle", False), ("waypoint", False), ("waypoint", True)]


def _torchrl_env(mode, dict_obs, **kw):
    from torchrl.envs import PettingZooWrapper

    pz = covert_env.parallel_env(n_uavs=3, action_mode=mode, dict_obs=dict_obs, **kw)
    return pz, PettingZooWrapper(env=pz, return_state=True, seed=0)


@pytest.mark.parametrize(("mode", "dict_obs"), MODES, ids=["unicycle", "waypoint", "waypoint-dict_obs"])
def test_torchrl_check_env_specs_and_rollout(mode, dict_obs):
    needs("torchrl")
    import torch
    from torchrl.envs.utils import check_env_specs

    pz, env = _torchrl_env(mode, dict_obs)
    check_env_specs(env)
    assert env.group_map == {"uav": ["uav_0", "uav_1", "uav_2"]}
    td = env.rollout(100, break_when_any_done=False)       # crosses the end of the 70-slot episode
    assert td.batch_size == (100,)
    obs_key = ("uav", "observation", "observation") if dict_obs else ("uav", "observation")
    n_obs = (pz.observation_space("uav_0")["observation"] if dict_obs else pz.observation_space("uav_0")).shape[0]
    assert td[obs_key].shape == (100, 3, n_obs) and td[obs_key].dtype == torch.float32
    assert td["state"].shape == (100, *pz.state_space.shape)
    assert torch.allclose(td["next", "state"][-1], torch.as_tensor(pz.state()))
    assert td["next", "uav", "reward"].shape == (100, 3, 1)
    done = td["next", "done"].reshape(100)
    assert done.nonzero().flatten().tolist() == [69], "one truncation, at the end of the route"
    assert td["next", "truncated"].reshape(100)[69] and not td["next", "terminated"].any()
    info = td["next", "uav", "info"]
    assert set(info.keys()) == INFO_KEYS
    assert set(td["uav", "info"].keys()) == INFO_KEYS               # from reset: the same keys
    # The infos arrive as float32 tensors: the share cost_los_path is rounded on its own and in the sum.
    assert torch.allclose(info["cost"], info["cost_los"] + info["cost_los_path"] + info["cost_zone"]
                          + info["cost_separation"] + info["cost_terrain"], atol=1e-6)
    assert torch.equal(info["cost_los"], 1 - info["los"]) and torch.equal(info["cost_zone"], 1 - info["in_zone"])
    assert ((info["cost_los_path"] >= 0) & (info["cost_los_path"] <= 1)).all()
    assert torch.equal(info["cost_los_path"] == 0, info["los_path"].bool())
    assert info["slot"][:69, 0].tolist() == list(range(1, 70))
    terms = sum(info[k] for k in INFO_KEYS if k.startswith("reward_"))
    assert torch.allclose(terms, td["next", "uav", "reward"].squeeze(-1), atol=1e-5)
    if mode == "waypoint":
        mask = td["uav", "action_mask"]
        assert mask.shape == (100, 3, len(pz.lattice)) and mask.dtype == torch.bool
        assert 0 < mask.sum() < mask.numel()
        assert env.full_action_spec["uav", "action"].space.n == len(pz.lattice)
        assert _mask_respected(mask, td["uav", "action"]), "a random action outside the mask"
        # An allowed node is reachable, so it is flown exactly; only where no node was reachable (the documented
        # fallback: every node allowed) may the manoeuvre be infeasible.
        strict = ~mask.all(-1)
        assert strict.any() and not info["infeasible"][strict].any(), "an allowed waypoint was infeasible"
    else:
        assert ("uav", "action_mask") not in td.keys(True)
        assert td["uav", "action"].shape == (100, 3, 2)


@pytest.mark.parametrize("dict_obs", [False, True], ids=["infos", "dict_obs"])
def test_torchrl_masks_equal_env_action_mask(dict_obs):
    needs("torchrl")
    from torchrl.envs.utils import step_mdp

    pz, env = _torchrl_env("waypoint", dict_obs, max_cycles=12)
    td = env.reset()
    for t in range(12):
        mask = td["uav", "action_mask"].numpy()
        for i, agent in enumerate(pz.possible_agents):
            np.testing.assert_array_equal(mask[i], pz.action_mask(agent).astype(bool), err_msg=f"slot {t} {agent}")
        np.testing.assert_allclose(td["state"].numpy(), pz.state(), rtol=0, atol=0)
        td = env.rand_step(td)
        assert _mask_respected(mask, td["uav", "action"])
        td = step_mdp(td)
    assert td["done"].item()


# ----------------------------------------------------------------------------- BenchMARL
def _csv_values(folder: Path, name: str) -> list[float]:
    files = list(folder.rglob(f"{name}.csv"))
    assert files, f"no {name}.csv under {folder}"
    with files[0].open() as f:
        return [float(row[-1]) for row in csv.reader(f) if row]


@pytest.mark.parametrize("task_name", ["UNICYCLE", "WAYPOINT"])
def test_benchmarl_task_specs(task_name):
    needs("benchmarl")
    from covert_env.integrations.benchmarl import CovertSensingTask

    task = CovertSensingTask[task_name].get_task()
    waypoint = task_name == "WAYPOINT"
    assert task.supports_discrete_actions() is waypoint and task.supports_continuous_actions() is not waypoint
    env = task.get_env_fun(num_envs=1, continuous_actions=not waypoint, seed=0, device="cpu")()
    pz = covert_env.parallel_env(n_uavs=3, action_mode=task_name.lower())
    assert task.group_map(env) == {"uav": ["uav_0", "uav_1", "uav_2"]}
    assert task.max_steps(env) == 70
    assert task.observation_spec(env)["uav", "observation"].shape == (3, pz.observation_space("uav_0").shape[0])
    assert task.state_spec(env)["state"].shape == pz.state_space.shape
    assert set(task.info_spec(env)["uav", "info"].keys()) == INFO_KEYS
    mask_spec = task.action_mask_spec(env)
    action = task.action_spec(env)["uav", "action"]
    if waypoint:
        assert mask_spec["uav", "action_mask"].shape == (3, len(pz.lattice))
        assert action.space.n == len(pz.lattice)
    else:
        assert mask_spec is None and action.shape == (3, 2)
    # Each env built by one env function has its own seed, so BenchMARL's copies fly different scenes.
    make = task.get_env_fun(num_envs=2, continuous_actions=not waypoint, seed=0, device="cpu")
    a, b = make(), make()
    assert not np.array_equal(a.reset()["state"].numpy(), b.reset()["state"].numpy())


def test_benchmarl_task_config():
    needs("benchmarl")
    from covert_env.integrations.benchmarl import CovertSensingTask

    task = CovertSensingTask.UNICYCLE.get_task(config={"n_uavs": 1, "max_cycles": 20,
                                                        "env_kwargs": {"los_penalty": 2.0}})
    env = task.get_env_fun(num_envs=1, continuous_actions=True, seed=0, device="cpu")()
    assert task.group_map(env) == {"uav": ["uav_0"]} and task.max_steps(env) == 20
    assert env._env.penalties["los"] == 2.0
    assert CovertSensingTask.WAYPOINT.get_task(config={"max_cycles": 1000}).max_steps(env) == 70   # the route
    suite = CovertSensingTask.WAYPOINT.get_task(config={"suite_task": "downtown-6uav"})
    env = suite.get_env_fun(num_envs=1, continuous_actions=False, seed=0, device="cpu")()
    assert suite.group_map(env) == {"uav": [f"uav_{i}" for i in range(6)]}
    assert env._env.task == "downtown-6uav" and env._env.config.n_polytopes == 56
    dense = CovertSensingTask.UNICYCLE.get_task(config={"family": "dense", "n_uavs": 1})
    env = dense.get_env_fun(num_envs=1, continuous_actions=True, seed=0, device="cpu")()
    assert env._env.family == "dense" and suite.group_map(env) == {"uav": ["uav_0"]}
    with pytest.raises(ValueError, match="flies 3 UAV"):
        CovertSensingTask.UNICYCLE.get_task(config={"suite_task": "paper-3uav", "n_uavs": 1}).get_env_fun(
            1, True, 0, "cpu")()
    with pytest.raises(ValueError, match="unknown fields.*'n_uav'"):
        CovertSensingTask.UNICYCLE.get_task(config={"n_uav": 3}).get_env_fun(1, True, 0, "cpu")
    with pytest.raises(ValueError, match="env_kwargs may not set.*action_mode"):
        CovertSensingTask.UNICYCLE.get_task(config={"env_kwargs": {"action_mode": "waypoint"}}).max_steps(env)


try:  # a module-level class: BenchMARL pickles its callbacks
    from benchmarl.experiment.callback import Callback as _Callback
except ImportError:
    _Callback = object


class _KeepBatches(_Callback):
    """BenchMARL callback keeping every collected batch."""

    batches: list = []

    def on_batch_collected(self, batch):
        self.batches.append(batch.clone())


@pytest.mark.parametrize(("task_name", "vectorized"), [("UNICYCLE", False), ("WAYPOINT", False), ("UNICYCLE", True),
                                                       ("WAYPOINT", True)])
def test_benchmarl_smoke_run(task_name, vectorized, tmp_path):
    """A few hundred frames of MAPPO on the shipped task: frames collected, losses finite, masks respected."""
    needs("benchmarl")
    from benchmarl.algorithms import MappoConfig
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models import MlpConfig

    from covert_env.integrations.benchmarl import CovertSensingTask

    config = ExperimentConfig.get_from_yaml()
    config.max_n_frames = 300
    config.on_policy_collected_frames_per_batch = 100
    config.on_policy_n_envs_per_worker = 2 if vectorized else 1    # vectorized: 2 copies, one batched env
    config.on_policy_minibatch_size = 50
    config.on_policy_n_minibatch_iters = 1
    config.evaluation = False
    config.loggers = ["csv"]
    config.create_json = False
    config.save_folder = str(tmp_path)
    exp = Experiment(task=CovertSensingTask[task_name].get_task(config={"max_cycles": 40, "vectorized": vectorized}),
                     algorithm_config=MappoConfig.get_from_yaml(), model_config=MlpConfig.get_from_yaml(),
                     seed=0, config=config, callbacks=[_KeepBatches()])
    _KeepBatches.batches.clear()
    exp.run()
    assert exp.total_frames == 300 and exp.n_iters_performed == 3 and len(_KeepBatches.batches) == 3
    for name in ("train_uav_loss_objective", "train_uav_loss_critic"):
        values = _csv_values(tmp_path, name)
        assert len(values) == 3 and all(math.isfinite(v) for v in values)
    assert len(_csv_values(tmp_path, "collection_uav_info_cost")) == 3
    for batch in _KeepBatches.batches:
        assert batch["state"].shape[-1] == 155
        assert batch["next", "done"].sum() >= 2                        # 100 frames, 40-slot episodes
        if task_name == "WAYPOINT":
            assert _mask_respected(batch["uav", "action_mask"], batch["uav", "action"]), "MAPPO left the mask"


@pytest.mark.parametrize("algorithm", ["mappo", "ippo"])
def test_benchmarl_hydra_runner(tmp_path, algorithm):
    """``python -m covert_env.integrations.benchmarl algorithm=... task=covert_sensing/...`` (hydra overrides only):
    BenchMARL's own MAPPO and IPPO on the waypoint task with its action masks."""
    needs("benchmarl")
    overrides = [f"algorithm={algorithm}", "task=covert_sensing/waypoint", "task.n_uavs=2", "task.max_cycles=20",
                 "experiment.max_n_frames=100", "experiment.on_policy_collected_frames_per_batch=100",
                 "experiment.on_policy_n_envs_per_worker=1", "experiment.on_policy_minibatch_size=50",
                 "experiment.on_policy_n_minibatch_iters=1", "experiment.evaluation=false",
                 "experiment.loggers=[csv]", "experiment.create_json=false", f"hydra.run.dir={tmp_path}"]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p)}
    subprocess.run([sys.executable, "-m", "covert_env.integrations.benchmarl", *overrides], check=True,
                   cwd=tmp_path, env=env, capture_output=True, timeout=600)
    assert len(_csv_values(tmp_path, "train_uav_loss_objective")) == 1


# ----------------------------------------------------------------------------- Tianshou
def test_tianshou_mask_only_with_dict_obs():
    """Tianshou reads the mask from ``observation["action_mask"]`` only: dict_obs=True is the setting it needs."""
    needs("tianshou")
    from tianshou.env import PettingZooEnv

    with_mask, _ = PettingZooEnv(covert_env.env(n_uavs=3, action_mode="waypoint", dict_obs=True)).reset(seed=0)
    without, _ = PettingZooEnv(covert_env.env(n_uavs=3, action_mode="waypoint")).reset(seed=0)
    aec = covert_env.env(n_uavs=3, action_mode="waypoint")
    aec.reset(seed=0)
    expected = aec.unwrapped.action_mask("uav_0").astype(bool)
    assert with_mask["agent_id"] == "uav_0"
    np.testing.assert_array_equal(with_mask["mask"], expected)
    assert not expected.all() and all(without["mask"]), "without dict_obs Tianshou allows every action"
