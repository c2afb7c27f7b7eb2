"""What the eroded zone (eq. 5) and the widened shadows buy under a real prediction error.

The target drives with bounded speed noise (``Config.prediction_error`` = b, docs/decisions/model.md#prediction-error);
the shadow-aware DP team plans on the prediction (re-made every slot from the true current position) and the
metrics score the truth. Three planners fly the same scenes (road, terrain, true track and starts):

* ``r_u = 0``: neither eq. 5's erosion nor widened shadows (the planner trusts the prediction);
* ``eroded``: r_u = b, shadows of the predicted target only (``los_margin=0``: eq. 10 as the paper states it);
* ``eroded + widened``: r_u = b and the line of sight checked to every true position the error allows
  (the default with ``prediction_error > 0``, docs/decisions/model.md#prediction-los).

Per UAV-slot, against the true target:

* zone violations: the UAV outside the true target's zone Phi(q[k+1]) of eq. 4 at the slot's end, on slots
  whose move the planner found feasible (a fallback move, e.g. from a start heading away from the zone, is
  counted apart: no r_u helps it);
* blocked LoS at slot times (eq. 6), on the planner's feasible moves and in all; and along the path.

Eq. 5 with r_u >= b guarantees the first (up to the heading change between predicted and true position on a
curved road, at most R2 * b * max curvature); the widened shadows guarantee LoS at slot times on feasible moves.
Every rate comes with a 95 % percentile bootstrap interval over the scenes (:func:`baselines.intervals.bootstrap_ci`).

Run: ``covert-env reproduce --out DIR --prediction-study`` (writes ``prediction_study.md``,
``prediction_study.json`` and ``fig_prediction.png``), or ``python -m baselines.prediction_study``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from baselines.intervals import bootstrap_ci
from baselines.rollout import rollout
from covert_env.world.config import Config
from covert_env.world.metrics import slot_quantities
from covert_env.world.scenario import Scenario

__all__ = ["BOUND", "QUICK_SCENES", "QUICK_SLOTS", "SCENES", "ZONE_TOL", "fly", "prediction_study", "study_figure",
           "study_markdown", "variants", "write_study"]

#: Signed distance (m) beyond the zone's boundary that counts as a violation: a UAV planned onto the
#: boundary itself lands within round-off of it, on either side.
ZONE_TOL = 1e-6
#: Default prediction-error bound b (m).
BOUND = 4.0
#: Default scenes: the 20 held-out scenes of the full reproduction (``Scenario.random(1_000_000 + i)``).
SCENES = tuple(("random", 1_000_000 + i) for i in range(20))
#: ``--quick``: two held-out scenes where, with 3 UAVs and b = 4 m, the r_u = 0 planner (1_000_002, slot 5) and
#: the eroded one without widened shadows (1_000_005, slot 19) lose LoS to the true target (found by the full
#: study; chosen so the effect shows, not representative), 20 slots.
QUICK_SCENES = (("random", 1_000_002), ("random", 1_000_005))
QUICK_SLOTS = 20
#: Per-scene counts, and the rates of the table (numerator key, title).
COUNTS = ("uav_slots", "zone_violations", "blocked", "blocked_planned", "blocked_path", "fallback_slots",
          "fallback_zone_violations")
RATES = (("zone_violations", "zone violations (planned moves)"), ("blocked_planned", "blocked LoS, planned moves"),
         ("blocked", "blocked LoS, all moves"), ("blocked_path", "blocked LoS along the path"),
         ("fallback_slots", "fallback moves"))


def variants(bound: float) -> tuple[tuple[str, float, float | None], ...]:
    """The compared planners: (label, r_u, los_margin); ``los_margin=None`` is the planner's default (r_u)."""
    return (("r_u = 0", 0.0, None), ("eroded, shadows of the prediction", float(bound), 0.0),
            ("eroded + widened shadows", float(bound), None))


def _scene(kind: str, seed: int, config: Config) -> Scenario:
    return Scenario.paper(config) if kind == "paper" else Scenario.random(int(seed), config)


def fly(kind: str, seed: int, config: Config, r_u: float, los_margin: float | None, n_slots: int) -> dict:
    """One scene flown by the shadow-aware DP team with uncertainty radius ``r_u`` and ``los_margin``: the counts
    of :data:`COUNTS` and the largest zone distance of a planned move. The world (road, terrain, true track,
    starts) is drawn with r_u = 0 whatever ``r_u``, so the planners fly the same scene."""
    world = _scene(kind, seed, config.replace(r_u=0.0))
    cfg = config.replace(r_u=float(r_u))
    sc = Scenario(cfg, world.terrain, world.track, world.uav_xy, world.uav_theta, name=world.name)
    traj = rollout(sc, n_slots=min(int(n_slots), cfg.n_slots), los_margin=los_margin)["trajectory"]
    q = slot_quantities(traj, sc.terrain, cfg)
    fallback = traj.infeasible
    out = q.zone_distance > ZONE_TOL
    return {"uav_slots": int(q.los.size), "zone_violations": int((out & ~fallback).sum()),
            "blocked": int((~q.los).sum()), "blocked_planned": int((~q.los & ~fallback).sum()),
            "blocked_path": int((q.los_path < 1).sum()), "fallback_slots": int(fallback.sum()),
            "fallback_zone_violations": int((out & fallback).sum()),
            "max_zone_distance": float(q.zone_distance[~fallback].max(initial=-np.inf))}


