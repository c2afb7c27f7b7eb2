"""The suite's leaderboard as the README and the documentation site show it, generated from a run of
``covert-env benchmark`` so that a re-run updates them.

    python -m covert_env.evaluation.leaderboard outputs/suite   # publish a run: docs/results/suite.json, figure, README
    python -m covert_env.evaluation.leaderboard --check         # the README's table is the published run's

``covert-env benchmark`` writes ``summary.json`` beside its other outputs: the run's meta (command, covert_env
version, env id), the reference rewards, each policy's aggregate with its tier and median decision time, the mean
score per task and every cell's score. Publishing copies it to ``docs/results/suite.json``, draws the performance
profiles from it to ``docs/suite_profile.png`` and rewrites the README's table between its markers. The
documentation site renders its tables from the same file (``docs/hooks.py``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from covert_env.command_line import UsageError, run_main
from covert_env.evaluation.tiers import TIERS, spec_tier

__all__ = ["README_MARKERS", "SUMMARY", "draw_profiles", "profile_figure", "publish", "summary", "task_table",
           "tier_table"]

ROOT = Path(__file__).resolve().parents[2]          # the checkout this module runs from
#: Where the published run lives in the repository.
SUMMARY = ROOT / "docs" / "results" / "suite.json"
#: The README's generated block lies between these two lines.
README_MARKERS = ("<!-- leaderboard:start (python -m covert_env.evaluation.leaderboard) -->",
                  "<!-- leaderboard:end -->")
#: Tiers in the order the tables show them.
ORDER = tuple(TIERS)
#: (summary key, column header, format) of the constraint columns.
COLUMNS = (("zone_violation_rate", "zone viol.", ".3f"), ("occlusion_rate", "blocked LoS, slot ends", ".3f"),
           ("blocked_path_share", "path share blocked", ".3f"), ("separation_violations", "sep. viol./UAV", ".3f"),
           ("terrain_violations", "terrain viol./UAV", ".3f"), ("min_separation", "min sep. (m)", ".1f"))


def summary(results: dict, version: str | None = None, env_id: str | None = None, commit: str | None = None) -> dict:
    """The compact record of a suite run (``results.json`` of ``covert-env benchmark``) that the docs are made
    from. ``version``, ``env_id`` and ``commit`` default to the run's meta (runs before they were recorded: give
    them)."""
    meta = dict(results["meta"])
    meta.setdefault("covert_env", version)
    meta.setdefault("env", env_id)
    if meta.get("commit") is None and commit:
        meta["commit"] = commit
    if not meta["covert_env"] or not meta["env"]:
        raise ValueError("summary: the run's meta names no covert_env version or env id; pass version= and env_id=")
    cells = results["cells"]
    policies = {}
    for p, agg in results["aggregate"]["policies"].items():
        mine = [c for c in cells if c["policy"] == p]
        times = [c["decision_time_ms"] for c in mine if c.get("decision_time_ms") is not None]
        policies[p] = {"tier": spec_tier(p), **agg, "decision_time_ms": float(np.median(times)) if times else None,
                       "per_task": {t: float(np.mean([c["score"] for c in mine if c["task"] == t]))
                                    for t in agg["tasks"]}}
    return {"suite": results["suite"], "meta": meta, "reference": results["reference"], "policies": policies,
            "improvement": results["aggregate"]["improvement"],
            "cells": [[c["task"], c["policy"], c["run"], c["scene_seed"], round(float(c["score"]), 6)]
                      for c in cells]}


def _ordered(s: dict) -> list[str]:
    """The policies by tier, then by score IQM (best first)."""
    return sorted(s["policies"], key=lambda p: (ORDER.index(s["policies"][p]["tier"]),
                                                -s["policies"][p]["iqm"][0]))


#: The columns of the compact table (the documentation's home page).
COMPACT = ("zone_violation_rate", "separation_violations", "terrain_violations")


def tier_table(s: dict, compact: bool = False) -> str:
    """One row per policy, grouped in tiers: the normalised score's IQM with its interval (1 = the run's best
    planner on each task), the constraint rates and the median decision time (``compact``: the zone, separation
    and terrain rates only)."""
    cols = [c for c in COLUMNS if not compact or c[0] in COMPACT]
    lines = ["| tier | policy | tasks | score IQM [95 % CI] | " + " | ".join(h for _, h, _ in cols)
             + ("" if compact else " | decision per slot (ms)") + " |",
             "|---|---|---|---|" + "---|" * (len(cols) + (not compact))]
    for p in _ordered(s):
        a = s["policies"][p]
        lo, hi = a["iqm"][1], a["iqm"][2]
        t = a["decision_time_ms"]
        lines.append(f"| {a['tier']} | `{p}` | {len(a['tasks'])} | {a['iqm'][0]:.3f} [{lo:.3f}, {hi:.3f}] | "
                     + " | ".join(format(a[k], f) for k, _, f in cols)
                     + ("" if compact else f" | {'-' if t is None else f'{t:.0f}'}") + " |")
    return "\n".join(lines)


def task_table(s: dict) -> str:
    """The mean normalised score per task and policy, with random's and the best planner's mean rewards."""
    pols = _ordered(s)
    lines = ["| task | random, best planner | " + " | ".join(f"`{p}`" for p in pols) + " |",
             "|---|---|" + "---|" * len(pols)]
    for task, (lo, hi) in s["reference"].items():
        row = [s["policies"][p]["per_task"].get(task) for p in pols]
        lines.append(f"| {task} | {lo:.1f}, {hi:.1f} | "
                     + " | ".join("-" if v is None else f"{v:.3f}" for v in row) + " |")
    return "\n".join(lines)


def caption(s: dict) -> str:
    """What made the run: version, env, scenes and the command."""
    m = s["meta"]
    at = f" (commit {m['commit'][:7]})" if m.get("commit") else ""
    return (f"covert_env {m['covert_env']}{at}, `{m['env']}`, suite `{s['suite']}`: {len(m['tasks'])} tasks x "
            f"{m['scenes']} held-out scenes, `{m['command']}`")


def draw_profiles(scores: dict[str, np.ndarray], tiers: dict[str, str], title: str, path) -> None:
    """Performance profiles to ``path``: per policy (in ``scores``' order), the share of its (task, run, scene)
    normalised scores above tau, styled by its tier."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    every = np.concatenate(list(scores.values()))
    taus = np.linspace(min(-0.25, np.floor(4 * every.min()) / 4), max(1.25, np.ceil(4 * every.max()) / 4), 301)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    styles = {"planner": "-", "hybrid": "--", "learned": "-.", "reference": ":"}
    for p, mine in scores.items():
        ax.plot(taus, (np.asarray(mine)[:, None] > taus).mean(axis=0), styles[tiers[p]], label=f"{p} ({tiers[p]})")
    ax.set_xlabel("normalised score tau (0 = random@waypoint, 1 = the run's best planner)")
    ax.set_ylabel("share of (task, run, scene) scores > tau")
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def profile_figure(s: dict, path) -> None:
    """The published run's performance profiles (:func:`draw_profiles`) to ``path``, titled with what made it."""
    m = s["meta"]
    scores = {p: np.array([c[4] for c in s["cells"] if c[1] == p]) for p in _ordered(s)}
    draw_profiles(scores, {p: s["policies"][p]["tier"] for p in scores},
                  f"Performance profiles, {s['suite']} ({len(m['tasks'])} tasks), covert_env {m['covert_env']}, "
                  f"{m['env']}", path)


def readme_block(s: dict) -> str:
    """The README's generated block: the tier table and what made it."""
    return "\n".join([README_MARKERS[0], "", tier_table(s), "", f"*{caption(s)}.*", "", README_MARKERS[1]])


def _replace_block(text: str, block: str) -> str:
    start, end = README_MARKERS
    if text.count(start) != 1 or text.count(end) != 1:
        raise ValueError(f"the README must hold the markers {start!r} and {end!r} once each")
    head, rest = text.split(start)
    return head + block + rest.split(end, 1)[1]


def publish(run: Path, root: Path = ROOT, version: str | None = None, env_id: str | None = None,
            commit: str | None = None) -> Path:
    """Make a ``covert-env benchmark`` run the published one: its ``summary.json`` to ``docs/results/suite.json``,
    the profiles figure to ``docs/suite_profile.png``, the README's table. A run from before ``summary.json`` was
    written is summarised from its ``results.json``, with the ``version`` and ``env_id`` it was run on."""
    src = run / "summary.json"
    if src.is_file():
        s = json.loads(src.read_text())
    elif (run / "results.json").is_file():
        try:
            s = summary(json.loads((run / "results.json").read_text()), version, env_id, commit)
        except ValueError:
            raise UsageError(f"{run}: its results.json names no covert_env version or env id; pass "
                             "--covert-env-version and --env-id (what the run was measured on)") from None
    else:
        raise UsageError(f"{run}: no summary.json or results.json; run covert-env benchmark --out {run} first")
    dest = root / "docs" / "results" / "suite.json"
    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_text(json.dumps(s, indent=1) + "\n")
    profile_figure(s, root / "docs" / "suite_profile.png")
    readme = root / "README.md"
    readme.write_text(_replace_block(readme.read_text(encoding="utf-8"), readme_block(s)), encoding="utf-8")
    return dest


def check(root: Path = ROOT) -> list[str]:
    """What differs between the README's block and the published run (empty: nothing)."""
    s = json.loads((root / "docs" / "results" / "suite.json").read_text())
    text = (root / "README.md").read_text(encoding="utf-8")
    if _replace_block(text, readme_block(s)) == text:
        return []
    return ["README.md: the leaderboard block is not the published run's; python -m covert_env.evaluation.leaderboard "
            "RUN publishes one"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m covert_env.evaluation.leaderboard",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("run", nargs="?", type=Path, help="a covert-env benchmark output folder to publish")
    parser.add_argument("--check", action="store_true", help="only check that the README shows the published run")
    parser.add_argument("--covert-env-version", help="for a run without summary.json: the version it ran on")
    parser.add_argument("--env-id", help="for a run without summary.json: the env id it ran on (covert_sensing_vN)")
    parser.add_argument("--commit", help="for a run without summary.json: the commit it ran at")
    args = parser.parse_args(argv)

    def go() -> int:
        if args.check:
            problems = check()
            print("\n".join(problems) or "README.md shows the published run")
            return 1 if problems else 0
        if args.run is None:
            raise UsageError("give a run folder to publish, or --check")
        print(f"published {publish(args.run, version=args.covert_env_version, env_id=args.env_id, commit=args.commit)}")
        return 0

    return run_main(parser, go)


if __name__ == "__main__":
    sys.exit(main())
