"""Multi-agent PPO on RLlib (new API stack): one shared policy for every UAV, for training beyond one machine.

Install the extra: ``pip install -e ".[rllib]"``. The env goes through RLlib's ``ParallelPettingZooEnv``; every agent
maps to the module ``shared_policy`` (parameter sharing, as in :mod:`training.sb3.ppo_multi`).

    PYTHONHASHSEED=0 OMP_NUM_THREADS=1 python -m training.rllib_ppo --iterations 200 --num-env-runners 2
    ray start --head                                        # or join an existing cluster:
    PYTHONHASHSEED=0 python -m training.rllib_ppo --address auto --num-env-runners 16
    python -m training.rllib_ppo --resume runs/<run>/checkpoint --trust-checkpoint --iterations 100
    covert-env evaluate --policies random dp rllib:runs/<run>/checkpoint --trust-checkpoint

Checkpoints: ``runs/{env}__rllib_ppo__{seed}__{time}/checkpoint`` (``Algorithm.save_to_path``), with
``args.json`` beside it. They are pickled: ``--resume`` and :func:`load_policy` load one only with
``--trust-checkpoint`` / ``trust_checkpoint=True`` (:mod:`training.trust`).

Inference without Ray running (what the evaluation harness does, :func:`load_policy`): the checkpoint holds the
RLModule's own state under ``learner_group/learner/rl_module/shared_policy``; ``RLModule.from_checkpoint`` on
that folder rebuilds it as a plain torch module, no ``ray.init()``, no cluster::

    from ray.rllib.core.rl_module.rl_module import RLModule
    module = RLModule.from_checkpoint(ckpt / "learner_group/learner/rl_module/shared_policy")
    out = module.forward_inference({"obs": torch.as_tensor(obs_batch)})       # obs of all agents, stacked
    mean = out["action_dist_inputs"][:, :2]       # Gaussian (mean, log_std); act with clip(mean, -1, 1)

Pitfalls (each cost us time):

* ``PYTHONHASHSEED``: ``ParallelPettingZooEnv`` keeps the agent ids in a ``set``, whose order depends on string
  hashing, so without a fixed ``PYTHONHASHSEED`` two runs with the same ``seed`` differ. It must be set before
  Python starts (export it); the script passes it on to the workers through ``runtime_env`` and warns if unset.
* One torch thread per worker: every env runner and learner otherwise starts as many torch/OpenMP threads as
  there are cores, which oversubscribes small machines badly (docs/training.md). We set
  ``OMP_NUM_THREADS=1`` in the workers' ``runtime_env`` and ``torch.set_num_threads(1)`` in the env creator.
* ``clip_actions``: RLlib samples Gaussian actions without bounds; with ``clip_actions=True`` they are clipped
  to the Box before ``env.step``. (Our env clips out-of-range actions itself, documented, but other envs raise.)
  At inference take the Gaussian mean and clip it to [-1, 1] too.
* ``sample_timeout_s``: with remote env runners on a busy machine RLlib's default 60 s sample timeout can expire
  and the iteration then reports no episodes (``episode_return_mean`` missing) instead of failing; we wait 600 s.
* ``ParallelPettingZooEnv`` resets the env once in its constructor (harmless here); our env's flat infos
  (rewards' terms, constraint costs) pass through untouched.
"""

from __future__ import annotations

import json
import os
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from baselines.policies import parallel_env_of
from covert_env.command_line import UsageError, read_run_json
from covert_env.envs.covert_sensing import CovertSensingParallelEnv
from training.common import parse_args, resumed_args, run_name, save_run, setup_torch
from training.run_args import TrainingArgs
from training.runs import run_env
from training.trust import require_trust

ALGO = "rllib_ppo"
ENV_NAME = "covert_sensing_v4"
MODULE_ID = "shared_policy"


