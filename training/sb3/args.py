"""The settings every Stable-Baselines3 script shares, one dataclass per layer (CleanRL-style ``Args``).

Each script's ``Args`` extends :class:`SB3Args` (SAC) or :class:`PPOArgs` (the PPO family), overriding the defaults
that differ and adding its own fields; :func:`training.common.parse_args` turns any of them into a command line,
a field's docstring being its ``--help``.
"""

from __future__ import annotations

from dataclasses import dataclass

from training.run_args import TrainingArgs

__all__ = ["PPOArgs", "SB3Args"]


@dataclass
class SB3Args(TrainingArgs):
    """:class:`~training.run_args.TrainingArgs` and the env and learner settings of every SB3 script."""

    env_id: str = "covert_env/CovertSensing-v4"
    """Gymnasium id of the single-UAV env"""
    total_timesteps: int = 1_000_000
    """training steps"""
    learning_rate: float = 3e-4
    """Adam learning rate"""
    batch_size: int = 512
    """minibatch size"""
    gamma: float = 0.97
    """discount factor"""
    net_arch: tuple[int, ...] = (128, 128)
    """hidden layers of the policy and value MLPs"""
    norm_obs: bool = True
    """VecNormalize observations"""
    norm_reward: bool = True
    """VecNormalize rewards"""
    checkpoint_freq: int = 100_000
    """save model + VecNormalize statistics every this many steps (0: never)"""
    resume: str = ""
    """a run folder to continue from its newest checkpoint"""
    trust_checkpoint: bool = False
    """allow --resume to load the run's SB3 checkpoint (.zip), which holds pickles that run any code they carry:
    only for a run from a source you trust"""


@dataclass
class PPOArgs(SB3Args):
    """:class:`SB3Args` and the PPO update's settings."""

    n_steps: int = 256
    """rollout length per env"""
    n_epochs: int = 5
    """PPO epochs per rollout"""
    gae_lambda: float = 0.95
    """GAE lambda"""
    clip_range: float = 0.2
    """PPO clip range"""
    ent_coef: float = 0.0
    """entropy bonus"""
