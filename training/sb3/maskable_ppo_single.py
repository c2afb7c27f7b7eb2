"""Single-UAV MaskablePPO (sb3-contrib) on ``gym.make("covert_env/CovertSensingWaypoint-v4")``.

The action is a node of the DP planner's waypoint lattice; ``env.action_masks()`` marks nodes reachable in one
slot and in the visible zone (eq. 10), and MaskablePPO never samples a masked node.

    OMP_NUM_THREADS=1 python -m training.sb3.maskable_ppo_single --total-timesteps 500000
    python -m training.sb3.maskable_ppo_single --resume runs/<run> --trust-checkpoint
    covert-env evaluate --n-uavs 1 --policies random@waypoint dp sb3:runs/<run> --trust-checkpoint

Outputs in ``runs/{env}__maskable_ppo_single__{seed}__{time}/`` (model.zip, vecnormalize.json, checkpoints/, tb/).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from training.common import parse_args
from training.sb3.args import PPOArgs
from training.sb3.run import train_single

ALGO = "maskable_ppo_single"


@dataclass
class Args(PPOArgs):
    env_id: str = "covert_env/CovertSensingWaypoint-v4"
    """Gymnasium id of the single-UAV waypoint env (with action_masks())"""
    total_timesteps: int = 500_000
    ent_coef: float = 0.01
    """entropy bonus (keeps exploring among the allowed waypoints)"""
    n_envs: int = 8
    """parallel env copies (in-process DummyVecEnv)"""


def train(args: Args) -> Path:
    """Train and save (the shared run of :func:`training.sb3.run.train_single`); returns the run folder."""
    def build(args, venv, tb):
        from sb3_contrib import MaskablePPO

        return MaskablePPO("MlpPolicy", venv, learning_rate=args.learning_rate, n_steps=args.n_steps,
                           batch_size=args.batch_size, n_epochs=args.n_epochs, gamma=args.gamma,
                           gae_lambda=args.gae_lambda, clip_range=args.clip_range, ent_coef=args.ent_coef,
                           seed=args.seed, device="cpu",
                           policy_kwargs=dict(net_arch=dict(pi=list(args.net_arch), vf=list(args.net_arch))),
                           tensorboard_log=tb, verbose=0)

    return train_single(args, ALGO, "MaskablePPO", "waypoint", build)


def main(argv: list[str] | None = None) -> Path:
    return train(parse_args(Args, argv, description=__doc__.split("\n")[0]))


if __name__ == "__main__":
    main()
