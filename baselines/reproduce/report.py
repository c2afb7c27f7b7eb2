"""``metrics.md`` of ``covert-env reproduce``: every rate per method and team size with its bootstrap interval
over the held-out scenes, the paper's claims checked, and where the time went."""

from __future__ import annotations

import os

import numpy as np

from baselines.intervals import BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, bootstrap_ci
from baselines.reproduce.runs import METHODS, QUICK_POOL, QUICK_SLOTS
from covert_env.world.config import Config

#: The rates of metrics.md: key, column title, value of one UAV's record (per UAV-slot unless said).
RATES = (
    ("occlusion", "occlusion rate (LoS blocked at slot times)", lambda r: r["blocked_slots"] / r["slots"]),
    ("blocked_unflagged", "blocked, unflagged", lambda r: r["blocked_unflagged"] / r["slots"]),
    ("lost_between", "LoS lost between slot times", lambda r: r["lost_between_slots"] / r["slots"]),
    ("blocked_path", "blocked along path", lambda r: r["blocked_path_slots"] / r["slots"]),
    ("infeasible", "infeasible (flagged)", lambda r: r["infeasible_slots"] / r["slots"]),
    ("zone_violation", "zone violation", lambda r: r["zone_violation_rate"]),
    ("disguise", "mean disguise kappa", lambda r: r["mean_disguise"]),
)


def scene_values(records: list[dict], value) -> tuple[list[int], np.ndarray]:
    """(seeds, per-scene values): ``value(record)`` averaged over the UAVs of each run (equal slots per UAV, so
    the mean over scenes equals the pooled rate over UAV-slots)."""
    seeds = sorted({r["seed"] for r in records})
    return seeds, np.array([np.mean([value(r) for r in records if r["seed"] == s]) for s in seeds])


def aggregate(records: list[dict]) -> list[dict]:
    """One row per (scene set, team size, method): counts, and every rate with its 95 % CI over scenes."""
    rows = []
    keys = sorted({(r["scene"], r["n_uavs"], r["method"]) for r in records},
                  key=lambda t: (t[0] != "paper", t[1], list(METHODS).index(t[2])))
    for scene, u, method in keys:
        rs = [r for r in records if (r["scene"], r["n_uavs"], r["method"]) == (scene, u, method)]
        row = {
            "scene": scene, "n_uavs": u, "method": method, "runs": len({r["run"] for r in rs}),
            "uav_slots": sum(r["slots"] for r in rs),
            "blocked": sum(r["blocked_slots"] for r in rs),
            "blocked_unflagged": sum(r["blocked_unflagged"] for r in rs),
            "lost_between": sum(r["lost_between_slots"] for r in rs),
            "blocked_path": sum(r["blocked_path_slots"] for r in rs),
            "blocked_path_unflagged": sum(r["blocked_path_unflagged"] for r in rs),
            "infeasible": sum(r["infeasible_slots"] for r in rs),
            "truncated": sum(r["truncated_slots"] for r in rs),
            "mean_disguise": float(np.mean([r["mean_disguise"] for r in rs])),
            "path_length": float(np.mean([r["path_length"] for r in rs])),
            "objective": float(np.mean([r["objective"] for r in rs])),
            "min_separation": float(min((r["min_separation"] for r in rs if r["min_separation"] is not None),
                                        default=float("inf"))),
            "separation_violations": sum(r["separation_violations"] for r in rs),
            "terrain_violations": sum(r["terrain_violations"] for r in rs),
            "speed_violations": sum(r["speed_violations"] for r in rs),
            "team_ms_median": float(np.median([r["team_time_ms_median"] for r in rs])),
            "team_ms_p90": float(np.max([r["team_time_ms_p90"] for r in rs])),
            "rounds": sum(r["negotiation_rounds"] for r in rs) // max(u, 1),
            "unresolved": sum(r["unresolved_conflicts"] for r in rs) // max(u, 1),
        }
        for key, _, value in RATES:
            _, vals = scene_values(rs, value)
            row["rate_" + key] = float(vals.mean())
            row["rate_" + key + "_ci"] = bootstrap_ci(vals) if len(vals) > 1 else None
        rows.append(row)
    return rows


def _fmt_ci(value: float, ci, fmt: str = "{:.3f}") -> str:
    if ci is None:
        return fmt.format(value)
    return f"{fmt.format(value)} [{fmt.format(ci[0])}, {fmt.format(ci[1])}]"


