"""Env-steps per second of the vector env at B = 1, 64, 256, 1024 copies, both action modes, vs VMAS navigation.

    python benchmarks/vector_throughput.py [--seconds 3] [--sizes 1 64 256 1024] [--rounds 2] [--profile]

``--profile`` also profiles one episode at the largest B in both modes: the share of a step each part takes
(flight, manoeuvres, line of sight, separation, clearance, zone, observations, masks and their table lookups,
solve_manoeuvre) and the functions by own time.

Ours: ``covert_env.vector_env(num_envs=B, n_uavs=3, scenario="paper")`` (16 polytopes), automatic resets
included. Unicycle actions are drawn up front; waypoint actions are drawn from the current masks (a uniform
allowed node per agent, from pre-drawn noise: that cost is part of using masks). VMAS: ``navigation`` with 3 agents
on the CPU, one torch thread, when ``vmas`` is importable (run this script with the interpreter of a venv that has
it, e.g. ``.venv-vmas/bin/python``).

An env-step is one copy advancing one slot (all its agents), as VMAS counts them. Each configuration runs
``rounds`` times, interleaved with the others, so load from other processes hits all of them alike; the table
gives wall-clock and CPU-time throughput (CPU time is what the process itself used, robust to a loaded machine),
their ratios, and the resident memory per copy (RSS growth over building and stepping the env through an automatic
reset, / B, measured in a fresh interpreter).
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
# This checkout's covert_env, also when another copy is installed (e.g. in the VMAS venv).
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize() / 2 ** 20


class Ours:
    def __init__(self, b: int, mode: str):
        import covert_env

        self.env = covert_env.vector_env(num_envs=b, n_uavs=3, scenario="paper", action_mode=mode)
        self.env.reset(seed=0)
        rng = np.random.default_rng(0)
        self.mode = mode
        if mode == "unicycle":
            self.pool = rng.uniform(-1, 1, (8, b, 3, 2)).astype(np.float32)
        else:
            self.pool = rng.random((4, b, 3, len(self.env.lattice)), dtype=np.float32) + 0.5
        self.n = 0
        for _ in range(3):
            self.step()

    def step(self):
        if self.mode == "unicycle":
            act = self.pool[self.n % len(self.pool)]
        else:
            act = np.argmax(self.pool[self.n % len(self.pool)] * self.env.action_masks(), axis=-1)
        self.env.step(act)
        self.n += 1


class Vmas:
    def __init__(self, b: int):
        import torch
        import vmas

        torch.set_num_threads(1)
        self.env = vmas.make_env("navigation", num_envs=b, device="cpu", continuous_actions=True, n_agents=3,
                                 seed=0)
        self.env.reset()
        g = torch.Generator().manual_seed(0)
        self.pool = [[torch.rand(b, 2, generator=g) * 2 - 1 for _ in range(3)] for _ in range(8)]
        self.n = 0
        for _ in range(3):
            self.step()

    def step(self):
        _, _, dones, _ = self.env.step(self.pool[self.n % len(self.pool)])
        if dones.any():
            for i in dones.nonzero().flatten().tolist():
                self.env.reset_at(i)
        self.n += 1


def memory_per_copy(name: str, b: int) -> float:
    """MB of resident memory per copy: RSS growth over building the env and stepping it through an automatic
    reset (75 steps), divided by B, in a fresh interpreter (imports and caches of other runs excluded)."""
    make = f"m.Vmas({b})" if name == "vmas navigation" else f"m.Ours({b}, {name!r})"
    warm = "m.Vmas(1)" if name == "vmas navigation" else f"m.Ours(1, {name!r})"
    code = (f"import benchmarks.vector_throughput as m\n"
            f"{warm}; rss = m._rss_mb(); r = {make}\n"
            f"for _ in range(75): r.step()\n"
            f"print((m._rss_mb() - rss) / {b})")
    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=root, check=True)
    return float(out.stdout.split()[-1])


def measure(runner, seconds: float) -> tuple[int, float, float]:
    """Steps, wall seconds and CPU seconds of stepping ``runner`` for about ``seconds``."""
    n, w0, c0 = 0, time.perf_counter(), time.process_time()
    while True:
        runner.step()
        n += 1
        if time.perf_counter() - w0 >= seconds:
            return n, time.perf_counter() - w0, time.process_time() - c0


#: The parts of a batched step the profile breaks out (function names in covert_env, cumulative time each).
PARTS = (
    ("flight, unicycle (fly_arc)", "flight.py", "fly_arc"),
    ("flight, waypoint (fly_waypoints)", "batch.py", "fly_waypoints"),
    ("  manoeuvres to the chosen nodes (solve_manoeuvre + fallback)", "flight.py", "waypoint_controls"),
    ("  turn-then-straight path (fly_turn_straight)", "flight.py", "fly_turn_straight"),
    ("slot quantities (moves_quantities)", "metrics.py", "moves_quantities"),
    ("  line of sight (TerrainRows.line_of_sight)", "visibility.py", "line_of_sight"),
    ("  separation along the path (nearest_teammate)", "metrics.py", "nearest_teammate"),
    ("  terrain clearance", "metrics.py", "terrain_clearance"),
    ("  zone distance", "zone.py", "zone_distance"),
    ("observations (own features, rows)", "vector.py", "_obs_rows"),
    ("waypoint masks (action_masks)", "batch.py", "action_masks"),
    ("  table lookups (ReachTable._lookup)", "reach.py", "_lookup"),
    ("solve_manoeuvre, all calls", "dynamics.py", "solve_manoeuvre"),
    ("automatic resets (_reset_copies)", "vector.py", "_reset_copies"),
)


def profile_step(b: int, mode: str, steps: int = 70) -> None:
    """cProfile of ``steps`` batched steps (one episode: the automatic resets are in it): where the time of a
    step goes, by part (cumulative CPU time per step and share of the step), then the functions by own time."""
    import cProfile
    import pstats

    r = Ours(b, mode)
    prof = cProfile.Profile(time.process_time)          # CPU time: robust to other processes' load
    prof.enable()
    for _ in range(steps):
        r.step()
    prof.disable()
    stats = pstats.Stats(prof)
    step = next(ct for (f, _, name), (_, _, _, ct, _) in stats.stats.items()
                if name == "step" and f.endswith("vector.py"))
    print(f"\nprofile: {steps} steps at B = {b}, {mode}: {1e3 * step / steps:.2f} ms CPU per batched step (cProfile "
          f"adds overhead), of which")
    for label, file, func in PARTS:
        ct = sum(ct for (f, _, name), (_, _, _, ct, _) in stats.stats.items() if name == func and f.endswith(file))
        if ct:
            print(f"  {1e3 * ct / steps:7.2f} ms  {100 * ct / step:5.1f} %  {label}")
    print("functions by own time:")
    stats.sort_stats("tottime").print_stats(12)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=3.0, help="measuring time per configuration and round")
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 64, 256, 1024])
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--no-vmas", action="store_true")
    parser.add_argument("--profile", action="store_true", help="also profile one episode at the largest B")
    args = parser.parse_args(argv)
    try:
        if args.no_vmas:
            raise ImportError
        import vmas  # noqa: F401
    except ImportError:
        have_vmas = False
        print("vmas is not importable: no reference measurement (see the module docstring)")
    else:
        have_vmas = True

    rows = []
    for b in args.sizes:
        runners = {"unicycle": Ours(b, "unicycle"), "waypoint": Ours(b, "waypoint")}
        if have_vmas:
            runners["vmas navigation"] = Vmas(b)
        tot = {name: np.zeros(3) for name in runners}
        for _ in range(args.rounds):
            for name, r in runners.items():
                tot[name] += measure(r, args.seconds)
        res = {name: (b * t[0] / t[1], b * t[0] / t[2], memory_per_copy(name, b)) for name, t in tot.items()}
        rows.append((b, res))
        del runners

    print(f"\n{'B':>5}  {'env':<16} {'steps/s wall':>12} {'steps/s CPU':>12} {'MB/copy':>8}  ratios (wall, CPU)")
    for b, res in rows:
        for name, (wall, cpu, mb) in res.items():
            ratio = ""
            if name == "unicycle" and "vmas navigation" in res:
                v = res["vmas navigation"]
                ratio = f"vs VMAS {wall / v[0]:.2f}x, {cpu / v[1]:.2f}x"
            elif name == "waypoint":
                u = res["unicycle"]
                ratio = f"vs unicycle {wall / u[0]:.2f}x, {cpu / u[1]:.2f}x"
            print(f"{b:>5}  {name:<16} {wall:>12.0f} {cpu:>12.0f} {mb:>8.3f}  {ratio}")
    print(f"load average: {os.getloadavg()[0]:.1f} (1 min) on {os.cpu_count()} CPUs")
    if args.profile:
        profile_step(max(args.sizes), "unicycle")
        profile_step(max(args.sizes), "waypoint")


if __name__ == "__main__":
    main()
