"""A dense reference of the paper's DP (eqs. 19-21) for the planner's tests: every transition solved exactly.

Independent of the planner's pruning and lookup table. States are (node, heading bin) and keep the exact heading of
their best arrival; ``bins = 1`` is the paper's inherited heading. ``extra_cost`` adds a term to each feasible
transition (the learned path cost)::

    from _dense_dp import dense_dp
    cost, nodes = dense_dp(config, start, theta, tq, tphi, allowed, bins=1)
"""

from __future__ import annotations

import numpy as np

from covert_env.geometry.angles import wrap_angle
from covert_env.geometry.cost import uav_target_angle, uav_target_distance
from covert_env.geometry.dynamics import solve_manoeuvre
from covert_env.geometry.zone import to_world, zone_lattice

TWO_PI = 2 * np.pi


def dense_dp(config, start, theta, tq, tphi, allowed, bins=1, extra_cost=None):
    """The cheapest plan over slots 1..N and its cost: ``(cost, (N,) node per slot)``, or ``(inf, None)``.

    ``tq`` (N+1, 3) and ``tphi`` (N+1,) are the target's poses at slots k..k+N, ``allowed`` (N, L) the nodes each
    slot may use. ``extra_cost(j, m, feasible)``, if given, returns the extra cost of stage ``j``'s manoeuvres ``m``
    (an array of ``m``'s shape; only its ``feasible`` entries are read)."""
    c = config
    lat = zone_lattice(c)
    n = len(tq) - 1
    xy = [to_world(lat, tq[j, :2], tphi[j]) for j in range(1, n + 1)]
    al = [uav_target_angle(xy[j - 1], tq[j, :2], tphi[j]) for j in range(1, n + 1)]
    dd = [uav_target_distance(xy[j - 1], tq[j, :2]) for j in range(1, n + 1)]
    a0, d0 = uav_target_angle(start, tq[0, :2], tphi[0]), uav_target_distance(start, tq[0, :2])

    def g(length, aa, ab, da, db):
        return length - c.lam * (c.eta * np.abs(wrap_angle(ab - aa)) + np.abs(db - da))

    def plus_extra(j, cost, m):
        feasible = np.asarray(m.feasible)
        return cost if extra_cost is None else cost + np.where(feasible, extra_cost(j, m, feasible), 0.0)

    cols = np.flatnonzero(allowed[0])
    m = solve_manoeuvre(start, theta, xy[0][cols], v_max=c.v_max, w_max=c.w_max, delta=c.delta)
    ok = np.asarray(m.feasible)
    cost = plus_extra(0, g(m.length, a0, al[0][cols], d0, dd[0][cols]), m)
    node, th, J = cols[ok], np.asarray(m.heading_after)[ok], cost[ok]
    hist = node[:, None]
    for j in range(1, n):
        cols = np.flatnonzero(allowed[j])
        m = solve_manoeuvre(xy[j - 1][node][:, None], th[:, None], xy[j][cols][None], v_max=c.v_max,
                            w_max=c.w_max, delta=c.delta)
        cost = plus_extra(j, J[:, None] + g(m.length, al[j - 1][node][:, None], al[j][cols][None],
                                            dd[j - 1][node][:, None], dd[j][cols][None]), m)
        r, q = np.nonzero(np.asarray(m.feasible))
        if r.size == 0:
            return np.inf, None
        head = np.asarray(m.heading_after)[r, q]
        key = cols[q] * bins + (np.floor(np.mod(head, TWO_PI) * bins / TWO_PI).astype(int) % bins)
        order = np.lexsort((cost[r, q], key))
        first = np.concatenate([[True], key[order][1:] != key[order][:-1]])
        w = order[first]
        node, th, J = cols[q[w]], head[w], cost[r[w], q[w]]
        hist = np.column_stack([hist[r[w]], node])
    best = int(np.argmin(J))
    return float(J[best]), hist[best]
