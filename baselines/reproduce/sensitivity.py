"""``covert-env reproduce --sensitivity``: aware against blind with one parameter varied at a time."""

from __future__ import annotations

import json

import numpy as np

from baselines.reproduce.report import scene_values
from baselines.reproduce.runs import HELDOUT_SEED_BASE, QUICK_POOL, RunSpec, most_shadowed_scenes, run_pairs
from covert_env.world.config import Config

#: ``--sensitivity``: scenes (the most shadowed of the first QUICK_POOL held-out ones), slots, and the values
#: tried for each parameter (one parameter varied at a time, the others at the config's values).
SENSITIVITY_SCENES = 3
SENSITIVITY_SLOTS = 30
SENSITIVITY_VALUES = {"grid_step": (2.0, 3.0, 4.0), "r_u": (0.0, 2.0, 5.0), "h_min": (None, 20.0, 40.0),
                      "target_speed": (5.0, 10.0, 15.0)}


def sensitivity(config: Config, jobs: int = 1, heading: str = "inherited", scenes: int = SENSITIVITY_SCENES,
                n_slots: int = SENSITIVITY_SLOTS, values: dict | None = None) -> str:
    """The sensitivity table (markdown): aware vs blind, 1 UAV, on the most shadowed held-out scenes, varying one
    parameter at a time. A target speed other than the config's changes the road's length, hence the scenes."""
    values = SENSITIVITY_VALUES if values is None else values
    n_slots = min(n_slots, config.n_slots)
    seeds = most_shadowed_scenes(scenes, n_slots, config)
    variants = [(name, v, config.replace(**{name: v})) for name, vals in values.items() for v in vals]
    # One pool for every run; a variant equal to the config (each parameter's default) runs once.
    distinct = list({json.dumps(cfg.to_dict(), sort_keys=True): cfg for _, _, cfg in variants}.values())
    pairs = [(RunSpec("random", s, 1, m, n_slots, heading), cfg) for cfg in distinct for s in seeds
             for m in ("aware", "blind")]
    done = run_pairs(pairs, jobs)
    by_cfg: dict[str, list[dict]] = {}
    for (_, cfg), res in zip(pairs, done, strict=True):
        by_cfg.setdefault(json.dumps(cfg.to_dict(), sort_keys=True), []).extend(res["records"])
    rows = []
    for name, v, cfg in variants:
        recs = by_cfg[json.dumps(cfg.to_dict(), sort_keys=True)]
        row = {"param": name, "value": "auto" if v is None else f"{v:g}", "default": v == getattr(config, name)}
        for m in ("aware", "blind"):
            rs = [r for r in recs if r["method"] == m]
            _, occ = scene_values(rs, lambda r: r["blocked_slots"] / r["slots"])
            _, lost = scene_values(rs, lambda r: r["lost_between_slots"] / r["slots"])
            _, inf = scene_values(rs, lambda r: r["infeasible_slots"] / r["slots"])
            _, kap = scene_values(rs, lambda r: r["mean_disguise"])
            row[m] = (occ.mean(), lost.mean(), inf.mean(), kap.mean(),
                      float(np.median([r["team_time_ms_median"] for r in rs])))
        rows.append(row)
    lines = ["# covert-env reproduce --sensitivity", "",
             f"1 UAV, {n_slots} slots, held-out scenes {', '.join(str(s - HELDOUT_SEED_BASE) for s in seeds)} "
             f"(seed - {HELDOUT_SEED_BASE}; the {len(seeds)} of the first {QUICK_POOL} whose zone is most in shadow: "
             "the effects are larger than on random scenes). One parameter varied at a time; * = the config's value. "
             "Rates per UAV-slot, mean over the scenes. A target speed other than the config's changes the road "
             "length and so the scenes themselves. Identical rows for different h_min mean that the planner's "
             "visible set does not depend on it (the DP tests the line of sight of every lattice node exactly, "
             "eq. 6; h_min truncates the shadow polygons, eq. 9, which then only serve drawings and fast tests).",
             "",
             "| parameter | value | aware: occlusion | aware: lost between slots | aware: infeasible | "
             "aware: disguise | blind: occlusion | blind: lost between slots | blind: disguise | "
             "replan ms (aware / blind) |",
             "|" + "---|" * 10]
    for r in rows:
        a, b = r["aware"], r["blind"]
        lines.append(f"| {r['param']} | {r['value']}{' *' if r['default'] else ''} | {a[0]:.3f} | {a[1]:.3f} | "
                     f"{a[2]:.3f} | {a[3]:.1f} | {b[0]:.3f} | {b[1]:.3f} | {b[3]:.1f} | {a[4]:.0f} / {b[4]:.0f} |")
    return "\n".join(lines) + "\n"


