"""Single-UAV MaskablePPO (sb3-contrib) on ``gym.make("covert_env/CovertSensingWaypoint-v4")``.

The action is a node of the DP planner's waypoint lattice; ``env.action_masks()`` marks nodes reachable in one
slot and in the visible zone (eq. 10), and MaskablePPO never samples a masked node.

    OMP_NUM_THREADS=1 python -m training.maskable_ppo_single --total-timesteps 500000
    python -m training.maskable_ppo_single --resume runs/<run> --trust-checkpoint
    python -m training.evaluate --n-uavs 1 --policies random@waypoint dp sb3:runs/<run> --trust-checkpoint

Outputs in ``runs/{env}__maskable_ppo_single__{seed}__{time}/`` (model.zip, vecnormalize.json, checkpoints/, tb/).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from training.common import parse_args, train_single

ALGO = "maskable_ppo_single"


@dataclass
class Args:
    env_id: str = "covert_env/CovertSensingWaypoint-v4"
    """Gymnasium id of the single-UAV waypoint env (with action_masks())"""
    seed: int = 0
    """seed of the envs, the policy and the action sampling"""
    n_envs: int = 8
    """parallel env copies (in-process DummyVecEnv)"""
    max_cycles: int = 70
    """episode length in slots (70 = the whole route)"""
    scene_pool: int = 10_000
    """training scene seeds are drawn from range(scene_pool); evaluation uses seeds >= 1_000_000"""
    total_timesteps: int = 500_000
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
    ent_coef: float = 0.01
    """entropy bonus (keeps exploring among the allowed waypoints)"""
    net_arch: tuple[int, ...] = (128, 128)
    """hidden layers of the policy and value MLPs"""
    norm_obs: bool = True
    """VecNormalize observations"""
    norm_reward: bool = True
    """VecNormalize rewards"""
    checkpoint_freq: int = 100_000
    """save model + VecNormalize statistics every this many steps (0: never)"""
    runs_dir: str = "runs"
    """folder of the runs (git-ignored)"""
    run_name: str = ""
    """run folder name; empty: {env}__maskable_ppo_single__{seed}__{time}"""
    resume: str = ""
    """a run folder to continue from its newest checkpoint"""
    trust_checkpoint: bool = False
    """allow --resume to load the run's SB3 checkpoint (.zip), which holds pickles that run any code they carry:
    only for a run from a source you trust"""
    torch_threads: int = 1
    """torch threads (1: 2 threads on 2 busy cores can be 50x slower)"""
    progress_bar: bool = True
    """show a tqdm progress bar"""


def train(args: Args) -> Path:
    """Train and save (the shared run of :func:`training.common.train_single`); returns the run folder."""
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
