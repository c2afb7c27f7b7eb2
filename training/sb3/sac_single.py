"""Single-UAV SAC on ``gym.make("covert_env/CovertSensing-v4")`` (SB3, continuous (v, omega) actions).

    OMP_NUM_THREADS=1 python -m training.sb3.sac_single --total-timesteps 300000
    python -m training.sb3.sac_single --resume runs/<run> --trust-checkpoint   # continue from the newest checkpoint
    covert-env evaluate --n-uavs 1 --policies random dp sb3:runs/<run> --trust-checkpoint

Outputs in ``runs/{env}__sac_single__{seed}__{time}/`` (model.zip, vecnormalize.json, checkpoints/, tb/, args.json).
The replay buffer is not checkpointed (it is large); ``--resume`` restarts with an empty buffer and refills it
for ``learning_starts`` steps.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from training.common import parse_args
from training.sb3.args import SB3Args
from training.sb3.run import train_single

ALGO = "sac_single"


@dataclass
class Args(SB3Args):
    total_timesteps: int = 300_000
    learning_rate: float = 3e-4
    """Adam learning rate (actor, critics and entropy coefficient)"""
    batch_size: int = 256
    net_arch: tuple[int, ...] = (256, 256)
    """hidden layers of the actor and critics"""
    norm_reward: bool = False
    """VecNormalize rewards (off for SAC: its entropy tuning works on the raw scale)"""
    checkpoint_freq: int = 50_000
    n_envs: int = 1
    """parallel env copies (in-process DummyVecEnv)"""
    buffer_size: int = 300_000
    """replay buffer size"""
    learning_starts: int = 5_000
    """random-action steps before learning starts"""
    tau: float = 0.005
    """target network soft-update rate"""
    train_freq: int = 1
    """gradient updates every this many env steps"""
    gradient_steps: int = 1
    """gradient steps per update"""


def train(args: Args) -> Path:
    """Train and save (the shared run of :func:`training.sb3.run.train_single`); returns the run folder."""
    def build(args, venv, tb):
        from stable_baselines3 import SAC

        return SAC("MlpPolicy", venv, learning_rate=args.learning_rate, buffer_size=args.buffer_size,
                   learning_starts=args.learning_starts, batch_size=args.batch_size, gamma=args.gamma, tau=args.tau,
                   train_freq=args.train_freq, gradient_steps=args.gradient_steps, seed=args.seed, device="cpu",
                   policy_kwargs=dict(net_arch=list(args.net_arch)), tensorboard_log=tb, verbose=0)

    return train_single(args, ALGO, "SAC", "unicycle", build)


def main(argv: list[str] | None = None) -> Path:
    return train(parse_args(Args, argv, description=__doc__.split("\n")[0]))


if __name__ == "__main__":
    main()
