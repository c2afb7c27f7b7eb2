"""What the eroded zone (eq. 5) buys under a real prediction error (``Config.prediction_error``).

The target drives with bounded speed noise (docs/decisions.md#prediction-error); the shadow-aware DP
team plans on the prediction (re-made every slot from the true current position) and the metrics
score the truth. For each prediction-error bound b and uncertainty radius r_u the table counts, over
the UAV-slots flown:

* zone violations: the UAV outside the true target's zone Phi(q[k+1]) of eq. 4 at the slot's end,
  on slots whose move the planner found feasible (a fallback move, e.g. from a start heading away
  from the zone, is counted apart: no r_u helps it);
* blocked LoS at slot times and along the path (eq. 6 against the true target).

Eq. 5 guarantees the first: a node of the zone eroded by r_u >= b around the predicted q lies in the
zone of every q0 within b of it (up to the heading change between predicted and true position on a
curved road, at most R2 * b * max curvature). It does not protect the line of sight: shadows (eq. 10)
are computed from the predicted target, and the erosion does not dilate them.

Run: ``covert-env reproduce --out DIR --prediction-study`` (writes ``prediction_study.md`` and
``prediction_study.json``), or ``python -m baselines.prediction_study``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from covert_env.config import Config
from covert_env.metrics import slot_quantities
from covert_env.scenario import Scenario

__all__ = ["SCENES", "ZONE_TOL", "prediction_study", "study_markdown", "write_study"]

#: Signed distance (m) beyond the zone's boundary that counts as a violation: a UAV planned onto the
#: boundary itself lands within round-off of it, on either side.
ZONE_TOL = 1e-6
#: Default scenes: the paper's and three held-out ones (``Scenario.random(1_000_000 + i)``).
SCENES = (("paper", 0), ("random", 1_000_000), ("random", 1_000_001), ("random", 1_000_003))


def _scene(kind: str, seed: int, config: Config) -> Scenario:
    return Scenario.paper(config) if kind == "paper" else Scenario.random(int(seed), config)


def prediction_study(config: Config | None = None, *, bounds=(0.0, 4.0), r_us=(0.0, 4.0), scenes=SCENES,
                     n_uavs: int = 1, n_slots: int = 30) -> list[dict]:
    """One row per (bound, r_u): counts summed over ``scenes``, each flown ``n_slots`` slots.

    Every r_u flies the same scene (road, terrain, true track and starts, drawn with r_u = 0), so the
    rows differ only in the planner's zone.
    """
    from baselines.reproduce import rollout

    base = (config or Config()).replace(n_uavs=int(n_uavs))
    rows = []
    for b in bounds:
        worlds = [_scene(kind, seed, base.replace(prediction_error=float(b), r_u=0.0)) for kind, seed in scenes]
        for r_u in r_us:
            cfg = base.replace(prediction_error=float(b), r_u=float(r_u))
            tot = dict.fromkeys(("uav_slots", "zone_violations", "fallback_slots", "fallback_zone_violations",
                                 "blocked", "blocked_path"), 0)
            worst = -np.inf
            for w in worlds:
                sc = Scenario(cfg, w.terrain, w.track, w.uav_xy, w.uav_theta, name=w.name)
                traj = rollout(sc, n_slots=min(n_slots, cfg.n_slots))["trajectory"]
                q = slot_quantities(traj, sc.terrain, cfg)
                fallback = traj.infeasible
                out = q.zone_distance > ZONE_TOL
                tot["uav_slots"] += q.los.size
                tot["zone_violations"] += int((out & ~fallback).sum())
                tot["fallback_slots"] += int(fallback.sum())
                tot["fallback_zone_violations"] += int((out & fallback).sum())
                tot["blocked"] += int((~q.los).sum())
                tot["blocked_path"] += int((q.los_path < 1).sum())
                worst = max(worst, float(q.zone_distance[~fallback].max(initial=-np.inf)))
            rows.append({"prediction_error": float(b), "r_u": float(r_u), **tot,
                         "blocked_rate": tot["blocked"] / tot["uav_slots"],
                         "blocked_path_rate": tot["blocked_path"] / tot["uav_slots"],
                         "max_zone_distance": worst})
    return rows


def study_markdown(rows: list[dict], n_scenes: int, n_slots: int, n_uavs: int) -> str:
    lines = ["# Prediction error and the eroded zone (eq. 5)", "",
             f"Shadow-aware DP, {n_uavs} UAV(s), {n_scenes} scenes x {n_slots} slots; the truth scored, the "
             "prediction planned on (docs/decisions.md#prediction-error).", "",
             "| prediction error b (m) | r_u (m) | UAV-slots | zone violations | max zone distance (m) | "
             "blocked LoS (slot times) | blocked LoS (along path) | fallback slots (zone violations) |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['prediction_error']:g} | {r['r_u']:g} | {r['uav_slots']} | {r['zone_violations']} | "
                     f"{r['max_zone_distance']:+.2f} | {r['blocked']} ({100 * r['blocked_rate']:.1f} %) | "
                     f"{r['blocked_path']} ({100 * r['blocked_path_rate']:.1f} %) | "
                     f"{r['fallback_slots']} ({r['fallback_zone_violations']}) |")
    lines += ["", "Zone violations: the UAV outside the true target's zone of eq. 4 after a planned (non-fallback) "
              "move; max zone distance: the largest signed distance to that zone's boundary over those moves "
              "(positive = outside; a violation is > 1e-6 m, round-off on the boundary excluded). Eq. 5 with "
              "r_u >= b keeps the UAVs in the zone; it says nothing about "
              "shadows, which are computed from the prediction, so blocked LoS is not expected to vanish.", ""]
    return "\n".join(lines)


def write_study(out: Path, config: Config | None = None, *, quick: bool = False) -> str:
    """Run the default study (a shorter one with ``quick``), write ``prediction_study.md`` / ``.json``
    into ``out``, and return the markdown."""
    scenes = SCENES[:2] if quick else SCENES
    n_slots = 12 if quick else 30
    rows = prediction_study(config, scenes=scenes, n_slots=n_slots)
    text = study_markdown(rows, len(scenes), n_slots, 1)
    out = Path(out)
    (out / "prediction_study.md").write_text(text)
    (out / "prediction_study.json").write_text(json.dumps({"scenes": [list(s) for s in scenes], "n_slots": n_slots,
                                                           "rows": rows}, indent=1) + "\n")
    return text


if __name__ == "__main__":  # pragma: no cover
    print(study_markdown(prediction_study(), len(SCENES), 30, 1))
    sys.exit(0)