def _fly_task(task):
    i, kind, seed, cfg_dict, r_u, los_margin, n_slots = task
    return i, fly(kind, seed, Config.from_dict(cfg_dict), r_u, los_margin, n_slots)


def prediction_study(config: Config | None = None, *, bound: float = BOUND, scenes=SCENES, n_uavs: int = 3,
                     n_slots: int = 70, jobs: int = 1, compared=None) -> list[dict]:
    """One row per compared planner (default :func:`variants`): counts summed over ``scenes``, every rate with its
    mean over the scenes and 95 % bootstrap interval, and the per-scene counts (``per_scene``).

    Args:
        config: model parameters (default the paper's); ``prediction_error`` is set to ``bound``, ``n_uavs`` to
            ``n_uavs``.
        scenes: (kind, seed) pairs, kind "paper" or "random".
        jobs: worker processes (spawned; 1 runs in this process).
        compared: (label, r_u, los_margin) triples instead of :func:`variants`.
    """
    base = (config or Config()).replace(n_uavs=int(n_uavs), prediction_error=float(bound))
    compared = tuple(compared) if compared is not None else variants(bound)
    tasks = [(len(scenes) * v + s, kind, int(seed), base.to_dict(), r_u, margin, int(n_slots))
             for v, (_, r_u, margin) in enumerate(compared) for s, (kind, seed) in enumerate(scenes)]
    results: list = [None] * len(tasks)
    if jobs > 1 and len(tasks) > 1:
        import multiprocessing as mp

        with mp.get_context("spawn").Pool(min(int(jobs), len(tasks))) as pool:
            for i, res in pool.imap_unordered(_fly_task, tasks):
                results[i] = res
    else:
        for t in tasks:
            i, res = _fly_task(t)
            results[i] = res
    rows = []
    for v, (label, r_u, margin) in enumerate(compared):
        per = results[v * len(scenes):(v + 1) * len(scenes)]
        row = {"planner": label, "prediction_error": float(bound), "r_u": float(r_u),
               "los_margin": float(r_u) if margin is None else float(margin),
               **{k: sum(p[k] for p in per) for k in COUNTS},
               "max_zone_distance": max(p["max_zone_distance"] for p in per),
               "per_scene": [{"scene": list(sc), **p} for sc, p in zip(scenes, per, strict=True)]}
        for key, _ in RATES:
            rates = np.array([p[key] / p["uav_slots"] for p in per])
            row["rate_" + key] = float(rates.mean())
            row["rate_" + key + "_ci"] = [float(x) for x in bootstrap_ci(rates)] if len(rates) > 1 else None
        rows.append(row)
    return rows


def study_markdown(rows: list[dict], n_scenes: int, n_slots: int, n_uavs: int, note: str = "") -> str:
    """The study's table: per planner, each rate as mean over scenes [95 % CI] (count)."""
    head = " | ".join(title for _, title in RATES)
    lines = ["# Prediction error: the eroded zone (eq. 5) and the widened shadows (eq. 10)", "",
             f"Shadow-aware DP team, {n_uavs} UAV(s), {n_scenes} scenes x {n_slots} slots, prediction error bound "
             f"b = {rows[0]['prediction_error']:g} m; the truth scored, the prediction planned on "
             "(docs/decisions/model.md#prediction-error, #prediction-los). Rates per UAV-slot: mean over the scenes "
             "[95 % percentile bootstrap interval over scenes] (count).", ""]
    if note:
        lines += [note, ""]
    lines += [f"| planner | r_u (m) | LoS margin (m) | UAV-slots | {head} | max zone distance (m) |",
              "|---|---:|---:|---:|" + "---:|" * len(RATES) + "---:|"]
    for r in rows:
        cells = []
        for key, _ in RATES:
            ci = r["rate_" + key + "_ci"]
            band = f" [{100 * ci[0]:.2f}, {100 * ci[1]:.2f}]" if ci is not None else ""
            cells.append(f"{100 * r['rate_' + key]:.2f} %{band} ({r[key]})")
        lines.append(f"| {r['planner']} | {r['r_u']:g} | {r['los_margin']:g} | {r['uav_slots']} | "
                     + " | ".join(cells) + f" | {r['max_zone_distance']:+.2f} |")
    lines += ["", "Zone violations: the UAV outside the true target's zone of eq. 4 after a planned (non-fallback) "
              "move (> 1e-6 m beyond the boundary); max zone distance: the largest signed distance to that zone's "
              "boundary over those moves (positive = outside). Blocked LoS: eq. 6 from the UAV to the true target at "
              "the slot's end (planned moves, and all moves including fallbacks), and at any of the 11 instants "
              "along the slot. Eq. 5 with r_u >= b keeps the UAVs in the true zone; the widened shadows (LoS to every "
              "position the error allows) keep LoS at slot times on planned moves; between slot times neither "
              "(the path checks of `check_path` use the prediction).", ""]
    return "\n".join(lines)


