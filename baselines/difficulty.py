"""Measured difficulty of each scene family: how much of the zone lies in shadow and what it costs the planners.

    python -m baselines.difficulty [--families sparse paper ...] [--scenes 10] [--slots 70] [--jobs 2]
                                   [--out outputs/difficulty]

Per family (:mod:`covert_env.world.families`), on its first ``--scenes`` held-out scenes, 3 UAVs, slots 1..``--slots``:

* **zone in shadow**: the share of the eroded zone's lattice nodes that do not see the target (eq. 10,
  :func:`covert_env.world.visibility.visible_nodes`), mean over slots and scenes; **slots > 25 %**: the share of slots
  with more than a quarter of it shadowed;
* **eq. 3 binds**: the share of slots where some lattice node lies within d_safe2 of a polytope top (the planner
  must avoid it; on other slots eq. 3 removes nothing);
* **blocked LoS** of the shadow-blind DP team (the method of [1]) and the shadow-aware one (the paper's), at slot
  times and along the flown paths: the share of UAV-slots (``occlusion_rate`` and ``occlusion_rate_path`` of
  :func:`covert_env.world.metrics.episode_metrics`).

Writes ``difficulty.md`` (the table, the command, the wall time) and ``difficulty.json`` into ``--out`` and prints
the table. The planner runs take most of the time; they go to ``--jobs`` worker processes.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from baselines.reproduce import RunSpec, make_scenario, run_pairs
from covert_env.command_line import UsageError, int_range, output_dir, positive_int, run_main
from covert_env.geometry.zone import to_world, zone_lattice
from covert_env.world.config import Config
from covert_env.world.families import FAMILIES, HELD_OUT_SEEDS, family_config
from covert_env.world.metrics import terrain_clearance
from covert_env.world.visibility import visible_nodes

__all__ = ["COLUMNS", "geometry", "main", "measure"]

#: Team size of the planner runs.
N_UAVS = 3
#: The table's columns: key, header.
COLUMNS = (("shadow", "zone in shadow"), ("shadowed_slots", "slots > 25 % shadowed"),
           ("eq3_slots", "slots where eq. 3 binds"), ("blind_slot", "blind: blocked LoS at slots"),
           ("blind_path", "blind: along paths"), ("aware_slot", "aware: blocked LoS at slots"),
           ("aware_path", "aware: along paths"))


def geometry(config: Config, seed: int, n_slots: int) -> dict:
    """The shadow and eq. 3 figures of one scene (no planner): per-slot shares over slots 1..n_slots."""
    sc = make_scenario("random", seed, N_UAVS, config)
    track, lattice = sc.track, zone_lattice(config)
    q, phi = track.positions[1:n_slots + 1], track.headings[1:n_slots + 1]
    shadow = 1.0 - visible_nodes(sc.terrain, lattice, q, phi, config.altitude).mean(axis=1)
    near = terrain_clearance(to_world(lattice, q[:, :2], phi), config.altitude, sc.terrain) < config.d_safe2
    return {"shadow": shadow.tolist(), "eq3": near.any(axis=1).tolist()}


def measure(families, scenes: int, n_slots: int, jobs: int) -> dict:
    """Every figure of the table per family, with the per-scene values behind it."""
    seeds = [HELD_OUT_SEEDS.start + i for i in range(scenes)]
    configs = {name: family_config(name) for name in families}
    pairs = [(RunSpec("random", s, N_UAVS, m, n_slots, family=name), Config())
             for name in families for s in seeds for m in ("blind", "aware")]
    runs = run_pairs(pairs, jobs)
    out = {}
    for name, cfg in configs.items():
        geo = [geometry(cfg, s, n_slots) for s in seeds]
        shadow = np.array([g["shadow"] for g in geo])
        row = {"shadow": float(shadow.mean()), "shadowed_slots": float((shadow > 0.25).mean()),
               "eq3_slots": float(np.mean([g["eq3"] for g in geo]))}
        for method in ("blind", "aware"):
            recs = [r for (spec, _), res in zip(pairs, runs, strict=True)
                    if spec.family == name and spec.method == method for r in res["records"]]
            row[f"{method}_slot"] = float(np.mean([r["occlusion_rate"] for r in recs]))
            row[f"{method}_path"] = float(np.mean([r["occlusion_rate_path"] for r in recs]))
        row["per_scene"] = {str(s): {"shadow": float(np.mean(g["shadow"])), "eq3_slots": float(np.mean(g["eq3"]))}
                            for s, g in zip(seeds, geo, strict=True)}
        out[name] = row
    return out


def table(results: dict) -> str:
    """The markdown table of :func:`measure`'s results, shares in %."""
    lines = ["| family | " + " | ".join(h for _, h in COLUMNS) + " |", "|---" * (len(COLUMNS) + 1) + "|"]
    for name, row in results.items():
        lines.append(f"| `{name}` | " + " | ".join(f"{100 * row[k]:.1f} %" for k, _ in COLUMNS) + " |")
    return "\n".join(lines)


def build_parser(prog: str = "python -m baselines.difficulty") -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n")[0])
    p.add_argument("--families", nargs="+", choices=list(FAMILIES), default=list(FAMILIES),
                   help="the families to measure (default: all)")
    p.add_argument("--scenes", type=int_range(1, 1000), default=10,
                   help="held-out scenes per family, in [1, 1000] (default 10)")
    p.add_argument("--slots", type=positive_int, default=None, help="slots per episode (default: the config's 70)")
    p.add_argument("--jobs", type=int_range(1, 64), default=2, help="worker processes for the planner runs")
    p.add_argument("--out", default="outputs/difficulty", help="output folder (git-ignored outputs/)")
    return p


def main(argv: list[str] | None = None, prog: str = "python -m baselines.difficulty") -> int:
    parser = build_parser(prog)
    args = parser.parse_args(argv)
    command = f"{prog} " + " ".join(sys.argv[1:] if argv is None else argv)
    return run_main(parser, lambda: _main(args, command))


def _main(args: argparse.Namespace, command: str) -> int:
    n_slots = Config().n_slots if args.slots is None else args.slots
    if n_slots > Config().n_slots:
        raise UsageError(f"--slots must be in [1, {Config().n_slots}] (n_slots of the config), got {n_slots}")
    out = output_dir(args.out, files=("difficulty.md", "difficulty.json"))
    t0 = time.perf_counter()
    results = measure(list(dict.fromkeys(args.families)), args.scenes, n_slots, args.jobs)
    wall = time.perf_counter() - t0
    text = (f"# Scene families: measured difficulty\n\n{args.scenes} held-out scenes per family (seeds "
            f"{HELD_OUT_SEEDS.start} .. {HELD_OUT_SEEDS.start + args.scenes - 1}), {N_UAVS} UAVs, slots 1..{n_slots}; "
            f"shares of node-slots, slots and UAV-slots (baselines/difficulty.py).\n\n{table(results)}\n\n"
            f"Command: `{command}` ({wall:.0f} s, {args.jobs} worker(s)).\n")
    (out / "difficulty.md").write_text(text)
    (out / "difficulty.json").write_text(json.dumps({"command": command, "scenes": args.scenes, "slots": n_slots,
                                                     "wall_s": wall, "families": results}, indent=1) + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
