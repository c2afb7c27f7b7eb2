"""The team's safety layer: separate the slot that is actually flown when the negotiation left a conflict in it."""

from __future__ import annotations

from dataclasses import replace
from typing import NamedTuple

import numpy as np

from baselines.dp.fallback import nearness
from baselines.dp.path_checks import FALLBACK_PENALTY
from baselines.dp.plan import DPPlan, flown_paths
from baselines.dp.transitions import transition_costs
from covert_env.cost import uav_target_angle, uav_target_distance
from covert_env.dynamics import solve_manoeuvre
from covert_env.separation import priority_negotiation, separation

__all__ = ["secure_first_moves"]

#: The escape's score per best effort in a pair: above any sum of stage costs, so fewer best efforts always win.
PER_BEST_EFFORT = 1e9


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
    best_effort: bool = False  # the engine's best effort toward ``node`` (an escape), not a manoeuvre to it


def secure_first_moves(team, plans, *, xy, th, target_xyz, target_phi, target_path=None) -> list:
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
    no single move). With the team's ``best_effort_escape``, the engine's best efforts toward every node are then
    candidates too, for it and for the settled UAV it is re-chosen with (:meth:`_FirstSlot.escape`, flagged).
    Failing that it is left without one (docs/decisions.md#safety-layer) and, in the order that stands, takes its
    most separated move (flagged). Moves keep eq. 3 along their samples. ``status="safety"``.

    Cost: at most U orders, each O(U) picks and O(U^2) pair repairs; every UAV's candidate moves are solved
    once (L manoeuvres, or L best efforts), and with the escape its best efforts once more. ``team.stats`` counts
    ``safety_orders`` and ``safety_solves``.
    """
    slot = _FirstSlot(team, plans, xy, th, target_xyz, target_phi, target_path)
    moves = slot.negotiate()
    return [plan if moves[i] is None else slot.safety_plan(plan, i, moves[i]) for i, plan in enumerate(plans)]


def _clear_of(pts: np.ndarray, others) -> np.ndarray:
    """(n,) smallest distance (eq. 2) from candidate paths (n, P-1, 2) to the given settled paths."""
    others = list(others)
    if not others:
        return np.full(len(pts), np.inf)
    return separation(pts[:, None], np.stack(others)[None]).min(axis=1)


class _FirstSlot:
    """The slot about to be flown: the team's poses, the next slot's lattice nodes, and each UAV's candidate moves
    to them (solved on first use, once: the orders tried by the negotiation share them)."""

    def __init__(self, team, plans, xy, th, target_xyz, target_phi, target_path):
        pl = team.planner
        self.team, self.config, self.paths = team, team.config, pl.paths
        self.xy, self.th = xy, th
        self.tq = np.asarray(target_xyz, float).reshape(-1, 3)
        self.tp = np.asarray(target_phi, float).reshape(-1)
        self.stage = pl.cache.stage(self.tq[1], self.tp[1])
        self.allowed_nodes = pl.allowed_nodes(self.tq[1], self.tp[1])
        self.sight = pl.paths.context(self.tq, self.tp, target_path) if pl.samples_path else None
        self.path_cost = pl.path_cost
        self.escapes = team.best_effort_escape
        self.min_distance = team.separation
        self.n_samples = team.path_samples
        self.own = [q.path_points(self.n_samples)[0][1:] for q in plans]   # sample 0 (the current position) is fixed
        self._candidates: dict[int, _Candidates] = {}
        self._efforts: dict[int, _Candidates] = {}

    # ------------------------------------------------------------------------------------- candidate moves
    def candidates(self, i: int) -> _Candidates:
        """UAV i's moves to every node: manoeuvres where one is flyable, else the engine's best efforts."""
        if i not in self._candidates:
            self.team.stats["safety_solves"] += 1
            self._candidates[i] = self._manoeuvres(i)
        return self._candidates[i]

    def best_efforts(self, i: int) -> _Candidates:
        """UAV i's best efforts toward every node (the escape's extra candidates; its candidates if it reaches no
        node)."""
        if self.candidates(i).best_effort:
            return self.candidates(i)
        if i not in self._efforts:
            self.team.stats["safety_solves"] += 1
            self._efforts[i] = self._best_efforts(i)
        return self._efforts[i]

    def path_of(self, i: int, move: _Move) -> np.ndarray:
        """(P - 1, 2) the samples UAV i flies with ``move``."""
        return (self.best_efforts(i) if move.best_effort else self.candidates(i)).samples[move.node]

    def _manoeuvres(self, i: int) -> _Candidates:
        c, st, clearance = self.config, self.stage, self.paths.clearance
        m = solve_manoeuvre(self.xy[i], self.th[i], st.xy, v_max=c.v_max, w_max=c.w_max, delta=c.delta)
        ok = np.asarray(m.feasible, bool).copy()
        if clearance.active:
            ok &= clearance.clear(st.xy)                          # eq. 3 at the node and along the path
            ok[ok] = clearance.manoeuvres_clear(m, ok)
        if not ok.any():
            return self._best_efforts(i)
        a0 = uav_target_angle(self.xy[i], self.tq[0, :2], self.tp[0])
        d0 = uav_target_distance(self.xy[i], self.tq[0, :2])
        g = transition_costs(c, m, ok, a0, d0, st.alpha, st.d)
        good = self.allowed_nodes.copy()
        if self.path_cost is not None and ok.any():
            # The planner's learned path cost ranks the moves as it ranks them in the DP.
            g[ok] += self.path_cost[0] * self.paths.blocked_share(m, ok, self.sight, 0)
        elif self.sight is not None and ok.any():
            clear = np.zeros(len(ok), bool)
            clear[ok] = self.paths.keeps_sight(m, ok, self.sight, 0, zone=False)
            good &= clear
        return _Candidates(heading=m.heading_after, speed=m.v, flyable=ok, samples=m.points(self.n_samples)[:, 1:],
                           cost=g, allowed=good, best_effort=False)

    def _best_efforts(self, i: int) -> _Candidates:
        st = self.stage
        n = len(st.xy)
        flown = flown_paths(np.broadcast_to(self.xy[i], st.xy.shape), np.full(n, self.th[i]), st.xy, self.config,
                            self.n_samples)
        ok = self.paths.clearance.paths_clear(flown)
        nan = np.full(n, np.nan)
        return _Candidates(heading=nan, speed=nan, flyable=ok, samples=flown[:, 1:],
                           cost=np.where(ok, nearness(self.config, st, self.xy[i], self.allowed_nodes), np.inf),
                           allowed=np.zeros(n, bool), best_effort=True)

    # ------------------------------------------------------------------------------------- choosing moves
    def pick(self, i: int, fixed: dict) -> _Move | None:
        """UAV i's cheapest move separated from the settled paths ``fixed``: to an allowed node if one is, else
        to any node (flagged); None if no move is separated."""
        cand = self.candidates(i)
        d = np.where(cand.flyable, _clear_of(cand.samples, fixed.values()), -np.inf)
        safe = d >= self.min_distance
        if (safe & cand.allowed).any():
            return _Move(int(np.argmin(np.where(safe & cand.allowed, cand.cost, np.inf))), False)
        if safe.any():
            return _Move(int(np.argmin(np.where(safe, cand.cost, np.inf))), True)
        return None

    def repair(self, i: int, h: int, fixed: dict) -> tuple[_Move, _Move] | None:
        """The moves of i and of the settled h re-chosen together (all pairs of their candidates): h's, then i's."""
        lim = self.min_distance
        rest = [f for k, f in fixed.items() if k != h]
        cand_i, cand_h = self.candidates(i), self.candidates(h)
        ci = np.flatnonzero(cand_i.flyable & (_clear_of(cand_i.samples, rest) >= lim))
        ch = np.flatnonzero(cand_h.flyable & (_clear_of(cand_h.samples, rest) >= lim))
        if ci.size == 0 or ch.size == 0:
            return None
        al_h, al_i = cand_h.allowed[ch], cand_i.allowed[ci]
        d = separation(cand_h.samples[ch][:, None], cand_i.samples[ci][None])
        # Prefer both visible, then the lowest total stage cost.
        score = cand_h.cost[ch][:, None] + cand_i.cost[ci][None] + FALLBACK_PENALTY * (
            (~al_h)[:, None].astype(float) + (~al_i)[None].astype(float))
        score = np.where(d >= lim, score, np.inf)
        if not np.isfinite(score).any():
            return None
        a_, b_ = np.unravel_index(int(np.argmin(score)), score.shape)
        return _Move(int(ch[a_]), bool(not al_h[a_])), _Move(int(ci[b_]), bool(not al_i[b_]))

    def _wide(self, i: int) -> tuple[_Candidates, int]:
        """UAV i's manoeuvres and best efforts stacked (the escape's candidates), and L: index k >= L is the best
        effort toward node k - L."""
        cand, eff = self.candidates(i), self.best_efforts(i)
        if cand.best_effort:
            return cand, len(cand.cost)
        both = _Candidates(*(np.concatenate([a, b]) for a, b in zip(cand[:-1], eff[:-1], strict=True)), False)
        return both, len(cand.cost)

    @staticmethod
    def _wide_move(k: int, n: int, cand: _Candidates, effort_only: bool) -> _Move:
        if effort_only:
            return _Move(k, True, True)
        return _Move(k % n, bool(k >= n or not cand.allowed[k]), k >= n)

    def escape(self, i: int, fixed: dict, moves: dict) -> _Move | None:
        """UAV i's best effort separated from the settled paths (the nearest node first); else i and the latest
        settled UAV that allows it re-chosen together over manoeuvres and best efforts (fewest best efforts, then
        the lowest summed cost: stage cost for a manoeuvre, level 3's nearness for a best effort), h's move and
        path in ``moves`` and ``fixed`` replaced. None if neither separates."""
        lim = self.min_distance
        eff = self.best_efforts(i)
        d = np.where(eff.flyable, _clear_of(eff.samples, fixed.values()), -np.inf)
        if (d >= lim).any():
            return _Move(int(np.argmin(np.where(d >= lim, eff.cost, np.inf))), True, True)
        wi, ni = self._wide(i)
        for h in reversed(list(fixed)):
            rest = [f for k, f in fixed.items() if k != h]
            wh, nh = self._wide(h)
            ci = np.flatnonzero(wi.flyable & (_clear_of(wi.samples, rest) >= lim))
            ch = np.flatnonzero(wh.flyable & (_clear_of(wh.samples, rest) >= lim))
            if ci.size == 0 or ch.size == 0:
                continue
            sep = separation(wh.samples[ch][:, None], wi.samples[ci][None])
            efforts = (ch >= nh)[:, None].astype(float) + (ci >= ni)[None].astype(float)
            score = np.where(sep >= lim, efforts * PER_BEST_EFFORT + wh.cost[ch][:, None] + wi.cost[ci][None], np.inf)
            if not np.isfinite(score).any():
                continue
            a_, b_ = np.unravel_index(int(np.argmin(score)), score.shape)
            moves[h] = self._wide_move(int(ch[a_]), nh, wh, self.candidates(h).best_effort)
            fixed[h] = wh.samples[ch[a_]]
            return self._wide_move(int(ci[b_]), ni, wi, self.candidates(i).best_effort)
        return None

    def most_separated(self, i: int, fixed: dict) -> _Move | None:
        """UAV i's flyable move farthest from the settled paths (flagged; among its best efforts too with the
        escape); None if none is flyable."""
        cand, n = self._wide(i) if self.escapes else (self.candidates(i), len(self.candidates(i).cost))
        if not cand.flyable.any():
            return None
        d = np.where(cand.flyable, _clear_of(cand.samples, fixed.values()), -np.inf)
        return self._wide_move(int(np.argmax(d)), n, cand, self.candidates(i).best_effort)

    # ------------------------------------------------------------------------------------- settling the team
    def settle(self, order: list[int]) -> tuple[dict, int | None]:
        """Moves per UAV settled in ``order`` (None: it keeps its plan); and the first UAV left without a
        separated move (None: clean)."""
        fixed, moves, stuck = {}, {}, None
        for i in order:
            if _clear_of(self.own[i][None], fixed.values())[0] >= self.min_distance:
                mv = None
            else:
                mv = self.pick(i, fixed)
                if mv is None:
                    mv = self._repair_with_a_settled_uav(i, fixed, moves)
                if mv is None and self.escapes:
                    mv = self.escape(i, fixed, moves)
                if mv is None:
                    stuck = i if stuck is None else stuck
                    mv = self.most_separated(i, fixed)         # None: nothing flyable, keep the (fallback) plan
            moves[i] = mv
            fixed[i] = self.own[i] if mv is None else self.path_of(i, mv)
        return moves, stuck

    def _repair_with_a_settled_uav(self, i: int, fixed: dict, moves: dict) -> _Move | None:
        """i's move from a joint re-choice with the latest settled UAV that allows one (whose move and path in
        ``moves`` and ``fixed`` it replaces); None if none does."""
        for h in reversed(list(fixed)):
            both = self.repair(i, h, fixed)
            if both is not None:
                moves[h], mv = both
                fixed[h] = self.candidates(h).samples[moves[h].node]
                return mv
        return None

    def negotiate(self) -> dict:
        """Moves per UAV in the order that stands after :func:`~covert_env.separation.priority_negotiation`."""
        settled: dict = {}
        u = len(self.own)

        def settle_order(order, rows):
            self.team.stats["safety_orders"] += 1
            seq = order[0].tolist()
            settled["moves"], stuck = self.settle(seq)
            return np.array([u if stuck is None else seq.index(stuck)])

        priority_negotiation(settle_order, 1, u)
        return settled["moves"]

    def safety_plan(self, plan: DPPlan, i: int, move: _Move) -> DPPlan:
        """``plan`` cut to UAV i's one safety move (``status="safety"``)."""
        cand = self.best_efforts(i) if move.best_effort else self.candidates(i)
        node = move.node
        n = len(plan.nodes)
        nodes = np.full(n, -1, np.int64)
        nodes[0] = node
        wp = np.full((n, 2), np.nan)
        wp[0] = self.stage.xy[node]
        head, v, cost = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
        head[0], v[0] = cand.heading[node], cand.speed[node]
        cost[0] = np.nan if cand.best_effort else cand.cost[node]          # a best effort has no planned cost
        return replace(plan, nodes=nodes, waypoints=wp, headings=head, speeds=v, stage_costs=cost,
                       cost=float(cost[0]), depth=1, status="safety", infeasible=move.infeasible, layers=None)
