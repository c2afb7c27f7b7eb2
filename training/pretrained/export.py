"""Ship a trained actor: ``NAME.npz`` (actor weights, float32, no pickle) and its model card ``NAME.json``.

    python -m training.pretrained.export runs/<mappo-run> --name mappo --episodes 20
    python -m training.pretrained.export --rescore mappo      # the shipped weights on the current env version
    python -m training.pretrained.export runs/<run> --suite outputs/suite/cells.csv --suite-policy SPEC --suite-run 0

The card holds what a reader needs to trust and reproduce the weights: the algorithm, the run's arguments (the
recipe) and training summary (env steps, wall time), the repository commit, the env's id and covert_env's
version, and the scores of the harness (:mod:`covert_env.evaluation.evaluate`, env default reward) on the held-out
scenes 1_000_000 .. 1_000_000 + episodes - 1: mean ± std over scenes, IQM with a 95 % bootstrap interval over scenes
(:mod:`covert_env.evaluation.stats`; one training seed, so the scenes are the resampled runs), the paper's metrics,
and the reward of each scene (``tests/test_pretrained.py`` replays them and compares), and the platform and library
versions that measured them (``platform``, :mod:`covert_env.evaluation.provenance`).

``constraints`` states each constraint's rate on those scenes (the paper's constraints: the zone, eq. 4; LoS at
slot times, eq. 6, and along the flown path; separation, eq. 2; terrain, eq. 3). With ``--suite``, ``suite`` adds
the suite protocol's rows of the weights (``covert-env benchmark``'s ``cells.csv``: the policy spec and, for a seed
group, the run that these weights are): per task, the normalised score and the same rates, over its test scenes,
with the env id they were measured on.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import numpy as np

import covert_env
from baselines.learned_cost import KIND, is_cost_planner_card, load_cost_planner
from covert_env.evaluation.benchmark import CONSTRAINTS
from covert_env.evaluation.evaluate import HELD_OUT_OFFSET, evaluate, summarise
from covert_env.evaluation.provenance import code_commit, platform_record
from covert_env.evaluation.stats import iqm, stratified_bootstrap_ci
from training.pretrained import PRETRAINED_DIR, as_flown, load_learned

__all__ = ["export", "main", "rescore", "suite_rows"]


def export(run: Path, name: str, episodes: int = 20, out_dir: Path = PRETRAINED_DIR, progress: bool = True,
           training_commit: str = "", note: str = "", suite: dict | None = None) -> Path:
    """Write ``out_dir/NAME.npz`` and ``out_dir/NAME.json`` from a :mod:`training.mappo` or :mod:`training.dp_cost`
    run folder; returns the card's path."""
    run = Path(run)
    meta = json.loads((run / "model.json").read_text())
    args = json.loads((run / "args.json").read_text())
    if meta.get("kind") == KIND:
        return _export_cost_planner(run, meta, args, name, episodes, out_dir, progress, note, suite)
    summary = json.loads((run / "train_summary.json").read_text()) if (run / "train_summary.json").exists() else {}
    with np.load(run / "model.npz", allow_pickle=False) as data:
        weights = {k: data[k].astype(np.float32) for k in data.files if k.startswith("actor.")}
    out_dir.mkdir(parents=True, exist_ok=True)
    npz = out_dir / f"{name}.npz"
    np.savez_compressed(npz, **weights)
    from covert_env.envs.vector import CovertSensingVectorEnv

    # env_id: the env the scores below are measured on (the env it was trained on is the recipe's env_id).
    card = {"name": name, "algorithm": meta["algorithm"], "actor": meta["actor"], "env_kwargs": meta["env_kwargs"],
            "train_tasks": meta.get("train_tasks"), "env_id": CovertSensingVectorEnv.metadata["name"],
            "separation_shield": meta.get("separation_shield"),
            "shield_end_margin": meta.get("shield_end_margin"),
            "viability_shield": bool(meta.get("viability_shield", False)),
            "viability_min_reach": meta.get("viability_min_reach"),
            "shield_lookahead": bool(meta.get("shield_lookahead", False)),
            "safety_filter": bool(meta.get("safety_filter", False)),
            "filter_scores": bool(meta.get("filter_scores", False)),
            "covert_env_version": covert_env.__version__, "commit": code_commit(),
            "recipe": {k: v for k, v in args.items() if k not in ("card", "resume", "runs_dir")},
            "training": {**summary, "run": run.name, "commit": training_commit or "unknown"}, "note": note}
    return _scored_card(npz, card, episodes, progress, suite)


