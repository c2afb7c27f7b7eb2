"""What the MAPPO training loop makes of the engine: env-steps per CPU-second and per wall-second of the loop against
the raw vector env at the same B, tasks and mask mode, in the same run, with where the loop's time goes.

    python benchmarks/training_throughput.py [--sizes 16 64 256] [--updates 2] [--num-steps 16]
        [--guards filter none shield] [--recipe 3uav-suite] [--overlap]

For each B: the raw env (the recipe's tasks as one vector env, ``covert_env.envs.task_mix``, kinematic mask,
masked-random nodes, automatic resets), then the recipe's loop (``training.mappo``: rollout of ``--num-steps``
slots, GAE, the PPO update) for
``--updates`` updates after one untimed update, with each guard of ``--guards``:

* ``filter``: the safety filter as ``3uav-suite`` trains through it (``--safety-filter``: eqs. 2 and 3 along the
  flown path, certified moves; its viability rule at a bar of 10, the policy's logits as its preferences);
* ``shield``: the separation shield as ``3uav-suite-shield`` trained with it (``training.shield``, with its
  look-ahead and viability rule);
* ``none``: no guard (what the loop costs without one).

With ``--overlap``, each guard also gets a row for the loop with ``--overlap-update`` (the next rollout collected
while the PPO update runs, two threads: what a run makes of two cores); its time is not split by part.

It prints the command, one row per (B, guard): env-steps per CPU-second and per wall-second, the ratio of the
latter to the raw env's of the same B (one thread), and the share of the loop's CPU time in the env's step, the
guard, the node features, the actor and critic in the rollout, and the PPO update. ``torch`` runs on one thread
per thread of the loop, as the recipes do.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import time
from contextlib import contextmanager
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

PARTS = ("env step", "guard", "node features", "actor and critic", "PPO update", "other")

#: Each guard's flags over the recipe's: the safety filter as ``3uav-suite`` trains through it, the separation
#: shield as ``3uav-suite-shield`` did, and neither.
_FILTER_OFF = ["--safety-filter", "false", "--learn-flown-nodes", "false", "--filter-scores", "false"]
GUARDS = {
    "filter": ["--safety-filter", "true", "--separation-shield", "false", "--shield-lookahead", "false",
               "--viability-shield", "true", "--viability-min-reach", "10", "--learn-flown-nodes", "true",
               "--filter-scores", "true"],
    "shield": [*_FILTER_OFF, "--separation-shield", "true", "--shield-lookahead", "true", "--viability-shield",
               "true", "--viability-min-reach", "10"],
    "none": [*_FILTER_OFF, "--separation-shield", "false", "--shield-lookahead", "false", "--viability-shield",
             "false", "--viability-min-reach", "1"],
}


class Timer:
    """CPU seconds by part; ``wrap(obj, name, part)`` times a method of ``obj`` under ``part``."""

    def __init__(self):
        self.t = dict.fromkeys(PARTS, 0.0)
        self._stack: list[str] = []

    @contextmanager
    def part(self, name: str):
        t0 = time.process_time()
        self._stack.append(name)
        try:
            yield
        finally:
            self._stack.pop()
            dt = time.process_time() - t0
            self.t[name] += dt
            if self._stack:                       # nested: the outer part does not count it twice
                self.t[self._stack[-1]] -= dt

    def wrap(self, obj, method: str, name: str) -> None:
        fn = getattr(obj, method)

        def timed(*a, **k):
            with self.part(name):
                return fn(*a, **k)

        setattr(obj, method, timed)


def env_kwargs(args) -> dict:
    """The env settings of the recipe's loop (``training.mappo.train``'s, for the mix of its tasks)."""
    kw = dict(action_mode=args.action_mode, max_cycles=args.max_cycles, map_size=args.map_size,
              mask_mode=args.mask_mode)
    if args.target_path:
        kw["target_path"] = args.target_path
    return kw


def raw_rate(tasks: list[str], b: int, seconds: float, kwargs: dict) -> tuple[float, float]:
    """Env-steps per CPU-second and per wall-second of the raw mix, masked-random nodes."""
    from training.task_mix import make_training_env

    env = make_training_env(tasks, b, **kwargs)
    env.reset(seed=0)
    rng = np.random.default_rng(0)

    def step():
        m = env.action_masks().astype(bool)
        env.step(np.argmax(np.where(m, rng.random(m.shape), -1.0), axis=2))

    for _ in range(3):
        step()
    t0, w0, n = time.process_time(), time.perf_counter(), 0
    while time.process_time() - t0 < seconds or n < 10:
        step()
        n += 1
    rate, wall = b * n / (time.process_time() - t0), b * n / (time.perf_counter() - w0)
    env.close()
    return rate, wall


def loop_rate(recipe: str, b: int, guard: str, updates: int, num_steps: int,
              overlap: bool = False) -> tuple[float, float, dict]:
    """Env-steps per CPU-second and per wall-second of ``updates`` training updates of ``recipe`` at B = ``b`` with
    ``guard`` (with ``overlap``, each update beside the next rollout, as ``--overlap-update`` runs them), and the
    CPU seconds by part (sequential only)."""
    from concurrent.futures import ThreadPoolExecutor

    import torch

    from covert_env.envs.safety_filter import SafetyFilteredVectorEnv
    from training import mappo
    from training.common import parse_args
    from training.recipes import MAPPO_RECIPES
    from training.shield import SeparationShield
    from training.task_mix import make_training_env

    torch.set_num_threads(1)
    argv = ["--recipe", recipe, "--num-envs", str(b), "--num-steps", str(num_steps), "--progress-bar", "false"]
    argv += GUARDS[guard]
    args = parse_args(mappo.Args, argv, description="", presets=MAPPO_RECIPES)
    mappo.check_args(args)
    np.random.seed(0)
    torch.manual_seed(0)
    env = make_training_env(mappo.task_list(args), b, **env_kwargs(args))
    timer = Timer()
    timer.wrap(env, "step", "env step")
    if guard == "filter":
        timer.wrap(env, "safety_state", "guard")                         # what the filter reads of the env
        env = SafetyFilteredVectorEnv(env)
        timer.wrap(env.safety, "filter", "guard")
    s = mappo.sizes_of(args, env)
    shield = None
    if guard == "shield":
        shield = SeparationShield(env.config.d_safe1 + args.shield_margin, args.shield_end_margin,
                                  lookahead=args.shield_lookahead, min_reach=args.viability_min_reach)
        timer.wrap(shield, "choose", "guard")
    actor, critic, optim = mappo.make_networks(args, s)
    agents = mappo.Agents(args, s, env, actor, critic, mappo.RunningNorm(), shield)
    timer.wrap(agents, "node_feats", "node features")
    timer.wrap(agents, "act", "actor and critic")
    timer.wrap(agents, "value", "actor and critic")
    buf, episodes = mappo.Rollout(s), mappo.Episodes(s)
    lam = dict.fromkeys(s.constrained, 0.0)
    obs, _ = env.reset(seed=0)
    state = env.state()
    behaviour = mappo.behaviour_copy(agents) if overlap else agents
    rollouts = (buf, mappo.Rollout(s)) if overlap else (buf, buf)
    pool = ThreadPoolExecutor(1) if overlap else None

    def collect(into):
        nonlocal obs, state
        with timer.part("other"):
            obs, state = mappo.collect_rollout(behaviour, into, episodes, obs, state, lam=lam)
            return behaviour.value(obs, state)

    def learn(rollout, next_value):
        adv, ret = mappo.advantages(rollout, next_value, args.gamma, args.gae_lambda)
        mappo.ppo_update(agents, optim, rollout, adv, ret, rng=np.random.default_rng(0))

    next_value, i = collect(rollouts[0]), 0

    def update():
        nonlocal next_value, i
        if overlap:                          # training.mappo.train's --overlap-update loop
            done = pool.submit(learn, rollouts[i], next_value)
            next_value = collect(rollouts[1 - i])
            done.result()
            mappo.copy_weights(agents, behaviour)
            i = 1 - i
        else:
            with timer.part("PPO update"):
                learn(buf, next_value)
            next_value = collect(buf)

    try:
        update()                                               # untimed: first scenes, allocations
        timer.t = dict.fromkeys(PARTS, 0.0)
        t0, w0 = time.process_time(), time.perf_counter()
        for _ in range(updates):
            update()
        cpu, wall = time.process_time() - t0, time.perf_counter() - w0
    finally:
        env.close()
        if pool is not None:
            pool.shutdown()
    return b * num_steps * updates / cpu, b * num_steps * updates / wall, timer.t


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[16, 64, 256], help="B, copies (default 16 64 256)")
    parser.add_argument("--guards", nargs="+", choices=list(GUARDS), default=["filter", "none"])
    parser.add_argument("--recipe", default="3uav-suite", help="the training.mappo recipe (default 3uav-suite)")
    parser.add_argument("--updates", type=int, default=2, help="timed PPO updates per row (default 2)")
    parser.add_argument("--num-steps", type=int, default=16, help="rollout slots per update (default 16)")
    parser.add_argument("--seconds", type=float, default=4.0, help="CPU-seconds of the raw env per B (default 4)")
    parser.add_argument("--overlap", action="store_true",
                        help="also time each guard's loop with --overlap-update (two threads)")
    args = parser.parse_args(argv)
    from training import mappo
    from training.common import parse_args
    from training.recipes import MAPPO_RECIPES

    if args.recipe not in MAPPO_RECIPES:
        parser.error(f"--recipe must be one of {', '.join(MAPPO_RECIPES)}, got {args.recipe!r}")
    rec = MAPPO_RECIPES[args.recipe]
    recipe_args = parse_args(mappo.Args, ["--recipe", args.recipe], description="", presets=MAPPO_RECIPES)
    tasks = mappo.task_list(recipe_args)
    bad = [b for b in args.sizes if b < 1 or b % max(len(tasks), 1)]
    if bad:
        parser.error(f"--sizes must be positive multiples of the recipe's {len(tasks)} tasks (each task gets as many "
                     f"copies), got {bad}")
    print("command:", shlex.join(["python", "benchmarks/training_throughput.py", *(argv or sys.argv[1:])]))
    import covert_env

    print(f"covert_env {covert_env.__version__}, recipe {args.recipe}: {len(tasks)} tasks, mask "
          f"{rec.get('mask_mode', 'visible')}, load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    print("| B | loop | env-steps per CPU-second | per wall-second | / raw env (wall) | " + " | ".join(PARTS) + " |")
    print("|---|---|---|---|---|" + "---|" * len(PARTS))
    for b in args.sizes:
        raw, raw_wall = raw_rate(tasks, b, args.seconds, env_kwargs(recipe_args))
        print(f"| {b} | raw env | {raw:,.0f} | {raw_wall:,.0f} | 1.00 |" + " |" * len(PARTS), flush=True)
        for guard in args.guards:
            for overlap in (False, True) if args.overlap else (False,):
                rate, wall, parts = loop_rate(args.recipe, b, guard, args.updates, args.num_steps, overlap)
                total = sum(parts.values())
                shares = (" |" * len(PARTS) if overlap else
                          " " + " | ".join(f"{100 * parts[p] / total:.0f} %" for p in PARTS) + " |")
                name = f"{guard}, overlapped" if overlap else guard
                print(f"| {b} | {name} | {rate:,.0f} | {wall:,.0f} | {wall / raw_wall:.3f} |" + shares, flush=True)
    print(f"load average at the end: {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
