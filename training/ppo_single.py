"""Single-UAV PPO on ``gym.make("covert_env/CovertSensing-v1")`` (SB3, continuous (v, omega) actions).

    OMP_NUM_THREADS=1 python -m training.ppo_single --total-timesteps 1000000
    python -m training.ppo_single --resume runs/<run>                 # continue from the newest checkpoint
    python -m training.evaluate --n-uavs 1 --policies random dp sb3:runs/<run>

Outputs in ``runs/{env}__ppo_single__{seed}__{time}/`` (model.zip, vecnormalize.json, checkpoints/, tb/, args.json).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

from training.common import (
    latest_checkpoint,
    make_callbacks,
    parse_args,
    resumed_args,
    run_name,
    save_final_vecnormalize,
    save_run,
    setup_torch,
)

ALGO = "ppo_single"


@dataclass
class Args:
    env_id: str = "covert_env/CovertSensing-v1"
    """Gymnasium id of the single-UAV env"""
    seed: int = 0
    """seed of the envs, the policy and the action sampling"""
    n_envs: int = 8
    """parallel env copies (in-process DummyVecEnv)"""
    max_cycles: int = 70
    """episode length in slots (70 = the whole route)"""
    scene_pool: int = 10_000
    """training scene seeds are drawn from range(scene_pool); evaluation uses seeds >= 1_000_000"""
    total_timesteps: int = 1_000_000
    """training steps"""
    time_budget_minutes: float = 0.0
    """stop gracefully after this much wall-clock training time and save (0: no budget)"""
    learning_rate: float = 3e-4
    """Adam learning rate"""
    n_steps: int = 256
    """rollout length per env"""
    batch_size: int = 512
    """minibatch size"""
    n_epochs: int = 5
    """PPO epochs per rollout"""
    gamma: float = 0.97
    """discount factor"""
    gae_lambda: float = 0.95
    """GAE lambda"""
    clip_range: float = 0.2
    """PPO clip range"""
    ent_coef: float = 0.0
    """entropy bonus"""
    net_arch: tuple[int, ...] = (128, 128)
    """hidden layers of the policy and value MLPs"""
    log_std_init: float = -0.5
    """initial log standard deviation of the Gaussian policy"""
    norm_obs: bool = True
    """VecNormalize observations"""
    norm_reward: bool = True
    """VecNormalize rewards"""
    checkpoint_freq: int = 100_000
    """save model + VecNormalize statistics every this many steps (0: never)"""
    runs_dir: str = "runs"
    """folder of the runs (git-ignored)"""
    run_name: str = ""
    """run folder name; empty: {env}__ppo_single__{seed}__{time}"""
    resume: str = ""
    """a run folder to continue from its newest checkpoint"""
    torch_threads: int = 1
    """torch threads (1: 2 threads on 2 busy cores can be 50x slower)"""
    progress_bar: bool = True
    """show a tqdm progress bar"""


def env_kwargs(args: Args) -> dict:
    return dict(max_cycles=args.max_cycles, scene_pool=args.scene_pool)


def train(args: Args) -> Path:
    setup_torch(args.torch_threads)
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    import covert_env  # noqa: F401  (registers the Gymnasium ids)
    from training.vec_env import load_vecnormalize

    if args.resume:
        run_dir = Path(args.resume)
        args = resumed_args(args, run_dir)
    else:
        run_dir = Path(args.runs_dir) / (args.run_name or run_name(args.env_id, ALGO, args.seed))
    ekw = env_kwargs(args)
    save_run(run_dir, args, {"algo": ALGO, "sb3_class": "PPO", "multi_agent": False,
                             "env_kwargs": {**ekw, "n_uavs": 1, "action_mode": "unicycle"}})
    venv = make_vec_env(args.env_id, n_envs=args.n_envs, seed=args.seed, env_kwargs=ekw)
    ckpt = latest_checkpoint(run_dir) if args.resume else None
    if ckpt is not None:
        venv = load_vecnormalize(ckpt[1], venv) if ckpt[1] else venv
        model = PPO.load(str(ckpt[0]), env=venv, device="cpu")
        print(f"resumed from {ckpt[0]} at {model.num_timesteps} steps", flush=True)
    else:
        if args.norm_obs or args.norm_reward:
            venv = VecNormalize(venv, norm_obs=args.norm_obs, norm_reward=args.norm_reward, gamma=args.gamma)
        model = PPO("MlpPolicy", venv, learning_rate=args.learning_rate, n_steps=args.n_steps,
                    batch_size=args.batch_size, n_epochs=args.n_epochs, gamma=args.gamma, gae_lambda=args.gae_lambda,
                    clip_range=args.clip_range, ent_coef=args.ent_coef, seed=args.seed, device="cpu",
                    policy_kwargs=dict(net_arch=dict(pi=list(args.net_arch), vf=list(args.net_arch)),
                                       log_std_init=args.log_std_init),
                    tensorboard_log=str(run_dir / "tb"), verbose=0)
    cbs, budget = make_callbacks(run_dir, ALGO, args.total_timesteps, venv.num_envs, args.checkpoint_freq,
                                 args.time_budget_minutes, args.progress_bar)
    t0 = time.monotonic()
    model.learn(max(args.total_timesteps - model.num_timesteps, 0), callback=cbs, tb_log_name=ALGO,
                reset_num_timesteps=ckpt is None)
    model.save(run_dir / "model.zip")
    save_final_vecnormalize(model, run_dir)
    info = {"timesteps": int(model.num_timesteps), "train_minutes": round((time.monotonic() - t0) / 60, 2),
            "stopped_by_time_budget": budget.stopped}
    (run_dir / "train_summary.json").write_text(json.dumps(info, indent=2))
    print(f"saved {run_dir / 'model.zip'}: {info}", flush=True)
    venv.close()
    return run_dir


def main(argv: list[str] | None = None) -> Path:
    return train(parse_args(Args, argv, description=__doc__.split("\n")[0]))


if __name__ == "__main__":
    main()
