"""Learn the planner's cost for LoS lost along the path, with the cross-entropy method (CEM), across the suite.

    python -m training.dp_cost --seed 0                 # the 8 three-UAV core tasks (time: docs/training.md)
    python -m training.dp_cost --seed 0 --shadow-aware false   # the kinematic mask's nodes: shadows left to the cost
    python -m training.dp_cost --plot runs/a,runs/b --plot-out outputs/dp_cost_curves.png
    covert-env evaluate --task downtown-3uav --policies dp runs/<run>   # as mappo:runs/<run> or pretrained:dp-cost

The paper's planner keeps LoS at slot times; between them it is blind, and the env's reward charges the share of the
flown path without LoS (``reward_los_path``). This script learns how much the planner's search should charge for
that share (:class:`~baselines.dp.DPPlanner`'s ``path_cost``): per stage j of the horizon,
``path_cost[j] = 100 scale decay^j`` m (:func:`~baselines.learned_cost.path_cost_of`; 100 m is what the
reward charges for a slot fully blocked). Two numbers, learned from episode returns on the training scenes:

* every iteration draws ``scenes_per_task`` training scenes per task (``task.train_seeds``, below ``scene_pool``), and
  every candidate of the iteration flies the same scenes from the same starts (common random numbers), with the
  env's default reward;
* candidates are drawn from a Gaussian over ``(scale, decay)`` (clipped to [0, ``max_scale``] x [0, 1]); the
  ``elite`` best by mean episode return (per UAV, over tasks x scenes) give the next mean and standard deviation
  (plus ``extra_std``, shrinking over the iterations, so the search does not collapse early);
* the paper's planner (``path_cost`` = 0) flies the same scenes every iteration: ``gain`` in the curve is the
  return over it, on the same episodes;
* the result is the last mean.

Writes ``runs/{run_name}/``: ``model.npz`` (``path_cost``) and ``model.json`` (the card, ``kind`` = ``dp-cost``),
``curve.jsonl`` (one line per iteration), ``args.json``. :mod:`training.pretrained.export`-style shipping:
copy both files to ``training/pretrained/NAME.{npz,json}``.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from baselines.learned_cost import KIND, path_cost_of
from covert_env.command_line import ordered_results
from covert_env.world.tasks import get_task
from training.common import parse_args, save_run
from training.run_args import RunArgs

__all__ = ["Args", "episode_return", "main"]

#: The suite's 3-UAV core tasks (the ``3uav-suite`` MAPPO recipe trains on the same).
SUITE_3UAV = ("sparse-3uav,paper-3uav,winding-3uav,dense-3uav,downtown-3uav,towers-3uav,paper-3uav-deviating,"
              "downtown-3uav-deviating")


@dataclass
class Args(RunArgs):
    seed: int = 0
    """seed of the scenes drawn and of the candidates"""
    run_name: str = ""
    """run folder name (default {tasks}__dp_cost__{seed}__{time})"""
    tasks: str = SUITE_3UAV
    """comma-separated suite tasks to learn on (their training scenes)"""
    iterations: int = 4
    """CEM iterations"""
    population: int = 6
    """candidates per iteration (the first is the current mean)"""
    elite: int = 2
    """best candidates that make the next distribution"""
    scenes_per_task: int = 1
    """training scenes per task and iteration (every candidate flies the same ones)"""
    scene_pool: int = 10_000
    """scenes are drawn from the task's first scene_pool training seeds"""
    init_scale: float = 1.0
    """initial mean of scale (path_cost[0] = 100 scale m)"""
    init_decay: float = 0.5
    """initial mean of decay (path_cost[j] = 100 scale decay^j m)"""
    init_std_scale: float = 1.0
    """initial standard deviation of scale"""
    init_std_decay: float = 0.3
    """initial standard deviation of decay"""
    extra_std: float = 0.1
    """standard deviation added to both after each iteration, times (1 - iteration / iterations)"""
    max_scale: float = 10.0
    """largest scale drawn (path_cost[0] <= 100 max_scale m)"""
    heading: str = "inherited"
    """the planner's heading mode: inherited (the paper) or binned (slower: docs/performance.md)"""
    separated_continuation: bool = True
    """the candidates' team looks one slot past plans of depth 1 (baselines.dp.continuation); the paper's planner
    they are compared with does not"""
    best_effort_escape: bool = True
    """the candidates' safety layer may fly a best effort where no pair of manoeuvres keeps two UAVs apart
    (baselines.dp.safety); the paper's planner they are compared with does not"""
    shadow_aware: bool = True
    """the candidates plan over the visible zone (eq. 10, the paper's nodes); false: over the kinematic mask's nodes
    (every zone node clear of the tops, shadowed or not), so the learned cost is all that keeps them out of the
    shadows, and they fly in envs with ``mask_mode="kinematic"``. The paper's planner they are compared with stays
    shadow-aware"""
    jobs: int = 2
    """worker processes for the episodes"""
    plot: str = ""
    """instead of learning: comma-separated run folders whose curves (return over the paper's planner, blocked path
    share, per iteration) are drawn into plot_out"""
    plot_out: str = "outputs/dp_cost_curves.png"
    """the figure of --plot"""


