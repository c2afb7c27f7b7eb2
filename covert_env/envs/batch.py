"""One slot of B env copies x U UAVs as array operations: controls, flight, rewards, costs, observations, masks.

Pure functions on batch-first arrays ``(B, U, ...)``, no Python loop over copies, UAVs or lattice nodes: the
vector env (:mod:`covert_env.envs.vector`) is a thin state holder around them. They use the model's own
functions (:func:`~covert_env.world.metrics.moves_quantities`, the manoeuvre solver, the reachability table) with the
batch as their leading axes, and fly with :mod:`covert_env.geometry.flight`, the engine's flight
(tests/test_batch_flight.py checks it against the plain integration bit for bit), so a copy computes exactly what the
parallel env computes for the same scene, starts and actions. Written with numpy calls that have direct torch
counterparts, so a torch backend is a port.
"""

from __future__ import annotations

import numpy as np

from covert_env.envs.observation import OFFSET_CLIP, OWN_SIZE, OWN_SLICES
from covert_env.geometry.flight import fly_waypoints
from covert_env.geometry.zone import to_target_frame
from covert_env.world.config import short_repr

#: Smallest commanded speed as a fraction of V_max: the unicycle needs v > 0 (eq. 1).
MIN_SPEED_FRACTION = 0.01
#: The reward's terms; ``infos[agent]["reward_<term>"]`` holds each (the parallel env's Rewards section).
REWARD_TERMS = ("path", "disguise", "los", "los_path", "zone", "separation", "terrain")
#: The constraint costs, ``infos[agent]["cost_<name>"]``: the paper's constraints (§2.4), 1.0 where the slot violated
#: one, and ``los_path``, the share of the slot's flown path with LoS blocked, in [0, 1].
COSTS = ("los", "los_path", "zone", "separation", "terrain")

__all__ = ["COSTS", "MIN_SPEED_FRACTION", "OFFSET_CLIP", "REWARD_TERMS", "action_masks", "constraint_costs",
           "fly_to_goals",
           "own_features", "reward_terms",
           "unicycle_actions", "unicycle_controls", "waypoint_actions"]


def _action_array(actions, shape: tuple, mode: str, layout: str, kinds: str) -> np.ndarray:
    """``actions`` as an array of numbers of ``shape``; a ragged nesting, another dtype or shape is an error that
    names the ``mode``, the ``layout`` of the shape and the ``kinds`` of number expected."""
    try:
        a = np.asarray(actions)
    except ValueError:                      # ragged nesting: no array of any shape
        raise ValueError(f"{mode} actions must have shape {shape} ({layout}), got a ragged nesting "
                         f"{short_repr(actions)}") from None
    if a.dtype.kind not in "iuf":
        raise TypeError(f"{mode} actions must be {kinds}, got dtype {a.dtype}")
    if a.shape != shape:
        raise ValueError(f"{mode} actions must have shape {shape} ({layout}), got {a.shape}")
    return a


def unicycle_actions(actions, shape: tuple[int, int], agents) -> np.ndarray:
    """Box actions (B, U, 2) as floats, checked: numbers, the shape, finite (errors name the copy and agent)."""
    a = _action_array(actions, shape + (2,), "unicycle", "copies, agents, 2",
                      "numbers (speed, turn rate) in [-1, 1]").astype(float, copy=False)
    bad = ~np.isfinite(a).all(axis=-1)
    if bad.any():
        j, i = np.argwhere(bad)[0]
        raise ValueError(f"action of copy {j}, agent {agents[i]} must be finite, got {a[j, i].tolist()}")
    return a


def waypoint_actions(actions, shape: tuple[int, int], n: int, agents) -> np.ndarray:
    """Lattice indices (B, U) as int64, checked: numbers, the shape, integers in [0, n) (errors name copy, agent)."""
    a = _action_array(actions, shape, "waypoint", "copies, agents", "integers (lattice node indices)")
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(a) & (a == np.round(a)) & (a >= 0) & (a < n)
    if not ok.all():
        j, i = np.argwhere(~ok)[0]
        raise ValueError(f"action of copy {j}, agent {agents[i]} must be an integer in "
                         f"[0, {n - 1}], got {a[j, i].item()!r}")
    return a.astype(np.int64)


def unicycle_controls(act: np.ndarray, c) -> tuple[np.ndarray, np.ndarray]:
    """(v, omega) (B, U) from Box(-1, 1) actions (B, U, 2): clipped, then scaled (the parallel env's docstring)."""
    act = np.minimum(np.maximum(act, -1.0), 1.0)
    v = c.v_max * (MIN_SPEED_FRACTION + (1 - MIN_SPEED_FRACTION) * (act[..., 0] + 1) / 2)
    return v, c.w_max * act[..., 1]


