"""Env-steps per second of the vector env, default (a new random scene per episode) vs cached scene vs VMAS.

    python benchmarks/vector_throughput.py [--sizes 1 64 256 1024] [--episodes 2] [--seconds 3] [--rounds 2]
        [--modes unicycle waypoint kinematic] [--scenes default cached] [--no-vmas] [--no-memory] [--profile]
    python benchmarks/vector_throughput.py --rss 1000000 [--rss-size 1024] [--rss-every 100000]

The protocol: Ours, "default": ``covert_env.vector_env(num_envs=B, n_uavs=3)`` at its defaults, a new
random training scene per episode (drawn from 10,000 seeds; the pool keeps B + 32 scenes, so a reset mostly builds
new ones). "cached": the same env on the paper scene (``scenario="paper"``, 16 polytopes), built once. VMAS:
``navigation`` with 3 agents on the CPU, one torch thread, reset (all copies, one call) every 70 steps. Every
configuration is timed over whole 70-slot episodes (at least ``--episodes`` per round, more until ``--seconds``
have passed), so the automatic resets, and for "default" the scenes they build, are in the figures. The warm-up
(one ``reset(seed=0)`` and 3 steps) builds only the scenes of the first, untimed, episodes: the column "new
scenes" gives the scenes built in the timed steps per copy-episode (1.0: every episode built its scene; a little
less: a seed drawn again while its scene was still in the pool). Unicycle actions are drawn up front; waypoint
actions from the current masks (a uniform allowed node per agent, from pre-drawn noise: that cost is part of using
masks). Mode "waypoint" is the waypoint env with its default (visible) mask, "kinematic" the same with
``mask_mode="kinematic"`` (every reachable node; the suite's learned teams train with it). An env-step is one
copy advancing one slot (all its agents), as VMAS counts them.

Each configuration runs ``--rounds`` times, interleaved with the others, so load from other processes hits all of
them alike; the table gives wall-clock and CPU-time throughput (CPU time is what the process itself used, robust
to a loaded machine), the resident memory per copy (RSS growth over building and stepping the env through an
automatic reset, / B, in a fresh interpreter; ``--no-memory`` skips it), then the ratios of the same run:
default / cached (target >= 0.5), default / VMAS (target >= 1), cached / VMAS (target >= 2), waypoint / unicycle
and kinematic / unicycle (target >= 0.5 each).
The command line is printed first.

``--profile`` also profiles one episode of each of our configurations at the largest B: the share of a step each
part takes (flight, manoeuvres, line of sight, separation, clearance, zone, observations, masks and their table
lookups, solve_manoeuvre, automatic resets and the new scenes they build) and the functions by own time.

``--rss N`` runs only the memory check instead: the default unicycle env at B = ``--rss-size`` stepped for N
env-steps (e.g. 10**6), RSS printed every ``--rss-every`` env-steps; it should stay flat once the scene pool is
full (B + 32 scenes: after the second reset at large B).

VMAS is optional; the peers (VMAS here, mpe2 for benchmarks/env_throughput.py) go in one venv that sees this
machine's CPU torch (name torch==2.13.0 in the same pip command, or pip fetches a CUDA build)::

    python -m venv --system-site-packages .venv-peers
    .venv-peers/bin/pip install torch==2.13.0 vmas mpe2
    .venv-peers/bin/python benchmarks/vector_throughput.py

Without ``vmas`` importable the script says so and measures ours alone.
"""

from __future__ import annotations

import argparse
import os
import resource
import shlex
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
# This checkout's covert_env, also when another copy is installed (e.g. in the peers' venv).
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

#: Episode length of every configuration: the env's default (Config.n_slots), VMAS reset to match.
EPISODE = 70
SCENES = {"default": {}, "cached": {"scenario": "paper"}}
#: Env keywords every measured configuration of ours gets besides its scene (``--path-samples``).
EXTRA: dict = {}


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize() / 2 ** 20


