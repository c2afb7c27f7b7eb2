"""The suite protocol: every (task, policy, run, scene) cell, per-task leaderboards, one aggregate with intervals.

    covert-env benchmark                                         # the core tasks, the planners and random
    covert-env benchmark --tasks paper-3uav downtown-3uav --policies dp dp-path random@waypoint --scenes 3
    covert-env benchmark --tasks core --policies dp random@waypoint pretrained:mappo --out outputs/suite

Tasks are names of :mod:`covert_env.world.tasks` (``core``: :data:`~covert_env.world.tasks.DEFAULT_TASKS`, ``all``:
every task); policies are the harness's specs (:mod:`covert_env.evaluation.evaluate`: ``dp``, ``dp-path``, ``dp-blind``,
``dp-binned``, ``random``, ``hold-centre``, ``pretrained:NAME``, ``mappo:``/``sb3:``/``rllib:`` paths, seed groups
``PREFIX:PATH1,PATH2`` whose members are the runs). A learned policy acts for one team size: it is scored on the
tasks of that size only (said in the output). Each cell flies one held-out scene of the task (its first
``--scenes`` test scenes, from their own seeded starts) under the env's default reward, scored by
:func:`covert_env.world.metrics.episode_metrics`.

The protocol, fixed so that two users' runs compare (defaults: :data:`DEFAULT_POLICIES`, ``--scenes``
:data:`DEFAULT_SCENES`):

* **Normalised score** per task: ``(reward - random) / (best planner - random)``, where ``random`` is the mean
  episode reward of masked-random waypoints (``random@waypoint``, always run) and ``best planner`` the highest
  mean of the ``dp*`` policies of the run (at least one is required) on that task. So 0 is random, 1 the best
  planner.
* **Aggregate** per policy over the tasks it was scored on: the IQM of the normalised scores with its 95 %
  stratified-bootstrap interval (strata = tasks, resampled = runs x scenes, :mod:`covert_env.evaluation.stats`), the
  mean, and the constraint rates beside it (zone violations, blocked LoS at slot times and along the flown path,
  separation and terrain violations per UAV, the smallest separation).
* **Performance profile** (``performance_profile.png``): the share of a policy's (task, run, scene) scores above
  tau, for tau from -0.25 (or the lowest score) to 1.25 (or the highest). **Probability of improvement**
  (``improvement.png``): P(X > Y) over the tasks both were scored on (Mann-Whitney per task, averaged).
* Raw results: ``cells.csv`` (one row per cell), ``results.json``, ``summary.json`` (what the README and the
  documentation show, :mod:`covert_env.evaluation.leaderboard`) and ``marl_eval.json`` (marl-eval's raw-data
  layout: environment, task, algorithm, ``run_i``, one evaluation step with per-scene lists and
  ``absolute_metrics``). Per-task leaderboards: ``tasks/<task>/leaderboard.md`` (the harness's tables).

Cells run in a local process pool (``--jobs``, default every CPU), or on a Ray cluster with ``--ray-address``
(``local`` starts one here; Ray is the ``rllib`` extra); each cell's result depends on its cell alone, so any number
of workers, and Ray, give the same rows (tested).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

import covert_env
from covert_env.command_line import (
    MAX_SCENES,
    UsageError,
    int_range,
    ordered_results,
    output_dir,
    positive_int,
    run_main,
)
from covert_env.envs.covert_sensing import CovertSensingParallelEnv
from covert_env.evaluation import leaderboard
from covert_env.evaluation.evaluate import COLUMNS, evaluate, load_policy, split_seeds, summarise, write_outputs
from covert_env.evaluation.provenance import code_commit
from covert_env.evaluation.registry import from_files
from covert_env.evaluation.stats import iqm, mean, probability_of_improvement, stratified_bootstrap_ci
from covert_env.evaluation.tiers import TIERS, spec_tier
from covert_env.world.tasks import DEFAULT_TASKS, SUITE_VERSION, TASKS, TEST_SCENES, get_task, resolve_tasks

__all__ = ["DEFAULT_POLICIES", "DEFAULT_SCENES", "REFERENCE", "aggregate", "main", "normalised_scores", "run_cells"]

DEFAULT_POLICIES = ("dp", "dp-path", "dp-blind", "dp-binned", "random@waypoint")
"""The policies ``covert-env benchmark`` runs by default: the planner variants and the random reference."""
DEFAULT_SCENES = 5
"""Test scenes per task by default (the first of the task's held-out scenes)."""
REFERENCE = "random@waypoint"
"""The policy whose mean reward is a task's score 0 (masked-random waypoints)."""
#: The constraint rates reported beside every score (keys of covert_env.world.metrics.episode_metrics).
CONSTRAINTS = (("zone_violation_rate", "zone viol."), ("occlusion_rate", "blocked LoS, slots"),
               ("occlusion_rate_path", "blocked LoS, path"), ("blocked_path_share", "path share blocked"),
               ("separation_violations", "sep. viol./UAV"),
               ("terrain_violations", "terrain viol./UAV"), ("min_separation", "min sep. (m)"))


# ---------------------------------------------------------------------- cells
def _run_cell(task: str, spec: str, run: int, scenes: int, trust: bool) -> list[dict]:
    """One (task, policy, run) group: its first ``scenes`` test scenes, one row each (a worker's unit of work)."""
    t = get_task(task)
    member = split_seeds(spec)[run]
    pol, settings = load_policy(member, t.n_uavs, trust_checkpoint=trust)
    rows = evaluate(pol, settings, scenes, t.test_seeds.start, env_kwargs={"task": task}, progress=False)
    mask = settings.get("mask_mode", "visible") if settings["action_mode"] == "waypoint" else "none"
    return [{"task": task, "policy": spec, "run": run, "action_mode": settings["action_mode"], "mask_mode": mask,
             "target_path": int(settings.get("target_path", 0)), **row} for row in rows]


def run_cells(cells: list[tuple[str, str, int]], scenes: int, *, jobs: int = 1, trust: bool = False,
              progress: bool = True, ray_address: str | None = None) -> list[dict]:
    """Rows of every (task, spec, run) cell group, in the order of ``cells`` whatever runs them: this process
    (``jobs`` = 1), a local pool of ``jobs`` processes, or a Ray cluster at ``ray_address`` (``"local"`` starts one
    on this machine; Ray is the ``rllib`` extra)."""
    args = [(task, spec, run, scenes, trust) for task, spec, run in cells]
    bar = _bar(len(args), progress)
    out: list[list[dict]] = []
    if ray_address is not None:
        import ray

        ray.init(address=ray_address, include_dashboard=False, log_to_driver=False, ignore_reinit_error=True)
        remote = ray.remote(_run_cell)
        refs = [remote.remote(*a) for a in args]
        for ref in refs:
            out.append(ray.get(ref))
            bar.update()
    else:
        out = ordered_results(_run_cell, args, jobs, bar.update)
    bar.close()
    return [row for group in out for row in group]


def _bar(total: int, progress: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, desc="cells (task x policy x run)", disable=not progress, file=sys.stderr,
                mininterval=1.0 if sys.stderr.isatty() else 30.0)


# ---------------------------------------------------------------------- scores
def normalised_scores(rows: list[dict]) -> tuple[list[dict], dict]:
    """The rows with their normalised score (a new ``score`` key) and, per task, the (random, best planner) mean
    rewards it uses."""
    ref: dict[str, tuple[float, float]] = {}
    by_task: dict[str, dict[str, list[float]]] = {}
    for r in rows:
        by_task.setdefault(r["task"], {}).setdefault(r["policy"], []).append(r["reward"])
    for task, pols in by_task.items():
        lo = float(np.mean(pols[REFERENCE]))
        planners = {p: float(np.mean(v)) for p, v in pols.items() if p.split("@")[0].startswith("dp")}
        hi = max(planners.values())
        if not hi > lo:
            raise ValueError(f"task {task}: the best planner's mean reward ({hi:g}) is not above random's ({lo:g})")
        ref[task] = (lo, hi)
    scored = [{**r, "score": (r["reward"] - ref[r["task"]][0]) / (ref[r["task"]][1] - ref[r["task"]][0])}
              for r in rows]
    return scored, ref


def _matrix(rows: list[dict], policy: str, key: str = "score") -> tuple[np.ndarray, list[str]]:
    """(runs x scenes, tasks) values of ``policy``, one column per task it was scored on (rliable's layout)."""
    tasks = list(dict.fromkeys(r["task"] for r in rows if r["policy"] == policy))
    cols = [[r[key] for r in rows if r["policy"] == policy and r["task"] == t] for t in tasks]
    return np.array(cols, float).T, tasks


def _constraint(key: str, values: list[float]) -> float:
    """A policy's constraint figure over its cells: the mean rate, or for ``min_separation`` the smallest finite one
    (a one-UAV task has no teammate: inf), NaN if there is none."""
    v = np.asarray(values, float)
    if key == "min_separation":
        v = v[np.isfinite(v)]
        return float(v.min()) if len(v) else math.nan
    return float(np.nanmean(v))


def aggregate(rows: list[dict], policies: list[str]) -> dict:
    """Per policy: IQM and mean of the normalised score with their 95 % stratified-bootstrap intervals, the tasks it
    was scored on, and the constraint rates (means over its cells); and P(X > Y) for every pair on shared tasks."""
    out: dict = {"policies": {}, "improvement": {}}
    for p in policies:
        m, tasks = _matrix(rows, p)
        mine = [r for r in rows if r["policy"] == p]
        out["policies"][p] = {
            "tasks": tasks, "cells": len(mine),
            "iqm": stratified_bootstrap_ci(m, iqm, reps=2000), "mean": stratified_bootstrap_ci(m, mean, reps=2000),
            **{k: _constraint(k, [r[k] for r in mine]) for k, _ in CONSTRAINTS}}
    for p in policies:
        for q in policies:
            shared = [t for t in out["policies"][p]["tasks"] if t in out["policies"][q]["tasks"]]
            if p == q or not shared:
                continue
            a = np.array([[r["score"] for r in rows if r["policy"] == p and r["task"] == t] for t in shared]).T
            b = np.array([[r["score"] for r in rows if r["policy"] == q and r["task"] == t] for t in shared]).T
            out["improvement"][f"{p} > {q}"] = probability_of_improvement(a, b)
    return out


# ---------------------------------------------------------------------- outputs
def marl_eval(rows: list[dict]) -> dict:
    """The rows in marl-eval's raw-data layout: ``{env: {task: {algorithm: {run_i: {step_0: {...},
    absolute_metrics: {...}}}}}}``, each metric a list over the scenes."""
    keys = ["score", *(k for k, _, _ in COLUMNS)]
    data: dict = {}
    for r in rows:
        run = data.setdefault("covert_env", {}).setdefault(r["task"], {}).setdefault(r["policy"], {}) \
            .setdefault(f"run_{r['run']}", {"step_0": {"step_count": 0}, "absolute_metrics": {}})
        for k in keys:
            v = float(r[k])
            run["step_0"].setdefault(k, []).append(v)
            run["absolute_metrics"].setdefault(k, []).append(v)
    return data


def _fmt(ci: tuple[float, float, float]) -> str:
    return f"{ci[0]:.3f} [{ci[1]:.3f}, {ci[2]:.3f}]"


def write_suite(out: Path, rows: list[dict], ref: dict, agg: dict, meta: dict, skipped: dict) -> None:
    """``suite.md``, ``cells.csv``, ``results.json``, ``marl_eval.json``, the two figures, and the per-task
    leaderboards under ``tasks/``."""
    pols = list(agg["policies"])
    lines = [f"# Suite {SUITE_VERSION}: {len(ref)} tasks x {meta['scenes']} held-out scenes", "",
             "Normalised score per task: (reward - random@waypoint's mean) / (best dp* planner's mean - random's "
             "mean), so 0 is masked-random waypoints and 1 the best planner of this run on that task. IQM and mean "
             "over tasks x runs x scenes with 95 % stratified-bootstrap intervals (strata: tasks). Constraint rates "
             "are means over the policy's cells (per UAV); min sep. is the smallest over its cells with a "
             "teammate. Action mask: the env's waypoint mask a policy acted with ('visible': reachable nodes of the "
             "visible zone; 'kinematic': reachable nodes only; the planners choose among their own nodes, the visible "
             "zone's or, shadow-blind, every zone node, and ignore the mask).", "",
             "Tiers, by what a team reads to act: " + "; ".join(TIERS.values()) + ". A spec ending in +shield "
             "flew through the safety filter (covert_env.envs.safety_filter).", "",
             "| tier | policy | action mask | tasks | score IQM [95 % CI] | score mean [95 % CI] | "
             + " | ".join(h for _, h in CONSTRAINTS) + " |",
             "|---|---|---|---|---|---|" + "---|" * len(CONSTRAINTS)]
    tiers = {p: spec_tier(p) for p in pols}
    for p in sorted(pols, key=lambda q: list(TIERS).index(tiers[q])):        # stable: the run's order per tier
        a = agg["policies"][p]
        masks = ", ".join(sorted({r.get("mask_mode", "visible") for r in rows if r["policy"] == p}))
        lines.append(f"| {tiers[p]} | {p} | {masks} | {len(a['tasks'])} | {_fmt(a['iqm'])} | {_fmt(a['mean'])} | "
                     + " | ".join(f"{a[k]:.3f}" if k != "min_separation" else f"{a[k]:.1f}" for k, _ in CONSTRAINTS)
                     + " |")
    lines += ["", "Mean normalised score per task (random's and the best planner's mean rewards in brackets):", "",
              "| task | random, best | " + " | ".join(pols) + " |", "|---|---|" + "---|" * len(pols)]
    for task, (lo, hi) in ref.items():
        cells = []
        for p in pols:
            v = [r["score"] for r in rows if r["task"] == task and r["policy"] == p]
            cells.append(f"{np.mean(v):.3f}" if v else "-")
        lines.append(f"| {task} | {lo:.1f}, {hi:.1f} | " + " | ".join(cells) + " |")
    if agg["improvement"]:
        lines += ["", "Probability of improvement P(row > column) on the tasks both were scored on:", "",
                  "| | " + " | ".join(pols) + " |", "|---|" + "---|" * len(pols)]
        for p in pols:
            poi = [agg["improvement"].get(f"{p} > {q}", math.nan) for q in pols]
            lines.append(f"| {p} | " + " | ".join("-" if p == q else f"{v:.2f}" for q, v in zip(pols, poi, strict=True))
                         + " |")
    for p, tasks in skipped.items():
        lines.append(f"\n{p} acts for another team size: not scored on {', '.join(tasks)}.")
    lines += ["", f"Wall time: {meta['seconds']:.0f} s ({meta['jobs']} worker(s)).",
              f"Command: `{meta['command']}`", ""]
    (out / "suite.md").write_text("\n".join(lines))
    keys = ["task", "policy", "run", "action_mode", "mask_mode", "target_path", "scene_seed", "score",
            *(k for k, _, _ in COLUMNS)]
    with open(out / "cells.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(keys)
        for r in rows:
            w.writerow([r.get(k, 0) if k == "target_path" else r[k] for k in keys])   # rows of older runs: 0
    (out / "results.json").write_text(json.dumps({"suite": SUITE_VERSION, "meta": meta, "reference": ref,
                                                  "aggregate": agg, "cells": rows}, indent=1))
    (out / "marl_eval.json").write_text(json.dumps(marl_eval(rows)))
    results = {"suite": SUITE_VERSION, "meta": meta, "reference": ref, "aggregate": agg, "cells": rows}
    if "covert_env" in meta:                                   # what the docs are made from (leaderboard.py)
        (out / "summary.json").write_text(json.dumps(leaderboard.summary(results), indent=1))
    _figures(out, rows, agg)
    for task in ref:
        _task_leaderboard(out / "tasks" / task, get_task(task), [r for r in rows if r["task"] == task], meta)


def _task_leaderboard(folder: Path, task, rows: list[dict], meta: dict) -> None:
    """The harness's leaderboard files (:func:`covert_env.evaluation.evaluate.write_outputs`) of one task."""
    results = {}
    for p in dict.fromkeys(r["policy"] for r in rows):
        mine = [r for r in rows if r["policy"] == p]
        results[p] = {"rows": mine, "summary": summarise(mine), "spec": p, "runs": 1 + max(r["run"] for r in mine),
                      "settings": {"action_mode": mine[0]["action_mode"], "mask_mode": mine[0].get("mask_mode"),
                                   "target_path": mine[0].get("target_path", 0), "n_uavs": task.n_uavs}}
    write_outputs(results, folder, {"episodes": meta["scenes"], "seed_offset": task.test_seeds.start,
                                    "n_uavs": task.n_uavs, "family": task.family, "scene_set": None,
                                    "command": meta["command"]})


def _figures(out: Path, rows: list[dict], agg: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pols = list(agg["policies"])
    leaderboard.draw_profiles({p: np.array([r["score"] for r in rows if r["policy"] == p]) for p in pols},
                              {p: spec_tier(p) for p in pols}, f"Performance profiles ({SUITE_VERSION})",
                              out / "performance_profile.png")
    m = np.full((len(pols), len(pols)), np.nan)
    for i, p in enumerate(pols):
        for j, q in enumerate(pols):
            m[i, j] = agg["improvement"].get(f"{p} > {q}", np.nan)
    fig, ax = plt.subplots(figsize=(1.2 * len(pols) + 3, 1.0 * len(pols) + 2))
    im = ax.imshow(m, vmin=0, vmax=1, cmap="RdBu")
    for (i, j), v in np.ndenumerate(m):
        if np.isfinite(v):
            ax.text(j, i, f"{v:.2f}", ha="center", va="center", fontsize=8)
    ax.set_xticks(range(len(pols)), pols, rotation=30, ha="right", fontsize=8)
    ax.set_yticks(range(len(pols)), pols, fontsize=8)
    ax.set_title("P(row > column), normalised score")
    fig.colorbar(im, ax=ax)
    fig.tight_layout()
    fig.savefig(out / "improvement.png", dpi=110)
    plt.close(fig)


# ---------------------------------------------------------------------- command line
def build_parser(prog: str = "python -m covert_env.evaluation.benchmark") -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n")[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--tasks", nargs="+", default=["core"],
                   help=f"task names of covert_env.world.tasks, or the groups 'core' (the protocol's "
                        f"{len(DEFAULT_TASKS)} tasks) and 'all' ({len(TASKS)})")
    p.add_argument("--policies", nargs="+", default=list(DEFAULT_POLICIES),
                   help=f"policy specs (as covert-env evaluate); at least one dp* planner (a dp*+shield planner "
                        f"counts: the best planner of the run is each task's score 1); {REFERENCE} is always run")
    p.add_argument("--scenes", type=int_range(1, min(TEST_SCENES, MAX_SCENES)), default=DEFAULT_SCENES,
                   help=f"test scenes per task, in [1, {TEST_SCENES}] (the first of each task's held-out scenes)")
    p.add_argument("--jobs", type=positive_int, default=os.cpu_count() or 1, help="worker processes, >= 1")
    p.add_argument("--ray-address", metavar="ADDRESS", default=argparse.SUPPRESS,     # none: a local pool
                   help="run the cells on the Ray cluster at ADDRESS instead of a local pool ('local' starts one on "
                        "this machine; pip install -e \".[rllib]\"); the results are the same")
    p.add_argument("--out", default="outputs/suite", help="output folder (git-ignored outputs/)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--trust-checkpoint", action="store_true",
                   help="allow sb3: and rllib: specs (pickles: only files from a source you trust)")
    return p


def main(argv: list[str] | None = None, prog: str = "python -m covert_env.evaluation.benchmark") -> int:
    """The protocol's command line (``covert-env benchmark``); bad arguments exit with status 2 and one line."""
    parser = build_parser(prog)
    args = parser.parse_args(argv)
    args.ray_address = getattr(args, "ray_address", None)
    argv = list(argv if argv is not None else sys.argv[1:])
    return run_main(parser, lambda: _main(args, f"{prog} " + " ".join(argv)))


def _main(args: argparse.Namespace, command: str) -> int:
    try:
        tasks = resolve_tasks(args.tasks)
    except ValueError as exc:
        raise UsageError(f"--tasks: {exc}") from None
    twice = sorted({p for p in args.policies if args.policies.count(p) > 1})
    if twice:
        raise UsageError(f"--policies: {', '.join(twice)} given twice; give each spec once")
    specs = list(dict.fromkeys([*args.policies, REFERENCE]))
    if not any(s.split("@")[0].startswith("dp") for s in specs):
        raise UsageError("--policies: include at least one dp planner (dp, dp-path, dp-blind, dp-binned): the best "
                         "planner is each task's score 1")
    cells, skipped = [], {}
    for spec in specs:                                  # every spec loads before any cell runs
        for t in tasks:
            try:
                settings = [load_policy(m, t.n_uavs, trust_checkpoint=args.trust_checkpoint)[1]
                            for m in split_seeds(spec)]
            except UsageError as exc:
                if from_files(spec) and "acts for teams of" in str(exc):
                    skipped.setdefault(spec, []).append(t.name)
                    continue
                raise UsageError(f"--policies: {exc}") from None
            cells += [(t.name, spec, run) for run in range(len(settings))]
        if spec in skipped and len(skipped[spec]) == len(tasks):
            raise UsageError(f"--policies: {spec} acts for another team size than every task of --tasks "
                             f"({', '.join(t.name for t in tasks)}); add a task of its team size")
    out = output_dir(args.out, files=("suite.md", "cells.csv", "results.json", "summary.json", "marl_eval.json",
                                      "performance_profile.png", "improvement.png"), folders=("tasks",))
    t0 = time.perf_counter()
    if args.ray_address is not None:
        try:
            import ray  # noqa: F401
        except ModuleNotFoundError:
            raise UsageError("--ray-address needs ray, which is not installed: pip install -e \".[rllib]\"") from None
    rows = run_cells(cells, args.scenes, jobs=args.jobs, trust=args.trust_checkpoint, progress=not args.no_progress,
                     ray_address=args.ray_address)
    scored, ref = normalised_scores(rows)
    agg = aggregate(scored, specs)
    workers = args.jobs if args.ray_address is None else f"Ray at {args.ray_address}"
    meta = {"scenes": args.scenes, "jobs": workers, "seconds": time.perf_counter() - t0, "command": command,
            "tasks": [t.name for t in tasks], "policies": specs, "covert_env": covert_env.__version__,
            "env": CovertSensingParallelEnv.metadata["name"], "commit": code_commit()}
    write_suite(out, scored, ref, agg, meta, skipped)
    for p, a in agg["policies"].items():
        print(f"{p:28s} score IQM {_fmt(a['iqm'])}  zone viol. {a['zone_violation_rate']:.3f}  blocked LoS "
              f"{a['occlusion_rate']:.3f} (path {a['occlusion_rate_path']:.3f})")
    print(f"wrote {out / 'suite.md'} and the figures ({meta['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
