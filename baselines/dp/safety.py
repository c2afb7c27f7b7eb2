"""The team's safety layer: separate the slot that is actually flown when the negotiation left a conflict in it."""

from __future__ import annotations

from dataclasses import replace
from typing import NamedTuple

import numpy as np

from baselines.dp.fallback import nearness
from baselines.dp.path_checks import FALLBACK_PENALTY
from baselines.dp.plan import DPPlan, flown_paths
from baselines.dp.transitions import transition_costs
from covert_env.geometry.cost import uav_target_angle, uav_target_distance
from covert_env.geometry.dynamics import solve_manoeuvre
from covert_env.geometry.separation import priority_negotiation, separation
from covert_env.geometry.ties import first_argmax, first_argmin, tie_tolerance

__all__ = ["secure_first_moves"]

#: The escape's score per best effort in a pair: above any sum of stage costs and fallback penalties, so fewer
#: best efforts always win.
PER_BEST_EFFORT = 1e9

#: Candidates of h compared with all of i's at once in the escape's pair search (at most CHUNK x L pairs of paths:
#: a UAV's manoeuvres and its escape's best efforts go to disjoint nodes).
CHUNK = 64

#: The per-node arrays of :class:`_Candidates` (stacked by :meth:`_FirstSlot._wide`).
_FIELDS = ("heading", "speed", "flyable", "samples", "cost", "allowed")


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
    escaped: bool = False     # a best effort of the escape (toward a node the UAV's manoeuvres cannot reach)


