"""The team's safety layer: separate the slot that is actually flown when the negotiation left a conflict in it."""

from __future__ import annotations

from dataclasses import replace
from typing import NamedTuple

import numpy as np

from baselines.dp.fallback import nearness
from baselines.dp.path_checks import FALLBACK_PENALTY
from baselines.dp.plan import flown_paths
from baselines.dp.transitions import transition_costs
from covert_env.cost import uav_target_angle, uav_target_distance
from covert_env.dynamics import solve_manoeuvre
from covert_env.separation import priority_negotiation, separation

__all__ = ["secure_first_moves"]


class _Candidates(NamedTuple):
    """One UAV's one-slot moves to every lattice node of the next slot, as the engine flies them."""

    heading: np.ndarray       # (L,) heading after the move (NaN for a best effort)
    speed: np.ndarray         # (L,) its speed (NaN for a best effort)
    flyable: np.ndarray       # (L,) reachable (or, if no node is, flown as a best effort) and clear of the tops
    samples: np.ndarray       # (L, P - 1, 2) path samples after the start
    cost: np.ndarray          # (L,) stage cost g (eq. 18), or level 3's nearness for a best effort; inf if not flyable
    allowed: np.ndarray       # (L,) an allowed node (and, with check_path, LoS kept along the way)
    best_effort: bool         # no node is reachable: every move is the engine's best effort (flagged)


class _Move(NamedTuple):
    node: int
    infeasible: bool          # the move leaves the allowed nodes (flagged to the engine)


