"""One set of metrics for every policy (docs/model.md#metrics), computed from a recorded :class:`Trajectory`.

:func:`slot_quantities` turns positions into the per-slot quantities (LoS at slot times and along
the path, zone membership, alpha, d, kappa, g, separation, terrain clearance); the environments'
rewards and infos use the same function, so an env rollout and an evaluation agree by construction.
:func:`episode_metrics` aggregates them per UAV.

Conventions: slot k moves every UAV from p[k] to p[k+1] while the target moves from q[k] to q[k+1];
the slot's disguise and cost (eqs. 11, 18) compare alpha/d at k and k+1; LoS and zone membership
"at slot k" are evaluated at p[k+1] against q[k+1] (the paper's I_LoS at each instant).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from covert_env.geometry.cost import disguise, stage_cost, uav_target_angle, uav_target_distance
from covert_env.geometry.separation import nearest_teammate, team_separation
from covert_env.geometry.zone import zone_distance
from covert_env.world.config import Config
from covert_env.world.roles import PolytopeTops, TerrainPerCopy
from covert_env.world.terrain import Terrain
from covert_env.world.trajectory import Trajectory
from covert_env.world.visibility import line_of_sight

__all__ = ["SlotQuantities", "slot_quantities", "moves_quantities", "episode_metrics", "nearest_teammate",
           "terrain_clearance", "top_clearance", "METRIC_DESCRIPTIONS"]


@dataclass
class SlotQuantities:
    """Per-slot, per-UAV quantities of a trajectory (arrays of shape (T, U) unless noted).

    Attributes:
        los: LoS clear at the end of the slot (p[k+1] to q[k+1]), eq. 6.
        los_path: LoS clear at every sample along the slot's path (against the target at the same instant);
            NaN when not computed (``path_los=False``).
        blocked_path_share: the share of the slot's path samples (after its start, which the previous slot
            counts) whose LoS to the target at the same instant is blocked, in [0, 1]; NaN when not computed.
        in_zone: p[k+1] inside the feasible zone Phi(q[k+1]) of eq. 4 (not eroded: the true target).
        zone_distance: signed distance (m) from p[k+1] to that zone's boundary, negative inside.
        alpha, d: UAV-target angle and distance at the end of the slot, eqs. 12-13.
        kappa: disguise of the slot, eq. 11.
        g: stage cost of the slot, eq. 18.
        path_length: distance flown, v delta.
        separation: distance to the nearest teammate at the end of the slot, eq. 2 (inf with one UAV).
        separation_path: nearest-teammate distance over the samples along the path (synchronous), eq. 2
            (:func:`covert_env.geometry.separation.team_separation`).
        terrain_clearance: distance from the UAV to the nearest polytope top point, eq. 3 (inf if none).
    """

    los: np.ndarray
    los_path: np.ndarray
    blocked_path_share: np.ndarray
    in_zone: np.ndarray
    zone_distance: np.ndarray
    alpha: np.ndarray
    d: np.ndarray
    kappa: np.ndarray
    g: np.ndarray
    path_length: np.ndarray
    separation: np.ndarray
    separation_path: np.ndarray
    terrain_clearance: np.ndarray


def terrain_clearance(xy: np.ndarray, altitude: float, terrain: PolytopeTops) -> np.ndarray:
    """(..., 2) -> (...) distance from (x, y, h) to the nearest polytope highest point (eq. 3).

    ``terrain``: a :class:`Terrain`, or one terrain per row of the leading axis (``highest_points`` (N, M, 3),
    e.g. a :class:`~covert_env.world.roles.TerrainPerCopy`: the vector env's copies): :func:`top_clearance` of its
    ``highest_points``."""
    return top_clearance(xy, altitude, terrain.highest_points)


def top_clearance(xy: np.ndarray, altitude: float, top: np.ndarray) -> np.ndarray:
    """Eq. 3's distance: from UAVs at (x, y, h), xy (..., 2), to the nearest of the points ``top``, (M, 3) or (N, M, 3)
    with row j of xy's leading axis against tops j only; (...) float, inf if there is none. The one computation
    behind the metrics, the env's cost, the start sampler and the planner (:mod:`baselines.dp.clearance`)."""
    top = np.asarray(top, float)
    if top.shape[-2] == 0:
        return np.full(xy.shape[:-1], np.inf)
    if top.ndim == 3:                                            # row j of xy against terrain j only
        top = top.reshape((len(top),) + (1,) * (xy.ndim - 2) + top.shape[1:])
    dz = altitude - top[..., 2]
    d2 = xy[..., 0, None] - top[..., 0]
    d2 *= d2
    dy = xy[..., 1, None] - top[..., 1]
    dy *= dy
    # (dx^2 + dy^2) + dz^2 written out, in place: the sum of (dxy ** 2).sum(-1) + dz ** 2 without a reduction over
    # a length-2 axis; the square root after the minimum (it is monotone: the same value).
    d2 += dy
    d2 += dz * dz
    return np.sqrt(d2.min(axis=-1))


def slot_quantities(traj: Trajectory, terrain: Terrain, config: Config, *, path_los: bool = True) -> SlotQuantities:
    """Evaluate every slot of ``traj`` (see the module docstring for the conventions).

    ``path_los=False`` skips LoS along the path (``los_path`` is then NaN): environments use it for
    their per-step rewards, which do not need it; episode metrics always compute it.
    """
    return moves_quantities(traj.uav_xy[:-1], traj.uav_xy[1:],
                            target_start=traj.target_xyz[:-1], phi_start=traj.target_phi[:-1],
                            target_end=traj.target_xyz[1:], phi_end=traj.target_phi[1:],
                            path_xy=traj.path_xy, path_length=traj.path_length,
                            target_path_xyz=traj.target_path_xyz if path_los else None, terrain=terrain, config=config)


def moves_quantities(start_xy, end_xy, *, target_start, phi_start, target_end, phi_end, path_xy, path_length,
                     target_path_xyz, terrain: Terrain | TerrainPerCopy, config: Config) -> SlotQuantities:
    """:class:`SlotQuantities` of a batch of one-slot moves: the one function behind
    :func:`slot_quantities` (B = the T slots of an episode) and the engine's per-step quantities
    (B = the copies of :class:`covert_env.envs.vector.CovertSensingVectorEnv`; 1 for an engine).

    Args:
        start_xy, end_xy: (*B, U, 2) the team before and after each move.
        target_start, target_end: (*B, 3) the target before and after; phi_start, phi_end: (*B,) its heading.
        path_xy: (*B, U, P, 2) samples along each move; path_length: (*B, U).
        target_path_xyz: (*B, P, 3) the target at the same instants, or None to skip LoS along the path
            (``los_path`` is then NaN).
        terrain: a :class:`Terrain` for every move, or a :class:`~covert_env.world.roles.TerrainPerCopy`, one terrain
        per
            move (B = (N,), the vector env's copies), whose line of sight takes one target per move:
            ``target_path_xyz`` must then be None.
    """
    c = config
    alpha_prev = uav_target_angle(start_xy, target_start[..., None, :2], phi_start[..., None])
    alpha = uav_target_angle(end_xy, target_end[..., None, :2], phi_end[..., None])
    d_prev = uav_target_distance(start_xy, target_start[..., None, :2])
    d = uav_target_distance(end_xy, target_end[..., None, :2])
    kappa = disguise(alpha_prev, alpha, d_prev, d, c.eta)
    g = stage_cost(path_length, alpha_prev, alpha, d_prev, d, c.eta, c.lam, kappa=kappa)

    zd = zone_distance(end_xy, target_end[..., None, :2], phi_end[..., None], c.r1, c.r2, c.mu)
    if isinstance(terrain, Terrain):
        los_fn = functools.partial(line_of_sight, terrain)
    else:
        los_fn = terrain.line_of_sight
    if target_path_xyz is not None:
        # Sample j of every UAV against the target at the same instant, in one vectorised call (every
        # slot has its own target). Sample 0 is the previous slot's end, checked there; the last
        # sample is this slot's end, so the slot-time LoS comes with it.
        clear = los_fn(path_xy[..., 1:, :], c.altitude, target_path_xyz[..., None, 1:, :])
        los, los_path, blocked = clear[..., -1], clear.all(axis=-1), 1.0 - clear.mean(axis=-1)
    else:
        los = los_fn(end_xy, c.altitude, target_end[..., None, :])
        los_path = np.full(los.shape, np.nan)
        blocked = np.full(los.shape, np.nan)

    # Like LoS: sample 0 is the previous slot's end (counted there), so each instant counts once.
    sep_path = team_separation(path_xy[..., 1:, :])
    sep = team_separation(path_xy[..., -1:, :])
    clearance = terrain_clearance(end_xy, c.altitude, terrain)
    return SlotQuantities(los=los, los_path=los_path, blocked_path_share=blocked, in_zone=zd <= 0.0, zone_distance=zd,
                          alpha=alpha, d=d,
                          kappa=kappa, g=g, path_length=np.asarray(path_length, float),
                          separation=sep, separation_path=sep_path, terrain_clearance=clearance)


METRIC_DESCRIPTIONS = {
    "occlusion_rate": "fraction of slots whose end position has blocked LoS (the paper's I_LoS = 1)",
    "occlusion_rate_path": "fraction of slots with blocked LoS somewhere along the flown path",
    "blocked_path_share": "share of the flown path with blocked LoS (per slot, the share of its path samples whose "
                          "LoS to the target at the same instant is blocked; mean over slots)",
    "zone_violation_rate": "fraction of slots ending outside the feasible zone Phi(q) (eq. 4)",
    "mean_disguise": "mean kappa per slot (eq. 11); higher is better disguised",
    "path_length": "total distance flown (m), the paper's energy proxy (eq. 15)",
    "objective": "sum of the stage cost g over the episode (eq. 17); lower is better",
    "min_separation": "smallest distance to a teammate, at slot times and along paths (m)",
    "separation_violations": "slots with separation < d_safe1 at the slot time or along the path (eq. 2)",
    "terrain_violations": "slots ending closer than d_safe2 to a polytope's highest point (eq. 3)",
    "speed_violations": "slots whose commanded speed exceeded V_max or turn rate exceeded W_max",
    "infeasible_slots": "slots the policy flagged as fallback moves (no feasible plan found)",
    "decision_time_ms": "mean time the policy took per slot and UAV (ms)",
}


def episode_metrics(traj: Trajectory, terrain: Terrain, config: Config,
                    quantities: SlotQuantities | None = None) -> list[dict[str, float]]:
    """Per-UAV episode metrics (docs/model.md#metrics): one dict per UAV with the keys of METRIC_DESCRIPTIONS."""
    q = quantities if quantities is not None else slot_quantities(traj, terrain, config)
    if np.isnan(np.asarray(q.los_path, float)).any():
        q = slot_quantities(traj, terrain, config)
    eps = 1e-9
    sep_bad = (q.separation < config.d_safe1 - eps) | (q.separation_path < config.d_safe1 - eps)
    speed_bad = (traj.max_speed > config.v_max + 1e-6) | (traj.max_turn_rate > config.w_max + 1e-6)
    out = []
    for i in range(traj.n_uavs):
        min_sep = float(min(q.separation[:, i].min(initial=np.inf), q.separation_path[:, i].min(initial=np.inf)))
        dt = traj.decision_time[:, i]
        out.append({
            "occlusion_rate": float(1.0 - q.los[:, i].mean()),
            "occlusion_rate_path": float(1.0 - q.los_path[:, i].mean()),
            "blocked_path_share": float(q.blocked_path_share[:, i].mean()),
            "zone_violation_rate": float(1.0 - q.in_zone[:, i].mean()),
            "mean_disguise": float(q.kappa[:, i].mean()),
            "path_length": float(q.path_length[:, i].sum()),
            "objective": float(q.g[:, i].sum()),
            "min_separation": min_sep,
            "separation_violations": int(sep_bad[:, i].sum()),
            "terrain_violations": int((q.terrain_clearance[:, i] < config.d_safe2 - eps).sum()),
            "speed_violations": int(speed_bad[:, i].sum()),
            "infeasible_slots": int(np.asarray(traj.infeasible[:, i], bool).sum()),
            "decision_time_ms": float(np.nanmean(dt) * 1e3) if np.isfinite(dt).any() else float("nan"),
        })
    return out