def secure_first_moves(team, plans, *, xy, th, target_xyz, target_phi, target_path=None) -> list:
    """Safety layer for the slot that is flown, after the negotiation left a conflict in it.

    Every path here is the one the engine will fly: a plan's first move as :meth:`DPPlan.path_points` gives it
    (a best-effort fallback included), a candidate move as its manoeuvre. In the order of
    :func:`~covert_env.geometry.separation.priority_negotiation`, a UAV keeps its plan if its first move keeps
    ``d_safe1 + separation_margin`` from those of the UAVs already settled, at every sample; otherwise it takes,
    among all lattice nodes of the next slot (solved exactly from its pose), the separated move to an allowed
    (visible) node with the lowest stage cost (eq. 18), else to any node (flagged infeasible). A UAV that can
    reach no node at all (a last-resort fallback) chooses among the engine's best efforts to every node instead,
    the nearest first (level 3's rule), flagged. If it has no separated move at all, its move and that of one
    settled UAV are re-chosen together (every pair of their candidates; a fast teammate sweeping past can leave
    no single move). Failing that it is left without one (docs/decisions/planner.md#safety-layer) and, in the order that
    stands, takes its most separated move (flagged). With the team's ``best_effort_escape``, that order is settled
    once more, and a UAV left without a separated move may also fly the engine's best effort toward a node it
    cannot reach, alone or re-chosen with a settled UAV (:meth:`_FirstSlot.escape`, flagged). Moves keep eq. 3
    along their samples. ``status="safety"``.

    Cost: at most U orders (U + 1 with the escape), each O(U) picks and O(U^2) pair repairs; every UAV's
    candidate moves are solved once (L manoeuvres, or L best efforts), and with the escape its best efforts once
    more. ``team.stats`` counts ``safety_orders`` and ``safety_solves``.
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
        self._reachable: dict[int, np.ndarray] = {}
        self._efforts: dict[int, _Candidates | None] = {}

    # ------------------------------------------------------------------------------------- candidate moves
    def candidates(self, i: int) -> _Candidates:
        """UAV i's moves to every node: manoeuvres where one is flyable, else the engine's best efforts."""
        if i not in self._candidates:
            self.team.stats["safety_solves"] += 1
            self._candidates[i] = self._manoeuvres(i)
        return self._candidates[i]

    def escape_efforts(self, i: int) -> _Candidates | None:
        """The escape's extra moves for UAV i: the engine's best efforts toward the nodes its manoeuvres cannot
        reach (flyable where eq. 3 holds along them); None if it reaches no node (its candidates are best efforts
        already)."""
        if self.candidates(i).best_effort:
            return None
        if i not in self._efforts:
            self.team.stats["safety_solves"] += 1
            eff = self._best_efforts(i)
            self._efforts[i] = eff._replace(flyable=eff.flyable & ~self._reachable[i])
        return self._efforts[i]

    def path_of(self, i: int, move) -> np.ndarray:
        """(P - 1, 2) the samples UAV i flies with ``move`` (a :class:`_Move`)."""
        return (self.escape_efforts(i) if move.escaped else self.candidates(i)).samples[move.node]

    def _manoeuvres(self, i: int) -> _Candidates:
        c, st, clearance = self.config, self.stage, self.paths.clearance
        m = solve_manoeuvre(self.xy[i], self.th[i], st.xy, v_max=c.v_max, w_max=c.w_max, delta=c.delta)
        self._reachable[i] = np.asarray(m.feasible, bool)
        ok = self._reachable[i].copy()
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
            return _Move(first_argmin(np.where(safe & cand.allowed, cand.cost, np.inf)), False)
        if safe.any():
            return _Move(first_argmin(np.where(safe, cand.cost, np.inf)), True)
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
        a_, b_ = np.unravel_index(first_argmin(score), score.shape)
        return _Move(int(ch[a_]), bool(not al_h[a_])), _Move(int(ci[b_]), bool(not al_i[b_]))

    def _wide(self, i: int) -> tuple[_Candidates, int]:
        """UAV i's candidates with the escape's best efforts stacked after them, and L: index k >= L is the best
        effort toward node k - L."""
        cand, eff = self.candidates(i), self.escape_efforts(i)
        if eff is None:
            return cand, len(cand.cost)
        both = {f: np.concatenate([getattr(cand, f), getattr(eff, f)]) for f in _FIELDS}
        return _Candidates(**both, best_effort=False), len(cand.cost)

    @staticmethod
    def _wide_move(k: int, n: int, wide: _Candidates, flagged: bool = False) -> _Move:
        return _Move(k % n, bool(flagged or not wide.allowed[k]), k >= n)

    def escape(self, i: int, fixed: dict, moves: dict) -> _Move | None:
        """UAV i's escape: its best effort toward a node it cannot reach, separated from the settled paths (the
        nearest node first, level 3's rule); else i and the latest settled UAV h that allows it, re-chosen
        together over their moves and best efforts (the fewest best efforts, then the fewest moves off the
        allowed nodes, then the lowest summed cost: stage cost for a manoeuvre, level 3's nearness for a best
        effort), h's move and path in ``moves`` and ``fixed`` replaced. None if neither separates."""
        lim = self.min_distance
        eff = self.escape_efforts(i)
        if eff is not None:
            d = np.where(eff.flyable, _clear_of(eff.samples, fixed.values()), -np.inf)
            if (d >= lim).any():
                return _Move(first_argmin(np.where(d >= lim, eff.cost, np.inf)), True, True)
        wi, ni = self._wide(i)
        for h in reversed(list(fixed)):
            rest = [f for k, f in fixed.items() if k != h]
            wh, nh = self._wide(h)
            ci = np.flatnonzero(wi.flyable & (_clear_of(wi.samples, rest) >= lim))
            ch = np.flatnonzero(wh.flyable & (_clear_of(wh.samples, rest) >= lim))
            if ci.size == 0 or ch.size == 0:
                continue
            score_i = PER_BEST_EFFORT * (ci >= ni) + FALLBACK_PENALTY * ~wi.allowed[ci] + wi.cost[ci]
            score_h = PER_BEST_EFFORT * (ch >= nh) + FALLBACK_PENALTY * ~wh.allowed[ch] + wh.cost[ch]
            best, pair = np.inf, None
            for s in range(0, len(ch), CHUNK):
                k = ch[s:s + CHUNK]
                sep = separation(wh.samples[k][:, None], wi.samples[ci][None])
                score = np.where(sep >= lim, score_h[s:s + CHUNK, None] + score_i[None], np.inf)
                q = first_argmin(score)
                if score.flat[q] < best - tie_tolerance(best, score.dtype):
                    best, pair = score.flat[q], (int(k[q // len(ci)]), int(ci[q % len(ci)]))
            if pair is None:
                continue
            moves[h] = self._wide_move(pair[0], nh, wh)
            fixed[h] = wh.samples[pair[0]]
            return self._wide_move(pair[1], ni, wi)
        return None

    def most_separated(self, i: int, fixed: dict, escape: bool = False) -> _Move | None:
        """UAV i's flyable move farthest from the settled paths (flagged; with ``escape``, its escape's best
        efforts count too); None if none is flyable."""
        cand, n = self._wide(i) if escape else (self.candidates(i), len(self.candidates(i).cost))
        if not cand.flyable.any():
            return None
        d = np.where(cand.flyable, _clear_of(cand.samples, fixed.values()), -np.inf)
        return self._wide_move(first_argmax(d), n, cand, flagged=True)

    # ------------------------------------------------------------------------------------- settling the team
    def settle(self, order: list[int], escape: bool = False) -> tuple[dict, int | None]:
        """Moves per UAV settled in ``order`` (None: it keeps its plan), with :meth:`escape` as the last resort if
        ``escape``; and the first UAV left without a separated move (None: clean)."""
        fixed, moves, stuck = {}, {}, None
        for i in order:
            if _clear_of(self.own[i][None], fixed.values())[0] >= self.min_distance:
                mv = None
            else:
                mv = self.pick(i, fixed)
                if mv is None:
                    mv = self._repair_with_a_settled_uav(i, fixed, moves)
                if mv is None and escape:
                    mv = self.escape(i, fixed, moves)
                if mv is None:
                    stuck = i if stuck is None else stuck
                    mv = self.most_separated(i, fixed, escape)   # None: nothing flyable, keep the (fallback) plan
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
                fixed[h] = self.path_of(h, moves[h])
                return mv
        return None

    def negotiate(self) -> dict:
        """Moves per UAV in the order that stands after :func:`~covert_env.geometry.separation.priority_negotiation`; if
        that order leaves a UAV without a separated move and the team escapes, that order settled again with the
        escape (so the escape acts only where no order separates the team with the UAVs' own candidates)."""
        settled: dict = {}
        u = len(self.own)

        def settle_order(order, rows):
            self.team.stats["safety_orders"] += 1
            settled["order"] = order[0].tolist()
            settled["moves"], stuck = self.settle(settled["order"])
            return np.array([u if stuck is None else settled["order"].index(stuck)])

        if priority_negotiation(settle_order, 1, u)[0] and self.escapes:
            self.team.stats["safety_orders"] += 1
            settled["moves"], _ = self.settle(settled["order"], escape=True)
        return settled["moves"]

    def safety_plan(self, plan: DPPlan, i: int, move: _Move) -> DPPlan:
        """``plan`` cut to UAV i's one safety move (``status="safety"``)."""
        cand = self.escape_efforts(i) if move.escaped else self.candidates(i)
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
