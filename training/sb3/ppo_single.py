"""Single-UAV PPO on ``gym.make("covert_env/CovertSensing-v4")`` (SB3, continuous (v, omega) actions).

    OMP_NUM_THREADS=1 python -m training.sb3.ppo_single --total-timesteps 1000000
    python -m training.sb3.ppo_single --resume runs/<run> --trust-checkpoint   # continue from the newest checkpoint
    covert-env evaluate --n-uavs 1 --policies random dp sb3:runs/<run> --trust-checkpoint

Outputs in ``runs/{env}__ppo_single__{seed}__{time}/`` (model.zip, vecnormalize.json, checkpoints/, tb/, args.json).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from training.common import parse_args
from training.sb3.args import PPOArgs
from training.sb3.run import train_single

ALGO = "ppo_single"


@dataclass
class Args(PPOArgs):
    n_envs: int = 8
    """parallel env copies (in-process DummyVecEnv)"""
    log_std_init: float = -0.5
    """initial log standard deviation of the Gaussian policy"""


def train(args: Args) -> Path:
    """Train and save (the shared run of :func:`training.sb3.run.train_single`); returns the run folder."""
    def build(args, venv, tb):
        from stable_baselines3 import PPO

        return PPO("MlpPolicy", venv, learning_rate=args.learning_rate, n_steps=args.n_steps,
                   batch_size=args.batch_size, n_epochs=args.n_epochs, gamma=args.gamma, gae_lambda=args.gae_lambda,
                   clip_range=args.clip_range, ent_coef=args.ent_coef, seed=args.seed, device="cpu",
                   policy_kwargs=dict(net_arch=dict(pi=list(args.net_arch), vf=list(args.net_arch)),
                                      log_std_init=args.log_std_init),
                   tensorboard_log=tb, verbose=0)

    return train_single(args, ALGO, "PPO", "unicycle", build)


def main(argv: list[str] | None = None) -> Path:
    return train(parse_args(Args, argv, description=__doc__.split("\n")[0]))


if __name__ == "__main__":
    main()
