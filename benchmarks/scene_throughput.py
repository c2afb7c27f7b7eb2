"""Scenes built per second, per scene family, by the vector env's reset, and where a scene build's time goes.

    python benchmarks/scene_throughput.py [--sizes 64 1024] [--families NAME ...] [--mode unicycle|waypoint]
        [--repeats 1] [--profile-size 64] [--functions 0]

For each family and B: ``covert_env.vector_env(num_envs=B, n_uavs=3, family=NAME)`` (unicycle actions unless
``--mode waypoint``, whose scenes also tabulate the lattice's visibility per slot), then one timed
``reset(seed=...)`` per repeat, each on a fresh env: a reset draws a training scene per copy and builds those not in
the pool, so about B new scenes (fewer when two copies draw the same of the 10,000 seeds; the table counts the
scenes actually built). Scenes/s is scenes built per second of that reset, which also draws every copy's starts
and writes the first observations. A B = 2 reset of each family first warms the code paths.

Then a cProfile (CPU time) of one reset at ``--profile-size`` per family: the share of the reset in the pieces of a
scene build (cumulative time of each function): the new scenes as arrays (``SceneBatch.random``: the batched
generator's terrains and roads, their faces, circles and growth factors, and their tracks), the pool's terrain rows
(``TerrainRows.set_rows``), the observation's shared blocks with their per-slot maps (``ScenePool._blocks``), the
lattice visibility (``ScenePool._lattice_visible``, waypoint mode), the start candidates
(``ScenePool._write_starts``), the terrain's padded arrays where they are built polytope by polytope
(``visibility._build_arrays``: the paper scene), all the line of sight (``visible_nodes_rows``), the rest of the
scene build, and the reset outside it. ``--functions N``
also prints the N functions by own time.

Families come from ``covert_env.world.families.FAMILIES``, flown with ``vector_env(num_envs=B, n_uavs=3, family=NAME)``.
The command line is printed first.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
# This checkout's covert_env, also when another copy is installed.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

#: Pieces of a scene build: (label, file, function); indented ones are inside the piece above.
PARTS = (
    ("new scenes as arrays (SceneBatch.random)", "scene_cache.py", "random"),
    ("  terrain generation (generation.random_terrains)", "generation.py", "random_terrains"),
    ("  roads (generation.random_roads)", "generation.py", "random_roads"),
    ("  faces, circles, growth (SceneArrays.__init__)", "scenario.py", "__init__"),
    ("  tracks (SceneArrays.tracks)", "scenario.py", "tracks"),
    ("pool terrain rows (TerrainRows.set_rows)", "visibility.py", "set_rows"),
    ("observation blocks (ScenePool._blocks)", "scene_pool.py", "_blocks"),
    ("lattice visibility (ScenePool._lattice_visible)", "scene_pool.py", "_lattice_visible"),
    ("start candidates (ScenePool._write_starts)", "scene_pool.py", "_write_starts"),
    ("terrain arrays (_build_arrays), inside the first piece using them", "visibility.py", "_build_arrays"),
    ("line of sight, all pieces (visible_nodes_rows)", "visibility.py", "visible_nodes_rows"),
)


def families(names: list[str] | None) -> list[tuple[str, dict]]:
    """(name, vector_env keyword arguments) of the families to measure (all of them without ``names``)."""
    from covert_env.world.families import FAMILIES

    found = [(name, {"family": name}) for name in FAMILIES]
    if names:
        known = dict(found)
        missing = [n for n in names if n not in known]
        if missing:
            raise SystemExit(f"unknown families {missing}; known: {list(known)}")
        found = [(n, known[n]) for n in names]
    return found


def make_env(b: int, mode: str, kwargs: dict):
    """The vector env and a one-item list counting the scenes its pool builds (a benchmark may read the pool)."""
    import covert_env

    env = covert_env.vector_env(num_envs=b, n_uavs=3, action_mode=mode, **kwargs)
    built, pool = [0], env._pool
    fill = pool._fill

    def counted(rows, *args):
        built[0] += len(rows)
        return fill(rows, *args)

    pool._fill = counted
    return env, built


def timed_reset(b: int, mode: str, kwargs: dict, seed: int) -> tuple[int, float, float]:
    """Scenes built, wall and CPU seconds of ``reset(seed=seed)`` on a fresh env of B copies."""
    env, built = make_env(b, mode, kwargs)
    w0, c0 = time.perf_counter(), time.process_time()
    env.reset(seed=seed)
    return built[0], time.perf_counter() - w0, time.process_time() - c0


def profile_reset(name: str, b: int, mode: str, kwargs: dict, functions: int) -> None:
    import cProfile
    import pstats

    env, built = make_env(b, mode, kwargs)
    prof = cProfile.Profile(time.process_time)          # CPU time: robust to other processes' load
    prof.enable()
    env.reset(seed=1000)
    prof.disable()
    stats = pstats.Stats(prof)

    def cum(file, func):
        return sum(ct for (f, _, fn), (_, _, _, ct, _) in stats.stats.items() if fn == func and f.endswith(file))

    reset = cum("vector.py", "reset")
    scenes = cum("scene_pool.py", "_batch") + cum("scene_pool.py", "_fill")
    n = max(built[0], 1)
    print(f"\nprofile: {name}, reset at B = {b} ({mode}), {built[0]} scenes built: {1e3 * reset / n:.2f} ms CPU per "
          f"scene (cProfile adds overhead, most to the many small calls of the generator), per scene and share:")
    top = 0.0
    for label, file, func in PARTS:
        ct = cum(file, func)
        if not label.startswith(" ") and "inside" not in label and "all pieces" not in label:
            top += ct
        if ct:                                          # e.g. no lattice visibility in unicycle mode
            print(f"  {1e3 * ct / n:7.2f} ms  {100 * ct / reset:5.1f} %  {label}")
    print(f"  {1e3 * (scenes - top) / n:7.2f} ms  {100 * (scenes - top) / reset:5.1f} %  rest of the scene build")
    print(f"  {1e3 * (reset - scenes) / n:7.2f} ms  {100 * (reset - scenes) / reset:5.1f} %  "
          f"reset outside scene builds (starts, first observations)")
    if functions:
        print("functions by own time:")
        stats.sort_stats("tottime").print_stats(functions)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 1024])
    parser.add_argument("--families", nargs="+", metavar="NAME", help="default: every family")
    parser.add_argument("--mode", choices=["unicycle", "waypoint"], default="unicycle")
    parser.add_argument("--repeats", type=int, default=1, help="timed resets per family and B (fresh envs)")
    parser.add_argument("--profile-size", type=int, default=64, help="B of the profiled reset (0: no profile)")
    parser.add_argument("--functions", type=int, default=0, help="functions by own time printed per profile")
    args = parser.parse_args(argv)
    import covert_env

    print("command:", shlex.join(sys.orig_argv if argv is None else [sys.executable, __file__, *argv]))
    print(f"covert_env {covert_env.__version__}, OMP_NUM_THREADS={os.environ['OMP_NUM_THREADS']}, "
          f"load average {os.getloadavg()[0]:.1f} (1 min) on {os.cpu_count()} CPUs")
    fams = families(args.families)
    for _, kwargs in fams:
        timed_reset(2, args.mode, kwargs, seed=999)

    print(f"\n{'family':<16} {'B':>5} {'scenes':>7} {'reset s':>8} {'scenes/s wall':>13} {'scenes/s CPU':>12} "
          f"{'ms/scene CPU':>12}")
    for name, kwargs in fams:
        for b in args.sizes:
            tot = [0, 0.0, 0.0]
            for rep in range(args.repeats):
                for i, v in enumerate(timed_reset(b, args.mode, kwargs, seed=rep)):
                    tot[i] += v
            n, wall, cpu = tot
            print(f"{name:<16} {b:>5} {n:>7} {wall:>8.2f} {n / wall:>13.1f} {n / cpu:>12.1f} {1e3 * cpu / n:>12.2f}",
                  flush=True)
    print(f"load average: {os.getloadavg()[0]:.1f} (1 min) on {os.cpu_count()} CPUs")
    if args.profile_size:
        for name, kwargs in fams:
            profile_reset(name, args.profile_size, args.mode, kwargs, args.functions)


if __name__ == "__main__":
    main()
