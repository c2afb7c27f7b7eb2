"""SB3 PPO training throughput on our multi-agent env vs mpe2 simple_spread through SuperSuit, in the same run.

    OMP_NUM_THREADS=1 python benchmarks/sb3_fps.py [--timesteps 30000] [--n-copies 8] [--repeats 2]

Both sides: 3 agents per env, ``n_copies`` env copies, one parameter-shared SB3 PPO with the 3-UAV recipe's
hyperparameters (:mod:`training.recipes`), one torch thread, training included (collection + updates). Ours goes
through :func:`training.sb3.vec_env.make_vec_env` (the batched adapter on the vector env); simple_spread through
SuperSuit's ``pettingzoo_env_to_vec_env_v1`` + ``concat_vec_envs_v1`` -- SuperSuit appears only here, as the thing to
beat (``pip install supersuit``; skipped with a message if absent). Runs alternate (ours, theirs, ours, ...) so machine
load hits both alike; the best of ``repeats`` is reported. fps = agent-steps per second (SB3 timesteps).
Prints the ratio ours / simple_spread (target >= 1).

``--share`` instead times where one PPO run on our env spends its wall time (issue target: the env <= 20 %): the
vector env's ``step``/``reset``, the rest of the SB3 adapter (per-row info dicts, SB3's bookkeeping), PPO's
updates (``train``) and the rest of the rollout collection (policy forward passes, buffer writes, VecMonitor).
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


def _ours(n_copies: int, **kw):
    from stable_baselines3.common.vec_env import VecMonitor

    from training.sb3.vec_env import make_vec_env

    return VecMonitor(make_vec_env(n_copies, dict(n_uavs=3, **kw)))


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


class _Timer:
    """Wraps a bound method, accumulating its wall time."""

    def __init__(self, fn):
        self.fn, self.total = fn, 0.0

    def __call__(self, *a, **kw):
        t0 = time.perf_counter()
        try:
            return self.fn(*a, **kw)
        finally:
            self.total += time.perf_counter() - t0


def share(n_copies: int, timesteps: int, scene_pool: int) -> None:
    """Where one PPO run on our env spends its wall time (printed); ``scene_pool`` as the env's argument."""
    from stable_baselines3 import PPO

    from training.recipes import RECIPES

    r = RECIPES["3uav-ppo"]
    venv = _ours(n_copies, scene_pool=scene_pool)
    adapter = venv.venv
    vec_step, vec_reset = _Timer(adapter.venv.step), _Timer(adapter.venv.reset)
    adapter.venv.step, adapter.venv.reset = vec_step, vec_reset
    wait = _Timer(adapter.step_wait)
    adapter.step_wait = wait
    model = PPO("MlpPolicy", venv, n_steps=r["n_steps"], batch_size=r["batch_size"], n_epochs=r["n_epochs"],
                gamma=r["gamma"], learning_rate=r["learning_rate"], seed=0, device="cpu",
                policy_kwargs=dict(net_arch=dict(pi=list(r["net_arch"]), vf=list(r["net_arch"]))))
    train = _Timer(model.train)
    model.train = train
    t0 = time.perf_counter()
    model.learn(timesteps)
    total = time.perf_counter() - t0
    env = vec_step.total + vec_reset.total
    rows = [("vector env step + reset (the env)", env), ("SB3 adapter around it (info rows, flags)", wait.total - env
            + 0.0), ("PPO updates (train: epochs of minibatch SGD)", train.total),
            ("rest of collection (policy forward, buffer, VecMonitor)", total - wait.total - train.total)]
    print(f"PPO, 3 agents x {n_copies} copies, scene_pool={scene_pool}, {model.num_timesteps} agent-steps, "
          f"{total:.1f} s wall "
          f"({model.num_timesteps / total:.0f} agent-steps/s), load average {os.getloadavg()[0]:.1f}:")
    for name, t in rows:
        print(f"  {name:58s} {t:7.2f} s  {100 * t / total:5.1f} %")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--timesteps", type=int, default=30_000, help="agent-steps per measurement")
    p.add_argument("--n-copies", type=int, default=8, help="env copies (x 3 agents)")
    p.add_argument("--repeats", type=int, default=2, help="alternating measurements per env; best is reported")
    p.add_argument("--share", action="store_true", help="only time where a PPO run on our env spends its time")
    p.add_argument("--scene-pool", type=int, default=10_000,
                   help="with --share: the env's scene_pool (default 10000: nearly every episode builds a new scene)")
    args = p.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    if args.share:
        share(args.n_copies, args.timesteps, args.scene_pool)
        return 0
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
    print(f"  covert_sensing_v4 via training.sb3.vec_env : {a:8.0f} agent-steps/s")
    print(f"  mpe2 simple_spread_v3 via SuperSuit    : {b:8.0f} agent-steps/s")
    print(f"  ratio ours / simple_spread = {a / b:.2f} (target >= 1)")
    # On a shared machine the load moves between runs; back-to-back pairs see about the same load.
    print(f"  median of the {len(paired)} back-to-back ratios = {statistics.median(paired):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
