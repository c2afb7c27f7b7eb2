"""Env-steps per second of the B = 1 parallel env, default (a new random scene per episode) and cached, vs mpe2.

    python benchmarks/env_throughput.py [--seconds 4] [--episodes 2] [--rounds 2] [--mode unicycle|waypoint|both]

The B = 1 comparison. Ours, "default": ``covert_env.parallel_env()`` at its defaults (3 UAVs, a new
random training scene per episode, 70-slot episodes); "cached": the same env on the paper scene
(``scenario="paper"``, 16 polytopes, built once). The peer: mpe2 ``simple_spread_v3`` (N=3, continuous actions)
with ``max_cycles`` set to our episode length, so both run episodes of the same length. Every env is timed over
whole episodes with their resets (``reset()`` when the agents are gone: for "default" it builds the next scene):
at least ``--episodes`` per round, more until ``--seconds`` have passed. The warm-up (``reset(seed=0)`` and 20
steps) builds only the first, untimed, episode's scene. Continuous actions are drawn up front with numpy, so the
figure measures the env, not ``Box.sample()`` (about 40 us per call here, the same for every env); masked discrete
actions are drawn per step from the current mask (that cost is part of using the env). The envs run ``--rounds``
times, interleaved, so load from other processes hits them alike; the table gives wall-clock and CPU-time
env-steps/s and the ratios of the same run (default unicycle / mpe2: target >= 1). The command line
is printed first.

mpe2 is optional: it goes in the peers' venv beside VMAS (``.venv-peers``, made as benchmarks/vector_throughput.py
says), and ``.venv-peers/bin/python benchmarks/env_throughput.py`` runs this script there. Without ``mpe2``
importable the script says so and measures ours alone.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
# This checkout's covert_env, also when another copy is installed (e.g. in the peers' venv).
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

MPE = "mpe2 simple_spread_v3"


class Runner:
    """A PettingZoo parallel env stepped with random actions, reset when its agents are gone."""

    def __init__(self, env, masked: bool = False):
        self.env, self.masked = env, masked
        self.rng = np.random.default_rng(0)
        space = env.action_space(env.possible_agents[0])
        self.pool = None if masked else self.rng.uniform(
            space.low, space.high, (4096, len(env.possible_agents)) + space.shape).astype(space.dtype)
        self.n = 0
        _, self.infos = env.reset(seed=0)
        for _ in range(20):
            self.step()

    def step(self) -> None:
        env = self.env
        if self.masked:
            acts = {a: int(self.rng.choice(np.flatnonzero(self.infos[a]["action_mask"]))) for a in env.agents}
        else:
            row = self.pool[self.n % len(self.pool)]
            acts = {a: row[i] for i, a in enumerate(env.agents)}
        _, _, _, _, self.infos = env.step(acts)
        self.n += 1
        if not env.agents:
            _, self.infos = env.reset()


def measure(runner: Runner, length: int, seconds: float, episodes: int) -> np.ndarray:
    """Steps, wall seconds and CPU seconds over whole episodes (``length`` consecutive steps hold one reset,
    whatever the phase): at least ``episodes``, more until ``seconds`` have passed."""
    n, w0, c0 = 0, time.perf_counter(), time.process_time()
    while n < episodes * length or time.perf_counter() - w0 < seconds:
        for _ in range(length):
            runner.step()
        n += length
    return np.array([n, time.perf_counter() - w0, time.process_time() - c0])


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=4.0,
                        help="least measuring time per env and round (whole episodes)")
    parser.add_argument("--episodes", type=int, default=2, help="least whole episodes per env and round")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--mode", choices=["unicycle", "waypoint", "both"], default="both")
    args = parser.parse_args(argv)

    import covert_env

    print("command:", shlex.join(sys.orig_argv if argv is None else [sys.executable, __file__, *argv]))
    print(f"covert_env {covert_env.__version__}, load average {os.getloadavg()[0]:.1f} (1 min) on "
          f"{os.cpu_count()} CPUs")
    runners = {}
    for mode in ["unicycle", "waypoint"] if args.mode == "both" else [args.mode]:
        for scene, kwargs in (("default", {}), ("cached", {"scenario": "paper"})):
            env = covert_env.parallel_env(action_mode=mode, **kwargs)
            runners[f"{scene} {mode}"] = Runner(env, masked=mode == "waypoint")
    length = runners[next(iter(runners))].env.max_cycles
    try:
        from mpe2 import simple_spread_v3
    except ImportError:
        print("mpe2 is not importable: no reference measurement (see the module docstring for its venv)")
    else:
        runners[MPE] = Runner(simple_spread_v3.parallel_env(N=3, max_cycles=length, continuous_actions=True))

    tot = {name: np.zeros(3) for name in runners}
    for _ in range(args.rounds):
        for name, r in runners.items():
            tot[name] += measure(r, length, args.seconds, args.episodes)
    rate = {name: (t[0] / t[1], t[0] / t[2], int(t[0])) for name, t in tot.items()}

    print(f"\n{length}-step episodes, resets included; ours: 3 UAVs, default = a new random scene per episode, "
          f"cached = the paper scene; {MPE}: N=3, continuous, max_cycles={length}")
    print(f"{'env':<22} {'steps/s wall':>12} {'steps/s CPU':>12} {'timed steps':>11}")
    for name, (wall, cpu, n) in rate.items():
        print(f"{name:<22} {wall:>12.0f} {cpu:>12.0f} {n:>11}")
    print(f"\n{'ratio (same run)':<30} {'wall':>6} {'CPU':>6}  target")
    for mode in ("unicycle", "waypoint"):
        goal = ">= 1" if mode == "unicycle" else ""           # the target is for the defaults
        for num, den, target in ((f"default {mode}", MPE, goal), (f"cached {mode}", MPE, ""),
                                 (f"default {mode}", f"cached {mode}", "")):
            if num in rate and den in rate:
                label = f"{num} / {den.split()[0] if den == MPE else 'cached'}"
                print(f"{label:<30} {rate[num][0] / rate[den][0]:>5.2f}x {rate[num][1] / rate[den][1]:>5.2f}x  "
                      f"{target}".rstrip())
    print(f"load average: {os.getloadavg()[0]:.1f} (1 min) on {os.cpu_count()} CPUs")


if __name__ == "__main__":
    main()