class Ours:
    """The vector env at B copies, ``scene`` "default" (a new random scene per episode) or "cached" (paper)."""

    def __init__(self, b: int, mode: str, scene: str = "cached"):
        import covert_env

        self.b, self.mode = b, mode
        kwargs = dict(action_mode="waypoint", mask_mode="kinematic") if mode == "kinematic" else dict(action_mode=mode)
        self.env = covert_env.vector_env(num_envs=b, n_uavs=3, **kwargs, **SCENES[scene], **EXTRA)
        assert self.env.episode_length == EPISODE
        # Counts the scenes built, to show that the timed episodes build theirs (a benchmark may read the pool).
        self.built, pool = 0, self.env._pool
        fill = pool._fill

        def counted(rows, *args):
            self.built += len(rows)
            return fill(rows, *args)

        pool._fill = counted
        self.env.reset(seed=0)
        rng = np.random.default_rng(0)
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
    """VMAS navigation, 3 agents, B copies on the CPU; every copy reset together every EPISODE steps."""

    def __init__(self, b: int):
        import torch
        import vmas

        torch.set_num_threads(1)
        self.b, self.built = b, 0
        self.env = vmas.make_env("navigation", num_envs=b, device="cpu", continuous_actions=True, n_agents=3,
                                 seed=0)
        self.env.reset()
        g = torch.Generator().manual_seed(0)
        self.pool = [[torch.rand(b, 2, generator=g) * 2 - 1 for _ in range(3)] for _ in range(8)]
        self.n = 0
        for _ in range(3):
            self.step()

    def step(self):
        self.env.step(self.pool[self.n % len(self.pool)])
        self.n += 1
        if self.n % EPISODE == 0:
            self.env.reset()


def make_runner(name: str, b: int):
    """``name``: "vmas navigation" or "<scene> <mode>" (e.g. "default unicycle")."""
    if name == "vmas navigation":
        return Vmas(b)
    scene, mode = name.split()
    return Ours(b, mode, scene)


def memory_per_copy(name: str, b: int) -> float:
    """MB of resident memory per copy: RSS growth over building the env and stepping it through an automatic
    reset (75 steps), divided by B, in a fresh interpreter (imports and caches of other runs excluded)."""
    code = (f"import benchmarks.vector_throughput as m\n"
            f"m.make_runner({name!r}, 1); rss = m._rss_mb(); r = m.make_runner({name!r}, {b})\n"
            f"for _ in range(75): r.step()\n"
            f"print((m._rss_mb() - rss) / {b})")
    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=root, check=True)
    return float(out.stdout.split()[-1])


def measure(runner, seconds: float, episodes: int) -> tuple[int, float, float, int]:
    """Steps, wall seconds, CPU seconds and scenes built over whole episodes of ``runner``: at least ``episodes``,
    more until ``seconds`` have passed (EPISODE consecutive steps hold one reset of every copy, whatever the
    phase)."""
    n, built, w0, c0 = 0, runner.built, time.perf_counter(), time.process_time()
    while n < episodes * EPISODE or time.perf_counter() - w0 < seconds:
        for _ in range(EPISODE):
            runner.step()
        n += EPISODE
    return n, time.perf_counter() - w0, time.process_time() - c0, runner.built - built


#: The parts of a batched step the profile breaks out (function names in covert_env, cumulative time each).
PARTS = (
    ("flight, unicycle (fly_arc)", "flight.py", "fly_arc"),
    ("flight, waypoint (fly_waypoints)", "flight.py", "fly_waypoints"),
    ("  manoeuvres to the chosen nodes (solve_manoeuvre + fallback)", "flight.py", "waypoint_controls"),
    ("  turn-then-straight path (fly_turn_straight)", "flight.py", "fly_turn_straight"),
    ("slot quantities (moves_quantities)", "metrics.py", "moves_quantities"),
    ("  line of sight (TerrainRows.line_of_sight)", "visibility.py", "line_of_sight"),
    ("  separation along the path (nearest_teammate)", "metrics.py", "nearest_teammate"),
    ("  terrain clearance", "metrics.py", "terrain_clearance"),
    ("  zone distance", "zone.py", "zone_distance"),
    ("observations (own features, rows)", "vector.py", "_obs_rows"),
    ("waypoint masks (action_masks)", "batch.py", "action_masks"),
    ("  table lookups (reach._lookup_labels)", "reach.py", "_lookup_labels"),
    ("solve_manoeuvre, all calls", "dynamics.py", "solve_manoeuvre"),
    ("automatic resets (_reset_copies)", "vector.py", "_reset_copies"),
    ("  new scenes (ScenePool.rows_of)", "scene_pool.py", "rows_of"),
)


