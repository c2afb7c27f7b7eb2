"""Learning curves of :mod:`training.mappo` runs: training episode reward vs env steps and vs wall time.

A second row draws the separation constraint the same way: slots per UAV and episode closer than d_safe1
(``cost_separation``, eq. 2), with the target level (``--separation-target``, default 0.5) as a dashed line.
Runs trained with ``--constraints`` get one row per constrained cost instead (per UAV and episode), each with its
limit (the run's per-slot limit times the episode's slots) as the dashed line.

    python -m training.curves runs/<seed0> runs/<seed1> runs/<seed2> --dp 240.4 --out outputs/curves.png

Each run's ``curve.jsonl`` (one line per update: env steps, wall seconds, mean reward of the episodes that ended
in the update) is interpolated onto a common grid up to the shortest run; the figure draws the mean over runs
(training seeds) with a 95 % bootstrap interval over them (resampled runs; one run: its curve alone), and the DP
planner's level on the held-out scenes as a dashed line. Training episodes are random training scenes with
sampled (not greedy) actions, so they sit below the harness's deterministic scores.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from covert_env.envs.batch import COSTS as ENV_COSTS

__all__ = ["load_curve", "band", "main"]


COSTS = tuple(f"cost_{name}" for name in ENV_COSTS)
LABELS = {"cost_los": "blocked LoS at slot ends", "cost_los_path": "blocked share of the path",
          "cost_zone": "zone violations", "cost_separation": "separation violations",
          "cost_terrain": "terrain violations"}


def load_curve(run: Path) -> dict[str, np.ndarray]:
    """``env_steps``, ``wall_seconds``, ``reward`` and the ``cost_*`` arrays of a run's ``curve.jsonl``."""
    rows = [json.loads(line) for line in (Path(run) / "curve.jsonl").read_text().splitlines() if line.strip()]
    if not rows:
        raise ValueError(f"{run}/curve.jsonl has no rows")
    if not all(isinstance(r, dict) and "env_steps" in r and "reward" in r for r in rows):
        # training.imitation's curve has epochs and losses, not env steps and rewards: not a curve to draw here.
        raise ValueError(f"{run}/curve.jsonl is not a training.mappo curve (its rows lack env_steps or reward)")
    return {k: np.array([r.get(k, np.nan) for r in rows], float)
            for k in ("env_steps", "wall_seconds", "reward", *COSTS)}


def constraint_levels(run: Path) -> dict[str, float]:
    """``{cost key: limit per UAV and episode}`` of a run's ``--constraints`` (``args.json``; empty without)."""
    path = Path(run) / "args.json"
    if not path.is_file():
        return {}
    args = json.loads(path.read_text())
    slots = float(args.get("max_cycles", 70))
    limits = {}
    for item in filter(None, (x.strip() for x in str(args.get("constraints", "")).split(","))):
        name, _, value = item.partition("=")
        limits[f"cost_{name.strip()}"] = float(value) * slots
    if args.get("lagrangian"):
        limits["cost_separation"] = float(args.get("cost_limit", 0.007)) * slots
    return {k: limits[k] for k in COSTS if k in limits}


def band(xs: list[np.ndarray], ys: list[np.ndarray], points: int = 200, reps: int = 1000,
         seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Grid, mean over runs and the 2.5 / 97.5 percentiles of the mean over runs resampled with replacement."""
    grid = np.linspace(max(x[0] for x in xs), min(x[-1] for x in xs), points)
    curves = np.stack([np.interp(grid, x, y) for x, y in zip(xs, ys, strict=True)])      # (runs, points)
    idx = np.random.default_rng(seed).integers(0, len(curves), size=(reps, len(curves)))
    means = curves[idx].mean(axis=1)
    lo, hi = np.percentile(means, [2.5, 97.5], axis=0)
    return grid, curves.mean(axis=0), lo, hi


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m training.curves", description=__doc__.split("\n")[0])
    p.add_argument("runs", nargs="+", help="training.mappo run folders (one per training seed)")
    p.add_argument("--dp", type=float, default=None, help="the DP planner's episode reward, drawn as a line")
    p.add_argument("--separation-target", type=float, default=0.5,
                   help="separation violations per UAV and episode aimed at, drawn as a line")
    p.add_argument("--out", default="outputs/curves.png", help="figure path")
    a = p.parse_args(argv)
    missing = [r for r in a.runs if not (Path(r) / "curve.jsonl").is_file()]
    if missing:
        p.error(f"no curve.jsonl in {', '.join(missing)}")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401  (matplotlib.ticker.FuncFormatter below)

    try:
        curves = [load_curve(Path(r)) for r in a.runs]
    except (ValueError, OSError) as exc:
        p.error(str(exc))
    metrics = [("reward", "training episode reward\n(mean over UAVs)", a.dp, "DP planner (held-out scenes)")]
    limits = constraint_levels(Path(a.runs[0]))
    if set(limits) - {"cost_separation"}:              # --constraints: a row per constrained cost
        for key, level in limits.items():
            if all(np.isfinite(c[key]).all() for c in curves):
                metrics.append((key, f"{LABELS[key]}\n(per UAV and episode)", level, f"limit ({level:.3g})"))
    elif all(np.isfinite(c["cost_separation"]).all() for c in curves):
        metrics.append(("cost_separation", "separation violations\n(slots per UAV and episode)",
                        a.separation_target, f"target ({a.separation_target:g})"))
    fig, axes = plt.subplots(len(metrics), 2, figsize=(11, 3.6 * len(metrics)), sharey="row", squeeze=False)
    for row, (metric, ylabel, level, level_label) in enumerate(metrics):
        for ax, key, label in ((axes[row, 0], "env_steps", "env steps (copy-slots)"),
                               (axes[row, 1], "wall_seconds", "wall time (min)")):
            scale = 60.0 if key == "wall_seconds" else 1.0
            grid, mean, lo, hi = band([c[key] / scale for c in curves], [c[metric] for c in curves])
            ax.plot(grid, mean, label=f"mean of {len(curves)} run(s)")
            ax.fill_between(grid, lo, hi, alpha=0.3, label="95 % bootstrap CI over runs")
            if level is not None:
                ax.axhline(level, ls="--", color="k", label=level_label)
            ax.set_xlabel(label)
            if key == "env_steps":                      # 400000-wide labels overlap: thousands
                ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v / 1e3:g}k"))
            ax.grid(alpha=0.3)
        axes[row, 0].set_ylabel(ylabel)
        axes[row, 0].legend(fontsize=8)
    fig.tight_layout()
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.out, dpi=110)
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
