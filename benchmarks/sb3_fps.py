"""SB3 PPO training throughput on our multi-agent env vs mpe2 simple_spread through SuperSuit, in the same run.

    OMP_NUM_THREADS=1 python benchmarks/sb3_fps.py [--timesteps 30000] [--n-copies 8] [--repeats 2]

Both sides: 3 agents per env, ``n_copies`` env copies, one parameter-shared SB3 PPO with the 3-UAV recipe's
hyperparameters (:mod:`training.recipes`), one torch thread, training included (collection + updates). Ours goes
through :class:`training.vec_env.ParallelEnvVecAdapter`; simple_spread through SuperSuit's
``pettingzoo_env_to_vec_env_v1`` + ``concat_vec_envs_v1`` -- SuperSuit appears only here, as the thing to beat
(``pip install supersuit``; skipped with a message if absent). Runs alternate (ours, theirs, ours, ...) so machine
load hits both alike; the best of ``repeats`` is reported. fps = agent-steps per second (SB3 timesteps).
Prints the ratio ours / simple_spread (target >= 1).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _ours(n_copies: int):
    from stable_baselines3.common.vec_env import VecMonitor

    from training.vec_env import make_vec_env

    return VecMonitor(make_vec_env(n_copies, dict(n_uavs=3)))


def _simple_spread(n_copies: int):
    import supersuit as ss
    from mpe2 import simple_spread_v3
    from stable_baselines3.common.vec_env import VecMonitor

    env = simple_spread_v3.parallel_env(N=3, continuous_actions=True, max_cycles=70)
    env = ss.pettingzoo_env_to_vec_env_v1(env)
    env = ss.concat_vec_envs_v1(env, n_copies, num_cpus=0, base_class="stable_baselines3")
    return VecMonitor(env)


def fps(make, n_copies: int, timesteps: int, seed: int = 0) -> float:
    from stable_baselines3 import PPO

    from training.recipes import RECIPES

    r = RECIPES["3uav-ppo"]
    venv = make(n_copies)
    model = PPO("MlpPolicy", venv, n_steps=r["n_steps"], batch_size=r["batch_size"], n_epochs=r["n_epochs"],
                gamma=r["gamma"], learning_rate=r["learning_rate"], seed=seed, device="cpu",
                policy_kwargs=dict(net_arch=dict(pi=list(r["net_arch"]), vf=list(r["net_arch"]))))
    t0 = time.perf_counter()
    model.learn(timesteps)
    dt = time.perf_counter() - t0
    n = model.num_timesteps
    venv.close()
    return n / dt


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--timesteps", type=int, default=30_000, help="agent-steps per measurement")
    p.add_argument("--n-copies", type=int, default=8, help="env copies (x 3 agents)")
    p.add_argument("--repeats", type=int, default=2, help="alternating measurements per env; best is reported")
    args = p.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    try:
        import mpe2  # noqa: F401
        import supersuit  # noqa: F401
    except ImportError as e:
        print(f"skipped: {e.name} is not installed (pip install supersuit mpe2); it is only the baseline here")
        return 0
    ours, theirs = [], []
    for _ in range(args.repeats):
        ours.append(fps(_ours, args.n_copies, args.timesteps))
        # seed=None: SuperSuit's ConcatVecEnv has no seed(), so PPO(..., seed=0) crashes through it (one of the
        # reasons the library does not use SuperSuit).
        theirs.append(fps(_simple_spread, args.n_copies, args.timesteps, seed=None))
        print(f"  covert_sensing (our adapter) {ours[-1]:8.0f} fps   simple_spread (SuperSuit) {theirs[-1]:8.0f} fps"
              f"   ratio {ours[-1] / theirs[-1]:.2f}", flush=True)
    a, b = max(ours), max(theirs)
    paired = [x / y for x, y in zip(ours, theirs, strict=True)]
    print(f"SB3 PPO, 3 agents x {args.n_copies} copies, {args.timesteps} agent-steps, best of {args.repeats}:")
    print(f"  covert_sensing_v1 via training.vec_env : {a:8.0f} agent-steps/s")
    print(f"  mpe2 simple_spread_v3 via SuperSuit    : {b:8.0f} agent-steps/s")
    print(f"  ratio ours / simple_spread = {a / b:.2f} (target >= 1)")
    # On a shared machine the load moves between runs; back-to-back pairs see about the same load.
    print(f"  median of the {len(paired)} back-to-back ratios = {statistics.median(paired):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