def disguise_ratio_ci(records: list[dict], u: int) -> tuple[float, tuple[float, float]] | None:
    """Held-out disguise ratio aware / blind (ratio of the means over scenes) and its paired bootstrap CI."""
    aw = [r for r in records if r["scene"] == "heldout" and r["n_uavs"] == u and r["method"] == "aware"]
    bl = [r for r in records if r["scene"] == "heldout" and r["n_uavs"] == u and r["method"] == "blind"]
    s_aw, v_aw = scene_values(aw, lambda r: r["mean_disguise"])
    s_bl, v_bl = scene_values(bl, lambda r: r["mean_disguise"])
    if not s_aw or s_aw != s_bl or len(s_aw) < 2:
        return None
    pairs = np.column_stack([v_aw, v_bl])
    ci = bootstrap_ci(pairs, lambda b: b[..., 0].mean(axis=1) / b[..., 1].mean(axis=1))
    return float(v_aw.mean() / v_bl.mean()), ci


def metrics_markdown(rows: list[dict], records: list[dict], config: Config, elapsed: float, quick: bool,
              figures: list[str], load: tuple[float, float], timing: dict | None = None) -> str:
    lines = [
        "# covert-env reproduce: the paper's DP planner, shadow-aware vs shadow-blind",
        "",
        f"Config: paper defaults (N = {config.horizon}, delta = {config.delta:g} s, V_max = {config.v_max:g} m/s, "
        f"W_max = {config.w_max:g} rad/s, eta = {config.eta:g}, lambda = {config.lam:g}, grid {config.grid_step:g} m, "
        f"d_safe1 = {config.d_safe1:g} m){' -- QUICK run' if quick else ''}. Heading: inherited (the paper's DP).",
        "Methods: `aware` = the paper's method (visible zone, eq. 10); `blind` = the earlier method [1] "
        "(plain feasible zone); `aware-path` = aware + LoS and zone checked along every manoeuvre.",
    ]
    families = sorted({r["family"] for r in records if r.get("family")})
    if families:
        lines.append(f"Held-out scenes of scene family {', '.join(families)} (covert_env.world.families); the paper "
                     "scene is the paper's.")
    if quick:
        lines.append(f"QUICK: held-out scenes = those of the first {QUICK_POOL} whose zone is most in shadow over "
                     "the flown slots (`most_shadowed_scenes`), so rates here are NOT representative of random "
                     f"scenes; {QUICK_SLOTS} slots by default (with the paper's parameters the paper scene's zone is "
                     "in shadow at slots 11-15).")
    lines += [
        f"Total wall time {elapsed:.0f} s on {os.cpu_count()} CPUs (load average {load[0]:.1f} at start, "
        f"{load[1]:.1f} at the end: timings on a shared machine are upper bounds).",
        "",
        "## Rates",
        "",
        "Per UAV-slot (mean disguise: per UAV-slot, eq. 11). Held-out rows: mean over the scenes "
        f"[95 % percentile bootstrap confidence interval over scenes, {BOOTSTRAP_RESAMPLES:,} resamples, "
        f"seed {BOOTSTRAP_SEED}]; the paper scene is a single scene (no interval).",
        "",
        "| scenes | U | method | runs | UAV-slots | " + " | ".join(title for _, title, _ in RATES) + " |",
        "|" + "---|" * (5 + len(RATES)),
    ]
    for r in rows:
        cells = [_fmt_ci(r["rate_" + key], r["rate_" + key + "_ci"], "{:.1f}" if key == "disguise" else "{:.3f}")
                 for key, _, _ in RATES]
        lines.append(f"| {r['scene']} | {r['n_uavs']} | {r['method']} | {r['runs']} | {r['uav_slots']} | "
                     + " | ".join(cells) + " |")
    lines += [
        "", "## Counts and planning time", "",
        "| scenes | U | method | UAV-slots | blocked LoS | blocked, unflagged | LoS lost between slot times | "
        "blocked along path | infeasible (flagged) | truncated | path length (m) | objective | min sep. (m) | "
        "sep. viol. | terrain viol. | speed viol. | team replan ms median / p90 | negotiation rounds | "
        "future conflicts left |",
        "|" + "---|" * 19,
    ]
    for r in rows:
        lines.append(
            f"| {r['scene']} | {r['n_uavs']} | {r['method']} | {r['uav_slots']} | {r['blocked']} | "
            f"{r['blocked_unflagged']} | {r['lost_between']} | {r['blocked_path']} | {r['infeasible']} | "
            f"{r['truncated']} | {r['path_length']:.0f} | {r['objective']:.0f} | {r['min_separation']:.2f} | "
            f"{r['separation_violations']} | {r['terrain_violations']} | {r['speed_violations']} | "
            f"{r['team_ms_median']:.0f} / {r['team_ms_p90']:.0f} | {r['rounds']} | {r['unresolved']} |")
    lines += ["", "## The paper's claims", ""]
    by = {(r["scene"], r["n_uavs"], r["method"]): r for r in rows}
    for scene in ("paper", "heldout"):
        for u in (1, 3):
            aw, bl = by.get((scene, u, "aware")), by.get((scene, u, "blind"))
            if aw is None or bl is None:
                continue
            ratio = aw["mean_disguise"] / bl["mean_disguise"] if bl["mean_disguise"] else float("nan")
            rci = disguise_ratio_ci(records, u) if scene == "heldout" else None
            ratio_txt = f"**{ratio:.2f}**" + (f" [{rci[1][0]:.2f}, {rci[1][1]:.2f}]" if rci else "")
            occ = _fmt_ci(bl["rate_occlusion"], bl["rate_occlusion_ci"])
            lines.append(
                f"- {scene}, {u} UAV{'s' if u > 1 else ''}: shadow-aware blocked-LoS UAV-slots on unflagged slots "
                f"= **{aw['blocked_unflagged']}** ({aw['infeasible']} slots flagged infeasible); shadow-blind blocked "
                f"= **{bl['blocked']}** of {bl['uav_slots']} (rate {occ}); "
                f"disguise aware / blind = {ratio_txt} "
                f"({'>= 0.8: holds' if ratio >= 0.8 else '< 0.8: does NOT hold'}).")
            lines.append(f"  - LoS lost between slot times (clear at the slot time, blocked along the manoeuvre): "
                         f"aware **{aw['lost_between']}** of {aw['uav_slots']} UAV-slots "
                         f"(rate {_fmt_ci(aw['rate_lost_between'], aw['rate_lost_between_ci'])}), "
                         f"blind {bl['lost_between']}.")
            ap = by.get((scene, u, "aware-path"))
            if ap is not None:
                lines.append(f"  - with check_path: blocked LoS along the flown path in "
                             f"**{ap['blocked_path_unflagged']}** unflagged UAV-slots ({ap['blocked_path']} in all, "
                             f"rate {_fmt_ci(ap['rate_blocked_path'], ap['rate_blocked_path_ci'])}; "
                             f"{ap['infeasible']} slots flagged), disguise {ap['mean_disguise']:.1f}.")
    lines += ["", "Columns: *blocked LoS* counts UAV-slots whose end position has no line of sight (the paper's "
              "I_LoS = 1); *unflagged* excludes slots the planner flagged infeasible (its fallback, see "
              "`baselines.dp`); *LoS lost between slot times*: clear at the slot's end but blocked at some sample "
              "of the manoeuvre; *along path* uses every sample of the manoeuvre, its end included "
              "(docs/model.md#metrics); *future "
              "conflicts left*: conflicts in later, not yet flown slots still present when the negotiation hit its "
              "round limit, summed over replans (the flown slot is always separated). Metric definitions: "
              "`covert_env.world.metrics.METRIC_DESCRIPTIONS`.", ""]
    if timing:
        lines += ["## Where the time went", "",
                  f"Runs (planner + metrics, {timing['jobs']} worker process{'es' if timing['jobs'] > 1 else ''}): "
                  f"{timing['runs_s']:.0f} s wall; summed over runs: planner and engine (the rollouts) "
                  f"{timing['planner_s']:.0f} s, metrics {timing['metrics_s']:.1f} s. Figures "
                  f"{timing['figures_s']:.0f} s wall. "
                  f"Choosing --quick's scenes {timing.get('choose_s', 0.0):.1f} s.", ""]
    if figures:
        lines += ["## Figures", ""] + [f"- `{f}`" for f in figures] + [""]
    return "\n".join(lines)


