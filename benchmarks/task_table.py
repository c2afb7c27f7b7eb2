"""Per-task scores and constraint rates of a suite run, with each policy against the best planner of the task.

    python benchmarks/task_table.py outputs/suite/cells.csv                    # every policy of the run
    python benchmarks/task_table.py outputs/suite/cells.csv --policies dp mappo:runs/a,runs/b

The suite's ``suite.md`` aggregates over tasks; a target stated per task ("on every 3-UAV task, zone violations
<= 1 %") needs the per-task view. For each task and policy this prints the normalised score's IQM with its 95 %
bootstrap interval over runs x scenes (one stratum: the task), the constraint rates (zone violations, blocked LoS
at slot times and along the path, the blocked share of the path, separation-violation slots per UAV, the smallest
separation), and P(policy > the task's best planner), the Mann-Whitney probability over their (run, scene) scores
(:mod:`covert_env.evaluation.stats`). The best planner is the ``dp*`` policy with the highest mean score on the task.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from covert_env.evaluation.stats import iqm, probability_of_improvement, stratified_bootstrap_ci  # noqa: E402

RATES = (("zone_violation_rate", "zone"), ("occlusion_rate", "LoS slots"), ("occlusion_rate_path", "LoS path"),
         ("blocked_path_share", "path share"), ("separation_violations", "sep./UAV"))


def task_tables(rows: list[dict], policies: list[str]) -> str:
    """The per-task markdown tables (module docstring) of ``rows`` (a cells.csv read as dicts)."""
    out = []
    for task in dict.fromkeys(r["task"] for r in rows):
        mine = [r for r in rows if r["task"] == task]
        everyone = list(dict.fromkeys(r["policy"] for r in mine))
        scores = {p: np.array([float(r["score"]) for r in mine if r["policy"] == p]) for p in everyone}
        planners = [p for p in everyone if p.startswith("dp")]           # of the whole run, shown or not
        best = max(planners, key=lambda p: scores[p].mean()) if planners else None
        best_scores = scores.get(best)
        scores = {p: scores[p] for p in policies if p in scores}
        out += [f"### {task} (best planner: {best})", "",
                "| policy | score IQM [95 % CI] | " + " | ".join(h for _, h in RATES)
                + " | min sep. (m) | P(> best planner) |", "|---" * (len(RATES) + 4) + "|"]
        for p, s in scores.items():
            point, lo, hi = stratified_bootstrap_ci(s[:, None], iqm, reps=2000)
            rates = [np.mean([float(r[k]) for r in mine if r["policy"] == p]) for k, _ in RATES]
            sep = min(float(r["min_separation"]) for r in mine if r["policy"] == p)
            poi = ("-" if best is None or p == best
                   else f"{probability_of_improvement(s[:, None], best_scores[:, None]):.2f}")
            out.append(f"| {p} | {point:.3f} [{lo:.3f}, {hi:.3f}] | " + " | ".join(f"{v:.3f}" for v in rates)
                       + f" | {sep:.1f} | {poi} |")
        out.append("")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("cells", help="a suite's cells.csv (covert-env benchmark --out DIR writes DIR/cells.csv)")
    p.add_argument("--policies", nargs="+", help="policy specs to show, in this order (default: every one)")
    a = p.parse_args(argv)
    try:
        with open(a.cells, newline="") as f:
            rows = list(csv.DictReader(f))
    except OSError as exc:
        p.error(f"{a.cells}: {exc.strerror}")
    if not rows or "score" not in rows[0]:
        p.error(f"{a.cells}: not a suite cells.csv (no rows with a score column)")
    policies = a.policies or list(dict.fromkeys(r["policy"] for r in rows))
    missing = [q for q in policies if not any(r["policy"] == q for r in rows)]
    if missing:
        p.error(f"--policies: {missing} not in {a.cells}")
    print(task_tables(rows, policies))
    return 0


if __name__ == "__main__":
    sys.exit(main())