#: The figure's panels: rate key, title.
FIGURE_PANELS = (("zone_violations", "outside the true zone\n(planned moves, slot times)"),
                 ("blocked_planned", "LoS to the true target blocked\n(planned moves, slot times)"),
                 ("blocked_path", "LoS blocked along the path\n(all moves)"),
                 ("fallback_slots", "fallback moves\n(no visible node reachable)"))


def study_figure(rows: list[dict], path: Path, n_scenes: int) -> str:
    """``fig_prediction.png``: per planner, each rate of :data:`FIGURE_PANELS` (% of UAV-slots, mean over scenes)
    with its 95 % bootstrap interval and the count; returns the file name."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = ("tab:red", "tab:orange", "tab:blue")
    fig, axes = plt.subplots(1, len(FIGURE_PANELS), figsize=(3.6 * len(FIGURE_PANELS), 3.8))
    x = np.arange(len(rows))
    for ax, (key, title) in zip(axes, FIGURE_PANELS, strict=True):
        val = np.array([100 * r["rate_" + key] for r in rows])
        ci = np.array([[100 * c for c in (r["rate_" + key + "_ci"] or (r["rate_" + key],) * 2)] for r in rows])
        ax.bar(x, val, color=colors[:len(rows)], yerr=np.abs(ci.T - val), capsize=4)
        top = max(float(ci.max()), 0.05)
        for i, r in enumerate(rows):
            ax.text(i, ci[i, 1] + 0.03 * top, f"{val[i]:.2f} %\n({r[key]})", ha="center", va="bottom", fontsize=8)
        ax.set_ylim(0, 1.35 * top)
        ax.set_xticks(x, [f"r_u = {r['r_u']:g} m\nLoS margin\n{r['los_margin']:g} m" for r in rows], fontsize=8)
        ax.set_ylabel("% of UAV-slots")
        ax.set_title(title, fontsize=9)
    fig.suptitle(f"Prediction error b = {rows[0]['prediction_error']:g} m, {rows[0]['uav_slots']} UAV-slots per "
                 f"planner over {n_scenes} scenes; bars: mean over scenes, whiskers: 95 % bootstrap CI (count).\n"
                 "r_u: zone erosion (eq. 5); LoS margin: shadows widened to every true position within it "
                 "(0 = the prediction's shadows, eq. 10)", fontsize=9)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=90, bbox_inches="tight")
    plt.close(fig)
    return path.name


def write_study(out: Path, config: Config | None = None, *, quick: bool = False, jobs: int = 1,
                figure: bool = True) -> str:
    """Run the default study (:data:`QUICK_SCENES` with ``quick``), write ``prediction_study.md`` / ``.json``
    (and ``fig_prediction.png`` with ``figure``) into ``out``, and return the markdown."""
    scenes = QUICK_SCENES if quick else SCENES
    n_slots = QUICK_SLOTS if quick else (config or Config()).n_slots
    n_uavs = 3
    rows = prediction_study(config, scenes=scenes, n_slots=n_slots, n_uavs=n_uavs, jobs=jobs)
    note = ("QUICK: two scenes chosen where the effect shows (see `QUICK_SCENES`); not representative."
            if quick else "")
    text = study_markdown(rows, len(scenes), n_slots, n_uavs, note)
    out = Path(out)
    (out / "prediction_study.md").write_text(text)
    if figure:
        study_figure(rows, out / "fig_prediction.png", len(scenes))
    (out / "prediction_study.json").write_text(json.dumps({"scenes": [list(s) for s in scenes], "n_slots": n_slots,
                                                           "n_uavs": n_uavs, "rows": rows}, indent=1) + "\n")
    return text


if __name__ == "__main__":  # pragma: no cover
    print(study_markdown(prediction_study(jobs=2), len(SCENES), Config().n_slots, 3))
    sys.exit(0)