RANGES = {"iterations": (1, 100), "population": (2, 100), "elite": (1, 100), "scenes_per_task": (1, 100),
          "scene_pool": (1, 1_000_000), "jobs": (1, 64)}


def episode_return(task: str, scene_seed: int, path_cost: list[float] | None, heading: str,
                   separated_continuation: bool = False, best_effort_escape: bool = False,
                   shadow_aware: bool = True) -> dict:
    """One episode of the planner (``path_cost`` None: the paper's, shadow-aware, without the look-ahead or the
    escape) on a task's scene: mean return per UAV and the blocked path share (a worker's unit of work)."""
    from baselines.policies import DPPolicy, run_episode
    from covert_env.envs.covert_sensing import CovertSensingParallelEnv

    t = get_task(task)
    learned = path_cost is not None
    aware = shadow_aware or not learned                 # the reference is the paper's planner
    # The mask mode changes only the action mask and the infeasible flags, not the dynamics or the reward.
    env = CovertSensingParallelEnv(task=task, n_uavs=t.n_uavs, action_mode="waypoint",
                                   mask_mode="visible" if aware else "kinematic")
    pol = DPPolicy(heading=heading, path_cost=path_cost, shadow_aware=aware,
                   separated_continuation=separated_continuation and learned,
                   best_effort_escape=best_effort_escape and learned)
    res = run_episode(pol, env, seed=scene_seed, options={"scene_seed": scene_seed})
    env.close()
    return {"return": float(np.mean(list(res["return"].values()))),
            "blocked_path_share": float(np.mean([m["blocked_path_share"] for m in res["metrics"]]))}


def training_budget(training: dict, tasks: list[str]) -> dict:
    """The episodes and env steps (team slots) a run of these ``training`` settings (the card's block) flies: every
    iteration, the population and the paper's planner on ``scenes_per_task`` scenes of every task."""
    episodes = training["iterations"] * (training["population"] + 1) * len(tasks) * training["scenes_per_task"]
    n_slots = get_task(tasks[0]).config().n_slots
    return {"episodes": episodes, "env_steps": episodes * n_slots}


def _check(args: Args) -> None:
    for name, (lo, hi) in RANGES.items():
        v = getattr(args, name)
        if not lo <= v <= hi:
            raise SystemExit(f"--{name.replace('_', '-')} must be in [{lo}, {hi}], got {v}")
    if args.elite > args.population:
        raise SystemExit(f"--elite {args.elite} must be at most --population {args.population}")
    if args.heading not in ("inherited", "binned"):
        raise SystemExit(f"--heading must be inherited or binned, got {args.heading!r}")
    for name in ("init_scale", "init_std_scale", "init_std_decay", "extra_std"):
        v = getattr(args, name)
        if not (np.isfinite(v) and 0 <= v <= 100):
            raise SystemExit(f"--{name.replace('_', '-')} must be in [0, 100], got {v}")
    if not 0 <= args.init_decay <= 1:
        raise SystemExit(f"--init-decay must be in [0, 1], got {args.init_decay}")
    if not (np.isfinite(args.max_scale) and 0 < args.max_scale <= 1e4):
        raise SystemExit(f"--max-scale must be in (0, 10000], got {args.max_scale}")
    try:
        tasks = [get_task(t) for t in args.tasks.split(",")]
    except ValueError as exc:
        raise SystemExit(f"--tasks: {exc}") from None
    if len({t.n_uavs for t in tasks}) != 1:
        raise SystemExit("--tasks must share one team size")


