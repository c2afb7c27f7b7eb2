"""Parameter-shared multi-agent PPO on the covert_env PettingZoo env (SB3, our own VecEnv adapter, no SuperSuit).

One policy acts for every UAV of every env copy: :class:`training.sb3.vec_env.ParallelEnvVecAdapter` flattens
``n_copies x n_uavs`` agents into SB3 rows. Timesteps count agent-steps (rows), as in SB3.

    OMP_NUM_THREADS=1 python -m training.sb3.ppo_multi --recipe 3uav-ppo            # the documented recipe
    python -m training.sb3.ppo_multi --recipe 3uav-ppo --resume runs/<run> --trust-checkpoint   # the last checkpoint
    tensorboard --logdir runs

Outputs in ``runs/{env}__ppo_multi__{seed}__{time}/`` (see :mod:`training.common`). Evaluate with
``covert-env evaluate --policies random dp sb3:runs/<run> --trust-checkpoint``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from training.common import parse_args
from training.recipes import RECIPES
from training.sb3.args import PPOArgs
from training.sb3.run import train_sb3

ALGO = "ppo_multi"


@dataclass
class Args(PPOArgs):
    env_id: str = "covert_sensing_v4"
    """name of the env in run names (the PettingZoo env covert_env.parallel_env)"""
    total_timesteps: int = 20_000_000
    """upper bound on agent-steps (the time budget usually stops training first)"""
    time_budget_minutes: float = 50.0
    n_steps: int = 256
    """rollout length per SB3 env row (a rollout has n_steps * n_copies * n_uavs samples)"""
    batch_size: int = 1024
    gamma: float = 0.97
    """discount factor (also used by VecNormalize's reward scaling)"""
    net_arch: tuple[int, ...] = (128, 128)
    """hidden layers of the policy and value MLPs (separate networks)"""
    norm_reward: bool = True
    """VecNormalize rewards (by the running std of the discounted return)"""
    checkpoint_freq: int = 500_000
    """save model + VecNormalize statistics every this many agent-steps (0: never)"""
    resume: str = ""
    """a run folder to continue from its newest checkpoint (same settings)"""
    n_uavs: int = 3
    """UAVs per env copy (all share one policy)"""
    n_copies: int = 8
    """env copies; SB3 sees n_copies * n_uavs envs"""
    action_mode: str = "unicycle"
    """'unicycle' (continuous (v, omega)) or 'waypoint' (discrete lattice, plain PPO without masks)"""
    los_penalty: float = 2.0
    """training reward: penalty per slot with blocked LoS (the env's own is 1)"""
    zone_penalty: float = 2.0
    """training reward: base penalty per slot outside the feasible zone (the env's own is 1)"""
    separation_penalty: float = 1.0
    """training reward: penalty per slot closer than d_safe1 to a teammate"""
    disguise_in_zone_only: bool = True
    """training reward: count the disguise bonus only while inside the zone (blocks the circle-the-target exploit)"""
    vf_coef: float = 0.5
    """value-loss coefficient"""
    max_grad_norm: float = 0.5
    """gradient clipping"""
    log_std_init: float = -0.5
    """initial log standard deviation of the Gaussian policy (unicycle mode)"""
    verbose: int = 1
    """1: print a short progress line every 10 rollouts"""


def env_kwargs(args: Args) -> dict:
    """Keyword arguments of ``CovertSensingParallelEnv`` for training (evaluation uses the env's defaults)."""
    return dict(n_uavs=args.n_uavs, action_mode=args.action_mode, max_cycles=args.max_cycles,
                scene_pool=args.scene_pool, los_penalty=args.los_penalty, zone_penalty=args.zone_penalty,
                separation_penalty=args.separation_penalty)


def shaped_reward(disguise_in_zone_only: bool):
    """Training-time reward: the env reward, without the disguise bonus outside the zone if asked."""
    if not disguise_in_zone_only:
        return None

    def fn(reward: float, info: dict) -> float:
        return reward if info["in_zone"] else reward - info["reward_disguise"]

    return fn


def _info_stats_callback(verbose: int):
    from stable_baselines3.common.callbacks import BaseCallback

    class InfoStats(BaseCallback):
        """Logs LoS / in-zone rates and the unshaped env reward per slot of every rollout to TensorBoard."""

        def _on_rollout_start(self) -> None:
            self.n = self.los = self.zone = 0
            self.env_r = 0.0

        def _on_training_start(self) -> None:
            self.t0, self.s0, self.rollouts = time.monotonic(), self.model.num_timesteps, 0
            self._on_rollout_start()

        def _on_step(self) -> bool:
            for info in self.locals["infos"]:
                if "los" in info:
                    self.n += 1
                    self.los += info["los"]
                    self.zone += info["in_zone"]
                    self.env_r += info.get("env_reward", sum(v for k, v in info.items() if k.startswith("reward_")))
            return True

        def _on_rollout_end(self) -> None:
            if not self.n:
                return
            los, zone, r = self.los / self.n, self.zone / self.n, self.env_r / self.n
            self.logger.record("covert/los_rate", los)
            self.logger.record("covert/zone_rate", zone)
            self.logger.record("covert/env_reward_per_slot", r)
            self.rollouts += 1
            if verbose and self.rollouts % 10 == 0:
                dt = time.monotonic() - self.t0
                fps = (self.model.num_timesteps - self.s0) / max(dt, 1e-9)
                print(f"[{dt / 60:6.1f} min] steps {self.model.num_timesteps:>9d}  fps {fps:6.0f}  "
                      f"los {los:.3f}  in-zone {zone:.3f}  env reward/slot {r:+.3f}", flush=True)

    return InfoStats()


def train(args: Args) -> Path:
    """Train (or resume) and return the run folder (holding model.zip, vecnormalize.json, args.json).
    Resuming from an SB3 checkpoint (pickled) needs ``args.trust_checkpoint``."""
    def make_venv(args):
        from stable_baselines3.common.vec_env import VecMonitor

        from training.sb3.vec_env import make_vec_env

        return VecMonitor(make_vec_env(args.n_copies, env_kwargs(args),
                                       reward_fn=shaped_reward(args.disguise_in_zone_only)))

    def build(args, venv, tensorboard_log):
        from stable_baselines3 import PPO

        policy_kwargs = dict(net_arch=dict(pi=list(args.net_arch), vf=list(args.net_arch)))
        if args.action_mode == "unicycle":
            policy_kwargs["log_std_init"] = args.log_std_init
        return PPO("MlpPolicy", venv, learning_rate=args.learning_rate, n_steps=args.n_steps,
                   batch_size=args.batch_size, n_epochs=args.n_epochs, gamma=args.gamma, gae_lambda=args.gae_lambda,
                   clip_range=args.clip_range, ent_coef=args.ent_coef, vf_coef=args.vf_coef,
                   max_grad_norm=args.max_grad_norm, policy_kwargs=policy_kwargs, seed=args.seed, device="cpu",
                   tensorboard_log=tensorboard_log, verbose=0)

    return train_sb3(args, ALGO, "PPO", lambda args: {"multi_agent": True, "env_kwargs": env_kwargs(args)},
                     make_venv, build, callbacks=lambda args: [_info_stats_callback(args.verbose)])


def main(argv: list[str] | None = None) -> Path:
    args = parse_args(Args, argv, description=__doc__.split("\n")[0], presets=RECIPES)
    return train(args)


if __name__ == "__main__":
    main()
