"""The evaluation harness: every policy on the same held-out scenes, scored by the shared metrics code.

    covert-env evaluate --policies random hold-centre dp dp-blind pretrained:mappo --episodes 20
    covert-env evaluate --policies random sb3:runs/<run> --trust-checkpoint
    covert-env evaluate --trust-checkpoint --policies sb3:runs/<run>/checkpoints/ppo_multi_500000_steps.zip
    covert-env evaluate --policies dp rllib:runs/<rllib-run>/checkpoint --trust-checkpoint
    python -m covert_env.evaluation.evaluate ...     # the same

Policy specs (``SPEC[@MODE][+shield]``, :mod:`covert_env.evaluation.specs`; MODE = ``unicycle`` or ``waypoint``
picks the env's action mode; ``+shield`` flies a waypoint policy through the safety filter,
:mod:`covert_env.envs.safety_filter`). Each NAME and PREFIX is an entry point of the group ``covert_env.policies``
(:mod:`covert_env.evaluation.registry`); the learned ones are loaded by :mod:`training.learned_policies`:

* ``dp`` (shadow-aware, the paper's method), ``dp-blind`` (shadow-blind), ``dp-binned``, ``random``,
  ``hold-centre`` (alias ``heuristic``): :mod:`baselines.policies`. DP defaults to waypoint mode, where it acts
  exactly as planned (the env's lattice is its node set); ``random`` and ``hold-centre`` default to unicycle
  mode, the action space of the learned continuous policies (``random@waypoint`` is masked-random waypoints).
* ``sb3:PATH``: an SB3 model (PPO, SAC, MaskablePPO) -- a run folder (its ``model.zip``) or a ``.zip``
  checkpoint; its ``args.json`` gives the env settings and the VecNormalize statistics beside the model
  (``vecnormalize.json``, read without pickle; older ``.pkl`` statistics are refused, see
  :mod:`training.sb3.convert_vecnormalize`) are applied. Single-UAV models act for every UAV independently (each sees
  its own observation), so they need ``--n-uavs 1`` unless they were trained with the same team size.
* ``rllib:PATH``: an RLlib checkpoint of :mod:`training.rllib_ppo`; inference runs in plain torch, no Ray
  cluster is started.
* SB3 ``.zip`` files and RLlib checkpoints hold pickles, which run any code they carry when loaded: ``sb3:`` and
  ``rllib:`` specs are refused unless ``--trust-checkpoint`` is given (``trust_checkpoint=True`` in
  :func:`~covert_env.evaluation.specs.load_policy`), only for files from a source you trust (:mod:`training.trust`).
* ``mappo:PATH``: a MAPPO/IPPO actor of :mod:`training.mappo` -- a run folder (its ``model.npz`` and
  ``model.json``) or ``NAME.npz`` with its card ``NAME.json``; ``pretrained:NAME``: the weights shipped in
  ``training/pretrained/`` (``pretrained:mappo``). Both run in numpy (no torch, no pickle): :mod:`training.pretrained`.
  A card of ``kind`` ``dp-cost`` is the planner with a learned cost (:mod:`baselines.learned_cost`,
  ``pretrained:dp-cost``, ``pretrained:dp-cost-binned``, a :mod:`training.dp_cost` run folder): it plans for any
  team size in waypoint mode.
* **Training seeds as one row**: ``PREFIX:PATH1,PATH2,...`` (``mappo:``, ``sb3:``, ``rllib:``) evaluates each run
  of a recipe (one per training seed) on the same scenes and reports them as one row: the metrics' mean ± std
  over seeds x episodes, and the reward's IQM with its 95 % stratified-bootstrap interval over seeds x scenes
  (seeds resampled within each scene, rliable's method) and P(> DP).

Held-out scenes: episode i flies ``reset(seed=s, options={"scene_seed": s})`` with ``s = seed_offset + i``
(default 1_000_000 + i, outside the training pool ``range(scene_pool)``). Every policy sees the same scenes and
start poses. The env uses its DEFAULT reward settings, whatever a policy was trained with, so "reward" is
comparable across rows (it is the mean over UAVs of the episode return).

Writes ``leaderboard.md``, ``leaderboard.csv`` (mean and std over episodes of the team-mean per-UAV metrics of
:func:`covert_env.world.metrics.episode_metrics`; for ``min_separation`` the team's smallest), ``episodes.csv`` (one row
per policy and episode) and ``comparison.png`` into ``--out`` (default ``outputs/leaderboard``).
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from covert_env.command_line import (
    MAX_SCENES,
    UsageError,
    int_range,
    output_dir,
    positive_int,
    read_run_json,
    run_main,
)
from covert_env.envs.covert_sensing import CovertSensingParallelEnv
from covert_env.envs.vector import MAX_SCENE_SEED
from covert_env.evaluation.episodes import COLUMNS, HELD_OUT_OFFSET, evaluate, summarise
from covert_env.evaluation.registry import from_files, spec_forms
from covert_env.evaluation.specs import SHIELD_SUFFIX, load_policy, split_seeds
from covert_env.evaluation.stats import iqm, probability_of_improvement, stratified_bootstrap_ci
from covert_env.evaluation.tiers import TIERS, spec_tier
from covert_env.world.families import FAMILIES
from covert_env.world.scene_set import SceneSet
from covert_env.world.tasks import get_task

__all__ = ["main", "load_policy", "evaluate", "split_seeds", "COLUMNS", "HELD_OUT_OFFSET"]

def write_outputs(results: dict[str, dict], out: Path, meta: dict) -> None:
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "leaderboard.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["policy", "mode", "uavs", "episodes"] + [x for k, _, _ in COLUMNS for x in (k, k + "_std")])
        for name, r in results.items():
            s = r["summary"]
            w.writerow([name, r["settings"]["action_mode"], r["settings"]["n_uavs"], len(r["rows"])]
                       + [f"{x:.6g}" for k, _, _ in COLUMNS for x in s[k]])
    with open(out / "episodes.csv", "w", newline="") as f:
        keys = ["scene_seed", "reward"]
        for r in results.values():                    # a seed group's rows also carry "run"
            keys += [k for k in r["rows"][0] if k not in keys]
        w = csv.writer(f)
        w.writerow(["policy"] + keys)
        for name, r in results.items():
            for row in r["rows"]:
                w.writerow([name] + [row.get(k, "") for k in keys])
    family = (f", task {meta['task']}" if meta.get("task") else
              f", family {meta['family']}" if meta.get("family") else "")
    where = (f"scenes of scene set {meta['scene_set']}" if meta.get("scene_set") else
             f"held-out scenes (scene seeds {meta['seed_offset']} .. {meta['seed_offset'] + meta['episodes'] - 1}"
             f"{family})")
    lines = [f"# Leaderboard: {meta['episodes']} {where}, {meta['n_uavs']} UAV(s)", "",
             "Tiers, by what a team reads to act: " + "; ".join(TIERS.values()) + ".", "",
             "Mean ± std over episodes of the team-mean per-UAV metrics (covert_env.world.metrics.episode_metrics; "
             "min separation: the team's smallest); "
             "episode reward = env default reward, mean over UAVs. Lower is better except reward, disguise and "
             "min separation.", "",
             "| tier | policy | mode | " + " | ".join(h for _, h, _ in COLUMNS) + " |",
             "|---|---|---|" + "---|" * len(COLUMNS)]
    for name, r in results.items():
        cells = []
        for k, _, fmt in COLUMNS:
            m, s = r["summary"][k]
            cells.append(f"{fmt.format(m)} ± {fmt.format(s)}")
        lines.append(f"| {spec_tier(r.get('spec', name))} | {name} | {r['settings']['action_mode']} | "
                     + " | ".join(cells) + " |")
    lines += _robust_lines(results)
    lines += ["", f"Command: `{meta['command']}`", ""]
    (out / "leaderboard.md").write_text("\n".join(lines))
    _figure(results, out / "comparison.png")


def _reward_matrix(r: dict) -> np.ndarray:
    """Episode rewards ``(runs, scenes)``: one row per training seed of a seed group, else ``(1, scenes)``."""
    rows = r["rows"]
    runs = r.get("runs", 1)
    scenes = sorted({row["scene_seed"] for row in rows})
    m = np.full((runs, len(scenes)), np.nan)
    col = {s: j for j, s in enumerate(scenes)}
    for row in rows:
        m[row.get("run", 0), col[row["scene_seed"]]] = row["reward"]
    return m


def _robust_lines(results: dict[str, dict]) -> list[str]:
    """The episode reward's interquartile mean with its 95 % bootstrap interval, and the probability of
    improvement over the DP planner (rliable's definitions, :mod:`covert_env.evaluation.stats`).

    A seed group's rewards are a (seeds, scenes) matrix: the interval resamples the seeds within each scene
    (stratified by scene) and P(X > DP) is the Mann-Whitney statistic per scene, averaged over scenes. A single
    run has no seeds to resample, so its interval resamples the scenes instead (said in the table)."""
    dp = next((r for r in results.values() if r.get("spec", "").split("@")[0] == "dp"), None)
    lines = ["", "Episode reward: interquartile mean with its 95 % stratified-bootstrap interval (over seeds x scenes "
             "for seed groups, over scenes for single runs)"
             + (", and P(reward > DP shadow-aware's) on the same scenes" if dp else "")
             + " (covert_env.evaluation.stats).", "",
             "| policy | runs | reward IQM [95 % CI] |" + (" P(> DP) |" if dp else ""),
             "|---|---|---|" + ("---|" if dp else "")]
    for name, r in results.items():
        m = _reward_matrix(r)
        if m.shape[0] > 1:
            point, lo, hi = stratified_bootstrap_ci(m, iqm, reps=2000)
        else:
            point, lo, hi = stratified_bootstrap_ci(m.T, iqm, reps=2000)        # the scenes as the runs
        cell = f"| {name} | {m.shape[0]} | {point:.1f} [{lo:.1f}, {hi:.1f}] |"
        if dp is not None:
            ref = _reward_matrix(dp)
            same = sorted({row["scene_seed"] for row in r["rows"]}) == sorted({row["scene_seed"] for row in dp["rows"]})
            cell += f" {probability_of_improvement(m, ref):.2f} |" if same else " - |"
        lines.append(cell)
    return lines


def _figure(results: dict[str, dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = [c for c in COLUMNS if c[0] in ("reward", "occlusion_rate", "occlusion_rate_path", "zone_violation_rate",
                                           "mean_disguise", "path_length")]
    names = list(results)
    fig, axes = plt.subplots(2, 3, figsize=(13, 7))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, (k, header, _) in zip(axes.ravel(), keys, strict=True):
        m = [results[n]["summary"][k][0] for n in names]
        s = [results[n]["summary"][k][1] for n in names]
        ax.bar(range(len(names)), m, yerr=s, capsize=3, color=[colors[i % len(colors)] for i in range(len(names))])
        ax.set_xticks(range(len(names)))
        ax.set_xticklabels([n if len(n) < 22 else n[:20] + "…" for n in names], rotation=30, ha="right", fontsize=8)
        ax.set_title(header)
        ax.grid(axis="y", alpha=0.3)
    fig.suptitle("covert_env: policies on the same held-out scenes (mean ± std over episodes)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def build_parser(prog: str = "python -m covert_env.evaluation.evaluate") -> argparse.ArgumentParser:

    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n")[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--policies", nargs="+", default=["random", "hold-centre", "dp", "dp-blind"],
                   help=f"policy specs: {', '.join(spec_forms())} (covert-env list describes them), each "
                        "optionally @unicycle or @waypoint, and +shield for a waypoint policy")
    p.add_argument("--episodes", type=int_range(1, MAX_SCENES), default=20,
                   help=f"held-out scenes per policy, in [1, {MAX_SCENES}]")
    p.add_argument("--n-uavs", type=positive_int, default=3, help="team size, >= 1")
    p.add_argument("--seed-offset", type=int_range(0, MAX_SCENE_SEED - MAX_SCENES), default=HELD_OUT_OFFSET,
                   help=f"first held-out scene seed, in [0, {MAX_SCENE_SEED - MAX_SCENES}]")
    p.add_argument("--family", choices=list(FAMILIES), default="paper",
                   help="scene family (covert_env.world.families) of the held-out scenes")
    p.add_argument("--task", metavar="NAME", default=argparse.SUPPRESS,                # none: --family
                   help="a task of the suite (covert_env.world.tasks, e.g. downtown-3uav-deviating): its family, team "
                        "and target; not with --family, and --n-uavs must agree")
    p.add_argument("--scene-set", metavar="FILE", default=argparse.SUPPRESS,            # none: held-out seeds
                   help="fly the first --episodes scenes of this scene set file (covert_env.world.scene_set; "
                        "covert-env scene-set writes one) instead of held-out seeds; not with --family or "
                        "--seed-offset")
    p.add_argument("--out", default="outputs/leaderboard", help="output folder (git-ignored outputs/)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument("--trust-checkpoint", action="store_true",
                   help="allow sb3: and rllib: specs: their files hold pickles, which run any code they carry when "
                        "loaded; pass this only for files from a source you trust (mappo:, pretrained: and the "
                        "built-in policies need no trust)")
    p.add_argument("--reuse", action="store_true",
                   help="reuse the per-episode results of built-in policies (dp, random, ...) cached in OUT/cache "
                        "by an earlier run with the same episodes, seed offset and team size (they are deterministic)")
    return p


def main(argv: list[str] | None = None, prog: str = "python -m covert_env.evaluation.evaluate") -> int:
    """The harness's command line (``prog``: the name in usage and error lines, ``covert-env evaluate`` from
    :mod:`covert_env.command_line`). Mistakes in the arguments exit with status 2 and one error line."""

    parser = build_parser(prog)
    args = parser.parse_args(argv)
    args.scene_set = getattr(args, "scene_set", None)
    args.task = getattr(args, "task", None)
    argv = list(argv if argv is not None else sys.argv[1:])
    return run_main(parser, lambda: _main(args, f"{prog} " + " ".join(argv)))


def _scene_set(args: argparse.Namespace) -> SceneSet | None:
    """The ``--scene-set`` file, checked against the other flags (one error line for a bad file or combination)."""
    if args.scene_set is None:
        return None
    if args.family != "paper" or args.seed_offset != HELD_OUT_OFFSET:
        raise UsageError("--scene-set FILE holds its scenes: --family and --seed-offset do not go with it")
    try:
        scenes = SceneSet.load(args.scene_set)
    except (OSError, ValueError) as exc:
        raise UsageError(f"--scene-set: {exc}") from None
    if len(scenes) < args.episodes:
        raise UsageError(f"--scene-set {args.scene_set} has {len(scenes)} scenes, fewer than --episodes "
                         f"{args.episodes}; pass --episodes {len(scenes)}")
    if scenes[0].n_uavs != args.n_uavs:
        raise UsageError(f"--scene-set {args.scene_set} has starts for {scenes[0].n_uavs} UAV(s), --n-uavs is "
                         f"{args.n_uavs}; pass --n-uavs {scenes[0].n_uavs}")
    return scenes


def _task_flags(args: argparse.Namespace) -> dict:
    """The env keywords of ``--task`` or ``--family``; ``--task`` sets ``args.family`` and ``args.n_uavs`` (a
    different ``--family`` or ``--n-uavs`` is a usage error)."""
    if args.task is None:
        return {"family": args.family}
    if args.scene_set is not None:
        raise UsageError("--task flies the task's held-out scenes, --scene-set a file's: pass one")
    try:
        task = get_task(args.task)
    except ValueError as exc:
        raise UsageError(f"--task: {exc}") from None
    if args.family != "paper":
        raise UsageError(f"--task {task.name} sets the family ({task.family}): leave out --family")
    if args.n_uavs not in (3, task.n_uavs):
        raise UsageError(f"--task {task.name} flies {task.n_uavs} UAV(s), --n-uavs is {args.n_uavs}; leave it out")
    args.family, args.n_uavs = task.family, task.n_uavs
    return {"task": task.name}


def _check_team(n_uavs: int, seed: int, env_kwargs: dict) -> None:
    """Build the env with ``--n-uavs`` (and ``--family`` or ``--task``) and reset it on the first held-out scene, so
    that a team size the env rejects (or cannot place) fails with one error line before any evaluation runs."""
    try:
        env = CovertSensingParallelEnv(n_uavs=n_uavs, **env_kwargs)
    except ValueError as exc:
        raise UsageError(f"--n-uavs {n_uavs}: {exc}") from None
    try:
        env.reset(seed=seed, options={"scene_seed": seed})
    except ValueError as exc:
        raise UsageError(f"--n-uavs {n_uavs}: {exc}") from None
    finally:
        env.close()


#: The files :func:`main` writes into ``--out`` (besides ``cache/``).
OUTPUT_FILES = ("leaderboard.md", "leaderboard.csv", "episodes.csv", "comparison.png", "results.json")


def read_cache(path: Path, args: argparse.Namespace) -> list[dict]:
    """The per-episode rows cached at ``path`` by an earlier run (``--reuse``), checked against ``args``: one row
    per held-out scene ``seed_offset + i`` with every leaderboard column a number. A damaged or foreign file is a
    :class:`~covert_env.command_line.UsageError` naming it and the first bad field."""

    fix = "; delete it (it is rewritten) or run without --reuse"
    try:
        rows = read_run_json(path, "--reuse: cached results")
    except UsageError as exc:
        raise UsageError(f"{exc}{fix}") from None
    where = f"--reuse: cached results {path}"
    if not isinstance(rows, list) or len(rows) != args.episodes:
        got = f"{len(rows)} rows" if isinstance(rows, list) else type(rows).__name__
        raise UsageError(f"{where}: expected a list of {args.episodes} episode rows, got {got}{fix}")
    for i, row in enumerate(rows):
        if not isinstance(row, dict):
            raise UsageError(f"{where}: row {i} must be a JSON object, got {type(row).__name__}{fix}")
        seed = row.get("scene_seed")
        if seed != args.seed_offset + i or isinstance(seed, bool):
            raise UsageError(f"{where}: row {i} has scene_seed {seed!r}, expected {args.seed_offset + i}{fix}")
        for key, _, _ in COLUMNS:
            v = row.get(key)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise UsageError(f"{where}: row {i} field {key} must be a finite number, got {v!r}{fix}")
    return rows


def _cache_name(spec: str, args: argparse.Namespace) -> str:
    """The cached results of built-in policy ``spec`` inside ``--out``: ``cache/<spec, episodes, seeds, team>.json``."""
    key = f"{spec}__{args.episodes}__{args.seed_offset}__{args.n_uavs}".replace("/", "_").replace("@", "-")
    if args.task is not None:
        key += f"__{args.task}"
    elif args.family != "paper":               # the paper family's caches keep their names from before families
        key += f"__{args.family}"
    if args.scene_set is not None:
        key += f"__set-{hashlib.sha256(Path(args.scene_set).read_bytes()).hexdigest()[:16]}"
    return f"cache/{key}.json"


def _main(args: argparse.Namespace, command: str) -> int:
    twice = sorted({p for p in args.policies if args.policies.count(p) > 1})
    if twice:
        raise UsageError(f"--policies: {', '.join(twice)} given twice; give each spec once")

    env_kwargs = _task_flags(args)
    scenes = _scene_set(args)
    if scenes is None:
        _check_team(args.n_uavs, args.seed_offset, env_kwargs)
    caches = {spec: _cache_name(spec, args) for spec in args.policies if not from_files(spec)}
    outputs = {"files": (*OUTPUT_FILES, *caches.values()), "folders": ("cache",) if caches else ()}
    output_dir(args.out, create=False, **outputs)
    # Every spec is loaded before any evaluation: a bad one fails at once, not after the others have run.
    loaded = []
    for spec in args.policies:
        try:
            group = [load_policy(part, args.n_uavs, trust_checkpoint=args.trust_checkpoint)
                     for part in split_seeds(spec)]
        except UsageError as exc:
            raise UsageError(f"--policies: {exc}") from None
        if len({json.dumps(st, sort_keys=True) for _, st in group}) > 1:
            raise UsageError(f"--policies: the runs of {spec} need different env settings "
                             f"({[st for _, st in group]}); a seed group must share them")
        loaded.append((spec, group))
    # Cached results are read and checked before any evaluation too.
    reused = {spec: read_cache(Path(args.out) / name, args) for spec, name in caches.items()
              if args.reuse and (Path(args.out) / name).exists()}
    out = output_dir(args.out, **outputs)
    results: dict[str, dict] = {}
    for spec, group in loaded:
        pol, settings = group[0]
        # A built-in policy's row is its spec, as in the suite's tables (dp, not its planner label).
        builtin = spec in caches
        name = (spec if builtin else getattr(pol, "name", spec)) if len(group) == 1 else \
            f"{spec.split(':', 1)[0]} ({len(group)} seeds)"
        # The row names the mode and the filter as the spec does: NAME[@MODE][+shield].
        bare, shield = spec.removesuffix(SHIELD_SUFFIX), SHIELD_SUFFIX if spec.endswith(SHIELD_SUFFIX) else ""
        name = name.removesuffix(SHIELD_SUFFIX)
        if "@" in bare and not name.endswith(bare.rsplit("@", 1)[1]):
            name = f"{name}@{bare.rsplit('@', 1)[1]}"
        name += shield
        while name in results:
            name += "'"
        t0 = time.perf_counter()
        cache = out / caches[spec] if builtin else None
        if spec in reused:
            rows = reused[spec]
        else:
            rows = []
            for i, (member, _) in enumerate(group):
                label = name if len(group) == 1 else f"{name} seed run {i + 1}"
                for row in evaluate(member, settings, args.episodes, args.seed_offset,
                                    env_kwargs=env_kwargs, progress=not args.no_progress,
                                    label=label, scenes=scenes):
                    rows.append({**row, "run": i} if len(group) > 1 else row)
            if builtin:
                cache.parent.mkdir(parents=True, exist_ok=True)
                cache.write_text(json.dumps(rows))
        results[name] = {"rows": rows, "summary": summarise(rows), "settings": settings, "spec": spec,
                         "runs": len(group)}
        s = results[name]["summary"]
        print(f"{name:40s} reward {s['reward'][0]:8.1f} ± {s['reward'][1]:6.1f}  blocked LoS "
              f"{s['occlusion_rate'][0]:.3f}  zone viol. {s['zone_violation_rate'][0]:.3f}  "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
        if rows and "filter_infeasible" in rows[0]:
            print(f"{'':40s} safety filter: {sum(r['filter_infeasible'] for r in rows)} infeasible event(s) in "
                  f"{sum(r['filter_team_slots'] for r in rows)} team-slots; {sum(r['filter_changed'] for r in rows)} "
                  f"UAV choices changed, {sum(r['filter_backups'] for r in rows)} backup moves flown", flush=True)
    write_outputs(results, out, {"episodes": args.episodes, "seed_offset": args.seed_offset, "n_uavs": args.n_uavs,
                                 "family": args.family, "task": args.task, "scene_set": args.scene_set,
                                 "command": command})
    (out / "results.json").write_text(json.dumps({n: {"summary": r["summary"], "settings": r["settings"],
                                                      "spec": r["spec"]} for n, r in results.items()}, indent=2))
    print(f"wrote {out / 'leaderboard.md'}, {out / 'leaderboard.csv'}, {out / 'comparison.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