def secure_first_moves(team, plans, xy, th, target_xyz, target_phi, target_path=None) -> list:
    """Safety layer for the slot that is flown, after the negotiation left a conflict in it.

    Every path here is the one the engine will fly: a plan's first move as :meth:`DPPlan.path_points` gives it
    (a best-effort fallback included), a candidate move as its manoeuvre. In the order of
    :func:`~covert_env.separation.priority_negotiation`, a UAV keeps its plan if its first move keeps
    ``d_safe1 + separation_margin`` from those of the UAVs already settled, at every sample; otherwise it takes,
    among all lattice nodes of the next slot (solved exactly from its pose), the separated move to an allowed
    (visible) node with the lowest stage cost (eq. 18), else to any node (flagged infeasible). A UAV that can
    reach no node at all (a last-resort fallback) chooses among the engine's best efforts to every node instead,
    the nearest first (level 3's rule), flagged. If it has no separated move at all, its move and that of one
    settled UAV are re-chosen together (every pair of their candidates; a fast teammate sweeping past can leave
    no single move); failing that it is left without one (docs/decisions.md#safety-layer) and, in the order that
    stands, takes its most separated move (flagged). Moves keep eq. 3 along their samples. ``status="safety"``.

    Cost: at most U orders, each O(U) picks and O(U^2) pair repairs; every UAV's candidate moves are solved
    once (L manoeuvres, or L best efforts). ``team.stats`` counts ``safety_orders`` and ``safety_solves``.
    """
    pl, c = team.planner, team.config
    tq = np.asarray(target_xyz, float).reshape(-1, 3)
    tp = np.asarray(target_phi, float).reshape(-1)
    st = pl.cache.stage(tq[1], tp[1])
    allowed_nodes = pl.allowed_nodes(tq[1], tp[1])
    ctx = pl.paths.context(tq, tp, target_path) if pl.check_path else None
    clearance = pl.paths.clearance
    lim = team.separation
    p = team.path_samples
    u = len(plans)
    own = [q.path_points(p)[0][1:] for q in plans]           # sample 0 (the current position) is fixed
    cands: dict = {}

    def candidates(i) -> _Candidates:
        if i not in cands:
            team.stats["safety_solves"] += 1
            m = solve_manoeuvre(xy[i], th[i], st.xy, v_max=c.v_max, w_max=c.w_max, delta=c.delta)
            ok = np.asarray(m.feasible, bool).copy()
            if clearance.active:
                ok &= clearance.clear(st.xy)                          # eq. 3 at the node and along the path
                ok[ok] = clearance.manoeuvres_clear(m, ok)
            if not ok.any():
                cands[i] = best_efforts(i)
                return cands[i]
            a0 = uav_target_angle(xy[i], tq[0, :2], tp[0])
            d0 = uav_target_distance(xy[i], tq[0, :2])
            g = transition_costs(c, m, ok, a0, d0, st.alpha, st.d)
            good = allowed_nodes.copy()
            if ctx is not None and ok.any():
                clear = np.zeros(len(ok), bool)
                clear[ok] = pl.paths.keeps_sight(m, ok, ctx, 0, zone=False)
                good &= clear
            cands[i] = _Candidates(m.heading_after, m.v, ok, m.points(p)[:, 1:], g, good, False)
        return cands[i]

    def best_efforts(i) -> _Candidates:
        n = len(st.xy)
        flown = flown_paths(np.broadcast_to(xy[i], st.xy.shape), np.full(n, th[i]), st.xy, c, p)
        ok = clearance.paths_clear(flown)
        nan = np.full(n, np.nan)
        return _Candidates(nan, nan, ok, flown[:, 1:], np.where(ok, nearness(c, st, xy[i], allowed_nodes), np.inf),
                           np.zeros(n, bool), True)

    def clear_of(pts, others):
        """(n,) smallest distance (eq. 2) from candidate paths (n, P-1, 2) to the given settled paths."""
        others = list(others)
        if not others:
            return np.full(len(pts), np.inf)
        return separation(pts[:, None], np.stack(others)[None]).min(axis=1)

    def pick(i, fixed):
        _, _, ok, pts, g, allowed, _ = candidates(i)
        d = np.where(ok, clear_of(pts, fixed.values()), -np.inf)
        safe = d >= lim
        if (safe & allowed).any():
            return _Move(int(np.argmin(np.where(safe & allowed, g, np.inf))), False)
        if safe.any():
            return _Move(int(np.argmin(np.where(safe, g, np.inf))), True)
        return None

    def repair(i, h, fixed):
        """Re-choose the moves of i and of the settled h together (all pairs of their candidates)."""
        rest = [f for k, f in fixed.items() if k != h]
        (_, _, ok_i, p_i, g_i, al_i, _), (_, _, ok_h, p_h, g_h, al_h, _) = candidates(i), candidates(h)
        ci = np.flatnonzero(ok_i & (clear_of(p_i, rest) >= lim))
        ch = np.flatnonzero(ok_h & (clear_of(p_h, rest) >= lim))
        if ci.size == 0 or ch.size == 0:
            return None
        d = separation(p_h[ch][:, None], p_i[ci][None])
        # Prefer both visible, then the lowest total stage cost.
        score = g_h[ch][:, None] + g_i[ci][None] + FALLBACK_PENALTY * (
            (~al_h[ch])[:, None].astype(float) + (~al_i[ci])[None].astype(float))
        score = np.where(d >= lim, score, np.inf)
        if not np.isfinite(score).any():
            return None
        a_, b_ = np.unravel_index(int(np.argmin(score)), score.shape)
        return _Move(int(ch[a_]), bool(not al_h[ch[a_]])), _Move(int(ci[b_]), bool(not al_i[ci[b_]]))

    def settle(order):
        """Moves per UAV settled in ``order``; and the first UAV left without a separated move (None: clean)."""
        fixed, moves, stuck = {}, {}, None
        for i in order:
            if clear_of(own[i][None], fixed.values())[0] >= lim:
                moves[i] = None                               # keeps its plan
                fixed[i] = own[i]
                continue
            mv = pick(i, fixed)
            if mv is None:
                for h in reversed(list(fixed)):
                    both = repair(i, h, fixed)
                    if both is not None:
                        moves[h], mv = both
                        fixed[h] = candidates(h).samples[moves[h].node]
                        break
            if mv is None:
                stuck = i if stuck is None else stuck
                _, _, ok, pts, _, _, _ = candidates(i)
                if not ok.any():
                    moves[i] = None                           # nothing flyable: keep the (fallback) plan
                    fixed[i] = own[i]
                    continue
                d = np.where(ok, clear_of(pts, fixed.values()), -np.inf)
                mv = _Move(int(np.argmax(d)), True)
            moves[i] = mv
            fixed[i] = candidates(i).samples[mv.node]
        return moves, stuck

    settled: dict = {}

    def settle_order(order, rows):
        team.stats["safety_orders"] += 1
        seq = order[0].tolist()
        settled["moves"], stuck = settle(seq)
        return np.array([u if stuck is None else seq.index(stuck)])

    priority_negotiation(settle_order, 1, u)
    out = list(plans)
    for i, mv in settled["moves"].items():
        if mv is None:
            continue
        node, flag = mv
        heading, speed, _, _, g, _, best_effort = candidates(i)
        n = len(out[i].nodes)
        nodes = np.full(n, -1, np.int64)
        nodes[0] = node
        wp = np.full((n, 2), np.nan)
        wp[0] = st.xy[node]
        head, v, cost = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
        head[0], v[0] = heading[node], speed[node]
        cost[0] = np.nan if best_effort else g[node]                  # a best effort has no planned cost
        out[i] = replace(out[i], nodes=nodes, waypoints=wp, headings=head, speeds=v, stage_costs=cost,
                         cost=float(cost[0]), depth=1, status="safety", infeasible=flag, layers=None)
    return out
