"""Learning curves of :mod:`training.mappo` runs: training episode reward vs env steps and vs wall time.

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

__all__ = ["load_curve", "band", "main"]


def load_curve(run: Path) -> dict[str, np.ndarray]:
    """``env_steps``, ``wall_seconds`` and ``reward`` arrays of a run's ``curve.jsonl``."""
    rows = [json.loads(line) for line in (Path(run) / "curve.jsonl").read_text().splitlines() if line.strip()]
    if not rows:
        raise ValueError(f"{run}/curve.jsonl has no rows")
    return {k: np.array([r[k] for r in rows], float) for k in ("env_steps", "wall_seconds", "reward")}


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
    p.add_argument("--out", default="outputs/curves.png", help="figure path")
    a = p.parse_args(argv)
    missing = [r for r in a.runs if not (Path(r) / "curve.jsonl").is_file()]
    if missing:
        p.error(f"no curve.jsonl in {', '.join(missing)}")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401  (matplotlib.ticker.FuncFormatter below)

    curves = [load_curve(Path(r)) for r in a.runs]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for ax, key, label in ((axes[0], "env_steps", "env steps (copy-slots)"),
                           (axes[1], "wall_seconds", "wall time (min)")):
        scale = 60.0 if key == "wall_seconds" else 1.0
        grid, mean, lo, hi = band([c[key] / scale for c in curves], [c["reward"] for c in curves])
        ax.plot(grid, mean, label=f"mean of {len(curves)} run(s)")
        ax.fill_between(grid, lo, hi, alpha=0.3, label="95 % bootstrap CI over runs")
        if a.dp is not None:
            ax.axhline(a.dp, ls="--", color="k", label="DP planner (held-out scenes)")
        ax.set_xlabel(label)
        if key == "env_steps":                      # 400000-wide labels overlap: thousands
            ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v / 1e3:g}k"))
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("training episode reward (mean over UAVs)")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.out, dpi=110)
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