@dataclass
class Args(TrainingArgs):
    env_id: str = ENV_NAME
    """name of the env in run names and the Ray env registry"""
    seed: int = 0
    """seed of the algorithm (env runners get seed + worker index)"""
    time_budget_minutes: float = 0.0
    """stop after the iteration that crosses this wall-clock budget and save (0: no budget)"""
    torch_threads: int = 1
    """torch threads of the driver's learner (the env runners use one each; with --num-env-runners 0 the driver
    samples too, with one)"""
    n_uavs: int = 3
    """UAVs per env (all share one policy)"""
    action_mode: str = "unicycle"
    """'unicycle' (continuous, the supported mode) or 'waypoint'"""
    los_penalty: float = 2.0
    """training reward: penalty per slot with blocked LoS (as the SB3 recipe)"""
    zone_penalty: float = 2.0
    """training reward: base penalty per slot outside the feasible zone (as the SB3 recipe)"""
    iterations: int = 100
    """training iterations (algo.train() calls)"""
    num_env_runners: int = 1
    """remote env-runner actors (0: sample in the driver process)"""
    num_envs_per_env_runner: int = 1
    """vectorised env copies per env runner"""
    sample_timeout_s: float = 600.0
    """how long the driver waits for remote env runners per iteration (RLlib's 60 s default times out on busy
    2-core machines and the iteration silently trains on nothing)"""
    address: str = ""
    """Ray cluster address to join ('auto' for a local `ray start` cluster); empty: start a local Ray"""
    train_batch_size: int = 2048
    """env-steps per training iteration (RLlib counts env steps; x n_uavs agent-steps)"""
    minibatch_size: int = 512
    """SGD minibatch size"""
    num_epochs: int = 5
    """SGD epochs per iteration"""
    lr: float = 3e-4
    """learning rate"""
    gamma: float = 0.97
    """discount factor"""
    lambda_: float = 0.95
    """GAE lambda"""
    net_arch: tuple[int, ...] = (128, 128)
    """hidden layers of the shared policy/value MLP"""
    checkpoint_every: int = 10
    """save a checkpoint every this many iterations (0: only at the end)"""
    resume: str = ""
    """a checkpoint folder to continue from (pickled: needs --trust-checkpoint)"""
    trust_checkpoint: bool = False
    """allow --resume to load the checkpoint, which is pickled and runs any code it carries: only for a
    checkpoint from a source you trust"""


def env_kwargs(args: Args) -> dict:
    return dict(n_uavs=args.n_uavs, action_mode=args.action_mode, max_cycles=args.max_cycles,
                scene_pool=args.scene_pool, los_penalty=args.los_penalty, zone_penalty=args.zone_penalty)


def _env_creator(env_config: dict):
    import torch
    from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

    torch.set_num_threads(1)                    # one torch thread per worker (see the module docstring)
    return ParallelPettingZooEnv(CovertSensingParallelEnv(**env_config))


def build_config(args: Args):
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.multi_rl_module import MultiRLModuleSpec
    from ray.rllib.core.rl_module.rl_module import RLModuleSpec

    return (
        PPOConfig()
        .environment(ENV_NAME, env_config=env_kwargs(args), clip_actions=True)
        .env_runners(num_env_runners=args.num_env_runners, num_envs_per_env_runner=args.num_envs_per_env_runner,
                     num_cpus_per_env_runner=1, sample_timeout_s=args.sample_timeout_s)
        .multi_agent(policies={MODULE_ID}, policy_mapping_fn=lambda agent_id, episode, **kw: MODULE_ID)
        .rl_module(rl_module_spec=MultiRLModuleSpec(rl_module_specs={
            MODULE_ID: RLModuleSpec(model_config={"fcnet_hiddens": list(args.net_arch), "fcnet_activation": "tanh",
                                                  "vf_share_layers": False})}))
        .training(train_batch_size_per_learner=args.train_batch_size, minibatch_size=args.minibatch_size,
                  num_epochs=args.num_epochs, lr=args.lr, gamma=args.gamma, lambda_=args.lambda_)
        .learners(num_learners=0)
        .debugging(seed=args.seed)
    )