def _export_cost_planner(run: Path, meta: dict, args: dict, name: str, episodes: int, out_dir: Path, progress: bool,
                         note: str, suite: dict | None) -> Path:
    """:func:`export` for a :mod:`training.dp_cost` run: the learned ``path_cost`` and a card of ``kind`` dp-cost
    (the same ``scores``, ``constraints`` and ``suite`` blocks as a MAPPO card)."""
    from covert_env.envs.vector import CovertSensingVectorEnv
    from training.dp_cost import training_budget

    with np.load(run / "model.npz", allow_pickle=False) as data:
        w = np.asarray(data["path_cost"], dtype=float)
    out_dir.mkdir(parents=True, exist_ok=True)
    npz = out_dir / f"{name}.npz"
    np.savez(npz, path_cost=w)
    card = {"name": name, **{k: meta[k] for k in ("kind", "planner", "params", "path_cost", "algorithm",
                                                  "env_kwargs")},
            "train_tasks": meta["tasks"], "env_id": CovertSensingVectorEnv.metadata["name"],
            "covert_env_version": covert_env.__version__, "commit": code_commit(),
            "recipe": {k: v for k, v in args.items() if k not in ("runs_dir", "progress_bar")},
            "training": {**meta["training"], **training_budget(meta["training"], meta["tasks"]), "run": run.name,
                         "commit": meta.get("commit", "unknown")}, "note": note}
    return _scored_card(npz, card, episodes, progress, suite)


def _scored_card(npz: Path, card: dict, episodes: int, progress: bool, suite: dict | None) -> Path:
    """Write ``card`` beside ``npz`` (the loader needs it to score the weights), then again with its ``scores``,
    ``constraints`` and ``suite``; returns its path."""
    card_path = npz.with_suffix(".json")
    card_path.write_text(json.dumps(card, indent=2))
    card["scores"] = _scores(npz, card["name"], episodes, progress)
    card["platform"] = platform_record()
    card["constraints"] = _constraints(card["scores"], _team(card))
    if suite is not None:
        card["suite"] = {"env_id": card["env_id"], **suite}
    card_path.write_text(json.dumps(card, indent=2))
    return card_path


def _team(card: dict) -> int:
    """The team a card is scored with: its env's ``n_uavs``, else the harness's default of 3 (the learned-cost
    planners plan for any team)."""
    return int(card.get("env_kwargs", {}).get("n_uavs", 3))


def _constraints(scores: dict, n_uavs: int) -> dict:
    """Each constraint's rate (mean over the scored scenes) from the card's scores, named for a reader, with the
    scenes and team they were measured on (the paper family's: a family that binds another constraint, such as
    towers for eq. 3, is in the ``suite`` rows)."""
    m = {k: v[0] for k, v in scores["metrics_mean_std"].items()}
    first, last = scores["scenes"]
    return {"measured_on": f"held-out paper-family scenes {first}..{last}, {n_uavs} UAVs (per suite task: the "
                           "card's suite)",
            "zone_violation_rate": m["zone_violation_rate"], "blocked_los_rate_slot_times": m["occlusion_rate"],
            "blocked_los_rate_along_path": m["occlusion_rate_path"], "blocked_path_share": m["blocked_path_share"],
            "separation_violation_slots_per_uav": m["separation_violations"],
            "min_separation_m": scores.get("min_separation", m["min_separation"]),
            "terrain_violation_slots_per_uav": m["terrain_violations"]}