def fly_to_goals(xy, theta, goals, c, times) -> np.ndarray:
    """Path samples ``(B, U, M, P, 2)`` of the UAVs at poses xy (B, U, 2), theta (B, U) flown to each of their
    ``goals`` ``(B, U, M, 2)`` by :func:`fly_waypoints`; NaN where a goal is NaN (no node: nothing is flown)."""
    ci, ui, mi = np.nonzero(~np.isnan(goals[..., 0]))             # only the real (copy, UAV, goal) triples
    out = np.full((*goals.shape[:3], len(times), 2), np.nan)
    out[ci, ui, mi] = fly_waypoints(xy[ci, ui][:, None], theta[ci, ui][:, None], goals[ci, ui, mi][:, None], c,
                                    times)[0][:, 0]
    return out


def action_masks(xy, theta, q_xy, phi, lattice, visible, table, available=None) -> np.ndarray:
    """Waypoint masks (B, U, L) int8: the ``lattice`` nodes (L, 2) placed at the targets q_xy (B, 2), phi (B,) of
    slot k+1, reachable in one slot from the poses (B, U) (``table``: the config's
    :class:`~covert_env.geometry.reach.ReachTable`, exactly ``solve_manoeuvre``'s answer) and ``visible`` (B, L) there
    (None: reachable only, the kinematic mask); where no node qualifies the reachable ones, and where none is
    reachable all. With ``available`` (B, L) bool (a copy's task has only these nodes) every node outside it is
    left out, as if the lattice had only its nodes."""
    reach = table.reachable(xy, theta, q_xy, phi, lattice)
    if available is not None:
        reach &= available[:, None, :]
    if visible is None:
        mask = reach.copy()
    else:
        mask = reach & visible[:, None, :]
    empty = ~mask.any(axis=-1)
    if empty.any():                                   # rare: fix those rows only
        rows = reach[empty]
        every = True if available is None else np.broadcast_to(available[:, None, :], mask.shape)[empty]
        mask[empty] = np.where(rows.any(axis=-1, keepdims=True), rows, every)
    return mask.view(np.int8)


def constraint_costs(quant, c) -> np.ndarray:
    """(5, B, U) float costs in the order of ``COSTS`` (the parallel env's Constraint Costs table): 0/1 violations
    of LoS at the slot's end, the zone, separation and terrain, and the share of the path with LoS blocked."""
    costs = np.empty((len(COSTS),) + quant.los.shape)
    np.logical_not(quant.los, out=costs[0])
    costs[1] = quant.blocked_path_share
    np.logical_not(quant.in_zone, out=costs[2])
    np.less(quant.separation_path, c.d_safe1, out=costs[3])
    np.less(quant.terrain_clearance, c.d_safe2, out=costs[4])
    return costs


def reward_terms(quant, costs, c, scale, p: dict) -> np.ndarray:
    """(7, B, U) reward terms in the order of ``REWARD_TERMS`` (the parallel env's Rewards section); ``scale`` and
    the penalties ``p`` are numbers, or (B, 1) arrays when copies have their own."""
    outside = np.maximum(quant.zone_distance, 0.0) / (c.r2 - c.r1)
    cols = np.empty((len(REWARD_TERMS),) + outside.shape)
    np.divide(quant.path_length, -scale, out=cols[0])
    np.multiply(quant.kappa, c.lam, out=cols[1])
    cols[1] /= scale
    np.multiply(costs[0], -p["los"], out=cols[2])
    np.multiply(costs[1], -p["los_path"], out=cols[3])
    cols[4] = np.minimum(outside, 2.0) + 1.0
    cols[4] *= costs[2]
    cols[4] *= -p["zone"]
    np.multiply(costs[3], -p["separation"], out=cols[5])
    np.multiply(costs[4], -p["terrain"], out=cols[6])
    return cols


def own_features(xy, theta, q, phi, speed, los, zone_dist, c) -> np.ndarray:
    """(B, U, OWN_SIZE) per-UAV features (the observation layout's own block: offset, heading, speed, LoS, zone,
    zone distance), targets q (B, 3), phi (B,)."""
    cs, sn = np.cos(phi)[:, None], np.sin(phi)[:, None]
    f = np.empty(theta.shape + (OWN_SIZE,))
    offset, heading = f[..., OWN_SLICES["offset"]], f[..., OWN_SLICES["heading"]]
    offset[:] = to_target_frame(xy - q[:, None, :2], cs, sn) / c.r2
    np.minimum(np.maximum(offset, -OFFSET_CLIP), OFFSET_CLIP, out=offset)
    dth = theta - phi[:, None]
    heading[..., 0] = np.cos(dth)
    heading[..., 1] = np.sin(dth)
    f[..., OWN_SLICES["speed"].start] = np.minimum(speed / c.v_max, 1.0)
    f[..., OWN_SLICES["los"].start] = los
    f[..., OWN_SLICES["in_zone"].start] = zone_dist <= 0
    f[..., OWN_SLICES["zone_distance"].start] = np.minimum(np.maximum(zone_dist / (c.r2 - c.r1), -OFFSET_CLIP),
                                                           OFFSET_CLIP)
    return f