def profile_step(b: int, mode: str, scene: str = "cached", steps: int = EPISODE) -> None:
    """cProfile of ``steps`` batched steps (one episode: the automatic resets are in it): where the time of a
    step goes, by part (cumulative CPU time per step and share of the step), then the functions by own time."""
    import cProfile
    import pstats

    r = Ours(b, mode, scene)
    prof = cProfile.Profile(time.process_time)          # CPU time: robust to other processes' load
    prof.enable()
    for _ in range(steps):
        r.step()
    prof.disable()
    stats = pstats.Stats(prof)

    def cum(file, func):
        return sum(ct for (f, _, name), (_, _, _, ct, _) in stats.stats.items() if name == func and f.endswith(file))

    step = cum("vector.py", "step")
    print(f"\nprofile: {steps} steps at B = {b}, {scene} {mode}: {1e3 * step / steps:.2f} ms CPU per batched step "
          f"(cProfile adds overhead), of which")
    for label, file, func in PARTS:
        ct = cum(file, func)
        if ct:
            print(f"  {1e3 * ct / steps:7.2f} ms  {100 * ct / step:5.1f} %  {label}")
    print("functions by own time:")
    stats.sort_stats("tottime").print_stats(12)


def rss_run(b: int, env_steps: int, every: int) -> None:
    """The default unicycle env at B copies stepped for ``env_steps`` env-steps, RSS every ``every`` env-steps."""
    r = Ours(b, "unicycle", "default")
    steps = -(-env_steps // b)
    every = max(1, every // b)
    print(f"RSS of the default env (a new scene per episode), B = {b}, {steps} batched steps = {steps * b} "
          f"env-steps; target: flat once the scene pool ({b + 32} scenes) is full")
    print(f"{'env-steps':>10} {'episodes':>8} {'scenes built':>12} {'RSS MB':>8} {'wall s':>7}")
    t0, first, pool = time.perf_counter(), None, r.env._pool
    for i in range(1, steps + 1):
        r.step()
        if i % every == 0 or i == steps:
            rss = _rss_mb()
            print(f"{i * b:>10} {r.n // EPISODE:>8} {r.built:>12} {rss:>8.1f} {time.perf_counter() - t0:>7.1f}",
                  flush=True)
            if first is None and len(pool) == pool.capacity:   # no more rows to grow
                first = (i * b, rss)
    if first is not None:
        print(f"RSS growth since the scene pool was full (at {first[0]} env-steps): {_rss_mb() - first[1]:+.1f} MB")


def ratio_rows(res: dict) -> list[tuple[str, str, str]]:
    """(label, numerator, denominator, target) rows of the table's ratios present in ``res``."""
    out = []
    for mode in ("unicycle", "waypoint"):
        out.append((f"default / cached, {mode}", f"default {mode}", f"cached {mode}", ">= 0.5"))
    out.append(("default / VMAS, unicycle", "default unicycle", "vmas navigation", ">= 1"))
    out.append(("cached / VMAS, unicycle", "cached unicycle", "vmas navigation", ">= 2"))
    for scene in ("default", "cached"):
        for mode in ("waypoint", "kinematic"):
            out.append((f"{mode} / unicycle, {scene}", f"{scene} {mode}", f"{scene} unicycle", ">= 0.5"))
    return [r for r in out if r[1] in res and r[2] in res]


def write_json(path: Path, rows, argv) -> None:
    """The rows as the documentation's throughput figure reads them: per B and configuration the env-steps per
    second (wall clock and CPU time), with the command, version and load that made them."""
    import json

    import covert_env

    cmd = shlex.join(["python", "benchmarks/vector_throughput.py", *(sys.argv[1:] if argv is None else argv)])
    data = {"command": cmd, "covert_env": covert_env.__version__, "date": time.strftime("%Y-%m-%d"),
            "cpus": os.cpu_count(), "load_average": round(os.getloadavg()[0], 1),
            "rows": [{"B": int(b), "config": name, "steps_per_s_wall": round(float(r[0]), 1),
                      "steps_per_s_cpu": round(float(r[1]), 1)} for b, res in rows for name, r in res.items()]}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1) + "\n")
    print(f"wrote {path}")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=3.0,
                        help="least measuring time per configuration and round (whole episodes)")
    parser.add_argument("--episodes", type=int, default=2, help="least whole episodes per configuration and round")
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 64, 256, 1024])
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--modes", nargs="+", choices=["unicycle", "waypoint", "kinematic"],
                        default=["unicycle", "waypoint", "kinematic"],
                        help="unicycle; waypoint (visible mask); kinematic (waypoint with the kinematic mask)")
    parser.add_argument("--scenes", nargs="+", choices=list(SCENES), default=list(SCENES))
    parser.add_argument("--no-vmas", action="store_true")
    parser.add_argument("--path-samples", type=int, metavar="P",
                        help="the env's path_samples (default: its own, 11): LoS and separation are checked at P - 1 "
                             "instants per slot; 2 checks the slot's end only (with --no-memory)")
    parser.add_argument("--no-memory", action="store_true", help="skip the memory per copy (fresh interpreters)")
    parser.add_argument("--profile", action="store_true", help="also profile one episode at the largest B")
    parser.add_argument("--json", type=Path, metavar="PATH",
                        help="also write the rows to PATH (docs/results/throughput.json: the documentation's figure)")
    parser.add_argument("--rss", type=int, metavar="ENV_STEPS", help="only the RSS check over ENV_STEPS env-steps")
    parser.add_argument("--rss-size", type=int, default=1024, help="B of the RSS check")
    parser.add_argument("--rss-every", type=int, metavar="ENV_STEPS", help="RSS printed every ... (default: 20 rows)")
    args = parser.parse_args(argv)
    if args.path_samples is not None:
        if not args.no_memory:
            parser.error("--path-samples needs --no-memory (the memory probe builds the default env)")
        EXTRA["path_samples"] = args.path_samples
    import covert_env

    print("command:", shlex.join(sys.orig_argv if argv is None else [sys.executable, __file__, *argv]))
    print(f"covert_env {covert_env.__version__}, OMP_NUM_THREADS={os.environ['OMP_NUM_THREADS']}, "
          f"load average {os.getloadavg()[0]:.1f} (1 min) on {os.cpu_count()} CPUs")
    if args.rss is not None:
        rss_run(args.rss_size, args.rss, args.rss_every or max(args.rss // 20, 1))
        return
    try:
        if args.no_vmas:
            raise ImportError
        import vmas  # noqa: F401
    except ImportError:
        have_vmas = False
        print("vmas is not importable (or --no-vmas): no VMAS measurement (see the module docstring for its venv)")
    else:
        have_vmas = True

    names = [f"{scene} {mode}" for mode in args.modes for scene in args.scenes]
    if have_vmas:
        names.append("vmas navigation")
    rows = []
    for b in args.sizes:
        runners = {name: make_runner(name, b) for name in names}
        tot = {name: np.zeros(4) for name in runners}
        for _ in range(args.rounds):
            for name, r in runners.items():
                tot[name] += measure(r, args.seconds, args.episodes)
        del runners
        res = {name: (b * t[0] / t[1], b * t[0] / t[2], np.nan if args.no_memory else memory_per_copy(name, b),
                      t[3] / (b * t[0] / EPISODE), int(t[0])) for name, t in tot.items()}
        rows.append((b, res))

    print(f"\n{'B':>5}  {'env':<17} {'steps/s wall':>12} {'steps/s CPU':>12} {'MB/copy':>8} {'new scenes':>10} "
          f"{'timed steps':>11}")
    for b, res in rows:
        for name, (wall, cpu, mb, new, n) in res.items():
            new = "-" if name == "vmas navigation" else f"{new:.2f}"    # VMAS has no scenes to build
            print(f"{b:>5}  {name:<17} {wall:>12.0f} {cpu:>12.0f} {mb:>8.3f} {new:>10} {n:>11}")
    print(f"\n{'B':>5}  {'ratio (same run)':<30} {'wall':>6} {'CPU':>6}  target")
    for b, res in rows:
        for label, num, den, target in ratio_rows(res):
            print(f"{b:>5}  {label:<30} {res[num][0] / res[den][0]:>5.2f}x {res[num][1] / res[den][1]:>5.2f}x  "
                  f"{target}".rstrip())
    print(f"load average: {os.getloadavg()[0]:.1f} (1 min) on {os.cpu_count()} CPUs")
    if args.json:
        write_json(args.json, rows, argv)
    if args.profile:
        for name in names:
            if name != "vmas navigation":
                scene, mode = name.split()
                profile_step(max(args.sizes), mode, scene)


if __name__ == "__main__":
    main()
