"""Env-steps per second of the covert-sensing parallel env vs mpe2's simple_spread, in the same run.

    python benchmarks/env_throughput.py [--seconds 10] [--mode unicycle|waypoint|both]

Both envs: 3 agents, random continuous actions (drawn up front), full observations, resets included.
Ours runs the paper scenario's 16 polytopes. mpe2 is optional (``pip install mpe2``).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")




def steps_per_second(env, seconds: float, masked: bool = False) -> float:
    """Random actions for about ``seconds`` (after a warm-up); returns env-steps/s, resets included.

    Continuous actions are drawn up front with numpy, so the figure measures the env, not
    ``Box.sample()`` (about 40 us per call here, the same for every env). Masked discrete actions are
    drawn per step from the current mask (that cost is part of using the env).
    """
    import numpy as np

    rng = np.random.default_rng(0)
    space = env.action_space(env.possible_agents[0])
    pool = None if masked else rng.uniform(space.low, space.high, (4096, len(env.possible_agents),)
                                           + space.shape).astype(space.dtype)
    obs, infos = env.reset(seed=0)
    n, t0, warm = 0, None, 50
    while True:
        if not env.agents:
            obs, infos = env.reset()
        if masked:
            acts = {a: int(rng.choice(np.flatnonzero(infos[a]["action_mask"]))) for a in env.agents}
        else:
            row = pool[n % len(pool)]
            acts = {a: row[i] for i, a in enumerate(env.agents)}
        obs, rew, term, trunc, infos = env.step(acts)
        n += 1
        if t0 is None and n == warm:
            t0, n = time.perf_counter(), 0
        if t0 is not None and n % 50 == 0 and time.perf_counter() - t0 >= seconds:
            return n / (time.perf_counter() - t0)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="measuring time per env")
    parser.add_argument("--mode", choices=["unicycle", "waypoint", "both"], default="both")
    args = parser.parse_args(argv)

    import covert_env

    rows = []
    modes = ["unicycle", "waypoint"] if args.mode == "both" else [args.mode]
    for mode in modes:
        env = covert_env.parallel_env(n_uavs=3, scenario="paper", action_mode=mode)
        rows.append((f"covert_sensing_v2 ({mode}, 3 UAVs, 16 polytopes)",
                     steps_per_second(env, args.seconds, masked=mode == "waypoint")))
    try:
        from mpe2 import simple_spread_v3
    except ImportError:
        mpe = None
        print("mpe2 is not installed (pip install mpe2): no reference measurement")
    else:
        mpe = steps_per_second(simple_spread_v3.parallel_env(N=3, continuous_actions=True), args.seconds)
        rows.append(("mpe2 simple_spread_v3 (N=3, continuous)", mpe))
    width = max(len(r[0]) for r in rows)
    print(f"{'env':<{width}}  env-steps/s  ratio to mpe2")
    for name, sps in rows:
        ratio = f"{sps / mpe:.2f}x" if mpe else "-"
        print(f"{name:<{width}}  {sps:11.0f}  {ratio}")



if __name__ == "__main__":
    main()
