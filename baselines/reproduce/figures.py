"""The figures of ``covert-env reproduce``: the paper's Figs. 8-15 for 1 and 3 UAVs, the held-out scenes' bars,
LoS lost between slot times, and the README's animation (:func:`write_gif`)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from baselines.intervals import bootstrap_ci
from baselines.reproduce.runs import HELDOUT_SEED_BASE, METHODS, figure_slot, make_scenario, zone_shadow_shares
from baselines.rollout import rollout
from covert_env.geometry.zone import feasible_zone, to_world, zone_lattice
from covert_env.render import (
    TERRAIN_COLOR,
    UAV_COLORS,
    draw_3d_view,
    draw_top_view,
    episode_frames,
    fill_geometry,
    outline_geometry,
    save_episode_gif,
    zones_at,
)
from covert_env.world.config import Config
from covert_env.world.scenario import Scenario
from covert_env.world.visibility import visible_nodes

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


def write_figures(out: Path, results: dict, config: Config, jobs: int = 1) -> list[str]:
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


