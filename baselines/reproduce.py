"""Reproduce the paper's experiments: ``covert-env reproduce --out DIR`` (or ``python -m baselines.reproduce``).

Runs the paper's DP planner (:mod:`baselines.dp`) on the paper's defaults (Config(): N = 5, delta = 1 s,
V_max = 50 m/s, W_max = 3 rad/s, eta = 55, lambda = 10, 70 slots):

1. the paper scenario with 1 UAV (§3.1) and with 3 UAVs (§3.2), the shadow-aware planner (the paper's
   method, "aware") against the shadow-blind one (the earlier method [1], "blind");
2. both methods on 20 held-out random scenes (``Scenario.random(1_000_000 + i)``: terrain, road and
   starts), with 1 and 3 UAVs;
3. the shadow-aware planner with ``check_path=True`` ("aware-path") on the held-out scenes, which also
   keeps the line of sight between slot times (1 UAV by default; ``--path-uavs 1 3`` adds 3 UAVs).

Every run drives a :class:`covert_env.engine.Engine` exactly as the waypoint environment does (same
scenario, same lattice nodes as waypoints), and is scored by :func:`covert_env.metrics.episode_metrics`.

Outputs in ``--out``:

* ``fig08_trajectories_1uav.png`` ... ``fig15_disguise_3uav.png``: like the paper's Figs. 8-15 --
  trajectories (top view and 3D), the LoS occlusion index I_LoS per slot, the zones with shadows at one
  slot (feasible zone, visible zone, shadows, lattice nodes whose LoS is blocked), disguise kappa per slot;
* ``fig_heldout.png``: occlusion and disguise per held-out scene;
* ``metrics.json``: one record per run and UAV (episode metrics of docs/model.md#metrics, blocked-LoS counts,
  infeasible-slot counts, planning time, negotiation rounds);
* ``metrics.md``: aggregate tables and the paper's claims checked.

``--quick`` runs a tiny version for CI (2 held-out scenes, 12 slots). ``--jobs`` sets worker processes.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from baselines.dp import DPPlanner, DPTeamPlanner
from covert_env.config import Config
from covert_env.engine import Engine
from covert_env.metrics import episode_metrics, slot_quantities
from covert_env.scenario import Scenario

__all__ = ["HELDOUT_SEED_BASE", "METHODS", "RunSpec", "main", "make_scenario", "rollout", "run"]

#: Held-out scene seeds are HELDOUT_SEED_BASE + i (outside any training pool of the environments).
HELDOUT_SEED_BASE = 1_000_000
#: Planner settings of each compared method.
METHODS = {
    "aware": dict(shadow_aware=True),                      # the paper's method (eq. 10 zone)
    "blind": dict(shadow_aware=False),                     # the earlier method [1]
    "aware-path": dict(shadow_aware=True, check_path=True),  # + LoS and zone along every manoeuvre
}


@dataclass(frozen=True)
class RunSpec:
    """One episode: scene kind ("paper" or "random"), scene seed, team size, method (key of METHODS)."""

    kind: str
    seed: int
    n_uavs: int
    method: str
    n_slots: int = 70
    heading: str = "inherited"

    @property
    def label(self) -> str:
        scene = "paper" if self.kind == "paper" else f"seed{self.seed}"
        return f"{scene}-{self.n_uavs}uav-{self.method}"


def make_scenario(kind: str, seed: int, n_uavs: int, config: Config | None = None) -> Scenario:
    """The scene of a run, built as the environments build it (``config.n_uavs`` = ``n_uavs``)."""
    cfg = (config or Config()).replace(n_uavs=int(n_uavs))
    if kind == "paper":
        return Scenario.paper(cfg)
    return Scenario.random(int(seed), cfg)


def rollout(scenario: Scenario, *, shadow_aware: bool = True, heading: str = "inherited", heading_bins: int = 16,
            check_path: bool = False, max_rounds: int = 5, separation_margin: float = 0.5,
            n_slots: int | None = None) -> dict:
    """Fly the DP team planner through a scenario on an :class:`Engine` (one team replan per slot).

    This is what :class:`baselines.policies.DPPolicy` does through the waypoint environment; the first
    waypoint of every UAV's plan is handed to the engine, which flies the manoeuvre.

    Returns:
        dict with ``engine`` (finished), ``trajectory``, per-slot arrays ``team_time`` (s), ``rounds``,
        ``conflicts`` and ``status`` ((T, U) strings), and ``planner`` (the :class:`DPPlanner`).
    """
    planner = DPPlanner(scenario.config, scenario.terrain, shadow_aware=shadow_aware, heading=heading,
                        heading_bins=heading_bins, check_path=check_path)
    team = DPTeamPlanner(planner, max_rounds=max_rounds, separation_margin=separation_margin)
    eng = Engine(scenario)
    t_max = scenario.config.n_slots if n_slots is None else int(n_slots)
    times, rounds, conflicts, status = [], [], [], []
    while eng.k < t_max:
        plan = team.plan_engine(eng)
        u = len(plan.plans)
        eng.step(waypoints=plan.waypoints, infeasible=plan.infeasible, decision_time=np.full(u, plan.time / u))
        times.append(plan.time)
        rounds.append(plan.rounds)
        conflicts.append(plan.conflicts)
        status.append([p.status for p in plan.plans])
    return {"engine": eng, "trajectory": eng.trajectory(), "team_time": np.array(times),
            "rounds": np.array(rounds), "conflicts": np.array(conflicts), "status": np.array(status),
            "planner": planner}


def run(spec: RunSpec, config: Config | None = None) -> dict:
    """Run one :class:`RunSpec`; returns per-UAV records and the per-slot series the figures need."""
    # The scene is built for the config's full episode (its road length, hence its terrain, depends on
    # n_slots); a shorter run flies only the first spec.n_slots slots of the same scene.
    sc = make_scenario(spec.kind, spec.seed, spec.n_uavs, config)
    t0 = time.perf_counter()
    out = rollout(sc, heading=spec.heading, n_slots=spec.n_slots, **METHODS[spec.method])
    wall = time.perf_counter() - t0
    traj = out["trajectory"]
    q = slot_quantities(traj, sc.terrain, sc.config)
    metrics = episode_metrics(traj, sc.terrain, sc.config, q)
    tt = out["team_time"] * 1e3
    records = []
    for i, m in enumerate(metrics):
        st = out["status"][:, i]
        rec = {"run": spec.label, "scene": "paper" if spec.kind == "paper" else "heldout", "seed": spec.seed,
               "n_uavs": spec.n_uavs, "method": spec.method, "heading": spec.heading, "uav": i,
               "slots": int(traj.n_slots)}
        rec.update(m)
        rec.update({
            "blocked_slots": int((~q.los[:, i]).sum()),
            "blocked_unflagged": int((~q.los[:, i] & ~traj.infeasible[:, i]).sum()),
            "blocked_path_slots": int((~q.los_path[:, i]).sum()),
            "blocked_path_unflagged": int((~q.los_path[:, i] & ~traj.infeasible[:, i]).sum()),
            "truncated_slots": int((st == "truncated").sum()),
            "team_time_ms_median": float(np.median(tt)),
            "team_time_ms_p90": float(np.percentile(tt, 90)),
            "negotiation_rounds": int(out["rounds"].sum()),
            "unresolved_conflicts": int(out["conflicts"].sum()),
            "wall_s": wall,
        })
        records.append(rec)
    series = {"los": q.los, "los_path": q.los_path, "kappa": q.kappa, "infeasible": traj.infeasible,
              "uav_xy": traj.uav_xy, "target_xyz": traj.target_xyz, "path_xy": traj.path_xy}
    return {"spec": spec, "records": records, "series": series}


def _run_job(args):
    spec, cfg_dict = args
    res = run(spec, Config.from_dict(cfg_dict))
    # Paths are only needed for the paper runs' figures; keep the result small for the other runs.
    if spec.kind != "paper":
        res["series"] = {k: v for k, v in res["series"].items() if k in ("los", "kappa", "infeasible")}
    return res


# ===================================================================================== figures
def _figures(out: Path, results: dict, config: Config) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from covert_env.render import UAV_COLORS, draw_3d_view, draw_top_view, zones_at
    from covert_env.visibility import line_of_sight
    from covert_env.zone import to_world, zone_lattice

    written = []
    fig_no = {1: (8, 9, 10, 11), 3: (12, 13, 14, 15)}
    colors = {"aware": "tab:blue", "blind": "tab:red"}
    for u, (f_traj, f_los, f_zone, f_kap) in fig_no.items():
        aw = results.get(("paper", 0, u, "aware"))
        bl = results.get(("paper", 0, u, "blind"))
        if aw is None or bl is None:
            continue
        sc = make_scenario("paper", 0, u, config)
        k_end = aw["series"]["uav_xy"].shape[0] - 1

        # Figs. 8 / 12: trajectories, top view + 3D.
        fig = plt.figure(figsize=(16, 10))
        grid = fig.add_gridspec(2, 1, height_ratios=(1.2, 1.0))
        ax3 = fig.add_subplot(grid[0], projection="3d")
        ax2 = fig.add_subplot(grid[1])
        draw_3d_view(ax3, sc, k_end)
        draw_top_view(ax2, sc, k_end, legend=False)
        tq = aw["series"]["target_xyz"]
        ax2.plot(tq[:, 0], tq[:, 1], color="gold", lw=2, label="target track")
        ax3.plot(tq[:, 0], tq[:, 1], tq[:, 2], color="gold", lw=2)
        for name, res in (("aware", aw), ("blind", bl)):
            xy = res["series"]["uav_xy"]
            for i in range(u):
                ls = "-" if name == "aware" else "--"
                lab = f"{'shadow-aware (paper)' if name == 'aware' else 'shadow-blind [1]'}" + (
                    f" uav_{i}" if u > 1 else "")
                col = UAV_COLORS[i % len(UAV_COLORS)] if u > 1 else colors[name]
                ax2.plot(xy[:, i, 0], xy[:, i, 1], ls, color=col, lw=1.2, label=lab, alpha=0.9)
                ax3.plot(xy[:, i, 0], xy[:, i, 1], np.full(len(xy), config.altitude), ls, color=col, lw=1.0)
        lo = np.vstack([tq[:, :2], aw["series"]["uav_xy"].reshape(-1, 2)]).min(0) - 40
        hi = np.vstack([tq[:, :2], aw["series"]["uav_xy"].reshape(-1, 2)]).max(0) + 40
        ax2.set_xlim(lo[0], hi[0])
        ax2.set_ylim(lo[1], hi[1])
        ax2.set_title(f"trajectories over {k_end} slots (solid: shadow-aware, dashed: shadow-blind)")
        ax2.legend(loc="upper left", fontsize=7)
        fig.suptitle(f"Paper scenario, {u} UAV{'s' if u > 1 else ''}: trajectories (cf. Fig. {f_traj})")
        fig.tight_layout()
        written.append(_save(fig, out / f"fig{f_traj:02d}_trajectories_{u}uav.png"))

        # Figs. 9 / 13: LoS occlusion index per slot.
        fig, axes = plt.subplots(u, 1, figsize=(11, 2.2 * u + 0.8), squeeze=False, sharex=True)
        for i in range(u):
            ax = axes[i, 0]
            for name, res, off in (("blind", bl, 0.0), ("aware", aw, 0.04)):
                ilos = (~res["series"]["los"][:, i]).astype(float)
                ax.step(np.arange(1, len(ilos) + 1), ilos + off, where="mid", color=colors[name],
                        label=f"{'shadow-blind [1]' if name == 'blind' else 'shadow-aware (paper)'}: "
                              f"{int(ilos.sum())} blocked")
            ax.set_ylim(-0.15, 1.25)
            ax.set_yticks([0, 1])
            ax.set_ylabel(f"I_LoS uav_{i}" if u > 1 else "I_LoS")
            ax.legend(loc="upper right", fontsize=8)
        axes[-1, 0].set_xlabel("slot k")
        fig.suptitle(f"LoS occlusion index per slot (1 = blocked), {u} UAV{'s' if u > 1 else ''} (cf. Fig. {f_los})")
        fig.tight_layout()
        written.append(_save(fig, out / f"fig{f_los:02d}_los_{u}uav.png"))

        # Figs. 10 / 14: zones and shadows at the slot where the blind method's LoS is blocked most.
        blocked = (~bl["series"]["los"]).sum(axis=1)
        k = int(np.argmax(blocked)) + 1 if blocked.any() else k_end // 2
        fig, axes = plt.subplots(1, 2, figsize=(15, 7))
        lat = zone_lattice(config)
        q = sc.track.position(k)
        phi = float(sc.track.heading(k))
        nodes = to_world(lat, q[:2], phi)
        clear = line_of_sight(sc.terrain, nodes, config.altitude, q)
        for ax, (name, res) in zip(axes, (("blind", bl), ("aware", aw)), strict=True):
            draw_top_view(ax, sc, k, legend=False)
            ax.plot(*nodes[~clear].T, ".", color="red", ms=2.5, label="lattice nodes with LoS blocked")
            xy = res["series"]["uav_xy"]
            for i in range(u):
                ax.plot(xy[max(k - 5, 0):k + 1, i, 0], xy[max(k - 5, 0):k + 1, i, 1], "-", color=UAV_COLORS[i], lw=1)
                ok = bool(res["series"]["los"][k - 1, i])
                ax.plot(*xy[k, i], marker="^", ms=11, color=UAV_COLORS[i], mec="k" if ok else "red", mew=2,
                        ls="none", label=f"uav_{i} ({'LoS clear' if ok else 'LoS BLOCKED'})")
                ax.plot([xy[k, i, 0], q[0]], [xy[k, i, 1], q[1]], ":", color="green" if ok else "red", lw=1)
            zone, _, vis = zones_at(sc, k)
            ax.set_xlim(q[0] - 130, q[0] + 130)
            ax.set_ylim(q[1] - 130, q[1] + 130)
            what = ("shadow-blind [1]: plans in the feasible zone" if name == "blind"
                    else "shadow-aware (paper): plans in the visible zone")
            ax.set_title(f"{what}\nslot {k}: zone {zone.area:.0f} m², visible {vis.area:.0f} m²", fontsize=10)
            ax.legend(loc="upper left", fontsize=7)
        fig.suptitle(f"Feasible zone (black), shadows (red), visible zone (green) at slot {k} (cf. Fig. {f_zone})")
        fig.tight_layout()
        written.append(_save(fig, out / f"fig{f_zone:02d}_zones_{u}uav.png"))

        # Figs. 11 / 15: disguise per slot.
        fig, axes = plt.subplots(u, 1, figsize=(11, 2.4 * u + 0.8), squeeze=False, sharex=True)
        for i in range(u):
            ax = axes[i, 0]
            for name, res, ls in (("aware", aw, "-"), ("blind", bl, "--")):
                kap = res["series"]["kappa"][:, i]
                what = "shadow-aware (paper)" if name == "aware" else "shadow-blind [1]"
                ax.plot(np.arange(1, len(kap) + 1), kap, ls, color=colors[name], label=f"{what}: mean {kap.mean():.1f}")
            ax.set_ylabel(f"kappa uav_{i}" if u > 1 else "kappa")
            ax.legend(loc="upper right", fontsize=8)
        axes[-1, 0].set_xlabel("slot k")
        fig.suptitle(f"Disguise kappa = eta|d alpha| + |d d| per slot (eq. 11), {u} UAV{'s' if u > 1 else ''} "
                     f"(cf. Fig. {f_kap})")
        fig.tight_layout()
        written.append(_save(fig, out / f"fig{f_kap:02d}_disguise_{u}uav.png"))

    # Held-out scenes: per-scene occlusion and disguise.
    held = sorted({(s, u) for (kind, s, u, m) in results if kind == "random"})
    if held:
        seeds = sorted({s for s, _ in held})
        fig, axes = plt.subplots(2, 2, figsize=(15, 8), sharex=True)
        x = np.arange(len(seeds))
        for col, u in enumerate((1, 3)):
            methods = (("blind", "tab:red"), ("aware", "tab:blue"), ("aware-path", "tab:green"))
            for mi, (name, colr) in enumerate(methods):
                occ, kap = [], []
                for s in seeds:
                    r = results.get(("random", s, u, name))
                    occ.append(np.nan if r is None else (~r["series"]["los"]).mean())
                    kap.append(np.nan if r is None else r["series"]["kappa"].mean())
                axes[0, col].bar(x + (mi - 1) * 0.27, occ, 0.27, color=colr, label=name)
                axes[1, col].bar(x + (mi - 1) * 0.27, kap, 0.27, color=colr, label=name)
            axes[0, col].set_title(f"held-out scenes, {u} UAV{'s' if u > 1 else ''}: occlusion rate at slot times")
            axes[1, col].set_title("mean disguise kappa")
            axes[1, col].set_xticks(x, [str(s - HELDOUT_SEED_BASE) for s in seeds], fontsize=7)
            axes[1, col].set_xlabel(f"scene (seed - {HELDOUT_SEED_BASE})")
            axes[0, col].legend(fontsize=8)
        fig.tight_layout()
        written.append(_save(fig, out / "fig_heldout.png"))
    return written


def _save(fig, path: Path) -> str:
    import matplotlib.pyplot as plt

    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path.name


# ===================================================================================== tables
def _aggregate(records: list[dict]) -> list[dict]:
    """One row per (scene set, team size, method)."""
    rows = []
    keys = sorted({(r["scene"], r["n_uavs"], r["method"]) for r in records},
                  key=lambda t: (t[0] != "paper", t[1], list(METHODS).index(t[2])))
    for scene, u, method in keys:
        rs = [r for r in records if (r["scene"], r["n_uavs"], r["method"]) == (scene, u, method)]
        uav_slots = sum(r["slots"] for r in rs)
        rows.append({
            "scene": scene, "n_uavs": u, "method": method, "runs": len({r["run"] for r in rs}),
            "uav_slots": uav_slots,
            "blocked": sum(r["blocked_slots"] for r in rs),
            "blocked_unflagged": sum(r["blocked_unflagged"] for r in rs),
            "blocked_path": sum(r["blocked_path_slots"] for r in rs),
            "blocked_path_unflagged": sum(r["blocked_path_unflagged"] for r in rs),
            "infeasible": sum(r["infeasible_slots"] for r in rs),
            "truncated": sum(r["truncated_slots"] for r in rs),
            "occlusion_rate": float(np.mean([r["occlusion_rate"] for r in rs])),
            "zone_violation_rate": float(np.mean([r["zone_violation_rate"] for r in rs])),
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
        })
    return rows


def _markdown(rows: list[dict], config: Config, elapsed: float, quick: bool, figures: list[str],
              load: tuple[float, float]) -> str:
    lines = [
        "# covert-env reproduce: the paper's DP planner, shadow-aware vs shadow-blind",
        "",
        f"Config: paper defaults (N = {config.horizon}, delta = {config.delta:g} s, V_max = {config.v_max:g} m/s, "
        f"W_max = {config.w_max:g} rad/s, eta = {config.eta:g}, lambda = {config.lam:g}, grid {config.grid_step:g} m, "
        f"d_safe1 = {config.d_safe1:g} m){' -- QUICK run' if quick else ''}. Heading: inherited (the paper's DP).",
        "Methods: `aware` = the paper's method (visible zone, eq. 10); `blind` = the earlier method [1] "
        "(plain feasible zone); `aware-path` = aware + LoS and zone checked along every manoeuvre.",
        f"Total wall time {elapsed:.0f} s on {os.cpu_count()} CPUs (load average {load[0]:.1f} at start, "
        f"{load[1]:.1f} at the end: timings on a shared machine are upper bounds).",
        "",
        "| scenes | U | method | runs | UAV-slots | blocked LoS | blocked, unflagged | blocked along path | "
        "infeasible (flagged) | truncated | occlusion rate | zone viol. rate | mean disguise | path length (m) | "
        "objective | min sep. (m) | sep. viol. | terrain viol. | speed viol. | team replan ms median / p90 | "
        "negotiation rounds | future conflicts left |",
        "|" + "---|" * 22,
    ]
    for r in rows:
        lines.append(
            f"| {r['scene']} | {r['n_uavs']} | {r['method']} | {r['runs']} | {r['uav_slots']} | {r['blocked']} | "
            f"{r['blocked_unflagged']} | {r['blocked_path']} | {r['infeasible']} | {r['truncated']} | "
            f"{r['occlusion_rate']:.3f} | {r['zone_violation_rate']:.3f} | {r['mean_disguise']:.1f} | "
            f"{r['path_length']:.0f} | {r['objective']:.0f} | {r['min_separation']:.2f} | "
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
            lines.append(
                f"- {scene}, {u} UAV{'s' if u > 1 else ''}: shadow-aware blocked-LoS UAV-slots on unflagged slots "
                f"= **{aw['blocked_unflagged']}** ({aw['infeasible']} slots flagged infeasible); shadow-blind blocked "
                f"= **{bl['blocked']}** of {bl['uav_slots']}; disguise aware / blind = **{ratio:.2f}** "
                f"({'>= 0.8: holds' if ratio >= 0.8 else '< 0.8: does NOT hold'}).")
            ap = by.get((scene, u, "aware-path"))
            if ap is not None:
                lines.append(f"  - with check_path: blocked LoS along the flown path in "
                             f"**{ap['blocked_path_unflagged']}** unflagged UAV-slots ({ap['blocked_path']} in all; "
                             f"{ap['infeasible']} slots flagged), disguise {ap['mean_disguise']:.1f}.")
    lines += ["", "Columns: *blocked LoS* counts UAV-slots whose end position has no line of sight (the paper's "
              "I_LoS = 1); *unflagged* excludes slots the planner flagged infeasible (its fallback, see "
              "`baselines.dp`); *along path* uses the samples between slot times (docs/model.md#metrics); *future "
              "conflicts left*: conflicts in later, not yet flown slots still present when the negotiation hit its "
              "round limit, summed over replans (the flown slot is always separated). Metric definitions: "
              "`covert_env.metrics.METRIC_DESCRIPTIONS`.", ""]
    if figures:
        lines += ["## Figures", ""] + [f"- `{f}`" for f in figures] + [""]
    return "\n".join(lines)


# ===================================================================================== main
def build_parser(prog: str = "covert-env reproduce") -> argparse.ArgumentParser:
    from covert_env.cli import MAX_JOBS, MAX_SCENES, int_range, positive_int

    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n")[0])
    p.add_argument("--out", required=True, help="output folder (created)")
    p.add_argument("--quick", action="store_true", help="tiny CI version: 2 held-out scenes, 12 slots")
    p.add_argument("--scenes", type=int_range(0, MAX_SCENES), default=None,
                   help=f"number of held-out scenes, in [0, {MAX_SCENES}] (default: 20; with --quick 2)")
    p.add_argument("--slots", type=positive_int, default=None,
                   help="slots per episode, in [1, n_slots] (default: n_slots of the config, 70 with the paper's "
                        "parameters; with --quick 12)")
    p.add_argument("--jobs", type=int_range(1, MAX_JOBS), default=None,
                   help=f"worker processes, in [1, {MAX_JOBS}] (default: the number of CPUs, at most 2)")
    p.add_argument("--path-uavs", type=int, nargs="*", default=[1], choices=[1, 3],
                   help="team sizes of the check_path runs on the held-out scenes (default: 1; '1 3' adds the "
                        "3-UAV runs, about 40%% more time; none to skip)")
    p.add_argument("--heading", choices=("inherited", "binned"), default="inherited",
                   help="DP heading variant: inherited is the paper's (default: inherited)")
    p.add_argument("--config", default=None, help="a Config JSON file (default: the paper's parameters)")
    p.add_argument("--prediction-study", action="store_true",
                   help="also run baselines/prediction_study.py (prediction error vs r_u, eq. 5): "
                        "prediction_study.md and .json in --out")
    return p


def specs_for(n_scenes: int, n_slots: int, heading: str = "inherited", path_uavs=(1,)) -> list[RunSpec]:
    """The runs: paper scene and held-out scenes, 1 and 3 UAVs, aware and blind; aware-path for ``path_uavs``."""
    specs = [RunSpec("paper", 0, u, m, n_slots, heading) for u in (1, 3) for m in ("aware", "blind")]
    for i in range(n_scenes):
        for u in (1, 3):
            for m in ("aware", "blind") + (("aware-path",) if u in path_uavs else ()):
                specs.append(RunSpec("random", HELDOUT_SEED_BASE + i, u, m, n_slots, heading))
    return specs


def main(argv: list[str] | None = None, prog: str = "covert-env reproduce") -> int:
    from covert_env.cli import run_main

    parser = build_parser(prog)
    args = parser.parse_args(argv)
    return run_main(parser, lambda: _main(args))


def _main(args: argparse.Namespace) -> int:
    from covert_env.cli import UsageError, load_config, output_dir

    config = load_config(args.config) if args.config else Config()
    n_scenes = args.scenes if args.scenes is not None else (2 if args.quick else 20)
    n_slots = args.slots if args.slots is not None else (min(12, config.n_slots) if args.quick else config.n_slots)
    if not 1 <= n_slots <= config.n_slots:
        raise UsageError(f"--slots must be in [1, {config.n_slots}] (n_slots of the config), got {n_slots}")
    jobs = args.jobs if args.jobs is not None else min(os.cpu_count() or 1, 2)
    out = output_dir(args.out)
    specs = specs_for(n_scenes, n_slots, args.heading, path_uavs=tuple(args.path_uavs))
    # Longest runs first keeps both workers busy to the end.
    order = sorted(range(len(specs)), key=lambda i: (-specs[i].n_uavs, specs[i].method != "aware-path"))
    jobs_args = [(specs[i], config.to_dict()) for i in order]
    t0 = time.perf_counter()
    load0 = os.getloadavg()[0]
    results = {}
    bar = _progress(len(specs))
    if jobs > 1:
        import multiprocessing as mp
        import signal

        def _terminate(signum, frame):
            # Leaving the `with` block by an exception terminates the workers (a bare kill would orphan them).
            raise SystemExit(128 + signum)

        signal.signal(signal.SIGTERM, _terminate)
        with mp.get_context("spawn").Pool(jobs) as pool:
            for res in pool.imap_unordered(_run_job, jobs_args):
                _collect(results, res, bar)
    else:
        for a in jobs_args:
            _collect(results, _run_job(a), bar)
    bar.close()
    elapsed = time.perf_counter() - t0
    records = [_finite(r) for s in specs for r in results[(s.kind, s.seed, s.n_uavs, s.method)]["records"]]
    (out / "metrics.json").write_text(json.dumps({"config": config.to_dict(), "records": records}, indent=1,
                                                 default=_json_default) + "\n")
    figures = _figures(out, results, config)
    rows = _aggregate(records)
    (out / "metrics.md").write_text(_markdown(rows, config, elapsed, args.quick, figures,
                                              (load0, os.getloadavg()[0])))
    print(f"wrote {out}/metrics.json ({len(records)} records), metrics.md and {len(figures)} figures "
          f"in {elapsed:.0f} s", file=sys.stderr)
    print((out / "metrics.md").read_text().split("## The paper's claims")[1].split("Columns:")[0].strip())
    if args.prediction_study:
        from baselines.prediction_study import write_study

        print(write_study(out, config, quick=args.quick))
    return 0


def _progress(total: int):
    """A tqdm bar on stderr; a plain counter if tqdm is missing (it ships with the ``train`` extra)."""
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover
        class _Plain:
            n = 0

            def set_postfix_str(self, s):
                self.s = s

            def update(self, k):
                self.n += k
                print(f"reproduce: {self.n}/{total} runs ({self.s})", file=sys.stderr, flush=True)

            def close(self):
                pass

        return _Plain()
    return tqdm(total=total, desc="reproduce", unit="run", file=sys.stderr)


def _collect(results: dict, res: dict, bar) -> None:
    s = res["spec"]
    results[(s.kind, s.seed, s.n_uavs, s.method)] = res
    bar.set_postfix_str(s.label)
    bar.update(1)


def _finite(rec: dict) -> dict:
    """JSON has no inf/NaN: such values (e.g. min_separation of a lone UAV) become null."""
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in rec.items()}


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        v = float(o)
        return v if math.isfinite(v) else None
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