def suite_rows(cells: Path, policy: str, run: int | None = None) -> dict:
    """The card's ``suite``: the rows of ``policy`` (its ``run`` of a seed group, or all) in a suite's
    ``cells.csv``, per task: scenes, the mean normalised score and reward, each constraint's mean rate, and the
    smallest separation of any scene.
    A ValueError names the file when it has no such rows."""
    with open(cells, newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["policy"] == policy and (run is None or int(r["run"]) == run)]
    if not rows:
        raise ValueError(f"{cells}: no rows of policy {policy!r}" + ("" if run is None else f" run {run}"))
    tasks: dict[str, dict] = {}
    for t in dict.fromkeys(r["task"] for r in rows):
        mine = [r for r in rows if r["task"] == t]
        tasks[t] = {"scenes": [int(r["scene_seed"]) for r in mine], "mask_mode": mine[0].get("mask_mode"),
                    **{k: float(np.mean([float(r[k]) for r in mine]))
                       for k in ("score", "reward", *(c for c, _ in CONSTRAINTS))},
                    "min_separation": float(min(float(r["min_separation"]) for r in mine))}
    return {"cells": str(cells), "policy": policy, "run": run, "tasks": tasks}


def rescore(name: str, episodes: int | None = None, out_dir: Path = PRETRAINED_DIR, progress: bool = True) -> Path:
    """Score shipped weights again on the current env version (same held-out scenes; ``episodes`` defaults to the
    card's count) and rewrite the card's ``scores``, ``platform``, ``constraints``, ``env_id``,
    ``covert_env_version`` and ``commit``. A ``suite`` block keeps the env id it was measured on (its ``env_id``,
    the card's old one where it has none): a suite is hours of runs, and its rows stay labelled with the env they
    are from. The env id the weights were trained on stays in ``recipe``. Returns the card's path."""
    from covert_env.envs.vector import CovertSensingVectorEnv

    npz = Path(out_dir) / f"{name}.npz"
    card_path = npz.with_suffix(".json")
    card = json.loads(card_path.read_text())
    try:
        first, last = card["scores"]["scenes"]
    except (KeyError, TypeError, ValueError):
        raise ValueError(f"{card_path}: no scores.scenes [first, last] to score again (not a card this module "
                         "wrote)") from None
    card["scores"] = _scores(npz, name, episodes or last - first + 1, progress)
    card["platform"] = platform_record()
    card["constraints"] = _constraints(card["scores"], _team(card))
    if isinstance(card.get("suite"), dict):
        card["suite"] = {"env_id": card["suite"].get("env_id", card.get("env_id")), **card["suite"]}
    card.update(env_id=CovertSensingVectorEnv.metadata["name"], covert_env_version=covert_env.__version__,
                commit=code_commit())
    card_path.write_text(json.dumps(card, indent=2))
    return card_path