def _commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, timeout=10,
                             cwd=Path(__file__).resolve().parent)
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def plot_curves(runs: list[Path], out: Path) -> Path:
    """Per iteration and run: the mean return over the paper's planner on the iteration's episodes (the current
    mean's and the best candidate's) and the blocked path share of both planners."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401  (matplotlib.ticker.MaxNLocator below)

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.6))
    for i, run in enumerate(runs):
        rows = [json.loads(x) for x in (Path(run) / "curve.jsonl").read_text().splitlines() if x.strip()]
        if not rows:
            raise ValueError(f"{run}/curve.jsonl: no iterations")
        it = [r["iteration"] for r in rows]
        col = f"C{i}"
        a1.plot(it, [r["gain_of_mean"] for r in rows], "o-", color=col, label=f"{Path(run).name}: the mean")
        a1.plot(it, [max(r["returns"]) - r["paper_return"] for r in rows], "x:", color=col, label="best candidate")
        a2.plot(it, [r["mean_path_share"] for r in rows], "o-", color=col, label=f"{Path(run).name}: the mean")
        a2.plot(it, [r["paper_path_share"] for r in rows], "s--", color=col, alpha=0.6, label="paper's planner")
    a1.axhline(0.0, color="k", lw=0.8)
    a1.set_ylabel("return over the paper's planner\n(per UAV, same episodes)")
    a2.set_ylabel("blocked share of the path")
    for ax in (a1, a2):
        ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
        ax.set_xlabel("CEM iteration")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def main(argv: list[str] | None = None) -> Path:
    args = parse_args(Args, argv, description=__doc__.split("\n\n")[0])
    if args.plot:
        runs = [Path(r) for r in args.plot.split(",")]
        missing = [str(r) for r in runs if not (r / "curve.jsonl").is_file()]
        if missing:
            raise SystemExit(f"--plot: no curve.jsonl in {', '.join(missing)}")
        try:
            out = plot_curves(runs, Path(args.plot_out))
        except (ValueError, OSError) as exc:
            raise SystemExit(f"--plot: {exc}") from None
        print(f"wrote {out}")
        return out
    _check(args)
    tasks = args.tasks.split(",")
    horizon = get_task(tasks[0]).config().horizon
    rng = np.random.default_rng(args.seed)
    env = "suite3" if args.tasks == SUITE_3UAV else "tasks"
    name = args.run_name or f"{env}__dp_cost__{args.seed}__{int(time.time())}"
    run_dir = Path(args.runs_dir) / name
    save_run(run_dir, args)
    lo, hi = np.array([0.0, 0.0]), np.array([args.max_scale, 1.0])
    mean = np.array([args.init_scale, args.init_decay])
    std = np.array([args.init_std_scale, args.init_std_decay])
    bar = None
    if args.progress_bar:
        from tqdm.auto import tqdm

        total = args.iterations * (args.population + 1) * len(tasks) * args.scenes_per_task
        bar = tqdm(total=total, desc="dp_cost episodes", file=sys.stderr, mininterval=1.0 if sys.stderr.isatty()
                   else 30.0)
    t_start = time.perf_counter()
    commit = _commit()                  # the code that learns, read before it runs
    curve = open(run_dir / "curve.jsonl", "w")
    for it in range(args.iterations):
        cands = np.clip(mean + std * rng.standard_normal((args.population, 2)), lo, hi)
        cands[0] = mean
        scenes = [(t, int(s)) for t in tasks for s in rng.choice(min(args.scene_pool, len(get_task(t).train_seeds)),
                                                                 args.scenes_per_task, replace=False)]
        costs = [None] + [path_cost_of(a, g, horizon).tolist() for a, g in cands]
        work = [(t, s, c, args.heading, args.separated_continuation, args.best_effort_escape, args.shadow_aware)
                for c in costs for (t, s) in scenes]
        res = ordered_results(episode_return, work, jobs=args.jobs, on_result=bar.update if bar else None)
        ret = np.array([r["return"] for r in res]).reshape(len(costs), len(scenes))
        share = np.array([r["blocked_path_share"] for r in res]).reshape(len(costs), len(scenes))
        score = ret[1:].mean(axis=1)
        elite = cands[np.argsort(-score)[:args.elite]]
        line = {"iteration": it, "wall_s": round(time.perf_counter() - t_start, 1), "mean": mean.tolist(),
                "std": std.tolist(), "candidates": cands.tolist(), "returns": score.tolist(),
                "paper_return": float(ret[0].mean()), "gain_of_mean": float(ret[1].mean() - ret[0].mean()),
                "paper_path_share": float(share[0].mean()), "mean_path_share": float(share[1].mean()),
                "scenes": scenes}
        curve.write(json.dumps(line) + "\n")
        curve.flush()
        mean = elite.mean(axis=0)
        std = elite.std(axis=0) + args.extra_std * (1 - (it + 1) / args.iterations)
    curve.close()
    if bar is not None:
        bar.close()
    w = path_cost_of(mean[0], mean[1], horizon)
    np.savez(run_dir / "model.npz", path_cost=w)
    planner = {"heading": args.heading, "separated_continuation": args.separated_continuation,
               "best_effort_escape": args.best_effort_escape, "shadow_aware": args.shadow_aware}
    card = {"kind": KIND, "planner": planner, "params": {"scale": float(mean[0]), "decay": float(mean[1])},
            "path_cost": w.tolist(), "algorithm": "CEM", "tasks": tasks, "seed": args.seed,
            "training": {"iterations": args.iterations, "population": args.population, "elite": args.elite,
                         "scenes_per_task": args.scenes_per_task,
                         "wall_time_minutes": round((time.perf_counter() - t_start) / 60, 1), "jobs": args.jobs},
            "commit": commit, "env_kwargs": {"action_mode": "waypoint",
                                             "mask_mode": "visible" if args.shadow_aware else "kinematic"}}
    card["training"].update(training_budget(card["training"], tasks))
    (run_dir / "model.json").write_text(json.dumps(card, indent=2) + "\n")
    print(f"path_cost {np.round(w, 1).tolist()} (scale {mean[0]:.3f}, decay {mean[1]:.3f}) -> {run_dir}")
    return run_dir


if __name__ == "__main__":
    main()