def train(args: Args) -> Path:
    """Train and return the checkpoint folder. ``args.resume`` (a pickled checkpoint) needs
    ``args.trust_checkpoint``."""
    if args.resume:
        require_trust(args.resume, "an RLlib checkpoint", args.trust_checkpoint)
    setup_torch(args.torch_threads)
    import ray
    from ray.tune.registry import register_env

    if "PYTHONHASHSEED" not in os.environ:
        warnings.warn("PYTHONHASHSEED is not set: RLlib runs with the same seed are not reproducible "
                      "(ParallelPettingZooEnv orders agents through a set); export PYTHONHASHSEED=0", stacklevel=2)
    env_vars = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                "PYTHONHASHSEED": os.environ.get("PYTHONHASHSEED", "0")}
    repo = str(Path(__file__).resolve().parents[1])
    env_vars["PYTHONPATH"] = os.pathsep.join(p for p in (repo, os.environ.get("PYTHONPATH", "")) if p)
    if not ray.is_initialized():
        kw = dict(address=args.address) if args.address else dict(num_cpus=max(2, args.num_env_runners + 1),
                                                                   include_dashboard=False)
        ray.init(runtime_env={"env_vars": env_vars}, log_to_driver=False, **kw)
    register_env(ENV_NAME, _env_creator)

    if args.resume:
        ckpt_dir = Path(args.resume).resolve()
        run_dir = ckpt_dir.parent
        args = resumed_args(args, run_dir)
    else:
        run_dir = (Path(args.runs_dir) / (args.run_name or run_name(args.env_id, ALGO, args.seed))).resolve()
        ckpt_dir = run_dir / "checkpoint"
    save_run(run_dir, args, {"algo": ALGO, "multi_agent": True, "env_kwargs": env_kwargs(args)})
    algo = build_config(args).build_algo()
    if args.resume:
        algo.restore_from_path(str(ckpt_dir))
        print(f"resumed from {ckpt_dir}", flush=True)
    from tqdm.auto import tqdm

    t0 = time.monotonic()
    bar = tqdm(range(args.iterations), desc=ALGO, disable=not args.progress_bar)
    history = []
    for it in bar:
        result = algo.train()
        er = result.get("env_runners", {})
        row = {"iteration": it + 1, "return_mean": er.get("episode_return_mean"),
               "env_steps": er.get("num_env_steps_sampled_lifetime"), "minutes": (time.monotonic() - t0) / 60}
        history.append(row)
        bar.set_postfix(ret=row["return_mean"])
        if args.checkpoint_every and (it + 1) % args.checkpoint_every == 0:
            algo.save_to_path(str(ckpt_dir))
        if args.time_budget_minutes > 0 and row["minutes"] > args.time_budget_minutes:
            print(f"time budget reached after {it + 1} iterations", flush=True)
            break
    algo.save_to_path(str(ckpt_dir))
    (run_dir / "train_summary.json").write_text(json.dumps(history, indent=2, default=float))
    print(f"saved {ckpt_dir}", flush=True)
    algo.stop()
    if not args.address:
        ray.shutdown()
    return ckpt_dir


# ---------------------------------------------------------------------- inference without Ray running
class RLlibPolicy:
    """An RLlib ``shared_policy`` module behind the common policy interface, run in plain torch (no Ray cluster)."""

    def __init__(self, module, env_settings: dict, name: str = "rllib_ppo"):
        self.module = module
        self.env_settings = env_settings
        self.name = name

    def reset(self, env, seed=None) -> None:
        pass

    def act(self, observations, env):
        import torch

        par, single = parallel_env_of(env)
        agents = [a for a in par.possible_agents if a in par.agents]
        obs_d = observations if single is None else {single: observations}
        obs = torch.as_tensor(np.stack([np.asarray(obs_d[a], np.float32) for a in agents]))
        with torch.no_grad():
            logits = self.module.forward_inference({"obs": obs})["action_dist_inputs"].numpy()
        if par.action_mode == "waypoint":
            masks = np.stack([par.action_mask(a) for a in agents]) > 0
            acts = np.where(masks, logits, -np.inf).argmax(axis=1)
            out = {a: int(acts[i]) for i, a in enumerate(agents)}
        else:
            n = logits.shape[1] // 2                              # (mean, log_std): act with the clipped mean
            out = {a: np.clip(logits[i, :n], -1.0, 1.0).astype(np.float32) for i, a in enumerate(agents)}
        return out[single] if single is not None else out


def load_policy(path: str | Path, *, trust_checkpoint: bool = False) -> RLlibPolicy:
    """Load the shared policy of a :mod:`training.rllib_ppo` checkpoint for inference, without starting Ray.
    The checkpoint is pickled: refused unless ``trust_checkpoint=True`` (:func:`training.trust.require_trust`).
    The env settings come from ``args.json`` beside it, checked before the checkpoint is loaded."""
    require_trust(path, "an RLlib checkpoint", trust_checkpoint)
    path = Path(path)
    module_dir = path / "learner_group" / "learner" / "rl_module" / MODULE_ID
    if not module_dir.exists():
        raise FileNotFoundError(f"no RLlib module at {module_dir} (expected a training.rllib_ppo checkpoint)")
    meta_path = path.parent / "args.json"
    meta = read_run_json(meta_path, "run arguments") if meta_path.exists() else {}
    where = str(meta_path) if meta_path.exists() else f"{path} (no args.json beside it)"
    if not isinstance(meta, dict):
        raise UsageError(f"{where}: must be a JSON object (a run's arguments), got {type(meta).__name__}")
    settings, env = run_env(meta.get("env_kwargs", {}), where, n_uavs=3)
    env.close()

    import torch
    from ray.rllib.core.rl_module.rl_module import RLModule

    torch.set_num_threads(1)
    module = RLModule.from_checkpoint(str(module_dir))
    module.eval()
    return RLlibPolicy(module, settings, name=f"rllib_ppo ({path.parent.name})")


def main(argv: list[str] | None = None) -> Path:
    return train(parse_args(Args, argv, description=__doc__.split("\n")[0]))


if __name__ == "__main__":
    main()
