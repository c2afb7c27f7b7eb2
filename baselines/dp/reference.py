"""Exact references the planner is tested against: a plan's exact cost, and the optimum by enumeration."""

from __future__ import annotations

import numpy as np

from covert_env.geometry.angles import wrap_angle
from covert_env.geometry.cost import uav_target_angle, uav_target_distance
from covert_env.geometry.dynamics import solve_manoeuvre
from covert_env.geometry.ties import first_argmin
from covert_env.geometry.zone import to_world, zone_lattice
from covert_env.world.config import Config

__all__ = ["brute_force_plan", "evaluate_plan"]


def evaluate_plan(config: Config, start_xy, start_theta: float, target_xyz, target_phi, waypoints) -> float:
    """Exact cost (eq. 17) of flying ``waypoints`` (M, 2) for slots k+1..k+M, heading propagated continuously.

    inf if some manoeuvre is infeasible. The reference the DP is tested against.
    """
    c = config
    wp = np.asarray(waypoints, float).reshape(-1, 2)
    tq = np.asarray(target_xyz, float).reshape(-1, 3)
    tp = np.asarray(target_phi, float).reshape(-1)
    p, th = np.asarray(start_xy, float).reshape(2), float(start_theta)
    a = uav_target_angle(p, tq[0, :2], tp[0])
    d = uav_target_distance(p, tq[0, :2])
    total = 0.0
    for j, g in enumerate(wp, start=1):
        m = solve_manoeuvre(p, th, g, v_max=c.v_max, w_max=c.w_max, delta=c.delta)
        if not bool(m.feasible):
            return float("inf")
        a1 = uav_target_angle(g, tq[j, :2], tp[j])
        d1 = uav_target_distance(g, tq[j, :2])
        total += float(m.length) - c.lam * (c.eta * abs(wrap_angle(a1 - a)) + abs(d1 - d))
        p, th, a, d = g, float(m.heading_after), a1, d1
    return total


def brute_force_plan(config: Config, start_xy, start_theta: float, target_xyz, target_phi, allowed):
    """The true optimum J* over every node sequence (continuous heading propagated), by enumeration.

    Args:
        allowed: (N, L) bool, the nodes allowed per stage (e.g. ``DPPlanner.allowed_nodes``).

    Returns:
        ``(J*, nodes)``: the optimal cost and (N,) lattice indices; ``(inf, None)`` if nothing is feasible.
        Vectorised over sequences, so only for small lattices (prod of allowed counts up to ~1e5).
    """
    c = config
    lat = zone_lattice(c)
    tq = np.asarray(target_xyz, float).reshape(-1, 3)
    tp = np.asarray(target_phi, float).reshape(-1)
    n = len(tq) - 1
    ok = np.asarray(allowed, bool).reshape(n, len(lat))
    seq = np.zeros((1, 0), np.int64)
    pos = np.asarray(start_xy, float).reshape(1, 2)
    th = np.array([float(start_theta)])
    a = np.atleast_1d(uav_target_angle(pos, tq[0, :2], tp[0]))
    d = np.atleast_1d(uav_target_distance(pos, tq[0, :2]))
    J = np.zeros(1)
    for j in range(1, n + 1):
        cols = np.flatnonzero(ok[j - 1])
        xy = to_world(lat[cols], tq[j, :2], tp[j])
        m = solve_manoeuvre(pos[:, None, :], th[:, None], xy[None, :, :], v_max=c.v_max, w_max=c.w_max,
                            delta=c.delta)
        a1 = uav_target_angle(xy, tq[j, :2], tp[j])
        d1 = uav_target_distance(xy, tq[j, :2])
        g = m.length - c.lam * (c.eta * np.abs(wrap_angle(a1[None] - a[:, None])) + np.abs(d1[None] - d[:, None]))
        feas = np.asarray(m.feasible, bool)
        r, cc = np.nonzero(feas)
        if r.size == 0:
            return float("inf"), None
        seq = np.column_stack([seq[r], cols[cc]])
        J = J[r] + g[r, cc]
        pos, th, a, d = xy[cc], np.asarray(m.heading_after)[r, cc], a1[cc], d1[cc]
    best = first_argmin(J)
    return float(J[best]), seq[best]