def _scores(npz: Path, name: str, episodes: int, progress: bool) -> dict:
    """The card's ``scores``: the harness on held-out scenes 1_000_000 .. + episodes - 1 (module docstring)."""
    if is_cost_planner_card(npz):
        pol = load_cost_planner(npz)
        settings = {"n_uavs": 3, **pol.env_settings}     # the harness's default team
    else:
        pol = load_learned(npz)
        settings = pol.env_settings
        pol = as_flown(pol)                          # scored as the harness flies it (the filter, if trained so)
    rows = evaluate(pol, settings, episodes, HELD_OUT_OFFSET, progress=progress, label=name)
    rewards = np.array([r["reward"] for r in rows])
    point, lo, hi = stratified_bootstrap_ci(rewards[:, None], iqm, reps=5000)
    return {
        "scenes": [HELD_OUT_OFFSET, HELD_OUT_OFFSET + episodes - 1],
        "reward_mean": float(rewards.mean()), "reward_std": float(rewards.std()),
        "reward_iqm": point, "reward_iqm_ci95_over_scenes": [lo, hi],
        "metrics_mean_std": {k: list(v) for k, v in summarise(rows).items() if k != "decision_time_ms"},
        "per_scene_reward": {str(r["scene_seed"]): r["reward"] for r in rows},
        "min_separation": float(min(r["min_separation"] for r in rows)),     # the smallest of any scene
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m training.pretrained.export", description=__doc__.split("\n")[0])
    p.add_argument("run", nargs="?", help="a training.mappo or training.dp_cost run folder (model.npz, model.json, "
                   "args.json)")
    p.add_argument("--rescore", metavar="NAME", help="instead: score the shipped NAME.npz in --out-dir again on the "
                   "current env version and rewrite its card's scores (--episodes: the card's count by default)")
    p.add_argument("--name", default="mappo", help="file stem in training/pretrained/ (pretrained:NAME)")
    p.add_argument("--episodes", type=int, default=None, help="held-out scenes to score (>= 1; default 20)")
    p.add_argument("--out-dir", default=str(PRETRAINED_DIR), help="where to write NAME.npz and NAME.json")
    p.add_argument("--training-commit", default="", help="the commit of the code that trained the run")
    p.add_argument("--note", default="", help="what a user should know (e.g. the constraints it violates)")
    p.add_argument("--suite", metavar="CELLS_CSV", help="a suite's cells.csv (covert-env benchmark) holding rows of "
                   "these weights: their per-task scores and constraint rates go into the card")
    p.add_argument("--suite-policy", metavar="SPEC", help="the weights' policy spec in --suite (e.g. "
                   "mappo:runs/a,runs/b)")
    p.add_argument("--suite-run", type=int, default=None, help="which run of a seed group the weights are (>= 0)")
    a = p.parse_args(argv)
    if a.episodes is not None and a.episodes < 1:
        p.error(f"--episodes {a.episodes}: must be >= 1")
    if a.rescore is not None:
        if a.run is not None:
            p.error("give a run folder or --rescore NAME, not both")
        for flag, value in (("--name", a.name != "mappo"), ("--note", a.note), ("--training-commit",
                                                                               a.training_commit),
                            ("--suite", a.suite), ("--suite-policy", a.suite_policy),
                            ("--suite-run", a.suite_run is not None)):
            if value:
                p.error(f"{flag} does not go with --rescore (it rewrites only the card's scores, constraints, env "
                        "id, version and commit)")
        if Path(a.rescore).name != a.rescore or a.rescore in ("", ".", ".."):
            p.error(f"--rescore {a.rescore}: a file stem in --out-dir (NAME of NAME.npz), not a path")
        stem = Path(a.out_dir) / a.rescore
        if not stem.with_suffix(".json").is_file() or not stem.with_suffix(".npz").is_file():
            p.error(f"--rescore {a.rescore}: no {a.rescore}.npz with its card in {a.out_dir}")
        try:
            card = rescore(a.rescore, a.episodes, Path(a.out_dir))
        except ValueError as exc:
            p.error(str(exc))
    else:
        if a.run is None:
            p.error("give a training.mappo run folder, or --rescore NAME")
        if not (Path(a.run) / "model.npz").is_file():
            p.error(f"{a.run}: no model.npz (not a finished training.mappo run)")
        suite = None
        if a.suite is None and (a.suite_policy or a.suite_run is not None):
            p.error("--suite-policy and --suite-run need --suite (a suite's cells.csv)")
        if a.suite is not None:
            if not a.suite_policy:
                p.error("--suite needs --suite-policy (the weights' spec in that cells.csv)")
            if a.suite_run is not None and a.suite_run < 0:
                p.error(f"--suite-run {a.suite_run}: must be >= 0")
            try:
                suite = suite_rows(Path(a.suite), a.suite_policy, a.suite_run)
            except (OSError, KeyError, ValueError) as exc:
                p.error(f"--suite {a.suite}: {exc}")
        card = export(Path(a.run), a.name, a.episodes or 20, Path(a.out_dir), training_commit=a.training_commit,
                      note=a.note, suite=suite)
    s = json.loads(card.read_text())["scores"]
    wrote = card if a.rescore else f"{card} and {card.with_suffix('.npz')}"
    print(f"wrote {wrote}: reward {s['reward_mean']:.1f} ± {s['reward_std']:.1f}, IQM {s['reward_iqm']:.1f} "
          f"[{s['reward_iqm_ci95_over_scenes'][0]:.1f}, {s['reward_iqm_ci95_over_scenes'][1]:.1f}]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
