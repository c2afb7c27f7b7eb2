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
  trajectories (a top view per method, a 3D view of the flown area, the positions in the target's frame),
  the LoS occlusion index I_LoS per slot, the zones with shadows at one slot (:func:`figure_slot`: where the
  shadow-blind method loses LoS for the most UAVs, else where the zone is most in shadow), disguise kappa per slot;
* ``fig_heldout.png``: occlusion and disguise per held-out scene, with the mean and its 95 % CI;
* ``fig_los_between_slots.png``: per held-out scene, UAV-slots whose LoS was clear at the slot time but lost
  along the manoeuvre before it (the paper checks slot times only);
* ``metrics.json``: one record per run and UAV (episode metrics of docs/model.md#metrics, blocked-LoS counts,
  infeasible-slot counts, planning time, negotiation rounds);
* ``metrics.md``: every rate with a 95 % percentile bootstrap confidence interval over the held-out scenes
  (:func:`bootstrap_ci`), counts, the paper's claims checked, and where the time went;
* ``sensitivity.md`` (``--sensitivity``): grid step, r_u, h_min and target speed varied one at a time;
* ``prediction_study.md``, ``.json`` and ``fig_prediction.png`` (``--prediction-study``): a prediction error of
  4 m, the planner with r_u = 0, with the eroded zone of eq. 5, and with it and the widened shadows
  (docs/decisions/model.md#prediction-los): zone violations and blocked LoS against the true target, with 95 % CIs
  (:mod:`baselines.prediction_study`).

``--quick`` flies the paper scene and 2 held-out scenes for 15 slots, chosen so that the paper's effects show:
the paper scene's zone is in shadow at slots 11-15 and the held-out scenes are the 2 of the first 20 whose zone is
most in shadow over those slots (:func:`most_shadowed_scenes`, geometry only). ``--jobs`` sets worker processes.
``covert-env animate --out docs/dp_team.gif`` (:func:`write_gif`) writes the README's animation.
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

from baselines.intervals import BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, bootstrap_ci
from baselines.prediction_study import write_study
from baselines.rollout import rollout
from covert_env.command_line import (
    MAX_JOBS,
    MAX_SCENES,
    UsageError,
    int_range,
    load_config,
    output_dir,
    positive_int,
    run_main,
)
from covert_env.config import Config
from covert_env.families import FAMILIES, HELD_OUT_SEEDS, family_config
from covert_env.metrics import episode_metrics, slot_quantities
from covert_env.render import (
    TERRAIN_COLOR,
    UAV_COLORS,
    draw_3d_view,
    draw_top_view,
    episode_frames,
    fill_geometry,
    outline_geometry,
    save_episode_gif,
    shadow_share,
    zones_at,
)
from covert_env.scenario import Scenario
from covert_env.visibility import visible_nodes
from covert_env.zone import feasible_zone, to_world, zone_lattice

__all__ = ["HELDOUT_SEED_BASE", "METHODS", "RunSpec", "bootstrap_ci", "figure_slot", "main", "make_scenario",
           "most_shadowed_scenes", "rollout", "run", "run_pairs", "write_gif", "zone_shadow_shares"]

#: Held-out scene seeds are HELDOUT_SEED_BASE + i (outside any training pool of the environments).
HELDOUT_SEED_BASE = HELD_OUT_SEEDS.start
#: Planner settings of each compared method.
METHODS = {
    "aware": dict(shadow_aware=True),                      # the paper's method (eq. 10 zone)
    "blind": dict(shadow_aware=False),                     # the earlier method [1]
    "aware-path": dict(shadow_aware=True, check_path=True),  # + LoS and zone along every manoeuvre
}


@dataclass(frozen=True)
class RunSpec:
    """One episode: scene kind ("paper" or "random"), scene seed, team size, method (key of METHODS); a random
    scene of scene family ``family`` (:mod:`covert_env.families`; None: the config as given)."""

    kind: str
    seed: int
    n_uavs: int
    method: str
    n_slots: int = 70
    heading: str = "inherited"
    family: str | None = None

    @property
    def label(self) -> str:
        scene = "paper" if self.kind == "paper" else f"seed{self.seed}"
        return f"{scene}-{self.n_uavs}uav-{self.method}"


def make_scenario(kind: str, seed: int, n_uavs: int, config: Config | None = None,
                  family: str | None = None) -> Scenario:
    """The scene of a run, built as the environments build it (``config.n_uavs`` = ``n_uavs``): the paper's, or a
    random one (of scene family ``family`` if given; the paper scene is always the paper's)."""
    cfg = (config or Config()).replace(n_uavs=int(n_uavs))
    if kind == "paper":
        return Scenario.paper(cfg)
    return Scenario.random(int(seed), cfg if family is None else family_config(family, cfg))


#: ``--quick``: slots per episode (the paper scene's zone is in shadow at slots 11-15), number of held-out
#: scenes, and the pool (the full job's first scenes) they are chosen from by :func:`most_shadowed_scenes`.
QUICK_SLOTS = 15
QUICK_SCENES = 2
QUICK_POOL = 20
#: Percentile bootstrap over scenes: resamples and seed (fixed: metrics.md is reproducible).
def zone_shadow_shares(scenario: Scenario, slots) -> np.ndarray:
    """Share of the feasible zone in shadow at each of ``slots`` (:func:`covert_env.render.shadow_share`)."""
    return np.array([shadow_share(scenario, int(k)) for k in slots])


def most_shadowed_scenes(n: int, n_slots: int, config: Config | None = None, pool: int = QUICK_POOL,
                         n_uavs: int = 1, family: str | None = None) -> list[int]:
    """``--quick``'s held-out scenes: the ``n`` seeds among the first ``pool`` held-out scenes whose feasible
    zone is most in shadow, on average over slots 1..``n_slots`` (ties: lower seed). Purely geometric (no
    planner run), so the choice is deterministic and cheap; a zone in shadow is where the shadow-blind planner
    can lose the line of sight. Returned in seed order."""
    config = config or Config()
    share = [zone_shadow_shares(make_scenario("random", HELDOUT_SEED_BASE + i, n_uavs, config, family),
                                range(1, n_slots + 1)).mean() for i in range(pool)]
    best = sorted(range(pool), key=lambda i: (-share[i], i))[:n]
    return sorted(HELDOUT_SEED_BASE + i for i in best)


def figure_slot(blind_los: np.ndarray, shares: np.ndarray) -> int:
    """The slot k (1-based) that figs. 10/14 show: where the shadow-blind planner's LoS is blocked for the most
    UAVs, ties broken by the larger share of the zone in shadow; with no blocked slot, the most shadowed slot.

    Args:
        blind_los: (T, U) LoS of the shadow-blind run at slot times 1..T.
        shares: (T,) share of the zone in shadow at slots 1..T.
    """
    blocked = (~np.asarray(blind_los, bool)).sum(axis=1)
    order = np.lexsort((-np.asarray(shares), -blocked))    # last key first: most blocked, then most shadow
    return int(order[0]) + 1


def run(spec: RunSpec, config: Config | None = None) -> dict:
    """Run one :class:`RunSpec`; returns per-UAV records and the per-slot series the figures need."""
    # The scene is built for the config's full episode (its road length, hence its terrain, depends on
    # n_slots); a shorter run flies only the first spec.n_slots slots of the same scene.
    sc = make_scenario(spec.kind, spec.seed, spec.n_uavs, config, spec.family)
    t0 = time.perf_counter()
    out = rollout(sc, heading=spec.heading, n_slots=spec.n_slots, **METHODS[spec.method])
    wall = time.perf_counter() - t0
    traj = out["trajectory"]
    t1 = time.perf_counter()
    q = slot_quantities(traj, sc.terrain, sc.config)
    metrics = episode_metrics(traj, sc.terrain, sc.config, q)
    metrics_s = time.perf_counter() - t1
    tt = out["team_time"] * 1e3
    records = []
    for i, m in enumerate(metrics):
        st = out["status"][:, i]
        rec = {"run": spec.label, "scene": "paper" if spec.kind == "paper" else "heldout", "seed": spec.seed,
               "family": None if spec.kind == "paper" else spec.family, "n_uavs": spec.n_uavs,
               "method": spec.method, "heading": spec.heading, "uav": i,
               "slots": int(traj.n_slots)}
        rec.update(m)
        rec.update({
            "blocked_slots": int((~q.los[:, i]).sum()),
            "blocked_unflagged": int((~q.los[:, i] & ~traj.infeasible[:, i]).sum()),
            "blocked_path_slots": int((~q.los_path[:, i]).sum()),
            "blocked_path_unflagged": int((~q.los_path[:, i] & ~traj.infeasible[:, i]).sum()),
            # Clear at the slot time but blocked somewhere along the manoeuvre before it.
            "lost_between_slots": int((q.los[:, i] & ~q.los_path[:, i]).sum()),
            "truncated_slots": int((st == "truncated").sum()),
            "team_time_ms_median": float(np.median(tt)),
            "team_time_ms_p90": float(np.percentile(tt, 90)),
            "negotiation_rounds": int(out["rounds"].sum()),
            "unresolved_conflicts": int(out["conflicts"].sum()),
            "wall_s": wall,
        })
        records.append(rec)
    series = {"los": q.los, "los_path": q.los_path, "kappa": q.kappa, "infeasible": traj.infeasible,
              "uav_xy": traj.uav_xy, "target_xyz": traj.target_xyz, "target_phi": traj.target_phi}
    return {"spec": spec, "records": records, "series": series,
            "timing": {"rollout_s": wall, "metrics_s": metrics_s}}


def _run_job(args):
    spec, cfg_dict = args
    res = run(spec, Config.from_dict(cfg_dict))
    # Paths are only needed for the paper runs' figures; keep the result small for the other runs.
    if spec.kind != "paper":
        res["series"] = {k: v for k, v in res["series"].items() if k in ("los", "los_path", "kappa", "infeasible")}
    return res


# ===================================================================================== figures
NAMES = {"aware": "shadow-aware (paper)", "blind": "shadow-blind [1]", "aware-path": "aware + path check"}
COLORS = {"aware": "tab:blue", "blind": "tab:red", "aware-path": "tab:green"}


def _target_frame(xy: np.ndarray, q: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """UAV positions (T, U, 2) in the target's frame at the same slots (x along the target's heading)."""
    d = xy - q[:, None, :2]
    c, s = np.cos(phi)[:, None], np.sin(phi)[:, None]
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)


def _fig_trajectories(plt, sc: Scenario, aw: dict, bl: dict, u: int, fig_no: int, config: Config):
    """Figs. 8 / 12: top views (one per method), a cropped 3D view and the positions in the target's frame."""
    k_end = aw["series"]["uav_xy"].shape[0] - 1
    tq = aw["series"]["target_xyz"]
    pts = np.vstack([tq[:, :2]] + [r["series"]["uav_xy"].reshape(-1, 2) for r in (aw, bl)])
    lo, hi = pts.min(0) - 30, pts.max(0) + 30
    fig = plt.figure(figsize=(13, 11))
    grid = fig.add_gridspec(3, 2, height_ratios=(1, 1, 1.5), width_ratios=(1.25, 1))
    road = sc.road.points
    for row, (name, res) in enumerate((("aware", aw), ("blind", bl))):
        ax = fig.add_subplot(grid[row, :])
        for p in sc.terrain:
            fill_geometry(ax, p.footprint, color=TERRAIN_COLOR, alpha=0.8, lw=0)
        ax.plot(road[:, 0], road[:, 1], color="0.35", lw=0.8, ls="--")
        ax.plot(tq[:, 0], tq[:, 1], color="gold", lw=3, alpha=0.9, label="target track")
        xy = res["series"]["uav_xy"]
        los = res["series"]["los"]
        for i in range(u):
            col = UAV_COLORS[i % len(UAV_COLORS)]
            ax.plot(xy[:, i, 0], xy[:, i, 1], "-", color=col, lw=0.9, alpha=0.85, label=f"uav_{i}")
            ax.plot(xy[0, i, 0], xy[0, i, 1], "o", color=col, mec="k", ms=6)
        bad = np.argwhere(~los)                              # (slot - 1, uav) pairs
        ax.plot(xy[bad[:, 0] + 1, bad[:, 1], 0], xy[bad[:, 0] + 1, bad[:, 1], 1], "x", color="red", ms=7, mew=2,
                label="LoS blocked at slot time")
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal", adjustable="box")
        ax.set_ylabel("y (m)")
        ax.set_title(f"{NAMES[name]}: {u} UAV{'s' if u > 1 else ''} over {k_end} slots "
                     f"({int((~los).sum())} UAV-slots with LoS blocked; o = start)", fontsize=10)
        ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
        if row == 1:
            ax.set_xlabel("x (m)")
    ax3 = fig.add_subplot(grid[2, 0], projection="3d")
    draw_3d_view(ax3, sc, k_end, extent=(lo, hi))
    ax3.plot(tq[:, 0], tq[:, 1], tq[:, 2], color="gold", lw=2)
    for i in range(u):
        xy = aw["series"]["uav_xy"]
        ax3.plot(xy[:, i, 0], xy[:, i, 1], np.full(len(xy), config.altitude), color=UAV_COLORS[i % len(UAV_COLORS)],
                 lw=0.8)
    ax3.set_title("3D, shadow-aware (paper)", fontsize=10)
    ax = fig.add_subplot(grid[2, 1])
    outline_geometry(ax, feasible_zone((0.0, 0.0), 0.0, config.r1, config.r2, config.mu, 0.0), color="k", lw=1.2,
             label="feasible zone (eq. 4)")
    if config.r_u > 0:
        outline_geometry(ax, feasible_zone((0.0, 0.0), 0.0, config.r1, config.r2, config.mu, config.r_u), color="k",
                 lw=0.8, ls=":", label=f"eroded by r_u = {config.r_u:g} m (eq. 5)")
    for name, res, mk in (("aware", aw, "o"), ("blind", bl, "x")):
        rel = _target_frame(res["series"]["uav_xy"][1:], tq[1:], np.asarray(aw["series"]["target_phi"][1:]))
        for i in range(u):
            ax.plot(rel[:, i, 0], rel[:, i, 1], mk, color=UAV_COLORS[i % len(UAV_COLORS)], ms=3.5, alpha=0.6,
                    mfc="none" if mk == "o" else None, label=f"{NAMES[name]}" if i == 0 else None)
    ax.plot(0, 0, "*", color="gold", mec="k", ms=14, label="target")
    ax.set_aspect("equal")
    ax.set_xlabel("ahead of the target (m)")
    ax.set_ylabel("left of the target (m)", labelpad=0)
    ax.set_title("UAV positions at slot times in the target's frame", fontsize=10)
    ax.legend(loc="upper right", fontsize=7)
    fig.suptitle(f"Paper scenario, {u} UAV{'s' if u > 1 else ''}: trajectories (cf. Fig. {fig_no}); "
                 f"colours: UAVs", fontsize=12)
    fig.tight_layout()
    fig.subplots_adjust(wspace=0.3)
    return fig


def _fig_los(plt, aw: dict, bl: dict, u: int, fig_no: int):
    """Figs. 9 / 13: the LoS occlusion index per slot; the legend beside the axes."""
    fig, axes = plt.subplots(u, 1, figsize=(12, 1.9 * u + 1.0), squeeze=False, sharex=True)
    for i in range(u):
        ax = axes[i, 0]
        for name, res, off in (("blind", bl, 0.0), ("aware", aw, 0.04)):
            ilos = (~res["series"]["los"][:, i]).astype(float)
            ax.step(np.arange(1, len(ilos) + 1), ilos + off, where="mid", color=COLORS[name],
                    label=f"{NAMES[name]}: {int(ilos.sum())} blocked")
        ax.set_ylim(-0.15, 1.2)
        ax.set_yticks([0, 1])
        ax.set_ylabel(f"I_LoS uav_{i}" if u > 1 else "I_LoS")
        ax.legend(loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=8)
    axes[-1, 0].set_xlabel("slot k")
    fig.suptitle(f"LoS occlusion index per slot (1 = blocked), {u} UAV{'s' if u > 1 else ''} (cf. Fig. {fig_no})")
    fig.tight_layout()
    return fig


def _fig_zones(plt, sc: Scenario, aw: dict, bl: dict, u: int, fig_no: int, config: Config):
    """Figs. 10 / 14: both methods at the slot of :func:`figure_slot`, zoomed on the zone."""
    t = bl["series"]["los"].shape[0]
    shares = zone_shadow_shares(sc, range(1, t + 1))
    k = figure_slot(bl["series"]["los"], shares)
    q = sc.track.position(k)
    phi = float(sc.track.heading(k))
    nodes = to_world(zone_lattice(config), q[:2], phi)
    clear = visible_nodes(sc.terrain, zone_lattice(config), q, phi, config.altitude)
    center = q[:2] - 0.5 * config.r2 * np.array([math.cos(phi), math.sin(phi)])
    zone, _, vis = zones_at(sc, k)
    fig, axes = plt.subplots(1, 2, figsize=(13, 7.2))
    for ax, (name, res) in zip(axes, (("blind", bl), ("aware", aw)), strict=True):
        xy = res["series"]["uav_xy"]
        draw_top_view(ax, sc, k, xy[k], trails=xy[max(k - 4, 0):k + 1].swapaxes(0, 1), legend=False,
                      los_lines=True, radius=0.72 * config.r2, center=center)
        ax.plot(*nodes[~clear].T, ".", color="darkred", ms=1.5, label="lattice nodes with LoS blocked")
        blocked = [i for i in range(u) if not res["series"]["los"][k - 1, i]]
        for i in blocked:
            ax.plot(*xy[k, i], "o", ms=16, mfc="none", mec="red", mew=2)
        what = ("shadow-blind [1]: plans in the feasible zone" if name == "blind"
                else "shadow-aware (paper): plans in the visible zone")
        ax.set_title(f"{what}\n{len(blocked)} of {u} UAV{'s' if u > 1 else ''} with LoS blocked "
                     f"({', '.join(f'uav_{i}' for i in blocked) or 'none'})", fontsize=10)
    h, lab = axes[0].get_legend_handles_labels()
    h2, lab2 = axes[1].get_legend_handles_labels()
    keep = dict(zip(lab + lab2, h + h2, strict=True))
    fig.legend(keep.values(), keep.keys(), loc="lower center", ncol=6, fontsize=8)
    fig.suptitle(f"Slot {k}: feasible zone {zone.area:.0f} m², {100 * shares[k - 1]:.0f} % of it in shadow (solid "
                 f"red), visible zone {vis.area:.0f} m² (green); lines: LoS (green clear, red blocked) "
                 f"(cf. Fig. {fig_no})", fontsize=11)
    fig.tight_layout(rect=(0, 0.09, 1, 0.96))
    return fig


def _fig_disguise(plt, aw: dict, bl: dict, u: int, fig_no: int):
    """Figs. 11 / 15: disguise kappa per slot."""
    fig, axes = plt.subplots(u, 1, figsize=(12, 2.2 * u + 1.0), squeeze=False, sharex=True)
    for i in range(u):
        ax = axes[i, 0]
        for name, res, ls in (("aware", aw, "-"), ("blind", bl, "--")):
            kap = res["series"]["kappa"][:, i]
            ax.plot(np.arange(1, len(kap) + 1), kap, ls, color=COLORS[name], label=f"{NAMES[name]}: "
                    f"mean {kap.mean():.1f}")
        ax.set_ylabel(f"kappa uav_{i}" if u > 1 else "kappa")
        ax.legend(loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=8)
    axes[-1, 0].set_xlabel("slot k")
    fig.suptitle(f"Disguise kappa = eta|d alpha| + |d d| per slot (eq. 11), {u} UAV{'s' if u > 1 else ''} "
                 f"(cf. Fig. {fig_no})")
    fig.tight_layout()
    return fig


def _per_scene_bars(ax, seeds, results, u, methods, value, fmt="{:.3f}", ci=True):
    """Grouped bars per held-out scene; a marker on every value so that 0 shows (missing runs: none)."""
    methods = [m for m in methods if any(results.get(("random", s, u, m)) is not None for s in seeds)]
    x = np.arange(len(seeds))
    w = 0.8 / max(len(methods), 1)
    for mi, name in enumerate(methods):
        vals = np.array([np.nan if (r := results.get(("random", s, u, name))) is None else value(r) for s in seeds])
        ok = np.isfinite(vals)
        if not ok.any():
            continue
        pos = x + (mi - (len(methods) - 1) / 2) * w
        ax.bar(pos[ok], vals[ok], w, color=COLORS[name], alpha=0.8)
        lab = f"{NAMES[name]}: mean {fmt.format(vals[ok].mean())}"
        if ci and ok.sum() > 1:
            lo, hi = bootstrap_ci(vals[ok])
            lab += f" [{fmt.format(lo)}, {fmt.format(hi)}]"
        ax.plot(pos[ok], vals[ok], "o", color=COLORS[name], mec="k", mew=0.6, ms=4, clip_on=False, zorder=3)
        ax.plot([], [], "s", color=COLORS[name], label=lab)
    ax.set_xticks(x, [str(s - HELDOUT_SEED_BASE) for s in seeds], fontsize=7)
    ax.set_xlim(-0.6, len(seeds) - 0.4)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(0.0, -0.16), ncol=1, frameon=False)


def _fig_heldout(plt, results: dict):
    seeds = sorted({s for (kind, s, _, _) in results if kind == "random"})
    sizes = sorted({u for (kind, _, u, _) in results if kind == "random"})
    fig, axes = plt.subplots(2, len(sizes), figsize=(7.5 * len(sizes), 9.5), squeeze=False)
    methods = ("blind", "aware", "aware-path")
    for col, u in enumerate(sizes):
        _per_scene_bars(axes[0, col], seeds, results, u, methods, lambda r: float((~r["series"]["los"]).mean()))
        axes[0, col].set_ylabel("occlusion rate (share of UAV-slots\nwith LoS blocked at slot times)")
        axes[0, col].set_title(f"held-out scenes, {u} UAV{'s' if u > 1 else ''}: occlusion rate", fontsize=10)
        _per_scene_bars(axes[1, col], seeds, results, u, methods, lambda r: float(r["series"]["kappa"].mean()),
                        fmt="{:.1f}")
        axes[1, col].set_ylabel("mean disguise kappa per UAV-slot")
        axes[1, col].set_title(f"held-out scenes, {u} UAV{'s' if u > 1 else ''}: mean disguise", fontsize=10)
        for ax in axes[:, col]:
            ax.set_xlabel(f"scene (seed - {HELDOUT_SEED_BASE}); dot = the value (also when 0)", fontsize=8)
    fig.suptitle("Held-out scenes per scene; legend: mean over scenes [95 % bootstrap CI]")
    fig.tight_layout()
    return fig


def _fig_los_between(plt, results: dict):
    """LoS lost between slot times (clear at both slot times, blocked along the manoeuvre), per held-out scene."""
    seeds = sorted({s for (kind, s, _, _) in results if kind == "random"})
    sizes = sorted({u for (kind, _, u, _) in results if kind == "random"})
    fig, axes = plt.subplots(len(sizes), 1, figsize=(12, 4.2 * len(sizes)), squeeze=False)
    for row, u in enumerate(sizes):
        ax = axes[row, 0]

        def lost(r):
            s = r["series"]
            return float((s["los"] & ~s["los_path"]).sum())

        _per_scene_bars(ax, seeds, results, u, ("blind", "aware", "aware-path"), lost, fmt="{:.1f}")
        n = {m: sum(lost(r) for (kind, _, uu, mm), r in results.items() if kind == "random" and uu == u and mm == m)
             for m in ("blind", "aware", "aware-path")
             if any(kind == "random" and uu == u and mm == m for (kind, _, uu, mm) in results)}
        slots = sum(r["series"]["los"].size for (kind, _, uu, mm), r in results.items()
                    if kind == "random" and uu == u and mm == "aware")
        from matplotlib.ticker import MaxNLocator

        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_ylabel("UAV-slots with LoS lost\nbetween slot times")
        ax.set_title(f"held-out scenes, {u} UAV{'s' if u > 1 else ''}: LoS clear at the slot time but lost along "
                     f"the manoeuvre before it, of {slots} UAV-slots: "
                     + "; ".join(f"{NAMES[m]} {v:.0f}" for m, v in n.items()), fontsize=9)
        ax.set_xlabel(f"scene (seed - {HELDOUT_SEED_BASE}); dot = the value (also when 0)", fontsize=8)
    fig.suptitle("LoS lost between slot times (the paper checks LoS at slot times only); legend: mean per scene "
                 "[95 % bootstrap CI]", fontsize=11)
    fig.tight_layout()
    return fig


def _figure_tasks(out: Path, results: dict, config: Config) -> list[tuple]:
    """One task per figure: (kind, output path, the results it needs, config). Small enough to pickle."""
    tasks = []
    for u, nos in PAPER_FIGURES.items():
        aw = results.get(("paper", 0, u, "aware"))
        bl = results.get(("paper", 0, u, "blind"))
        if aw is None or bl is None:
            continue
        pair = {"aware": aw["series"], "blind": bl["series"], "u": u}
        for kind, no in zip(PAPER_FIGURE_KINDS, nos, strict=True):
            tasks.append((kind, out / f"fig{no:02d}_{kind}_{u}uav.png", dict(pair, no=no), config.to_dict()))
    held = {key: {"series": r["series"]} for key, r in results.items() if key[0] == "random"}
    if held:
        tasks.append(("heldout", out / "fig_heldout.png", held, config.to_dict()))
        tasks.append(("between", out / "fig_los_between_slots.png", held, config.to_dict()))
    return tasks


#: The paper's figure numbers per team size, in the order of :data:`PAPER_FIGURE_KINDS`.
PAPER_FIGURES = {1: (8, 9, 10, 11), 3: (12, 13, 14, 15)}
PAPER_FIGURE_KINDS = ("trajectories", "los", "zones", "disguise")


def output_files(args: argparse.Namespace) -> tuple[str, ...]:
    """The files :func:`main` writes into ``--out`` with these arguments (checked before the runs: a folder in
    the place of one is an error)."""
    names = ["metrics.json", "metrics.md"]
    if not args.no_figures:
        names += [f"fig{no:02d}_{kind}_{u}uav.png" for u, nos in PAPER_FIGURES.items()
                  for kind, no in zip(PAPER_FIGURE_KINDS, nos, strict=True)]
        names += ["fig_heldout.png", "fig_los_between_slots.png"]
    if args.sensitivity:
        names.append("sensitivity.md")
    if args.prediction_study:
        names += ["prediction_study.md", "prediction_study.json"] + ([] if args.no_figures else ["fig_prediction.png"])
    return tuple(names)


def _draw(task) -> str:
    """Draw and save one figure task of :func:`_figure_tasks` (in a worker process or not)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kind, path, data, cfg_dict = task
    config = Config.from_dict(cfg_dict)
    if kind in ("heldout", "between"):
        fig = (_fig_heldout if kind == "heldout" else _fig_los_between)(plt, data)
    else:
        u, no = data["u"], data["no"]
        aw, bl = {"series": data["aware"]}, {"series": data["blind"]}
        if kind == "trajectories":
            fig = _fig_trajectories(plt, make_scenario("paper", 0, u, config), aw, bl, u, no, config)
        elif kind == "zones":
            fig = _fig_zones(plt, make_scenario("paper", 0, u, config), aw, bl, u, no, config)
        elif kind == "los":
            fig = _fig_los(plt, aw, bl, u, no)
        else:
            fig = _fig_disguise(plt, aw, bl, u, no)
    return _save(fig, path)


def _figures(out: Path, results: dict, config: Config, jobs: int = 1) -> list[str]:
    """Write every figure (``jobs`` worker processes); returns the file names in figure order."""
    tasks = _figure_tasks(out, results, config)
    if jobs > 1 and len(tasks) > 1:
        import multiprocessing as mp

        # Slowest first (the trajectory and zone figures draw terrain and shadows).
        order = sorted(range(len(tasks)), key=lambda i: tasks[i][0] not in ("trajectories", "zones"))
        with mp.get_context("spawn").Pool(min(jobs, len(tasks))) as pool:
            names = pool.map(_draw, [tasks[i] for i in order], chunksize=1)
        by_index = dict(zip(order, names, strict=True))
        return [by_index[i] for i in range(len(tasks))]
    return [_draw(t) for t in tasks]


def _save(fig, path: Path) -> str:
    import matplotlib.pyplot as plt

    fig.savefig(path, dpi=90, bbox_inches="tight")
    plt.close(fig)
    return path.name


# ===================================================================================== tables
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


def _aggregate(records: list[dict]) -> list[dict]:
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


def _markdown(rows: list[dict], records: list[dict], config: Config, elapsed: float, quick: bool,
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
        lines.append(f"Held-out scenes of scene family {', '.join(families)} (covert_env.families); the paper scene "
                     "is the paper's.")
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
              "`covert_env.metrics.METRIC_DESCRIPTIONS`.", ""]
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


# ===================================================================================== main
def build_parser(prog: str = "covert-env reproduce") -> argparse.ArgumentParser:

    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n")[0])
    p.add_argument("--out", required=True, help="output folder (created)")
    p.add_argument("--quick", action="store_true",
                   help=f"small version ({QUICK_SLOTS} slots, {QUICK_SCENES} held-out scenes) where the paper's "
                        f"effects show: the held-out scenes are the ones of the first {QUICK_POOL} whose zone is "
                        "most in shadow")
    p.add_argument("--scenes", type=int_range(0, MAX_SCENES), default=None,
                   help=f"number of held-out scenes, in [0, {MAX_SCENES}] (default: 20; with --quick "
                        f"{QUICK_SCENES}, at most {QUICK_POOL})")
    p.add_argument("--slots", type=positive_int, default=None,
                   help="slots per episode, in [1, n_slots] (default: n_slots of the config, 70 with the paper's "
                        f"parameters; with --quick {QUICK_SLOTS})")
    p.add_argument("--jobs", type=int_range(1, MAX_JOBS), default=None,
                   help=f"worker processes, in [1, {MAX_JOBS}] (default: the number of CPUs, at most 2)")
    p.add_argument("--path-uavs", type=int, nargs="*", default=[1], choices=[1, 3],
                   help="team sizes of the check_path runs on the held-out scenes (default: 1; '1 3' adds the "
                        "3-UAV runs, about 40%% more time; none to skip)")
    p.add_argument("--heading", choices=("inherited", "binned"), default="inherited",
                   help="DP heading variant: inherited is the paper's (default: inherited)")
    p.add_argument("--config", default=None, help="a Config JSON file (default: the paper's parameters)")
    p.add_argument("--family", choices=list(FAMILIES), default=None,
                   help="scene family (covert_env.families) of the held-out scenes; the paper scene stays the "
                        "paper's (default: the config's generator fields, which are the paper family's unless "
                        "--config changes them)")
    p.add_argument("--prediction-study", action="store_true",
                   help="also run baselines/prediction_study.py (prediction error b = 4 m: r_u = 0 vs the eroded "
                        "zone of eq. 5 with and without widened shadows, 3 UAVs; blocked LoS and zone violations "
                        "against the true target with 95%% CIs): prediction_study.md and .json in --out")
    p.add_argument("--sensitivity", action="store_true",
                   help="also write sensitivity.md: aware vs blind, 1 UAV, on the "
                        f"{SENSITIVITY_SCENES} most shadowed held-out scenes, {SENSITIVITY_SLOTS} slots, varying "
                        "grid step, r_u, h_min and target speed one at a time")
    p.add_argument("--no-figures", action="store_true", help="skip the figures (metrics only)")
    return p


def specs_for(scenes, n_slots: int, heading: str = "inherited", path_uavs=(1,),
              family: str | None = None) -> list[RunSpec]:
    """The runs: paper scene and held-out scenes, 1 and 3 UAVs, aware and blind; aware-path for ``path_uavs``.

    ``scenes``: a number n (seeds HELDOUT_SEED_BASE + 0..n-1) or the held-out seeds themselves; ``family``: the
    held-out scenes' scene family."""
    seeds = [HELDOUT_SEED_BASE + i for i in range(scenes)] if isinstance(scenes, int) else list(scenes)
    specs = [RunSpec("paper", 0, u, m, n_slots, heading) for u in (1, 3) for m in ("aware", "blind")]
    for seed in seeds:
        for u in (1, 3):
            for m in ("aware", "blind") + (("aware-path",) if u in path_uavs else ()):
                specs.append(RunSpec("random", seed, u, m, n_slots, heading, family))
    return specs


def main(argv: list[str] | None = None, prog: str = "covert-env reproduce") -> int:

    parser = build_parser(prog)
    args = parser.parse_args(argv)
    return run_main(parser, lambda: _main(args))


def _main(args: argparse.Namespace) -> int:

    config = load_config(args.config) if args.config is not None else Config()
    n_scenes = args.scenes if args.scenes is not None else (QUICK_SCENES if args.quick else 20)
    n_slots = args.slots if args.slots is not None else (min(QUICK_SLOTS, config.n_slots) if args.quick
                                                          else config.n_slots)
    if not 1 <= n_slots <= config.n_slots:
        raise UsageError(f"--slots must be in [1, {config.n_slots}] (n_slots of the config), got {n_slots}")
    if args.quick and n_scenes > QUICK_POOL:
        raise UsageError(f"--scenes must be in [0, {QUICK_POOL}] with --quick (chosen among the first "
                         f"{QUICK_POOL} held-out scenes), got {n_scenes}")
    jobs = args.jobs if args.jobs is not None else min(os.cpu_count() or 1, 2)
    out = output_dir(args.out, files=output_files(args))
    t0 = time.perf_counter()
    load0 = os.getloadavg()[0]
    if args.family is not None:
        try:
            family_config(args.family, config)
        except ValueError as exc:
            raise UsageError(f"--family {args.family}: {exc}") from None
    seeds = (most_shadowed_scenes(n_scenes, n_slots, config, family=args.family) if args.quick and n_scenes
             else n_scenes)
    choose_s = time.perf_counter() - t0
    specs = specs_for(seeds, n_slots, args.heading, path_uavs=tuple(args.path_uavs), family=args.family)
    results = _run_all(specs, config, jobs)
    runs_s = time.perf_counter() - t0 - choose_s
    records = [_finite(r) for s in specs for r in results[(s.kind, s.seed, s.n_uavs, s.method)]["records"]]
    (out / "metrics.json").write_text(json.dumps({"config": config.to_dict(), "records": records}, indent=1,
                                                 default=_json_default) + "\n")
    t1 = time.perf_counter()
    figures = [] if args.no_figures else _figures(out, results, config, jobs)
    figures_s = time.perf_counter() - t1
    rows = _aggregate(records)
    elapsed = time.perf_counter() - t0
    timing = {"jobs": jobs, "runs_s": runs_s, "figures_s": figures_s, "choose_s": choose_s,
              "planner_s": sum(r["timing"]["rollout_s"] for r in results.values()),
              "metrics_s": sum(r["timing"]["metrics_s"] for r in results.values())}
    (out / "metrics.md").write_text(_markdown(rows, records, config, elapsed, args.quick, figures,
                                              (load0, os.getloadavg()[0]), timing))
    print(f"wrote {out}/metrics.json ({len(records)} records), metrics.md and {len(figures)} figures "
          f"in {elapsed:.0f} s (runs {runs_s:.0f} s: rollouts {timing['planner_s']:.0f} s and metrics "
          f"{timing['metrics_s']:.1f} s summed over {jobs} worker(s); figures {figures_s:.0f} s)", file=sys.stderr)
    if args.sensitivity:
        t2 = time.perf_counter()
        text = sensitivity(config, jobs, heading=args.heading)
        (out / "sensitivity.md").write_text(text)
        print(f"wrote {out}/sensitivity.md in {time.perf_counter() - t2:.0f} s", file=sys.stderr)
    print((out / "metrics.md").read_text().split("## The paper's claims")[1].split("Columns:")[0].strip())
    if args.prediction_study:
        t3 = time.perf_counter()
        print(write_study(out, config, quick=args.quick, jobs=jobs, figure=not args.no_figures))
        print(f"wrote {out}/prediction_study.md and .json in {time.perf_counter() - t3:.0f} s", file=sys.stderr)
    return 0


def _run_all(specs: list[RunSpec], config: Config, jobs: int) -> dict:
    """Run every spec (``jobs`` spawned worker processes); results keyed by (kind, seed, n_uavs, method)."""
    results = {}
    for res in run_pairs([(s, config) for s in specs], jobs):
        s = res["spec"]
        results[(s.kind, s.seed, s.n_uavs, s.method)] = res
    return results


def run_pairs(pairs: list[tuple[RunSpec, Config]], jobs: int) -> list[dict]:
    """Run (spec, config) pairs in ``jobs`` spawned worker processes; results in the order of ``pairs``."""
    # Longest runs first keeps both workers busy to the end.
    order = sorted(range(len(pairs)), key=lambda i: (-pairs[i][0].n_uavs, pairs[i][0].method != "aware-path"))
    jobs_args = [(i, pairs[i][0], pairs[i][1].to_dict()) for i in order]
    results = [None] * len(pairs)
    bar = _progress(len(pairs))
    if jobs > 1 and len(pairs) > 1:
        import multiprocessing as mp
        import signal

        def _terminate(signum, frame):
            # Leaving the `with` block by an exception terminates the workers (a bare kill would orphan them).
            raise SystemExit(128 + signum)

        signal.signal(signal.SIGTERM, _terminate)
        with mp.get_context("spawn").Pool(min(jobs, len(pairs))) as pool:
            for i, res in pool.imap_unordered(_run_indexed, jobs_args):
                results[i] = res
                _tick(bar, res)
    else:
        for a in jobs_args:
            i, res = _run_indexed(a)
            results[i] = res
            _tick(bar, res)
    bar.close()
    return results


def _run_indexed(args):
    i, spec, cfg_dict = args
    return i, _run_job((spec, cfg_dict))


# ===================================================================================== sensitivity
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


# ===================================================================================== the README's animation
def write_gif(path, *, n_uavs: int = 3, method: str = "aware", n_slots: int | None = None, frames_per_slot: int = 2,
              size: int = 420, dpi: int = 70, fps: int = 6, config: Config | None = None) -> dict:
    """Fly the DP team on the paper scene and write the animation (:func:`covert_env.render.episode_frames`,
    :func:`covert_env.render.save_episode_gif`). Returns {"frames", "bytes", "slots"}."""
    config = config or Config()
    sc = make_scenario("paper", 0, n_uavs, config)
    out = rollout(sc, n_slots=n_slots, **METHODS[method])
    traj = out["trajectory"]
    title = f"DP team, {n_uavs} UAV{'s' if n_uavs > 1 else ''}, {NAMES[method]}"
    frames = episode_frames(sc, traj, frames_per_slot=frames_per_slot, size=(size, size), dpi=dpi, title=title)
    save_episode_gif(frames, path, fps=fps)
    return {"frames": len(frames), "bytes": Path(path).stat().st_size, "slots": int(traj.n_slots)}


def _progress(total: int):
    """A tqdm bar on stderr."""
    from tqdm import tqdm

    return tqdm(total=total, desc="reproduce", unit="run", file=sys.stderr)


def _tick(bar, res: dict) -> None:
    bar.set_postfix_str(res["spec"].label)
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
